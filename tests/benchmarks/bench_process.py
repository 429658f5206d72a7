"""What each piece of the engine's process tuning is worth on the demo run (issue 29).

`aeroid.pipeline.running._process` keeps a piece of tuning only where it is worth more
than 5 % of a demo run. This benchmark runs the demo campaign cold, as a user
types it (``aeroid run configs/demo.yaml`` with a fresh store, the default
environment, a fresh process each time), as shipped and with one piece taken
out at a time:

- ``spawn``: workers spawned instead of forked (they import numpy, scipy and
  aeroid afresh);
- ``blas threads``: the workers keep the BLAS/OpenMP thread pools they would
  have by default, instead of one thread each;

Prints, per variant, the median wall time over ``--repeats`` runs and its
ratio to the shipped run's median (above 1.05: the piece is worth keeping).
Two more pieces were measured here for time: a garbage-collector freeze of the
objects that exist before the workers fork (without it the demo ran 0.99x as
long, on a 2-core VM and on 2 cores of a 16-core machine) and importing the
stages' modules once before the workers fork (without it 0.94x over 5 runs on
the VM: the workers' own imports overlap, the parent's did not). Both are kept
for memory, which ``bench_campaign_1000.py`` measures: forked workers share the
imported modules' pages, and the freeze keeps their garbage collector from
copying the planner's (the 1,000-flight process tree peaked near 330 MB without
it, 300 MB with it).
Usage: ``python tests/benchmarks/bench_process.py [--repeats N] [--config PATH]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Each variant: Python run before the command-line entry point, in the same process.
VARIANTS = {
    "as shipped": "",
    "spawn": "import os; os.environ['AEROID_START_METHOD'] = 'spawn'",
    "blas threads": (
        "import contextlib\n"
        "from aeroid.pipeline import _process\n"
        "_process._BLAS_ENV.clear()\n"
        "_process.blas_pinned = lambda fork: contextlib.nullcontext()\n"
    ),
}

ENTRY = "import sys\nfrom aeroid.cli import main\nsys.argv = {argv!r}\nmain()\n"


def _run(patch: str, config: Path, store: Path) -> tuple[float, int]:
    argv = ["aeroid", "run", str(config), "--store", str(store), "--json", "--quiet"]
    code = patch + "\n" + ENTRY.format(argv=argv)
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=False
    )
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"run failed:\n{r.stderr[-3000:]}")
    return dt, int(json.loads(r.stdout)["computed"])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "demo.yaml")
    parser.add_argument("--only", nargs="*", default=None, help="variants to run")
    args = parser.parse_args()
    chosen = {k: v for k, v in VARIANTS.items() if args.only is None or k in args.only}
    print(f"demo: {args.config}; cores: {len(os.sched_getaffinity(0))}", flush=True)
    times: dict[str, list[float]] = {k: [] for k in chosen}
    work = Path(tempfile.mkdtemp(prefix="aeroid-bench-process-"))
    try:
        # interleaved, so that a change in the machine's load touches every variant alike
        for i in range(args.repeats):
            for name, patch in chosen.items():
                store = work / f"{name.replace(' ', '_')}_{i}"
                dt, computed = _run(patch, args.config, store)
                times[name].append(dt)
                print(f"  {name:16s} run {i}: {dt:6.1f} s ({computed} tasks)", flush=True)
                shutil.rmtree(store, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    base = statistics.median(times["as shipped"]) if "as shipped" in times else float("nan")
    print(f"\n{'variant':16s} {'median s':>9s} {'vs shipped':>11s}")
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"{name:16s} {med:9.1f} {med / base:10.2f}x")


if __name__ == "__main__":
    main()
