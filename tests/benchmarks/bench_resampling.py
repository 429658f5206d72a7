"""Benchmark: multi-rate resampling onto one grid, and automatic manoeuvre segmentation.

Run as ``python tests/benchmarks/bench_resampling.py``. Prints the accuracy
figures next to their targets (issue 32: decimation 400 -> 50 Hz of a
band-limited signal <= 1e-3 relative; five manoeuvres found, edges within
0.5 s) and the time of a first call (fresh process, imports included) and
the warm median of several runs.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from _timing import timed

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the synthetic record

from _manoeuvre_record import manoeuvre_record

FREQS = (0.3, 1.7, 4.1, 7.3, 9.9)  # below 0.4 x the new Nyquist frequency (10 Hz)
AMPS = (1.0, 0.7, 0.5, 0.4, 0.3)


def _signal(t: np.ndarray, phases: np.ndarray) -> np.ndarray:
    return sum(
        a * np.sin(2 * np.pi * f * t + p) for f, a, p in zip(FREQS, AMPS, phases, strict=True)
    )


def _long_log(minutes: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Gyros at 400 Hz (jittered stamps), attitude at 50 Hz, air data at 10 Hz."""
    rng = np.random.default_rng(0)
    log = {}
    for name, rate, jitter in (
        ("IMU.GyrX", 400, 0.2),
        ("IMU.GyrY", 400, 0.2),
        ("IMU.GyrZ", 400, 0.2),
        ("ATT.Pitch", 50, 0.0),
        ("ATT.Roll", 50, 0.0),
        ("ARSP.Airspeed", 10, 0.0),
    ):
        n = int(minutes * 60 * rate) + 1
        t = (np.arange(n) + rng.uniform(-jitter, jitter, n)) / rate
        log[name] = (t, np.sin(0.7 * t) + 0.01 * rng.standard_normal(n))
    return log


def resampling_accuracy() -> None:
    from aeroid import resample

    print("resampling accuracy (RMS error / RMS signal, one filter length from the ends)")
    print(f"{'case':52s} {'measured':>10s} {'target':>8s}")
    phases = np.random.default_rng(0).uniform(0, 2 * np.pi, len(FREQS))
    t = np.arange(60 * 400 + 1) / 400.0
    rng = np.random.default_rng(1)
    jittered = t + rng.uniform(-0.3, 0.3, t.size) / 400.0
    cases = [
        ("400 -> 50 Hz, grid on source stamps, auto", t, 0.0, "auto"),
        ("400 -> 50 Hz, grid between stamps, auto (cubic)", t, 0.0137, "auto"),
        ("400 -> 50 Hz, grid between stamps, linear", t, 0.0137, "linear"),
        ("400 -> 50 Hz, jittered stamps (+-0.3 step), auto", jittered, 0.0137, "auto"),
    ]
    for label, stamps, t0, method in cases:
        out = resample(
            {"x": (stamps, _signal(stamps, phases))}, ["x"], rate=50, t0=t0, method=method
        )
        edge = out.metadata["resampling"]["channels"]["x"]["anti_alias"]["edge_s"]
        inner = (out.time > out.time[0] + edge) & (out.time < out.time[-1] - edge)
        truth = _signal(out.time[inner], phases)
        err = np.sqrt(np.mean((out["x"][inner] - truth) ** 2) / np.mean(truth**2))
        print(f"{label:52s} {err:10.2e} {1e-3:8.0e}")
    for f, alias in ((26.0, 24.0), (40.0, 10.0)):
        out = resample({"x": (t, np.sin(2 * np.pi * f * t))}, ["x"], rate=50, t0=0.0013)
        design = out.metadata["resampling"]["channels"]["x"]["anti_alias"]
        inner = (out.time > design["edge_s"]) & (out.time < out.time[-1] - design["edge_s"])
        label = f"{f:g} Hz tone (would alias to {alias:g} Hz): peak left"
        print(f"{label:52s} {np.abs(out['x'][inner]).max():10.2e} {1e-4:8.0e}")
    print(
        f"  filter: {design['taps']} taps, beta {design['beta']:.2f}, flat to "
        f"{design['passband_edge_hz']:g} Hz, {design['attenuation_db']:g} dB from "
        f"{design['stopband_edge_hz']:g} Hz"
    )
    w, h = 2 * np.pi * 0.5, 0.1
    ts = np.arange(0, 20 + h / 2, h)
    for method, bound in (("linear", (w * h) ** 2 / 8), ("cubic", 5 / 384 * (w * h) ** 4)):
        out = resample({"s": (ts, np.sin(w * ts))}, ["s"], rate=100, method=method)
        inner = (out.time > 2) & (out.time < 18)
        err = np.abs(out["s"] - np.sin(w * out.time))[inner].max()
        print(
            f"{'10 -> 100 Hz, 0.5 Hz sine, ' + method + ' (max error / bound)':52s} "
            f"{err:10.2e} {bound:8.1e}"
        )
    const = resample({"c": (jittered, np.full(t.size, 0.1 + 0.2))}, ["c"], rate=50, method="auto")
    print(
        f"{'constant 0.1 + 0.2 through the filter: max |change|':52s} "
        f"{np.abs(const['c'] - (0.1 + 0.2)).max():10.2e} {0.0:8.0e}"
    )


def resampling_speed() -> None:
    from aeroid import resample

    log = _long_log(30)
    names = list(log)
    start = time.perf_counter()
    resample(log, names, rate=50)
    first = time.perf_counter() - start
    warm, out = timed(lambda: resample(log, names, rate=50), 5)
    samples = sum(v[0].size for v in log.values())
    print(
        f"\nresample 30 min log, 6 channels (3 x 400 Hz jittered, 2 x 50, 1 x 10 Hz; "
        f"{samples / 1e6:.1f} M samples) -> 50 Hz ({out.n_samples} x {len(out.names)}): "
        f"first call {first:.3f} s (imports included), warm median {warm:.3f} s"
    )


def segmentation_recovery(seeds: int = 100) -> None:
    from aeroid import segment

    inputs = ["elevator", "aileron", "rudder"]
    found, worst, errors = 0, 0.0, []
    start = time.perf_counter()
    segment(manoeuvre_record(0)[0], inputs=inputs)
    first = time.perf_counter() - start
    for seed in range(seeds):
        data, truth = manoeuvre_record(seed)
        result = segment(data, inputs=inputs)
        if len(result.windows) != len(truth):
            continue
        found += 1
        e = [
            (abs(w.t0 - (a - 1.0)), abs(w.t1 - (b + 1.0)))
            for w, (a, b) in zip(result.windows, truth, strict=True)
        ]
        errors.extend(x for pair in e for x in pair)
        worst = max(worst, max(max(pair) for pair in e))
    data, _ = manoeuvre_record(0)
    warm, _ = timed(lambda: segment(data, inputs=inputs), 7)
    print(
        f"\nsegmentation, {seeds} seeds x 5 manoeuvres (200 s, 3 inputs at 50 Hz):\n"
        f"  records with all 5 found and no extra: {found}/{seeds} (target all)\n"
        f"  window edge error: median {np.median(errors):.3f} s, max {worst:.3f} s "
        f"(target <= 0.5 s)\n"
        f"  one call: first {first:.3f} s (imports included), warm median {warm:.4f} s"
    )


def main() -> None:
    resampling_accuracy()
    resampling_speed()
    segmentation_recovery()


if __name__ == "__main__":
    main()
