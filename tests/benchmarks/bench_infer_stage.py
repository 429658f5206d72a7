"""Benchmark: the demo's infer stage, two-halves DE against DE-MCz (issue 47).

    python tests/benchmarks/bench_infer_stage.py [--runs 3]

The demo's infer stage (``configs/demo.yaml``: flight_03, the coupled c172x model,
Cm_q, Cm_delta_e and the noise levels of alpha and q, 8 walkers, started at the
filter-error fit). Its load and identify tasks run once into a temporary store; then,
alternately, fresh processes run the stage's `infer` call with

- ``de``: the two-halves differential evolution, 1900 steps, 150 burn-in (0.11.0's
  demo: two batched simulations of 4 walkers a step);
- ``demcz``: differential evolution from an archive, 1500 steps, 200 burn-in (this
  release's demo: one batched simulation of 8 walkers a step),

each with ``AEROID_JAX_CACHE`` at a new empty folder: the first call is cold (it
compiles the batched simulation, as the cold demo does), a second call in the same
process warm. Printed per setting, medians over the runs: the process CPU time
(user + system, all threads) and wall time of the first and of the warm call, the
warm CPU per step, the longest autocorrelation time, the smallest effective sample
size and whether the stage's convergence check (50 autocorrelation times, split-R-hat
<= 1.05) passed; then the ratios demcz / de.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
SETTINGS = {"de": (1900, 150), "demcz": (1500, 200)}

_CHILD = r"""
import json, sys, time, warnings
from aeroid.pipeline.plans.planning import plan
from aeroid.pipeline.running.execution import _gather
from aeroid.pipeline.stages import library_stages as L
from aeroid.pipeline.stages.work import context_of, stage_of
from aeroid.uncertainty.inference import infer

config, store, move, steps, burn = sys.argv[1:6]
task = next(t for t in plan(config).tasks if t.stage == "infer")
ctx = context_of(task, stage_of(task), _gather(task, store, (), None, None))
kw = {**L._infer_kwargs(ctx), "move": move, "n_steps": int(steps), "burn_in": int(burn)}
model = L._infer_model(ctx)
out = {}
for call in ("first", "warm"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w0, c0 = time.perf_counter(), time.process_time()
        res = infer(model, ctx.inputs["data"], **kw)
        out[call] = (time.perf_counter() - w0, time.process_time() - c0)
out["tau"] = max(res.autocorrelation_time.values())
out["ess"] = min(res.effective_sample_size.values())
out["converged"] = bool(res.converged)
print(json.dumps(out))
"""


def _prepare(store: str) -> str:
    """The demo's load and identify of the infer stage's flight, run into `store`."""
    from aeroid.pipeline.plans.planning import plan
    from aeroid.pipeline.running.execution import execute_task

    config = str(ROOT / "configs" / "demo.yaml")
    tasks = plan(config).tasks
    by_key = {t.key: t for t in tasks}
    infer = next(t for t in tasks if t.stage == "infer")
    need: set[str] = set()
    todo = [infer]
    while todo:
        for ref in todo.pop().upstream.values():
            for key in ref if isinstance(ref, list) else [ref]:
                if key is not None and key not in need:
                    need.add(key)
                    todo.append(by_key[key])
    for t in tasks:  # the plan lists tasks after their inputs
        if t.key in need:
            status = execute_task(t, store)
            if status.status == "failed":
                raise SystemExit(f"{t.stage} failed: {status.get('error')}")
    return config


def _child(config: str, store: str, move: str) -> dict[str, Any]:
    steps, burn = SETTINGS[move]
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PYTHONPATH=str(ROOT), AEROID_JAX_CACHE=cache)
        args = [config, store, move, str(steps), str(burn)]
        done = subprocess.run(
            [sys.executable, "-c", _CHILD, *args],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
    if done.returncode != 0:
        raise SystemExit(done.stderr[-3000:])
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as store:
        config = _prepare(store)
        runs: dict[str, list[dict[str, Any]]] = {m: [] for m in SETTINGS}
        for _ in range(args.runs):  # alternated: both see the same load
            for move in SETTINGS:
                runs[move].append(_child(config, store, move))
    print(f"demo infer stage, {args.runs} fresh process(es) per setting (medians)")
    print("  move    steps  first CPU  first wall  warm CPU  warm wall  ms/step  tau  ESS  ok")
    med: dict[str, dict[str, float]] = {}
    for move, rs in runs.items():
        steps = SETTINGS[move][0]
        m = med[move] = {
            "first_cpu": statistics.median(r["first"][1] for r in rs),
            "first_wall": statistics.median(r["first"][0] for r in rs),
            "warm_cpu": statistics.median(r["warm"][1] for r in rs),
            "warm_wall": statistics.median(r["warm"][0] for r in rs),
            "tau": statistics.median(r["tau"] for r in rs),
            "ess": statistics.median(r["ess"] for r in rs),
        }
        ok = sum(r["converged"] for r in rs)
        print(
            f"  {move:6s} {steps:6d} {m['first_cpu']:8.2f} s {m['first_wall']:8.2f} s "
            f"{m['warm_cpu']:7.2f} s {m['warm_wall']:7.2f} s {1e3 * m['warm_cpu'] / steps:7.2f}"
            f" {m['tau']:5.1f} {m['ess']:4.0f}  {ok}/{len(rs)}"
        )
    a, b = med["demcz"], med["de"]
    print(
        f"  demcz / de: first CPU {a['first_cpu'] / b['first_cpu']:.2f}, warm CPU "
        f"{a['warm_cpu'] / b['warm_cpu']:.2f}, ESS per warm CPU-s "
        f"{(a['ess'] / a['warm_cpu']) / (b['ess'] / b['warm_cpu']):.2f}"
    )


if __name__ == "__main__":
    main()
