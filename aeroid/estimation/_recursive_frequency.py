"""Recursive least squares in the frequency domain (Klein & Morelli, sec. 8.2).

Morelli's real-time estimator: the finite Fourier transforms of the response
and the regressors are carried forward sample by sample,

    X̃_k(ω) = X̃_(k-1)(ω) + Δt x_k e^{-jω t_k},

an update of fixed cost whatever the record's length, and at chosen times
the equation-error solution on the transforms so far is the batch Fourier
transform regression of the record up to then (`equation_error` with
``domain="frequency"``, whose one solution every update calls). The signals
enter as deviations from their first sample: a trim offset has a transform at
every frequency of a finite record (``∫_0^T e^{-jωt} dt`` vanishes only at
multiples of ``1/T``, which move as the record grows), and would otherwise
pollute the band being fitted.

Here the transforms are accumulated between update times by the house's
`fourier` and shifted to the block's start, equal to the sample-by-sample
recursion to rounding and the same numbers a real-time loop would hold at
each update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._czt import fourier, trapezoid_ends
from .._records import FrozenState
from ..errors import DataFormatError, IdentificationError
from ._regression_fits import derivative_transform, fourier_regression
from ._regression_record import RegressionResult

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


@dataclass(frozen=True)
class FrequencyHistory(FrozenState):
    """What the recursion produced: per-sample histories (the latest update's values,
    NaN before the first), the update times, and the last update's full result."""

    history: FloatArray
    stderr_history: FloatArray
    dof_history: FloatArray
    fit_error_history: FloatArray
    prediction_errors: FloatArray
    update_times: FloatArray
    final: RegressionResult


def update_indices(n: int, step: float, first: float, interval: float) -> NDArray[np.intp]:
    """Samples after which the estimate is updated: from `first` seconds in, every
    `interval` seconds (on the sample grid), and always after the last sample."""
    if not (np.isfinite(interval) and interval >= step * (1.0 - 1e-9)):
        raise DataFormatError(
            f"update_interval: expected at least the sample interval {step:.6g} s, got {interval!r}"
        )
    if not (np.isfinite(first) and first >= 0.0):
        raise DataFormatError(f"first_update: expected a number of seconds >= 0, got {first!r}")
    last = n - 1
    start = round(first / step)
    count = int(np.floor((last * step - first) / interval + 1e-9)) + 1 if start < last else 0
    idx = np.unique(np.round((first + interval * np.arange(count)) / step).astype(np.intp))
    return np.append(idx[idx < last], last)


def frequency_recursion(
    z: FloatArray,
    x: FloatArray,
    names: list[str],
    zname: str,
    time: FloatArray,
    step: float,
    freq: FloatArray,
    *,
    has_const: bool,
    derivative: bool,
    updates: NDArray[np.intp],
    error_bars: str,
) -> FrequencyHistory:
    """Run the recursion over the record and solve at every update."""
    n, p = x.shape
    lead = 1 if has_const else 0
    xd = x.copy()
    xd[:, lead:] -= x[0, lead:]  # deviations from the first sample; the constant stays one
    zd = z - z[0]
    omega = 2.0 * np.pi * freq
    xt = np.zeros((freq.size, p), dtype=np.complex128)
    zt = np.zeros(freq.size, dtype=np.complex128)
    squares = np.zeros(p)
    hist = np.full((n, p), np.nan)
    se_hist = np.full((n, p), np.nan)
    dof_hist = np.full((n, p), np.nan)
    s_hist = np.full(n, np.nan)
    eps = np.full(n, np.nan)
    update_times: list[float] = []
    theta = np.full(p, np.nan)
    final: RegressionResult | None = None
    begin = 0
    for end in updates.tolist():
        rows = slice(begin, end + 1)
        shift = np.exp(-1j * omega * (time[begin] - time[0]))[:, None]
        xt += shift * fourier(xd[rows], step, freq)
        zt += shift[:, 0] * fourier(zd[rows], step, freq)
        squares += np.einsum("ij,ij->j", xd[rows], xd[rows])
        if not derivative:
            eps[rows] = zd[rows] - xd[rows] @ theta  # predicted from the estimate before
        begin = end + 1
        z_now, x_now = _as_taken(zt, xt, zd, xd, end, step, freq, derivative=derivative)
        try:
            result = fourier_regression(
                z_now,
                x_now,
                np.sqrt(squares),
                names,
                zname,
                time[: end + 1],
                step,
                freq,
                has_const=has_const,
                error_bars=error_bars,
            )
        except (IdentificationError, DataFormatError):
            if end == n - 1:
                raise
            continue  # the record so far does not yet determine every parameter
        final = result
        theta = np.array([result.parameters.get(k, 0.0) for k in names])
        later = slice(end, n)
        for j, k in enumerate(names):
            if k in result.parameters:
                hist[later, j] = result.parameters[k]
                se_hist[later, j] = result.stderr[k]
                dof_hist[later, j] = result.degrees_of_freedom[k]
            else:  # the constant, left out where it has no content: nothing known
                hist[later, j] = se_hist[later, j] = dof_hist[later, j] = np.nan
        s_hist[later] = result.fit_error
        update_times.append(float(time[end]))
    if final is None:  # the last update raises instead; kept for the type checker
        raise IdentificationError("recursive least squares: no update determined the model")
    if len(final.parameter_names) < p:
        # the constant has no content at these frequencies over the whole record (each a
        # multiple of 1/T): left out, as the batch estimator leaves it out
        hist, se_hist, dof_hist = hist[:, 1:], se_hist[:, 1:], dof_hist[:, 1:]
    return FrequencyHistory(hist, se_hist, dof_hist, s_hist, eps, np.asarray(update_times), final)


def _as_taken(
    zt: ComplexArray,
    xt: ComplexArray,
    zd: FloatArray,
    xd: FloatArray,
    end: int,
    step: float,
    freq: FloatArray,
    *,
    derivative: bool,
) -> tuple[ComplexArray, ComplexArray]:
    """The running transforms as the batch estimator takes them at sample `end`: as
    they are, or for the derivative trapezoids (half the end samples off) and the
    derivative's transform by parts."""
    if not derivative:
        return zt, xt
    span = end * step
    z_now = zt - trapezoid_ends(zd[0], zd[end], freq, span, step)
    x_now = xt - trapezoid_ends(xd[0], xd[end], freq, span, step)
    return derivative_transform(z_now, zd[0], zd[end], freq, span), x_now
