"""Data compatibility analysis: flight-path reconstruction and sensor-error estimation.

The measured body-axis rates and specific forces drive the rigid-body
kinematics (Klein & Morelli ch. 10, Jategaonkar ch. 10)::

    u' = r v - q w - g sin(theta) + ax
    v' = p w - r u + g cos(theta) sin(phi) + ay
    w' = q u - p v + g cos(theta) cos(phi) + az
    phi'   = p + tan(theta) (q sin(phi) + r cos(phi))
    theta' = q cos(phi) - r sin(phi)
    psi'   = (q sin(phi) + r cos(phi)) / cos(theta)
    h'     = u sin(theta) - v sin(phi) cos(theta) - w cos(phi) cos(theta)

with ``u, v, w`` the body-axis velocity over the ground and ``h`` the altitude
(positive up). The reconstructed airspeed, angles of attack and sideslip
(air-relative, after removing a constant wind given in north-east-down
axes), Euler angles, altitude and, where measured (GPS), north and east ground
speed are compared with the measured ones, and the
sensor errors that make the two agree are estimated by output error: an
`aeroid.Model` of the kinematics and the sensors is fitted with
`aeroid.identify`, the initial velocities and attitudes estimated with it.

Sensor model (every parameter is zero unless given or estimated):

* rate gyros and accelerometers, ``x_m = (1 + k_x) x + b_x`` for ``x`` in
  ``p, q, r, ax, ay, az``;
* air data, attitude, altitude and ground speed,
  ``y_m(t) = (1 + k_y) y(t - tau_y) + b_y`` for ``y`` in
  ``V, alpha, beta, phi, theta, psi, h, vn, ve``: a scale-factor error,
  an offset and a time shift (positive when the channel lags the inertial
  sensors, which are the time reference);
* wind ``w_n, w_e, w_d``: a constant wind (m/s, north-east-down) or zero.
  A constant wind obeys the same kinematics as the air velocity, so air data
  alone cannot tell it from the initial velocity: the horizontal wind needs
  the ground speed ``vn, ve``, the vertical one the altitude.

Time shifts. A shift enters the measurement equation to first order,
``y(t - tau) ~ y(t) - tau y'(t)`` with ``y'`` from the kinematics, so each
``tau_y`` is an ordinary parameter of the fit with an ordinary error bar.
The neglected second-order term would bias the scale factors slightly, so
after a fit the measured channel is shifted by the estimate (a fraction of a
sample, by a Fourier phase ramp on a uniform grid, which keeps white noise
white, else by linear interpolation) and the fit repeated from there, until
the remaining shift is below a twentieth of a sample, where the neglected term
is under a twelfth of the (already small) first-order one even at the Nyquist
frequency. The total shift is the sum; its error bar is that of the last fit.
The first and last samples of a shifted channel are extrapolated (to first
order), as any shift of a finite record must.

Error bars. Output error treats the inputs as exact; the share of the
gyro and accelerometer noise, which the kinematics integrate into wandering
attitude and velocity errors, is added by Monte Carlo (see
`check_compatibility`, Notes).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from .._stats import spread_over_noise
from .._threads import record_warnings, small_blas
from ..errors import IdentificationError
from ..io.data import FlightData, plain, whole_number
from ._compat_arguments import _ANGLE_LIMITS as _ANGLE_LIMITS
from ._compat_arguments import _STAND_IN_SOURCES as _STAND_IN_SOURCES
from ._compat_arguments import LATERAL_INPUT_ERRORS, LATERAL_OUTPUTS, _start_errors
from ._compat_arguments import _channel_map as _channel_map
from ._compat_arguments import _first_values as _first_values
from ._compat_arguments import _fitted_outputs as _fitted_outputs
from ._compat_arguments import _free_states as _free_states
from ._compat_arguments import _measured_state_names as _measured_state_names
from ._compat_arguments import _parameter_values as _parameter_values
from ._compat_arguments import _rewarn as _rewarn
from ._compat_arguments import _start_state as _start_state
from ._compat_arguments import _states_from as _states_from
from ._compat_input_noise import _difference_response as _difference_response
from ._compat_input_noise import _input_noise as _input_noise
from ._compat_input_noise import _input_noise_covariance as _input_noise_covariance
from ._compat_input_noise import (
    _measurement_noise_covariance as _measurement_noise_covariance,
)
from ._compat_input_noise import _shift as _shift
from ._compat_input_noise import _substeps as _substeps
from ._compat_model import _MEASURED as _MEASURED
from ._compat_model import _REQUIRED_OUTPUTS as _REQUIRED_OUTPUTS
from ._compat_model import _WIND as _WIND
from ._compat_model import DEFAULT_ESTIMATE as DEFAULT_ESTIMATE
from ._compat_model import INPUT_CHANNELS as INPUT_CHANNELS
from ._compat_model import OUTPUT_CHANNELS as OUTPUT_CHANNELS
from ._compat_model import SENSOR_PARAMETERS as SENSOR_PARAMETERS
from ._compat_model import STATES as STATES
from ._compat_model import _derivatives as _derivatives
from ._compat_model import _effective as _effective
from ._compat_model import _kinematics as _kinematics
from ._compat_model import _model as _model
from ._compat_model import _rates as _rates
from ._compat_model import _sensors as _sensors
from ._compat_model import _zero_sensor_errors as _zero_sensor_errors
from ._compat_sensors import (
    _off_centre,
    _per_record_x0,
    _pooled_noise,
    _records,
    _same_channels,
    _sensor_nominal,
)
from ._compatibility_record import CompatibilityResult as CompatibilityResult

__all__ = [
    "DEFAULT_ESTIMATE",
    "INPUT_CHANNELS",
    "OUTPUT_CHANNELS",
    "SENSOR_PARAMETERS",
    "CompatibilityResult",
    "check_compatibility",
]

FloatArray = NDArray[np.float64]

_MAX_PASSES = 6


def _moves(x: FloatArray) -> bool:
    """Whether a channel moves beyond its sample-to-sample noise: its spread about the
    mean more than three times the white-noise level its first differences give."""
    return spread_over_noise(x) > 3.0


@overload
def check_compatibility(
    data: FlightData,
    *,
    channels: Mapping[str, str | None] | None = None,
    estimate: Sequence[str] | Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    x0: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None,
    gravity: float = 9.80665,
    error_bars: str = "colored",
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    max_passes: int = 4,
    input_noise: Mapping[str, float] | None = None,
    n_draws: int = 40,
    seed: int = 0,
    outputs: Sequence[str] | None = None,
    measured_states: Sequence[str] = (),
    estimate_x0: bool | Sequence[str] = True,
    scale_about: str = "zero",
    integration: str = "rk4",
    accel_position: Sequence[float] = (0.0, 0.0, 0.0),
    alpha_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    beta_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    sideslip: str = "asin",
) -> CompatibilityResult: ...


@overload
def check_compatibility(
    data: Sequence[FlightData],
    *,
    channels: Mapping[str, str | None] | None = None,
    estimate: Sequence[str] | Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    x0: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None,
    gravity: float = 9.80665,
    error_bars: str = "colored",
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    max_passes: int = 4,
    input_noise: Mapping[str, float] | None = None,
    n_draws: int = 40,
    seed: int = 0,
    outputs: Sequence[str] | None = None,
    measured_states: Sequence[str] = (),
    estimate_x0: bool | Sequence[str] = True,
    scale_about: str = "zero",
    integration: str = "rk4",
    accel_position: Sequence[float] = (0.0, 0.0, 0.0),
    alpha_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    beta_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    sideslip: str = "asin",
) -> tuple[CompatibilityResult, ...]: ...


@small_blas
def check_compatibility(
    data: FlightData | Sequence[FlightData],
    *,
    channels: Mapping[str, str | None] | None = None,
    estimate: Sequence[str] | Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    x0: Mapping[str, float] | Sequence[Mapping[str, float]] | None = None,
    gravity: float = 9.80665,
    error_bars: str = "colored",
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    max_passes: int = 4,
    input_noise: Mapping[str, float] | None = None,
    n_draws: int = 40,
    seed: int = 0,
    outputs: Sequence[str] | None = None,
    measured_states: Sequence[str] = (),
    estimate_x0: bool | Sequence[str] = True,
    scale_about: str = "zero",
    integration: str = "rk4",
    accel_position: Sequence[float] = (0.0, 0.0, 0.0),
    alpha_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    beta_vane_position: Sequence[float] = (0.0, 0.0, 0.0),
    sideslip: str = "asin",
) -> CompatibilityResult | tuple[CompatibilityResult, ...]:
    """Reconstruct the flight path from the inertial sensors and estimate the sensor errors.

    Parameters
    ----------
    data : FlightData or sequence of FlightData
        One record, or several with the same channels fitted together (shared
        sensor errors, each record its own initial state), with body-axis
        rates ``p, q, r`` (rad/s), specific forces
        ``ax, ay, az`` (m/s^2, at `accel_position`), airspeed ``V``
        (m/s), angles ``alpha, beta, phi, theta, psi`` (rad), altitude ``h``
        (m) and ground speed north and east ``vn, ve`` (m/s). ``beta``,
        ``psi``, ``h``, ``vn`` and ``ve`` are optional: whichever the record
        lacks is not fitted. ``phi`` is optional too (a longitudinal
        analysis): without it the bank angle is held at zero. A heading that
        wraps at ±pi is unwrapped.
    channels : mapping of str to str or None, optional
        Data channel of each quantity where it is not named as above
        (``{"alpha": "aoa"}``); None marks an optional output as absent.
    estimate : sequence of str or mapping of str to float, optional
        Sensor parameters to estimate (names in `SENSOR_PARAMETERS`), or a
        mapping name -> start value. Default `DEFAULT_ESTIMATE`: gyro and
        accelerometer biases, offsets of ``V``, ``alpha``, ``beta`` and the
        scale-factor error of ``alpha``. Time shifts are ``tau_<output>``,
        wind ``w_n, w_e, w_d``.
    fixed : mapping of str to float, optional
        Known values of parameters not estimated (a calibrated scale factor,
        a known wind); every other parameter is zero.
    x0 : mapping of str to float, or a sequence of them, optional
        Start values of the initial state (``u, v, w, phi, theta, psi, h``),
        for every record or one mapping per record; default from the first
        sample of the measured channels.
    gravity : float
        Acceleration of gravity in m/s^2.
    error_bars : {"colored", "white"}
        As in `identify`.
    max_iterations : int
        Gauss-Newton iteration limit of each output-error pass.
    tolerance : float
        Convergence threshold on the relative parameter step, as in
        `identify` (whose default is tighter: here a step of a millionth
        moves no estimate by a noticeable fraction of its error bar).
    max_passes : int
        Output-error passes at most when time shifts are estimated (each
        pass re-shifts the channels by the estimated shifts).
    input_noise : mapping of str to float, optional
        Noise standard deviation of the inputs (``p, q, r, ax, ay, az``),
        for the error bars (see Notes); default estimated from each input's
        fourth differences and its quietest spectral band. Zero leaves an
        input out of the correction.
    n_draws : int
        Monte Carlo draws of input noise for that correction, where the
        kinematics do not compile (without JAX; compiled, it is exact), and
        for the residual spectrum that noise leaves (coloured error bars).
    seed : int
        Seed of those draws.
    outputs : sequence of str, optional
        The outputs to fit (default every one the record has); the others
        may still stand in for states (`measured_states`) or give the start.
    measured_states : sequence of str
        States replaced by their measurement throughout (SIDPAC's ``ims``):
        ``u, v, w`` from ``V, alpha, beta`` (and the wind), ``phi``,
        ``theta``, ``psi``, ``h`` from their channels, with the given sensor
        errors removed. Such a state is neither integrated nor estimated; a
        lateral analysis can take ``u, w, theta`` from the data, a
        longitudinal one ``v, phi, psi``.
    estimate_x0 : bool or sequence of str
        True: estimate every initial state the outputs see (``v`` with ``beta``
        or the ground speed, or where ``p`` or ``r`` move beyond their noise;
        ``phi`` with ``phi``, ``psi`` with ``psi`` or the ground speed, ``h``
        with ``h``); False: hold them
        all at the measured values (each channel's start low-passed at 2 Hz
        without leaning on its first sample, as SIDPAC's ``dcmp`` holds it:
        it lags a record that starts moving by a few samples, and a jitter at
        the start still moves it, so estimate where the start is not steady);
        or the names of the states to estimate, the others held. A start
        held at the measured values carries those channels' errors: with
        ``scale_about="zero"`` the errors it is made of (the air-data offsets,
        scales and wind for ``u``, ``v``, ``w``; ``b_phi``, ``k_phi`` for
        ``phi``, and so on) are refused, the default set's included, unless
        those states are estimated or given in `x0`.
    scale_about : {"zero", "initial"}
        What an output's scale factor multiplies: the value itself,
        ``(1 + k) y + b``, or its change from the start value,
        ``(1 + k) (y - y0) + y0 + b`` with ``y0`` the output reconstructed
        from the start state the fit begins from, fixed there (SIDPAC's form;
        the offset ``b`` then is the error at the start of the record). That
        start is the held one, or `x0` where given; with the start estimated,
        it is the first guess (the smoothed measured start, less the known
        errors), not the estimate, which SIDPAC's ``dcmp`` would follow.
    integration : {"rk4", "rk4_hold", "euler"}
        Runge-Kutta with substeps and the inputs interpolated linearly between
        samples (accurate); one Runge-Kutta step per sample with the inputs
        held at its first sample (what SIDPAC's saved data-compatibility
        results were computed with); or one forward-Euler step per sample
        with the inputs held (first order). A held input lags the sampled one
        by half a sample, and the biases absorb what that lag leaves (on an
        error-free simulated record at 25 Hz, a pitch-gyro bias of 2.4e-3
        rad/s): the last two serve to reproduce legacy results only.
    accel_position : sequence of 3 floats
        Where the accelerometers sit, m in body axes from the centre of
        gravity (as `AircraftConstants.accel_position`). They read the
        c.g.'s specific force plus ``w' x r + w x (w x r)``; the first term
        is taken off the record with the angular accelerations ``p_dot,
        q_dot, r_dot`` where the record has them, else the rates
        differentiated (as `coefficients_from_data` does); the second is the
        model's, with the corrected rates. Zero: at the c.g.
    alpha_vane_position, beta_vane_position : sequence of 3 floats
        Where the angle-of-attack and sideslip vanes sit (a nose boom), m in
        body axes from the c.g. A vane sees the air velocity plus the
        rotation's ``w x r``: ``alpha_v = atan((w + p y - q x) / (u + q z -
        r y))``, and ``beta_v`` from ``v + r x - p z`` (Klein & Morelli,
        ch. 10). The airspeed is the c.g.'s; a time shift's first-order term
        takes the rate of the c.g.'s angle (the re-shifted passes leave it
        a remainder under a twentieth of a sample). Zero: at the c.g.
    sideslip : {"asin", "atan"}
        What the sideslip channel reads: ``asin(v / V)`` (the sideslip angle)
        or ``atan(v / u)``, the angle of the air velocity in the body x-y
        plane, which a vane hinged on the body z axis aligns with (a flank
        angle, as Jategaonkar's FVSysID models the ATTAS boom).

    Notes
    -----
    Output error treats the inputs as exact, but gyro and accelerometer
    noise is integrated by the kinematics into slowly wandering attitude and
    velocity errors, which the classical error bars do not see, and which the
    coloured-residual correction sees only in part: the fitted biases and
    scale factors absorb the ramp-like share of a random walk, and the residuals
    keep no trace of it (on SIDPAC's dca demos set up as a known truth, the
    residuals' coloured bars were 0.1-0.8 of the true scatter). Their share is
    added here: the covariance of the linearised estimate shifts
    ``(J' W J)^-1 J' W dy`` that white input noise at the level of the data
    causes through the fitted kinematics. With JAX it is computed exactly to
    first order (the adjoint of the linearised kinematics carries every
    sample's noise to the estimates); without, it is the scatter of `n_draws`
    simulated records of such noise. The level of each input is the smaller
    of its fourth-difference estimate and the quietest band of its spectrum
    (white noise is as strong in every band; vibration near the Nyquist
    frequency is not noise at the low frequencies the kinematics integrate),
    and it is lowered further, by one common factor, where the residuals of
    an output are smaller, beyond chance, than that noise alone would leave
    them. With
    ``error_bars="colored"`` the residuals' coloured correction is taken of
    what their spectrum holds beyond the expected integrated input noise (the
    measurement noise), so the wander is counted once.

    Several records share one covariance of the sensor errors; the
    input-noise share and the coloured correction take each record's noise
    as independent (the input noise levels are pooled over the records).
    ``scale_about="initial"`` takes one record.

    Returns
    -------
    CompatibilityResult or tuple of CompatibilityResult
        One per record, for a sequence: each with the shared sensor errors
        and covariance and its own initial state, reconstruction and
        corrected data.

    Raises
    ------
    ChannelError
        A required channel (the six inputs, ``V``, ``alpha``, ``theta``) is
        missing, or a parameter to estimate belongs to an absent channel.
    DataFormatError
        `data` is not a FlightData or a sequence of them, the records' channels
        differ, a channel holds non-finite values, an angle exceeds its range in
        radians, or the airspeed is not positive.
    IdentificationError
        Unknown parameter names, bad values or options (a sensor position
        not three finite numbers).

    Warns
    -----
    IdentifiabilityWarning
        When the data cannot separate some of the estimated parameters (for
        instance a horizontal wind without ground-speed channels, or the
        air-data offsets from a wind on a straight leg).
    """
    from ._excitation import check_kinematic_channels, refuse_stuck_outputs
    from .identification import identify

    records = _records(data)
    presents = [_channel_map(d, channels) for d in records]
    _same_channels(presents)
    present = presents[0]
    for d, here in zip(records, presents, strict=True):
        check_kinematic_channels(d, here)
    fitted = _fitted_outputs(outputs, present)
    for d, here in zip(records, presents, strict=True):
        refuse_stuck_outputs(d, here, fitted)
    names, values = _parameter_values(
        estimate,
        fixed,
        {**{o: present[o] for o in fitted}, **{c: present[c] for c in INPUT_CHANNELS}},
    )
    held_in = _measured_state_names(measured_states, present)
    lever, geometry = _sensor_nominal(
        accel_position, alpha_vane_position, beta_vane_position, sideslip
    )
    if scale_about not in ("zero", "initial"):
        raise IdentificationError(
            f"scale_about: expected 'zero' or 'initial', got {plain(scale_about)}"
        )
    if scale_about == "initial" and len(records) > 1:
        raise IdentificationError(
            "scale_about: 'initial' pivots each scale factor on one record's start; "
            "with several records use 'zero'"
        )
    if integration not in ("rk4", "rk4_hold", "euler"):
        raise IdentificationError(
            f"integration: expected 'rk4', 'rk4_hold' or 'euler', got {plain(integration)}"
        )
    try:
        g = float(gravity)
    except (TypeError, ValueError):
        g = float("nan")
    if not (math.isfinite(g) and g > 0):
        raise IdentificationError(f"gravity must be a positive number, got {plain(gravity)}")
    max_passes = whole_number(max_passes, "max_passes", IdentificationError)
    n_draws = whole_number(n_draws, "n_draws", IdentificationError, least=2)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise IdentificationError(f"seed: expected an integer, got {plain(seed)}")
    max_passes = min(max_passes, _MAX_PASSES)
    outputs = list(fitted)
    times = [d.time for d in records]
    measures: list[dict[str, FloatArray]] = []
    feeds: list[dict[str, FloatArray]] = []
    for d in records:
        measured = {
            o: np.array(d.channels[present[o]], dtype=np.float64)
            for o in OUTPUT_CHANNELS
            if o in present
        }
        if "psi" in measured:
            measured["psi"] = np.unwrap(measured["psi"])
        measures.append(measured)
        inputs = {c: np.asarray(d.channels[present[c]], dtype=np.float64) for c in INPUT_CHANNELS}
        _off_centre(d, present, inputs, lever)
        feeds.append(inputs)
    substeps = max(
        _substeps(t, np.stack([inputs[c] for c in ("p", "q", "r")]))
        for t, inputs in zip(times, feeds, strict=True)
    )
    how: dict[str, Any] = (
        {"method": "rk4", "substeps": substeps} if integration == "rk4" else {"method": integration}
    )
    levels = [_input_noise(inputs, input_noise) for inputs in feeds]
    sigma_in = levels[0] if len(levels) == 1 else _pooled_noise(levels, [t.size for t in times])
    starts = [
        _start_state(_first_values(t, m), values, given)
        for t, m, given in zip(times, measures, _per_record_x0(x0, len(records)), strict=True)
    ]
    helds = []
    for t, measured in zip(times, measures, strict=True):
        stand_in = _states_from(measured, values)
        helds.append(
            np.column_stack([stand_in[s] if s in held_in else np.zeros(t.size) for s in STATES])
        )
    # the heading is seen by its own channel or through the ground speed; the side
    # velocity by the sideslip, the ground speed, or through p v and r v in the other
    # velocities' rates where the record rolls or yaws (the airspeed holds it only
    # squared: a wings-level record without beta cannot tell its start, and a fit asked
    # for it stalls on that direction)
    lateral = any(_moves(inputs["p"]) or _moves(inputs["r"]) for inputs in feeds)
    blind = [n for n in names if n in LATERAL_INPUT_ERRORS]
    if blind and not lateral and not LATERAL_OUTPUTS & set(outputs):
        raise IdentificationError(
            f"estimate: {blind}: a wings-level record without phi, beta, psi or a ground "
            "speed sees the lateral gyros and accelerometer only through second-order "
            "terms, too weakly to fit; leave them out (a longitudinal analysis)"
        )
    seen = {
        "v": bool({"beta", "vn", "ve"} & set(outputs)) or lateral,
        "phi": "phi" in outputs,
        "psi": bool({"psi", "vn", "ve"} & set(outputs)),
        "h": "h" in outputs,
    }
    free_x0 = [s for s in ("u", "v", "w", "phi", "theta", "psi", "h") if seen.get(s, True)]
    free_x0 = [s for s in _free_states(estimate_x0, free_x0) if s not in held_in]
    if scale_about == "zero":
        names = _start_errors(
            names, estimate is None, free_x0, held_in, x0, len(records), "beta" in present
        )
    masks = tuple((f"m_{s}", 1.0 if s in held_in else 0.0) for s in STATES)
    pivots = {o: 0.0 for o in OUTPUT_CHANNELS}
    if scale_about == "initial":
        x_start = np.array([starts[0][s] for s in STATES])
        c_start = np.concatenate([[feeds[0][c][0] for c in INPUT_CHANNELS], helds[0][0]])
        p_start = {**_zero_sensor_errors(values), "g": g, **dict(masks), **dict(geometry)}
        p_start.update({f"y0_{o}": 0.0 for o in OUTPUT_CHANNELS})
        y_start = _sensors(times[0][0], x_start, c_start, p_start)
        pivots = {o: float(y_start[j]) for j, o in enumerate(OUTPUT_CHANNELS)}
    shifted_names = [n for n in names if n.startswith("tau_")]
    applied = {n: 0.0 for n in shifted_names}
    current = dict(values)
    passes = 0
    fit: Any = None
    nominal = (("g", g), *masks, *((f"y0_{o}", v) for o, v in pivots.items()), *geometry)
    model = _model((*nominal, *sorted(values.items())))
    while True:
        passes += 1
        now = []
        for t, inputs, held, measured in zip(times, feeds, helds, measures, strict=True):
            channels_now = {c: inputs[c] for c in INPUT_CHANNELS}
            channels_now.update({m: held[:, j] for j, m in enumerate(_MEASURED)})
            for o in outputs:
                channels_now[o] = _shift(t, measured[o], applied.get(f"tau_{o}", 0.0))
            now.append(FlightData(t, channels_now))
        guess = {n: current[n] - applied.get(n, 0.0) for n in names}
        with record_warnings() as caught:
            fit = identify(
                model,
                now[0] if len(now) == 1 else now,
                guess,
                outputs=outputs,
                x0=starts[0] if len(now) == 1 else starts,
                estimate_x0=free_x0,
                error_bars=error_bars,
                max_iterations=max_iterations,
                tolerance=tolerance,
                simulate_options=how,
            )
        _rewarn(caught, names)
        current.update({n: fit.parameters[n] + applied.get(n, 0.0) for n in names})
        starts = [dict(s) for s in fit.initial_states]
        if not shifted_names or passes >= max_passes or not fit.success:
            break
        # Another pass only while the remaining shift is worth a re-interpolation: the
        # first-order term neglects (omega tau)^2 / 2, and below a twentieth of a sample
        # that is under a twelfth of the first-order term even at the Nyquist frequency.
        step = max(abs(fit.parameters[n]) for n in shifted_names)
        if step < 0.05 * min(float(np.min(np.diff(t))) for t in times):
            break
        applied = {n: current[n] for n in shifted_names}
    pieces = [
        (t, np.column_stack([*(inputs[c] for c in INPUT_CHANNELS), held]))
        for t, inputs, held in zip(times, feeds, helds, strict=True)
    ]
    out_idx = [OUTPUT_CHANNELS.index(o) for o in outputs]
    extra = _input_noise_covariance(
        model,
        pieces,
        fit,
        names,
        free_x0,
        out_idx,
        sigma_in,
        n_draws=n_draws,
        seed=int(seed),
        substeps=substeps,
    )
    base: tuple[FloatArray, FloatArray] | None = None
    if fit.error_bars == "colored":
        split = _measurement_noise_covariance(
            model,
            pieces,
            fit,
            names,
            free_x0,
            out_idx,
            sigma_in,
            n_draws=n_draws,
            seed=int(seed),
            substeps=substeps,
        )
        if split is not None:
            allowed, cov_noise, nu_noise = split
            extra = allowed * extra
            sigma_in = {c: v * math.sqrt(allowed) for c, v in sigma_in.items()}
            base = (cov_noise, nu_noise)
    results = tuple(
        _result(
            model,
            d,
            present,
            outputs,
            measures[r],
            {c: np.asarray(d.channels[present[c]], dtype=np.float64) for c in INPUT_CHANNELS},
            pieces[r][1],
            names,
            current,
            fit,
            extra,
            sigma_in,
            passes,
            g,
            how,
            tuple(s for s in STATES if s in held_in),
            {o: pivots[o] for o in outputs},
            base,
            record=r,
            several=len(records) > 1,
        )
        for r, d in enumerate(records)
    )
    return results[0] if isinstance(data, FlightData) else results


def _result(
    model: Any,
    data: FlightData,
    present: Mapping[str, str],
    outputs: list[str],
    measured: Mapping[str, FloatArray],
    inputs: Mapping[str, FloatArray],
    controls: FloatArray,
    names: list[str],
    values: Mapping[str, float],
    fit: Any,
    extra: FloatArray,
    sigma_in: Mapping[str, float],
    passes: int,
    g: float,
    how: Mapping[str, Any],
    held: tuple[str, ...],
    pivots: Mapping[str, float],
    base: tuple[FloatArray, FloatArray] | None = None,
    *,
    record: int = 0,
    several: bool = False,
) -> CompatibilityResult:
    t = data.time
    x0 = dict(fit.initial_states[record])
    # the fitted model itself (and whatever was compiled for it), free of output errors
    sim = model.simulate(t, controls, x0, _zero_sensor_errors(values), **how)
    true_out = np.asarray(sim.outputs)
    reconstructed = np.empty((t.size, len(outputs)))
    raw = np.empty((t.size, len(outputs)))
    corrected: dict[str, FloatArray] = {}
    for j, o in enumerate(outputs):
        k = OUTPUT_CHANNELS.index(o)
        b, s, tau = values[f"b_{o}"], values[f"k_{o}"], values[f"tau_{o}"]
        y0 = pivots[o]
        reconstructed[:, j] = (1.0 + s) * (_shift(t, true_out[:, k], -tau) - y0) + y0 + b
        raw[:, j] = data.channels[present[o]]
        fixed_y = (_shift(t, measured[o], tau) - b - y0) / (1.0 + s) + y0
        if o == "psi":  # back on the record's own branch of the heading
            fixed_y = fixed_y + (raw[:, j] - measured[o])
            reconstructed[:, j] = reconstructed[:, j] + (raw[:, j] - measured[o])
        corrected[present[o]] = fixed_y
    for c in INPUT_CHANNELS:
        corrected[present[c]] = (inputs[c] - values[f"b_{c}"]) / (1.0 + values[f"k_{c}"])
    dof = {n: float(fit.degrees_of_freedom.get(n, np.inf)) for n in (*names, *fit.extra_stderr)}
    # what the fit could not separate keeps its infinite bars whatever is added to them
    null = ~np.isfinite(np.diag(np.asarray(fit.covariance)))
    if base is None:
        cov = np.asarray(fit.covariance) + extra
    else:
        # the measurement-noise part is unbiased but noisy, possibly indefinite:
        # only the sum need be a covariance
        total = base[0] + extra
        total[null, :] = 0.0
        total[:, null] = 0.0
        w, v = np.linalg.eigh(0.5 * (total + total.T))
        cov = (v * np.maximum(w, 0.0)) @ v.T
        # Satterthwaite: only the measurement-noise part is estimated from a finite band
        # (none where the measurement noise adds nothing: the rest is not estimated)
        part = np.abs(np.diag(base[0]))
        with np.errstate(divide="ignore", invalid="ignore"):
            nu = np.where(part > 0, base[1] * (np.diag(cov) / part) ** 2, np.inf)
        dof.update({n: float(nu[j]) for j, n in enumerate(names)})
    cov[null, :] = np.nan
    cov[:, null] = np.nan
    cov[null, null] = np.inf
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    se[~np.isfinite(np.diag(cov))] = np.inf
    stderr = {n: float(se[j]) for j, n in enumerate(names)}
    if several:  # this record's initial states among every record's
        mine = f"x0[{record}]."
        x0_se = {
            k[len(mine) :]: float(v) for k, v in fit.extra_stderr.items() if k.startswith(mine)
        }
    else:
        x0_se = {s: float(v) for k, v in fit.extra_stderr.items() for s in [k.partition(".")[2]]}
    return CompatibilityResult(
        corrected=data.with_channels(corrected),
        parameters={n: float(values[n]) for n in names},
        stderr=stderr,
        covariance=cov,
        parameter_names=tuple(names),
        fixed={n: float(v) for n, v in values.items() if n not in names},
        initial_states=x0,
        initial_state_stderr=x0_se,
        time=t,
        output_names=tuple(outputs),
        channels={k: present[k] for k in (*INPUT_CHANNELS, *outputs)},
        measured=raw,
        reconstructed=reconstructed,
        states=np.asarray(sim.states),
        true_outputs=true_out,
        state_names=STATES,
        error_bars=fit.error_bars,
        identifiable=fit.identifiable,
        unidentifiable=fit.unidentifiable,
        success=fit.success,
        message=fit.message,
        n_passes=passes,
        gravity=g,
        input_noise=sigma_in,
        measured_states=held,
        degrees_of_freedom=dof,
        scale_pivots=pivots,
    )
