"""The coloured-residual correction of every estimator's error bars.

An estimator linear in its residual noise near the estimate has
``theta_hat - theta = M^-1 sum_t G_t' e_t`` with ``G_t`` (n_y, p) the weighted
sensitivities at sample t (regressors for equation error, ``R^-1/2 dy/dtheta``
for output error) and ``M = sum_t G_t' G_t``; with noise of cross-spectrum
``F(w)`` its covariance is ``M^-1 B M^-1``,

    B = sum_ij G_i' R(i - j) G_j = (1/N) sum_k G~_k^H F(w_k) G~_k,

the form Morelli & Klein write in the time domain (SIDPAC's colores) and here
in the frequency domain, where it is cheap and where its estimate can be
corrected for what the fit removed. `colored_covariance` is the one
implementation for estimators that fit time histories (equation error,
stepwise regression, output error, data compatibility); see its docstring
for the estimator and its degrees of freedom. `frequency_sandwich` is the same
``B`` for estimators that fit Fourier transforms on the ``k/T`` grid, where
each frequency is its own window.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Andrews (1991): the quadratic-spectral kernel's optimal bandwidth constant; its
# spectral window is Epanechnikov's, half-width 6 pi / (5 S) rad/sample for lag scale S.
_QS_CONSTANT = 1.3221
_RHO_LIMIT = 0.999
# The window is this many times narrower than Andrews' MSE-optimal one: for
# interval coverage the bias of a wide window near a sharp zero-frequency peak
# matters more than its variance, which the Satterthwaite degrees of freedom
# (and so the t widening) already carry (the fixed-b argument of Kiefer and
# Vogelsang, 2005).
_NARROW = 2.0


def _lag_scale(u: list[FloatArray]) -> float:
    """Andrews' AR(1) plug-in lag scale ``1.3221 (alpha(2) N)^(1/5)`` over all outputs."""
    num = den = 0.0
    n = 0
    for v in u:
        n += v.shape[0]
        c0 = np.einsum("tk,tk->k", v, v)
        c1 = np.einsum("tk,tk->k", v[:-1], v[1:])
        live = c0 > 0
        rho = np.clip(c1[live] / c0[live], -_RHO_LIMIT, _RHO_LIMIT)
        s4 = (c0[live] / v.shape[0]) ** 2
        num += float(np.sum(4.0 * rho**2 * s4 / (1.0 - rho) ** 8))
        den += float(np.sum(s4 / (1.0 - rho) ** 4))
    alpha = num / den if den > 0 else 0.0
    return _QS_CONSTANT * (alpha * n) ** 0.2


def _smooth(x: NDArray[np.generic], half: int) -> NDArray[np.generic]:
    """Epanechnikov smoothing of one-sided spectra along axis 0, reflected at both ends
    (a real series' spectrum is even and periodic); the flat mean when `half` spans
    the band."""
    from ._searches import mirror_smooth

    n_bins = x.shape[0]
    if half >= n_bins - 1:
        return np.broadcast_to(x.mean(axis=0), x.shape).copy()
    d = np.arange(-half, half + 1)
    w = 1.0 - (d / (half + 1.0)) ** 2
    w /= w.sum()
    return mirror_smooth(x, w)


def colored_covariance(
    sensitivities: list[FloatArray],
    residuals: list[FloatArray],
    m_inv: FloatArray,
    *,
    known: list[NDArray[np.complex128]] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Coloured-residual covariance ``M^-1 B M^-1`` and each parameter's degrees of freedom.

    Parameters
    ----------
    sensitivities : list of (n_t, n_y, p) arrays
        Weighted sensitivities ``G`` per record (manoeuvre), so that ``M = sum G'G``.
    residuals : list of (n_t, n_y) arrays
        Weighted residuals ``u`` per record, in the same units as ``G``.
    m_inv : (p, p) array
        The (pseudo-)inverse of ``M`` the estimate used.
    known : list of (n_t + 1, n_y, n_y) complex arrays, optional
        Per record, the expected cross-periodogram (over ``2 n_t`` points, divided
        by ``n_t``) of a part of the residuals whose share of the covariance the
        caller adds itself, such as integrated input noise propagated exactly
        (`aeroid.check_compatibility`). It is taken off the smoothed residual
        periodogram before the division by ``K*(1 - L)`` (the expectation already
        carries the fit's projection), so that part is not counted twice. The
        difference is unbiased but noisy where the known part dominates, and so
        is the covariance returned, which may then be indefinite: the caller
        adds the known part's covariance and makes the sum positive
        semi-definite (clipping this part alone would bias it up).

    Returns
    -------
    cov, nu : the covariance (p, p) and per-parameter Satterthwaite degrees of
    freedom (p,) of its diagonal: a standard error is ``sqrt(cov_jj)``, and its
    95 % interval takes Student's t quantile with ``nu_j`` degrees of freedom
    (`t_quantile`), not 1.96.

    Notes
    -----
    ``B`` needs the noise spectrum where the sensitivities have their energy;
    for constants and slow sensitivities that is near zero frequency, where the
    residuals are least like the noise: the fit removed the noise's component
    in the span of ``G`` (at w = 0 a constant removes all of it, so a sum of
    the residual autocorrelation over all lags, SIDPAC's, is nearly zero
    there). The residual periodogram's expectation tells how much: with the
    Fourier vector ``d_w`` and ``H`` the fit's projection, for noise locally
    flat at ``F(w)``

        E[I_u(w)]_aa = F_aa(w) (1 - L_aa(w)),  L_aa(w) = G~_a(w) M^-1 G~_a(w)^H / n,

    the leverage of frequency w on output a. Over all n Fourier frequencies the
    leverages sum to ``tr(M^-1 M) = p``. The spectrum is therefore estimated by
    smoothing the residual periodogram and the ``1 - L`` together over a
    window and dividing, ``F^ = K*I / K*(1 - L)`` (cross terms by the geometric
    mean of their outputs' factors): near w = 0 it borrows from neighbouring
    frequencies the fit left alone, and with white residuals and the window
    the whole band it is exactly ``SSE / (N - p)``, the classical variance with
    its classical degrees of freedom. That is the whole degrees-of-freedom
    correction for the projection: each frequency loses the fraction of a
    degree of freedom the fit took from it, no more (no ``N_eff / (N_eff - p)``
    factor on top, which would count the loss twice).

    The window is the quadratic-spectral kernel's (Epanechnikov in frequency),
    its bandwidth half Andrews' (1991) AR(1) plug-in from the residuals' lag-one
    correlations (see ``_NARROW``), widened until every smoothed ``K*(1 - L)`` holds at least
    one bin's worth of data. Sensitivities and residuals are transformed over
    2n points, so the circular products are the record's linear sums.

    The spectrum is estimated from a finite band, so ``B^_jj`` is itself
    random: each periodogram bin is ``F chi2_2 / 2``, and ``B^_jj`` a weighted
    sum of them, whose Satterthwaite degrees of freedom ``nu_j = 2 B_jj^2 /
    Var(B^_jj)`` follow from the weights (padded bins counted at half, as two
    share one bin's information). Narrow windows (strong colour) give few
    degrees of freedom and a wide t interval; white residuals give the
    classical N - p.
    """
    p = m_inv.shape[0]
    cov = np.zeros((p, p))
    var_terms = np.zeros(p)
    scale = _lag_scale(residuals)
    if known is not None and len(known) != len(residuals):
        raise ValueError("known: one expected periodogram per record")
    for i, (g, u) in enumerate(zip(sensitivities, residuals, strict=True)):
        n = u.shape[0]
        size = 2 * n
        n_bins = size // 2 + 1
        gf = np.fft.rfft(g, size, axis=0)  # (n_bins, n_y, p)
        uf = np.fft.rfft(u, size, axis=0)  # (n_bins, n_y)
        vf = np.matmul(gf, m_inv)  # sensitivities carried through M^-1
        # leverage of each bin on each output, and the residual cross-periodogram
        lev = np.einsum("kap,kap->ka", vf, gf.conj()).real / n
        keep = np.clip(1.0 - lev, 0.0, 1.0)
        pgram = np.einsum("ka,kb->kab", uf, uf.conj()) / n
        # half-width in bins of 2 pi / size: 6 pi / (5 S) rad/sample
        half = n_bins if scale <= 0 else int(np.ceil(3.0 * size / (5.0 * np.pi * _NARROW * scale)))
        half = max(half, 1)
        while True:
            kept = np.asarray(_smooth(keep, half), dtype=np.float64)
            if half >= n_bins - 1 or np.min(kept) * (half + 1) >= 1.0:
                break  # every estimate rests on at least one bin's worth of data
            half *= 2
        norm = np.sqrt(np.maximum(kept, 1e-300))
        denom = norm[:, :, None] * norm[:, None, :]
        total = _smooth(pgram, half) / denom
        spec = total
        if known is not None:
            # unbiased bin by bin; negative where noise outweighs the remainder, so
            # only the summed covariance is made positive semi-definite (below)
            spec = total - _smooth(np.asarray(known[i]), half) / denom

        # per-bin contributions to the covariance (one-sided: inner bins count twice)
        twice = np.full(n_bins, 2.0 / size)
        twice[0] = twice[-1] = 1.0 / size
        cov += np.einsum("kap,kab,kbq->pq", vf.conj(), spec, vf * twice[:, None, None]).real
        # Satterthwaite: the diagonal's per-bin parts, each a smoothed mean of
        # periodogram bins of unit relative variance (relative to the whole
        # residual spectrum, a known part included), mapped back to those bins
        diag = np.einsum("kap,kab,kbp->kp", vf.conj(), total, vf).real * twice[:, None]
        spread = np.asarray(_smooth(diag, half), dtype=np.float64)
        var_terms += (size / n) * np.sum(spread**2, axis=0)
    cov = 0.5 * (cov + cov.T)
    var = np.abs(np.diag(cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        nu = np.where(var_terms > 0, 2.0 * var**2 / var_terms, np.inf)
    return np.asarray(cov, dtype=np.float64), np.asarray(nu, dtype=np.float64)


def t_quantile(nu: FloatArray, level: float = 0.95) -> FloatArray:
    """The two-sided `level` quantile of Student's t with `nu` degrees of freedom
    (floored at one; the normal's where `nu` is infinite)."""
    from scipy.special import ndtri, stdtrit

    q = 0.5 + 0.5 * float(level)
    nu = np.asarray(nu, dtype=np.float64)
    finite = np.isfinite(nu)
    t = stdtrit(np.maximum(np.where(finite, nu, 1.0), 1.0), q)
    return np.asarray(np.where(finite, t, ndtri(q)), dtype=np.float64)


def margins(
    stderr: Mapping[str, float], dof: Mapping[str, float], level: float
) -> dict[str, float]:
    """Half-widths of two-sided `level` intervals: each standard error times the t
    quantile of its degrees of freedom (the normal's where none is given)."""
    if not 0.0 < level < 1.0:
        from .errors import IdentificationError

        raise IdentificationError(f"level must lie strictly between 0 and 1, got {level!r}")
    names = list(stderr)
    q = t_quantile(np.array([dof.get(n, np.inf) for n in names], dtype=float), level)
    return {n: float(q[i] * stderr[n]) for i, n in enumerate(names)}


def frequency_sandwich(jac: FloatArray, res: FloatArray, m_inv: FloatArray) -> FloatArray:
    """The same ``M^-1 B M^-1`` for an estimator that works on chosen frequencies.

    Frequency-domain estimators fit Fourier transforms on the ``k/T`` grid, where
    the transforms at distinct frequencies are nearly independent however
    coloured the residuals are in time, so ``B`` needs no smoothing across
    frequencies: each frequency's noise spectrum is its own residual's outer
    product, corrected for what the fit removed exactly as `colored_covariance`
    does, ``E[u u'] = F (1 - L)`` with ``L`` that frequency's leverage (here a
    matrix over its real-stacked rows), so ``u`` is scaled by ``(1 - L)^-1/2``.

    Parameters
    ----------
    jac : (M, r, p) array
        Per frequency, the real-stacked weighted sensitivities.
    res : (M, r) array
        Per frequency, the real-stacked weighted residuals.
    m_inv : (p, p) array
        The (pseudo-)inverse of ``M = sum J'J``.
    """
    lev = np.einsum("mrn,nk,msk->mrs", jac, m_inv, jac)
    lev = 0.5 * (lev + lev.transpose(0, 2, 1))
    w, v = np.linalg.eigh(np.eye(lev.shape[1])[None] - lev)
    # a frequency that alone fixes an unknown (1 - L ~ 0) keeps its plain residual
    scale = np.where(w > 1e-9, 1.0 / np.sqrt(np.maximum(w, 1e-300)), 1.0)
    u = np.einsum("mrs,ms,mts,mt->mr", v, scale, v, res)
    score = np.einsum("mrn,mr->mn", jac, u)
    return np.asarray(m_inv @ (score.T @ score) @ m_inv, dtype=np.float64)
