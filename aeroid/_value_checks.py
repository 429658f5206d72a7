"""Argument checks shared by the estimators: switches, choices, counts, real arrays, body
positions, delays, symmetry."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._checks import plain
from .errors import DataFormatError

FloatArray = NDArray[np.float64]


def _first_bad(values: FloatArray) -> int:
    return int(np.flatnonzero(~np.isfinite(values))[0])


def check_flag(value: Any, name: str, error: type[Exception]) -> bool:
    """`value` as a bool, else `error` naming `name`: a switch given as ``"no"`` or 0
    would otherwise be read by its truth value."""
    if not isinstance(value, (bool, np.bool_)):
        raise error(f"{name}: expected True or False, got {plain(value)}")
    return bool(value)


def check_choice(value: Any, name: str, choices: Any, error: type[Exception]) -> None:
    """Refuse a `value` that is not one of `choices`, naming the option `name`."""
    if value not in choices:
        raise error(f"{name} {value!r} is unknown; choose one of {list(choices)}")


def whole_number(value: Any, name: str, error: type[Exception], *, least: int = 1) -> int:
    """`value` as an int >= `least` (integral floats such as 2e3 accepted), else `error`."""
    try:
        n = int(value)
        ok = not isinstance(value, (bool, str)) and n == value and n >= least
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        what = {1: "a positive integer", 0: "a non-negative integer"}.get(
            least, f"an integer of at least {least}"
        )
        raise error(f"{name} must be {what}, got {plain(value)}")
    return n


def check_distinct(names: Sequence[Any], what: str, error: type[Exception]) -> None:
    """Refuse a name listed twice, naming it: one output, variable or channel twice would
    be counted as two independent ones."""
    seen: set[Any] = set()
    for name in names:
        if name in seen:
            raise error(f"{what}: {name!r} is listed twice")
        seen.add(name)


def check_seed(seed: Any, error: type[Exception], what: str = "seed") -> int | None:
    """`seed` as a non-negative integer or None, else `error` naming `what`: numpy's own
    refusal of ``"x"``, ``-3`` or ``1.5`` is a bare ``TypeError`` or ``ValueError``."""
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise error(f"{what}: expected a non-negative integer or None, got {plain(seed)}")
    return int(seed)


def real_array(values: Any, what: str, error: type[Exception] = DataFormatError) -> FloatArray:
    """`values` as a float64 array (not copied when it is one), or `error` naming
    `what`: not numeric, or complex (a cast would drop the imaginary part)."""
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise error(f"{what}: not numeric ({exc})") from None
    if arr.dtype.kind == "c":
        raise error(
            f"{what}: complex values are not supported; pass the real part or the "
            "magnitude explicitly (np.real, np.abs)"
        )
    if arr.dtype.kind not in "biuf":
        try:
            arr = arr.astype(np.float64)
        except (TypeError, ValueError) as exc:
            raise error(f"{what}: not numeric ({exc})") from None
    return np.asarray(arr, dtype=np.float64)


def body_position(value: Any, what: str, error: type[Exception]) -> tuple[float, float, float]:
    """A point in body axes (x, y, z in m from the centre of gravity) as three finite
    floats, or `error` naming `what` (a sensor's position, a moment reference point)."""
    expected = f"{what}: expected three body-axis coordinates (x, y, z) in m"
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{expected}, got {plain(value)}") from None
    if arr.shape != (3,):
        raise error(f"{expected}, got {plain(value)}")
    if not np.all(np.isfinite(arr)):
        raise error(f"{what}: position {arr.tolist()} is not finite")
    return float(arr[0]), float(arr[1]), float(arr[2])


def finite_array(values: Any, what: str, error: type[Exception] = DataFormatError) -> FloatArray:
    """`values` as a 1-D-at-least float64 array of finite numbers, or `error` naming `what`."""
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
    except (TypeError, ValueError):
        raise error(f"{what}: expected numbers, got {values!r}") from None
    if not np.all(np.isfinite(arr)):
        raise error(f"{what}: expected finite numbers, got {values!r}")
    return arr


def delay_starts(
    option: Any,
    known: Sequence[str],
    *,
    what: str,
    error: type[Exception],
    unknown: Callable[[str], Exception],
) -> dict[str, float]:
    """The ``time_delays=`` option read as name -> start value in seconds.

    A name, a sequence of names (each starting at 0 s) or a mapping name ->
    start; every name one of `known` (else ``unknown(name)`` is raised), every
    start a finite number (bools refused), else `error` names the entry.
    """
    if isinstance(option, str):
        option = [option]
    if isinstance(option, Mapping):
        items = list(option.items())
    else:
        try:
            items = [(c, 0.0) for c in option]
        except TypeError:
            raise error(
                f"time_delays: expected a {what} name, a list of them or a dict of {what} "
                f"name -> start value in s, got {plain(option)}"
            ) from None
    out: dict[str, float] = {}
    for name, value in items:
        if not isinstance(name, str) or name not in known:
            raise unknown(name)
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = float("nan")
        if isinstance(value, bool) or not np.isfinite(v):
            raise error(
                f"time_delays[{name!r}]: the start value must be a finite number of seconds, "
                f"got {plain(value)}"
            )
        out[name] = v
    return out


def check_symmetric(
    arr: FloatArray, names: Sequence[str], what: str, error: type[Exception]
) -> None:
    """Refuse a square matrix whose asymmetry is beyond rounding (relative to its largest
    entry), naming the entry; NaN and infinity are left to the caller's finiteness check."""
    with np.errstate(invalid="ignore"):
        asym = np.abs(arr - arr.T)
    if not np.all(np.isfinite(asym)):
        return
    scale = float(np.max(np.abs(arr))) if arr.size else 0.0
    if float(np.max(asym, initial=0.0)) > 1e-10 * scale:
        i, j = np.unravel_index(int(np.argmax(asym)), asym.shape)
        raise error(
            f"{what}: the matrix must be symmetric, but [{i}, {j}] = {plain(arr[i, j])} and "
            f"[{j}, {i}] = {plain(arr[j, i])} (order {list(names)})"
        )
