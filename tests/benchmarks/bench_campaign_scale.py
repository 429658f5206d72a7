"""Campaigns at scale (issue 49): planning, status and reruns at 1k-100k tiny flights.

Tiny flights: simulated short-period records of 2 s at 10 Hz, each loaded and
reduced to its channel means by a one-line user stage (`mean`), no campaign
step: what is measured is the engine, not the numerics. For each size, fresh
processes, the default environment:

- ``plan``: `aeroid.pipeline.plan` alone, in this process (median of 3);
- the cold run as a user types it (``aeroid run CONFIG --quiet --json``, the
  default workers: one per core): wall time, flights per hour, and the peak
  resident memory of the largest process (the run, which plans and collects,
  or one of its workers);
- ``aeroid status CONFIG`` on the finished store (median of ``--repeats``);
- an unchanged rerun (``aeroid run`` again: every result cached, trusted from
  the store's index of verified entries instead of opened);
- the per-task overhead of the engine: (run wall time - time spent in the
  stages) per task, in this process (``workers=0``) and on the local pool.

Targets (issue 49): ``status`` <= 3 s at 100,000 flights; planning, status
and rerun linear in flights. Usage:
``python tests/benchmarks/bench_campaign_scale.py [--sizes 1000 10000 100000] [--repeats 3]``
(``--no-run``: planning, and ``status`` before any run, only).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_PER_ENTRY = 10_000  # a simulated entry holds at most this many flights

TINY = '''\
"""Tiny flights: each reduced to its channel means."""
from dataclasses import dataclass

import numpy as np

from aeroid.pipeline import Pipeline, Stage, Step, register_record, register_stage
from aeroid.pipeline.config import Options


@register_record
@dataclass(frozen=True, eq=False)
class Means:
    names: tuple
    mean: np.ndarray

    def summary(self):
        return "means of " + ", ".join(self.names)


class MeanOptions(Options):
    scale: float = 1.0


def run_mean(ctx):
    data = ctx.inputs["data"]
    return Means(tuple(data.names), ctx.options.scale * data.array(list(data.names)).mean(axis=0))


register_stage(Stage("mean", "1", MeanOptions, "tiny:Means", run_mean, uses_model=False))
pipeline = Pipeline(
    "tiny", flight_steps=(Step("load"), Step("mean", inputs={"data": "load"})), campaign_steps=()
)
'''


def _config(n: int) -> str:
    lines = [
        f"name: tiny_{n}",
        "model: short_period",
        "pipeline: tiny:pipeline",
        "allow_imports: true",
        "seed: 1",
        "store: store",
        "flights:",
    ]
    for i, start in enumerate(range(0, n, _PER_ENTRY)):
        lines += [
            "  - simulated:",
            f"      n_flights: {min(_PER_ENTRY, n - start)}",
            f"      seed: {3 + i}",
            "      duration: 2.0",
            "      sample_rate: 10.0",
        ]
    lines += ["stages:", "  mean: {}", ""]
    return "\n".join(lines)


def _command(args: list[str], cwd: Path) -> tuple[float, str]:
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-m", "aeroid.cli", *args], cwd=cwd, capture_output=True, text=True
    )
    dt = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"{args[0]} failed:\n{out.stderr[-3000:]}")
    return dt, out.stdout


def _plan_seconds(cfg: Path) -> float:
    code = (
        "import sys, time; sys.path.insert(0, sys.argv[2]); from aeroid.pipeline import plan; "
        "t = time.perf_counter(); plan(sys.argv[1]); print(time.perf_counter() - t)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(cfg), str(cfg.parent)],
        capture_output=True,
        text=True,
        check=True,
    )
    return float(out.stdout.strip())


def _overhead(work: Path, n: int) -> None:
    """Per-task engine overhead: (wall - time in the stages) / tasks, in this process and on
    the local pool, on a fresh store each."""
    sys.path.insert(0, str(work))
    from aeroid.pipeline import run

    cfg = work / "overhead.yaml"
    cfg.write_text(_config(n), encoding="utf-8")
    for workers in (0, None):
        store = work / f"overhead-store-{workers}"
        summary = run(cfg, store=store, workers=workers)
        tasks = len(summary.plan.tasks)
        wall, compute = summary.seconds["run"], summary.seconds["compute"]
        cores = 1 if workers == 0 else len(os.sched_getaffinity(0))
        print(
            f"per-task overhead, {'in process' if workers == 0 else f'{cores} workers'}: "
            f"{1e3 * (wall * cores - compute) / tasks:.2f} ms of CPU a task "
            f"({tasks} tasks in {wall:.1f} s, {1e3 * compute / tasks:.2f} ms a task in stages)",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-run", action="store_true", help="measure planning only")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="aeroid-bench-scale-"))
    try:
        (work / "tiny.py").write_text(TINY, encoding="utf-8")
        print(f"cores: {len(os.sched_getaffinity(0))}", flush=True)
        if not args.no_run:
            _overhead(work, 1000)
        for n in args.sizes:
            folder = work / f"n{n}"
            folder.mkdir()
            shutil.copy(work / "tiny.py", folder / "tiny.py")
            cfg = folder / "campaign.yaml"
            cfg.write_text(_config(n), encoding="utf-8")
            plans = [_plan_seconds(cfg) for _ in range(args.repeats)]
            print(f"{n} flights: plan {statistics.median(plans):.2f} s", flush=True)
            if args.no_run:
                status = [_command(["status", str(cfg), "--json"], folder)[0] for _ in plans]
                print(f"{n} flights: status (no store yet) {statistics.median(status):.2f} s")
                continue
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            cold, out = _command(["run", str(cfg), "--quiet", "--json"], folder)
            doc = json.loads(out)
            largest = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            peak = f"{largest / 1024:.0f} MB" if largest > before else "below an earlier run's"
            print(
                f"{n} flights: cold run {cold:.1f} s ({doc['computed']} tasks, "
                f"{doc['failed']} failed; {3600 * n / cold:,.0f} flights/hour); "
                f"largest process {peak}",
                flush=True,
            )
            status = [
                _command(["status", str(cfg), "--json"], folder)[0] for _ in range(args.repeats)
            ]
            print(
                f"{n} flights: status median {statistics.median(status):.2f} s "
                f"(min {min(status):.2f})",
                flush=True,
            )
            rerun, out = _command(["run", str(cfg), "--quiet", "--json"], folder)
            print(
                f"{n} flights: unchanged rerun {rerun:.1f} s "
                f"({json.loads(out)['cached']} cached, {json.loads(out)['computed']} computed)",
                flush=True,
            )
            shutil.rmtree(folder / "store", ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
