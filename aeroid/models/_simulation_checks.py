"""Checks of simulation arguments: integrator settings and real numbers."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AeroidError, SimulationError
from ..io.data import as_float, plain, real_array
from . import integration as _integrate

FloatArray = NDArray[np.float64]


# RK4 holds the controls at every node of every interval, (n_t - 1) x (2 m + 1) values
# per control: a substep count far beyond any stiffness (the automatic choice stops at
# 256) would only exhaust memory.
MAX_SUBSTEPS = 10_000
# ... and with the batch, at most this many node values (1 GiB of float64).
_MAX_NODE_VALUES = 2**27


def check_substeps(substeps: Any, what: str, error: type[AeroidError]) -> int:
    """`substeps` as a whole number in 1..`MAX_SUBSTEPS`, else `error` naming `what`."""
    ok = not isinstance(substeps, (bool, np.bool_, str, bytes))
    try:
        ok = ok and int(substeps) == substeps and 1 <= substeps <= MAX_SUBSTEPS
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise error(
            f"{what} must be a positive integer of at most {MAX_SUBSTEPS} "
            f"(RK4 steps per sample interval), got {plain(substeps)}"
        )
    return int(substeps)


def check_integrator(
    method: Any,
    substeps: Any,
    rtol: Any,
    atol: Any,
    *,
    error: type[AeroidError] = SimulationError,
    prefix: str = "",
) -> None:
    """Refuse integrator settings `Model.simulate` cannot honour, naming the setting.

    `prefix` qualifies the names (``"simulate_options"`` gives
    ``simulate_options['rtol']``). A NaN tolerance would hang the adaptive
    solvers and a non-positive one is silently raised to rounding by SciPy;
    a bool substep count would be read as 1.
    """

    def name(key: str) -> str:
        return f"{prefix}[{key!r}]" if prefix else key

    if not isinstance(method, str) or method not in _integrate.METHODS:
        raise error(
            f"{name('method')}: unknown method {plain(method)}; choose one of "
            f"{list(_integrate.METHODS)}"
        )
    if substeps is not None:
        check_substeps(substeps, name("substeps"), error)
    for key, value, least in (("rtol", rtol, "positive"), ("atol", atol, "non-negative")):
        v = as_float(value)
        if v is None or not (np.isfinite(v) and (v > 0 if least == "positive" else v >= 0)):
            raise error(f"{name(key)}: expected a finite {least} number, got {plain(value)}")


def _real(values: Any, what: str) -> FloatArray:
    """`values` as float64 (as ``np.asarray(values, dtype=float)``), or a `SimulationError`
    naming `what`: text, or complex numbers whose imaginary part a cast would drop."""
    try:
        return real_array(values, what)
    except AeroidError as exc:
        raise SimulationError(str(exc)) from None


def real_number(
    value: Any, what: str, error: type[AeroidError] = SimulationError, *, finite: bool = False
) -> float:
    """`value` as a float, or `error` naming `what`: bools and text are refused (float()
    would read True as 1.0 and "2" as 2.0), so is a complex number, and with `finite`
    NaN and infinity."""
    v = as_float(value)
    if v is None:
        raise error(f"{what}: expected a number, got {plain(value)}")
    if finite and not np.isfinite(v):
        raise error(f"{what}: expected a finite number, got {plain(value)}")
    return v
