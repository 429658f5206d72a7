"""Benchmark: CIFER-style composite frequency response and transfer-function fit (issue 34).

Every case runs in its own ``python`` subprocess with this process's
environment unchanged (no BLAS pinning, no thread variables set here), so the
first call pays for importing `aeroid.frequency.frequency_id` and its SciPy modules. Each
case prints that first call and the median of several warm calls next to its
target.

* composite: 60 s at 100 Hz, one input and one output, windows 20/10/5 s
  (80 % overlap), 100 log-spaced frequencies;
* tf_fit: a second-order transfer function with delay fitted to that response
  (CIFER weighting, 0.5-15 rad/s).

Run: ``python tests/benchmarks/bench_frequency_id.py [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

# case: (label, target for the warm median in s)
CASES = {
    "composite": ("composite response, 3 windows, 100 frequencies, 60 s at 100 Hz", 0.050),
    "tf_fit": ("transfer-function fit, 2nd order + delay, ~80 frequencies", 0.020),
}

_CHILD = """
import json, statistics, sys, time
import numpy as np
import scipy.signal

case, repeat = sys.argv[1], int(sys.argv[2])
fs = 100.0
t = np.arange(6001) / fs
w0, w1 = 0.3, 25.0
u = np.sin(w0 * 60.0 / np.log(w1 / w0) * (np.exp(np.log(w1 / w0) * t / 60.0) - 1.0))
b, a = scipy.signal.bilinear([32.0], [1.0, 4.0, 16.0], fs)
y = scipy.signal.lfilter(b, a, u)
y = np.concatenate([np.zeros(5), y[:-5]]) + 0.05 * np.random.default_rng(0).standard_normal(t.size)

t0 = time.perf_counter()
import aeroid
data = aeroid.FlightData(t, {"u": u, "y": y})
if case == "composite":
    run = lambda: aeroid.composite_response(data, "u", "y", windows=(20.0, 10.0, 5.0))
else:
    response = aeroid.composite_response(data, "u", "y", windows=(20.0, 10.0, 5.0))
    t0 = time.perf_counter()
    run = lambda: aeroid.fit_transfer_function(
        response, numerator_order=0, denominator_order=2, frequency_range=(0.5, 15.0)
    )
out = run()
first = time.perf_counter() - t0
times = []
for _ in range(repeat):
    t0 = time.perf_counter()
    out = run()
    times.append(time.perf_counter() - t0)
if case == "composite":
    check = round(float(np.median(out.channels[0].coherence)), 4)
else:
    check = {k: round(v, 4) for k, v in out.parameters.items()}
print(json.dumps({"first": first, "warm": statistics.median(times), "best": min(times),
                  "check": check}))
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
        "times in s: the first call in a fresh process (import included; for the fit, "
        "the first fit after the response), the median of the warm calls (compared with "
        "the target) and the fastest warm call"
    )


if __name__ == "__main__":
    main()
