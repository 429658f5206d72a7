"""The demo campaign end to end (run by hand): ``python tests/benchmarks/bench_demo.py``.

Issue 47's target: the demo (``configs/demo.yaml``) cold at most 1.5 s a flight on
2 cores. Each run is ``python -m aeroid.cli run`` in a fresh process, as a user types
it: cold on an empty store and an empty compilation cache (the issue's "empty
caches"), then warm (an unchanged rerun on the stored results), then cold again on an
empty store with the first run's compiled programs kept on disk (``cold*``: what a
campaign run after an earlier one on the same machine pays).
Reported per run: wall time, the CPU time of the run and its workers (user + system:
on a shared machine the wall time follows the other load, the CPU time much less),
both per flight; and, from the store, the compute time of each stage summed over its
tasks, with the longest single task.

Options: ``--repeats N`` (default 1; the median is reported), ``--workers N``
(default: the run's own, one per core), ``--keep DIR`` (the store and report stay
there to look at), ``--cold-only`` (the cold runs alone), ``--tail`` (each cold run's
end: what ran after the last flight's identify, on which worker, when, with its CPU;
what the run waits on once its flights are done. Timed in the worker processes the
run forks, on Linux).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the checkout's aeroid, here and in the runs
TARGET = 1.5  # s a flight, cold, on 2 cores


def _config(folder: Path) -> Path:
    """The demo's config copied into `folder`, its store and report inside it."""
    shutil.copytree(ROOT / "configs", folder / "configs")
    path = folder / "configs" / "demo.yaml"
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"(?m)^store: .*$", f"store: {folder / 'store'}", text)
    text = re.sub(r"(?m)^report: .*$", f"report: {folder / 'report' / 'demo.md'}", text)
    path.write_text(text, encoding="utf-8")
    return path


# `aeroid run` with each task, part and the report's files timed into the file
# $AEROID_BENCH_TAIL (a JSON line each: process, what, start, end, CPU), for `--tail`
_TIMED = """
import json, os, resource, sys, time
from aeroid.pipeline.running import execution, runner

def cpu():
    me, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime

def timed(fn, what):
    def call(*args, **kwargs):
        t0, c0 = time.time(), cpu()
        out = fn(*args, **kwargs)
        line = dict(pid=os.getpid(), what=what(args), t0=t0, t1=time.time(), cpu=cpu() - c0)
        with open(os.environ["AEROID_BENCH_TAIL"], "a") as f:
            f.write(json.dumps(line) + "\\n")
        return out
    # pickled by name into the forked workers, which find this one under it
    call.__module__, call.__qualname__ = fn.__module__, fn.__qualname__
    return call

execution.execute_task = timed(execution.execute_task, lambda a: f"{a[0].step} {a[0].flight}")
execution.execute_part = timed(execution.execute_part, lambda a: f"{a[0].step} part {a[2]}")
runner.write_run_outputs = timed(runner.write_run_outputs, lambda a: "the report's files")
from aeroid.cli import main
main()
"""


def _run(
    config: Path, workers: int | None, jax_cache: Path, tail: Path | None = None
) -> tuple[float, float, str]:
    """One `aeroid run` in a fresh process, JAX's compiled programs kept in `jax_cache`
    (its tasks timed into `tail`, where given): (wall s, CPU s of it and its workers,
    stdout)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), AEROID_JAX_CACHE=str(jax_cache))
    cmd = [sys.executable, "-m", "aeroid.cli", "run", str(config)]
    if tail is not None:
        env["AEROID_BENCH_TAIL"] = str(tail)
        cmd[1:3] = ["-c", _TIMED]
    if workers is not None:
        cmd += ["--workers", str(workers)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # run from the config's folder: ``-m`` puts the working directory first on the path,
    # and run from another checkout it would import that checkout's aeroid
    done = subprocess.run(
        cmd, env=env, cwd=config.parent, capture_output=True, text=True, check=False
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"aeroid run failed ({done.returncode}):\n{done.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, done.stdout


def _print_tail(tail: Path) -> None:
    """What ran after the last flight's identify (`--tail`): per line the process (w0 the
    run's own), start and end in s after that identify, and CPU s."""
    rows = [json.loads(line) for line in tail.read_text().splitlines()]
    last = max((r["t1"] for r in rows if r["what"].startswith("identify ")), default=None)
    if last is None:
        return
    end = max(r["t1"] for r in rows)
    own = {r["pid"] for r in rows if r["what"] == "the report's files"}
    workers = dict.fromkeys(r["pid"] for r in rows if r["pid"] not in own)
    procs = {**{pid: i + 1 for i, pid in enumerate(workers)}, **dict.fromkeys(own, 0)}
    print(f"  after the last identify: {end - last:.2f} s to the end of the run")
    for r in sorted(rows, key=lambda r: r["t0"]):
        if r["t1"] > last:
            print(
                f"    w{procs[r['pid']]} {r['t0'] - last:+6.2f} {r['t1'] - last:+6.2f} s "
                f"CPU {r['cpu']:5.2f} s  {r['what']}"
            )


def _stage_times(config: Path) -> dict[str, tuple[int, float, float, float]]:
    """Per stage: (tasks, compute s summed, longest task s, CPU s summed), from the stored
    provenance (the CPU of the worker processes, every thread, while the stage ran)."""
    from aeroid.cli import _open_store
    from aeroid.pipeline.plans.planning import plan

    the_plan = plan(config)
    store = _open_store(str(config), None)
    out: dict[str, list[float]] = defaultdict(list)
    cpu: dict[str, float] = defaultdict(float)
    for task in the_plan.tasks:
        meta = store.metadata(task.key, task.stage)
        seconds = meta.get("provenance", {}).get("seconds", {})
        out[task.stage].append(float(seconds.get("compute", 0.0)))
        cpu[task.stage] += float(seconds.get("cpu", float("nan")))
    return {k: (len(v), sum(v), max(v), cpu[k]) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--cold-only", action="store_true", help="skip the warm and cold* runs")
    ap.add_argument("--tail", action="store_true", help="show what each cold run ends with")
    args = ap.parse_args()
    n_flights = 0
    cold: list[tuple[float, float]] = []
    kept: list[tuple[float, float]] = []
    warm: list[tuple[float, float]] = []
    stages: list[dict[str, Any]] = []
    for i in range(args.repeats):
        folder = Path(tempfile.mkdtemp(prefix="aeroid-bench-demo-"))
        try:
            config = _config(folder)
            n_flights = sum(
                1 for ln in config.read_text().splitlines() if ln.strip().startswith("- path:")
            )
            jax_cache = folder / "jax"  # empty: nothing compiled by an earlier run
            tail = folder / "tail.jsonl" if args.tail else None
            wall, cpu, _ = _run(config, args.workers, jax_cache, tail)
            cold.append((wall, cpu))
            # the programs the run compiled and kept (those over a fifth of a second)
            kept_programs = sorted(p.name.split("-")[0] for p in jax_cache.glob("*-cache"))
            print(
                f"cold run {i + 1}: {wall:.1f} s wall, {cpu:.1f} s CPU; programs kept on "
                f"disk: {len(kept_programs)} ({', '.join(kept_programs)})",
                flush=True,
            )
            stages.append(_stage_times(config))
            if tail is not None:
                _print_tail(tail)
            if args.cold_only:
                if args.keep is not None and i == args.repeats - 1:
                    shutil.rmtree(args.keep, ignore_errors=True)
                    shutil.copytree(folder, args.keep)
                continue
            wall, cpu, out = _run(config, args.workers, jax_cache)
            warm.append((wall, cpu))
            if not re.search(r"(?<!\d)0 computed", out):
                print("warning: the warm run computed something:", out.strip().splitlines()[-3:])
            # an empty store again, the compiled programs of the first run kept on disk
            shutil.rmtree(folder / "store")
            wall, cpu, _ = _run(config, args.workers, jax_cache)
            kept.append((wall, cpu))
            if args.keep is not None and i == args.repeats - 1:
                shutil.rmtree(args.keep, ignore_errors=True)
                shutil.copytree(folder, args.keep)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    print(f"demo campaign, {n_flights} flights, {os.cpu_count()} cores, {args.repeats} run(s)")
    for label, runs in (("cold", cold), ("cold*", kept), ("warm", warm)):
        if not runs:
            continue
        wall = statistics.median(w for w, _ in runs)
        cpu = statistics.median(c for _, c in runs)
        print(
            f"  {label}: {wall:6.1f} s wall = {wall / n_flights:5.2f} s a flight "
            f"(CPU {cpu:6.1f} s = {cpu / n_flights:5.2f} s a flight)"
            + (f"; target <= {TARGET} s a flight" if label == "cold" else "")
        )
    print("  (cold: empty store and compilation cache; cold*: empty store, compiled programs kept)")
    print("  compute time by stage (cold runs' medians): tasks, sum, longest task, CPU sum")
    median = {
        name: tuple(statistics.median(run[name][k] for run in stages) for k in range(4))
        for name in stages[-1]
    }
    for stage, (n, total, longest, cpu) in sorted(median.items(), key=lambda kv: -kv[1][3]):
        print(f"    {stage:18s} {n:3.0f} {total:7.2f} s {longest:6.2f} s {cpu:7.2f} s CPU")
    outside = statistics.median(
        c - sum(v[3] for v in run.values()) for (_, c), run in zip(cold, stages, strict=True)
    )
    print(f"    outside the stages (start-up, imports, store, scheduler): {outside:7.2f} s CPU")
    per = {
        "cold_s_per_flight": statistics.median(w for w, _ in cold) / n_flights,
        "cold_cpu_s_per_flight": statistics.median(c for _, c in cold) / n_flights,
    }
    if kept:
        per["cold_kept_programs_s_per_flight"] = statistics.median(w for w, _ in kept) / n_flights
    print(json.dumps(per))


if __name__ == "__main__":
    main()
