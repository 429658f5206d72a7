"""Benchmark: the workflow before output error, then output error, on a JSBSim demo flight.

    python tests/benchmarks/bench_chain.py [--repeat N]

The flight is ``configs/c172x/flight_03.csv`` (the c172x at 50 m/s, 1000 m;
an aileron doublet, a rudder doublet, a 3-2-1-1 on the elevator, light
turbulence and sensor noise, 20 s at 50 Hz). The chain, as a user runs it:

1. ``check_compatibility``: gyro and accelerometer biases, air-data offsets
   and scale factors, over the whole record;
2. ``coefficients_from_data`` on the corrected record, then
   ``stepwise_regression`` of ``Cm`` and ``CL`` over a pool of eight
   candidates (α, q c̄/2V, δe, α², α·δe, V/V0 - 1, q·α, δe²) on the
   elevator window;
3. ``identify`` of `aircraft.longitudinal` on that window, from start
   values taken from the regressions (``CD`` from its own least squares).

Target (issue 31): the whole chain <= 1 s. A fresh process with the default
environment (no BLAS pinning); the first chain (imports and compilation
included) and the median of the warm chains are printed, stage by stage, with
the identified ``Cm_alpha`` beside JSBSim's.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))  # the demo's model, shared with the physics check

from _c172x_model import longitudinal  # noqa: E402

FLIGHT = ROOT / "configs" / "c172x" / "flight_03.csv"
V0, ALTITUDE = 50.0, 1000.0
WINDOW = (9.5, 20.0)
TARGET = 1.0


def _candidates(d: Any, cbar: float) -> dict[str, np.ndarray]:
    a, q, de, V = d["alpha"], d["q"], d["delta_e"], d["V"]
    qhat = q * cbar / (2.0 * V)
    return {
        "alpha": a,
        "q": qhat,
        "delta_e": de,
        "alpha2": a * a,
        "alpha_delta_e": a * de,
        "V": V / V0 - 1.0,
        "q_alpha": qhat * a,
        "delta_e2": de * de,
    }


def chain(constants: Any) -> tuple[dict[str, float], Any]:
    import aeroid

    stages: dict[str, float] = {}
    t0 = time.perf_counter()
    data = aeroid.load_flight_test(FLIGHT)
    compat = aeroid.check_compatibility(data)
    t1 = time.perf_counter()
    stages["compatibility"] = t1 - t0
    coeffs = aeroid.coefficients_from_data(compat.corrected, constants, thrust="thrust")
    w = coeffs.window(*WINDOW)
    pool = _candidates(w, constants.cbar)
    start: dict[str, float] = {}
    for name in ("Cm", "CL"):
        sw = aeroid.stepwise_regression(w, name, pool)
        start[f"{name}_0"] = float(sw.regression.parameters.get("const", 0.0))
        for term in ("alpha", "q", "delta_e"):
            start[f"{name}_{term}"] = float(sw.regression.parameters.get(term, 0.0))
    cd = aeroid.equation_error(w, "CD", {"alpha": pool["alpha"]})
    start["CD_0"] = float(cd.parameters["const"])
    start["CD_alpha"] = float(cd.parameters["alpha"])
    t2 = time.perf_counter()
    stages["coefficients + stepwise"] = t2 - t1
    model = longitudinal(constants, V0)
    window = compat.corrected.window(*WINDOW)
    fit = aeroid.identify(model, window, start, estimate_x0=True)
    stages["output error"] = time.perf_counter() - t2
    stages["chain"] = time.perf_counter() - t0
    return stages, fit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    t0 = time.perf_counter()
    from aeroid.adapters.jsbsim_flights import FlightCondition, c172x_constants

    constants = c172x_constants(ALTITUDE)
    setup = time.perf_counter() - t0
    first, fit = chain(constants)
    runs = [chain(constants)[0] for _ in range(args.repeat)]
    warm = {k: statistics.median(r[k] for r in runs) for k in first}
    print(f"JSBSim demo flight {FLIGHT.name}: compatibility -> stepwise -> output error")
    print(f"  (import aeroid and the c172x constants: {setup:.2f} s, not counted)")
    print(f"  {'stage':28s} {'first':>8s} {'warm':>8s}")
    for k in first:
        print(f"  {k:28s} {first[k]:8.3f} {warm[k]:8.3f}")
    print(f"  chain warm / target {warm['chain'] / TARGET:.2f}  (target <= {TARGET} s)")
    from aeroid.adapters.jsbsim_flights import effective_derivatives

    eff = effective_derivatives(FlightCondition(V0, ALTITUDE))
    print(
        f"  Cm_alpha {fit.parameters['Cm_alpha']:.3f} +- {fit.stderr['Cm_alpha']:.3f} "
        f"(JSBSim {eff['Cm_alpha']:.3f}), converged: {fit.success}, {fit.n_iterations} iterations"
    )


if __name__ == "__main__":
    main()
