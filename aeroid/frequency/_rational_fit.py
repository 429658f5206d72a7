"""The rational transfer function a fit adjusts: its parameter structure, the
Sanathanan-Koerner start, the checks of its options, and the fit to a record's
Fourier transforms (`aeroid.frequency.frequency_id.fit_transfer_function`'s parts).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import constant_value
from .._colour import frequency_sandwich
from .._record_kernel import off_grid
from .._records import FrozenState
from .._stats import wald_p_value
from .._threads import CALLER_STACKLEVEL
from ..errors import ChannelError, IdentifiabilityWarning, IdentificationError
from ..estimation.least_squares import fit_residuals
from ..io.data import FlightData, as_float, check_flag, plain
from ._response_records import TransferFunctionFit, _band

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# The stopping rule's tolerance for the transfer-function fits (`fit_residuals`): a few
# parameters and cheap residuals, so they converge to near rounding.
_TOLERANCE = 1e-10
_EXCITED = 0.01  # power, relative to the input's peak, that counts as excited
_MIN_PERIODS = 2  # periods of a frequency a window (or the whole record) must hold


def _coherence_weight(coh: FloatArray) -> FloatArray:
    return np.asarray((1.58 * (1.0 - np.exp(-coh))) ** 2, dtype=np.float64)


class _Structure:
    """Maps the parameter vector [b_0..b_m, a_0..a_{n-1}, (tau)] to T(jω) and its log-derivatives."""

    def __init__(self, m: int, n: int, delay: bool, omega: FloatArray) -> None:
        self.m, self.n, self.delay = m, n, delay
        s = 1j * omega
        self.s = s
        self.sb = s[:, None] ** np.arange(m + 1)[None, :]  # (n_ω, m+1)
        self.sa = s[:, None] ** np.arange(n)[None, :]  # (n_ω, n)
        self.sn = s**n
        self.names = (
            [f"b{k}" for k in range(m + 1)]
            + [f"a{k}" for k in range(n)]
            + (["tau"] if delay else [])
        )

    def split(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        m, n = self.m, self.n
        tau = float(theta[m + 1 + n]) if self.delay else 0.0
        return theta[: m + 1], theta[m + 1 : m + 1 + n], tau

    def log_response(self, theta: FloatArray) -> tuple[ComplexArray, ComplexArray]:
        """log T(jω) and d log T / dθ (n_ω, p)."""
        b, a, tau = self.split(theta)
        num = self.sb @ b
        den = self.sn + self.sa @ a
        with np.errstate(all="ignore"):
            logt = np.log(num) - np.log(den) - tau * self.s
            cols: list[ComplexArray] = [self.sb / num[:, None], -self.sa / den[:, None]]
        if self.delay:
            cols.append(np.asarray(-self.s[:, None], dtype=np.complex128))
        return logt, np.concatenate(cols, axis=1)


def _levy_sk(
    st: _Structure, h: ComplexArray, weight: FloatArray, iterations: int = 6
) -> FloatArray:
    """Rational fit N/D to the complex response by Sanathanan-Koerner iterations of Levy's method."""
    prev = np.ones(h.size)
    a_cols = -h[:, None] * st.sa
    rhs = h * st.sn
    design = np.concatenate([st.sb, a_cols], axis=1)
    theta = np.zeros(design.shape[1])
    for _ in range(iterations):
        w = np.sqrt(weight) / prev
        x = design * w[:, None]
        y = rhs * w
        xs = np.concatenate([x.real, x.imag])
        ys = np.concatenate([y.real, y.imag])
        # column scaling keeps powers of ω from ruining the conditioning
        norms = np.linalg.norm(xs, axis=0)
        norms[norms == 0] = 1.0
        sol = np.linalg.lstsq(xs / norms, ys, rcond=None)[0] / norms
        if not np.all(np.isfinite(sol)):
            break
        theta = sol
        den = np.abs(st.sn + st.sa @ theta[st.m + 1 :])
        prev = np.maximum(den, 1e-12 * max(float(den.max()), 1e-300))
    return theta


def _start(
    st: _Structure,
    h: ComplexArray,
    w: FloatArray,
    weight: FloatArray,
    residual: Any,
    start: Mapping[str, float] | None,
) -> FloatArray:
    """Sanathanan-Koerner start, with τ from the phase the rational part leaves unexplained."""

    def cost(theta: FloatArray) -> float:
        r = residual(theta)
        return float(r @ r) if np.all(np.isfinite(r)) else np.inf

    best = _levy_sk(st, h, weight)
    if st.delay:
        best = np.append(best, 0.0)
        ratio = h / np.exp(st.log_response(best)[0])
        ph = np.unwrap(np.angle(ratio))
        # the phase left over is about −τω: its least-squares slope through the origin
        tau = max(0.0, -float(np.sum(w * ph) / np.sum(w * w)))
        candidates = [best]
        # and a grid up to half a turn of phase at the top frequency: a numerator of
        # higher order than the denominator lets the rational part mimic a lead and
        # leaves the phase slope above useless
        grid = np.linspace(0.0, np.pi / float(w.max()), 25)[1:]
        for t in (tau, 2.0 * tau, *grid):
            if t > 0:
                cand = np.append(_levy_sk(st, h * np.exp(1j * w * t), weight), t)
                candidates.append(cand)
        best = min(candidates, key=cost)
    if start is not None:
        if not isinstance(start, Mapping):
            raise IdentificationError(
                f"start: expected a mapping of parameter name to value, got {start!r}"
            )
        unknown = sorted(set(start) - set(st.names))
        if unknown:
            raise IdentificationError(
                f"start: unknown parameters {unknown}; parameters: {st.names}"
            )
        best = best.copy()
        for k, v in start.items():
            best[st.names.index(k)] = _start_value(k, v)
    return np.asarray(best, dtype=np.float64)


def _orders(numerator_order: Any, denominator_order: Any) -> tuple[int, int]:
    try:
        m, n = int(numerator_order), int(denominator_order)
        ok = m == numerator_order and n == denominator_order and m >= 0 and n >= 1
        ok = ok and not isinstance(numerator_order, bool | np.bool_)  # True is no order
        ok = ok and not isinstance(denominator_order, bool | np.bool_)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise IdentificationError(
            "numerator_order, denominator_order: expected integers m >= 0, n >= 1, got "
            f"{numerator_order!r}, {denominator_order!r}"
        )
    return m, n


def _record_grid(data: FlightData) -> tuple[float, float]:
    """Sample interval and record length of a uniformly sampled record."""
    if data.n_samples < 4 or not data.is_uniform:
        raise IdentificationError(
            "data: a transfer-function fit from flight data needs a uniformly sampled record "
            "of at least 4 samples"
        )
    dt = float(np.mean(np.diff(data.time)))
    return dt, dt * (data.n_samples - 1)


def refuse_constant(data: FlightData, inputs: Sequence[str], outputs: Sequence[str]) -> None:
    """Refuse a record in which an input or an output never changes: a constant input
    excites nothing, and a stuck or dead sensor responds to nothing (once the means
    are removed its rounding residue would pass for a response)."""
    for role, names in (("input", inputs), ("output", outputs)):
        for name in names:
            value = constant_value(data[name])
            if value is not None:
                what = "carries no excitation" if role == "input" else "carries no response"
                raise IdentificationError(
                    f"{role} {name!r} is constant ({plain(value)}) and {what}; a frequency "
                    f"response needs {'an input' if role == 'input' else 'an output'} that "
                    "varies (a stuck or dead channel: leave it out)"
                )


def _excited_band(data: FlightData, input: str) -> tuple[float, float]:
    """The band (rad/s) over which the input's power is at least 1 % of its peak."""
    from .frequency_domain import _transform

    dt, T = _record_grid(data)
    k = np.arange(1, data.n_samples // 2)
    omega = np.asarray(2 * np.pi * k / T, dtype=np.float64)
    u = np.asarray(data[input], dtype=np.float64)
    power = np.abs(_transform((u - u.mean())[:, None], dt, omega, cubic=False)[:, 0]) ** 2
    if not np.any(power > 0):
        raise IdentificationError(f"input {input!r} is constant: it excites no frequency")
    hit = np.flatnonzero(power >= _EXCITED * power.max())
    return float(omega[hit[0]]), float(omega[hit[-1]])


def _end_basis(w: FloatArray, span: float, order: int) -> ComplexArray | None:
    """Columns whose combination, over ``D(jω)``, is what a record's ends add to
    ``D(jω) Y = N(jω) e^{-jωτ} U`` on ``[0, T]``; None where a frequency is zero.

    The transform of a derivative over the record, ``F[x'] = jω X + x(T) e^{-jωT}
    - x(0)``, leaves polynomials in ``jω`` of degree below ``order`` (the larger
    polynomial order) weighted by the states at both ends; the straight lines the
    fit removes from input and output leave ``c0 + c1 t`` in the equation. On the
    ``k/T`` grid ``e^{-jωT} = 1``: the two polynomials merge and only the slope's
    ``-T/(jω)`` is left of the lines. A delay's input from before the record
    (its first τ seconds) is not among them. Columns are scaled to unit mean
    square."""
    if not np.all(w > 0):
        return None
    s = 1j * np.asarray(w, dtype=np.float64)
    powers = s[:, None] ** np.arange(order)[None, :]
    if off_grid(w, span) is None:
        cols = [powers, (1.0 / s)[:, None]]
    else:
        end = np.exp(-s * span)
        ramp = (1.0 - end) / s
        cols = [powers, -powers * end[:, None], ramp[:, None], ((ramp - span * end) / s)[:, None]]
    basis = np.concatenate(cols, axis=1)
    return np.asarray(basis / np.sqrt(np.mean(np.abs(basis) ** 2, axis=0)), dtype=np.complex128)


def _end_coefficients(v: ComplexArray, columns: ComplexArray) -> FloatArray:
    """The real coefficients of the least-squares fit of `v` by `columns`."""
    a = np.concatenate([columns.real, columns.imag])
    b = np.concatenate([v.real, v.imag])
    return np.asarray(np.linalg.lstsq(a, b, rcond=None)[0], dtype=np.float64)


def _without_ends(v: ComplexArray, columns: ComplexArray) -> ComplexArray:
    """`v` less its least-squares fit by `columns` with real coefficients."""
    return np.asarray(v - columns @ _end_coefficients(v, columns), dtype=np.complex128)


@dataclass(frozen=True)
class FourierRequest(FrozenState):
    """What `fit_transfer_function` asks of a fit to a record's Fourier transforms."""

    data: FlightData
    input: str | None
    output: str | None
    numerator_order: Any
    denominator_order: Any
    delay: Any
    frequency_range: tuple[float, float] | None
    frequencies: ArrayLike | None
    start: Mapping[str, float] | None
    fixed: Mapping[str, float] | None
    error_bars: str
    boundary: str


class RecordTransforms(NamedTuple):
    """A record's transforms at the fitted frequencies, and the fit's structure."""

    w: FloatArray  # rad/s
    U: ComplexArray
    Y: ComplexArray
    span: float  # the record's length T, s
    st: _Structure
    held: dict[str, float]
    free: NDArray[np.bool_]
    h: ComplexArray  # Y / U where U is not zero
    m: int
    n: int


def record_transforms(req: FourierRequest) -> RecordTransforms:
    """The input's and output's transforms (trends removed) at the frequencies a
    Fourier fit of the record uses, checked, with the transfer function's structure."""
    data, input, output = req.data, req.input, req.output
    frequency_range, error_bars = req.frequency_range, req.error_bars

    from .frequency_domain import _frequency_grid, _transform

    if input is None or output is None:
        raise ChannelError("response_or_data: flight data need input= and output= channel names")
    data.require([input], role="input")
    data.require([output], role="output")
    refuse_constant(data, [input], [output])
    m, n = _orders(req.numerator_order, req.denominator_order)
    dt, T = _record_grid(data)
    if frequency_range is not None and frequency_range[1] > np.pi / dt * (1.0 + 1e-9):
        raise IdentificationError(
            f"frequency_range: its top {frequency_range[1]:g} rad/s lies above the record's "
            f"Nyquist frequency {np.pi / dt:.6g} rad/s"
        )
    if req.frequencies is None:
        lo, hi = frequency_range if frequency_range is not None else _excited_band(data, input)
        # two periods in the record, the rule every window obeys (the whole record is
        # the window here): below it the detrend and the record's ends decide Y/U
        k = np.arange(
            max(_MIN_PERIODS, int(np.ceil(lo * T / (2 * np.pi) - 1e-9))),
            1 + int(hi * T / (2 * np.pi) + 1e-9),
        )
        w = np.asarray(2 * np.pi * k / T, dtype=np.float64)
        w = w[w < np.pi / dt]
    else:
        w = _frequency_grid(req.frequencies, dt, T, depth=3, shared=error_bars == "colored")
        if frequency_range is not None:
            lo, hi = _band(frequency_range)
            w = w[(w >= lo) & (w <= hi)]
        short = w < _MIN_PERIODS * 2.0 * np.pi / T * (1 - 1e-9)
        if np.any(short):
            warnings.warn(
                f"frequencies: {int(short.sum())} below {_MIN_PERIODS * 2 * np.pi / T:.4g} "
                "rad/s, two periods of the record; their transforms are decided by the "
                "detrend and the record's ends",
                UserWarning,
                stacklevel=CALLER_STACKLEVEL + 2,  # record_transforms, the fit, the public call
            )
    u = np.asarray(data[input], dtype=np.float64)
    y = np.asarray(data[output], dtype=np.float64)
    # linear trends (trim, drift) removed as SIDPAC's detrend; on the k/T grid a constant
    # has no transform anyway
    U = _transform(_detrended(data.time, u)[:, None], dt, w, cubic=False)[:, 0]
    Y = _transform(_detrended(data.time, y)[:, None], dt, w, cubic=True)[:, 0]
    st, held, free = _free_structure(
        m, n, req.delay, w, req.fixed, "in the band", f"{input} -> {output}"
    )
    ok = np.abs(U) > 0
    h = np.where(ok, Y / np.where(ok, U, 1.0), 0.0)
    return RecordTransforms(w, U, Y, T, st, held, free, h, m, n)


def _fit_fourier(req: FourierRequest) -> TransferFunctionFit:
    """Output error on the record's Fourier transforms, ``min Σ |Y − T U − E/D|²`` with
    real parameters and ``E`` the record's ends (`_end_basis`), as `boundary` asks."""

    from .frequency_domain import _BOUNDARY_LEVEL

    w, U, Y, T, st, held, free, h, m, n = record_transforms(req)
    input, output, error_bars, boundary = req.input, req.output, req.error_bars, req.boundary
    n_t = len(st.names)
    a_cols = slice(m + 1, m + 1 + n)

    def model(full: FloatArray, basis: ComplexArray | None) -> tuple[ComplexArray, ComplexArray]:
        logt, g = st.log_response(full[:n_t])
        tu = np.exp(logt) * U
        d_theta = tu[:, None] * g
        if basis is None:
            return tu, d_theta
        den = st.sn + st.sa @ full[a_cols]
        ends = (basis @ full[n_t:]) / den
        d_theta[:, a_cols] -= (ends / den)[:, None] * st.sa
        return tu + ends, np.concatenate([d_theta, basis / den[:, None]], axis=1)

    def fitted(basis: ComplexArray | None, theta: FloatArray) -> tuple[FloatArray, Any, Any]:
        """The fit with or without ends from `theta`, its residual and Jacobian."""

        def residual(full: FloatArray) -> FloatArray:
            v = Y - model(full, basis)[0]
            return np.concatenate([v.real, v.imag])

        def jacobian(full: FloatArray) -> FloatArray:
            d = -model(full, basis)[1]
            return np.concatenate([d.real, d.imag])

        full, mask = theta, free
        if basis is not None:
            # the ends' start: linear least squares given the start's transfer function
            den = st.sn + st.sa @ theta[a_cols]
            c = _end_coefficients(Y - model(theta, None)[0], basis / den[:, None])
            full = np.concatenate([theta, c])
            mask = np.concatenate([free, np.ones(c.size, dtype=bool)])
        return fit_free(residual, jacobian, full, mask), residual, jacobian

    def statistics(
        full: FloatArray, residual: Any, jacobian: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float]:
        mask = np.concatenate([free, np.ones(full.size - n_t, dtype=bool)])
        r, inv, info = _fitted_information(residual, jacobian, full, mask, f"{input} -> {output}")
        # complex circular residuals: each real and imaginary part is one observation of
        # variance σ²/2, estimated from the 2M real residuals less the unknowns
        s2 = float(r @ r) / (r.size - int(mask.sum()))
        cov = white = s2 * inv
        nu = np.full(full.size, float(r.size - int(mask.sum())))
        if error_bars == "colored" and np.all(np.isfinite(inv)):
            # the one correction in its frequency form: each frequency's residual
            # spectrum with its neighbours', and the noise that frequencies off the k/T
            # grid share
            jac = jacobian(full)
            k = w.size
            cov, nu = frequency_sandwich(
                np.stack([jac[:k], jac[k:]], axis=1),
                np.column_stack([r[:k], r[k:]]),
                inv,
                w,
                T,
            )
        return r, info, cov, white, nu, s2

    # the start: the rational fit of Y/U weighted by |U| (its equation-error form)
    def tf_only(theta: FloatArray) -> FloatArray:
        v = Y - model(theta, None)[0]
        return np.concatenate([v.real, v.imag])

    theta = _start(st, h, w, np.abs(U) ** 2, tf_only, req.start)
    for k_, v_ in held.items():
        theta[st.names.index(k_)] = v_
    basis = None if boundary == "ignore" else _end_basis(w, T, max(m, n))
    if basis is not None and 2 * w.size <= int(free.sum()) + basis.shape[1]:
        if boundary == "estimate":
            raise IdentificationError(
                f"boundary='estimate': {w.size} frequencies cannot fit {int(free.sum())} "
                f"parameters and {basis.shape[1]} record-end terms"
            )
        basis = None
    full, residual, jacobian = fitted(basis, theta)
    r, info, cov, white, nu, s2 = statistics(full, residual, jacobian)
    if basis is not None and boundary == "auto":
        ends = slice(n_t, None)
        p_value = wald_p_value(full[ends], [cov[ends, ends], white[ends, ends]])
        if p_value >= _BOUNDARY_LEVEL:  # not different from zero: the fit without them
            basis = None
            full, residual, jacobian = fitted(None, full[:n_t])
            r, info, cov, white, nu, s2 = statistics(full, residual, jacobian)
    fit = FourierFit(full[:n_t], cov[:n_t, :n_t], info[:n_t, :n_t], nu[:n_t], s2, float(r @ r))
    return fourier_record(req, st, free, fit, w, h, "fourier", ends=basis is not None)


class FourierFit(NamedTuple):
    """A Fourier fit's estimates in the structure's order, their covariance, the
    information, degrees of freedom, residual variance and residual sum of squares."""

    theta: FloatArray
    cov: FloatArray
    info: FloatArray
    nu: FloatArray
    s2: float
    sse: float


def fourier_record(
    req: FourierRequest,
    st: _Structure,
    free: NDArray[np.bool_],
    fit: FourierFit,
    w: FloatArray,
    h: ComplexArray,
    label: str,
    *,
    ends: bool,
) -> TransferFunctionFit:
    """The record of a fit to a record's Fourier transforms (output or equation error)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        se = undetermined_bars(fit.cov, free, st.names, f"{req.input} -> {req.output}", 3)
        insens = np.sqrt(fit.s2) / np.sqrt(np.diag(fit.info))
    return _fit_record(
        st,
        fit.theta,
        se,
        insens,
        fit.cov,
        0.5 * fit.sse / fit.s2,
        label,
        1.0,
        w,
        h,
        np.ones(w.size),
        np.full(w.size, np.nan),
        req.input,
        req.output,
        dict(zip(st.names, fit.nu.tolist(), strict=True)),
        ends,
    )


def undetermined_bars(
    cov: FloatArray, free: NDArray[np.bool_], names: Sequence[str], pair: str, depth: int
) -> FloatArray:
    """Standard errors from `cov`; a free parameter whose variance is not a positive
    number (rounding in a covariance the data leave singular: more poles and zeros
    than they hold) gets an infinite one, and a warning names them."""
    var = np.diag(cov)
    bad = free & ~(np.isfinite(var) & (var > 0))
    se = np.sqrt(np.clip(np.where(np.isfinite(var), var, 0.0), 0.0, None))
    if np.any(bad):
        se[bad] = np.inf
        lost = [n for n, b in zip(names, bad.tolist(), strict=True) if b]
        warnings.warn(
            f"fit_transfer_function ({pair}): the data cannot determine {lost} (their "
            "covariance is singular: an order higher than the response holds?); their "
            "standard errors are reported as infinite",
            IdentifiabilityWarning,
            stacklevel=CALLER_STACKLEVEL + depth,  # `depth` helpers below the public call
        )
    return se


def fit_free(
    residual: Callable[[FloatArray], FloatArray],
    jacobian: Callable[[FloatArray], FloatArray],
    theta: FloatArray,
    free: NDArray[np.bool_],
) -> FloatArray:
    """`theta` with its free entries fitted by SciPy's Levenberg–Marquardt (the held
    ones kept), through the one least-squares entry point and its stopping rule:
    the one least-squares call of the transfer-function fits."""

    def full(x: FloatArray) -> FloatArray:
        return _filled(theta, free, x)

    fit = fit_residuals(
        lambda x: residual(full(x)),
        lambda x: jacobian(full(x))[:, free],
        theta[free],
        tolerance=_TOLERANCE,
        solver="scipy",
    )
    return full(fit.theta)


def _filled(theta: FloatArray, free: NDArray[np.bool_], x: FloatArray) -> FloatArray:
    """`theta` with its free entries set to `x`, the held ones kept."""
    out = theta.copy()
    out[free] = x
    return out


def _detrended(t: Any, x: FloatArray) -> FloatArray:
    tt = np.asarray(t, dtype=np.float64)
    coef = np.polyfit(tt - tt[0], x, 1)
    return np.asarray(x - np.polyval(coef, tt - tt[0]), dtype=np.float64)


def _free_structure(
    m: int, n: int, delay: Any, w: FloatArray, fixed: Any, band: str, pair: str
) -> tuple[_Structure, dict[str, float], NDArray[np.bool_]]:
    """The fit's structure, its held parameters and the mask of the free ones, refusing
    a fit with nothing free or more free parameters than the frequencies can fit
    (`band` and the channel `pair` word the message)."""
    st = _Structure(m, n, check_flag(delay, "delay", IdentificationError), w)
    held = _held(st, fixed)
    free = np.array([nm not in held for nm in st.names])
    p = int(free.sum())
    if p == 0:
        raise IdentificationError("fixed: every parameter is fixed; nothing left to fit")
    if 2 * w.size <= p:
        raise IdentificationError(f"{w.size} frequencies {band} cannot fit {p} parameters ({pair})")
    return st, held, free


def _fitted_information(
    residual: Callable[[FloatArray], FloatArray],
    jacobian: Callable[[FloatArray], FloatArray],
    theta: FloatArray,
    free: NDArray[np.bool_],
    pair: str,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The residuals at the fitted `theta`, and the inverse and the information matrix
    of the Jacobian's free columns, both zero in the held rows and columns (no
    uncertainty there); an error naming the channel `pair` when the fit diverged."""
    r = residual(theta)
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(r))):
        raise IdentificationError(f"transfer-function fit {pair} diverged; give start values")
    jac = jacobian(theta)[:, free]
    info_free = jac.T @ jac
    inv = np.zeros((free.size, free.size))
    info = np.zeros((free.size, free.size))
    info[np.ix_(free, free)] = info_free
    try:
        inv[np.ix_(free, free)] = np.linalg.inv(info_free)
    except np.linalg.LinAlgError:
        inv[np.ix_(free, free)] = np.inf
    return r, inv, info


def _fit_record(
    st: _Structure,
    theta: FloatArray,
    se: FloatArray,
    insens: FloatArray,
    cov: FloatArray,
    *rest: Any,
) -> TransferFunctionFit:
    """A `TransferFunctionFit` of `theta`: its polynomials in descending powers, the
    denominator monic; `rest` the record's fields from the cost on."""
    b, a, tau = st.split(theta)
    names = st.names
    return TransferFunctionFit(
        dict(zip(names, theta.tolist(), strict=True)),
        dict(zip(names, se.tolist(), strict=True)),
        dict(zip(names, insens.tolist(), strict=True)),
        np.asarray(cov, dtype=np.float64),
        b[::-1].copy(),
        np.concatenate([[1.0], a[::-1]]),
        tau,
        *rest,
    )


def _held(st: _Structure, fixed: Any) -> dict[str, float]:
    """The `fixed` option checked: known names -> finite values."""
    if fixed is None:
        return {}
    if not isinstance(fixed, Mapping):
        raise IdentificationError(
            f"fixed: expected a mapping of parameter name to value, got {plain(fixed)}"
        )
    unknown = sorted(set(fixed) - set(st.names))
    if unknown:
        raise IdentificationError(f"fixed: unknown parameters {unknown}; parameters: {st.names}")
    return {str(k): _start_value(str(k), v, "fixed") for k, v in fixed.items()}


def _start_value(name: str, value: Any, what: str = "start") -> float:
    """A start (or fixed) value as a finite float, else an error naming the parameter."""
    out = as_float(value)
    if out is None or not np.isfinite(out):
        raise IdentificationError(f"{what}[{name!r}]: expected a finite number, got {plain(value)}")
    return out
