"""Recursive least squares: equation error updated sample by sample, as a real-time
estimator runs it (Klein & Morelli, ch. 8).

After sample k the estimate minimises the exponentially weighted cost

    J_k(theta) = sum_{i<=k} lambda^(k-i) (z_i - x_i' theta)^2
                 + lambda^k (theta - theta_0)' P_0^-1 (theta - theta_0),

with `lambda` the forgetting factor: one (the default) remembers the whole record,
so that with a diffuse start the last estimate is the batch least-squares one;
below one, old samples fade with a memory of about ``1 / (1 - lambda)`` samples
and the estimate tracks parameters that change. Each update is the classical
one: the gain ``g = P x / (lambda + x'P x)``, the estimate moved by g times the
prediction error ``eps = z - x' theta``, ``P`` updated as ``(P - g x'P) / lambda``.
The cost's minimum obeys ``J_k = lambda J_(k-1) + eps^2 lambda / (lambda + x'P x)``
exactly, so the running fit-error variance ``J_k / (n_k - p)`` (``n_k`` the
weighted sample count) is the batch one at every sample, not the sum of a
posteriori residuals, which under-reads it while the estimate still moves.
Below one the weights are not inverse noise variances, so the estimate's
covariance is the sandwich ``s^2 P Q P`` with ``Q = sum lambda^(2(k-i)) x_i x_i'``
(about ``s^2 P / (1 + lambda)`` for steady regressors, not ``s^2 P``), the noise
variance ``s^2 = J_k / (n_k - tr(P Q))`` (unbiased for white noise) and its
degrees of freedom ``(sum w)^2 / sum w^2 - p``; at one all three are the
classical ones.

With ``domain="frequency"`` it is Morelli's real-time estimator in the
frequency domain (Klein & Morelli sec. 8.2, `_recursive_frequency`): running
Fourier transforms, and at chosen times the Fourier transform regression of
the record so far. Only the chosen band enters, so the estimates need no
filtering of the measurements and are not biased by noise outside it.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._colour import colored_covariance
from .._records import IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table
from .._value_checks import check_flag, check_symmetric
from ..errors import (
    ChannelError,
    DataFormatError,
    IdentifiabilityWarning,
    IdentificationError,
)
from ..io.data import FlightData
from ..models.model import real_number
from ._recursive_frequency import frequency_recursion, update_indices
from ._regression_fits import (
    _classical_where_not_positive,
    _frequency_grid,
    _frequency_step,
    derivative_name,
)
from ._regressors import _resolve, _with_constant
from .least_squares import _ls_solve

__all__ = ["RecursiveResult", "recursive_least_squares"]

FloatArray = NDArray[np.float64]

_CONST = "const"
_DOMAINS = ("time", "frequency")
# SIDPAC's rtpid: an update every second from two seconds in
_UPDATE_INTERVAL = 1.0
_FIRST_UPDATE = 2.0
_ERROR_BARS = ("colored", "white")
# SIDPAC's and Klein & Morelli's start: a covariance this large times the identity,
# diffuse against the information of regressors of order one.
_DIFFUSE = 1.0e6


@dataclass(frozen=True, eq=False)
class RecursiveResult(IntervalMixin):
    """Recursive least-squares estimates: the last sample's, and their history.

    Attributes
    ----------
    parameters, stderr : mapping of str to float
        The estimates after the last sample and their standard errors
        (coloured-residual corrected unless ``error_bars == "white"``).
    covariance : ndarray, shape (p, p)
        Their covariance in the order of `parameter_names`.
    parameter_names : tuple of str
    response_name : str
    time : ndarray, shape (n,)
    history : ndarray, shape (n, p)
        The estimate after each sample.
    stderr_history : ndarray, shape (n, p)
        Each estimate's white-noise standard error from the samples up to it
        (the running fit-error variance times ``diag P``, or ``diag P Q P``
        with forgetting, module notes); NaN until the weighted sample count
        exceeds the number of parameters.
    gain_history : ndarray, shape (n, p)
        The update gain ``g`` at each sample (NaN in the frequency domain, where
        each update is a solution, not a gain).
    fit_error_history : ndarray, shape (n,)
        The running fit-error standard deviation ``sqrt(J_k / (n_k - p))``
        (``sqrt(J_k / (n_k - tr(P Q)))`` with forgetting).
    prediction_errors : ndarray, shape (n,)
        ``z_k - x_k' theta_(k-1)``: each sample's error predicted from the
        estimate before it (the real-time residual). In the frequency domain,
        the same for the deviations from the first sample with the latest
        update's estimate (NaN before the first update, and throughout when
        the response's derivative is modelled).
    forgetting : float
    error_bars : {"colored", "white"}
    degrees_of_freedom : mapping of str to float
        Per estimate, the degrees of freedom of its final standard error.
    domain : {"time", "frequency"}
    frequencies : ndarray
        The frequencies fitted, Hz (frequency domain; empty in time).
    dof_history : ndarray, shape (n, p)
        The degrees of freedom of each `stderr_history` entry, for its t
        quantile: the weighted sample count less ``p`` in time; in frequency
        each update's (few while the record is short, when frequencies closer
        than it resolves share their noise).
    update_times : ndarray
        When the estimate was updated (frequency domain: every sample's
        history holds the latest update, NaN before the first; in time, every
        sample, so empty).
    """

    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    parameter_names: tuple[str, ...]
    response_name: str
    time: FloatArray
    history: FloatArray
    stderr_history: FloatArray
    gain_history: FloatArray
    fit_error_history: FloatArray
    prediction_errors: FloatArray
    forgetting: float
    error_bars: str
    degrees_of_freedom: Mapping[str, float] = field(default_factory=dict)
    domain: str = "time"
    frequencies: FloatArray = field(default_factory=lambda: np.zeros(0))
    update_times: FloatArray = field(default_factory=lambda: np.zeros(0))
    dof_history: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))

    def __post_init__(self) -> None:
        for name in ("parameters", "stderr", "degrees_of_freedom"):
            object.__setattr__(self, name, frozen_mapping(getattr(self, name)))
        for name in (
            "covariance",
            "time",
            "history",
            "stderr_history",
            "gain_history",
            "fit_error_history",
            "prediction_errors",
            "frequencies",
            "update_times",
            "dof_history",
        ):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))

    def parameter(self, name: str) -> FloatArray:
        """The history of one estimate, shape (n,)."""
        if name not in self.parameter_names:
            raise ChannelError(
                f"parameter {name!r} not estimated; parameters: {list(self.parameter_names)}"
            )
        return self.history[:, self.parameter_names.index(name)]

    def summary(self) -> str:
        """A Markdown table of the final estimates, with the memory and fit error."""
        rows = []
        for name in self.parameter_names:
            est, se = self.parameters[name], self.stderr[name]
            rows.append([name, fmt(est), fmt(se), fmt(abs(est) / se if se > 0 else np.inf, 3)])
        memory = (
            "the whole record"
            if self.forgetting == 1.0
            else f"about {fmt(1.0 / (1.0 - self.forgetting), 3)} samples"
        )
        if self.domain == "frequency":
            f = self.frequencies
            how = (
                f"in the frequency domain ({f.size} frequencies, {fmt(float(f.min()), 3)}-"
                f"{fmt(float(f.max()), 3)} Hz), {self.update_times.size} updates"
            )
        else:
            how = f"forgetting factor {fmt(self.forgetting, 6)} (memory {memory})"
        head = (
            f"Recursive least squares for {self.response_name}: {self.time.size} samples, "
            f"{len(self.parameter_names)} parameters, {how}, {self.error_bars} error bars\n\n"
        )
        tail = f"\n\nfinal fit error s = {fmt(float(self.fit_error_history[-1]))}"
        table = markdown_table(["parameter", "estimate", "std error", "|t|"], rows)
        return head + table + tail

    def plot(self) -> Any:
        """Each estimate's history with its running 95 % band (Student's t at its
        degrees of freedom). Returns a Figure."""
        from scipy import stats

        from ..reports.plotting import figure

        names = list(self.parameter_names)
        fig, axes = figure(len(names), height=1.8)
        for j, name in enumerate(names):
            ax = axes[j, 0]
            est, se = self.history[:, j], self.stderr_history[:, j]
            dof = self.dof_history[:, j] if self.dof_history.size else np.full(est.shape, np.inf)
            with np.errstate(invalid="ignore"):
                half = stats.t.ppf(0.975, np.where(dof > 0, dof, np.nan)) * se
            ax.plot(self.time, est, lw=0.9)
            ax.fill_between(self.time, est - half, est + half, alpha=0.25, lw=0)
            ax.set_ylabel(name)
        axes[-1, 0].set_xlabel("time (s)")
        return fig


def recursive_least_squares(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    regressors: Sequence[str] | Mapping[str, Any] | None = None,
    *,
    intercept: bool = True,
    forgetting: float = 1.0,
    initial: Mapping[str, float] | None = None,
    initial_covariance: float | ArrayLike | None = None,
    error_bars: str | None = None,
    domain: str = "time",
    frequencies: ArrayLike | None = None,
    dt: float | None = None,
    update_interval: float | None = None,
    first_update: float | None = None,
    derivative: bool = False,
) -> RecursiveResult:
    """Equation-error estimates updated sample by sample (recursive least squares).

    The real-time form of `equation_error` (Klein & Morelli, ch. 8): after
    each sample the estimate minimises the exponentially weighted squared
    error of the samples so far plus the start's weight (module notes), so
    its history shows when each parameter became identifiable and, with a
    forgetting factor below one, follows parameters that change.

    Parameters
    ----------
    data, response, regressors
        As `equation_error`: flight data (or a mapping, or the regressor
        matrix itself), the modelled quantity and the regressors, by channel
        name or expression.
    intercept : bool
        Add a constant term ``const``.
    forgetting : float
        The forgetting factor ``lambda`` in (0, 1]; below one the estimator
        remembers about ``1 / (1 - lambda)`` samples (0.95-1 in practice).
    initial : mapping of str to float, optional
        The start ``theta_0`` by parameter name (others start at zero).
    initial_covariance : float or array_like (p, p), optional
        ``P_0``: a variance for every parameter, or the matrix in the order of
        the result's `parameter_names`; default ``1e6`` times the identity
        (SIDPAC's), diffuse for regressors of order one. Choose it large
        against the inverse of the information a few samples carry, or the
        start biases the estimates.
    error_bars : {"colored", "white"}, optional
        The final standard errors: coloured-residual corrected as
        `equation_error` corrects its own (the default with ``forgetting ==
        1``, where the final estimate is that estimator's), or white-noise
        bars (``s^2 P``, and below one, where they are the default, the
        weighted estimate's ``s^2 P Q P``, module notes). In time the history
        is always white: it is what the samples so far can tell. In the frequency
        domain every update's bars are the chosen kind, each the batch
        estimator's on the record so far: early on, frequencies closer than
        the short record resolves share their noise, which the classical bars
        would count as independent.
    domain : {"time", "frequency"}
        Update sample by sample in time, or Morelli's real-time estimator in
        the frequency domain (Klein & Morelli sec. 8.2; SIDPAC's ``rtpid``):
        the Fourier transforms of the response and regressors, as deviations
        from their first sample, are carried forward sample by sample, and at
        each update the estimate is `equation_error`'s with
        ``domain="frequency"`` on the record so far (the constant, when there
        is one, fits what is left of the offsets; where every frequency sits
        on the whole record's ``1/T`` grid, on which a constant has no
        transform, it is left out of the result, history included, as
        `equation_error` leaves it out). There is no start and no
        forgetting: `initial`, `initial_covariance` and `forgetting` are time
        domain options.
    frequencies : array_like, optional
        Frequencies in Hz for ``domain="frequency"`` (required there): the band
        of the motion, such as SIDPAC's 0.1-1.5 Hz in steps of 0.04 Hz.
    dt : float, optional
        Sample interval in s for array input in the frequency domain.
    update_interval, first_update : float, optional
        Frequency domain: update every `update_interval` seconds (at least a
        sample interval; default 1 s) from `first_update` seconds after the
        first sample (default 2 s), and after the last sample (SIDPAC's
        ``rtpid`` times). Updates before the record determines every
        parameter (a control not yet moved) leave the history NaN.
    derivative : bool
        Frequency domain: model the response's time derivative (state
        equations), as `equation_error` does with ``derivative=True``. The
        deviations from the first sample then obey the state equation plus
        its first derivative ``ẋ(0)``, which the constant term takes: with
        ``intercept=False`` the record must start at trim.

    Returns
    -------
    RecursiveResult

    Raises
    ------
    DataFormatError
        Malformed data, expression or option.
    ChannelError
        A named channel is missing.
    IdentificationError
        No more samples than parameters.
    """
    if domain not in _DOMAINS:
        raise DataFormatError(f"domain: expected one of {_DOMAINS}, got {domain!r}")
    check_flag(derivative, "derivative", DataFormatError)
    if domain == "frequency":
        return _in_frequency(
            data,
            response,
            regressors,
            intercept=intercept,
            forgetting=forgetting,
            initial=initial,
            initial_covariance=initial_covariance,
            error_bars=error_bars,
            frequencies=frequencies,
            dt=dt,
            update_interval=update_interval,
            first_update=first_update,
            derivative=bool(derivative),
        )
    for option, value in (
        ("frequencies", frequencies),
        ("dt", dt),
        ("update_interval", update_interval),
        ("first_update", first_update),
    ):
        if value is not None:
            raise DataFormatError(f"{option}: used with domain='frequency' only")
    if derivative:
        raise DataFormatError(
            "derivative: modelled in the frequency domain only (domain='frequency'); in "
            "time, differentiate the response (aeroid.differentiate)"
        )
    lam = real_number(forgetting, "forgetting", DataFormatError, finite=True)
    if not 0.0 < lam <= 1.0:
        raise DataFormatError(f"forgetting: expected a factor in (0, 1], got {forgetting!r}")
    bars = error_bars if error_bars is not None else ("colored" if lam == 1.0 else "white")
    if bars not in _ERROR_BARS:
        raise DataFormatError(f"error_bars: expected one of {_ERROR_BARS}, got {error_bars!r}")
    if bars == "colored" and lam < 1.0:
        raise DataFormatError(
            "error_bars: 'colored' corrects the whole record's estimate (forgetting = 1); "
            "with a forgetting factor below one the final bars are 'white'"
        )
    z, x, names, zname, time = _columns(data, response, regressors, intercept)
    n, p = x.shape
    if n <= p:
        raise IdentificationError(f"recursive least squares: {n} samples cannot fit {p} parameters")
    if lam < 1.0 and 1.0 / (1.0 - lam) <= p:
        raise DataFormatError(
            f"forgetting: {lam!r} remembers about {1.0 / (1.0 - lam):.3g} samples, no more "
            f"than the {p} parameters: no estimate could be told from the noise"
        )
    theta0 = _start(initial, names)
    p0 = _start_covariance(initial_covariance, names)
    t = time if time is not None else np.arange(n, dtype=np.float64)
    hist, se_hist, gains, s_hist, eps, cov_p, dof_hist = _recursion(z, x, theta0, p0, lam)
    theta = hist[-1]
    s2 = float(s_hist[-1]) ** 2
    cov_white = s2 * cov_p
    nu = dof_hist[-1].copy()
    if bars == "colored" and not _separable(x, names):
        bars = "white"  # what the data cannot see rests on the start: its covariance says so
    if bars == "colored":
        v = z - x @ theta
        cov, nu = colored_covariance([x[:, None, :]], [v[:, None]], cov_p)
        # the estimate leans on the start where the data are nearly silent (a direction
        # of collinear regressors): that share, s^2 P P0^-1 P, is the classical bars'
        start = s2 * cov_p @ np.linalg.solve(p0, cov_p)
        leans = np.diag(start) > np.diag(cov)
        cov = cov + start
        nu[leans] = float(n - p)
        _classical_where_not_positive(cov, cov_white, nu, n - p)
    else:
        cov = cov_white
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return RecursiveResult(
        parameters={k: float(theta[j]) for j, k in enumerate(names)},
        stderr={k: float(se[j]) for j, k in enumerate(names)},
        covariance=cov,
        parameter_names=tuple(names),
        response_name=zname,
        time=t,
        history=hist,
        stderr_history=se_hist,
        gain_history=gains,
        fit_error_history=s_hist,
        prediction_errors=eps,
        forgetting=lam,
        error_bars=bars,
        degrees_of_freedom={k: float(nu[j]) for j, k in enumerate(names)},
        dof_history=dof_hist,
    )


def _in_frequency(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    regressors: Sequence[str] | Mapping[str, Any] | None,
    *,
    intercept: bool,
    forgetting: float,
    initial: Mapping[str, float] | None,
    initial_covariance: float | ArrayLike | None,
    error_bars: str | None,
    frequencies: ArrayLike | None,
    dt: float | None,
    update_interval: float | None,
    first_update: float | None,
    derivative: bool,
) -> RecursiveResult:
    """`recursive_least_squares` with ``domain="frequency"``."""
    lam = real_number(forgetting, "forgetting", DataFormatError, finite=True)
    if lam != 1.0:
        raise DataFormatError(
            "forgetting: the frequency-domain estimator remembers the whole record "
            f"(forgetting = 1); got {forgetting!r}"
        )
    for option, value in (("initial", initial), ("initial_covariance", initial_covariance)):
        if value is not None:
            raise DataFormatError(
                f"{option}: the frequency-domain estimator solves each update from the "
                "record so far, with no start (a time-domain option)"
            )
    bars = "colored" if error_bars is None else error_bars
    if bars not in _ERROR_BARS:
        raise DataFormatError(f"error_bars: expected one of {_ERROR_BARS}, got {error_bars!r}")
    z, x, names, zname, time = _columns(data, response, regressors, intercept)
    if x.shape[0] < 2:
        raise IdentificationError("recursive least squares: fewer than two samples")
    step = _frequency_step(time, dt)
    freq = _frequency_grid(frequencies, step, x.shape[1])
    t = time if time is not None else np.arange(x.shape[0], dtype=np.float64) * step
    interval = real_number(
        _UPDATE_INTERVAL if update_interval is None else update_interval,
        "update_interval",
        DataFormatError,
        finite=True,
    )
    first = real_number(
        _FIRST_UPDATE if first_update is None else first_update,
        "first_update",
        DataFormatError,
        finite=True,
    )
    run = frequency_recursion(
        z,
        x,
        names,
        derivative_name(zname) if derivative else zname,
        t,
        step,
        freq,
        has_const=bool(intercept),
        derivative=derivative,
        updates=update_indices(x.shape[0], step, first, interval),
        error_bars=bars,
    )
    fit = run.final
    return RecursiveResult(
        parameters=fit.parameters,
        stderr=fit.stderr,
        covariance=fit.covariance,
        parameter_names=fit.parameter_names,
        response_name=fit.response_name,
        time=t,
        history=run.history,
        stderr_history=run.stderr_history,
        gain_history=np.full(run.history.shape, np.nan),
        fit_error_history=run.fit_error_history,
        prediction_errors=run.prediction_errors,
        forgetting=1.0,
        error_bars=bars,
        degrees_of_freedom=fit.degrees_of_freedom,
        domain="frequency",
        frequencies=freq,
        update_times=run.update_times,
        dof_history=run.dof_history,
    )


def _columns(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    regressors: Sequence[str] | Mapping[str, Any] | None,
    intercept: bool,
) -> tuple[FloatArray, FloatArray, list[str], str, FloatArray | None]:
    """The response and the regressor columns, with the constant first if asked."""
    check_flag(intercept, "intercept", DataFormatError)
    z, x, names, zname, time = _resolve(data, response, regressors, "recursive least squares")
    x, names = _with_constant(x, names, intercept)
    return z, x, names, zname, time


def _separable(x: FloatArray, names: list[str]) -> bool:
    """Whether the regressors alone determine every parameter (the batch fit would run);
    warns naming them where they do not (a constant, zero or collinear regressor), whose
    estimates then rest on the start."""
    try:
        _ls_solve(x, np.zeros(x.shape[0]), names)
    except IdentificationError as exc:
        warnings.warn(
            f"recursive_least_squares: {exc}; the estimates along it rest on the start, so "
            "the final error bars are the classical ones from the start's covariance",
            IdentifiabilityWarning,
            stacklevel=3,  # here, recursive_least_squares, the caller
        )
        return False
    return True


def _recursion(
    z: FloatArray, x: FloatArray, theta0: FloatArray, p0: FloatArray, lam: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The update over every sample: estimate, standard error, gain and fit-error
    histories, the prediction errors, the last estimates' covariance per unit noise
    variance (``P``, or ``P Q P`` with forgetting) and the standard errors' degrees
    of freedom."""
    n, p = x.shape
    hist = np.empty((n, p))
    se_hist = np.full((n, p), np.nan)
    gains = np.empty((n, p))
    s_hist = np.full(n, np.nan)
    dof_hist = np.full((n, p), np.nan)
    eps_all = np.empty(n)
    theta = theta0.copy()
    cov = p0.copy()
    cost = 0.0
    count = 0.0
    count2 = 0.0  # sum of the squared weights
    info2 = np.zeros((p, p))  # Q: the information with the weights squared
    for k in range(n):
        xk = x[k]
        px = cov @ xk
        den = lam + float(xk @ px)
        gain = px / den
        eps = float(z[k] - xk @ theta)
        theta = theta + gain * eps
        cov = (cov - np.outer(gain, px)) / lam
        cov = 0.5 * (cov + cov.T)  # rounding would make it drift off symmetric
        cost = lam * cost + eps * eps * lam / den
        count = lam * count + 1.0
        hist[k] = theta
        gains[k] = gain
        eps_all[k] = eps
        if lam < 1.0:
            count2 = lam * lam * count2 + 1.0
            info2 = lam * lam * info2 + np.outer(xk, xk)
        if count > p:
            s2, var, dof = _bar_terms(cost, count, count2, cov, info2, p, lam)
            s_hist[k] = np.sqrt(s2)
            se_hist[k] = np.sqrt(np.clip(var, 0.0, None))
            dof_hist[k] = dof
    if not (np.all(np.isfinite(hist[-1])) and np.all(np.isfinite(cov))):
        raise IdentificationError(
            "recursive least squares: the update overflowed; rescale the response or "
            "the regressors, or give a smaller initial_covariance"
        )
    # the estimates' covariance per unit noise variance (module notes, `_bar_terms`)
    unit = cov if lam == 1.0 else cov @ info2 @ cov
    return hist, se_hist, gains, s_hist, eps_all, unit, dof_hist


def _bar_terms(
    cost: float,
    count: float,
    count2: float,
    cov: FloatArray,
    info2: FloatArray,
    p: int,
    lam: float,
) -> tuple[float, FloatArray, float]:
    """The noise variance, the estimates' variances and their degrees of freedom
    after a sample, from the cost, the weight sums ``sum w`` and ``sum w^2``, ``P``
    and ``Q = sum w^2 x x'``."""
    if lam == 1.0:
        s2 = cost / (count - p)
        return s2, s2 * np.diag(cov), count - p
    # The weights lambda^(k-i) are not inverse variances (the noise is white), so the
    # estimate P X'W z has covariance sigma^2 P Q P, not sigma^2 P. The weighted
    # residual sum of squares has mean sigma^2 (sum w - tr(P Q)) (tr(W (I - H)), H the
    # weighted hat matrix), which gives the unbiased s^2; that sum mixes about
    # (sum w)^2 / sum w^2 independent squares (Satterthwaite), whose count less the p
    # parameters is the t quantile's degrees of freedom. Both reduce to n - p at
    # lambda = 1, where Q = P^-1 up to the start.
    cov_info2 = cov @ info2
    s2 = cost / (count - float(np.trace(cov_info2)))
    var = s2 * np.sum(cov_info2 * cov, axis=1)  # diag(P Q P), P symmetric
    return s2, var, count * count / count2 - p


def _start(initial: Mapping[str, float] | None, names: list[str]) -> FloatArray:
    theta0 = np.zeros(len(names))
    if initial is None:
        return theta0
    if not isinstance(initial, Mapping):
        raise DataFormatError(
            f"initial: expected a dict of parameter name -> value, got {type(initial).__name__}"
        )
    for name, value in initial.items():
        if name not in names:
            raise DataFormatError(
                f"initial: {name!r} is not a parameter of this regression; parameters: {names}"
            )
        theta0[names.index(name)] = real_number(
            value, f"initial[{name!r}]", DataFormatError, finite=True
        )
    return theta0


def _start_covariance(value: float | ArrayLike | None, names: list[str]) -> FloatArray:
    p = len(names)
    if value is None:
        return _DIFFUSE * np.eye(p)
    if np.ndim(value) == 0:
        v = real_number(value, "initial_covariance", DataFormatError, finite=True)
        if not v > 0.0:
            raise DataFormatError(f"initial_covariance: expected a positive variance, got {v!r}")
        return v * np.eye(p)
    try:
        mat = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataFormatError("initial_covariance: not numeric") from None
    if mat.shape != (p, p):
        raise DataFormatError(
            f"initial_covariance: expected a number or a ({p}, {p}) matrix in the order "
            f"{names}, got shape {mat.shape}"
        )
    if not np.all(np.isfinite(mat)):
        raise DataFormatError("initial_covariance: contains NaN or infinite values")
    check_symmetric(mat, names, "initial_covariance", DataFormatError)
    if np.linalg.eigvalsh(mat).min() <= 0.0:
        raise DataFormatError("initial_covariance: not positive definite")
    return mat
