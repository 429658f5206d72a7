"""Sensors off the centre of gravity and several records in data compatibility.

Split out of `aeroid.estimation.compatibility`: the checks of the sensor-position and
sideslip options, the nominal parameters that switch the model's lever-arm terms on,
the angular-acceleration share of the accelerometer reading (taken off the record
before the fit) and the checks of a sequence of records.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._value_checks import body_position
from ..errors import DataFormatError, IdentificationError
from ..io.data import FlightData, plain
from ._compat_model import _SIDESLIP_ATAN, ACCEL_POSITION, ALPHA_POSITION, BETA_POSITION

FloatArray = NDArray[np.float64]

_RATE_DERIVATIVES = ("p_dot", "q_dot", "r_dot")


def _position(name: str, value: Any) -> tuple[float, float, float]:
    return body_position(value, name, IdentificationError)


def _sensor_nominal(
    accel: Any, alpha: Any, beta: Any, sideslip: str
) -> tuple[tuple[float, float, float], tuple[tuple[str, float], ...]]:
    """The accelerometer position and the model's nominal entries for the sensor
    geometry (none where every position is zero and the sideslip is ``asin``)."""
    if sideslip not in ("asin", "atan"):
        raise IdentificationError(f"sideslip: expected 'asin' or 'atan', got {plain(sideslip)}")
    r_acc = _position("accel_position", accel)
    entries: list[tuple[str, float]] = []
    for label, value, keys in (
        ("accel_position", r_acc, ACCEL_POSITION),
        ("alpha_vane_position", alpha, ALPHA_POSITION),
        ("beta_vane_position", beta, BETA_POSITION),
    ):
        where = _position(label, value)
        if any(v != 0.0 for v in where):
            entries.extend(zip(keys, where, strict=True))
    if sideslip == "atan":
        entries.append((_SIDESLIP_ATAN, 1.0))
    return r_acc, tuple(entries)


def _angular_acceleration(data: FlightData, rate_channels: Sequence[str]) -> FloatArray:
    """p', q', r' (n, 3): the record's ``p_dot, q_dot, r_dot`` where it has them, else
    the rates differentiated (as `coefficients_from_data` does)."""
    from ..io.smoothing import differentiate

    out = np.empty((data.n_samples, 3))
    lacking = [c for c, d in zip(rate_channels, _RATE_DERIVATIVES, strict=True) if d not in data]
    derived = differentiate(data, lacking, method="fourier", suffix="_dot") if lacking else None
    for j, (c, d) in enumerate(zip(rate_channels, _RATE_DERIVATIVES, strict=True)):
        if d in data:
            out[:, j] = data.channels[d]
        else:
            assert derived is not None
            out[:, j] = derived.channels[c + "_dot"]
    if not np.all(np.isfinite(out)):
        raise DataFormatError("p_dot, q_dot, r_dot: the angular accelerations are not finite")
    return out


def _off_centre(
    data: FlightData,
    present: Mapping[str, str],
    inputs: dict[str, FloatArray],
    lever: tuple[float, float, float],
) -> None:
    """Take the angular-acceleration term ``w' x r`` off the specific forces in `inputs`
    (a constant gyro error leaves w' alone; ``w x (w x r)`` is the model's)."""
    if not any(v != 0.0 for v in lever):
        return
    wdot = _angular_acceleration(data, [present[c] for c in ("p", "q", "r")])
    term = np.cross(wdot, np.asarray(lever, dtype=np.float64))
    for j, c in enumerate(("ax", "ay", "az")):
        inputs[c] = inputs[c] - term[:, j]


def _records(data: Any) -> list[FlightData]:
    """One record or a sequence of them, each a FlightData."""
    if isinstance(data, FlightData):
        return [data]
    if isinstance(data, (str, bytes, Mapping)) or not isinstance(data, Sequence):
        raise DataFormatError(
            f"data: expected FlightData or a sequence of FlightData, got {type(data).__name__}"
        )
    if not data:
        raise DataFormatError("data: the sequence of records is empty")
    for i, d in enumerate(data):
        if not isinstance(d, FlightData):
            raise DataFormatError(f"data[{i}]: expected FlightData, got {type(d).__name__}")
    return list(data)


def _same_channels(presents: Sequence[Mapping[str, str]]) -> None:
    """Every record carries the quantities of the first (shared sensor errors)."""
    first = set(presents[0])
    for i, present in enumerate(presents[1:], start=1):
        if set(present) != first:
            extra = sorted(set(present) - first)
            lacking = sorted(first - set(present))
            raise DataFormatError(
                f"data[{i}]: its channels differ from data[0]'s (lacks {lacking}, adds "
                f"{extra}); records fitted together share their sensors"
            )


def _pooled_noise(levels: Sequence[Mapping[str, float]], sizes: Sequence[int]) -> dict[str, float]:
    """One noise level per input over the records: the root of the sample-weighted
    mean variance (the same sensors)."""
    total = float(sum(sizes))
    return {
        c: math.sqrt(sum(n * lv[c] ** 2 for lv, n in zip(levels, sizes, strict=True)) / total)
        for c in levels[0]
    }


def _per_record_x0(x0: Any, n: int) -> list[Any]:
    """The start-value mapping of each record: one for all, or one per record."""
    if x0 is None or isinstance(x0, Mapping) or n == 1:
        return [x0] * n
    if isinstance(x0, (str, bytes)) or not isinstance(x0, Sequence):
        raise IdentificationError(
            f"x0: expected a mapping state -> value or one per record, got {plain(x0)}"
        )
    if len(x0) != n:
        raise IdentificationError(f"x0: expected one mapping per record ({n}), got {len(x0)}")
    return list(x0)
