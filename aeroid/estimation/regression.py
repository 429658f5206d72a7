"""Equation-error and stepwise regression (Klein & Morelli, ch. 5 and 7).

Equation error fits a measured force or moment coefficient (or a state
derivative) ``z`` as a linear combination of regressors ``X`` by ordinary
least squares, ``θ = (X'X)^-1 X'z``. Regressors and the response are channels
of flight data, arrays, or simple expressions of channels:

* a channel name: ``"alpha"``;
* products, quotients and integer or real powers of channels and numbers,
  without parentheses: ``"alpha*q"``, ``"alpha^2"`` (or ``"alpha**2"``),
  ``"q/V"``, ``"0.5*q*de"``;
* the absolute value of a channel, as a factor like any other:
  ``"abs(beta)"``, ``"abs(beta)*alpha"`` (a coefficient even in the sideslip
  with a corner at zero, such as a fuselage's drag ``k |β|``, which no
  polynomial in β follows; Klein & Morelli ch. 5).

A column of ones (named ``"const"``) is added by default. Modelling residuals
of equation error are rarely white, and the classical ``s² (X'X)^-1``
understates the error bars then; by default they use Morelli's correction
for coloured residuals, ``(X'X)^-1 [Σ_ij x_i R(i−j) x_j'] (X'X)^-1``, with the
residual spectrum estimated as every estimator of the package estimates it
(`aeroid._colour`): a smoothed periodogram corrected for what the fit removed
at each frequency (least-squares residuals sum to zero, so SIDPAC's sum of
the residual autocorrelation over all lags nearly cancels along the
constant), and a Satterthwaite t-quantile for the spectrum's own
uncertainty. With white residuals it is the classical formula.

``error_bars="reml"`` corrects the bars exactly as output error corrects its
own (`aeroid.identify`): the residual is modelled as an AR(1) disturbance plus
white noise fitted by restricted maximum likelihood, which accounts for the
regressors the fit absorbed without any window, the sandwich is exact for that
model, and the noise model's own uncertainty widens the interval through a
Satterthwaite t-quantile. It covers as well or better (95–97 % on the tests'
records, white or AR(1) with φ = 0.9) at about the same cost, but it is exact
only for residuals its AR(1)-plus-white model describes. Real flight residuals
are seldom of that colour (a short-memory part plus slow content): the AR(1)
fit over-reads their low-frequency power, where the regressors' information
lies, and the ``"reml"`` bars can be several times too wide (2-6x against
AR(p) sandwiches and SIDPAC's ``colores`` on four real equations, the constant
widest). The window assumes no shape of the residual spectrum, so it stays the
default and the recommended bar, as SIDPAC's correction is.

Fit statistics follow Klein & Morelli: ``R² = 1 − SSE/SST`` (SST about the
mean when there is a constant term), the F statistic of the regression
``F = [(SST − SSE)/k] / [SSE/(N − p)]`` with ``k`` the regressors other
than the constant, and the predicted squared error
``PSE = SSE/N + σ²_max p/N``, ``σ²_max = Σ (z − z̄)²/N``.
The predicted residual sum of squares (PRESS, Klein & Morelli sec. 5.4;
SIDPAC's ``press``) adds the squared error of predicting each sample from
the fit without it, ``Σ [v_i/(1 − h_ii)]²``, with ``h_ii`` the diagonal of
the hat matrix ``X(X'X)^-1X'``, row by row with the fit's own inverse; with
estimated time delays, X is the Gauss–Newton Jacobian ``[X, ∂(Xθ)/∂τ]``, so
the delays are refitted too, to first order. In the frequency domain a
frequency leaves with both parts of its equation (SIDPAC's definition on
complex data): its residual pair becomes ``(I − H_k)^-1 (Re v_k, Im v_k)``
with ``H_k`` the 2 × 2 block of the stacked real system's hat matrix.

With ``domain="frequency"`` the regression runs on the finite Fourier
transforms of the response and regressors at chosen frequencies
(``X̃(f) = Δt Σ x(t) e^{−j2πft}``, by the chirp-z transform or a direct sum,
whichever does less work: `aeroid._czt.fourier`), and the parameters are the real
solution of the complex least squares, ``θ = Re(X̃*X̃)^-1 Re(X̃*Z̃)`` (Fourier
transform regression, Klein & Morelli ch. 7). Only the chosen band enters,
so high-frequency noise outside it drops out. A constant offset does not
vanish from the transform of a finite record at ``f > 0`` (``∫_0^T e^{−jωt}dt``
is zero only at multiples of ``1/T``), so the constant term stays in the
model unless the data are perturbations about trim (it is left out by itself
where it has no content: at multiples of ``1/(NΔt)``). The white error bars
use the classical formula with the residual variance ``Σ|Ṽ|²/(2M − p)`` per
real component. The default ones are the sandwich of the frequency-domain
estimators (`aeroid._colour.frequency_sandwich`): the noise spectrum at each
frequency is estimated from the leverage-corrected residuals there and at
its neighbours, which holds however the residuals are coloured in time,
because transforms at distinct frequencies of the ``k/(NΔt)`` grid are
nearly independent. Frequencies
closer than ``1/(NΔt)`` (SIDPAC's examples space them 0.04 Hz apart on
records shorter than 25 s) share their noise, and the sandwich adds each
pair's covariance through the record's kernel; there the classical formula
counts each shared noise as many times as it is sampled and the white bars
come out too small.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import FrozenState, IntervalMixin, fmt, markdown_table
from .._threads import CALLER_STACKLEVEL, small_blas
from ..errors import DataFormatError, IdentifiabilityWarning, IdentificationError
from ..io.data import FlightData, as_float, check_flag, whole_number
from ._regression_fits import _DELAY as _DELAY
from ._regression_fits import _delay_starts as _delay_starts
from ._regression_fits import _delayed_fit as _delayed_fit
from ._regression_fits import _fit as _fit
from ._regression_fits import _frequency_fit as _frequency_fit
from ._regression_fits import derivative_name
from ._regression_fits import fourier_regression as fourier_regression
from ._regression_record import RegressionResult as RegressionResult
from ._regression_record import _r2_f as _r2_f
from ._regression_record import _result as _result
from ._regressors import _CONST as _CONST
from ._regressors import _NUMBER as _NUMBER
from ._regressors import _check_names as _check_names
from ._regressors import _column as _column
from ._regressors import _evaluate as _evaluate
from ._regressors import _mapping_columns as _mapping_columns
from ._regressors import _resolve as _resolve
from ._regressors import _resolve_records, _several_records, _with_constant
from ._regressors import _step_of as _step_of
from ._regressors import candidate_pool as candidate_pool
from ._regressors import spline_terms as spline_terms
from .least_squares import _COLLINEAR as _COLLINEAR
from .least_squares import _WELL_POSED as _WELL_POSED
from .least_squares import _collinear as _collinear
from .least_squares import _gram_stats as _gram_stats
from .least_squares import _ls_solve as _ls_solve
from .least_squares import _qr_solve as _qr_solve
from .least_squares import _reml_covariance as _reml_covariance

__all__ = [
    "RegressionResult",
    "StepwiseResult",
    "StepwiseStep",
    "candidate_pool",
    "equation_error",
    "spline_terms",
    "stepwise_regression",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_DOMAINS = ("time", "frequency")
_ERROR_BARS = ("colored", "white", "reml")


# -- equation error ------------------------------------------------------------------------------


@small_blas
def equation_error(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    regressors: Sequence[str] | Mapping[str, Any] | None = None,
    *,
    intercept: bool = True,
    error_bars: str = "colored",
    domain: str = "time",
    frequencies: ArrayLike | None = None,
    dt: float | None = None,
    time_delays: str | Sequence[str] | Mapping[str, float] | None = None,
    derivative: bool = False,
) -> RegressionResult:
    """Equation-error (ordinary least-squares) estimation of a linear model.

    Parameters
    ----------
    data : FlightData, sequence of FlightData, mapping of str to array_like, or array_like (n, p)
        Where response and regressors come from (a table with named
        columns, a pandas DataFrame, reads as the mapping of its columns:
        by name, and without `regressors` every column but the response); or
        the regressor matrix itself (then `response` is the samples and
        `regressors` the optional column names, default ``x1 .. xp``). Several records (manoeuvres,
        time domain) are fitted together, one set of parameters for all, as
        Klein & Morelli and Jategaonkar join them; the coloured bars estimate
        each record's residual spectrum apart, so no correlation is counted
        across the joins (module notes). Name the response and regressors
        then; `time_delays` and ``"reml"`` bars take one record.
    response : str or array_like
        The modelled quantity ``z``: a channel name or expression, or samples.
    regressors : sequence of str, or mapping of str to str or array_like
        Channel names or expressions (module notes), or name to expression or
        samples. Not needed with a regressor matrix.
    intercept : bool
        Add a constant term ``const`` (its transform in the frequency domain).
        Without it, an offset in the data leaks into the other estimates in
        both domains.
    error_bars : {"colored", "white", "reml"}
        Coloured-residual corrected by the lag window (default, module
        notes), classical, or corrected as output error corrects its own:
        each residual modelled as AR(1) plus white noise fitted by restricted
        maximum likelihood, with the noise model's own uncertainty widening
        the bars (``"reml"``; exact only for AR(1)-plus-white residuals: on
        real residuals of another colour it can be several times too wide,
        2-6x on real flight equations, so the default is the recommended
        bar). In the frequency domain ``"colored"`` is the frequency
        sandwich (module notes) and ``"reml"`` is refused.
    domain : {"time", "frequency"}
        Ordinary least squares on the samples, or Fourier transform
        regression at `frequencies`.
    frequencies : array_like, optional
        Frequencies in Hz for ``domain="frequency"`` (required there).
    dt : float, optional
        Sample interval in s for array input in the frequency domain, or with
        `time_delays` on a mapping (flight data carry their own).
    time_delays : str, sequence of str or mapping of str to float, optional
        Channels (controls, typically) whose pure time delay to estimate, or
        a dict of channel to start value in s. Every regressor built from a
        delayed channel uses ``c(t - tau)``, interpolated linearly between
        samples (held at the record's ends), so a delay may be a fraction of a
        sample. Each delay is found by a one-dimensional search of the
        residual sum of squares with the coefficients profiled out (a grid in
        quarter samples from 4 samples before the start to 20 after it, then
        Brent's method), and its standard error comes with the coefficients'
        from the Gauss–Newton curvature of the fit. The delays are reported
        as ``"tau_<channel>"`` in `parameters` and `stderr`, and in
        ``time_delays``. Time domain only.
    derivative : bool
        Model the response's time derivative instead of the response, with
        ``domain="frequency"`` (the state equations ``ẋ = A x + B u`` as
        ``jω X̃ = A X̃ + B Ũ``, Klein & Morelli ch. 7): its transform is
        ``jω Z̃ + z(T) e^{-jωT} - z(0)``, exact by parts, so no numerical
        derivative enters and the record need not end where it began. The
        result's `response_name` is ``"d<response>/dt"``.

    Returns
    -------
    RegressionResult

    Raises
    ------
    DataFormatError
        Malformed data, expression or option; mismatched lengths; duplicate
        names; non-uniform sampling in the frequency domain.
    ChannelError
        A named channel is missing.
    IdentificationError
        Too few samples, or a regressor that is zero or a linear combination
        of the others.
    """
    if domain not in _DOMAINS:
        raise DataFormatError(f"domain: expected one of {_DOMAINS}, got {domain!r}")
    if error_bars not in _ERROR_BARS:
        raise DataFormatError(f"error_bars: expected one of {_ERROR_BARS}, got {error_bars!r}")
    records = _several_records(data)
    lengths: tuple[int, ...] = ()
    time: FloatArray | None
    one = records[0] if records else data
    if records is not None and len(records) > 1:
        if domain != "time":
            raise DataFormatError("data: several records are fitted in the time domain only")
        if time_delays is not None and time_delays is not False:
            raise DataFormatError("time_delays: estimated on one record; give one FlightData")
        if error_bars == "reml":
            raise DataFormatError(
                "error_bars: 'reml' models one record's residuals; choose 'colored' (each "
                "record's spectrum apart) or 'white'"
            )
        z, x, names, zname, time, lengths = _resolve_records(
            records, response, regressors, "equation error"
        )
    else:
        z, x, names, zname, time = _resolve(one, response, regressors, "equation error")
    check_flag(intercept, "intercept", DataFormatError)
    use_const = bool(intercept)
    n_terms = x.shape[1] + int(use_const)
    if domain == "time" and x.shape[0] <= n_terms:
        raise IdentificationError(
            f"equation error: {x.shape[0]} samples cannot fit {n_terms} parameters"
        )
    if domain == "time" and frequencies is not None:
        raise DataFormatError("frequencies: used with domain='frequency' only")
    check_flag(derivative, "derivative", DataFormatError)
    if derivative and domain != "frequency":
        raise DataFormatError(
            "derivative: the response's derivative is modelled in the frequency domain "
            "only (domain='frequency'); in time, differentiate it (aeroid.differentiate)"
        )
    if use_const and x.shape[0]:
        # a column of ones built by hand, as SIDPAC's regressor matrices carry (a zero
        # column is left to the solver, which refuses it as such)
        ends = np.flatnonzero((x[0] == x[-1]) & (x[0] != 0)).tolist()  # cheap candidates
        for j in [j for j in ends if np.all(x[:, j] == x[0, j])]:
            raise IdentificationError(
                f"regressor {names[j]!r} is constant and repeats the constant term "
                f"{_CONST!r} that intercept=True adds; drop it, or pass intercept=False "
                "to fit your own constant column"
            )
    x, names = _with_constant(x, names, use_const)
    if time_delays is not None and time_delays is not False:
        if domain != "time":
            raise DataFormatError("time_delays: estimated in the time domain only")
        return _delayed_fit(
            one,
            z,
            response,
            regressors,
            names,
            zname,
            time,
            dt,
            time_delays,
            has_const=use_const,
            error_bars=error_bars,
        )
    if domain == "time":
        for record in records if lengths and records else ():
            _step_of(np.asarray(record.time), dt)  # a dt given must agree with every record
        # a dt given must be positive and agree with the data
        step = None if lengths else _step_of(time, dt)
        t = time if time is not None else np.arange(z.shape[0], dtype=np.float64) * (step or 1.0)
        return _fit(
            z, x, names, zname, t, has_const=use_const, error_bars=error_bars, records=lengths
        )
    if error_bars == "reml":
        raise DataFormatError(
            "error_bars: 'reml' models the residuals in time; in the frequency domain "
            "choose 'colored' or 'white'"
        )
    return _frequency_fit(
        z,
        x,
        names,
        derivative_name(zname) if derivative else zname,
        time,
        dt,
        frequencies,
        has_const=use_const,
        error_bars=error_bars,
        derivative=bool(derivative),
    )


# -- stepwise regression ---------------------------------------------------------------------


@dataclass(frozen=True)
class StepwiseStep(FrozenState):
    """One step of stepwise regression.

    Attributes
    ----------
    step : int
        0 for the starting model, then 1, 2, ...
    action : {"start", "enter", "remove"}
    term : str
        The term entered or removed (empty at the start).
    f_value : float
        Its partial F statistic (F-to-enter or F-to-remove; NaN at the start).
    r_squared, pse : float
        Of the model after the step.
    n_terms : int
        Parameters in the model after the step, the constant included.
    """

    step: int
    action: str
    term: str
    f_value: float
    r_squared: float
    pse: float
    n_terms: int


@dataclass(frozen=True, eq=False)
class StepwiseResult(IntervalMixin):
    """Model structure chosen by stepwise regression, and its least-squares fit.

    Attributes
    ----------
    selected : tuple of str
        The candidate terms in the final model (forced terms and the constant
        excluded), in order of entry.
    forced : tuple of str
        Terms kept in every model.
    candidates : tuple of str
        The whole pool.
    steps : tuple of StepwiseStep
        Each step taken, starting model first.
    regression : RegressionResult
        Equation-error fit of the final model (constant, forced and selected
        terms) on the original, not orthogonalised, regressors.
    f_in, f_out : float
    orthogonalized : bool
    chosen_step : int
        The step whose model is the final one: the least PSE of the sequence.
    """

    selected: tuple[str, ...]
    forced: tuple[str, ...]
    candidates: tuple[str, ...]
    steps: tuple[StepwiseStep, ...]
    regression: RegressionResult
    f_in: float
    f_out: float
    orthogonalized: bool
    chosen_step: int = -1

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    @property
    def covariance(self) -> FloatArray:
        """Covariance of the selected model's parameters (its `regression`'s)."""
        return self.regression.covariance

    @property
    def parameters(self) -> Mapping[str, float]:
        """Estimates of the final model (see `regression`)."""
        return self.regression.parameters

    @property
    def stderr(self) -> Mapping[str, float]:
        """Standard errors of the final model (see `regression`)."""
        return self.regression.stderr

    @property
    def degrees_of_freedom(self) -> Mapping[str, float]:
        """Degrees of freedom of the final model's standard errors (see `regression`)."""
        return self.regression.degrees_of_freedom

    def summary(self) -> str:
        """A Markdown table of the steps followed by the final fit."""
        rows = [
            [
                f"**{s.step}**" if s.step == self.chosen_step else s.step,
                s.action,
                s.term or "—",
                "—" if not np.isfinite(s.f_value) else fmt(s.f_value),
                fmt(s.r_squared),
                fmt(s.pse),
                s.n_terms,
            ]
            for s in self.steps
        ]
        head = (
            f"Stepwise regression of {self.regression.response_name} over "
            f"{len(self.candidates)} candidates (F_in = {fmt(self.f_in)}, "
            f"F_out = {fmt(self.f_out)}"
            f"{', orthogonalised' if self.orthogonalized else ''}): "
            f"selected {', '.join(self.selected) or 'nothing'}"
            f"{f' (step {self.chosen_step}: the least PSE)' if self.chosen_step >= 0 else ''}\n\n"
        )
        table = markdown_table(["step", "action", "term", "F", "R²", "PSE", "terms"], rows)
        return head + table + "\n\n" + self.regression.summary()

    def plot(self) -> Any:
        """R² and predicted squared error after each step, and the final fit's estimates."""
        from ..reports.plotting import figure

        fig, axes = figure(3, height=2.2)
        k = np.array([s.step for s in self.steps])
        axes[0, 0].plot(k, [s.r_squared for s in self.steps], "o-")
        axes[0, 0].set_ylabel("R²")
        axes[1, 0].plot(k, [s.pse for s in self.steps], "o-", color="C1")
        axes[1, 0].set_ylabel("PSE")
        axes[1, 0].set_xlabel("step")
        names = list(self.regression.parameter_names)
        est = np.array([self.regression.parameters[n] for n in names])
        half = self.regression.margin(0.95)  # t intervals with each estimate's dof
        err = np.array([half[n] for n in names])
        axes[2, 0].errorbar(np.arange(len(names)), est, yerr=err, fmt="o", capsize=4)
        axes[2, 0].set_xticks(np.arange(len(names)), names)
        axes[2, 0].set_ylabel("estimate, 95 %")
        return fig


@small_blas
def stepwise_regression(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    candidates: Sequence[str] | Mapping[str, Any] | None = None,
    *,
    forced: Sequence[str] = (),
    intercept: bool = True,
    f_in: float = 4.0,
    f_out: float = 4.0,
    orthogonalize: bool = False,
    error_bars: str = "colored",
    max_steps: int | None = None,
) -> StepwiseResult:
    """Choose model terms from a candidate pool by stepwise regression.

    Klein & Morelli's procedure (ch. 5): starting from the constant and the
    `forced` terms, each step enters the candidate with the largest partial F
    statistic ``F = ΔSSE / s²`` if it exceeds `f_in`, then removes, one at a
    time, model terms whose partial F has fallen below `f_out`. It stops when
    no term enters or leaves (or a model would repeat). The final model is the
    one of that sequence with the least predicted squared error
    ``PSE = SSE/N + σ²_max p/N`` (σ²_max the response's variance about its
    mean, as SIDPAC's ``swr``), fitted by `equation_error`. The PSE judges the
    whole sequence, not each entry: one strong term may raise it by a hair
    (its F below 1/(1 - R²)) while the next lowers it well below, and gating
    each entry on it would stop short of the better model.

    Parameters
    ----------
    data, response
        As for `equation_error`.
    candidates : sequence of str, or mapping of str to str or array_like
        The pool: names or expressions, or name to samples (see
        `candidate_pool` and `spline_terms`). With a regressor matrix as
        `data`, the optional column names.
    forced : sequence of str
        Candidate names kept in every model.
    intercept : bool
        Include a constant term in every model.
    f_in, f_out : float
        F-to-enter and F-to-remove (textbook defaults 4); need
        ``f_out <= f_in``.
    orthogonalize : bool
        Select on orthogonal functions instead: the candidates, in pool order
        after the constant and forced terms, are orthogonalised by
        Gram–Schmidt, so each carries only what the candidates before it do
        not explain; correlated terms (``alpha``, ``alpha^2`` ...) then compete
        for the variance in a fixed order (Morelli's orthogonal modelling).
        The selected candidates are fitted on their original regressors.
    error_bars : {"colored", "white", "reml"}
        For the final fit, as in `equation_error`.
    max_steps : int, optional
        Cap on entries plus removals (default four times the pool size).

    Returns
    -------
    StepwiseResult

    Raises
    ------
    DataFormatError
        Bad data, names or options (unknown forced term, f_out > f_in ...).
    ChannelError
        A named channel is missing.
    IdentificationError
        Too few samples for the pool.
    """
    f_in_v, f_out_v = as_float(f_in), as_float(f_out)  # text is no F value
    ordered = (
        f_in_v is not None
        and f_out_v is not None
        and bool(np.isfinite(f_in_v) and np.isfinite(f_out_v) and 0 <= f_out_v <= f_in_v)
    )
    if not ordered:
        raise DataFormatError(
            f"f_in, f_out: need numbers 0 <= f_out <= f_in, got {f_in!r}, {f_out!r}"
        )
    check_flag(intercept, "intercept", DataFormatError)
    check_flag(orthogonalize, "orthogonalize", DataFormatError)
    if error_bars not in _ERROR_BARS:
        raise DataFormatError(f"error_bars: expected one of {_ERROR_BARS}, got {error_bars!r}")
    z, x, names, zname, time = _resolve(data, response, candidates, "stepwise regression")
    _check_names([*names, _CONST] if intercept else names)
    if isinstance(forced, str):
        forced = [forced]
    if not isinstance(forced, Sequence) or not all(isinstance(f, str) for f in forced):
        raise DataFormatError(f"forced: expected candidate names, got {forced!r}")
    forced_list = list(forced)
    for f in forced_list:
        if f not in names:
            raise DataFormatError(f"forced: {f!r} is not one of the candidates {names}")
        if forced_list.count(f) > 1:
            raise DataFormatError(f"forced: {f!r} is listed twice")
    n, c = x.shape
    if c == 0:
        raise DataFormatError("candidates: the pool is empty")
    if n <= int(intercept) + len(forced_list):
        raise IdentificationError(
            f"stepwise regression: {n} samples cannot fit the constant and forced terms"
        )
    f_in, f_out = float(f_in_v), float(f_out_v)  # type: ignore[arg-type]
    limit = 4 * c if max_steps is None else whole_number(max_steps, "max_steps", DataFormatError)
    # Work on centred columns when there is a constant: the constant then drops out of
    # the cross-products, and the partial F statistics are those of the full model.
    xw = x - x.mean(axis=0) if intercept else x.copy()
    zw = z - z.mean() if intercept else z
    if orthogonalize:
        order = [names.index(f) for f in forced_list] + [
            j for j in range(c) if names[j] not in forced_list
        ]
        q, r = np.linalg.qr(xw[:, order])
        ortho = q * np.diag(r)[None, :]
        xw = np.empty_like(ortho)
        xw[:, order] = ortho
    scale = np.linalg.norm(xw, axis=0)
    usable = scale > _COLLINEAR * np.maximum(np.linalg.norm(x, axis=0), 1e-300)
    xs = xw / np.where(usable, scale, 1.0)
    aug = np.column_stack([xs, zw])
    gram = aug.T @ aug
    szz = float(gram[-1, -1])
    s_dev = float(np.sum((z - z.mean()) ** 2))
    base = 1 if intercept else 0

    def stats(model: list[int]) -> tuple[float, float, float]:
        sse = _gram_stats(gram, szz, model)[0]
        p = len(model) + base
        return sse, 1.0 - sse / szz if szz > 0 else float("nan"), sse / n + s_dev / n * p / n

    model = [names.index(f) for f in forced_list]
    sse, r2, pse = stats(model)
    steps = [StepwiseStep(0, "start", "", float("nan"), r2, pse, len(model) + base)]
    visited = [list(model)]  # the model after each step
    seen = {frozenset(model)}
    while len(steps) - 1 < limit:
        changed = False
        # forward: the candidate with the largest reduction of SSE, from the parts of
        # the candidates and the response the model does not explain
        p_new = len(model) + base + 1
        free = [j for j in range(c) if j not in model and usable[j]]
        if n - p_new > 0 and free and sse > 0:
            cross = gram[np.ix_(free, free)].diagonal().copy()
            resp = gram[free, -1].copy()
            if model:
                _, theta, ginv = _gram_stats(gram, szz, model)
                if theta is None or ginv is None:
                    break
                block = gram[np.ix_(model, free)]
                cross -= np.sum(block * (ginv @ block), axis=0)
                resp -= block.T @ theta
            ok = cross > _WELL_POSED  # the columns are scaled to unit norm
            drop = np.where(ok, resp**2 / np.where(ok, cross, 1.0), -1.0)
            k = int(np.argmax(drop))
            if drop[k] > 0:
                best, best_sse = free[k], max(sse - float(drop[k]), 0.0)
                f_val = (
                    (sse - best_sse) / (best_sse / (n - p_new)) if best_sse > 0 else float("inf")
                )
                key = frozenset([*model, best])
                if f_val > f_in and key not in seen:
                    model.append(best)
                    seen.add(key)
                    sse, r2, pse = stats(model)
                    steps.append(
                        StepwiseStep(len(steps), "enter", names[best], f_val, r2, pse, p_new)
                    )
                    visited.append(list(model))
                    changed = True
        # backward: remove the weakest term while its F-to-remove is below f_out
        while len(steps) - 1 < limit:
            removable = [j for j in model if names[j] not in forced_list]
            if not removable or sse <= 0:
                break
            _, theta, ginv = _gram_stats(gram, szz, model)
            if theta is None or ginv is None:
                break
            s2 = sse / (n - len(model) - base)
            f_rem = {
                j: float(theta[k] ** 2 / ginv[k, k]) / s2
                for k, j in enumerate(model)
                if j in removable
            }
            worst = min(f_rem, key=lambda j: f_rem[j])
            key = frozenset(m for m in model if m != worst)
            if f_rem[worst] >= f_out or key in seen:
                break
            model.remove(worst)
            seen.add(key)
            sse, r2, pse = stats(model)
            steps.append(
                StepwiseStep(
                    len(steps), "remove", names[worst], f_rem[worst], r2, pse, len(model) + base
                )
            )
            visited.append(list(model))
            changed = True
        if not changed:
            break
    # the least PSE of the sequence (the earliest of equals: the fewest terms)
    chosen = min(range(len(steps)), key=lambda i: (steps[i].pse, i))
    model = visited[chosen]
    _warn_unweighed(gram, szz, model, [j for j in range(c) if j not in model and usable[j]], names)
    selected = [names[j] for j in model if names[j] not in forced_list]
    keep = [names.index(f) for f in forced_list] + [j for j in model if names[j] not in forced_list]
    fnames = [names[j] for j in keep]
    xf = x[:, keep]
    if intercept:
        fnames = [_CONST, *fnames]
        xf = np.column_stack([np.ones(n), xf])
    if not fnames:
        raise IdentificationError("stepwise regression: no term selected and no constant term")
    t = time if time is not None else np.arange(n, dtype=np.float64)
    regression = _fit(z, xf, fnames, zname, t, has_const=intercept, error_bars=error_bars)
    return StepwiseResult(
        selected=tuple(selected),
        forced=tuple(forced_list),
        candidates=tuple(names),
        steps=tuple(steps),
        regression=regression,
        f_in=f_in,
        f_out=f_out,
        orthogonalized=bool(orthogonalize),
        chosen_step=chosen,
    )


def _warn_unweighed(
    gram: NDArray[np.float64], szz: float, model: list[int], free: list[int], names: list[str]
) -> None:
    """Warn naming the candidates the steps never weighed: with the model's terms each
    leaves less than `_WELL_POSED` of its (unit) norm unexplained, a variance inflation
    above 1e8, where its partial F is rounding."""
    if not model or not free:
        return
    _, _, ginv = _gram_stats(gram, szz, model)
    if ginv is None:
        return
    block = gram[np.ix_(model, free)]
    left = gram[np.ix_(free, free)].diagonal() - np.sum(block * (ginv @ block), axis=0)
    unseen = [names[j] for j, v in zip(free, left, strict=True) if not v > _WELL_POSED]
    if unseen:
        warnings.warn(
            f"stepwise regression: {unseen} never weighed: each is, to 1 part in 1e8 of its "
            f"norm, a combination of the model's terms {[names[j] for j in model]} (variance "
            "inflation above 1e8), where its partial F is rounding; where it carries a real "
            "effect, enter the small difference itself (x2 - x1, rescaled) as a candidate",
            IdentifiabilityWarning,
            stacklevel=CALLER_STACKLEVEL + 1,
        )
