"""Pipeline benchmarks (run by hand): ``python tests/benchmarks/bench_pipeline.py``.

Figures (issue 5):
  1. a 24-flight campaign load -> identify -> validate -> propagate -> report,
     cold, with 2 worker processes vs 1 (target: >= 1.7x faster);
  2. keys, store and scheduling overhead of a cold run (target: <= 10 %),
     as (wall time - time inside the library calls / workers) / wall time;
  3. an unchanged rerun of the demo, end to end as a user types it
     (``aeroid run configs/demo.yaml``; target: <= 3 s).
Figures 1 and 2 are medians over --repeats runs of each run's own ratio or
share (beside them, the same from the median times); figure 3 is the median
time of --repeats reruns. Beside figure 1 the benchmark
measures two ceilings of the machine: the same CPU-bound loop run twice in
one process and once in each of two processes at the same time, and the
campaign's own library calls (fly, identify, validate, propagate, report for
every flight; no keys, store, Dask or figures) run in one process vs split
over two. On a shared or virtual machine two "cores" often give well under
2x; the pipeline's speed-up is reported against both. Runs with 1 and 2
workers are also timed from inside the workers, which splits the speed-up into
the machine's part (the same nodes take longer on two processes at once) and
the pipeline's (the share of the workers' time they are busy: not while the
cluster starts, nor while they wait on the last flight or on the report).
While the library's identify / validate / propagate / report are not
available, a CPU-bound stand-in stage replaces them (reported as such).
"""

from __future__ import annotations

import argparse
import multiprocessing
import multiprocessing.pool
import os
import shutil
import statistics
import subprocess
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

import aeroid
from aeroid.pipeline import run

ROOT = Path(__file__).resolve().parents[2]
CHAIN = all(hasattr(aeroid, f) for f in ("identify", "validate", "propagate", "report"))

STAND_IN = textwrap.dedent(
    """
    from dataclasses import dataclass
    import numpy as np
    from aeroid.pipeline import Pipeline, Stage, Step, register_record, register_stage
    from aeroid.pipeline.plans.config import Options

    @register_record
    @dataclass(frozen=True, eq=False)
    class Fit:
        theta: np.ndarray

    class FitOptions(Options):
        iterations: int = 6000

    def run_fit(ctx):  # about as much CPU as an output-error fit of one flight
        d = ctx.inputs["data"]
        x = d.array(list(d.names))
        theta = np.zeros(x.shape[1])
        for _ in range(ctx.options.iterations):
            theta = np.linalg.lstsq(x, x[:, 1] + 1e-3 * theta[1], rcond=None)[0]
        return Fit(theta)

    register_stage(Stage("fit", "1", FitOptions, "bench_stand_in:Fit", run_fit, uses_model=False))
    pipeline = Pipeline("bench", flight_steps=(Step("load"), Step("fit", inputs={"data": "load"})),
                        campaign_steps=(Step("campaign_report", inputs={"data": "load"}),))
    """
)


def campaign(tmp: Path, n: int, duration: float = 20.0, maneuver: str = "doublet_sweep") -> Path:
    cfg = tmp / "bench.yaml"
    flights = (
        f"flights: [{{simulated: {{n_flights: {n}, seed: 3, duration: {duration}, "
        f"maneuver: {maneuver}}}}}]\n"
    )
    if CHAIN:
        cfg.write_text(
            f"model: short_period\n{flights}"
            "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n"
            "  validate: {}\n  propagate: {metric: natural_frequency, n_samples: 2000}\n"
        )
    else:
        (tmp / "bench_stand_in.py").write_text(STAND_IN)
        cfg.write_text(
            f"model: short_period\npipeline: bench_stand_in:pipeline\n{flights}"
            "stages: {fit: {}}\n"
        )
    return cfg


# a memory file system where the machine has one: the same run with the store there
# tells the pipeline's own overhead from the disk's (file creation on a busy or
# journal-less ext4 costs 20-300 us, on tmpfs 4-10 us)
SHM = Path("/dev/shm") if Path("/dev/shm").is_dir() and os.access("/dev/shm", os.W_OK) else None


def settle() -> None:
    """Let a run's aftermath pass before the next one is timed, as it has for a fresh
    `aeroid run`: OpenBLAS's threads, started again when the run
    gives this process its BLAS threads back, spin for about 0.1 s before they sleep.
    The run's files are flushed to disk: otherwise the disk writes back one run's store
    (a few MB) while the next run creates its files, which on this VM's ext4 slowed file
    creation from about 25 us to 200-400 us, so runs early in a repeat were timed on a
    quiet disk and later ones on a busy one."""
    os.sync()
    time.sleep(0.2)


def cold(cfg: Path, workers: int, tag: str, base: Path) -> tuple[float, float]:
    store = Path(tempfile.mkdtemp(prefix=f"bench-{tag}-", dir=base)) / "store"
    t0 = time.perf_counter()
    s = run(cfg, store=store, workers=workers)
    wall = time.perf_counter() - t0  # the results are stored and the report written
    settle()
    if s.failed:
        raise SystemExit(f"benchmark run failed (store {store}): {s.to_json()['tasks']}")
    return wall, s.seconds["compute"]


def worker_time(cfg: Path, workers: int, base: Path) -> tuple[float, float, float, float, float]:
    """One cold run with `workers` processes, timed from inside the workers: (wall, worker
    time busy in the pipeline's nodes, and idle before a worker's first node, between
    nodes, after its last node), summed over the workers, from wall-clock stamps each
    node takes where it runs.

    Busy and idle add up to `workers` x wall. Idle time is what the pipeline could
    still win with more workers (starting the cluster, waiting on the last flight or
    on the report); busy time that grows from 1 worker to 2 is the machine's: two
    processes at once run slower than one alone (the ceilings above).
    """
    from aeroid.pipeline.running import execution as runner

    log = Path(tempfile.mkdtemp(prefix="bench-spans-", dir=base)) / "spans"

    def stamped(call: Any) -> Any:
        def node(*args: Any, **kwargs: Any) -> Any:
            start = time.time()
            try:
                return call(*args, **kwargs)
            finally:
                # one short line appended at once: the workers' lines do not mix
                with open(log, "a") as fh:
                    fh.write(f"{os.getpid()} {start!r} {time.time()!r}\n")

        return node

    chain, part = runner.execute_chain, runner.execute_part
    # bound into the run's nodes as it plans them; forked or pickled by value, the
    # workers run the stamped ones
    runner.execute_chain, runner.execute_part = stamped(chain), stamped(part)
    try:
        store = log.parent / "store"
        t0 = time.time()
        summary = run(cfg, store=store, workers=workers)
        t1 = time.time()
    finally:
        runner.execute_chain, runner.execute_part = chain, part
    settle()
    if summary.failed:
        raise SystemExit(f"benchmark run failed (store {store}): {summary.to_json()['tasks']}")
    spans: dict[int, list[tuple[float, float]]] = {}
    for line in log.read_text().splitlines():
        pid, a, b = line.split()
        spans.setdefault(int(pid), []).append((float(a), float(b)))
    busy = sum(b - a for s in spans.values() for a, b in s)
    before = sum(min(a for a, _ in s) - t0 for s in spans.values())
    after = sum(t1 - max(b for _, b in s) for s in spans.values())
    # a worker that never ran a node (more workers than nodes) idled throughout
    before += (workers - len(spans)) * (t1 - t0)
    between = workers * (t1 - t0) - busy - before - after
    return t1 - t0, busy, before, between, after


def _burn(n: int) -> float:
    t = time.perf_counter()
    x = 0
    for i in range(n):
        x += i * i
    return time.perf_counter() - t


def _two_burns(n: int) -> float:
    return _burn(n) + _burn(n)


def ceiling(pool: multiprocessing.pool.Pool, n: int = 6_000_000) -> float:
    """Two CPU-bound loops one after the other vs at the same time in two processes."""
    t = time.perf_counter()
    pool.apply(_two_burns, (n,))
    serial = time.perf_counter() - t
    t = time.perf_counter()
    pool.map(_burn, [n, n], chunksize=1)
    return serial / (time.perf_counter() - t)


def _library_flights(
    indices: list[int], duration: float = 20.0, maneuver: str = "doublet_sweep"
) -> float:
    """The campaign's per-flight library calls, as the pipeline's stages make them."""
    from aeroid.models import catalog
    from aeroid.pipeline.plans.synthetic import flight_spec, fly
    from aeroid.pipeline.stages.library_stages import natural_frequency

    model = catalog.short_period()
    spec = {"n_flights": 24, "seed": 3, "duration": duration, "maneuver": maneuver}
    t = time.perf_counter()
    for i in indices:
        data = fly(flight_spec(spec, i))
        r = aeroid.identify(model, data, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
        v = aeroid.validate(model, data, r)
        p = aeroid.propagate(r, natural_frequency, n_samples=2000, seed=i)
        aeroid.report(v, r, p, title=f"Flight {i}")
    return time.perf_counter() - t


def library_ceiling(
    pool: multiprocessing.pool.Pool, n: int, duration: float, maneuver: str
) -> float:
    """The library work of `n` flights in one process vs split over two at once."""
    t = time.perf_counter()
    pool.apply(_library_flights, (list(range(n)), duration, maneuver))
    serial = time.perf_counter() - t
    t = time.perf_counter()
    halves = [
        (list(range(0, n, 2)), duration, maneuver),
        (list(range(1, n, 2)), duration, maneuver),
    ]
    pool.starmap(_library_flights, halves, chunksize=1)
    return serial / (time.perf_counter() - t)


def fs_probe(base: Path, n: int = 200) -> tuple[float, float]:
    """Microseconds to create a folder and to create (and close) a small file where the
    benchmark's stores live: a commit creates one file per result and renames it, so on a
    slow or busy disk these, not the pipeline's Python, set much of the store's share of
    a cold run."""
    root = Path(tempfile.mkdtemp(prefix="bench-fs-", dir=base))
    t = time.perf_counter()
    for i in range(n):
        (root / f"d{i}").mkdir()
    folder = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for i in range(n):
        (root / f"d{i}" / "zarr.json").write_bytes(b"{}")
    file = (time.perf_counter() - t) / n
    return 1e6 * folder, 1e6 * file


def demo_cold(base: Path) -> None:
    """The main job's cold run: keys+store overhead in-process, and 2 vs 1 workers.

    Its flights carry long MCMC tasks, so fixed costs (starting the cluster, the
    serial end of the report) weigh far less than in the short campaign above.
    """
    demo = ROOT / "configs" / "demo.yaml"
    d0 = cold(demo, 0, "demo-w0", base)
    d1 = cold(demo, 1, "demo-w1", base)
    d2 = cold(demo, 2, "demo-w2", base)
    print(f"demo cold, in-process   : {d0[0]:7.2f} s (library time {d0[1]:.2f} s)")
    print(f"  overhead keys+store   : {100 * (d0[0] - d0[1]) / d0[0]:7.2f} %  (target <= 10)")
    print(f"demo cold, 1 worker     : {d1[0]:7.2f} s")
    print(f"demo cold, 2 workers    : {d2[0]:7.2f} s")
    print(f"  speed-up 2 vs 1       : {d1[0] / d2[0]:7.2f} x")


def overhead(runs: list[tuple[float, float]]) -> str:
    """The share of a run's wall time spent outside the library calls: the median of
    the runs' own shares (a run's wall and library time rise and fall together with
    the machine's load), then the same from the median wall and library times."""
    own = statistics.median((w - c) / w for w, c in runs)
    wall, lib = (statistics.median(x) for x in zip(*runs, strict=True))
    return f"{100 * own:5.1f} %  (from the medians {100 * (wall - lib) / wall:.1f} %)"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=5)
    # the demo's flights: 20 s at 50 Hz, a doublet and then a 0.2-3 Hz sweep
    ap.add_argument("--duration", type=float, default=20.0, help="record length, s")
    ap.add_argument("--maneuver", choices=("doublet", "doublet_sweep"), default="doublet_sweep")
    ap.add_argument("--no-demo", action="store_true", help="skip the demo rerun figure")
    ap.add_argument(
        "--demo-cold",
        action="store_true",
        help="also run the demo cold in-process, with 1 and with 2 workers (about 4 min)",
    )
    args = ap.parse_args()
    # every store and probe of the benchmark lives here; removed once it has measured
    # (a failed run stops it first and leaves them for a look)
    tmp = Path(tempfile.mkdtemp(prefix="bench-pipeline-"))
    measure(args, tmp)
    shutil.rmtree(tmp, ignore_errors=True)


def measure(args: argparse.Namespace, tmp: Path) -> None:
    cfg = campaign(tmp, args.flights, args.duration, args.maneuver)
    what = "load->identify->validate->propagate->report" if CHAIN else "STAND-IN load->fit->report"
    print(
        f"{args.flights}-flight campaign of {args.duration:g} s {args.maneuver} records, {what}, "
        f"{args.repeats} repeats"
    )

    # imports and caches of this process, paid once
    cold(cfg, 0, "warm-up", tmp)
    cold(cfg, 1, "warm-up", tmp)
    w1, w2, w0, m0, ceil, lib = [], [], [], [], [], []
    fs: list[tuple[float, float]] = []
    inside: dict[int, list[tuple[float, ...]]] = {1: [], 2: []}  # timed from the workers
    # the default environment: the library, not the benchmark, manages BLAS threads
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        ceiling(pool, 100_000)  # starts the pool's processes
        if CHAIN:
            pool.map(_library_flights, [[0], [1]], chunksize=1)  # and their imports
        for _ in range(args.repeats):  # interleaved, so drifts in machine load hit all
            ceil.append(ceiling(pool))
            if CHAIN:
                lib.append(library_ceiling(pool, args.flights, args.duration, args.maneuver))
            w1.append(cold(cfg, 1, "w1", tmp))
            w2.append(cold(cfg, 2, "w2", tmp))
            w0.append(cold(cfg, 0, "w0", tmp))
            if SHM is not None:
                m0.append(cold(cfg, 0, "w0-shm", SHM))
            fs.append(fs_probe(tmp))
    # after the timed repeats, which run as they did before this diagnostic existed
    for _ in range(max(3, args.repeats // 3)):
        for n in inside:
            inside[n].append(worker_time(cfg, n, tmp))
    t1 = statistics.median(w for w, _ in w1)
    t2 = statistics.median(w for w, _ in w2)
    t0 = statistics.median(w for w, _ in w0)
    c0 = statistics.median(c for _, c in w0)
    c1 = statistics.median(c for _, c in w1)
    print(f"cold, 1 worker process : {t1:7.2f} s (library time {c1:.2f} s)")
    print(f"cold, 2 worker processes: {t2:7.2f} s")
    # each repeat runs 1 and 2 workers back to back: the median of the paired ratios is
    # the headline (the ratio of the medians is shown too)
    speedups = [a / b for (a, _), (b, _) in zip(w1, w2, strict=True)]
    speedup = statistics.median(speedups)
    print(f"speed-up 2 vs 1         : {speedup:7.2f} x   (target >= 1.7)")
    print(f"  per repeat            : {', '.join(f'{x:.2f}' for x in speedups)}")
    print(f"  ratio of the medians  : {t1 / t2:7.2f} x")
    print(
        f"machine ceiling 2 vs 1  : {statistics.median(ceil):7.2f} x   "
        f"(per repeat {', '.join(f'{x:.2f}' for x in ceil)})"
    )
    print(f"speed-up / ceiling      : {speedup / statistics.median(ceil):7.2f}")
    if lib:
        print(
            f"library-only ceiling    : {statistics.median(lib):7.2f} x   "
            f"(per repeat {', '.join(f'{x:.2f}' for x in lib)})"
        )
        print(f"speed-up / library ceiling: {speedup / statistics.median(lib):5.2f}")
    med = {n: [statistics.median(x) for x in zip(*r, strict=True)] for n, r in inside.items()}
    for n, (wall, busy, before, between, after) in med.items():
        print(
            f"worker time, {n} worker{'s' if n > 1 else ' '}: busy {busy:.2f} s of "
            f"{n} x {wall:.2f} s; idle {before:.2f} s before a worker's first node, "
            f"{between:.2f} s between nodes, {after:.2f} s after its last"
        )
    # w_n = busy_n / (n u_n), u_n the share of n x w_n the workers were busy, so
    # 2 vs 1 = 2 x (busy_1 / busy_2) x (u_2 / u_1): the machine's part, then the pipeline's
    (wall1, busy1, *_), (wall2, busy2, *_) = med[1], med[2]
    u1, u2 = busy1 / wall1, busy2 / (2 * wall2)
    print(
        f"  2 vs 1 in these runs  : {wall1 / wall2:7.2f} x = 2 x {busy1 / busy2:.2f} (the same "
        f"work busy {busy2 / busy1:.2f} x as long on two processes at once) x {u2 / u1:.2f} "
        f"(workers busy {100 * u2:.0f} % of a 2-worker run, {100 * u1:.0f} % of a 1-worker run)"
    )
    print(f"cold, in-process        : {t0:7.2f} s (library time {c0:.2f} s)")
    print(f"overhead keys+store, in-process   : {overhead(w0)}  (target <= 10)")
    print(f"overhead keys+store+dask, 1 worker: {overhead(w1)}")
    if m0 and SHM is not None:
        print(f"overhead keys+store, in-process, store on tmpfs: {overhead(m0)}")
        for leftover in SHM.glob("bench-w0-shm-*"):  # memory, not disk: not left behind
            shutil.rmtree(leftover, ignore_errors=True)
    folder, file = (statistics.median(x) for x in zip(*fs, strict=True))
    print(
        f"file system: a folder {folder:.0f} us, a file {file:.0f} us (per repeat, files: "
        f"{', '.join(f'{f:.0f}' for _, f in fs)})"
    )
    if args.demo_cold:
        demo_cold(tmp)
    if args.no_demo:
        return

    demo = ROOT / "configs" / "demo.yaml"
    store = tmp / "demo-store"
    first = subprocess.run(
        ["aeroid", "run", str(demo), "--store", str(store), "--quiet"],
        capture_output=True,
        text=True,
    )
    print(f"demo cold run: exit {first.returncode}; {first.stdout.strip().splitlines()[-2:]}")
    times = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        subprocess.run(
            ["aeroid", "run", str(demo), "--store", str(store), "--quiet"],
            capture_output=True,
            text=True,
        )
        times.append(time.perf_counter() - t)
    print(f"unchanged demo rerun    : {statistics.median(times):7.2f} s   (target <= 3)")


if __name__ == "__main__":
    main()
