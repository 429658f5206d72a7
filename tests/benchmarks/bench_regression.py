"""Benchmark: equation-error and stepwise regression (issue 31), each case in a fresh process.

Every case runs in its own ``python`` subprocess with this process's
environment unchanged (no BLAS pinning, no thread variables set here), so the
first call pays for importing `aeroid.estimation.regression` and its SciPy modules. Each
case prints that first call and the median of several warm calls next to its
target.

Run: ``python tests/benchmarks/bench_regression.py [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

# case: (label, target for the warm median in s)
CASES = {
    "ee_white": ("equation error, 20 regressors, 10 000 samples, white residuals", 0.005),
    "ee_colored": ("equation error, 20 regressors, 10 000 samples, AR(1) 0.9 residuals", 0.005),
    "ee_frequency": ("equation error, frequency domain, 20 regressors, 50 frequencies", 0.005),
    "stepwise": ("stepwise, 20 candidates, 10 000 samples", 0.05),
    # Morelli's real-time estimator: 200 s at 50 Hz, an update each second; a real-time
    # loop needs each update well inside its second: here, 5 % of it
    "rls_frequency": ("recursive, frequency domain, 20 regressors, 199 updates", 10.0),
}

_CHILD = """
import json, statistics, sys, time
import numpy as np

case, repeat = sys.argv[1], int(sys.argv[2])
n, p = 10_000, 20
rng = np.random.default_rng(0)
# smooth regressors (AR(1), correlation time ~ 20 samples), as flight signals are
x = np.empty((n, p))
e = rng.standard_normal((n, p))
x[0] = e[0]
for k in range(1, n):
    x[k] = 0.9 * x[k - 1] + 0.44 * e[k]
theta = np.zeros(p)
theta[:3] = [-0.6, -9.0, -1.1]
noise = 0.05 * rng.standard_normal(n)
if case == "ee_colored":
    for k in range(1, n):
        noise[k] += 0.9 * noise[k - 1]
z = 0.02 + x @ theta + noise
names = [f"x{j}" for j in range(p)]
pool = {nm: x[:, j] for j, nm in enumerate(names)}
freq = np.arange(0.1, 2.1, 0.04)

t0 = time.perf_counter()
import aeroid
if case == "rls_frequency":
    run = lambda: aeroid.recursive_least_squares(
        x, z, names, domain="frequency", frequencies=freq, dt=0.02
    )
elif case.startswith("ee_"):
    kw = {"domain": "frequency", "frequencies": freq, "dt": 0.02} if case == "ee_frequency" else {}
    run = lambda: aeroid.equation_error(x, z, names, **kw)
else:
    run = lambda: aeroid.stepwise_regression(pool, z, pool)
out = run()
first = time.perf_counter() - t0
times = []
for _ in range(repeat):
    t0 = time.perf_counter()
    out = run()
    times.append(time.perf_counter() - t0)
if case == "stepwise":
    extra = list(out.selected)
elif case == "rls_frequency":
    extra = round(out.parameters["x1"], 6)
else:
    extra = round(out.r_squared, 6)
print(json.dumps({"first": first, "warm": statistics.median(times), "best": min(times),
                  "check": extra}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    root = Path(__file__).resolve().parents[2]
    print(
        f"{'case':70s} {'first':>8s} {'warm':>9s} {'best':>9s} {'target':>8s} {'/target':>8s}  check"
    )
    for case, (label, target) in CASES.items():
        proc = subprocess.run(
            [sys.executable, "-c", _CHILD, case, str(args.repeat)],
            capture_output=True,
            text=True,
            check=True,
            cwd=root,
        )
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        print(
            f"{label:70s} {r['first']:8.4f} {r['warm']:9.5f} {r['best']:9.5f} {target:8.3f} "
            f"{r['warm'] / target:8.2f}  {r['check']}"
        )
    print(
        "times in s: the first call in a fresh process (import included), the median of the "
        "warm calls (compared with the target) and the fastest warm call"
    )


if __name__ == "__main__":
    main()
