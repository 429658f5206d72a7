"""The scatter that estimating each output's weight from its residuals adds.

`colored_covariance` gives an estimate's covariance ``M^-1 B M^-1`` at fixed
weights. Output error weights each output by the mean square of its own
residuals (maximum likelihood), which is feasible GLS: the weights move with
the noise. To first order that adds nothing (Kackar & Harville, 1984: with
white noise the residuals, hence the weights, are independent of the
estimate), but coloured noise ties them together: a record whose slow noise
lies along a slow sensitivity loses it to the fit, that output's residual
mean square falls, its weight rises, and the estimate leans on the very
output that misled it. Where an output's noise has few degrees of freedom
this is not small: on SIDPAC's oe_lat flight it multiplies a side-force
derivative's spread by 1.6, as refits of the flight's own residuals also
show. `weighting_spread` measures it on the linearised estimator (Gaussian
records with the estimated spectrum, refitted with the weights re-estimated
to their fixed point and with the weights held); the caller multiplies each
variance by the ratio of the two spreads.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Gaussian records in `_weighting_spread`: the ratio of two spreads over the
# same draws, steady to a few per cent (its seed is fixed: the bars are data's).
_DRAWS = 400
_DRAW_BATCH = 50


def _spectral_roots(spec: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """A square root ``L L^H = F`` of each bin's cross-spectrum (positive semi-definite)."""
    scale = np.maximum(np.einsum("kaa->k", spec).real, 1e-300)
    eye = np.eye(spec.shape[1])
    try:
        return np.linalg.cholesky(spec + 1e-12 * scale[:, None, None] * eye)
    except np.linalg.LinAlgError:  # rank-deficient to rounding: clip the eigenvalues
        lam, vec = np.linalg.eigh(spec)
        return vec * np.sqrt(np.clip(lam, 0.0, None))[:, None, :]


def weighting_spread(
    sensitivities: list[FloatArray],
    spectra: list[NDArray[np.complex128]],
    m_inv: FloatArray,
    *,
    draws: int = _DRAWS,
    seed: int = 0,
) -> FloatArray:
    """Each parameter's variance with the weights re-estimated over its variance at fixed weights.

    The estimator is linearised at the estimate, in the weighted units the
    caller's ``M`` has (every weight one): ``theta(w) = (sum_a w_a A_a)^-1
    sum_a w_a G_a' e_a`` with ``A_a = G_a' G_a`` per output, and the weights
    at their fixed point ``w_a = N / |e_a - G_a theta(w)|^2``, the maximum-
    likelihood noise variances. `draws` records of noise with the estimated
    cross-spectrum (`spectra`, one per record, on the ``2 n`` bins of
    `colored_covariance`) are drawn with a fixed seed, so the same data give
    the same bars; both estimators see the same draws, so their ratio is far
    steadier than either variance. Each draw is the first ``n`` samples of a
    ``2n``-point circular record, as the spectrum's bins are, so its
    autocovariance is the spectrum's at every lag of the record (``n``
    points alone would wrap the slowest noise around); only ``G_a' e_a`` and
    ``|e_a|^2`` of it enter. Parameters outside the span of ``M`` (held or
    unidentifiable) get a ratio of one.
    """
    n_y = sensitivities[0].shape[1]
    if not all(np.all(np.isfinite(spec)) for spec in spectra):
        return np.ones(m_inv.shape[0])  # no spectrum to draw from: the bars at fixed weights
    # the estimable subspace: every weighting with positive weights has the same one
    lam, vec = np.linalg.eigh(m_inv)
    basis = vec[:, lam > lam.max() * 1e-13] if lam.max() > 0 else vec[:, :0]
    r = basis.shape[1]
    if r == 0:
        return np.ones(m_inv.shape[0])
    info = np.zeros((n_y, r, r))
    cross = np.zeros((n_y, draws, r))
    squares = np.zeros((draws, n_y))
    count = 0
    rng = np.random.default_rng(seed)
    for g, spec in zip(sensitivities, spectra, strict=True):
        n = g.shape[0]
        size = 2 * n  # the first n samples of a 2n-point circular record: not periodic
        count += n
        gb = np.ascontiguousarray(np.moveaxis(g @ basis, 1, 0))  # (n_y, n, r)
        info += np.matmul(np.swapaxes(gb, 1, 2), gb)
        root = np.sqrt(size) * _spectral_roots(spec)
        n_bins = spec.shape[0]
        for start in range(0, draws, _DRAW_BATCH):
            b = min(_DRAW_BATCH, draws - start)
            z = rng.standard_normal((b, n_bins, n_y, 2)).view(np.complex128)[..., 0]
            z *= np.sqrt(0.5)
            z[:, 0] = rng.standard_normal((b, n_y))
            z[:, -1] = rng.standard_normal((b, n_y))
            x = np.matmul(root, z[..., None])[..., 0]  # (b, bins, n_y)
            e = np.fft.irfft(x, size, axis=1)[:, :n, :]
            e_t = np.ascontiguousarray(np.moveaxis(e, 2, 0))  # (n_y, b, n)
            cross[:, start : start + b] += np.matmul(e_t, gb)
            squares[start : start + b] += np.einsum("abt,abt->ba", e_t, e_t)
    if not np.all(squares > 0):
        return np.ones(m_inv.shape[0])  # an output without noise: nothing to weigh
    try:
        fixed, theta = _estimates(info, cross, squares, count)
    except np.linalg.LinAlgError:  # a weighting that loses the span: keep the fixed bars
        return np.ones(m_inv.shape[0])
    v_fixed = np.einsum("jk,kl,jl->j", basis, np.cov(fixed.T).reshape(r, r), basis)
    v_free = np.einsum("jk,kl,jl->j", basis, np.cov(theta.T).reshape(r, r), basis)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = v_free / v_fixed
    return np.asarray(np.where((v_fixed > 0) & np.isfinite(ratio), ratio, 1.0), dtype=np.float64)


def _estimates(
    info: FloatArray, cross: FloatArray, squares: FloatArray, count: int
) -> tuple[FloatArray, FloatArray]:
    """Per draw, the estimate at fixed (unit) weights and at its weights' fixed point."""
    fixed = np.linalg.solve(np.einsum("apq->pq", info), np.einsum("adp->pd", cross)).T
    theta = fixed
    w = np.ones(squares.shape)
    for _ in range(50):
        fit = np.einsum("adp,dp->da", cross, theta)
        ss = squares - 2.0 * fit + np.einsum("dp,apq,dq->da", theta, info, theta)
        w_new = count / np.maximum(ss, 1e-300 * squares)
        mw = np.einsum("da,apq->dpq", w_new, info)
        rhs = np.einsum("da,adp->dp", w_new, cross)
        theta = np.linalg.solve(mw, rhs[..., None])[..., 0]
        done = np.max(np.abs(w_new / w - 1.0)) < 1e-9
        w = w_new
        if done:
            break
    return fixed, theta
