"""Argument checks shared by every module, below `FlightData` (a leaf: it imports
only the errors), so that the modules `aeroid.io.data` itself uses can check too."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import DataFormatError, SimulationError

__all__ = ["as_float", "check_time", "constant_value", "plain", "positive_number", "time_label"]


def plain(value: Any) -> str:
    """`value` for an error message: numpy scalars as plain numbers (0.45, not np.float64(0.45))."""
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def time_label(t: float) -> str:
    """A time stamp for a message: to the millisecond, however large the clock (``:g``
    printed every instant of an epoch-stamped flight as 1.7e+09)."""
    return str(np.format_float_positional(float(t), precision=3, trim="-"))


def as_float(value: Any) -> float | None:
    """`value` as a float, or None when it is not a plain real number: bools and text are
    refused (float() would read True as 1.0 and "2" as 2.0), and so are complex numbers.
    NaN and infinity pass: each caller says which values it takes, and in its own words."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return None
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return None


def constant_value(values: Any) -> float | None:
    """The value of a channel that never changes (its finite samples equal to 1e-12 of
    their size, or of 1), else None; None too for a channel with no finite sample."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    scale = max(1.0, float(np.max(np.abs(v))))
    return float(v[0]) if float(np.ptp(v)) <= 1e-12 * scale else None


def positive_number(value: Any, name: str, unit: str = "") -> float:
    """`value` as a finite float > 0, else a `DataFormatError` naming `name` (`unit`, such
    as ``" of seconds"``, completes "a positive number")."""
    x = as_float(value)
    if x is None or not (np.isfinite(x) and x > 0):
        raise DataFormatError(f"{name}: expected a positive number{unit}, got {plain(value)}")
    return x


def check_time(time: Any) -> NDArray[np.float64]:
    """A finite, strictly increasing 1-D time grid of at least two samples."""
    if np.iscomplexobj(time):  # a cast would drop the imaginary part
        raise SimulationError("time: complex values are not supported")
    try:
        t = np.asarray(time, dtype=np.float64)
    except (TypeError, ValueError):
        raise SimulationError(
            f"time: expected an array of numbers, got {type(time).__name__}"
        ) from None
    if t.ndim != 1 or t.size < 2:
        raise SimulationError(
            f"time: expected a 1-D grid of at least 2 samples, got shape {t.shape}"
        )
    if not np.all(np.isfinite(t)):
        raise SimulationError("time: contains NaN or infinite values")
    if np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise SimulationError(f"time: not strictly increasing at index {bad}")
    return t


def named_columns(value: Any) -> dict[str, Any] | None:
    """The columns of a table that names them (a pandas DataFrame) by name, or the
    entries of a labelled vector (a pandas Series) by label; None for anything else.
    A table's names must be read, never its column order."""
    if isinstance(value, (dict, np.ndarray, list, tuple)) or not hasattr(value, "to_numpy"):
        return None
    columns = getattr(value, "columns", None)
    if columns is not None:
        names = [str(c) for c in columns]
        if len(set(names)) != len(names):
            raise DataFormatError(f"a table's columns are named more than once: {names}")
        return {name: value[c].to_numpy() for name, c in zip(names, columns, strict=True)}
    index = getattr(value, "index", None)
    if index is not None and getattr(value, "ndim", 0) == 1:
        labels = [str(i) for i in index]
        if len(set(labels)) != len(labels) or labels == [str(i) for i in range(len(labels))]:
            return None  # a plain positional vector
        return dict(zip(labels, value.to_numpy().tolist(), strict=True))
    return None
