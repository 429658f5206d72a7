"""The `RegressionResult` record, apart from `aeroid.estimation.regression` so that the
fits that build it need not import the entry points (which re-export it)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._linalg import information_basis
from .._records import IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table

FloatArray = NDArray[np.float64]


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
    press : float
        Predicted residual sum of squares: the sum of squared errors of
        predicting each sample from a fit that left it out (module notes);
        infinite where one sample alone fixes a parameter, NaN on records
        built before it existed.
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
    record_lengths : tuple of int
        Samples per record of a fit to several records (manoeuvres), in their
        order: `response`, `fitted`, `residuals` and `time` are the records
        one after another. Empty for a fit to one record.
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
    press: float = float("nan")
    record_lengths: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "record_lengths", tuple(int(k) for k in self.record_lengths))
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
            f"PSE = {fmt(self.pse)}, PRESS = {fmt(self.press)}, s = {fmt(self.fit_error)}"
        )
        return head + markdown_table(["parameter", "estimate", "std error", "|t|"], rows) + stats

    def plot(self) -> Any:
        """Measured and fitted response, residuals, and estimates with 95 % error bars."""
        from ..reports.plotting import figure

        fig, axes = figure(3, height=2.2)
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


def _press(x: FloatArray, v: NDArray[Any], m: int = 0) -> float:
    """Predicted residual sum of squares of residuals `v` of least squares on `x`.

    Leaving sample i out changes its residual to ``v_i / (1 - h_ii)``, with ``h_ii``
    the hat matrix's diagonal, never formed: ``H = U U'`` over an orthonormal basis
    of the columns (from ``(X'X)^-1`` near-collinear columns would cancel its digits
    away). With ``m > 0``, `x` is the stacked real system of `m` complex rows (real
    parts, then imaginary ones): a frequency leaves with both its rows, and its
    residual pair becomes ``(I - H_k)^-1 (Re v_k, Im v_k)`` with ``H_k`` the hat
    matrix's 2 x 2 block there.
    """
    (u,), _ = information_basis([x[:, None, :]], 0.0)
    x = xi = u[:, 0, :]
    if m == 0:
        one_minus_h = 1.0 - np.einsum("ij,ij->i", xi, x)
        # where 1 - h vanishes, that sample alone fixes a parameter: no prediction of it
        if not np.all(one_minus_h > 1e-12):
            return float("inf")
        return float(np.sum((v / one_minus_h) ** 2))
    a = 1.0 - np.einsum("ij,ij->i", xi[:m], x[:m])
    b = -np.einsum("ij,ij->i", xi[:m], x[m:])
    d = 1.0 - np.einsum("ij,ij->i", xi[m:], x[m:])
    det = a * d - b * b
    if not np.all(det > 1e-12):
        return float("inf")
    # (I - H_k)^-1 of the symmetric block [[a, b], [b, d]], in closed form
    er = (d * v.real - b * v.imag) / det
    ei = (a * v.imag - b * v.real) / det
    return float(np.sum(er**2 + ei**2))


def _r2_f(sse: float, sst: float, n: int, p: int, k: int) -> tuple[float, float]:
    r2 = 1.0 - sse / sst if sst > 0 else float("nan")
    if k <= 0 or sst <= 0:
        return r2, float("nan")
    if sse <= 0:
        return r2, float("inf")
    return r2, ((sst - sse) / k) / (sse / (n - p))
