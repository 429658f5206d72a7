"""Time shifts and the input-noise covariance of data compatibility.

Split out of `aeroid.estimation.compatibility` (which re-exports every name): shifting a
channel by a fraction of a sample, the integration substeps, the input noise
levels and their propagation through the kinematics to the outputs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._linalg import information_inverse
from ..errors import IdentificationError
from ..io.data import plain
from ..models import compiled as _compiled
from ._compat_model import _MEASURED, INPUT_CHANNELS, OUTPUT_CHANNELS, STATES

# the pseudo-inverse cut of the input-noise draws' information (`information_inverse`)
_RCOND = 1e-12

FloatArray = NDArray[np.float64]


def _shift(t: FloatArray, y: FloatArray, tau: float) -> FloatArray:
    """``y(t + tau)``: band-limited on a uniform grid, else linear interpolation.

    Linear interpolation by a fraction of a sample averages neighbouring noise
    samples: less noise variance, correlated from sample to sample, and error
    bars that believe the channel became more precise. On a uniform grid the
    shift is a phase ramp in the Fourier domain instead (an all-pass that keeps
    white noise white, of the same variance), applied to the record less the
    line through its end points, continued by its point reflection about each
    end, so that the periodic extension and its slope are continuous; beyond
    the ends the shift then extrapolates to first order.
    """
    if tau == 0.0:
        return y.copy()
    steps = np.diff(t)
    if y.size < 4 or float(np.ptp(steps)) > 1e-6 * float(np.mean(steps)):
        return np.asarray(np.interp(t + tau, t, y), dtype=np.float64)
    n = y.size
    slope = (y[-1] - y[0]) / (t[-1] - t[0])
    rest = y - (y[0] + slope * (t - t[0]))
    odd = np.concatenate([rest, -rest[-2:0:-1]])  # period 2 (n - 1), zero at both ends
    m = odd.size
    freq = np.fft.rfftfreq(m, float(np.mean(steps)))
    shifted = np.fft.irfft(np.fft.rfft(odd) * np.exp(2j * np.pi * freq * tau), m)[:n]
    return np.asarray(shifted + y[0] + slope * (t + tau - t[0]), dtype=np.float64)


def _substeps(time: FloatArray, rates: FloatArray) -> int:
    # Keep h * omega <= 0.05, where an RK4 step's error on a rotation is ~1e-9 of it.
    h = float(np.max(np.diff(time)))
    omega = float(np.max(np.abs(rates)))
    return int(min(max(1, math.ceil(h * omega / 0.05)), 64))


def _input_noise(
    inputs: Mapping[str, FloatArray], given: Mapping[str, float] | None
) -> dict[str, float]:
    """Noise standard deviation per input: given, or the white level the record allows.

    Fourth differences measure the noise near the Nyquist frequency, while the
    kinematics integrate the noise at the lowest frequencies (a gyro bias is
    confounded with the noise's mean). White noise is as strong at every
    frequency, so its level is also bounded by the input's own spectrum in
    whichever band that is lowest: where vibration or buffet lifts the top of
    the band above a quieter middle, the quieter level is the one white noise
    can have (`_spectral_floor`). The smaller of the two is taken.
    """
    if given is not None and not isinstance(given, Mapping):
        raise IdentificationError(
            f"input_noise: expected a mapping input -> standard deviation, got {plain(given)}"
        )
    given = dict(given or {})
    unknown = sorted(set(given) - set(INPUT_CHANNELS))
    if unknown:
        raise IdentificationError(
            f"input_noise: {unknown} are not inputs; inputs: {list(INPUT_CHANNELS)}"
        )
    out = {}
    for c in INPUT_CHANNELS:
        if c in given:
            try:
                value = float(given[c])
            except (TypeError, ValueError):
                value = float("nan")
            if not (math.isfinite(value) and value >= 0):
                raise IdentificationError(
                    f"input_noise[{c!r}]: expected a standard deviation >= 0, got {plain(given[c])}"
                )
            out[c] = value
            continue
        x = inputs[c]
        if x.size < 6:
            out[c] = 0.0
            continue
        # White noise of variance s^2 gives fourth differences of variance 70 s^2,
        # while a smooth signal sampled well above its bandwidth leaves almost none.
        d4 = x[4:] - 4.0 * x[3:-1] + 6.0 * x[2:-2] - 4.0 * x[1:-3] + x[:-4]
        mad = float(np.median(np.abs(d4 - np.median(d4))))
        level = 1.482602218505602 * mad / math.sqrt(70.0)
        out[c] = min(level, _spectral_floor(x))
    return out


def _spectral_floor(x: FloatArray, *, level: float = 0.05) -> float:
    """An upper confidence bound on the standard deviation of white noise in `x`.

    Welch's averaged periodogram (Hann segments of about ``4 sqrt(n)`` points,
    half overlapping, each less its line) in bands of eight bins: white noise
    of variance ``s^2`` has density ``2 s^2 dt`` in every band, and the signal only
    adds to it. Each band's mean, with ``K B`` degrees of freedom for ``K``
    segments and ``B`` bins (half the nominal count: overlapping segments and
    the window's neighbouring bins are correlated), bounds ``s^2`` from above at
    confidence ``1 - level / n_bands`` (Bonferroni over the bands), so that the
    smallest bound undercuts white noise's level with probability at most
    `level`. Infinite where the record is too short for two bands.
    """
    from scipy.special import chdtri  # scipy.stats costs a first call tenths of a second

    from .._searches import welch_density

    n = x.size
    seg = 1 << max(5, round(math.log2(4.0 * math.sqrt(n))))
    if n < 2 * seg:
        return math.inf
    var = welch_density(x, seg)[2:-1] / 2.0  # the line took the lowest bins
    width = 8
    n_bands = var.size // width
    if n_bands < 2:
        return math.inf
    bands = var[: n_bands * width].reshape(n_bands, width).mean(axis=1)
    segments = 1 + (n - seg) // (seg // 2)
    dof = float(segments * width)
    bound = float(np.min(bands)) * dof / float(chdtri(dof, 1.0 - level / n_bands))
    return math.sqrt(bound)


def _difference_response(
    model: Any,
    t: FloatArray,
    controls: FloatArray,
    noise: FloatArray,
    theta: FloatArray,
    x0: FloatArray,
    names: list[str],
    x_idx: list[int],
    out_idx: list[int],
    weight: FloatArray,
    substeps: int,
) -> tuple[FloatArray, FloatArray | None]:
    """Weighted output sensitivities by forward differences and the draws' output changes.

    One simulated batch: the fitted point, a forward difference in every estimated
    parameter and initial state (accurate to about the step, a millionth: ample for an
    error bar), then the draws of input noise. None for the changes when a member fails.
    """
    n_p = len(names)
    n_draws = noise.shape[0]
    cols = n_p + len(x_idx)
    steps = np.empty(cols)
    steps[:n_p] = 1e-6 * np.maximum(np.abs(theta), 1e-3)
    steps[n_p:] = 1e-6 * np.maximum(np.abs(x0[x_idx]), 1.0)
    batch = 1 + cols + n_draws
    P = {n: np.full(batch, theta[j]) for j, n in enumerate(names)}
    X0 = np.repeat(x0[None, :], batch, axis=0)
    for j in range(cols):
        if j < n_p:
            P[names[j]][1 + j] += steps[j]
        else:
            X0[1 + j, x_idx[j - n_p]] += steps[j]
    U = np.repeat(controls[None], batch, axis=0)
    U[1 + cols :] += noise
    sim = model.simulate_batch(t, U, X0, P, method="rk4", substeps=substeps)
    if not np.all(sim.ok):
        return np.zeros((cols, 0)), None
    y = np.asarray(sim.outputs)[:, :, out_idx] * weight[None, None, :]
    jw = ((y[1 : 1 + cols] - y[:1]) / steps[:, None, None]).reshape(cols, -1)
    return jw, y[1 + cols :] - y[:1]


def _joint(n_p: int, n_x: int, n_rec: int, r: int, local: FloatArray, rows: bool) -> FloatArray:
    """A record's matrix over (parameters, its own initial states) placed in the joint
    space (parameters, every record's initial states): columns, or rows and columns."""
    if n_rec == 1:
        return local
    n = n_p + n_rec * n_x
    idx = np.concatenate([np.arange(n_p), n_p + r * n_x + np.arange(n_x)])
    if rows:
        out = np.zeros((n, n))
        out[np.ix_(idx, idx)] = local
    else:
        out = np.zeros((local.shape[0], n))
        out[:, idx] = local
    return out


def _input_noise_covariance(
    model: Any,
    pieces: list[tuple[FloatArray, FloatArray]],
    fit: Any,
    names: list[str],
    free_x0: list[str],
    out_idx: list[int],
    sigma: Mapping[str, float],
    *,
    n_draws: int,
    seed: int,
    substeps: int,
) -> FloatArray:
    """Covariance of the estimates that white input noise causes (see `check_compatibility`);
    `pieces` holds each record's time and controls (independent noise in each)."""
    n_p = len(names)
    # the measured stand-ins for states are not integrated: no share of theirs here
    scale = np.array([sigma[c] for c in INPUT_CHANNELS] + [0.0] * len(_MEASURED))
    if not np.any(scale > 0):
        return np.zeros((n_p, n_p))
    theta = np.array([fit.parameters[n] for n in names])
    x_idx = [STATES.index(s) for s in free_x0]
    variance = np.clip(np.diag(np.asarray(fit.noise_covariance)), 1e-300, None)
    params = dict(model.parameters)
    params.update(zip(names, theta.tolist(), strict=True))
    inverse = np.zeros(len(OUTPUT_CHANNELS))
    inverse[out_idx] = 1.0 / variance
    rng: Any = None
    info: Any = 0.0
    scatter: Any = 0.0
    n_rec = len(pieces)
    for r, (t, controls) in enumerate(pieces):
        x0 = np.array([fit.initial_states[r][s] for s in STATES])
        # Compiled: exact to first order, by the adjoint of the linearised kinematics.
        got = _compiled.input_noise_scatter(
            model, t, controls, x0, params, names, x_idx, substeps, inverse, scale
        )
        if got is not None:
            _, sens, part = got
            if not (np.all(np.isfinite(sens)) and np.all(np.isfinite(part))):
                return np.zeros((n_p, n_p))
            jac = sens[:, out_idx, :] / np.sqrt(variance)[None, :, None]
            flat = jac.reshape(-1, jac.shape[2])
            local = flat.T @ flat
        else:
            # Without the compiled path: the scatter of `n_draws` simulated draws.
            weight = 1.0 / np.sqrt(variance)
            rng = np.random.default_rng(seed) if rng is None else rng
            noise = rng.standard_normal((n_draws, *controls.shape)) * scale[None, None, :]
            jw, dy = _difference_response(
                model, t, controls, noise, theta, x0, names, x_idx, out_idx, weight, substeps
            )
            if dy is None:
                return np.zeros((n_p, n_p))
            local = jw @ jw.T
            gradients = jw @ dy.reshape(n_draws, -1).T
            part = gradients @ gradients.T / n_draws
        info = info + _joint(n_p, len(x_idx), n_rec, r, local, True)
        scatter = scatter + _joint(n_p, len(x_idx), n_rec, r, part, True)
    # the estimate shifts (J' W J)^-1 J' W dy: their covariance
    half = np.linalg.lstsq(info, scatter, rcond=1e-12)[0]
    cov = np.linalg.lstsq(info, half.T, rcond=1e-12)[0]
    return np.asarray(cov[:n_p, :n_p], dtype=np.float64)


def _measurement_noise_covariance(
    model: Any,
    pieces: list[tuple[FloatArray, FloatArray]],
    fit: Any,
    names: list[str],
    free_x0: list[str],
    out_idx: list[int],
    sigma: Mapping[str, float],
    *,
    n_draws: int,
    seed: int,
    substeps: int,
) -> tuple[float, FloatArray, FloatArray] | None:
    """The input-noise scale the residuals allow, and the coloured covariance of the rest.

    The output residuals already hold the integrated input noise: a coloured
    correction of them plus the input-noise share would count it twice. Draws of
    white input noise at levels ``sigma`` carried through the fitted kinematics and
    the fit's projection give the residual cross-periodogram that noise is
    expected to leave; the coloured covariance (`colored_covariance`) is taken
    of what the residual spectrum holds beyond it, the measurement noise.

    The input levels are upper bounds on the white input noise (see
    `_input_noise`), and the residual of an output cannot be smaller than the
    integrated input noise alone leaves it: where it is, beyond chance, every
    level is scaled down by one common factor (`_allowed_scale`). Returns that
    factor ``c`` (on variances), the measurement-noise covariance of the
    parameters and its degrees of freedom; None where no input noise is set
    or a draw fails. `pieces` holds each record's time and controls.
    """
    from .._colour import colored_covariance

    n_p = len(names)
    scale = np.array([sigma[c] for c in INPUT_CHANNELS] + [0.0] * len(_MEASURED))
    if not np.any(scale > 0) or not fit.residuals:
        return None
    theta = np.array([fit.parameters[n] for n in names])
    x_idx = [STATES.index(s) for s in free_x0]
    variance = np.clip(np.diag(np.asarray(fit.noise_covariance)), 1e-300, None)
    weight = 1.0 / np.sqrt(variance)
    rng = np.random.default_rng(seed)
    n_y, n_rec = len(out_idx), len(pieces)
    jacs: list[FloatArray] = []
    flats: list[FloatArray] = []
    for r, (t, controls) in enumerate(pieces):
        x0 = np.array([fit.initial_states[r][s] for s in STATES])
        noise = rng.standard_normal((n_draws, *controls.shape)) * scale[None, None, :]
        jw, dy = _difference_response(
            model, t, controls, noise, theta, x0, names, x_idx, out_idx, weight, substeps
        )
        if dy is None:
            return None
        # (n n_y, p + free states)
        jacs.append(_joint(n_p, len(x_idx), n_rec, r, jw.T, False))
        flats.append(dy.reshape(n_draws, -1).T)
    info = jacs[0].T @ jacs[0]
    for jac in jacs[1:]:
        info = info + jac.T @ jac
    m_inv = information_inverse(info, rcond=_RCOND)
    pull = jacs[0].T @ flats[0]
    for jac, flat in zip(jacs[1:], flats[1:], strict=True):
        pull = pull + jac.T @ flat
    step = m_inv @ pull
    drawn: Any = 0.0
    seen: Any = 0.0
    known: list[Any] = []
    residuals: list[FloatArray] = []
    for r, (jac, flat) in enumerate(zip(jacs, flats, strict=True)):
        n = pieces[r][0].size
        left = (flat - jac @ step).T.reshape(n_draws, n, n_y)
        u = np.asarray(fit.residuals[r], dtype=np.float64) * weight[None, :]
        drawn = drawn + np.sum(left**2, axis=1)
        seen = seen + np.sum(u**2, axis=0)
        lf = np.fft.rfft(left, 2 * n, axis=1)
        known.append(np.einsum("dka,dkb->kab", lf, lf.conj()))
        residuals.append(u)
    c = _allowed_scale(drawn, seen)
    # the output weights were estimated from these residuals (the fit's noise covariance)
    cov, nu = colored_covariance(
        [jac.reshape(pieces[r][0].size, n_y, -1) for r, jac in enumerate(jacs)],
        residuals,
        m_inv,
        known=[c * k / (pieces[r][0].size * n_draws) for r, k in enumerate(known)],
        estimated_weights=True,
        rcond=_RCOND,
    )
    return c, np.asarray(cov[:n_p, :n_p]), np.asarray(nu[:n_p])


def _allowed_scale(drawn: FloatArray, seen: FloatArray, *, level: float = 0.05) -> float:
    """The largest common factor on the input-noise variances the residuals allow.

    `drawn` (n_draws, n_y) holds the residual sum of squares that draws of the input
    noise alone leave on each output, `seen` (n_y,) the flight's. The sum of squares
    of a projected random walk has few degrees of freedom: its distribution is
    taken as Satterthwaite's scaled chi-square from the draws' mean and variance,
    and an output rejects the noise level only when its residual falls below that
    distribution's ``level / n_y`` quantile (Bonferroni over the outputs). The
    factor is then the one that puts the residual at that quantile: ``c = min(1,
    min_a seen_a / q_a)``. The flight's residual also holds measurement noise, so
    the test is conservative: it lowers the level only where the data show it.
    """
    from scipy.special import chdtri

    mean = np.mean(drawn, axis=0)
    var = np.var(drawn, axis=0, ddof=1) if drawn.shape[0] > 1 else np.zeros_like(mean)
    live = mean > 0
    if not np.any(live):
        return 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(var[live] > 0, 2.0 * mean[live] ** 2 / var[live], 1e6)
    low = mean[live] * chdtri(dof, 1.0 - level / int(np.sum(live))) / dof
    return float(min(1.0, np.min(seen[live] / low)))
