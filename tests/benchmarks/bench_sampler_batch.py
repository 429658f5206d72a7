"""Benchmark: the sampler's batched simulation of the demo's infer stage (issue 47).

    python tests/benchmarks/bench_sampler_batch.py [--runs 3] [--calls 300]

The demo's infer stage (``configs/demo.yaml``: flight_03, the coupled c172x model,
outputs alpha and q) scores half an ensemble per sampler call: one
`BatchSimulator.outputs` call, parameters to outputs in one compiled program, the RK4
substeps picked in it by the stiffness rule. Each run is a fresh ``python`` process
with ``AEROID_JAX_CACHE`` pointed at a new empty folder, so its first call compiles.
Printed per batch size (the walkers a call scores): the first call's wall and process
CPU time (tracing and compiling the program, then one call), and the median process
CPU time of a warm call with its ratio to the batch of 4 (the demo's 8 walkers), per
walker: what a sampler with more walkers a call saves. The median over the runs.
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

ROOT = Path(__file__).resolve().parents[2]
BATCHES = (4, 8, 16, 32)

_CHILD = r"""
import json, sys, tempfile, time, warnings
import numpy as np
from aeroid.models.batch_simulator import BatchSimulator
from aeroid.pipeline.plans.planning import plan
from aeroid.pipeline.running.execution import _gather
from aeroid.pipeline.stages.work import context_of, stage_of
from aeroid.pipeline.vehicle import resolve_model

config, calls = sys.argv[1], int(sys.argv[2])
the_plan = plan(config)
load = next(t for t in the_plan.tasks if t.stage == "load" and t.flight == "flight_03")
infer = next(t for t in the_plan.tasks if t.stage == "infer")
store = tempfile.mkdtemp()
ctx = context_of(load, stage_of(load), _gather(load, store, (), None, None))
data = stage_of(load).run(ctx)
model = resolve_model(infer.model_ref["spec"], infer.model_ref.get("base_dir"))
time_ = np.asarray(data.time)
x0 = {s: float(data[s][0]) if s in data.names else 0.0 for s in model.states}
index = [model.output_names.index(o) for o in ("alpha", "q")]
sim = BatchSimulator(model, time_, data, x0, repeated=10**6)
rng = np.random.default_rng(0)
out = {}
for batch in BATCHES:
    def params():
        return {
            "Cm_q": model.parameters["Cm_q"] * (1 + 0.01 * rng.standard_normal(batch)),
            "Cm_delta_e": model.parameters["Cm_delta_e"] * (1 + 0.01 * rng.standard_normal(batch)),
        }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w0, c0 = time.perf_counter(), time.process_time()
        sim.outputs(params(), index)
        first = (time.perf_counter() - w0, time.process_time() - c0)
        ts = []
        for _ in range(calls):
            p = params()
            c0 = time.process_time()
            sim.outputs(p, index)
            ts.append(time.process_time() - c0)
    out[batch] = {"first_wall": first[0], "first_cpu": first[1], "warm_cpu": float(np.median(ts))}
    sim = BatchSimulator(model, time_, data, x0, repeated=10**6)  # no padding to the last
print(json.dumps(out))
""".replace("BATCHES", repr(BATCHES))


def _run(calls: int) -> dict[str, dict[str, float]]:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PYTHONPATH=str(ROOT), AEROID_JAX_CACHE=cache)
        config = str(ROOT / "configs" / "demo.yaml")
        done = subprocess.run(
            [sys.executable, "-c", _CHILD, config, str(calls)],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
    if done.returncode != 0:
        raise SystemExit(done.stderr[-3000:])
    result: dict[str, dict[str, float]] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--calls", type=int, default=300)
    args = ap.parse_args()
    runs = [_run(args.calls) for _ in range(args.runs)]
    print(f"demo infer batches, {args.runs} fresh process(es), {args.calls} warm calls each")
    print("  batch  first wall  first CPU  warm CPU/call  per walker vs batch 4")
    base = None
    for b in BATCHES:
        key = str(b)
        first_wall = statistics.median(r[key]["first_wall"] for r in runs)
        first_cpu = statistics.median(r[key]["first_cpu"] for r in runs)
        warm = statistics.median(r[key]["warm_cpu"] for r in runs)
        base = warm / b if base is None else base
        print(
            f"  {b:5d}  {first_wall:8.2f} s  {first_cpu:7.2f} s  {warm * 1e3:10.2f} ms"
            f"  {warm / b / base:10.2f}"
        )


if __name__ == "__main__":
    main()
