"""Parameter identification: the `IdentificationResult` record and `identify`."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._records import ReadOnlyDict, fmt, frozen_array, frozen_mapping, markdown_table
from .data import FlightData, check_symmetric, fingerprint, measured_start, plain, whole_number
from .errors import IdentificationError

__all__ = ["IdentificationResult", "identify"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """Estimated parameters with their uncertainty and fit diagnostics.

    Attributes
    ----------
    parameters : mapping of str to float
        The estimated parameters (names in `parameter_names`).
    stderr : mapping of str to float
        Standard errors shown to users; see `error_bars` for which kind.
    covariance : ndarray, shape (n_p, n_p)
        Parameter covariance matching `stderr`, in `parameter_names` order.
    parameter_names : tuple of str
    fixed : mapping of str to float
        Model parameters held at given values (not estimated).
    covariance_white : ndarray, shape (n_p, n_p)
        Classical Cramér–Rao covariance that assumes white residuals.
    error_bars : str
        ``"colored"`` when `covariance` is corrected for residual
        autocorrelation, ``"white"`` when it is the classical one (asked for,
        or because the residuals were found white).
    identifiable : bool
        False when the data cannot separate some parameters.
    unidentifiable : tuple of tuple of str
        The parameter combinations the data cannot separate.
    success : bool
        True when the optimiser converged.
    message : str
    n_iterations : int
    cost : float
        Final value of the minimised objective.
    method : str
        ``"output_error"`` or ``"filter_error"``.
    output_names : tuple of str
        Outputs that entered the fit.
    noise_covariance : ndarray, shape (n_y, n_y)
        Measurement-noise covariance used (estimated from residuals unless given).
    initial_states : tuple of mapping
        Initial state per manoeuvre (estimated or fixed).
    biases : tuple of mapping
        Per manoeuvre, the estimated output biases (empty when not estimated).
    extra_stderr : mapping of str to float
        Standard errors of estimated initial states and biases, keyed
        ``"x0[i].state"`` and ``"bias[i].output"``.
    residuals : tuple of ndarray
        Per manoeuvre, measured minus model outputs, shape (n_t, n_y).
    sigma2 : float or None
        Filter error only: mean normalised innovation variance (≈ 1 when the
        noise specification is consistent with the data).
    process_noise : mapping of str to float
        Filter error only: process-noise intensities used or estimated.
    model_name : str
    data_fingerprints : tuple of str
        Per manoeuvre, a SHA-256 of the record fitted (time and channels):
        `validate`, `filter_states`, `frequency_response`, `sensitivities`
        and `infer`, given this result and one of those records, start from
        the state the fit used for it; other records start from their own
        measured state.
    """

    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    parameter_names: tuple[str, ...]
    fixed: Mapping[str, float]
    covariance_white: FloatArray
    error_bars: str
    identifiable: bool
    unidentifiable: tuple[tuple[str, ...], ...]
    success: bool
    message: str
    n_iterations: int
    cost: float
    method: str
    output_names: tuple[str, ...]
    noise_covariance: FloatArray
    initial_states: tuple[Mapping[str, float], ...] = ()
    biases: tuple[Mapping[str, float], ...] = ()
    extra_stderr: Mapping[str, float] = field(default_factory=dict)
    residuals: tuple[FloatArray, ...] = ()
    sigma2: float | None = None
    process_noise: Mapping[str, float] = field(default_factory=dict)
    model_name: str = ""
    data_fingerprints: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "data_fingerprints", tuple(str(f) for f in self.data_fingerprints))
        set_(self, "parameters", frozen_mapping(self.parameters))
        set_(self, "stderr", frozen_mapping(self.stderr))
        set_(self, "fixed", frozen_mapping(self.fixed))
        set_(self, "extra_stderr", frozen_mapping(self.extra_stderr))
        set_(self, "process_noise", frozen_mapping(self.process_noise))
        set_(self, "covariance", frozen_array(self.covariance))
        set_(self, "covariance_white", frozen_array(self.covariance_white))
        set_(self, "noise_covariance", frozen_array(self.noise_covariance))
        set_(self, "parameter_names", tuple(self.parameter_names))
        set_(self, "output_names", tuple(self.output_names))
        set_(self, "unidentifiable", tuple(tuple(c) for c in self.unidentifiable))
        set_(self, "initial_states", tuple(frozen_mapping(m) for m in self.initial_states))
        set_(self, "biases", tuple(frozen_mapping(m) for m in self.biases))
        set_(self, "residuals", tuple(frozen_array(r) for r in self.residuals))

    @property
    def correlation(self) -> FloatArray:
        """Parameter correlation matrix derived from `covariance`."""
        d = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.covariance / np.outer(d, d)
        c[~np.isfinite(c)] = 0.0
        np.fill_diagonal(c, 1.0)
        c.setflags(write=False)
        return c

    @property
    def stderr_white(self) -> Mapping[str, float]:
        """Classical (white-residual) standard errors."""
        d = np.sqrt(np.clip(np.diag(self.covariance_white), 0.0, None))
        return ReadOnlyDict({n: float(s) for n, s in zip(self.parameter_names, d, strict=True)})

    @property
    def all_parameters(self) -> Mapping[str, float]:
        """Fixed and estimated parameters together (a full model parameter set)."""
        merged: dict[str, Any] = dict(self.fixed)
        merged.update(self.parameters)
        return ReadOnlyDict(merged)

    def plot(self, **kwargs: Any) -> Any:
        """Residual histories and estimates with 95 % error bars. Returns a matplotlib Figure."""
        from .plotting import plot_identification

        return plot_identification(self, **kwargs)

    def summary(self) -> str:
        """Markdown table of estimates, standard errors and relative errors."""
        rows = []
        for n in self.parameter_names:
            est = self.parameters[n]
            se = self.stderr[n]
            rel = f"{100 * se / abs(est):.1f}%" if est != 0 and np.isfinite(se) else "—"
            rows.append((n, fmt(est), fmt(se), rel))
        table = markdown_table(("parameter", "estimate", "std. error", "rel. error"), rows)
        notes = []
        kind = (
            "corrected for coloured residuals"
            if self.error_bars == "colored"
            else "classical (white residuals)"
        )
        notes.append(f"Standard errors: {kind}; method: {self.method.replace('_', ' ')}.")
        if self.sigma2 is not None:
            notes.append(f"Normalised innovation variance sigma2 = {self.sigma2:.3g}.")
        if not self.success:
            notes.append(f"**Not converged:** {self.message}")
        if not self.identifiable:
            combos = "; ".join(" + ".join(c) for c in self.unidentifiable) or "see covariance"
            notes.append(f"**Not identifiable:** the data cannot separate {combos}.")
        return table + "\n\n" + "\n".join(notes)


_METHODS = ("output_error", "filter_error")
_GRADIENTS = ("fd", "jax")
_ERROR_BARS = ("colored", "white")


def _as_list(data: Any) -> list[FlightData]:
    if isinstance(data, FlightData):
        return [data]
    if isinstance(data, (list, tuple)) and data and all(isinstance(d, FlightData) for d in data):
        return list(data)
    raise IdentificationError(
        f"data: expected FlightData or a non-empty list of FlightData, got {type(data).__name__}"
    )


def _names_and_initial(model: Any, parameters: Any) -> tuple[list[str], dict[str, float]]:
    nominal = dict(model.parameters)
    if isinstance(parameters, str):
        parameters = [parameters]
    if isinstance(parameters, Mapping):
        names = list(parameters)
        initial = {}
        for n, v in parameters.items():
            try:
                initial[n] = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(
                    f"parameters: initial guess of {n!r} is not a number: {plain(v)}"
                ) from None
    else:
        try:
            names = [str(n) for n in parameters]
        except TypeError:
            raise IdentificationError(
                "parameters: expected a list of names to estimate or a dict name -> initial guess"
            ) from None
        initial = {}
    if not names:
        raise IdentificationError("parameters: name at least one parameter to estimate")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise IdentificationError(f"parameters: listed twice: {dupes}")
    for n in names:
        if n not in nominal:
            raise IdentificationError(
                f"parameter {n!r} is not a parameter of model {model.name!r}; "
                f"its parameters are {sorted(nominal)}"
            )
        initial.setdefault(n, float(nominal[n]))
        if not np.isfinite(initial[n]):
            raise IdentificationError(f"parameters: initial guess of {n!r} is not finite")
    return names, initial


def _select(option: Any, available: Sequence[str], what: str, *, strict: bool = True) -> list[str]:
    if option is False or option is None:
        return []
    if option is True:
        return list(available)
    try:
        chosen = [option] if isinstance(option, str) else list(option)
    except TypeError:
        raise IdentificationError(
            f"{what}: expected True, False or a list of names, got {plain(option)}"
        ) from None
    for c in chosen:
        if c not in available and strict:
            raise IdentificationError(f"{what}: {c!r} is not one of {list(available)}")
    return [c for c in chosen if c in available]


def _x0_values(xi: Any, states: list[str]) -> dict[str, float]:
    """One manoeuvre's given initial state (mapping or array) by state name."""
    if isinstance(xi, Mapping):
        unknown = sorted(set(xi) - set(states))
        if unknown:
            raise IdentificationError(f"x0: unknown states {unknown}; states: {states}")
        out = {}
        for s, v in xi.items():
            try:
                out[s] = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(f"x0[{s!r}]: expected a number, got {plain(v)}") from None
    else:
        try:
            arr = np.asarray(xi, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise IdentificationError(
                f"x0: expected a mapping of state -> value or {len(states)} numbers for "
                f"states {states}, got {plain(xi)}"
            ) from None
        if arr.size != len(states):
            raise IdentificationError(
                f"x0: expected {len(states)} values for states {states}, got {arr.size}"
            )
        out = dict(zip(states, arr.tolist(), strict=True))
    bad = [s for s, v in out.items() if not np.isfinite(v)]
    if bad:
        raise IdentificationError(f"x0: the initial value of {bad} is not finite")
    return out


def _weight_variances(weights: Any, outputs: list[str]) -> FloatArray:
    """Fixed noise variances per fitted output from `weights` (see `identify`)."""
    n = len(outputs)
    if isinstance(weights, Mapping):
        unknown = sorted(set(weights) - set(outputs))
        if unknown:
            raise IdentificationError(
                f"weights: unknown outputs {unknown}; fitted outputs: {outputs}"
            )
        w = np.empty(n)
        for k, o in enumerate(outputs):
            try:
                w[k] = float(weights.get(o, 1.0))
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


def identify(
    model: Any,
    data: FlightData | Sequence[FlightData],
    parameters: Sequence[str] | Mapping[str, float],
    *,
    method: str = "output_error",
    gradient: str = "fd",
    outputs: Sequence[str] | None = None,
    x0: Any = None,
    estimate_x0: bool | Sequence[str] = False,
    estimate_bias: bool | Sequence[str] = False,
    weights: Mapping[str, float] | Any = None,
    error_bars: str = "colored",
    max_iterations: int = 50,
    tolerance: float = 1e-8,
    simulate_options: Mapping[str, Any] | None = None,
    process_noise: Mapping[str, float] | Any = None,
    measurement_noise: Mapping[str, float] | Any = None,
    filter_options: Mapping[str, Any] | None = None,
    estimate_process_noise: bool | Sequence[str] = False,
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
        of name to initial guess. The others stay at their nominal values.
    method : {"output_error", "filter_error"}
        Maximum-likelihood output error, or filter error (fits on whitened
        Kalman-filter innovations; needs `process_noise`).
    gradient : {"fd", "jax"}
        Finite-difference sensitivities (batched) or exact JAX Jacobians.
    outputs : sequence of str, optional
        Model outputs to fit; default every model output present in the data.
    x0 : mapping, array or list of them, optional
        Initial state (per manoeuvre when a list); default the measured states
        at the first sample and zero for unmeasured ones.
    estimate_x0 : bool or sequence of str
        Estimate the initial value of these states (all when True), per manoeuvre.
    estimate_bias : bool or sequence of str
        Estimate a constant measurement bias on these outputs, per manoeuvre.
    weights : mapping of str to float or ndarray, optional
        Fixed output weights (inverse noise variances, positive) or a diagonal,
        positive definite noise covariance (correlated noise is refused, not
        dropped). Default: the noise covariance is estimated from the
        residuals at every iteration (maximum likelihood).
    error_bars : {"colored", "white"}
        Standard errors corrected for coloured residuals from their
        autocorrelation (default), or the classical Cramér–Rao values.
    max_iterations : int
        Gauss–Newton iteration limit (a positive integer); hitting it returns
        a result flagged ``success=False`` with a warning.
    tolerance : float
        Convergence threshold on the relative parameter step.
    simulate_options : mapping, optional
        Integrator options (``method``, ``substeps``, ``rtol``, ``atol``).
    process_noise, measurement_noise, filter_options, estimate_process_noise
        Filter-error settings: continuous process-noise PSD per state,
        measurement-noise variances per output, filter options, and whether
        to estimate the process-noise intensities.

    Returns
    -------
    IdentificationResult

    Raises
    ------
    IdentificationError
        Bad arguments, incompatible options, no more measurements (samples
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
    from .model import SimulatorModel, require_model

    require_model(model, IdentificationError)
    if method not in _METHODS:
        raise IdentificationError(f"method {method!r} is unknown; choose one of {list(_METHODS)}")
    if gradient not in _GRADIENTS:
        raise IdentificationError(
            f"gradient {gradient!r} is unknown; choose one of {list(_GRADIENTS)}"
        )
    if error_bars not in _ERROR_BARS:
        raise IdentificationError(
            f"error_bars {error_bars!r} is unknown; choose one of {list(_ERROR_BARS)}"
        )
    max_iterations = whole_number(max_iterations, "max_iterations", IdentificationError)
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        tol = float("nan")
    if not (tol > 0):
        raise IdentificationError(f"tolerance must be positive, got {plain(tolerance)}")
    datas = _as_list(data)
    names, initial = _names_and_initial(model, parameters)
    is_simulator = not hasattr(model, "simulate_batch") and isinstance(model, SimulatorModel)
    model_outputs = list(model.outputs)
    if outputs is None:
        fit_outputs = [o for o in model_outputs if all(o in d for d in datas)]
        if not fit_outputs:
            datas[0].require(model_outputs[:1], role="output")
    else:
        fit_outputs = _select(list(outputs), model_outputs, "outputs")
        if not fit_outputs:
            raise IdentificationError("outputs: name at least one output to fit")
    for d in datas:
        d.require(model.controls, role="control")
        d.require(fit_outputs, role="output")
    states = list(getattr(model, "states", ()))
    # Initial states per manoeuvre.
    if isinstance(x0, (list, tuple)) and len(x0) == len(datas) and len(datas) > 1:
        x0_list = list(x0)
    else:
        x0_list = [x0] * len(datas)
    x0_dicts: list[dict[str, float]] = []
    for d, xi in zip(datas, x0_list, strict=True):
        if xi is None:
            x0_dicts.append(measured_start(d, states))
        else:
            x0_dicts.append(_x0_values(xi, states))
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
        if gradient == "jax":
            raise IdentificationError("gradient='jax' is available for output error only")
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
                "process-noise intensities": len(noise_states),
                "measurement-noise variances": len(fit_outputs) if measurement_noise is None else 0,
            },
        )
        from ._filter_error import identify_filter_error

        fitted = identify_filter_error(
            model,
            datas,
            names,
            initial,
            outputs=fit_outputs,
            process_noise=process_noise,
            measurement_noise=measurement_noise,
            filter_options=filter_options,
            estimate_process_noise=estimate_process_noise,
            x0=x0_dicts if x0 is not None else None,
            max_iterations=max_iterations,
            tolerance=tol,
        )
        return _finish(fitted, datas)
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
    opts = dict(simulate_options or {})
    from ._output_error import SIMULATE_OPTIONS, fit_output_error

    unknown_opts = sorted(set(opts) - set(SIMULATE_OPTIONS))
    if unknown_opts:
        raise IdentificationError(
            f"simulate_options: unknown keys {unknown_opts}; valid keys are {list(SIMULATE_OPTIONS)}"
        )
    if not is_simulator:
        opts.setdefault("method", "auto")
    sel_x0 = _select(estimate_x0, states, "estimate_x0")
    if sel_x0 and (is_simulator or gradient == "jax"):
        raise IdentificationError("estimate_x0 needs a Model and gradient='fd'")
    sel_bias = _select(estimate_bias, fit_outputs, "estimate_bias")
    w_arr = None if weights is None else _weight_variances(weights, fit_outputs)
    _check_data_count(
        datas,
        fit_outputs,
        {
            "parameters": len(names),
            "initial states": len(sel_x0) * len(datas),
            "biases": len(sel_bias) * len(datas),
        },
    )
    fitted = fit_output_error(
        model,
        datas,
        names,
        initial,
        outputs=fit_outputs,
        x0=x0_dicts,
        estimate_x0=sel_x0,
        estimate_bias=sel_bias,
        weights=w_arr,
        error_bars=error_bars,
        max_iterations=max_iterations,
        tolerance=tol,
        simulate_options=opts,
        gradient=gradient,
    )
    return _finish(fitted, datas)


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


def _finish(fitted: IdentificationResult, datas: list[FlightData]) -> IdentificationResult:
    """Stamp the records' fingerprints; a fit that ended non-finite has not succeeded."""
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
            f"identify: {message}; the result is flagged success=False", UserWarning, stacklevel=3
        )
        fitted = replace(fitted, success=False, message=message)
    return replace(fitted, data_fingerprints=tuple(fingerprint(d) for d in datas))
