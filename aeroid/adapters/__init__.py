"""Adapters that bring external simulators into AeroID (optional extras).

* `aeroid.adapters.jsbsim`: `JsbsimModel` (property-mapped JSBSim aircraft)
  and `load_jsbsim_output` (JSBSim CSV logs as `FlightData`).
* `aeroid.adapters.rocketpy`: `RocketpyModel` (rocket flights built from
  parameters by a user callback) and `rocketpy_flight_data`.
* `aeroid.adapters.aerosandbox`: `aerosandbox_model`, a longitudinal 3-DOF
  `aeroid.Model` from tabulated AeroBuildup aerodynamics.

Each module imports its simulator only when it is used; a missing simulator
raises `AdapterError` naming the extra to install.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Mapping, Sequence
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AdapterError, ChannelError, SimulationError
from ..io.data import FlightData
from ..models.model import SIMULATE_OPTION_KEYS, check_time

__all__: list[str] = []

FloatArray = NDArray[np.float64]

# Keyword options of Model.simulate that generic callers (identify, validate, ...)
# may pass to any model; a stepped simulator integrates with its own scheme and
# accepts them without effect.
INTEGRATOR_OPTIONS = SIMULATE_OPTION_KEYS


def require(module: str, extra: str) -> ModuleType:
    """Import an optional simulator or raise `AdapterError` naming the extra."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise AdapterError(
            f"this adapter needs the {module!r} package, which is not installed "
            f'({exc}): pip install "aeroid[{extra}]"'
        ) from None


def check_options(options: Mapping[str, Any], allowed: Iterable[str], where: str) -> None:
    """Raise `AdapterError` for keyword options outside `allowed`, listing the valid ones."""
    valid = tuple(allowed)
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise AdapterError(f"{where}: unknown options {unknown}; valid options are {list(valid)}")


def time_grid(time: Any) -> FloatArray:
    """A finite, strictly increasing 1-D time grid of at least two samples."""
    return check_time(time)


def _numbers(values: Any, what: str) -> FloatArray:
    """`values` as floats, or a `SimulationError` naming `what` (text, complex numbers)."""
    if np.iscomplexobj(values):
        raise SimulationError(f"{what}: complex values are not supported")
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise SimulationError(f"{what}: expected numbers, got {type(values).__name__}") from None


def control_matrix(time: FloatArray, controls: Any, names: Sequence[str]) -> FloatArray:
    """Controls as an (n_t, n_u) array from None, a mapping, FlightData or an array."""
    n_t, n_u = time.size, len(names)
    if controls is None:
        return np.zeros((n_t, n_u))
    if isinstance(controls, FlightData):
        controls.require(names, role="control")
        if controls.n_samples != n_t:
            raise SimulationError(
                f"controls: flight data has {controls.n_samples} samples, time has {n_t}"
            )
        return np.array(controls.array(list(names)), dtype=np.float64).reshape(n_t, n_u)
    if isinstance(controls, Mapping):
        missing = [c for c in names if c not in controls]
        if missing:
            raise ChannelError(
                f"control {missing[0]!r} not given; controls given: {sorted(controls)}"
            )
        cols = []
        for c in names:
            col = _numbers(controls[c], f"control {c!r}")
            if col.shape != (n_t,):
                raise SimulationError(
                    f"control {c!r}: expected {n_t} samples, got shape {col.shape}"
                )
            cols.append(col)
        arr = np.stack(cols, axis=1) if cols else np.zeros((n_t, 0))
    else:
        arr = _numbers(controls, "controls")
        if arr.ndim == 1 and n_u == 1:
            arr = arr[:, None]
        if arr.shape != (n_t, n_u):
            raise SimulationError(
                f"controls: expected shape ({n_t}, {n_u}) for controls {list(names)}, "
                f"got {np.shape(controls)}"
            )
    if not np.all(np.isfinite(arr)):
        raise SimulationError("controls: contain NaN or infinite values")
    return arr
