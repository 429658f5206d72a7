"""Parameter identification: `identify` (its record, `IdentificationResult`, is re-exported)."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._threads import record_warnings, replay_warnings, small_blas
from ..errors import AeroidError, IdentificationError
from ..io.data import (
    FlightData,
    as_float,
    check_symmetric,
    delay_starts,
    fingerprint,
    measured_start,
    plain,
    whole_number,
)
from ._identification_record import IdentificationResult
from ._identification_start import (
    _as_list,
    _equation_error_start,
    _select,
    _x0_per_manoeuvre,
    _x0_values,
    names_and_initial,
)
from ._identification_start import _is_state_entry as _is_state_entry
from ._state_biases import (
    _bias_choice,
    _bias_parameters_out,
    _state_biases_out,
    _with_bias_parameters,
    _with_state_biases,
)

__all__ = ["IdentificationResult", "identify"]

FloatArray = NDArray[np.float64]


_METHODS = ("output_error", "filter_error")
_STARTS = ("given", "equation_error")
_GRADIENTS = ("auto", "fd", "jax")
_ERROR_BARS = ("colored", "white")


def _weight_variances(weights: Any, outputs: list[str]) -> FloatArray:
    """Fixed noise variances per fitted output from `weights` (see `identify`)."""
    n = len(outputs)
    if isinstance(weights, Mapping):
        unknown = sorted(set(weights) - set(outputs))
        if unknown:
            raise IdentificationError(
                f"weights: unknown outputs {unknown}; fitted outputs: {outputs}"
            )
        missing = [o for o in outputs if o not in weights]
        if missing:  # a weight of one would be as arbitrary as the unit it is read in
            raise IdentificationError(
                f"weights: no weight for fitted output(s) {missing}; give every fitted "
                "output's, or leave weights out to estimate them"
            )
        w = np.empty(n)
        for k, o in enumerate(outputs):
            try:
                w[k] = float(weights[o])
            except (TypeError, ValueError):
                raise IdentificationError(
                    f"weights[{o!r}]: expected a number, got {plain(weights[o])}"
                ) from None
        if np.any(w <= 0) or not np.all(np.isfinite(w)):
            raise IdentificationError("weights: every weight must be positive and finite")
        return 1.0 / w
    r: FloatArray | None
    try:
        r = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError):
        r = None
    if r is None or r.shape != (n, n):
        shape = f"shape {r.shape}" if r is not None else plain(weights)
        raise IdentificationError(
            f"weights: expected a mapping of output -> weight or a ({n}, {n}) noise "
            f"covariance, got {shape}"
        )
    if not np.all(np.isfinite(r)):
        raise IdentificationError("weights: the noise covariance holds NaN or infinite values")
    check_symmetric(r, outputs, "weights", IdentificationError)
    scale = float(np.max(np.abs(r)))
    low = float(np.linalg.eigvalsh(0.5 * (r + r.T))[0])
    if not low > 1e-12 * scale:
        # A zero variance would be an infinite weight: the fit needs positive definite.
        raise IdentificationError(
            f"weights: the noise covariance must be positive definite; its smallest "
            f"eigenvalue is {low:.6g} (order {outputs})"
        )
    if np.any(r != np.diag(np.diag(r))):
        # Only variances enter the fit; dropping correlations silently would mislead.
        raise IdentificationError(
            "weights: correlated measurement noise is not supported; give a diagonal noise "
            f"covariance (order {outputs}) or a mapping of output -> weight"
        )
    return np.diag(r).copy()


@small_blas
def identify(
    model: Any,
    data: FlightData | Sequence[FlightData],
    parameters: Sequence[str] | Mapping[str, float],
    *,
    method: str = "output_error",
    gradient: str = "auto",
    outputs: Sequence[str] | None = None,
    x0: Any = None,
    estimate_x0: bool | Sequence[str] | None = None,
    estimate_bias: bool | Sequence[str] | Mapping[str, Any] = False,
    weights: Mapping[str, float] | Any = None,
    error_bars: str | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-8,
    simulate_options: Mapping[str, Any] | None = None,
    process_noise: Mapping[str, float] | Any = None,
    measurement_noise: Mapping[str, float] | Any = None,
    filter_options: Mapping[str, Any] | None = None,
    estimate_process_noise: bool | Sequence[str] = False,
    bounds: Mapping[str, Any] | None = None,
    time_delays: str | Sequence[str] | Mapping[str, float] | None = None,
    start: str = "given",
) -> IdentificationResult:
    """Estimate model parameters from flight data.

    Parameters
    ----------
    model : Model or SimulatorModel
        The vehicle model. Stepped simulators work with output error and
        finite differences only.
    data : FlightData or sequence of FlightData
        One manoeuvre, or several fitted together with shared parameters and
        their own initial states and biases.
    parameters : sequence of str or mapping of str to float
        Names to estimate (starting from the model's nominal values) or a dict
        of name to initial guess. Every model parameter not named here is held
        fixed at its nominal value (``model.parameters``) and reported in
        ``result.fixed``; to fix a parameter at another value, build the model
        with that nominal value. Output error may name none when it estimates
        initial states, biases or time delays: only those are fitted, the model
        held whole (how `validate` starts a prediction with
        ``holdout_start="estimated"``).
    method : {"output_error", "filter_error"}
        Maximum-likelihood output error, or filter error (fits on whitened
        Kalman-filter innovations; needs `process_noise`).
    gradient : {"auto", "fd", "jax"}
        ``"auto"``: exact forward-mode sensitivities of a compiled RK4 when the
        model's numpy-written functions compile with JAX (nonlinear models),
        else finite differences. ``"fd"``: finite-difference sensitivities
        (batched). ``"jax"``: exact JAX Jacobians of functions written with
        jax.numpy.
    outputs : sequence of str, optional
        Model outputs to fit; default every model output present in the data.
    x0 : mapping, array or list of them, optional
        Initial state: a mapping of state to value or a vector of ``n_states``
        numbers, used for every manoeuvre; or a list (or 2-D array) of one
        such initial state per manoeuvre (``None`` entries for "measured").
        A flat list of numbers is always read as one state vector shared by
        every manoeuvre, even when its length also equals the number of
        manoeuvres (``x0=[p0, r0]`` for two manoeuvres of a two-state model
        is one state); only for a one-state model does a flat list of one
        number per manoeuvre give each manoeuvre its own. Default: the
        measured states at the first sample and zero for unmeasured ones
        (the start of those `estimate_x0` estimates).
    estimate_x0 : bool, sequence of str or None
        Estimate the initial value of these states (all when True), per
        manoeuvre. None (default): output error estimates the initial values
        of the states it fits as outputs when `x0` is not given (with a
        `Model` and ``gradient`` ``"auto"`` or ``"fd"``); other states, and
        filter error, start from the first samples. Held at a noisy first
        sample, a slowly decaying mode's wrong transient costs more than the
        data can pay back, and the fit moves the damping and the control
        power to shorten it: on a lateral model sampled at 50 Hz that bias
        reached 1.4 standard errors and coverage of 95 % intervals fell to
        0.53. The first sample is data like any other, so estimating the
        state from all of them is the maximum-likelihood choice (Jategaonkar,
        ch. 4); False holds them, as SIDPAC's demos do (at smoothed values
        given as `x0`).
    estimate_bias : bool, sequence of str or mapping of str to str
        Estimate constant biases, per manoeuvre. True or a list of names:
        measurement biases on those outputs (all fitted outputs when True).
        A mapping ``name -> "output"`` or ``"state"`` (or a list of both)
        chooses per name: ``"state"`` adds an estimated constant to that
        state's derivative (``x_dot = f(t, x, u, p) + b``), as lateral models
        use for unmodelled trims. State biases need a `Model` (not
        ``gradient="jax"``); they are reported in ``result.biases[i]`` under
        ``"state.<name>"`` and in `extra_stderr` as ``"bias[i].state.<name>"``.
        Filter error estimates both kinds the same way, as unknowns of its
        iteration with bars from its information matrix (Jategaonkar, ch. 5).
        Given the result and a record it was fitted to, `validate` and
        `sensitivities` replay the model with both kinds (and from the fit's
        initial state); `filter_states`, `frequency_response` and `infer`
        start from that state without them.
    weights : mapping of str to float or ndarray, optional
        Fixed output weights (inverse noise variances, positive, one for every
        fitted output) or a diagonal, positive definite noise covariance (correlated noise is refused, not
        dropped). Default: the noise covariance is estimated from the
        residuals at every iteration (maximum likelihood).
    error_bars : {"colored", "white"}, optional
        Standard errors corrected for coloured residuals from their spectrum
        (output error's default; where the residuals show no colour, a
        lag-one correlation below 3/sqrt(N), that is the classical bound and
        the summary says so), or the classical Cramér–Rao values. Filter
        error's innovations are white by construction: its bars are its Fisher
        information's, and an explicit "colored" there warns that it changes nothing. Output error with the
        noise covariance estimated (no `weights`) also carries the scatter that
        estimating it adds to the estimates (`aeroid._weighting`).
    max_iterations : int
        Gauss–Newton iteration limit (a positive integer); hitting it returns
        a result flagged ``success=False`` with a warning, unless the last
        allowed iteration converged (a higher limit would stop there too).
    tolerance : float
        Convergence threshold on the relative parameter step.
    simulate_options : mapping, optional
        Integrator options (``method``, ``substeps``, ``rtol``, ``atol``,
        ``control_interpolation`` as in `aeroid.Model.simulate`: with the
        cubic, the compiled sensitivities as with straight lines, and central
        differences of the simulation where a first fit would solve Newton's
        method over the record, which holds straight lines).
        With ``gradient="jax"`` (a fixed-step RK4 rollout) only ``substeps``
        (RK4 steps per sample interval; default chosen from the dynamics'
        stiffness) and ``control_interpolation`` apply; the others are refused.
    process_noise, measurement_noise, filter_options, estimate_process_noise
        Filter-error settings: continuous process-noise PSD per state,
        measurement-noise variances per output, filter options (among them
        ``control_interpolation``, as in `filter_states`), and whether to
        estimate the process-noise intensities (each started, where
        `process_noise` gives none, from what the state equations at the
        starting values leave unexplained in the state's measured channel).
    bounds : mapping of str to (float or None, float or None), optional
        Lower and upper bounds on estimated parameters, ``None`` (or
        ``-inf``/``inf``) for an open side, e.g. ``{"M_q": (None, 0.0)}``.
        The fit is a bounded Gauss–Newton (output error) or
        Levenberg–Marquardt (filter error): a parameter at a bound whose step
        would leave the box is held there and dropped from that step's normal
        equations (the active set), and steps are projected onto the box, so
        every iterate satisfies the bounds. A parameter that ends at a bound
        is listed in ``result.active_bounds``; its standard error is reported
        as 0 and the other parameters' covariance is conditional on the bound
        (computed with it held fixed). The initial value of a bounded
        parameter must lie inside its bounds (a bound itself is allowed).
    time_delays : str, sequence of str or mapping of str to float, optional
        Controls whose pure time delay to estimate (output error and filter
        error), or a dict of control name to start value in s (default start
        0). The control is delayed on the data grid: its values
        ``u(t_k - tau)`` at the sample times, read off the record's
        piecewise-linear control, are joined between samples as any control
        is (straight lines unless ``control_interpolation`` says otherwise),
        so a delay may be a fraction of a sample. A whole-sample delay is
        exactly ``u(t - tau)``; a fractional one is a linear-interpolation
        fractional-delay filter, exact at the sample times, cutting the
        corners the delayed control has at ``t_j + tau`` (a slight low-pass):
        on noise-free records made with the exact ``u(t - tau)`` it comes
        back within about 1 % of the sample interval. Each delay is reported as parameter ``"tau_<control>"`` in
        `parameters`, `stderr`, `covariance` and `summary`, and in
        ``result.time_delays``; it is shared by every manoeuvre.
    start : {"given", "equation_error"}
        ``"given"``: start from `parameters`. ``"equation_error"``: first
        regress each state equation on the measured states and controls
        (Klein & Morelli's equation error): the response is the smoothed
        derivative of each measured state (a channel ``<state>_dot`` when the
        data carry one, else `aeroid.io.smoothing.differentiate` of the state on
        a uniform grid; all states must be measured), the regressors the
        columns ``df/dp`` of the dynamics, and the least-squares estimates
        start the output-error fit. Needs dynamics linear in the estimated
        parameters (checked; an error names those that are not). Parameters
        that do not enter the state equations, or that the regression cannot
        separate, keep their given start.

    Returns
    -------
    IdentificationResult

    Raises
    ------
    IdentificationError
        Bad arguments (among them bounds on a name that is not an estimated
        parameter, a lower bound not below the upper one, a NaN bound, or an
        initial value outside its bounds), incompatible options, no more
        measurements (samples
        times outputs, over all records) than unknowns (parameters, estimated
        initial states, biases and noise intensities), or a model that cannot
        be simulated, or a cost that is not finite, at the initial guess.
    ChannelError
        A control or output the fit needs is missing from the data.

    Warns
    -----
    IdentifiabilityWarning
        When the data cannot separate some parameters (the result is flagged).
    UserWarning
        When the iteration limit is reached, or the fit ends with a non-finite
        cost or estimates; the result is flagged ``success=False``.
    """
    from .._units import require_model_units
    from ..models.model import (
        MAX_SUBSTEPS,
        SIMULATE_OPTION_KEYS,
        SimulatorModel,
        check_simulate_options,
        given_values,
        require_model,
        require_states,
    )
    from ._excitation import held_controls, warn_holes, warn_missing_outputs

    require_model(model, IdentificationError)
    if method not in _METHODS:
        raise IdentificationError(f"method {method!r} is unknown; choose one of {list(_METHODS)}")
    if gradient not in _GRADIENTS:
        raise IdentificationError(
            f"gradient {gradient!r} is unknown; choose one of {list(_GRADIENTS)}"
        )
    if method == "filter_error" and error_bars == "colored":
        warnings.warn(
            "error_bars='colored' does not apply to filter error: its innovations are white "
            "by construction, and its bars are its Fisher information's (error_bars='white')",
            UserWarning,
            stacklevel=3,  # identify, its BLAS wrapper, the caller
        )
    if error_bars is None:
        error_bars = "colored"
    if error_bars not in _ERROR_BARS:
        raise IdentificationError(
            f"error_bars {error_bars!r} is unknown; choose one of {list(_ERROR_BARS)}"
        )
    max_iterations = whole_number(max_iterations, "max_iterations", IdentificationError)
    # a bool or text is no tolerance; an infinite one would stop at the initial guess
    tol = as_float(tolerance)
    if tol is None or not (tol > 0 and np.isfinite(tol)):
        raise IdentificationError(f"tolerance must be positive and finite, got {plain(tolerance)}")
    datas = _as_list(data)
    names, initial = names_and_initial(model, parameters, allow_empty=True)
    if not names and not (
        (method == "output_error" and (estimate_x0 or estimate_bias or time_delays))
        or (method == "filter_error" and estimate_bias)
    ):
        raise IdentificationError(
            "parameters: name at least one parameter to estimate (output error may name "
            "none when it estimates initial states, biases or time delays)"
        )
    if start not in _STARTS:
        raise IdentificationError(f"start {start!r} is unknown; choose one of {list(_STARTS)}")
    delays = _time_delays(time_delays, model)
    shortest = min(float(d.time[-1] - d.time[0]) for d in datas)
    for c, tau in delays.items():
        if abs(tau) >= shortest:  # the control would be held at one end throughout
            raise IdentificationError(
                f"time_delays[{c!r}]: a start of {tau:g} s shifts the control off the "
                f"{shortest:g} s record"
            )
    is_simulator = not hasattr(model, "simulate_batch") and isinstance(model, SimulatorModel)
    model_outputs = list(model.outputs)
    if outputs is None:
        fit_outputs = [o for o in model_outputs if all(o in d for d in datas)]
        if not fit_outputs:
            datas[0].require(model_outputs[:1], role="output")
        warn_missing_outputs(model, datas, fit_outputs)
    else:
        # one name, not its letters
        chosen = [outputs] if isinstance(outputs, str) else list(outputs)
        fit_outputs = _select(chosen, model_outputs, "outputs")
        if not fit_outputs:
            raise IdentificationError("outputs: name at least one output to fit")
    for d in datas:
        d.require(model.controls, role="control")
        d.require(fit_outputs, role="output")
    warn_holes(datas, "identify")
    states = list(getattr(model, "states", ()))
    if given_values(x0):
        require_states(
            model, IdentificationError, "x0", "there is no initial state to give; leave x0 unset"
        )
    if estimate_x0:
        require_states(
            model, IdentificationError, "estimate_x0", "there is no initial state to estimate"
        )
    box = _check_bounds(bounds, model, names, initial)
    x0_list = _x0_per_manoeuvre(x0, len(datas), states)
    x0_dicts: list[dict[str, float]] = []
    for d, xi in zip(datas, x0_list, strict=True):
        if xi is None:
            x0_dicts.append(measured_start(d, states))
        else:
            x0_dicts.append(_x0_values(xi, states))
    if start == "equation_error":
        initial = _equation_error_start(model, datas, names, initial, delays, box)
    if method == "filter_error":
        if weights is not None:
            raise IdentificationError(
                "weights do not apply to filter error; give measurement_noise (variances) instead"
            )
        if simulate_options:
            raise IdentificationError(
                "simulate_options do not apply to filter error; pass integrator settings in "
                "filter_options (e.g. {'substeps': 4})"
            )
        if is_simulator or not hasattr(model, "dynamics"):
            raise IdentificationError(
                "filter error needs a continuous dynamics callable; a stepped simulator "
                "works with method='output_error'"
            )
        require_states(
            model,
            IdentificationError,
            "method='filter_error'",
            "there is no state for its Kalman filter to correct; use method='output_error'",
        )
        if gradient == "jax":
            raise IdentificationError("gradient='jax' is available for output error only")
        if estimate_x0:
            raise IdentificationError(
                "estimate_x0 applies to method='output_error' only; the filter-error "
                "method corrects the states through its Kalman filter"
            )
        sel_bias, state_bias = _bias_choice(estimate_bias, fit_outputs, states)
        if not (names or sel_bias or state_bias):
            raise IdentificationError("parameters: none named, and estimate_bias selects nothing")
        if process_noise is None and not estimate_process_noise:
            raise IdentificationError(
                "filter error needs process_noise (continuous PSD per state) or "
                "estimate_process_noise=True"
            )
        # Unknown names are reported by the filter-error code; count the valid ones.
        noise_states = _select(
            estimate_process_noise, states, "estimate_process_noise", strict=False
        )
        _check_data_count(
            datas,
            fit_outputs,
            {
                "parameters": len(names),
                "time delays": len(delays),
                "process-noise intensities": len(noise_states),
                "measurement-noise variances": len(fit_outputs) if measurement_noise is None else 0,
                "biases": (len(sel_bias) + len(state_bias)) * len(datas),
            },
        )
        held = held_controls(datas, model.controls)
        require_model_units(model, datas, [*fit_outputs, *model.controls])
        from ._filter_error import identify_filter_error

        # the biases are parameters of a wrapped model (one per manoeuvre each), fitted
        # and given bars by the filter error's own iteration and information matrix
        fe_model, fe_datas, biased, bias_names = (
            _with_bias_parameters(model, datas, sel_bias, state_bias)
            if sel_bias or state_bias
            else (model, datas, [], [])
        )
        fitted = identify_filter_error(
            fe_model,
            fe_datas,
            [*names, *bias_names],
            initial,
            outputs=fit_outputs,
            process_noise=process_noise,
            measurement_noise=measurement_noise,
            filter_options=filter_options,
            estimate_process_noise=estimate_process_noise,
            # a manoeuvre without a given start reads it from its record (the filter's
            # prior then that channel's noise, not a known start's none)
            x0=None
            if x0 is None
            else [None if xi is None else xd for xi, xd in zip(x0_list, x0_dicts, strict=True)],
            max_iterations=max_iterations,
            tolerance=tol,
            bounds=box,
            time_delays=delays,
        )
        if bias_names:
            fitted = _bias_parameters_out(fitted, bias_names, biased)
        return _finish(fitted, datas, model, held)
    if (
        process_noise is not None
        or measurement_noise is not None
        or filter_options
        or estimate_process_noise
    ):
        raise IdentificationError(
            "process_noise, measurement_noise, filter_options and estimate_process_noise "
            "apply to method='filter_error' only"
        )
    if gradient == "jax" and (is_simulator or not hasattr(model, "dynamics")):
        raise IdentificationError(
            "gradient='jax' needs a continuous dynamics callable written with jax.numpy; "
            "use gradient='fd' for a stepped simulator"
        )
    if simulate_options is not None and not isinstance(simulate_options, Mapping):
        raise IdentificationError(
            f"simulate_options: expected a dict, got {type(simulate_options).__name__}"
        )
    opts = dict(simulate_options or {})
    from ._output_error import fit_output_error

    unknown_opts = sorted(set(opts) - set(SIMULATE_OPTION_KEYS))
    if unknown_opts:
        raise IdentificationError(
            f"simulate_options: unknown keys {unknown_opts}; valid keys are {list(SIMULATE_OPTION_KEYS)}"
        )
    if gradient == "jax":
        # The JAX path is one fixed-step RK4 rollout: its substep count and the controls
        # between samples apply.
        refused = sorted(set(opts) - {"substeps", "control_interpolation"})
        if refused:
            raise IdentificationError(
                f"simulate_options {refused} do not apply to gradient='jax', whose simulation "
                "is a fixed-step RK4 rollout; only 'substeps' and 'control_interpolation' do "
                "(or use gradient='fd')"
            )
        if opts.get("substeps") is None:
            opts.pop("substeps", None)
        else:
            opts["substeps"] = whole_number(
                opts["substeps"], "simulate_options['substeps']", IdentificationError
            )
            if opts["substeps"] > MAX_SUBSTEPS:  # the rollout would not fit in memory
                raise IdentificationError(
                    f"simulate_options['substeps'] must be at most {MAX_SUBSTEPS}, "
                    f"got {opts['substeps']}"
                )
    elif not is_simulator:
        opts.setdefault("method", "auto")
        # here, not deep in the first simulation, and naming the option
        check_simulate_options(opts, model, IdentificationError)
    if estimate_x0 is None:
        # the states fitted as outputs: their first samples are data like the rest and
        # pin their initial values (a state only measured, or seen through others,
        # starts from its first sample as before)
        auto = x0 is None and not is_simulator and gradient != "jax"
        sel_x0 = [s for s in states if auto and s in fit_outputs]
    else:
        sel_x0 = _select(estimate_x0, states, "estimate_x0")
    if is_simulator and estimate_x0 is True:  # (state names it would refuse as unknown)
        raise IdentificationError(
            "estimate_x0: a SimulatorModel starts where its simulator does (it exposes no "
            "states); initial states are estimated for an aeroid.Model"
        )
    if sel_x0 and (is_simulator or gradient == "jax"):
        raise IdentificationError(
            f"estimate_x0 {sel_x0}: initial states are estimated for an aeroid.Model with "
            "gradient='auto' or 'fd'"
            + (" (gradient='jax' differentiates the parameters only)" if not is_simulator else "")
        )
    sel_bias, state_bias = _bias_choice(estimate_bias, fit_outputs, states)
    if state_bias and (is_simulator or not hasattr(model, "dynamics") or gradient == "jax"):
        raise IdentificationError(
            f"estimate_bias: biases on the state equations {state_bias} need a Model (a "
            "dynamics callable), and gradient='auto' or 'fd'"
        )
    if not (names or delays or sel_x0 or sel_bias or state_bias):
        raise IdentificationError(
            "parameters: none named, and estimate_x0 and estimate_bias select nothing"
        )
    w_arr = None if weights is None else _weight_variances(weights, fit_outputs)
    _check_data_count(
        datas,
        fit_outputs,
        {
            "parameters": len(names),
            "time delays": len(delays),
            "initial states": len(sel_x0) * len(datas),
            "biases": (len(sel_bias) + len(state_bias)) * len(datas),
        },
    )
    held = held_controls(datas, model.controls)
    require_model_units(model, datas, [*fit_outputs, *model.controls])
    fit_model, bias_states = _with_state_biases(model, state_bias) if state_bias else (model, [])

    # a partial, not a closure: the fit's warnings count their frames up to the caller
    fit = partial(
        fit_output_error,
        fit_model,
        datas,
        names,
        outputs=fit_outputs,
        estimate_x0=sel_x0 + bias_states,
        estimate_bias=sel_bias,
        weights=w_arr,
        error_bars=error_bars,
        max_iterations=max_iterations,
        tolerance=tol,
        gradient=gradient,
        bounds=box,
    )
    with record_warnings() as first_warnings:
        fitted = fit(initial, x0=x0_dicts, simulate_options=opts, delays=delays)
        finer = _path_substeps(fit_model, datas, fitted, opts)
    if finer is None:
        replay_warnings(first_warnings)
    else:
        # the integrator's step came from the modes at the start, and the fitted
        # paths stiffen beyond it: fit again, from here, with the step they need (the
        # first fit's warnings are about a fit that is not the result: dropped)
        fitted = fit(
            {n: fitted.parameters[n] for n in names},
            x0=[dict(x) for x in fitted.initial_states] if fitted.initial_states else x0_dicts,
            simulate_options={**opts, "substeps": finer},
            delays={c: fitted.time_delays.get(c, v) for c, v in delays.items()},
        )
    if state_bias:
        fitted = _state_biases_out(fitted, bias_states, state_bias)
    return _finish(fitted, datas, model, held)


def _path_substeps(
    model: Any, datas: list[FlightData], fitted: IdentificationResult, opts: Mapping[str, Any]
) -> int | None:
    """The RK4 substeps the fitted paths ask for where that is more than the rule at
    their start gave the fit (`integration.trajectory_substeps`), else None."""
    from ..models import integration as _integrate
    from ..models.model import Model, delayed_controls

    automatic = opts.get("substeps") is None and opts.get("method", "auto") in ("auto", "rk4")
    # a failed fit too: a step too coarse for the path makes the cost too rough to descend
    if not (automatic and isinstance(model, Model)):
        return None
    if model.linear is True or len(fitted.initial_states) != len(datas):
        return None  # exact on the grid: no step to choose
    values = {n: v for n, v in fitted.parameters.items() if n in model.parameters}
    member = {k: np.array([float(values.get(k, v))]) for k, v in model.parameters.items()}
    f = model._dynamics_batch
    need = 0
    for d, start in zip(datas, fitted.initial_states, strict=True):
        try:
            sim = model.simulate_data(
                delayed_controls(fitted, d), x0=dict(start), parameters=values, **opts
            )
        except AeroidError:
            return None  # the fit's own simulation reported what there is to say
        u = np.asarray(sim.controls, dtype=np.float64)
        x0 = np.asarray(sim.states[0], dtype=np.float64)[:, None]
        first = _integrate.auto_substeps(f, sim.time, x0, u[None], member)
        path = _integrate.trajectory_substeps(f, sim.time, np.asarray(sim.states), u, member)
        if path > first:
            need = max(need, path)
    return need or None


def _time_delays(option: Any, model: Any) -> dict[str, float]:
    """Control name -> start value (s) of each delay to estimate (see `identify`)."""
    if option is None or option is False:
        return {}
    controls = list(model.controls)

    def unknown(name: str) -> IdentificationError:
        return IdentificationError(
            f"time_delays: {name!r} is not a control of model "
            f"{getattr(model, 'name', '')!r}; its controls are {controls}"
        )

    out = delay_starts(option, controls, what="control", error=IdentificationError, unknown=unknown)
    for name in out:
        if f"tau_{name}" in model.parameters:
            raise IdentificationError(
                f"time_delays: the delay of {name!r} would be reported as 'tau_{name}', "
                "which is already a model parameter; rename that parameter"
            )
    return out


def _bound_value(value: Any, name: str, side: str, default: float) -> float:
    if value is None:
        return default
    if isinstance(value, bool):
        v = float("nan")
    else:
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = float("nan")
    if np.isnan(v):
        raise IdentificationError(
            f"bounds[{name!r}]: the {side} bound must be a number, None or ±inf, got {plain(value)}"
        )
    return v


def _check_bounds(
    bounds: Any, model: Any, names: list[str], initial: Mapping[str, float]
) -> dict[str, tuple[float, float]]:
    """Validated bounds ``name -> (lower, upper)`` with ±inf for open sides (see `identify`)."""
    if bounds is None:
        return {}
    if not isinstance(bounds, Mapping):
        raise IdentificationError(
            "bounds: expected a dict of parameter name -> (lower, upper), with None for an "
            f"open side, got {type(bounds).__name__}"
        )
    box: dict[str, tuple[float, float]] = {}
    for name, pair in bounds.items():
        if name not in model.parameters:
            raise IdentificationError(
                f"bounds: {name!r} is not a parameter of model {model.name!r}; its parameters "
                f"are {sorted(model.parameters)}"
            )
        if name not in names:
            raise IdentificationError(
                f"bounds: {name!r} is not estimated (it stays fixed at its nominal value "
                f"{float(model.parameters[name]):.6g}); add it to the parameters to estimate or "
                "drop its bounds"
            )
        items: list[Any] | None
        if isinstance(pair, (str, bytes, Mapping)):
            items = None
        else:
            try:
                items = list(pair)
            except TypeError:
                items = None
        if items is None or len(items) != 2:
            raise IdentificationError(
                f"bounds[{name!r}]: expected (lower, upper) with None for an open side, "
                f"got {plain(pair)}"
            )
        lo = _bound_value(items[0], name, "lower", -np.inf)
        hi = _bound_value(items[1], name, "upper", np.inf)
        if not lo < hi or lo == np.inf or hi == -np.inf:
            raise IdentificationError(
                f"bounds[{name!r}]: the lower bound {lo:.6g} must be below the upper bound {hi:.6g}"
            )
        start = float(initial[name])
        if not lo <= start <= hi:
            raise IdentificationError(
                f"bounds[{name!r}]: the initial value {start:.6g} lies outside [{lo:.6g}, "
                f"{hi:.6g}]; give an initial guess inside the bounds "
                f"(parameters={{{name!r}: ...}})"
            )
        box[name] = (lo, hi)
    return box


def _check_data_count(
    datas: list[FlightData], outputs: list[str], unknowns: dict[str, int]
) -> None:
    """Refuse a fit with no more measurements than unknowns (it would fit the noise exactly)."""
    n_samples = sum(d.n_samples for d in datas)
    n_meas = n_samples * len(outputs)
    n_unknown = sum(unknowns.values())
    if n_meas <= n_unknown:
        parts = " + ".join(f"{what} {n}" for what, n in unknowns.items() if n)
        raise IdentificationError(
            f"data: too few measurements to identify {n_unknown} unknowns ({parts}): "
            f"{n_samples} samples x {len(outputs)} outputs = {n_meas}; need more "
            "measurements than unknowns (a longer record, more outputs or fewer parameters)"
        )


def _finish(
    fitted: IdentificationResult, datas: list[FlightData], model: Any, held: dict[str, float]
) -> IdentificationResult:
    """Stamp the records' fingerprints and the parameters' units; a fit that ended
    non-finite has not succeeded; constant controls (`held`) must have moved the
    outputs."""
    estimates = [fitted.cost, *fitted.parameters.values()]
    for group in (*fitted.initial_states, *fitted.biases):
        estimates.extend(group.values())
    bad = not np.all(np.isfinite(estimates))
    if bad and fitted.success:
        message = (
            f"the fit ended with a non-finite cost or estimates (cost {fitted.cost:.6g}); "
            "check the data's scale and units"
        )
        warnings.warn(
            f"identify: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=4,  # _finish, identify, its BLAS wrapper, the caller
        )
        fitted = replace(fitted, success=False, message=message)
    from ._excitation import record_units, refuse_unexcited, response_to_noise, warn_unexcited

    ratios = {} if bad else response_to_noise(fitted.output_names, fitted.residuals, datas)
    refuse_unexcited(held, ratios)
    warn_unexcited(ratios)
    declared = dict(getattr(model, "parameter_units", None) or {})
    units = {
        n: "s" if n.startswith("tau_") and n not in declared else declared[n]
        for n in fitted.parameter_names
        if n in declared or n[4:] in fitted.time_delays
    }
    return replace(
        fitted,
        data_fingerprints=tuple(fingerprint(d) for d in datas),
        parameter_units=units,
        response_to_noise=ratios,
        units=record_units(model, datas, [*fitted.output_names, *getattr(model, "controls", ())]),
    )
