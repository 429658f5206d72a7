"""A 1,000-flight identify + validate campaign (issue 29): time, memory, status.

The short-period model, 1,000 simulated flights of 10 s at 50 Hz, each loaded,
identified, validated and reported, then one campaign report without figures.
Fresh processes, the default environment, the default workers (one per core):

- the cold run as a user types it (``aeroid run CONFIG --quiet --json``):
  wall time, the peak resident memory of the largest process (the run or one
  of its workers) and the peak of the whole process tree's resident memory,
  sampled every 0.1 s (an upper bound: pages the forked workers share with
  the run are counted in each);
- ``aeroid status CONFIG`` on the finished store, median of ``--repeats`` (and,
  where the environment sets ``PYTHONDONTWRITEBYTECODE``, again without it:
  then every process compiles the package's sources, which a default
  environment does once);
- an unchanged rerun.

Targets: cold <= 45 s, <= 300 MB, status <= 1 s.
Usage: ``python tests/benchmarks/bench_campaign_1000.py [--flights N] [--repeats N]``.
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
import threading
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[2]

CONFIG = """\
name: campaign_{n}
model: short_period
pipeline: campaign
seed: 1
store: store
report: out/campaign.md
flights:
  - simulated:
      generator: short_period_campaign
      n_flights: {n}
      seed: 3
      maneuver: doublet
      duration: 10.0
      sample_rate: 50.0
stages:
  identify: {{parameters: [Z_alpha, M_alpha, M_q, M_delta]}}
  validate: {{}}
  campaign_report: {{figures: false, include_flight_reports: false}}
"""


def _tree_rss(root: psutil.Process) -> int:
    total = 0
    for p in [root, *root.children(recursive=True)]:
        try:
            total += p.memory_full_info().pss
        except psutil.Error:
            pass
    return total


def _command(
    args: list[str], cwd: Path, env: dict[str, str] | None = None
) -> tuple[float, int, str]:
    """Wall time, sampled peak tree RSS and stdout of one CLI command in a fresh process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "aeroid.cli", *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    peak = 0
    done = threading.Event()

    def sample() -> None:
        nonlocal peak
        root = psutil.Process(proc.pid)
        while not done.is_set():
            try:
                peak = max(peak, _tree_rss(root))
            except psutil.Error:
                return
            time.sleep(0.2)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    out, err = proc.communicate()
    dt = time.perf_counter() - t0
    done.set()
    sampler.join()
    if proc.returncode != 0:
        raise SystemExit(f"{args[0]} failed:\n{err[-3000:]}")
    return dt, peak, out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--flights", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="aeroid-bench-1000-"))
    try:
        cfg = work / "campaign.yaml"
        cfg.write_text(CONFIG.format(n=args.flights), encoding="utf-8")
        print(f"{args.flights} flights; cores: {len(os.sched_getaffinity(0))}", flush=True)
        cold, tree_peak, out = _command(["run", str(cfg), "--quiet", "--json"], work)
        doc = json.loads(out)
        largest = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        print(
            f"cold run: {cold:.1f} s ({doc['computed']} tasks, {doc['failed']} failed); "
            f"largest process {largest:.0f} MB, process tree {tree_peak / 2**20:.0f} MB "
            "PSS (target <= 45 s, <= 300 MB)",
            flush=True,
        )
        times = [_command(["status", str(cfg)], work)[0] for _ in range(args.repeats)]
        print(
            f"status: median {statistics.median(times):.2f} s of {args.repeats} "
            f"(min {min(times):.2f}, max {max(times):.2f}; target <= 1 s)"
        )
        if os.environ.get("PYTHONDONTWRITEBYTECODE"):
            # This environment never caches bytecode, so every process compiles the
            # package's sources; a user's default environment caches it once.
            cached = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
            times = [_command(["status", str(cfg)], work, cached)[0] for _ in range(args.repeats)]
            print(
                f"status, bytecode cached (PYTHONDONTWRITEBYTECODE unset): median "
                f"{statistics.median(times[1:] or times):.2f} s (the first call writes it)"
            )
        rerun, _, out = _command(["run", str(cfg), "--quiet", "--json"], work)
        print(f"unchanged rerun: {rerun:.1f} s ({json.loads(out)['computed']} computed)")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
