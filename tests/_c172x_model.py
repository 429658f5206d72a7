"""The stability-axis longitudinal model fitted to the JSBSim c172x demo flights.

Shared by the physics check (`test_jsbsim_demo.py`) and the chain benchmark
(`benchmarks/bench_chain.py`), so both fit the same equations.
"""

from __future__ import annotations

from typing import Any

from aeroid.models import aircraft

TERMS = {
    "CD": ["0", "alpha"],
    "CL": ["0", "alpha", "q", "delta_e"],
    "Cm": ["0", "alpha", "q", "delta_e"],
}
OUTPUTS = ["V", "alpha", "theta", "q", "ax", "az"]


def longitudinal(constants: Any, V0: float) -> Any:
    """`aircraft.longitudinal` with the demo's coefficient terms and outputs."""
    return aircraft.longitudinal(constants, V0=V0, terms=TERMS, outputs=OUTPUTS)
