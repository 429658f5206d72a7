"""Equation-error fits in time, with a time delay, and in frequency.

Split out of `aeroid.estimation.regression` (which re-exports every name): the time-domain fit
with its error bars, the search over delayed regressors and Fourier transform
regression.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._colour import colored_covariance, frequency_sandwich
from .._czt import fourier
from ..errors import ChannelError, DataFormatError, IdentificationError
from ..io.data import FlightData, delay_starts, real_array
from ._regression_record import RegressionResult, _press, _r2_f, _result
from ._regressors import _resolve, _step_of
from .least_squares import _ls_solve, _qr_solve, _reml_covariance

FloatArray = NDArray[np.float64]

_DELAY = "tau_"


def _classical_where_not_positive(
    cov: FloatArray, cov_white: FloatArray, nu: FloatArray, dof: int
) -> None:
    """Where an estimated spectrum left a variance non-positive, keep the classical bars
    and degrees of freedom (in place)."""
    bad = ~(np.diag(cov) > 0)
    cov[bad, :] = cov_white[bad, :]
    cov[:, bad] = cov_white[:, bad]
    nu[bad] = float(dof)


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
    records: tuple[int, ...] = (),
) -> RegressionResult:
    """Least squares of `z` on `x`; `delays` (names, estimates, columns d(X theta)/d tau
    per delay) adds estimated time delays, whose covariance comes with the
    coefficients' from the Gauss–Newton curvature ``J'J``, ``J = [X, columns]``.
    `records` (samples per record, several) splits the rows into records whose
    residual spectra the coloured bars estimate apart: no lag spans two records."""
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
        cuts = np.cumsum(records[:-1]).tolist() if records else []
        cov, nu = colored_covariance(
            [xs[:, None, :] for xs in np.split(x, cuts)],
            [vs[:, None] for vs in np.split(v, cuts)],
            xtx_inv,
            rcond=0.0,  # the exact inverse: a collinear column was refused
        )
    elif error_bars == "reml":
        cov, nu = _reml_covariance(x, v, xtx_inv)
    else:
        cov = cov_white.copy()
    if error_bars != "white":
        _classical_where_not_positive(cov, cov_white, nu, n - p)
    r2, f_stat = _r2_f(sse, sst, n, p, p - 1 if has_const else p)
    pse = sse / n + (s_dev / n) * p / n
    # with delays, x is the Gauss-Newton Jacobian: leaving a sample out refits them too
    press = _press(x, v)
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
        press=press,
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
        record_lengths=records,
    )


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
    error_bars: str = "colored",
    derivative: bool = False,
) -> RegressionResult:
    step = _frequency_step(time, dt)
    freq = _frequency_grid(frequencies, step, x.shape[1])
    # the derivative's identity holds between integrals, which trapezoids follow to
    # O(dt^2); plain sums keep z = X theta exact sample by sample otherwise
    zt = fourier(z, step, freq, end_correction=derivative)
    xt = fourier(x, step, freq, end_correction=derivative)
    if derivative:
        zt = derivative_transform(zt, z[0], z[-1], freq, (z.shape[0] - 1) * step)
    return fourier_regression(
        zt,
        xt,
        np.sqrt(np.einsum("ij,ij->j", x, x)),  # no n x p temporary
        names,
        zname,
        time if time is not None else np.arange(z.shape[0], dtype=np.float64) * step,
        step,
        freq,
        has_const=has_const,
        error_bars=error_bars,
    )


def _frequency_step(time: FloatArray | None, dt: float | None) -> float:
    step = _step_of(time, dt)
    if step is None:
        raise DataFormatError(
            "frequency domain: needs uniformly sampled data (flight data with a uniform "
            "time grid, or dt= for arrays)"
        )
    return step


def _frequency_grid(frequencies: ArrayLike | None, step: float, p: int) -> FloatArray:
    """The chosen frequencies, Hz, checked against the sampling and the parameter count."""
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
    if np.unique(freq).size != freq.size:
        raise DataFormatError(
            "frequencies: a frequency is repeated (each one is a pair of equations once)"
        )
    if 2 * freq.shape[0] <= p:
        raise IdentificationError(
            f"frequency domain: {freq.shape[0]} frequencies cannot fit {p} real parameters"
        )
    return freq


def derivative_transform(
    transform: NDArray[np.complex128],
    first: float,
    last: float,
    freq: FloatArray,
    span: float,
) -> NDArray[np.complex128]:
    """The finite Fourier transform of a signal's time derivative from the signal's own:
    by parts, ``∫_0^T ż e^{-jωt} dt = jω Z̃ + z(T) e^{-jωT} - z(0)``, so no numerical
    derivative enters and a record that does not end where it began is exact."""
    omega = 2.0 * np.pi * freq
    return 1j * omega * transform + last * np.exp(-1j * omega * span) - first


def derivative_name(name: str) -> str:
    """``"dq/dt"`` for a channel, ``"d(alpha*q)/dt"`` for an expression."""
    return f"d{name}/dt" if name.isidentifier() else f"d({name})/dt"


def fourier_regression(
    zt: NDArray[np.complex128],
    xt: NDArray[np.complex128],
    column_norms: FloatArray,
    names: list[str],
    zname: str,
    time: FloatArray,
    step: float,
    freq: FloatArray,
    *,
    has_const: bool,
    error_bars: str,
    span: float | None = None,
) -> RegressionResult:
    """Fourier transform regression on given transforms (`freq` in Hz; `span` the
    record's length, default its samples times `step`): the one solution of the batch
    estimator, of every update of the recursive one and of a transfer function's
    equation error."""
    m, p = freq.shape[0], xt.shape[1]
    # A column with (next to) no content at these frequencies cannot be estimated; the
    # constant has none at multiples of 1/(N dt), and is then left out silently.
    content = np.sqrt(np.sum(xt.real**2 + xt.imag**2, axis=0))
    scale = step * np.sqrt(m) * column_norms
    empty = ~(content > 1e-9 * scale)
    if has_const and empty[0]:
        names, xt, empty = names[1:], xt[:, 1:], empty[1:]
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
    cov_white = s2 * xtx_inv
    nu = np.full(p, float(2 * m - p))
    if error_bars == "colored":
        # each frequency's residual spectrum with its neighbours' (the one correction's
        # frequency form); frequencies closer than the record resolves share their noise
        cov, nu = frequency_sandwich(
            np.stack([xt.real, xt.imag], axis=1),
            np.column_stack([v.real, v.imag]),
            xtx_inv,
            2 * np.pi * freq,
            time.shape[0] * step if span is None else span,
            nyquist=np.pi / step,
            rcond=0.0,  # the exact inverse: a collinear column was refused
        )
        _classical_where_not_positive(cov, cov_white, nu, 2 * m - p)
    else:
        cov = cov_white.copy()
    r2, f_stat = _r2_f(sse, szz, 2 * m, p, p)
    pse = sse / m + (szz / m) * p / m
    press = _press(xs, v, m)
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
        press=press,
        response=zt,
        fitted=fitted,
        residuals=v,
        time=time,
        frequencies=freq,
        domain="frequency",
        error_bars=error_bars,
        n_samples=m,
        degrees_of_freedom={k: float(nu[j]) for j, k in enumerate(names)},
    )
