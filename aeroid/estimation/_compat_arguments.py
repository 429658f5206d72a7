"""Argument checks and start values of data compatibility.

Split out of `aeroid.estimation.compatibility` (which re-exports every name): the channel
map and its unit check, the estimated and held parameters, the outputs fitted,
the measured states standing in for integrated ones and the initial state.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ChannelError, DataFormatError, IdentificationError, ResidualDriftWarning
from ..io.data import FlightData, plain
from ._compat_model import (
    _REQUIRED_OUTPUTS,
    _WIND,
    DEFAULT_ESTIMATE,
    INPUT_CHANNELS,
    OUTPUT_CHANNELS,
    SENSOR_PARAMETERS,
    STATES,
)
from ._compat_sensors import _per_record_x0

FloatArray = NDArray[np.float64]
# Hz: the low-pass a held initial state is taken through (`_held_start`)
START_CUTOFF = 2.0

# Largest plausible magnitude of each angle in radians: beyond it the data are in degrees.
_ANGLE_LIMITS = {"alpha": math.pi / 2, "beta": math.pi / 2, "phi": math.pi, "theta": math.pi / 2}


def _channel_map(data: FlightData, channels: Mapping[str, str | None] | None) -> dict[str, str]:
    """Canonical name -> data channel, for the channels present."""
    mapping: dict[str, str | None] = {c: c for c in (*INPUT_CHANNELS, *OUTPUT_CHANNELS)}
    if channels is not None:
        if not isinstance(channels, Mapping):
            raise IdentificationError(
                f"channels: expected a mapping of quantity -> channel name, got {plain(channels)}"
            )
        for key, value in channels.items():
            if key not in mapping:
                raise IdentificationError(
                    f"channels: {key!r} is not a quantity of the analysis; quantities: "
                    f"{list(mapping)}"
                )
            if value is not None and not isinstance(value, str):
                raise IdentificationError(
                    f"channels[{key!r}]: expected a channel name or None, got {plain(value)}"
                )
            mapping[key] = value
    present: dict[str, str] = {}
    for key, name in mapping.items():
        required = key in INPUT_CHANNELS or key in _REQUIRED_OUTPUTS
        if name is None:
            if required:
                raise ChannelError(f"channels[{key!r}]: {key} is required and cannot be None")
            continue
        if name in data:
            present[key] = name
        elif required or (channels is not None and key in channels):
            role = "input" if key in INPUT_CHANNELS else "output"
            raise ChannelError(
                f"{role} {key!r} (channel {name!r}) not found in flight data; channels present: "
                f"{sorted(data.names)}; map it with channels={{{key!r}: 'name'}}"
            )
    for key, name in present.items():
        _refuse_unit(key, name, data.units.get(name))
        values = data.channels[name]
        if not np.all(np.isfinite(values)):
            bad = int(np.flatnonzero(~np.isfinite(values))[0])
            raise DataFormatError(f"channel {name!r} ({key}): non-finite value at index {bad}")
        limit = _ANGLE_LIMITS.get(key)
        if limit is not None and float(np.max(np.abs(values))) > limit:
            raise DataFormatError(
                f"channel {name!r} ({key}): values up to {float(np.max(np.abs(values))):.4g} "
                f"exceed {limit:.4g}; angles must be in radians"
            )
    v = data.channels[present["V"]]
    if not float(np.min(v)) > 0.0:
        raise DataFormatError(
            f"channel {present['V']!r} (V): airspeed must be positive, minimum {float(np.min(v)):.4g}"
        )
    return present


def _refuse_unit(key: str, name: str, unit: str | None) -> None:
    """A channel whose declared unit is a scaled one the kinematics would read as their
    own (deg/s read as rad/s moved the biases by two orders of magnitude in silence)."""
    from ..io.channel_map import UNIT_CONVERSIONS

    if unit is None or unit not in UNIT_CONVERSIONS:
        return
    factor, si = UNIT_CONVERSIONS[unit]
    angular = key in _ANGLE_LIMITS or key in ("p", "q", "r")
    if (angular and factor != 1.0) or (key in ("ax", "ay", "az") and unit == "g"):
        takes = "rad and rad/s" if angular else "m/s^2 (or the units of gravity=)"
        raise DataFormatError(
            f"channel {name!r} ({key}): declared in {unit!r}; check_compatibility takes "
            f"{takes}: convert it (x {factor:.6g} to {si})"
        )


# outputs that see the lateral motion (roll, sideslip, heading, ground track)
LATERAL_OUTPUTS = frozenset({"beta", "phi", "psi", "vn", "ve"})
# the errors of the lateral inputs, which only those outputs see on a wings-level record
LATERAL_INPUT_ERRORS = ("b_p", "b_r", "b_ay", "k_p", "k_r", "k_ay")


def _parameter_values(
    estimate: Sequence[str] | Mapping[str, float] | None,
    fixed: Mapping[str, float] | None,
    present: Mapping[str, str],
) -> tuple[list[str], dict[str, float]]:
    """The names to estimate and every parameter's start (or fixed) value."""
    values = {n: 0.0 for n in SENSOR_PARAMETERS}
    if estimate is None:
        names = [n for n in DEFAULT_ESTIMATE if n.partition("_")[2] in present]
        if not LATERAL_OUTPUTS & set(present):
            # a longitudinal analysis (SIDPAC's dca_lon): no fitted output sees the
            # lateral gyros or accelerometer but through second-order terms
            names = [n for n in names if n not in LATERAL_INPUT_ERRORS]
    elif isinstance(estimate, str):
        names = [estimate]
    elif isinstance(estimate, Mapping):
        names = list(estimate)
    else:
        try:
            names = list(estimate)
        except TypeError:
            raise IdentificationError(
                f"estimate: expected a list of parameter names or a mapping name -> start "
                f"value, got {plain(estimate)}"
            ) from None
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise IdentificationError(f"estimate: listed twice: {dupes}")
    for n in names:
        if n not in values:
            raise IdentificationError(
                f"estimate: {n!r} is not a sensor parameter; choose from {list(SENSOR_PARAMETERS)}"
            )
        channel = n.partition("_")[2]
        if n not in _WIND and channel not in present:
            raise ChannelError(
                f"estimate: {n!r} belongs to channel {channel!r}, which the data lack "
                "or which is not among the fitted outputs"
            )
    if not names:
        raise IdentificationError("estimate: name at least one sensor parameter to estimate")
    if fixed is not None and not isinstance(fixed, Mapping):
        raise IdentificationError(f"fixed: expected a mapping name -> value, got {plain(fixed)}")
    given: dict[str, Any] = dict(fixed or {})
    both = sorted(set(given) & set(names))
    if both:
        raise IdentificationError(f"parameters {both} are both estimated and fixed")
    starts: dict[str, Any] = dict(estimate) if isinstance(estimate, Mapping) else {}
    for label, source in (("fixed", given), ("estimate", starts)):
        for n, v in source.items():
            if n not in values:
                raise IdentificationError(
                    f"{label}: {n!r} is not a sensor parameter; choose from "
                    f"{list(SENSOR_PARAMETERS)}"
                )
            try:
                value = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(
                    f"{label}[{n!r}]: expected a number, got {plain(v)}"
                ) from None
            if not math.isfinite(value):
                raise IdentificationError(f"{label}[{n!r}]: value {value!r} is not finite")
            if n.startswith("k_") and not value > -1.0:
                raise IdentificationError(
                    f"{label}[{n!r}]: a scale-factor error must exceed -1, got {value!r}"
                )
            values[n] = value
    return names, values


def _rewarn(caught: list[warnings.WarningMessage], names: list[str]) -> None:
    """The fit's warnings again, from here; an output drift is told in this function's
    terms (an offset to estimate, not an output bias of `identify`)."""
    for w in caught:
        drift = w.message
        if not isinstance(drift, ResidualDriftWarning):
            warnings.warn(w.message, w.category, stacklevel=4)
            continue
        offsets = [f"b_{o}" for o in drift.outputs if f"b_{o}" not in names]
        warnings.warn(
            ResidualDriftWarning(
                f"check_compatibility: the residuals of {list(drift.outputs)} drift like a "
                "random walk over the record; with their unknown offsets the error bars are "
                f"up to {drift.widening:.2g}x the white ones"
                + (f" (estimate={offsets} absorbs them)" if offsets else ""),
                drift.outputs,
                drift.widening,
            ),
            stacklevel=4,  # here, check_compatibility, its BLAS wrapper, the caller
        )


def _fitted_outputs(outputs: Sequence[str] | None, present: Mapping[str, str]) -> list[str]:
    """The outputs to fit, in `OUTPUT_CHANNELS` order."""
    if outputs is None:
        return [o for o in OUTPUT_CHANNELS if o in present]
    names = [outputs] if isinstance(outputs, str) else outputs
    try:
        names = list(names)
    except TypeError:
        raise IdentificationError(
            f"outputs: expected a list of output names, got {plain(outputs)}"
        ) from None
    for o in names:
        if o not in OUTPUT_CHANNELS:
            raise IdentificationError(
                f"outputs: {o!r} is not an output; outputs: {list(OUTPUT_CHANNELS)}"
            )
        if o not in present:
            raise ChannelError(f"outputs: {o!r} is not in the flight data")
    if not names:
        raise IdentificationError("outputs: name at least one output to fit")
    return [o for o in OUTPUT_CHANNELS if o in names]


_STAND_IN_SOURCES = {
    "u": ("V", "alpha"),
    "v": ("V", "alpha"),
    "w": ("V", "alpha"),
    "phi": ("phi",),
    "theta": ("theta",),
    "psi": ("psi",),
    "h": ("h",),
}


def _measured_state_names(states: Sequence[str], present: Mapping[str, str]) -> set[str]:
    names = [states] if isinstance(states, str) else states
    try:
        names = list(names)
    except TypeError:
        raise IdentificationError(
            f"measured_states: expected a list of state names, got {plain(states)}"
        ) from None
    for s in names:
        if s not in STATES:
            raise IdentificationError(
                f"measured_states: {s!r} is not a state; states: {list(STATES)}"
            )
        lacking = [c for c in _STAND_IN_SOURCES[s] if c not in present]
        if lacking:
            raise ChannelError(
                f"measured_states: state {s!r} needs the channel(s) {lacking}, which the data lack"
            )
    return set(names)


def _free_states(choice: bool | Sequence[str], seen: list[str]) -> list[str]:
    """The initial states to estimate."""
    if isinstance(choice, bool):
        return list(seen) if choice else []
    names = [choice] if isinstance(choice, str) else choice
    try:
        names = list(names)
    except TypeError:
        raise IdentificationError(
            f"estimate_x0: expected True, False or a list of state names, got {plain(choice)}"
        ) from None
    for s in names:
        if s not in STATES:
            raise IdentificationError(f"estimate_x0: {s!r} is not a state; states: {list(STATES)}")
    return [s for s in STATES if s in names]


def _first_values(t: FloatArray, measured: Mapping[str, FloatArray]) -> dict[str, FloatArray]:
    """Each channel's start, low-passed (a held initial state should carry neither one
    sample's noise nor a jitter the kinematics cannot follow): `_held_start`."""
    steps = np.diff(t)
    uniform = t.size >= 16 and float(np.ptp(steps)) <= 1e-6 * float(np.mean(steps))
    out: dict[str, FloatArray] = {}
    for o, y in measured.items():
        first = _held_start(y, float(np.mean(steps))) if uniform else float(y[0])
        out[o] = np.array([first])
    return out


def _held_start(y: FloatArray, dt: float, cutoff: float = START_CUTOFF) -> float:
    """The value at the first sample of `y` low-passed at `cutoff` Hz, without leaning
    on that sample (a record's ends are often its noisiest).

    The second to fourth samples are each low-passed by a Hann-windowed sinc over
    the samples after them (up to half the record), counted twice as though the
    record were reflected about that sample, and a least-squares line through the
    three is taken back to the first. That is how SIDPAC's ``dcmp`` holds its start
    (``xsmep``, at 2 Hz: a manned aircraft's rigid-body band), so a start held as
    SIDPAC holds it carries neither one sample's noise nor a vane's jitter. Like
    any one-sided mean it lags a record that starts moving (by 2.5 samples at
    50 Hz; a 0.5 Hz swing is held to 16 % of its amplitude): such a record wants
    its start estimated.
    """
    n_lags = max(min(y.size // 2, y.size - 4), 1)
    lags = np.arange(1, n_lags + 1, dtype=np.float64)
    band = 2.0 * cutoff * dt
    h = band * np.sinc(band * lags) * 0.5 * (1.0 + np.cos(np.pi * lags / (n_lags + 1)))
    norm = band + 2.0 * float(h.sum())
    near = np.array(
        [(band * y[j] + 2.0 * float(h @ y[j + 1 : j + 1 + n_lags])) / norm for j in (1, 2, 3)]
    )
    _, intercept = np.polyfit(np.array([1.0, 2.0, 3.0]), near, 1)
    return float(intercept)


def _states_from(
    measured: Mapping[str, FloatArray], values: Mapping[str, float]
) -> dict[str, FloatArray]:
    """The states as the air data, attitude and altitude channels give them, with the
    known sensor errors removed; ground velocity = air velocity + the wind, in body axes."""
    n = next(iter(measured.values())).size

    def get(o: str) -> FloatArray:
        if o not in measured:
            return np.zeros(n)
        y = measured[o]
        return np.asarray((y - values[f"b_{o}"]) / (1.0 + values[f"k_{o}"]), dtype=np.float64)

    V, alpha, beta = get("V"), get("alpha"), get("beta")
    phi, theta, psi = get("phi"), get("theta"), get("psi")
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    spsi, cpsi = np.sin(psi), np.cos(psi)
    along = cpsi * values["w_n"] + spsi * values["w_e"]
    across = cpsi * values["w_e"] - spsi * values["w_n"]
    wx = cth * along - sth * values["w_d"]
    wy = sphi * sth * along + cphi * across + sphi * cth * values["w_d"]
    wz = cphi * sth * along - sphi * across + cphi * cth * values["w_d"]
    return {
        "u": V * np.cos(alpha) * np.cos(beta) + wx,
        "v": V * np.sin(beta) + wy,
        "w": V * np.sin(alpha) * np.cos(beta) + wz,
        "phi": phi,
        "theta": theta,
        "psi": psi,
        "h": get("h"),
    }


def _start_state(
    first: Mapping[str, FloatArray],
    values: Mapping[str, float],
    x0: Mapping[str, float] | None,
) -> dict[str, float]:
    """Initial state from the (smoothed) first samples with the start sensor errors removed."""
    state = {s: float(v[0]) for s, v in _states_from(first, values).items()}
    if x0 is not None:
        if not isinstance(x0, Mapping):
            raise IdentificationError(f"x0: expected a mapping state -> value, got {plain(x0)}")
        for s, v in x0.items():
            if s not in state:
                raise IdentificationError(f"x0: unknown state {s!r}; states: {list(STATES)}")
            try:
                state[s] = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(f"x0[{s!r}]: expected a number, got {plain(v)}") from None
            if not math.isfinite(state[s]):
                raise IdentificationError(f"x0[{s!r}]: value {state[s]!r} is not finite")
    return state


# The states whose start a held fit reconstructs from each sensor's first samples (less
# its known errors): an error estimated on such a sensor while that start is held at the
# measured value shifts start and output alike, and the fit cannot see it.
_START_STATES = {
    # v starts from V sin(beta): without a sideslip channel, from the wind alone
    **{f"{kind}_V": ("u", "w", "v") for kind in "bk"},
    **{f"{kind}_alpha": ("u", "w") for kind in "bk"},
    **{f"{kind}_beta": ("u", "v", "w") for kind in "bk"},
    **{f"{kind}_{o}": (o,) for kind in "bk" for o in ("phi", "theta", "psi", "h")},
    **{w: ("u", "v", "w") for w in ("w_n", "w_e", "w_d")},
}


def _start_errors(
    names: list[str],
    default: bool,
    free_x0: Sequence[str],
    held_in: set[str],
    x0: Any,
    n_records: int,
    sideslip: bool,
) -> list[str]:
    """`names`, refused where it holds sensor errors a start held at the measured values
    would absorb (with ``scale_about="zero"``)."""
    given = [set(g or {}) for g in _per_record_x0(x0, n_records)]
    held = {
        s
        for s in STATES
        if s not in free_x0 and s not in held_in and any(s not in g for g in given)
    }

    def starts(name: str) -> set[str]:
        # without a sideslip channel v starts from the wind alone
        moved = set(_START_STATES.get(name, ()))
        return moved - {"v"} if not sideslip and not name.startswith("w_") else moved

    absorbed = [n for n in names if held & starts(n)]
    if not absorbed:
        return names
    shown = sorted(held & {s for n in absorbed for s in starts(n)})
    raise IdentificationError(
        f"estimate: {absorbed}{' (the default set)' if default else ''}: the start of "
        f"{shown} is held at the measured values, which carry these errors, so the fit "
        "cannot see them; estimate those initial states (estimate_x0), give x0, use "
        "scale_about='initial' (an offset is then the error at the start, SIDPAC's form) "
        "or leave them out of estimate"
    )
