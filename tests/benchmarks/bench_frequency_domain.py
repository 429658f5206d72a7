"""Benchmark: frequency-domain output error and Fourier transform regression (issue 34).

Each case runs in its own ``python`` subprocess with this process's
environment unchanged (no BLAS pinning, no thread variables set here). The
record is simulated before the clock starts; the first call then pays for
importing `aeroid.frequency.frequency_domain` and SciPy's chirp-z transform. Each case
prints that first call and the median of several warm calls next to its
target, and the largest estimate error in standard errors as a check.

Case: the linear lateral-directional model (`aeroid.models.aircraft.lateral_linear`,
states beta, p, r, phi; 12 dimensional derivatives), 30 s at 50 Hz with
measurement noise, starting 20 % off, fitted at the k/T grid from 0.1 to 2 Hz
(57 frequencies).

Run: ``python tests/benchmarks/bench_frequency_domain.py [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

# case: (label, target for the warm median in s)
CASES = {
    "output_error": ("FD output error, lateral linear, 12 parameters, 0.1-2 Hz", 0.2),
    "equation_error": ("FD equation error, lateral linear, 12 parameters, 0.1-2 Hz", 0.2),
}

_CHILD = """
import json, statistics, sys, time
import numpy as np

case, repeat = sys.argv[1], int(sys.argv[2])
from aeroid.models.aircraft import lateral_linear
truth = dict(Y_beta=-0.15, Y_delta_r=0.03, L_beta=-8.0, L_p=-2.5, L_r=0.8, L_delta_a=12.0,
             L_delta_r=1.0, N_beta=3.5, N_p=-0.1, N_r=-0.4, N_delta_a=-0.3, N_delta_r=-2.5)
model = lateral_linear(V0=60.0, parameters=truth)
dt = 0.02
t = np.arange(0.0, 30.0 + dt / 2, dt)
rng = np.random.default_rng(2)
ua, ur = np.zeros_like(t), np.zeros_like(t)
for i, f in enumerate(np.arange(0.1, 2.2, 0.05)):
    s = 0.005 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    if i % 2:
        ua += s
    else:
        ur += s
window = np.sin(np.pi * t / t[-1]) ** 2
sim = model.simulate(t, {"delta_a": ua * window, "delta_r": ur * window}, method="exact")
noise = {"beta": 0.001, "p": 0.003, "r": 0.002, "phi": 0.003}
if case == "equation_error":
    noise = {k: v / 10 for k, v in noise.items()}  # measured states: keep them clean
data = sim.to_flight_data(noise=noise, seed=1)
start = {k: 1.2 * v for k, v in truth.items()}

t0 = time.perf_counter()
import aeroid
run = lambda: aeroid.identify_frequency_domain(model, data, start, method=case)
out = run()
first = time.perf_counter() - t0
times = []
for _ in range(repeat):
    t0 = time.perf_counter()
    out = run()
    times.append(time.perf_counter() - t0)
z = max(abs(out.parameters[k] - v) / out.stderr[k] for k, v in truth.items())
print(json.dumps({"first": first, "warm": statistics.median(times), "best": min(times),
                  "check": f"max |error|/se = {z:.2f}, {out.n_iterations} iterations"}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()
    root = Path(__file__).resolve().parents[2]
    print(
        f"{'case':62s} {'first':>8s} {'warm':>9s} {'best':>9s} {'target':>8s} {'/target':>8s}  check"
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
            f"{label:62s} {r['first']:8.4f} {r['warm']:9.5f} {r['best']:9.5f} {target:8.3f} "
            f"{r['warm'] / target:8.2f}  {r['check']}"
        )
    print(
        "times in s: the first call in a fresh process (import included), the median of the "
        "warm calls (compared with the target) and the fastest warm call"
    )


if __name__ == "__main__":
    main()
