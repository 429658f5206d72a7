"""Model validation: residual statistics of a simulation against measurements."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt, fmt_fixed, frozen_array, markdown_table
from .._stats import chi2_sf, norm_ppf, t_quantile
from .._threads import CALLER_STACKLEVEL, small_blas
from .._units import require_model_units
from .._value_checks import check_distinct
from ..errors import IdentificationError
from ..io.data import FlightData, fingerprint, plain, whole_number
from ..models.model import (
    check_simulate_options,
    delayed_controls,
    fitted_start,
    require_model,
    resolve_parameters,
    simulator_outputs,
)
from ..models.replay import fitted_replay
from .prediction import STARTS, PredictionMetrics, PredictionResult, holdout_record, predict

__all__ = [
    "OutputMetrics",
    "PredictionMetrics",
    "PredictionResult",
    "ValidationResult",
    "ljung_box",
    "validate",
]

FloatArray = NDArray[np.float64]


def _autocorrelation(x: FloatArray, max_lag: int) -> FloatArray:
    """Sample autocorrelation r_k = sum (x_t - m)(x_{t+k} - m) / sum (x_t - m)^2, k = 0..max_lag."""
    xc = x - x.mean()
    den = float(xc @ xc)
    if den <= 0:
        return np.zeros(max_lag + 1)
    return np.array([float(xc[: x.size - k] @ xc[k:]) / den for k in range(max_lag + 1)])


def ljung_box(x: FloatArray, lags: int) -> tuple[float, float]:
    """Ljung–Box statistic Q = N(N+2) sum_k r_k^2/(N-k) and its chi-square(lags) p-value."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    lags = int(min(lags, n - 1))
    r = _autocorrelation(x, lags)
    k = np.arange(1, lags + 1)
    q = float(n * (n + 2) * np.sum(r[1:] ** 2 / (n - k)))
    return q, chi2_sf(q, lags)


@dataclass(frozen=True, eq=False)
class OutputMetrics(FrozenState):
    """Residual statistics of one output.

    Attributes
    ----------
    rmse : float
        Root-mean-square residual (measured minus model).
    bias : float
        Mean residual.
    bias_ci : tuple of float
        Confidence interval of the bias, widened for residual autocorrelation
        through an effective sample size (Student's t on its degrees of freedom).
    fit : float
        Normalised fit in percent, ``100 (1 - |e| / |y - mean(y)|)``.
    ljung_box_q, ljung_box_p : float
        Ljung–Box statistic and p-value over `whiteness_lags` lags.
    white : bool
        True when whiteness is not rejected at the 5 % level.
    input_correlation : mapping of str to float
        Per control, the largest absolute normalised residual–input
        cross-correlation over lags ±`whiteness_lags`, after both series are
        prewhitened (Box & Jenkins) by the residuals' whitening filter, an
        AR model of order up to 10 fitted to the residuals (order chosen by
        AIC; none for white residuals). Without it, coloured residuals
        against a smooth input would exceed the bound by chance most of the
        time: the cross-correlation's variance is ``1/N`` only when one
        series is white (Bartlett).
    input_correlation_bound : float
        The 5 % significance bound for the maximum over all lags,
        ``z/sqrt(N')`` with z Bonferroni-corrected for the number of lags and
        ``N'`` the prewhitened samples (N less the filter's order).
    input_correlated : bool
        True when any control's cross-correlation exceeds the bound.
    effective_samples : float
    """

    rmse: float
    bias: float
    bias_ci: tuple[float, float]
    fit: float
    ljung_box_q: float
    ljung_box_p: float
    white: bool
    input_correlation: Mapping[str, float]
    input_correlation_bound: float
    input_correlated: bool
    effective_samples: float

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "input_correlation", MappingProxyType(dict(self.input_correlation))
        )
        object.__setattr__(self, "bias_ci", (float(self.bias_ci[0]), float(self.bias_ci[1])))


@dataclass(frozen=True, eq=False)
class ValidationResult(FrozenState):
    """Per-output residual statistics of a model against one flight record.

    Attributes
    ----------
    metrics : mapping of str to OutputMetrics
    time : ndarray, shape (n_t,)
    measured, simulated, residuals : ndarray, shape (n_t, n_y)
    output_names : tuple of str
    confidence : float
    whiteness_lags : int
    control_names : tuple of str
        The model's controls, as flown (for plots: the inputs under the outputs).
    controls : ndarray, shape (n_t, n_u), or None
    units : mapping of str to str
        Units of the outputs and controls: the flight data's, else those the
        model declares (``channel_units`` of the `aeroid.models.aircraft` models).
    prediction : PredictionResult or None
        The model's prediction of held-out data (`validate`'s `holdout`).
    """

    metrics: Mapping[str, OutputMetrics]
    time: FloatArray
    measured: FloatArray
    simulated: FloatArray
    residuals: FloatArray
    output_names: tuple[str, ...]
    confidence: float
    whiteness_lags: int
    control_names: tuple[str, ...] = ()
    controls: FloatArray | None = None
    units: Mapping[str, str] = field(default_factory=dict)
    prediction: PredictionResult | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "metrics", MappingProxyType(dict(self.metrics)))
        for name in ("time", "measured", "simulated", "residuals"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        object.__setattr__(self, "output_names", tuple(self.output_names))
        object.__setattr__(self, "control_names", tuple(self.control_names))
        if self.controls is not None:
            object.__setattr__(self, "controls", frozen_array(self.controls))
        object.__setattr__(
            self, "units", MappingProxyType({str(k): str(v) for k, v in dict(self.units).items()})
        )

    def residual(self, name: str) -> FloatArray:
        """Residual history of one output."""
        return self.residuals[:, self.output_names.index(name)]

    def plot(self, **kwargs: Any) -> Any:
        """Measured vs model time histories with residuals. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_time_histories

        return plot_time_histories(self, **kwargs)

    def summary(self) -> str:
        """Markdown table of the per-output statistics."""
        pct = f"{100 * self.confidence:g} %"
        rows = []
        for n in self.output_names:
            m = self.metrics[n]
            corr = max(m.input_correlation.values(), default=0.0)
            rows.append(
                (
                    n,
                    fmt(m.rmse),
                    f"{fmt(m.bias)} [{fmt(m.bias_ci[0])}, {fmt(m.bias_ci[1])}]",
                    fmt_fixed(m.fit, 1),
                    f"{'yes' if m.white else 'no'} (p={fmt(m.ljung_box_p, 3)})",
                    f"{fmt(corr, 3)}{' (!)' if m.input_correlated else ''}",
                )
            )
        table = markdown_table(
            ("output", "RMSE", f"bias [{pct} CI]", "fit %", "white residuals", "max xcorr(e, u)"),
            rows,
        )
        if self.prediction is not None:
            table += "\n\n" + self.prediction.summary()
        return table


def _effective_samples(e: FloatArray) -> float:
    """N / tau with tau = (1 + r1) / (1 - r1) from the lag-one autocorrelation."""
    n = e.size
    r1 = float(np.clip(_autocorrelation(e, 1)[1], -0.99, 0.99))
    tau = max((1.0 + r1) / (1.0 - r1), 1.0)
    return max(n / tau, 2.0)


def _mean_halfwidth(e: FloatArray, n_eff: float, level: float) -> float:
    """Half-width of the `level` interval on the mean of the autocorrelated `e` with
    `n_eff` effective samples: the variance from the sum of squares about the mean,
    whose expectation is ``s^2 (n - n / n_eff)`` (the mean took ``1 / n_eff`` of it, not
    ``1 / n``), over ``n_eff``, and Student's t on ``n_eff - 1`` degrees of freedom
    (Zwiers & von Storch 1995): a strongly coloured record holds few samples' worth."""
    n = e.size
    ss = float(np.sum((e - e.mean()) ** 2))
    var = ss / max(n - n / n_eff, 1.0)
    q = float(t_quantile(np.array([max(n_eff - 1.0, 1.0)]), level)[0])
    return q * float(np.sqrt(var / n_eff))


# Box & Jenkins prewhiten before testing residual-input cross-correlations: the sample
# cross-correlation of two independent series has variance (1/N) sum_j rho_ee(j) rho_uu(j)
# (Bartlett), 1/N only when one of them is white. Coloured residuals (turbulence) against
# a smooth input (a doublet) make it many times 1/N, and z/sqrt(N) then flags a correct
# model most of the time. Both series are filtered by the residuals' whitening filter, an
# AR model of at most this order: a true relation e = h * u + v survives a filter applied
# to both sides, and residuals found white (AIC picks no model) are left as they are.
# Bartlett's sum estimated from the samples instead cost most of the test's power against
# small true relations in simulations (its long-lag terms are noisy for a smooth input).
_WHITENING_ORDER = 10


def _whitening_filter(e: FloatArray, max_order: int) -> FloatArray:
    """Coefficients ``a`` of the AR model ``e_t = sum_i a_i e_(t-i) + w_t`` fitted by
    Yule-Walker (Levinson-Durbin), its order (at most `max_order`) chosen by AIC;
    empty when no model beats white noise."""
    n = e.size
    ec = e - e.mean()
    r = np.array([float(ec[: n - k] @ ec[k:]) / n for k in range(max_order + 1)])
    a = np.zeros(0)
    best = np.zeros(0)
    if not r[0] > 0.0:
        return best
    s2 = r[0]
    best_aic = float(np.log(s2))
    for order in range(1, max_order + 1):
        k = (r[order] - float(a @ r[order - 1 : 0 : -1])) / s2
        a = np.concatenate([a - k * a[::-1], [k]])
        s2 *= 1.0 - k * k
        if not s2 > 0.0:
            break
        aic = float(np.log(s2)) + 2.0 * order / n
        if aic < best_aic:
            best_aic, best = aic, a.copy()
    return best


def _whiten(x: FloatArray, a: FloatArray) -> FloatArray:
    """``x_t - sum_i a_i x_(t-i)`` about the mean, for the samples with a full past."""
    xc = x - x.mean()
    p = a.size
    out = xc[p:].copy()
    for i in range(p):
        out -= a[i] * xc[p - 1 - i : xc.size - 1 - i]
    return out


def _max_crosscorrelation(e: FloatArray, u: FloatArray, lags: int) -> float:
    ec = e - e.mean()
    uc = u - u.mean()
    den = float(np.sqrt((ec @ ec) * (uc @ uc)))
    if den <= 0:
        return 0.0
    n = e.size
    best = 0.0
    for k in range(-lags, lags + 1):
        c = float(ec[: n - k] @ uc[k:]) if k >= 0 else float(ec[-k:] @ uc[: n + k])
        best = max(best, abs(c) / den)
    return best


@small_blas
def validate(
    model: Any,
    data: FlightData,
    parameters: Any = None,
    *,
    outputs: Sequence[str] | None = None,
    x0: Any = None,
    confidence: float = 0.95,
    whiteness_lags: int | None = None,
    simulate_options: Mapping[str, Any] | None = None,
    holdout: Mapping[str, float] | FlightData | None = None,
    holdout_start: Literal["measured", "estimated"] = "measured",
) -> ValidationResult:
    """Compare the model's simulation with measured outputs.

    Parameters
    ----------
    model : Model or SimulatorModel
    data : FlightData
        Must carry the model's controls and the outputs to check.
    parameters : mapping or result, optional
        Parameter values, or an identification/inference result. When `data`
        is a record the identification result was fitted to, the initial
        state and the biases the fit estimated for it (on outputs and on state
        equations) are applied as well. A
        fit's estimated time delays (``result.time_delays``) apply on any
        record: the model is simulated on the delayed controls.
    outputs : sequence of str, optional
        Outputs to check; default every model output present in the data.
    x0 : mapping or array, optional
        Initial state; default the fit's for this record (see `parameters`),
        else the measured states at t0.
    confidence : float
        Confidence level of the bias interval.
    whiteness_lags : int, optional
        Lags of the Ljung–Box test and of the residual–input correlation.
        At most N - 2 are used: more are clamped to N - 2 with a warning that
        names both. Default 20, or N - 2 for a shorter record.
    simulate_options : mapping, optional
        Passed to the simulation; default ``{"method": "auto"}`` for a `Model`,
        the integrator `identify` uses.
    holdout : mapping or FlightData, optional
        Data not used in the fit, to predict with the parameters fixed: a
        window of `data`, ``{"t0": .., "t1": ..}`` in seconds, or its last
        fraction, ``{"fraction": 0.25}``; or a second record (another
        manoeuvre). The model is simulated with the held-out controls from
        the held-out data's measured state at its first sample (on a window
        of a record it was fitted to, the fit's output biases are added to the
        outputs and taken off that measured state), and
        ``result.prediction`` holds per-output RMSE, Theil U, R^2 and fit %.
        At least 10 held-out samples are needed.
    holdout_start : {"measured", "estimated"}
        Where the prediction of `holdout` starts. ``"measured"``: as above.
        ``"estimated"``: Tischler's time-domain verification (ch. 15) and
        Klein & Morelli's prediction check: every model parameter held at the
        fit's values, the initial state and one constant shift per checked
        output are fitted to the held-out data by output error, so that
        neither another manoeuvre's trim nor the noise on its first sample
        counts against the model (`Model` only). The values used are in
        ``result.prediction.initial_state`` and ``.shifts``; where the data
        cannot tell a state's start from its sensor's shift (a bank angle that
        only integrates), only their sum is determined, and so is the
        prediction.

    Returns
    -------
    ValidationResult

    Raises
    ------
    IdentificationError
        Bad arguments, such as a `whiteness_lags` that is not a positive integer,
        an empty `outputs`, unknown or invalid `simulate_options`, or a record
        of fewer than 3 samples, or a `holdout` window outside the record or
        too short.
    ChannelError
        A control or output is missing from the data.
    """
    require_model(model, IdentificationError)
    if not isinstance(data, FlightData):
        raise IdentificationError(f"data: expected FlightData, got {type(data).__name__}")
    require_model_units(
        model, [data], [*model.controls, *getattr(model, "output_names", ())], IdentificationError
    )
    try:
        # float() would read "0.9" as 0.9
        level = float("nan") if isinstance(confidence, (str, bytes)) else float(confidence)
    except (TypeError, ValueError):
        level = float("nan")
    if not 0.0 < level < 1.0:
        raise IdentificationError(f"confidence must lie in (0, 1), got {plain(confidence)}")
    n = data.n_samples
    if n < 3:  # the Ljung–Box test needs one lag of N - 2: its p-value would be NaN
        raise IdentificationError(f"data: validation needs at least 3 samples, got {n}")
    opts = check_simulate_options(simulate_options, model, IdentificationError)
    if holdout_start not in STARTS:
        raise IdentificationError(
            f"holdout_start {plain(holdout_start)} is unknown; choose one of {list(STARTS)}"
        )
    if holdout is None and holdout_start != "measured":
        raise IdentificationError(f"holdout_start={holdout_start!r} needs a holdout to predict")
    if whiteness_lags is None:
        whiteness_lags = 20
    else:
        whiteness_lags = whole_number(whiteness_lags, "whiteness_lags", IdentificationError)
        if whiteness_lags > n - 2:
            warnings.warn(
                f"validate: whiteness_lags={whiteness_lags} is beyond the record's {n} "
                f"samples; using {max(n - 2, 0)} lags",
                UserWarning,
                stacklevel=CALLER_STACKLEVEL,
            )
    p = resolve_parameters(model, parameters, error=IdentificationError)
    names = list(model.outputs)
    if isinstance(outputs, str):  # one name, not its letters
        outputs = [outputs]
    chosen = [o for o in names if o in data] if outputs is None else list(outputs)
    for o in chosen:
        if o not in names:
            raise IdentificationError(f"outputs: {o!r} is not an output of model {model.name!r}")
    check_distinct(chosen, "outputs", IdentificationError)
    if outputs is not None and not chosen:  # an empty result would pass for a check
        raise IdentificationError("outputs: name at least one output to check")
    if not chosen:
        data.require(names[:1], role="output")
    data.require(chosen, role="output")
    # on a record the fit was fitted to: its start, output biases and state biases
    replay = fitted_replay(model, parameters, data, x0)
    biases = fitted_start(parameters, data)[1]
    # the controls as the fitted model takes them (a fit's estimated time delays)
    flown = delayed_controls(parameters, data)
    if hasattr(model, "simulate_batch"):
        opts.setdefault("method", "auto")  # the integrator identify uses by default
    # a stepped simulator's failure (a raise, a wrong shape, NaN) named as a Model's is
    run = partial(replay.model.simulate_data, flown, x0=replay.x0, parameters=p, **opts)
    y_sim = simulator_outputs(replay.model, run, n)
    idx = [names.index(o) for o in chosen]
    y_model = y_sim[:, idx] + np.array([replay.output_biases.get(o, 0.0) for o in chosen])
    y_meas = data.array(chosen)
    resid = y_meas - y_model
    lags = int(min(whiteness_lags, n - 2))
    # The maximum over 2L+1 lags is tested, so the 5 % level is split across them
    # (Bonferroni); a per-lag 1.96/sqrt(N) would flag a correct model most of the time.
    z_cross = norm_ppf(1 - 0.025 / (2 * lags + 1))
    metrics: dict[str, OutputMetrics] = {}
    for j, o in enumerate(chosen):
        e = resid[:, j]
        y = y_meas[:, j]
        bias = float(e.mean())
        n_eff = _effective_samples(e)
        half = _mean_halfwidth(e, n_eff, level)
        spread = float(np.linalg.norm(y - y.mean()))
        fit = 100.0 * (1.0 - float(np.linalg.norm(e)) / spread) if spread > 0 else float("nan")
        q, pval = ljung_box(e, lags)
        a = _whitening_filter(e, min(_WHITENING_ORDER, n // 10))
        ew = _whiten(e, a)
        bound = z_cross / np.sqrt(ew.size)
        reach = min(lags, ew.size - 1)
        xc = {
            c: _max_crosscorrelation(ew, _whiten(np.asarray(flown[c], dtype=np.float64), a), reach)
            for c in model.controls
        }
        metrics[o] = OutputMetrics(
            rmse=float(np.sqrt(np.mean(e**2))),
            bias=bias,
            bias_ci=(bias - half, bias + half),
            fit=fit,
            ljung_box_q=q,
            ljung_box_p=pval,
            white=bool(pval >= 0.05),
            input_correlation=xc,
            input_correlation_bound=float(bound),
            input_correlated=bool(any(v > bound for v in xc.values())),
            effective_samples=n_eff,
        )
    units = {
        k: v
        for k, v in {**dict(getattr(model, "channel_units", {}) or {}), **data.units}.items()
        if k in chosen or k in model.controls
    }
    prediction = None
    if holdout is not None:
        record, source, window = holdout_record(data, holdout)
        prediction = predict(
            model,
            record,
            p,
            chosen,
            delayed_controls(parameters, record),
            biases if window else {},
            opts,
            source,
            units,
            in_fit=window
            and fingerprint(data) in tuple(getattr(parameters, "data_fingerprints", ()) or ()),
            start=holdout_start,
        )
    return ValidationResult(
        metrics=metrics,
        time=data.time,
        measured=y_meas,
        simulated=y_model,
        residuals=resid,
        output_names=tuple(chosen),
        confidence=level,
        whiteness_lags=lags,
        control_names=tuple(model.controls),
        controls=data.array(list(model.controls)) if model.controls else None,
        # the record's own units, else those the model declares (the aircraft models)
        units=units,
        prediction=prediction,
    )
