"""Benchmark: the campaign stage ``database`` over 100 flights (issue 51, target <= 10 s).

The stage's run on 100 flights' briefs (15 coefficients with full covariances, a
speed term among them with its trim-speed reference, condition keys alpha, altitude
and airspeed), then the files a run writes beside
the report (JSBSim section, Parquet table, one band plot per coefficient). The
first call runs in a fresh process and pays for the imports.

Run: ``python tests/benchmarks/bench_database.py [--flights N] [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

TARGET_S = 10.0

_CHILD = """
import json, statistics, sys, tempfile, time
from pathlib import Path
import numpy as np

n, repeat = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
terms = ["CL_0", "CL_alpha", "CD_0", "Cm_0", "Cm_alpha", "Cm_V", "Cm_q", "Cm_delta_e",
         "CY_beta", "Cl_beta", "Cl_p", "Cl_delta_a", "Cn_beta", "Cn_r", "Cn_delta_r"]
k = len(terms)
ident, data = {}, {}
for i in range(n):
    a, h, v = rng.uniform(0, 0.17), rng.choice([500.0, 1000.0, 1500.0]), rng.uniform(35, 65)
    m = rng.standard_normal((k, k)) * 0.01
    cov = m @ m.T + np.eye(k) * 1e-4
    est = 0.1 * np.arange(1, k + 1) * (1 + a) + np.linalg.cholesky(cov) @ rng.standard_normal(k)
    ident[i] = {"names": terms, "parameters": dict(zip(terms, est.tolist())),
                "covariance": cov.tolist()}
    data[i] = {"alpha": a, "altitude": h, "airspeed": v}

t0 = time.perf_counter()
from aeroid.pipeline.stages.database_stage import DatabaseOptions, _band_plot, _run_database
from aeroid.pipeline.stages import StageContext

flights = tuple(f"flight_{i:03d}" for i in range(n))
ctx = StageContext(options=DatabaseOptions(held_out=[flights[0], flights[1]]), inputs={},
                   flights=flights, briefs={"identification": ident, "data": data})
out = Path(tempfile.mkdtemp())

def stage_and_files():
    db = _run_database(ctx)
    db.to_jsbsim(out / "aero.xml")
    db.to_parquet(out / "db.parquet")
    for t in db.terms:
        (out / f"{t}.png").write_bytes(_band_plot(db, t))
    return db

db = stage_and_files()
first = time.perf_counter() - t0
times = []
for _ in range(repeat):
    t0 = time.perf_counter()
    stage_and_files()
    times.append(time.perf_counter() - t0)
fit = []
for _ in range(repeat):
    t0 = time.perf_counter()
    _run_database(ctx)
    fit.append(time.perf_counter() - t0)
print(json.dumps({"first": first, "warm": statistics.median(times),
                  "fit": statistics.median(fit), "terms": len(db.terms)}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--flights", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(args.flights), str(args.repeat)],
        capture_output=True,
        text=True,
        check=True,
        cwd=root,
    )
    res = json.loads(out.stdout.strip().splitlines()[-1])
    print(
        f"database stage + files, {args.flights} flights, {res['terms']} coefficients: "
        f"first {res['first']:.2f} s, warm {res['warm']:.2f} s (fit alone {res['fit']:.3f} s), "
        f"target {TARGET_S:.0f} s, first/target {res['first'] / TARGET_S:.2f}"
    )


if __name__ == "__main__":
    main()
