"""Speed of the data-compatibility analysis (issue 31, part 1).

Case: 60 s at 50 Hz of the simulated flight of the tests, 12 sensor parameters
(the six gyro and accelerometer biases, offsets of V, alpha and beta, scale
factors of V, alpha and beta) with the seven initial states. Target <= 0.3 s.
A second line adds a time shift on alpha (a re-interpolating second pass).

Run as a script in a fresh process: ``python tests/benchmarks/bench_compatibility.py
[--repeat N] [--numpy]``. ``--numpy`` switches the compiled simulation off (when
`aeroid.models.compiled` exists). Reports the first call (imports, and any
compilation) and the median of `--repeat` warm calls.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from _timing import timed

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the simulated flight

from _compat_flight import BIASES, simulated_flight

import aeroid

ERRORS = {**BIASES, "k_V": 0.02, "k_alpha": 0.08, "k_beta": -0.05}
TARGET = 0.3


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--numpy", action="store_true")
    args = parser.parse_args()
    if args.numpy:
        try:
            from aeroid.models import compiled as _compiled

            _compiled.ENABLED = False
        except ImportError:
            pass
    cases = {
        "12 sensor parameters": (dict(ERRORS), list(ERRORS)),
        "12 + tau_alpha": ({**ERRORS, "tau_alpha": 0.05}, [*ERRORS, "tau_alpha"]),
    }
    for label, (errors, names) in cases.items():
        data = simulated_flight(60.0, 50.0, errors=errors, seed=0)

        def run(data: aeroid.FlightData = data, names: list[str] = names) -> object:
            return aeroid.check_compatibility(data, estimate=names)

        t0 = time.perf_counter()
        run()
        first = time.perf_counter() - t0
        warm, r = timed(run, args.repeat)
        z = max(abs(r.parameters[n] - errors[n]) / r.stderr[n] for n in names)  # type: ignore[attr-defined]
        print(
            f"compatibility, 60 s at 50 Hz, {label}: first call {first:.2f} s, warm median "
            f"{warm:.3f} s (target {TARGET} s); {r.n_passes} pass(es), "  # type: ignore[attr-defined]
            f"largest |error|/sigma {z:.2f}"
        )


if __name__ == "__main__":
    main()
