"""Benchmark: `identify` on the standard aircraft models of `aeroid.models.aircraft` (run as a script).

    python tests/benchmarks/bench_aircraft.py [longitudinal|six_dof]

* ``longitudinal``: the stability-axis model, outputs V, alpha, theta, q,
  q_dot, ax, az, 601 samples at 10 Hz, 11 coefficients; target <= 0.3 s warm.
* ``six_dof``: the body-axis model, 60 s at 50 Hz (3001 samples), 20
  coefficients estimated; target <= 1 s warm.

Each case runs in a fresh process with the default environment (no BLAS
pinning); the first call and the median of the warm calls are printed, with
the largest |estimate - truth| / standard error as a check of the answer.
The machine may be shared: the figures are medians and still noisy.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _timing import timed

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the aircraft data

from _aircraft_data import BASE, LONG
from _aircraft_data import LAT as LAT_ALL

REPEATS = 3
LAT = {k: v for k, v in LAT_ALL.items() if k not in ("CY_p", "CY_r", "CY_delta_a")}


def _constants() -> Any:
    from aeroid.models.aircraft import AircraftConstants

    return AircraftConstants(**BASE, Ixz=80.0, altitude=1000.0, accel_position=(0.3, 0.0, 0.1))


def _square(t: np.ndarray, start: float, widths: list[float], amplitude: float) -> np.ndarray:
    """A multistep input (3-2-1-1 for widths [3, 2, 1, 1]) with alternating signs."""
    out = np.zeros_like(t)
    edge = start
    for i, w in enumerate(widths):
        out[(t >= edge) & (t < edge + w)] = amplitude * (-1) ** i
        edge += w
    return out


def _run(model: Any, data: Any, guess: dict[str, float], x0: Any, truth: dict[str, float]) -> None:
    import aeroid

    def fit() -> Any:
        return aeroid.identify(model, data, guess, x0=x0)

    t0 = time.perf_counter()
    fit()
    first = time.perf_counter() - t0
    warm, res = timed(fit, REPEATS)
    worst = max(abs(res.parameters[k] - truth[k]) / res.stderr[k] for k in guess)
    print(f"  identify, first call                {first:8.3f} s   ({res.n_iterations} iterations)")
    print(f"  identify, warm (median of {REPEATS})       {warm:8.3f} s")
    print(f"  largest |estimate - truth| / stderr {worst:8.2f}")


def case_longitudinal() -> None:
    from aeroid.models.aircraft import longitudinal, trim

    model = longitudinal(_constants(), V0=53.6, parameters=LONG)
    tr = trim(model)
    t = np.arange(601) * 0.1
    de = tr.controls["delta_e"] + _square(t, 2.0, [3, 2, 1, 1], 0.03)
    de += _square(t, 30.0, [1.5, 1.5], 0.03)
    thrust = tr.controls["thrust"] * (1.0 + 0.3 * ((t > 15.0) & (t < 22.0)))
    U = np.column_stack([de, thrust])
    sim = model.simulate(t, U, tr.x0)
    noise = {"V": 0.2, "alpha": 0.002, "theta": 0.002, "q": 0.003, "q_dot": 0.01}
    data = sim.to_flight_data(noise={**noise, "ax": 0.05, "az": 0.1}, seed=0)
    guess = {k: 1.2 * v for k, v in LONG.items()}
    print("longitudinal: 601 samples, 7 outputs, 11 coefficients (target <= 0.3 s warm)")
    _run(model, data, guess, tr.x0, LONG)


def case_six_dof() -> None:
    from aeroid.models.aircraft import six_dof, trim

    terms = {
        "CY": ["beta", "delta_r"],
        "Cl": ["beta", "p", "r", "delta_a", "delta_r"],
        "Cn": ["beta", "p", "r", "delta_a", "delta_r"],
    }
    model = six_dof(_constants(), V0=53.6, terms=terms, parameters={**LONG, **LAT})
    tr = trim(model)
    t = np.arange(3001) * 0.02
    de = tr.controls["delta_e"] + _square(t, 2.0, [3, 2, 1, 1], 0.02)
    da = _square(t, 15.0, [1, 1], 0.05) + _square(t, 35.0, [1, 1], 0.05)
    dr = _square(t, 25.0, [1.5, 1.5], 0.05) + _square(t, 45.0, [1.5, 1.5], 0.05)
    U = np.column_stack([de, da, dr, np.full(t.size, tr.controls["thrust"])])
    sim = model.simulate(t, U, tr.x0)
    noise = dict.fromkeys(("alpha", "beta", "phi", "theta", "psi"), 0.002)
    noise.update(dict.fromkeys(("p", "q", "r"), 0.003))
    noise.update(V=0.2, p_dot=0.02, q_dot=0.02, r_dot=0.02, ax=0.05, ay=0.05, az=0.1)
    data = sim.to_flight_data(noise=noise, seed=0)
    free = [k for k in (*LONG, *LAT) if not k.endswith("_0")][:20]
    truth = {**LONG, **LAT}
    guess = {k: 1.2 * truth[k] for k in free}
    print(f"six_dof: 3001 samples, 15 outputs, {len(free)} coefficients (target <= 1 s warm)")
    _run(model, data, guess, tr.x0, truth)


CASES = {"longitudinal": case_longitudinal, "six_dof": case_six_dof}


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--case":
        CASES[sys.argv[2]]()
        return
    names = sys.argv[1:] or list(CASES)
    for name in names:
        # a fresh process per case: first-call costs (imports, compilation) are real
        subprocess.run([sys.executable, __file__, "--case", name], check=False)


if __name__ == "__main__":
    main()
