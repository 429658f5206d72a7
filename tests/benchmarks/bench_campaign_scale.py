"""Campaigns at scale (issue 49): planning, status and reruns at 1k-100k tiny flights.

Tiny flights: simulated short-period records of 2 s at 10 Hz, each loaded and
reduced to its channel means by a one-line user stage (`mean`), no campaign
step: what is measured is the engine, not the numerics. For each size, fresh
processes, the default environment:

- ``plan``: `aeroid.pipeline.plan` alone, in a fresh process (median of
  ``--repeats``), and the peak resident memory of that process: a whole plan,
  and a plan streamed a flight at a time (`plan_stream`, each task counted and
  let go, as ``aeroid status`` does);
- the cold run as a user types it (``aeroid run CONFIG --quiet --json``, the
  default workers: one per core): wall time, flights per hour, and the peak
  resident memory of the largest process (the run, which plans and collects,
  or one of its workers);
- ``aeroid status CONFIG`` on the finished store (median of ``--repeats``),
  reading the plan the run stored (`plan_cache`), and planning (its stored
  plans removed before each call: what every call cost before plans were
  stored);
- an unchanged rerun (``aeroid run`` again: every result cached, trusted from
  the store's index of verified entries instead of opened);
- the per-task overhead of the engine: (run wall time - time spent in the
  stages) per task, in this process (``workers=0``) and on the local pool.

Targets (issue 49): ``status`` <= 3 s at 100,000 flights; planning, status
and rerun linear in flights. Usage:
``python tests/benchmarks/bench_campaign_scale.py [--sizes 1000 10000 100000] [--repeats 3]``
(``--no-run``: planning, ``status`` before any run, and ``status`` on a store
whose entries are empty placeholder files, which is all ``status`` looks at:
their names; ``--collect``: the peak memory of the process that plans and
collects a cold run and an unchanged rerun, and its bytes a flight).
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
from aeroid.pipeline.plans.config import Options


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
    dt, _, out = _timed(args, cwd)
    return dt, out


def _timed(args: list[str], cwd: Path) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds of the command's processes, stdout) of ``aeroid ARGS``;
    the CPU time is what a loaded machine does not inflate."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-m", "aeroid.cli", *args], cwd=cwd, capture_output=True, text=True
    )
    dt = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise SystemExit(f"{args[0]} failed:\n{out.stderr[-3000:]}")
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return dt, cpu, out.stdout


_PLANNING = """\
import resource, sys, time
sys.path.insert(0, sys.argv[2])
from aeroid.pipeline import plan
from aeroid.pipeline.plans.planning import plan_stream
t = time.perf_counter()
if sys.argv[3] == "plan":
    plan(sys.argv[1])
else:
    sum(1 for _ in plan_stream(sys.argv[1]))
seconds = time.perf_counter() - t
try:  # this process's own peak: ru_maxrss may carry the parent's over its fork and exec
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
except (OSError, StopIteration):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(seconds, peak)
"""


def _planning(cfg: Path, how: str) -> tuple[float, float]:
    """(seconds, peak resident MB) of planning `cfg` in a fresh process: a whole plan
    (``how="plan"``) or a stream whose tasks are counted and let go (``"stream"``)."""
    out = subprocess.run(
        [sys.executable, "-c", _PLANNING, str(cfg), str(cfg.parent), how],
        capture_output=True,
        text=True,
        check=True,
    )
    seconds, peak = out.stdout.split()
    return float(seconds), int(peak) / 1024


_COLLECTING = """\
import json, sys, time
sys.path.insert(0, sys.argv[2])
from aeroid.pipeline import run


def rss(field):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith(field + ":"))


before = rss("VmRSS")
t, c = time.perf_counter(), time.process_time()
s = run(sys.argv[1], store=sys.argv[3])
doc = {"seconds": time.perf_counter() - t, "cpu": time.process_time() - c,
       "peak_kb": rss("VmHWM"), "before_kb": before, "computed": s.count("computed"),
       "cached": s.count("cached"), "failed": s.failed}
print(json.dumps(doc))
"""


def _collecting(cfg: Path, store: Path) -> dict[str, float]:
    """A run of `cfg` in a fresh process (default workers): its wall and CPU seconds and
    the peak resident memory of that process, the one that plans and collects (its
    workers are other processes), with what it held before the run (imports)."""
    out = subprocess.run(
        [sys.executable, "-c", _COLLECTING, str(cfg), str(cfg.parent), str(store)],
        capture_output=True,
        text=True,
    )
    if out.returncode != 0:
        raise SystemExit(f"run failed:\n{out.stderr[-3000:]}")
    doc: dict[str, float] = json.loads(out.stdout.splitlines()[-1])
    return doc


def _collect_sizes(work: Path, sizes: list[int]) -> None:
    """``--collect``: per size, a cold run and an unchanged rerun, each in a fresh process:
    the peak memory of the process that plans and collects, and bytes a flight (the
    growth between the smallest and each larger size, over the flights added)."""
    first: tuple[int, float] | None = None
    for n in sizes:
        folder = work / f"c{n}"
        folder.mkdir()
        shutil.copy(work / "tiny.py", folder / "tiny.py")
        cfg = folder / "campaign.yaml"
        cfg.write_text(_config(n), encoding="utf-8")
        for what in ("cold run", "unchanged rerun"):
            doc = _collecting(cfg, folder / "store")
            peak = doc["peak_kb"] * 1024
            slope = ""
            if what == "cold run":
                if first is None:
                    first = (n, peak)
                elif n > first[0]:
                    slope = f", {(peak - first[1]) / (n - first[0]):,.0f} bytes a flight beyond {first[0]:,}"
            print(
                f"{n} flights, {what}: {doc['seconds']:.1f} s (its own CPU {doc['cpu']:.1f} s; "
                f"{doc['computed']:.0f} computed, {doc['cached']:.0f} cached, "
                f"{doc['failed']:.0f} failed); planning/collecting process peak "
                f"{peak / 2**20:.0f} MB ({doc['before_kb'] / 1024:.0f} MB before the run){slope}",
                flush=True,
            )
        shutil.rmtree(folder, ignore_errors=True)


def _statuses(cfg: Path, folder: Path, repeats: int) -> str:
    """``aeroid status`` reading the stored plan, and planning (stored plans removed)."""
    planned, stored = [], []
    for _ in range(repeats):
        shutil.rmtree(folder / "store" / ".plans", ignore_errors=True)
        planned.append(_timed(["status", str(cfg), "--json"], folder)[:2])
    for _ in range(repeats):
        stored.append(_timed(["status", str(cfg), "--json"], folder)[:2])

    def shown(times: list[tuple[float, float]]) -> str:
        wall, cpu = (statistics.median(t[i] for t in times) for i in (0, 1))
        return f"{wall:.2f} s (CPU {cpu:.2f} s)"

    return f"status {shown(stored)} reading the stored plan, {shown(planned)} planning"


_PLACEHOLDERS = """\
import os, sys
sys.path.insert(0, sys.argv[2])
from aeroid.pipeline import open_store, plan
p = plan(sys.argv[1])
open_store(p.config.store_location, create=True)
for t in p.tasks:
    folder = os.path.join(p.config.store_location, t.stage)
    os.makedirs(folder, exist_ok=True)
    open(os.path.join(folder, t.key + ".zarr.zip"), "wb").close()
"""


def _placeholder_store(cfg: Path) -> None:
    """A store holding every task of `cfg` as an empty file (what `status` sees)."""
    subprocess.run(
        [sys.executable, "-c", _PLACEHOLDERS, str(cfg), str(cfg.parent)],
        check=True,
        capture_output=True,
    )


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
    parser.add_argument(
        "--collect",
        action="store_true",
        help="measure the memory of the process that plans and collects a run only",
    )
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="aeroid-bench-scale-"))
    try:
        (work / "tiny.py").write_text(TINY, encoding="utf-8")
        print(f"cores: {len(os.sched_getaffinity(0))}", flush=True)
        if args.collect:
            _collect_sizes(work, args.sizes)
            return
        if not args.no_run:
            _overhead(work, 1000)
        for n in args.sizes:
            folder = work / f"n{n}"
            folder.mkdir()
            shutil.copy(work / "tiny.py", folder / "tiny.py")
            cfg = folder / "campaign.yaml"
            cfg.write_text(_config(n), encoding="utf-8")
            plans = [_planning(cfg, "plan") for _ in range(args.repeats)]
            streamed = _planning(cfg, "stream")
            print(
                f"{n} flights: plan {statistics.median(p[0] for p in plans):.2f} s, peak "
                f"{max(p[1] for p in plans):.0f} MB; streamed {streamed[0]:.2f} s, peak "
                f"{streamed[1]:.0f} MB",
                flush=True,
            )
            if args.no_run:
                status = [_command(["status", str(cfg), "--json"], folder)[0] for _ in plans]
                print(f"{n} flights: status (no store yet) {statistics.median(status):.2f} s")
                _placeholder_store(cfg)
                print(f"{n} flights: placeholder store: {_statuses(cfg, folder, args.repeats)}")
                shutil.rmtree(folder / "store", ignore_errors=True)
                continue
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            cold, cpu, out = _timed(["run", str(cfg), "--quiet", "--json"], folder)
            doc = json.loads(out)
            largest = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            peak = f"{largest / 1024:.0f} MB" if largest > before else "below an earlier run's"
            print(
                f"{n} flights: cold run {cold:.1f} s ({doc['computed']} tasks, "
                f"{doc['failed']} failed; {3600 * n / cold:,.0f} flights/hour; CPU {cpu:.0f} s, "
                f"{1e3 * cpu / n:.1f} ms a flight); "
                f"largest process {peak}",
                flush=True,
            )
            print(f"{n} flights: {_statuses(cfg, folder, args.repeats)}", flush=True)
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
