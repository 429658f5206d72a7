"""Equation-error and stepwise regression (Klein & Morelli, ch. 5 and 7).

Equation error fits a measured force or moment coefficient (or a state
derivative) ``z`` as a linear combination of regressors ``X`` by ordinary
least squares, ``θ = (X'X)^-1 X'z``. Regressors and the response are channels
of flight data, arrays, or simple expressions of channels:

* a channel name: ``"alpha"``;
* products, quotients and integer or real powers of channels and numbers,
  without parentheses: ``"alpha*q"``, ``"alpha^2"`` (or ``"alpha**2"``),
  ``"q/V"``, ``"0.5*q*de"``.

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
records, white or AR(1) with φ = 0.9) at an order of magnitude more work,
so the spectral estimate stays the default of this fast first step.

Fit statistics follow Klein & Morelli: ``R² = 1 − SSE/SST`` (SST about the
mean when there is a constant term), the F statistic of the regression
``F = [(SST − SSE)/k] / [SSE/(N − p)]`` with ``k`` the regressors other
than the constant, and the predicted squared error
``PSE = SSE/N + σ²_max p/N``, ``σ²_max = Σ (z − z̄)²/N``.

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
where it has no content: at multiples of ``1/(NΔt)``). Transformed residuals
at distinct frequencies are nearly independent, and the error bars use the
classical formula with the residual variance ``Σ|Ṽ|²/(2M − p)`` per real
component.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._colour import colored_covariance
from ._czt import fourier
from ._records import IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table
from ._threads import small_blas
from .data import (
    FlightData,
    as_float,
    check_flag,
    delay_starts,
    positive_number,
    real_array,
    whole_number,
)
from .errors import ChannelError, DataFormatError, IdentificationError

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

_CONST = "const"
_DELAY = "tau_"
_DOMAINS = ("time", "frequency")
_ERROR_BARS = ("colored", "white", "reml")
# A regressor whose part independent of the earlier ones is below this fraction of its
# own norm is a linear combination of them to working precision.
_COLLINEAR = 1e-9
# Below this 1 - R^2 of a regressor on the others (condition number of the scaled
# Gram matrix above ~1e10) the normal equations lose digits; QR is used instead.
_WELL_POSED = 1e-8
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


# -- input resolution ----------------------------------------------------------------------


def _evaluate(lookup: Mapping[str, Any], expr: str, n: int, role: str) -> FloatArray:
    """Value of a channel name or a product/quotient/power expression of channels."""
    if repr(expr) not in role:
        role = f"{role} {expr!r}"
    if expr in lookup:
        column = np.asarray(lookup[expr], dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            raise DataFormatError(f"{role}: non-finite value at sample {int(bad[0])}")
        return column
    text = expr.replace("**", "^").replace(" ", "")
    if not text:
        raise DataFormatError(f"{role}: empty expression")
    parts = re.split(r"([*/])", text)
    out = np.ones(n)
    op = "*"
    for k, part in enumerate(parts):
        if k % 2 == 1:
            op = part
            continue
        base, _, power = part.partition("^")
        if not base:
            raise DataFormatError(f"{role}: cannot parse {part!r}")
        if _NUMBER.match(base):
            value: Any = float(base)
        elif base in lookup:
            value = np.asarray(lookup[base], dtype=np.float64)
        else:
            hint = (
                f"; {_CONST!r} is the constant term, added by intercept=True"
                if base == _CONST
                else ""
            )
            raise ChannelError(
                f"{role}: channel {base!r} not found; channels present: {sorted(lookup)}{hint}"
            )
        if power:
            if not _NUMBER.match(power):
                raise DataFormatError(f"{role}: power {power!r} is not a number")
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                value = np.power(value, float(power))
        # overflow and division by zero are reported below, by name, not as warnings
        with np.errstate(all="ignore"):
            out = out * value if op == "*" else out / value
    if not np.all(np.isfinite(out)):
        raise DataFormatError(
            f"{role}: non-finite value (division by zero, or a negative number to a fractional power?)"
        )
    return out


def _column(lookup: Mapping[str, Any], value: Any, n: int, role: str) -> FloatArray:
    if isinstance(value, str):
        return _evaluate(lookup, value, n, role)
    arr = real_array(value, role)
    if arr.shape != (n,):
        raise DataFormatError(f"{role}: expected {n} samples, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(
            f"{role}: non-finite value at sample {int(np.argmin(np.isfinite(arr)))}"
        )
    return arr


def _mapping_columns(data: Mapping[Any, Any]) -> tuple[dict[str, FloatArray], int]:
    """A mapping's entries as named 1-D float arrays of one length, and that length."""
    lookup = {str(k): real_array(v, f"data[{str(k)!r}]") for k, v in data.items()}
    if not lookup:
        raise DataFormatError("data: the mapping holds no channels")
    first, n = None, -1
    for name, col in lookup.items():
        if col.ndim != 1:
            raise DataFormatError(f"data[{name!r}]: expected a 1-D array, got shape {col.shape}")
        if first is None:
            first, n = name, col.shape[0]
        elif col.shape[0] != n:
            raise DataFormatError(
                f"data[{name!r}]: {col.shape[0]} samples where data[{first!r}] has {n}"
            )
    return lookup, n


def _resolve(
    data: Any, response: Any, regressors: Any, what: str
) -> tuple[FloatArray, FloatArray, list[str], str, FloatArray | None]:
    """Response, regressor matrix, regressor names, response name and time axis."""
    time: FloatArray | None = None
    if isinstance(data, FlightData):
        lookup: Mapping[str, Any] = data.channels
        n = data.n_samples
        time = np.asarray(data.time)
    elif isinstance(data, Mapping):
        lookup, n = _mapping_columns(data)
    else:
        if isinstance(data, (str, bytes)):
            raise DataFormatError(
                "data: expected FlightData, a mapping of arrays or a regressor matrix, got str"
            )
        mat = real_array(data, "data (a regressor matrix)")
        if mat.ndim != 2:
            raise DataFormatError(
                f"data: a regressor matrix must be 2-D (samples, regressors), got shape {mat.shape}"
            )
        if not np.all(np.isfinite(mat)):
            raise DataFormatError("data: the regressor matrix holds non-finite values")
        n, p = mat.shape
        if regressors is None:
            names = [f"x{j + 1}" for j in range(p)]
        elif isinstance(regressors, str) or len(regressors) != p:
            raise DataFormatError(
                f"regressors: with a regressor matrix give {p} names, got {regressors!r}"
            )
        else:
            names = [str(r) for r in regressors]
        z = _column({}, response, n, "response") if not isinstance(response, str) else None
        if z is None:
            raise DataFormatError("response: with a regressor matrix give the response samples")
        return z, mat, names, "z", None
    if isinstance(response, str):
        zname = response
        z = _evaluate(lookup, response, n, "response")
    else:
        zname = "z"
        z = _column(lookup, response, n, "response")
    if regressors is None:
        role = "candidates" if what.startswith("stepwise") else "regressors"
        raise DataFormatError(f"{role}: required for {what} on flight data or a mapping")
    if isinstance(regressors, str):
        regressors = [regressors]
    if not isinstance(regressors, (Mapping, Sequence)):
        role = "candidates" if what.startswith("stepwise") else "regressors"
        raise DataFormatError(
            f"{role}: expected names or expressions, or a mapping of name to samples, "
            f"got {type(regressors).__name__}"
        )
    if isinstance(regressors, Mapping):
        items = [(str(k), v) for k, v in regressors.items()]
    else:
        items = []
        for r in regressors:
            if not isinstance(r, str):
                raise DataFormatError(
                    "regressors: give names/expressions, or a mapping of name to samples"
                )
            items.append((r, r))
    cols = [_column(lookup, v, n, f"regressor {k!r}") for k, v in items]
    mat = np.column_stack(cols) if cols else np.zeros((n, 0))
    return z, mat, [k for k, _ in items], zname, time


def _check_names(names: Sequence[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise DataFormatError(f"regressors: the name {name!r} appears twice")
        seen.add(name)


def _step_of(time: FloatArray | None, dt: float | None) -> float | None:
    if time is not None:
        steps = np.diff(time)
        if np.ptp(steps) > 1e-6 * float(np.mean(steps)):
            return None
        step = float(np.mean(steps))
        if dt is not None and not np.isclose(
            positive_number(dt, "dt", " of seconds"), step, rtol=1e-6
        ):
            raise DataFormatError(f"dt: {dt!r} contradicts the data's sample interval {step:.6g} s")
        return step
    if dt is None:
        return None
    return positive_number(dt, "dt", " of seconds")


# -- least squares core ----------------------------------------------------------------------


def _collinear(names: Sequence[str], j: int) -> IdentificationError:
    return IdentificationError(
        f"regressor {names[j]!r} is zero or a linear combination of "
        f"{list(names[:j]) or 'nothing'}; drop it or the regressors it repeats"
    )


def _qr_solve(x: FloatArray, z: FloatArray, names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
    """Least-squares parameters and (X'X)^-1 by Householder QR; refuses collinear columns."""
    q, r = np.linalg.qr(x)
    norms = np.linalg.norm(x, axis=0)
    diag = np.abs(np.diag(r))
    for j in range(x.shape[1]):
        if not diag[j] > _COLLINEAR * norms[j] or norms[j] == 0:
            raise _collinear(names, j)
    # R is only p x p: a plain inverse is cheaper here than LAPACK's triangular solver
    r_inv = np.linalg.inv(r)
    theta = r_inv @ (q.T @ z)
    return theta, r_inv @ r_inv.T


def _ls_solve(
    x: FloatArray, z: FloatArray, names: Sequence[str]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Least-squares parameters, (X'X)^-1 and X'X.

    Normal equations on the column-scaled Gram matrix with one step of iterative
    refinement: forming X'X costs a fraction of a QR factorisation of the tall
    matrix, and the refinement step brings the estimate to QR accuracy while the
    scaled matrix is well conditioned. Near-collinear columns go to QR.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # reported below, by name
        gram = x.T @ x
    d = np.sqrt(np.diag(gram))
    for j in np.flatnonzero(~np.isfinite(d)).tolist():
        raise DataFormatError(
            f"regressor {names[j]!r}: its sum of squares overflows; rescale it (units?)"
        )
    for j in np.flatnonzero(~(d > 0)).tolist():
        raise _collinear(names, j)
    scaled = gram / np.outer(d, d)
    try:
        chol = np.linalg.cholesky(scaled)
    except np.linalg.LinAlgError:
        return (*_qr_solve(x, z, names), gram)
    # the squared pivot is 1 - R^2 of a column on the ones before it
    if float(np.min(np.diag(chol))) ** 2 < _WELL_POSED:
        return (*_qr_solve(x, z, names), gram)
    l_inv = np.linalg.inv(chol)
    xtx_inv = (l_inv.T @ l_inv) / np.outer(d, d)
    theta = xtx_inv @ (x.T @ z)
    theta = theta + xtx_inv @ (x.T @ (z - x @ theta))
    return theta, xtx_inv, gram


def _reml_covariance(
    x: FloatArray, v: FloatArray, xtx_inv: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Output error's coloured-residual covariance for this one-output regression: the
    residual as AR(1) plus white noise by REML, with Satterthwaite's degrees of freedom
    (`_output_error`)."""
    from ._noise_model import _colored_covariance as output_error_covariance

    cov, _, nu = output_error_covariance([x[:, None, :]], [v[:, None]], np.ones(1), xtx_inv)
    return cov, nu


# -- result records ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RegressionResult(IntervalMixin):
    """Equation-error (least-squares) estimates with fit statistics.

    Attributes
    ----------
    parameters, stderr : mapping of str to float
        Estimates and their standard errors (coloured-residual corrected
        unless ``error_bars == "white"``), by regressor name.
    covariance : ndarray, shape (p, p)
        Parameter covariance in the order of `parameter_names`.
    covariance_white : ndarray, shape (p, p)
        The classical ``s² (X'X)^-1``.
    parameter_names : tuple of str
    response_name : str
    r_squared, f_statistic, pse : float
        Coefficient of determination, F statistic of the regression and
        predicted squared error (module notes).
    fit_error : float
        Residual standard deviation ``s = sqrt(SSE / (N − p))`` (per real
        component in the frequency domain).
    response, fitted, residuals : ndarray
        Measured response, model prediction and their difference; complex
        Fourier transforms in the frequency domain.
    time : ndarray
        Sample times (sample index when none were given); in the frequency
        domain, `frequencies` holds the abscissa instead.
    frequencies : ndarray
        Frequencies in Hz of a frequency-domain fit (empty otherwise).
    domain : {"time", "frequency"}
    error_bars : {"colored", "white", "reml"}
    n_samples : int
        Samples (time) or frequencies (frequency domain) in the fit.
    time_delays : mapping of str to float
        Estimated time delay (s) per delayed channel (``time_delays=`` of
        `equation_error`), also among the parameters as ``"tau_<channel>"``.
    degrees_of_freedom : mapping of str to float
        Per estimate, the degrees of freedom of its standard error (``N - p``
        for white bars; the Satterthwaite count of the residual spectrum for
        coloured ones): `interval` and `margin` take Student's t with it.
    """

    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    covariance_white: FloatArray
    parameter_names: tuple[str, ...]
    response_name: str
    r_squared: float
    f_statistic: float
    pse: float
    fit_error: float
    response: NDArray[Any]
    fitted: NDArray[Any]
    residuals: NDArray[Any]
    time: FloatArray
    frequencies: FloatArray = field(default_factory=lambda: frozen_array(np.zeros(0)))
    domain: str = "time"
    error_bars: str = "colored"
    n_samples: int = 0
    time_delays: Mapping[str, float] = field(default_factory=dict)
    degrees_of_freedom: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_delays", frozen_mapping(self.time_delays))
        object.__setattr__(self, "degrees_of_freedom", frozen_mapping(self.degrees_of_freedom))
        object.__setattr__(self, "parameters", frozen_mapping(self.parameters))
        object.__setattr__(self, "stderr", frozen_mapping(self.stderr))
        for name in ("covariance", "covariance_white", "time", "frequencies"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        for name in ("response", "fitted", "residuals"):
            arr = np.array(getattr(self, name), copy=True)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "parameter_names", tuple(self.parameter_names))

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    def summary(self) -> str:
        """A Markdown table of the estimates and the fit statistics."""
        rows = []
        for name in self.parameter_names:
            est, se = self.parameters[name], self.stderr[name]
            t = abs(est) / se if se > 0 else np.inf
            rows.append([name, fmt(est), fmt(se), fmt(t, 3)])
        head = (
            f"Equation error ({self.domain} domain) for {self.response_name}: "
            f"{self.n_samples} {'samples' if self.domain == 'time' else 'frequencies'}, "
            f"{len(self.parameter_names)} parameters, {self.error_bars} error bars\n\n"
        )
        stats = (
            f"\n\nR² = {fmt(self.r_squared)}, F = {fmt(self.f_statistic)}, "
            f"PSE = {fmt(self.pse)}, s = {fmt(self.fit_error)}"
        )
        return head + markdown_table(["parameter", "estimate", "std error", "|t|"], rows) + stats

    def plot(self) -> Any:
        """Measured and fitted response, residuals, and estimates with 95 % error bars."""
        from .plotting import _figure

        fig, axes = _figure(3, height=2.2)
        if self.domain == "time":
            x, label = self.time, "time (s)"
            meas, fit, res = self.response, self.fitted, self.residuals
        else:
            x, label = self.frequencies, "frequency (Hz)"
            meas, fit, res = np.abs(self.response), np.abs(self.fitted), np.abs(self.residuals)
        ax = axes[0, 0]
        ax.plot(x, meas, lw=0.9, label="measured")
        ax.plot(x, fit, lw=0.9, ls="--", label="fit")
        ax.set_ylabel(self.response_name if self.domain == "time" else f"|{self.response_name}|")
        ax.legend(loc="best", fontsize="small")
        ax = axes[1, 0]
        ax.plot(x, res, lw=0.8, color="C2")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel("residual" if self.domain == "time" else "|residual|")
        ax.set_xlabel(label)
        ax = axes[2, 0]
        names = list(self.parameter_names)
        est = np.array([self.parameters[n] for n in names])
        half = self.margin(0.95)  # t intervals with each estimate's dof
        err = np.array([half[n] for n in names])
        ax.errorbar(np.arange(len(names)), est, yerr=err, fmt="o", capsize=4)
        ax.set_xticks(np.arange(len(names)), names)
        ax.set_ylabel("estimate, 95 %")
        return fig


def _fit(
    z: FloatArray,
    x: FloatArray,
    names: list[str],
    zname: str,
    time: FloatArray,
    *,
    has_const: bool,
    error_bars: str,
    delays: tuple[list[str], FloatArray, FloatArray] | None = None,
) -> RegressionResult:
    """Least squares of `z` on `x`; `delays` (names, estimates, columns d(X theta)/d tau
    per delay) adds estimated time delays, whose covariance comes with the
    coefficients' from the Gauss–Newton curvature ``J'J``, ``J = [X, columns]``."""
    n, p = x.shape
    n_d = 0 if delays is None else len(delays[0])
    if n <= p + n_d:
        raise IdentificationError(f"equation error: {n} samples cannot fit {p + n_d} parameters")
    with np.errstate(over="ignore"):
        zz = float(z @ z)
    if not np.isfinite(zz):
        raise DataFormatError(f"response {zname!r}: its sum of squares overflows; rescale it")
    theta, xtx_inv, gram = _ls_solve(x, z, names)
    fitted = x @ theta
    v = z - fitted
    sse = float(v @ v)
    zc = z - z.mean()
    s_dev = float(zc @ zc)
    sst = s_dev if has_const else zz
    if delays is not None:
        x = np.column_stack([x, delays[2]])
        names = [*names, *delays[0]]
        theta = np.concatenate([theta, delays[1]])
        p = x.shape[1]
        gram = x.T @ x
        d = np.sqrt(np.diag(gram))
        for j in np.flatnonzero(~(d > 0)).tolist():
            raise IdentificationError(
                f"equation error: the regressors do not change with time delay {names[j]!r}; "
                "is its channel constant, or in no regressor?"
            )
        try:
            xtx_inv = np.linalg.inv(gram / np.outer(d, d)) / np.outer(d, d)
        except np.linalg.LinAlgError:
            raise IdentificationError(
                f"equation error: the time delays {list(delays[0])} cannot be separated from "
                "the coefficients"
            ) from None
    s2 = sse / (n - p)
    cov_white = s2 * xtx_inv
    nu = np.full(p, float(n - p))  # the classical t interval's degrees of freedom
    if error_bars == "colored":
        cov, nu = colored_covariance([x[:, None, :]], [v[:, None]], xtx_inv)
    elif error_bars == "reml":
        cov, nu = _reml_covariance(x, v, xtx_inv)
    else:
        cov = cov_white.copy()
    bad = ~(np.diag(cov) > 0)
    if error_bars != "white" and np.any(bad):
        # a lag-window estimate can go non-positive: keep the classical bars there
        cov[bad, :] = cov_white[bad, :]
        cov[:, bad] = cov_white[:, bad]
        nu[bad] = float(n - p)
    r2, f_stat = _r2_f(sse, sst, n, p, p - 1 if has_const else p)
    pse = sse / n + (s_dev / n) * p / n
    return _result(
        theta,
        cov,
        names,
        s2,
        covariance_white=cov_white,
        response_name=zname,
        r_squared=r2,
        f_statistic=f_stat,
        pse=pse,
        response=z,
        fitted=fitted,
        residuals=v,
        time=time,
        domain="time",
        error_bars=error_bars,
        n_samples=n,
        degrees_of_freedom={k: float(nu[j]) for j, k in enumerate(names)},
        time_delays={}
        if delays is None
        else {k[len(_DELAY) :]: float(t) for k, t in zip(delays[0], delays[1], strict=True)},
    )


def _result(
    theta: FloatArray, cov: FloatArray, names: Sequence[str], s2: float, **fields: Any
) -> RegressionResult:
    """The result record: estimates and standard errors by name, ``s`` from ``s2``."""
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return RegressionResult(
        parameters={k: float(theta[j]) for j, k in enumerate(names)},
        stderr={k: float(se[j]) for j, k in enumerate(names)},
        covariance=cov,
        parameter_names=tuple(names),
        fit_error=float(np.sqrt(s2)),
        **fields,
    )


def _r2_f(sse: float, sst: float, n: int, p: int, k: int) -> tuple[float, float]:
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")
    if k <= 0 or sst <= 0:
        return r2, float("nan")
    if sse <= 0:
        return r2, float("inf")
    return r2, ((sst - sse) / k) / (sse / (n - p))


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
) -> RegressionResult:
    """Equation-error (ordinary least-squares) estimation of a linear model.

    Parameters
    ----------
    data : FlightData, mapping of str to array_like, or array_like (n, p)
        Where response and regressors come from; or the regressor matrix
        itself (then `response` is the samples and `regressors` the optional
        column names, default ``x1 .. xp``).
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
        the bars (``"reml"``; an order of magnitude more work than the
        window). The frequency domain always uses the classical formula.
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
    z, x, names, zname, time = _resolve(data, response, regressors, "equation error")
    check_flag(intercept, "intercept", DataFormatError)
    use_const = bool(intercept)
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
    if use_const:
        names = [_CONST, *names]
        x = np.column_stack([np.ones(x.shape[0]), x])
    _check_names(names)
    if x.shape[1] == 0:
        raise DataFormatError("regressors: none given and no constant term")
    if time_delays is not None and time_delays is not False:
        if domain != "time":
            raise DataFormatError("time_delays: estimated in the time domain only")
        return _delayed_fit(
            data,
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
        step = _step_of(time, dt)  # a dt given must be positive and agree with the data
        t = time if time is not None else np.arange(z.shape[0], dtype=np.float64) * (step or 1.0)
        return _fit(z, x, names, zname, t, has_const=use_const, error_bars=error_bars)
    return _frequency_fit(z, x, names, zname, time, dt, frequencies, has_const=use_const)


def _delay_starts(option: Any, lookup: Mapping[str, Any]) -> dict[str, float]:
    """Channel -> start value (s) of each delay to estimate."""

    def unknown(name: str) -> ChannelError:
        return ChannelError(
            f"time_delays: channel {name!r} not found; channels present: {sorted(lookup)}"
        )

    out = delay_starts(option, list(lookup), what="channel", error=DataFormatError, unknown=unknown)
    if not out:
        raise DataFormatError("time_delays: name at least one channel")
    return out


def _delayed_fit(
    data: Any,
    z: FloatArray,
    response: Any,
    regressors: Any,
    names: list[str],
    zname: str,
    time: FloatArray | None,
    dt: float | None,
    option: Any,
    *,
    has_const: bool,
    error_bars: str,
) -> RegressionResult:
    """Equation error with estimated time delays of some channels (see `equation_error`)."""
    from scipy.optimize import minimize_scalar

    if isinstance(data, FlightData):
        lookup: dict[str, Any] = dict(data.channels)
    elif isinstance(data, Mapping):
        lookup = {str(k): np.asarray(v, dtype=np.float64) for k, v in data.items()}
    else:
        raise DataFormatError(
            "time_delays: need flight data or a mapping of channels (the delayed channels "
            "are shifted before the regressors are formed), not a regressor matrix"
        )
    n = z.shape[0]
    if time is None:
        if dt is None:
            raise DataFormatError("time_delays: give dt= (s) with a mapping of channels")
        step = _step_of(None, dt)
        assert step is not None
        time = np.arange(n, dtype=np.float64) * step
    else:
        step = float(np.min(np.diff(time)))
    starts = _delay_starts(option, lookup)
    delayed = list(starts)
    for c in delayed:
        if f"{_DELAY}{c}" in names:
            raise DataFormatError(f"regressors: the name {_DELAY}{c!r} is taken by a delay")
    original = {c: np.asarray(lookup[c], dtype=np.float64) for c in delayed}
    const = [np.ones(n)] if has_const else []

    def design(taus: FloatArray) -> FloatArray:
        shifted = dict(lookup)
        for c, tau in zip(delayed, taus, strict=True):
            shifted[c] = np.interp(time - tau, time, original[c])
        x = _resolve(shifted, z, regressors, "equation error")[1]
        return np.column_stack([*const, x])

    def sse(taus: FloatArray) -> float:
        x = design(taus)
        sol = np.linalg.lstsq(x, z, rcond=None)[0]
        v = z - x @ sol
        return float(v @ v)

    taus = np.array([starts[c] for c in delayed])
    for _sweep in range(3 if len(delayed) > 1 else 1):
        before = taus.copy()
        for i in range(len(delayed)):
            grid = starts[delayed[i]] + step * np.arange(-4.0, 20.25, 0.25)

            def at(tau: float, i: int = i) -> float:
                trial = taus.copy()
                trial[i] = tau
                return sse(trial)

            values = np.array([at(float(g)) for g in grid])
            k = int(np.argmin(values))
            res = minimize_scalar(
                at,
                bounds=(float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])),
                method="bounded",
                options={"xatol": 1e-6 * step},
            )
            taus[i] = float(res.x) if float(res.fun) <= values[k] else float(grid[k])
        if np.all(np.abs(taus - before) < 1e-4 * step):
            break
    x = design(taus)
    theta = _ls_solve(x, z, names)[0]
    # d(X theta)/d tau by central differences: exact inside a sample interval, where
    # the interpolated channel is linear in the delay
    h = 1e-3 * step
    columns = np.empty((n, len(delayed)))
    for i in range(len(delayed)):
        up, down = taus.copy(), taus.copy()
        up[i] += h
        down[i] -= h
        columns[:, i] = (design(up) - design(down)) @ theta / (2.0 * h)
    return _fit(
        z,
        x,
        names,
        zname,
        time,
        has_const=has_const,
        error_bars=error_bars,
        delays=([f"{_DELAY}{c}" for c in delayed], taus, columns),
    )


def _frequency_fit(
    z: FloatArray,
    x: FloatArray,
    names: list[str],
    zname: str,
    time: FloatArray | None,
    dt: float | None,
    frequencies: ArrayLike | None,
    *,
    has_const: bool,
) -> RegressionResult:
    step = _step_of(time, dt)
    if step is None:
        raise DataFormatError(
            "frequency domain: needs uniformly sampled data (flight data with a uniform "
            "time grid, or dt= for arrays)"
        )
    if frequencies is None:
        raise DataFormatError("frequencies: required for domain='frequency' (Hz)")
    freq = np.atleast_1d(real_array(frequencies, "frequencies"))
    nyquist = 0.5 / step
    if (
        freq.ndim != 1
        or not np.all(np.isfinite(freq))
        or np.any(freq < 0)
        or np.any(freq > nyquist)
    ):
        raise DataFormatError(
            f"frequencies: expected a 1-D array of frequencies in [0, {nyquist:.6g}] Hz"
        )
    m, p = freq.shape[0], x.shape[1]
    if 2 * m <= p:
        raise IdentificationError(
            f"frequency domain: {m} frequencies cannot fit {p} real parameters"
        )
    zt, xt = fourier(z, step, freq), fourier(x, step, freq)
    # A column with (next to) no content at these frequencies cannot be estimated; the
    # constant has none at multiples of 1/(N dt), and is then left out silently.
    content = np.sqrt(np.sum(xt.real**2 + xt.imag**2, axis=0))
    scale = step * np.sqrt(m) * np.sqrt(np.einsum("ij,ij->j", x, x))  # no n x p temporary
    empty = ~(content > 1e-9 * scale)
    if has_const and empty[0]:
        names, x, xt, empty = names[1:], x[:, 1:], xt[:, 1:], empty[1:]
        p -= 1
    for j in np.flatnonzero(empty).tolist():
        raise IdentificationError(
            f"regressor {names[j]!r} has no content at the chosen frequencies; drop it"
        )
    if p == 0:
        raise DataFormatError("regressors: none left to estimate at these frequencies")
    # complex least squares with real parameters = real least squares on stacked parts
    xs = np.concatenate([xt.real, xt.imag])
    zs = np.concatenate([zt.real, zt.imag])
    theta, xtx_inv = _qr_solve(xs, zs, names)
    fitted = xt @ theta
    v = zt - fitted
    sse = float(np.sum(v.real**2 + v.imag**2))
    szz = float(np.sum(zt.real**2 + zt.imag**2))
    s2 = sse / (2 * m - p)
    cov = s2 * xtx_inv
    r2, f_stat = _r2_f(sse, szz, 2 * m, p, p)
    pse = sse / m + (szz / m) * p / m
    return _result(
        theta,
        cov,
        names,
        s2,
        covariance_white=cov,
        response_name=zname,
        r_squared=r2,
        f_statistic=f_stat,
        pse=pse,
        response=zt,
        fitted=fitted,
        residuals=v,
        time=time if time is not None else np.arange(z.shape[0], dtype=np.float64) * step,
        frequencies=freq,
        domain="frequency",
        error_bars="white",
        n_samples=m,
    )


# -- candidate pools -------------------------------------------------------------------------


def spline_terms(
    x: ArrayLike, knots: Sequence[float], *, name: str = "alpha", degree: int = 1
) -> dict[str, FloatArray]:
    """Truncated-power spline columns ``max(x − k, 0)^degree`` for each knot.

    Parameters
    ----------
    x : array_like, shape (n,)
        The variable (typically the angle of attack).
    knots : sequence of float
        Knot positions in the units of `x`.
    name : str
        Name of the variable in the column names, ``"(alpha-0.1)+"`` or
        ``"(alpha-0.1)+^2"``.
    degree : int
        Power of the truncated term (1: a change of slope at the knot).

    Returns
    -------
    dict of str to ndarray
    """
    arr = real_array(x, f"spline_terms: {name}")
    if arr.ndim != 1 or not np.all(np.isfinite(arr)):
        raise DataFormatError(f"spline_terms: {name} must be a finite 1-D array")
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)) or degree < 1:
        raise DataFormatError(f"degree: expected a positive integer, got {degree!r}")
    if isinstance(knots, (str, bytes)) or not isinstance(knots, Sequence | np.ndarray):
        raise DataFormatError(f"knots of {name}: expected a sequence of numbers, got {knots!r}")
    out: dict[str, FloatArray] = {}
    for k in knots:
        knot = as_float(k)
        if knot is None or not np.isfinite(knot):
            raise DataFormatError(f"knots of {name}: expected finite numbers, got {k!r}")
        label = f"({name}-{knot:g})+" if knot >= 0 else f"({name}+{-knot:g})+"
        if degree > 1:
            label += f"^{degree}"
        if label in out:  # the same knot to the label's precision: the same column
            raise DataFormatError(f"knots of {name}: {knot:g} is given twice")
        with np.errstate(over="ignore"):
            column = np.maximum(arr - knot, 0.0) ** degree
        if not np.all(np.isfinite(column)):
            raise DataFormatError(f"spline {label}: overflows (degree {degree} too high?)")
        out[label] = column
    return out


def candidate_pool(
    data: FlightData | Mapping[str, ArrayLike],
    variables: Sequence[str],
    *,
    squares: bool = True,
    products: bool = True,
    cubes: bool = False,
    splines: Mapping[str, Sequence[float]] | None = None,
) -> dict[str, FloatArray]:
    """Candidate regressors for `stepwise_regression` built from a few variables.

    Parameters
    ----------
    data : FlightData or mapping of str to array_like
        Where the variables come from.
    variables : sequence of str
        Channel names or expressions (e.g. ``"alpha"``, ``"q*cbar/V"`` is not
        allowed — put scaled rates in the mapping or data first).
    squares, products, cubes : bool
        Add ``v^2`` for each variable, ``v*w`` for each pair, ``v^3``.
    splines : mapping of str to sequence of float, optional
        Knots of first-degree splines per variable, ``{"alpha": [0.1, 0.2]}``.

    Returns
    -------
    dict of str to ndarray
        Name to column, in the order: linear terms, squares, products, cubes,
        splines. Names are expressions `equation_error` also understands
        (except the splines).
    """
    if isinstance(variables, str):
        variables = [variables]
    if not isinstance(variables, Sequence) or not all(isinstance(v, str) for v in variables):
        raise DataFormatError(
            f"variables: expected channel names or expressions, got {variables!r}"
        )
    if not variables:
        raise DataFormatError("variables: give at least one variable")
    if isinstance(data, FlightData):
        lookup: Mapping[str, Any] = data.channels
        n = data.n_samples
    elif isinstance(data, Mapping):
        lookup, n = _mapping_columns(data)
    else:
        raise DataFormatError("data: expected FlightData or a mapping of name to samples")
    if splines is not None and not isinstance(splines, Mapping):
        raise DataFormatError(f"splines: expected a mapping of variable to knots, got {splines!r}")
    cols = {v: _evaluate(lookup, v, n, "variable") for v in variables}
    out: dict[str, FloatArray] = dict(cols)
    if squares:
        out.update({f"{v}^2": cols[v] ** 2 for v in variables})
    if products:
        for i, a in enumerate(variables):
            for b in variables[i + 1 :]:
                out[f"{a}*{b}"] = cols[a] * cols[b]
    if cubes:
        out.update({f"{v}^3": cols[v] ** 3 for v in variables})
    for v, knots in dict(splines or {}).items():
        if v not in cols:
            cols[v] = _evaluate(lookup, v, n, "spline variable")
        out.update(spline_terms(cols[v], knots, name=v))
    return out


# -- stepwise regression ---------------------------------------------------------------------


@dataclass(frozen=True)
class StepwiseStep:
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
    """

    selected: tuple[str, ...]
    forced: tuple[str, ...]
    candidates: tuple[str, ...]
    steps: tuple[StepwiseStep, ...]
    regression: RegressionResult
    f_in: float
    f_out: float
    orthogonalized: bool

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
                s.step,
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
            f"selected {', '.join(self.selected) or 'nothing'}\n\n"
        )
        table = markdown_table(["step", "action", "term", "F", "R²", "PSE", "terms"], rows)
        return head + table + "\n\n" + self.regression.summary()

    def plot(self) -> Any:
        """R² and predicted squared error after each step, and the final fit's estimates."""
        from .plotting import _figure

        fig, axes = _figure(3, height=2.2)
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


def _gram_stats(
    gram: FloatArray, szz: float, model: list[int]
) -> tuple[float, FloatArray | None, FloatArray | None]:
    """SSE of a model from the cross-products, its parameters and (X'X)^-1 block."""
    if not model:
        return szz, None, None
    g = gram[np.ix_(model, model)]
    b = gram[model, -1]
    try:
        ginv = np.linalg.inv(g)
    except np.linalg.LinAlgError:
        return szz, None, None
    theta = np.asarray(ginv @ b, dtype=np.float64)
    return max(szz - float(b @ theta), 0.0), theta, np.asarray(ginv, dtype=np.float64)


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
    statistic ``F = ΔSSE / s²`` if it exceeds `f_in` and lowers the predicted
    squared error, then removes, one at a time, model terms whose partial F
    has fallen below `f_out`. It stops when no term enters or leaves (or a
    model would repeat). The final model is fitted by `equation_error`.

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
    try:
        f_in, f_out = float(f_in), float(f_out)
        ordered = bool(np.isfinite(f_in) and np.isfinite(f_out) and 0 <= f_out <= f_in)
    except (TypeError, ValueError):
        ordered = False
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
                new_pse = best_sse / n + s_dev / n * p_new / n
                f_val = (
                    (sse - best_sse) / (best_sse / (n - p_new)) if best_sse > 0 else float("inf")
                )
                key = frozenset([*model, best])
                if f_val > f_in and new_pse < pse and key not in seen:
                    model.append(best)
                    seen.add(key)
                    sse, r2, pse = stats(model)
                    steps.append(
                        StepwiseStep(len(steps), "enter", names[best], f_val, r2, pse, p_new)
                    )
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
            changed = True
        if not changed:
            break
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
    )
