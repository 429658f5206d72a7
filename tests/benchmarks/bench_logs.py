"""Speed and memory of loading flight data: CSV on pyarrow, and autopilot logs (issue 32).

Cases and targets:

* CSV of 10 million rows x 8 columns (time + 7 channels) through
  `aeroid.load_flight_test`: <= 10 s, and a peak resident memory (above the
  fresh process's baseline after imports) <= 2x the file's size.
* `aeroid.list_channels` of the sample PX4 ULog: <= 1 s.
* `aeroid.load_flight_test` of 12 ULog channels resampled at 100 Hz: <= 2 s
  (needs `aeroid.io.resampling.resample`; skipped when that module is absent).

Run as a script: ``python tests/benchmarks/bench_logs.py [--rows N] [--repeat N]``.
Every measured call runs in a fresh child process (default environment), so
the first call and the peak memory are those a user sees; the warm median
repeats the call inside one child.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

HERE = Path(__file__).resolve().parent
ULOG = HERE.parent / "data" / "px4" / "sample_log_small.ulg"
ULOG_CHANNELS = [
    "vehicle_angular_velocity.xyz[0]",
    "vehicle_angular_velocity.xyz[1]",
    "vehicle_angular_velocity.xyz[2]",
    "sensor_combined.accelerometer_m_s2[0]",
    "sensor_combined.accelerometer_m_s2[1]",
    "sensor_combined.accelerometer_m_s2[2]",
    "vehicle_attitude.q[0]",
    "vehicle_attitude.q[1]",
    "vehicle_attitude.q[2]",
    "vehicle_attitude.q[3]",
    "actuator_controls_0.control[0]",
    "actuator_controls_0.control[1]",
]

CHILD = textwrap.dedent(
    """
    import json, resource, statistics, sys, time
    import aeroid, aeroid.io.data, pyarrow.csv  # imports belong to the baseline
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    kind, path, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3])
    channels = json.loads(sys.argv[4])

    def call():
        if kind == "csv":
            return aeroid.load_flight_test(path)
        if kind == "list":
            return aeroid.list_channels(path)
        return aeroid.load_flight_test(path, channels=channels, sample_rate=100.0,
                                     max_gap=float("inf"))

    t0 = time.perf_counter()
    out = call()
    first = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - base
    del out
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    print(json.dumps({"first": first, "peak": peak,
                      "warm": statistics.median(times) if times else first}))
    """
)


def _child(kind: str, path: Path, repeat: int, channels: list[str] | None = None) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, kind, str(path), str(repeat), json.dumps(channels)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def _write_csv(path: Path, rows: int) -> None:
    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    rng = np.random.default_rng(0)
    block = 1_000_000
    with pacsv.CSVWriter(
        str(path), pa.schema([(n, pa.float64()) for n in ["time", *(f"c{j}" for j in range(7))]])
    ) as writer:
        for start in range(0, rows, block):
            n = min(block, rows - start)
            cols = {"time": (start + np.arange(n)) * 0.01}
            cols.update({f"c{j}": rng.standard_normal(n) for j in range(7)})
            writer.write_table(pa.table(cols))


def _csv_case(rows: int, repeat: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "flight.csv"
        _write_csv(csv, rows)
        size = csv.stat().st_size
        r = _child("csv", csv, repeat)
    print(
        f"CSV {rows} x 8 ({size / 1e9:.2f} GB): first {r['first']:.2f} s, "
        f"warm median {r['warm']:.2f} s (target <= 10 s); peak RSS above baseline "
        f"{r['peak'] / 1e9:.2f} GB = {r['peak'] / size:.2f}x the file (target <= 2x)"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rows", type=int, default=10_000_000, help="0: the log cases only")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if args.rows > 0:
        _csv_case(args.rows, args.repeat)
    r = _child("list", ULOG, max(args.repeat, 5))
    print(
        f"list_channels({ULOG.name}): first {r['first']:.3f} s, warm median "
        f"{r['warm']:.3f} s (target <= 1 s)"
    )
    if importlib.util.find_spec("aeroid.io.resampling") is None:
        print("load_flight_test(ULog, 12 channels, 100 Hz): skipped (no aeroid.io.resampling)")
        return
    r = _child("load", ULOG, max(args.repeat, 5), ULOG_CHANNELS)
    print(
        f"load_flight_test({ULOG.name}, 12 channels, 100 Hz): first {r['first']:.3f} s, "
        f"warm median {r['warm']:.3f} s (target <= 2 s)"
    )


if __name__ == "__main__":
    main()
