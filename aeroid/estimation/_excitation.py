"""Checks that the numbers can be trusted before an estimate is made of them.

An estimator given an input that never moves, or a channel off by a unit
factor, still converges and reports tiny error bars: the error bars are only
as good as the information in the record. These checks catch the cases the
data itself can show (Klein & Morelli, ch. 9: a record without excitation
holds no information about the derivatives it is meant to give).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import constant_value
from ..errors import ChannelError, IdentifiabilityWarning, IdentificationError

FloatArray = NDArray[np.float64]

# Airspeed of anything that flies, m/s: a glider's stall to beyond Mach 10. A
# median outside is a channel in another unit (km/h near the top, mm/s or cm/s
# beyond it, knots x 1000...), not a flight.
_AIRSPEED_RANGE = (0.5, 4000.0)
# residual RMS over the record's RMS beyond which an end point is a runaway simulation
_RUNAWAY = 100.0
# body rates, rad/s: 20 rad/s (1150 deg/s) is beyond any airframe
_RATE_LIMIT = 20.0


def held_controls(datas: Sequence[Any], controls: Iterable[str]) -> dict[str, float]:
    """The controls that hold one non-zero value in every manoeuvre, by name, when every
    control does (else empty).

    A control held at zero leaves the free response from the initial states; a
    constant non-zero one is a step at the record's start: from a known start
    (a step from rest) the transient carries the derivatives, but from trim the
    states never move and the input cannot be told from a trim bias.
    `refuse_unexcited` decides which, from the fit.
    """
    names = list(controls)
    held: dict[str, float] = {}
    for name in names:
        values = [constant_value(d[name]) for d in datas]
        if any(v is None or v == 0.0 for v in values):
            return {}
        held[name] = float(values[0])  # type: ignore[arg-type]
    return held


def refuse_unexcited(held: Mapping[str, float], ratios: Mapping[str, float]) -> None:
    """Refuse a fit whose every control is constant (`held`) and whose fitted response
    stands out of its residual noise on no output (`response_to_noise` below one, or
    none: the fit ended non-finite).

    Raises
    ------
    IdentificationError
        Naming the controls and their constant values.
    """
    if not held or (ratios and any(v >= 1.0 for v in ratios.values())):
        return
    listing = ", ".join(f"{n!r} = {v:.6g}" for n, v in held.items())
    raise IdentificationError(
        f"no excitation: every control is constant in every manoeuvre ({listing}) and no "
        "output's fitted response stands out of its residual noise; a constant input cannot "
        "be told from a trim bias, so the derivatives it multiplies are not identifiable. "
        "Fit a record with an input (doublet, 3-2-1-1, multisine), or a step from a known "
        "start"
    )


def response_to_noise(
    outputs: Sequence[str], residuals: Sequence[Any], datas: Sequence[Any]
) -> dict[str, float]:
    """Each output's fitted response over its residual noise (RMS over RMS).

    The fitted response is the measurement minus the residual, about its mean in
    each manoeuvre; the noise is the residual about its mean. Empty where the
    records do not hold the outputs on the residuals' grid.
    """
    ratios: dict[str, float] = {}
    for k, name in enumerate(outputs):
        moves, noise = [], []
        for d, r in zip(datas, residuals, strict=False):
            res = np.asarray(r, dtype=np.float64)[:, k]
            try:
                y = np.asarray(d[name], dtype=np.float64)
            except (KeyError, TypeError):
                return {}
            if y.shape != res.shape:
                return {}
            fit = y - res
            moves.append(fit - np.mean(fit))
            noise.append(res - np.mean(res))
        signal = float(np.sqrt(np.mean(np.concatenate(moves) ** 2)))
        scatter = float(np.sqrt(np.mean(np.concatenate(noise) ** 2)))
        # a flat output (all zero, say) shows no response however small its residuals
        ratios[name] = signal / scatter if scatter > 0 else (float("inf") if signal > 0 else 0.0)
    return ratios


def warn_unexcited(ratios: Mapping[str, float]) -> None:
    """Warn when no output's fitted response stands out of its residual noise
    (`response_to_noise` below one on every output): the record holds no manoeuvre
    the model could be fitted to, and the estimates and their error bars describe
    noise, however the optimiser ended."""
    if not ratios or any(v >= 1.0 for v in ratios.values()):
        return
    listing = ", ".join(f"{n!r} {v:.2g}" for n, v in ratios.items())
    warnings.warn(
        "identify: the record is not excited: no output's fitted response stands out of "
        f"its residual noise (response over noise, RMS: {listing}); the estimates and their "
        "error bars describe noise. Fit a window that holds a manoeuvre (doublet, 3-2-1-1, "
        "multisine)",
        IdentifiabilityWarning,
        stacklevel=5,  # here, _finish, identify, its BLAS wrapper, the caller
    )


def check_kinematic_channels(data: Any, present: Mapping[str, str]) -> None:
    """Refuse flight-path reconstruction from channels that cannot be right.

    `present` maps a quantity (``V``, ``alpha``, ``p`` ...) to its channel.

    Raises
    ------
    ChannelError
        An airspeed or rate whose magnitude is off by a unit factor,
        naming the channel.
    IdentificationError
        Every rate and acceleration channel constant: nothing to reconstruct.
    """
    inertial = [q for q in ("p", "q", "r", "ax", "ay", "az") if q in present]
    if inertial and all(constant_value(data[present[q]]) is not None for q in inertial):
        raise IdentificationError(
            "no excitation: every rate and acceleration channel ("
            + ", ".join(repr(present[q]) for q in inertial)
            + ") is constant; the sensor errors cannot be estimated from a record without motion"
        )
    if "V" in present:
        v = np.asarray(data[present["V"]], dtype=np.float64)
        median = float(np.nanmedian(np.abs(v))) if v.size else float("nan")
        lo, hi = _AIRSPEED_RANGE
        if np.isfinite(median) and not lo <= median <= hi:
            raise ChannelError(
                f"channel {present['V']!r} (airspeed V): median {median:.4g} is not an "
                f"airspeed in m/s ({lo:g} to {hi:g}); convert the channel (km/h, knots, "
                "mm/s?) or map the right one"
            )
    # (the angles' range is checked with the channel map)
    for quantity in ("p", "q", "r"):
        if quantity not in present:
            continue
        v = np.asarray(data[present[quantity]], dtype=np.float64)
        peak = float(np.nanmax(np.abs(v))) if v.size else 0.0
        if peak > _RATE_LIMIT:
            raise ChannelError(
                f"channel {present[quantity]!r} ({quantity}): reaches {peak:.4g}, beyond the "
                f"{_RATE_LIMIT:g} rad/s any airframe shows; is it in degrees per second?"
            )


# The rates and accelerations that move each air-data or attitude quantity: one held at
# exactly zero while any of its own moves is a dead or missing channel (a zero beta, phi
# or psi beside zero p, r and ay is a symmetric flight's, and is left alone).
_DRIVEN_BY = {
    "V": ("ax", "az", "q"),
    "alpha": ("q", "az"),
    "theta": ("q",),
    "h": ("q",),
    "beta": ("p", "r", "ay"),
    "phi": ("p",),
    "psi": ("r",),
}


def refuse_stuck_outputs(data: Any, present: Mapping[str, str], fitted: Iterable[str]) -> None:
    """Refuse a fitted air-data or attitude channel that holds one value while the rates
    and accelerations move: a stuck or held sensor, whose scale factor and bias the fit
    would report with error bars it does not have (or, at zero, whose fit breaks down
    with non-finite numbers that name no channel); and a rate or acceleration held at
    one non-zero value while the others move.

    Raises
    ------
    ChannelError
        Naming the channel, its value and the channels that move.
    """
    inertial = [q for q in ("p", "q", "r", "ax", "ay", "az") if q in present]
    moving = [q for q in inertial if constant_value(data[present[q]]) is None]
    if not moving:
        return  # no motion: check_kinematic_channels says so
    for quantity in inertial:
        # a rate or acceleration frozen at a non-zero reading while the others move: the
        # reconstruction would integrate it as motion (a zero one is a symmetric flight's)
        value = constant_value(data[present[quantity]])
        if value is not None and value != 0.0:
            others = [q for q in moving if q != quantity]
            raise ChannelError(
                f"channel {present[quantity]!r} ({quantity}): holds {value:.6g} through the "
                f"record while {', '.join(repr(present[q]) for q in others)} "
                f"move{'s' * (len(others) == 1)}: a stuck or held sensor. Fix the channel"
            )
    for quantity in fitted:
        value = constant_value(data[present[quantity]])
        if value is None:
            continue
        drivers = (
            moving if value != 0.0 else [q for q in _DRIVEN_BY.get(quantity, ()) if q in moving]
        )
        if drivers:
            raise ChannelError(
                f"channel {present[quantity]!r} ({quantity}): holds {value:.6g} through the "
                f"record while {', '.join(repr(present[q]) for q in drivers)} "
                f"move{'s' * (len(drivers) == 1)}: a stuck, "
                f"held or missing sensor. Fix the channel or leave {quantity!r} out of outputs="
            )


def refuse_runaway(
    model: Any,
    names: Sequence[str],
    theta: FloatArray,
    outputs: Sequence[str],
    residuals: list[FloatArray],
    measured: FloatArray,
) -> None:
    """Refuse an end point whose simulation runs away from the record.

    From an unstable start the output-error cost can stall where the simulated
    outputs diverge: the estimated noise variances swallow residuals of 1e20
    and the iteration "converges". Predicting a constant zero gives residuals
    no larger than the record's own RMS, so residuals a hundred times that are
    no fit of the record at all.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        res = np.concatenate(residuals, axis=0)
        rms_res = np.sqrt(np.mean(res**2, axis=0))
        rms_meas = np.sqrt(np.mean(measured**2, axis=0))
    away = [
        (o, float(a), float(b))
        for o, a, b in zip(outputs, rms_res, rms_meas, strict=True)
        if not np.isfinite(a) or (b > 0.0 and a > _RUNAWAY * b)
    ]
    if away:
        listing = ", ".join(f"{o!r} off by {a:.3g} RMS (the record's {b:.3g})" for o, a, b in away)
        params = {n: float(f"{v:.6g}") for n, v in zip(names, theta.tolist(), strict=True)}
        raise IdentificationError(
            f"the fit stalled where the simulation of {getattr(model, 'name', '')!r} diverges "
            f"from the record: {listing}, at the parameters {params}. An unstable or "
            "wrong-signed start: start nearer the truth (start='equation_error') or fit an "
            "unstable airframe with method='filter_error'"
        )


def warn_missing_outputs(model: Any, datas: Sequence[Any], fitted: Sequence[str]) -> None:
    """Warn, when `identify` chose the outputs itself, that some model outputs are in
    no record: a misnamed column (``Q`` for ``q``) would otherwise drop that output
    silently, and the fit of the rest looks like a convergence failure.

    An aircraft model's measurement outputs (``q_dot``, ``ax``, ``ay``, ...) are
    optional extras many records lack; only its states are named. Passing
    ``outputs=`` says which are meant and silences this.
    """
    from ..models.aircraft import AircraftModel

    missing = [o for o in model.outputs if o not in fitted]
    if isinstance(model, AircraftModel):
        missing = [o for o in missing if o in model.states]
    if not missing or not fitted:
        return
    channels = sorted({c for d in datas for c in d.names})
    shown = ", ".join(channels[:12]) + (
        f", ... ({len(channels)} in all)" if len(channels) > 12 else ""
    )
    alike = {o: c for o in missing for c in channels if c.casefold() == o.casefold()}
    hints = "".join(f"; the record has {c!r}, not {o!r}" for o, c in alike.items())
    listing = ", ".join(repr(o) for o in missing)
    warnings.warn(
        f"identify: model output{'s' if len(missing) > 1 else ''} {listing} not in "
        f"{'the record' if len(datas) == 1 else 'every record'} (channels: {shown}){hints}; "
        f"fitting {', '.join(fitted)} only (pass "
        "outputs= to choose the outputs)",
        UserWarning,
        stacklevel=4,  # here, identify, its BLAS wrapper, the caller
    )


def warn_holes(datas: Sequence[Any], what: str) -> None:
    """Warn of a hole in a record's stamps (rows dropped, a logger's pause): the model
    flies across it on controls interpolated straight between its ends, unseen by
    the data, and a manoeuvre inside it is lost or bent (a doublet that reversed
    in a hole biased M_alpha by 36 standard errors, success reported). A hole is a
    step longer than the one `aeroid.resample` refuses by default (`GAP_STEPS`)."""
    from ..io.resampling import GAP_STEPS

    for i, d in enumerate(datas):
        steps = np.diff(np.asarray(d.time, dtype=np.float64))
        if steps.size < 2:
            continue
        median = float(np.median(steps))
        k = int(np.argmax(steps))
        if not steps[k] > GAP_STEPS * median:
            continue
        holes = int(np.count_nonzero(steps > GAP_STEPS * median))
        which = "the record" if len(datas) == 1 else f"record {i}"
        warnings.warn(
            f"{what}: {which} has {holes} hole{'s' if holes > 1 else ''} in its time stamps, "
            f"the longest {steps[k]:.4g} s at t = {float(d.time[k]):.6g} s ({steps[k] / median:.0f} "
            "median steps): the model flies across on controls interpolated straight "
            "between the ends, which no sample checks; fit the parts either side as "
            "records of their own (a list of data.window(t0, t1)) or fill the hole",
            UserWarning,
            stacklevel=4,  # here, the function, its BLAS wrapper, the caller
        )


def record_units(model: Any, datas: Sequence[Any], channels: Iterable[str]) -> dict[str, str]:
    """Units of `channels`: the records' own (a channel the records give different
    units is left out), else those the model declares."""
    declared = dict(getattr(model, "channel_units", None) or {})
    out: dict[str, str] = {}
    for name in channels:
        stated = {dict(getattr(d, "units", None) or {}).get(name) or "" for d in datas}
        unit = stated.pop() if len(stated) == 1 else ""
        unit = unit or (declared.get(name, "") if stated <= {""} else "")
        if unit:
            out[name] = unit
    return out
