"""Checks of what a manoeuvre family gives `design_experiment` (its controls, bounds,
initial and canonical designs) and of the trim it is flown about, each naming the
family's method at fault: a user's family breaking the protocol otherwise surfaced as
a bare numpy error, or as a fault of the optimiser's options."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import as_float, plain
from .._value_checks import check_distinct
from ..errors import ChannelError, IdentificationError

FloatArray = NDArray[np.float64]


def _name(maneuver: Any) -> str:
    return f"maneuver {type(maneuver).__name__}"


def family_controls(maneuver: Any) -> tuple[str, ...]:
    """The family's controls, each named once (twice would drive one control twice)."""
    controls = tuple(maneuver.controls)
    check_distinct(controls, f"{_name(maneuver)}.controls", IdentificationError)
    return controls


def family_bounds(maneuver: Any) -> tuple[FloatArray, tuple[str, ...]]:
    """The family's bounds, (n_v, 2) finite with low < high, and its variable names."""
    what = f"{_name(maneuver)}.bounds"
    try:
        bounds = np.array(maneuver.bounds, dtype=np.float64)
        ok = (bounds.ndim == 2 and bounds.shape[1] == 2) or bounds.size == 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise IdentificationError(
            f"{what}: expected a (low, high) pair per design variable, got "
            f"{plain(maneuver.bounds):.200}"
        )
    bounds = bounds.reshape(-1, 2)
    var_names = tuple(maneuver.variable_names)
    if bounds.shape[0] == 0:
        raise IdentificationError(
            f"maneuver {maneuver!r} has no design variables: give a (low, high) range for at "
            "least one of its settings"
        )
    if len(var_names) != bounds.shape[0]:
        raise IdentificationError(
            f"{what}: {bounds.shape[0]} bounds for {len(var_names)} variable names "
            f"{list(var_names)}"
        )
    if not np.all(np.isfinite(bounds)) or np.any(bounds[:, 1] <= bounds[:, 0]):
        raise IdentificationError(
            f"{what}: expected finite bounds with low < high per design variable "
            f"{list(var_names)}, got {bounds.tolist()}"
        )
    return bounds, var_names


def family_vector(
    maneuver: Any,
    method: str,
    call: Callable[[], Any],
    bounds: FloatArray,
    *,
    inside: bool,
) -> FloatArray:
    """What ``maneuver.<method>`` returns as one finite value per design variable,
    inside the bounds (to rounding) where `inside`, else an error naming the method."""
    what = f"{_name(maneuver)}.{method}()"
    n = bounds.shape[0]
    try:
        v = np.asarray(call(), dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise IdentificationError(f"{what}: expected {n} numbers, got an error: {exc}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise IdentificationError(
            f"{what}: expected {n} finite numbers (one per design variable), got "
            f"{plain(v.tolist()):.200}"
        )
    if inside:
        slack = 1e-9 * (bounds[:, 1] - bounds[:, 0])
        out = (v < bounds[:, 0] - slack) | (v > bounds[:, 1] + slack)
        if np.any(out):
            j = int(np.flatnonzero(out)[0])
            raise IdentificationError(
                f"{what}: design variable {j} = {v[j]:g} lies outside its bounds "
                f"({bounds[j, 0]:g}, {bounds[j, 1]:g})"
            )
        v = np.clip(v, bounds[:, 0], bounds[:, 1])
    return v


def trim_vector(
    trim: Mapping[str, float] | None, controls: Sequence[str], model_name: str
) -> FloatArray | None:
    """The trim controls in the model's control order (None: all zero), checked."""
    if trim is None:
        return None
    if not isinstance(trim, Mapping):
        raise IdentificationError(
            f"trim: expected a dict of control -> value, got {type(trim).__name__}"
        )
    unknown = sorted(set(trim) - set(controls))
    if unknown:
        raise ChannelError(
            f"trim: {unknown} are not controls of model {model_name!r}; controls: {list(controls)}"
        )
    out = np.zeros(len(controls))
    for name, value in trim.items():
        v = as_float(value)
        if v is None or not math.isfinite(v):
            raise IdentificationError(
                f"trim: the value of {name!r} is {value!r}; expected a finite number"
            )
        out[controls.index(name)] = v
    return out
