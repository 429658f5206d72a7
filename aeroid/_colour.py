"""The coloured-residual correction of every estimator's error bars.

An estimator linear in its residual noise near the estimate has
``theta_hat - theta = M^-1 sum_t G_t' e_t`` with ``G_t`` (n_y, p) the weighted
sensitivities at sample t (regressors for equation error, ``R^-1/2 dy/dtheta``
for output error) and ``M = sum_t G_t' G_t``; with noise of cross-spectrum
``F(w)`` its covariance is ``M^-1 B M^-1``,

    B = sum_ij G_i' R(i - j) G_j = (1/N) sum_k G~_k^H F(w_k) G~_k,

the form Morelli & Klein write in the time domain (SIDPAC's colores) and here
in the frequency domain, where it is cheap, where its estimate can be
corrected for what the fit removed, and where prewhitening by an AR(1) filter
and recolouring by its inverse are products. `colored_covariance` is the one
implementation for estimators that fit time histories (equation error,
stepwise regression, output error, data compatibility); see its docstring
for the estimator and its degrees of freedom. `frequency_sandwich` is the same
``B`` for estimators that fit Fourier transforms at chosen frequencies, where
the window spans a frequency and its neighbours. Both hold the weighting fixed;
where it was estimated from the same residuals, both add the scatter that
brings (`estimated_weights`, measured by `aeroid._weighting`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ._ar1_forms import ar1_bilinear
from ._linalg import information_basis
from ._record_kernel import kept_off_grid, off_grid, overlap_terms, record_kernel

FloatArray = NDArray[np.float64]

# Andrews (1991): the quadratic-spectral kernel's optimal bandwidth constant; its
# spectral window is Epanechnikov's, half-width 6 pi / (5 S) rad/sample for lag scale S.
_QS_CONSTANT = 1.3221
_RHO_LIMIT = 0.999
# The window is this many times narrower than Andrews' MSE-optimal one: for coverage
# a wide window's bias at a sharp peak at w = 0 matters more than its variance, which
# the t widening carries (the fixed-b argument of Kiefer and Vogelsang, 2005).
_NARROW = 2.0
# `frequency_sandwich`'s noise spectrum at a chosen frequency: the house window's
# mean over this many neighbouring chosen frequencies either side.
_NEIGHBOURS = 1
# Prewhitening (Andrews & Monahan, 1992) by one AR(1) per output; False gives the
# kernel without it (private: for comparisons only).
_PREWHITEN = True
# Fixed-point steps that move the AR(1) coefficients until the model's expected
# residual lag-one correlation is the one seen (the fit removed the slowest noise).
_AR_STEPS = 3
# At most this many (bin, output) pairs of the low band get the exact covariance.
_BAND_SIZE = 128
# ... and only where the window reaches no further than this many bins from w = 0.
_BAND_ROWS = 4096


def _band_bins(half: int) -> int:
    """The low band's bins for a window `half` bins wide: those whose periodogram
    enters the estimate within the window of w = 0."""
    return 2 * half + 2


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


def _prewhitening(u: list[FloatArray]) -> FloatArray:
    """Each output's lag-one correlation pooled over the records (least squares),
    within +-`_cap` (zero for an output without residuals)."""
    return np.asarray(np.clip(_lag_one(u), -_cap(u), _cap(u)), dtype=np.float64)


def _innovations(u: list[FloatArray], a: FloatArray) -> FloatArray:
    """Each output's mean square of the whitened residuals ``u_t - a u_{t-1}``."""
    num = sum(np.einsum("tk,tk->k", v[1:] - a * v[:-1], v[1:] - a * v[:-1]) for v in u)
    den = sum(max(v.shape[0] - 1, 1) for v in u)
    out = np.asarray(num, dtype=np.float64) / den
    return np.asarray(np.where(out > 0, out, 1.0), dtype=np.float64)


def _bins(
    g: FloatArray, a: FloatArray, size: int
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], FloatArray]:
    """The sensitivities' one-sided transform over `size` points, the prewhitening
    filter ``1 - a e^{-iw}`` at its bins, and each bin's weight in a linear sum
    (inner bins count twice)."""
    n_bins = size // 2 + 1
    gf = np.fft.rfft(g, size, axis=0)
    filt = 1.0 - a[None, :] * np.exp(-2j * np.pi * np.arange(n_bins) / size)[:, None]
    twice = np.full(n_bins, 2.0 / size)
    twice[0] = twice[-1] = 1.0 / size
    return gf, filt, twice


class _ArModel(NamedTuple):
    """The AR(1) noise model a residual periodogram's expectation was taken under."""

    keeps: list[FloatArray]  # per record, E[I_u] over the model spectrum (bins, n_y)
    level: FloatArray  # each output's innovation variance
    cov: FloatArray  # the estimate's covariance under it, M^-1 (sum G'SG) M^-1
    sgf: list[NDArray[np.complex128]]  # per record, the transform of S G (bins, n_y, p)


def _model_keeps(
    sensitivities: list[FloatArray], residuals: list[FloatArray], m_inv: FloatArray, a: FloatArray
) -> _ArModel:
    """Per record, bin and output, the residual periodogram's expectation over the noise
    spectrum were the noise the AR(1) model `a` (``1 - L`` for white noise).

    With ``S`` the model's covariance (one AR(1) per output), ``H = G M^-1 G'`` and
    ``d`` the Fourier vector, ``E[I_u(w)] = d'(S - 2 HS + HSH)d / n``: the Fejer mean
    of the model spectrum, less twice ``Re G~ M^-1 (SG)~^H / n``, plus
    ``G~ M^-1 G'SG M^-1 G~^H / n``, exact through Toeplitz products by FFT.
    """
    level = _innovations(residuals, a)
    p = m_inv.shape[0]
    b_model = np.zeros((p, p))
    if not np.any(a != 0.0):
        out = []
        sgfs = []
        for g, u in zip(sensitivities, residuals, strict=True):
            gf, _, _ = _bins(g, a, 2 * u.shape[0])
            lev = np.einsum("kaq,kaq->ka", gf @ m_inv, gf.conj()).real / u.shape[0]
            out.append(np.clip(1.0 - lev, 0.0, 1.0))
            b_model += np.einsum("tap,taq,a->pq", g, g, level)
            sgfs.append(gf * level[None, :, None])
        return _ArModel(out, level, m_inv @ b_model @ m_inv, sgfs)
    parts = []
    for g, u in zip(sensitivities, residuals, strict=True):
        n = u.shape[0]
        size = 2 * n
        gf, filt, _ = _bins(g, a, size)
        lags = np.arange(n)[:, None]
        acov = level / (1.0 - a**2) * a[None, :] ** lags  # (n, n_y)
        # the Toeplitz product S g, exact through a circulant of twice the length
        circ = np.concatenate([acov, np.zeros((1, a.size)), acov[:0:-1]])
        spec = np.fft.rfft(circ, axis=0).real  # (n_bins, n_y)
        sg = np.fft.irfft(spec[:, :, None] * gf, size, axis=0)[:n]
        b_model += np.tensordot(g, sg, axes=([0, 1], [0, 1]))
        # Fejer mean of the model spectrum: sum_|k|<n (1 - |k|/n) r(k) e^{-iwk}
        taper = (1.0 - lags / n) * acov
        fejer = 2.0 * np.fft.rfft(taper, size, axis=0).real - taper[0]
        shape = level[None, :] / np.abs(filt) ** 2
        parts.append((gf, np.fft.rfft(sg, size, axis=0), fejer, shape, n))
    model_cov = m_inv @ b_model @ m_inv
    out = []
    for gf, sgf, fejer, shape, n in parts:
        cross = np.einsum("kaq,kaq->ka", gf @ m_inv, sgf.conj()).real / n
        back = np.einsum("kaq,kaq->ka", gf @ model_cov, gf.conj()).real / n
        out.append(np.clip((fejer - 2.0 * cross + back) / shape, 0.0, None))
    return _ArModel(out, level, model_cov, [part[1] for part in parts])


def _band_moments(
    gf: NDArray[np.complex128],
    sgf: NDArray[np.complex128],
    n: int,
    a: FloatArray,
    level: FloatArray,
    m_inv: FloatArray,
    model_cov: FloatArray,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """``E[w w^H]`` and ``E[w w^T]``, each (bins, n_y, bins, n_y), of the whitened
    padded transform ``w_la = (1 - a_a e^{-i w_l}) u~_la`` of one record's residuals
    over the first bins (those of `gf` and `sgf`, the transforms of ``G`` and
    ``SG``), were the noise the AR(1) model (innovation variances `level`) and
    ``u = (I - H) e`` the fit's residuals.

    With ``d_l`` the Fourier vector, ``E[u~_la u~_mb^*] = d_l'(S - HS - SH + HSH)_ab
    d_m^*``; the ``S`` part in closed form, the others through ``G~`` and
    ``(SG)~``. ``E[u~ u~^T]`` is the same with ``d_m`` unconjugated: it vanishes
    only for a circular series, which the low bins of a real record are not.
    """
    size = 2 * n
    bins, n_y = gf.shape[:2]
    w = 2.0 * np.pi * np.arange(bins) / size
    s_gam = np.zeros((bins, n_y, bins), dtype=np.complex128)  # d_l' S_a d_m^*
    s_rel = np.zeros((bins, n_y, bins), dtype=np.complex128)  # d_l' S_a d_m
    for k in range(n_y):
        var = float(level[k] / (1.0 - a[k] ** 2))
        s_gam[:, k] = ar1_bilinear(w, n, float(a[k]), var, conjugate=False)
        s_rel[:, k] = ar1_bilinear(w, n, float(a[k]), var, conjugate=True)
    eye = np.eye(n_y)
    gm_inv = (gf @ m_inv).reshape(bins * n_y, -1)
    sgm_inv = (sgf @ m_inv).reshape(bins * n_y, -1)
    gm_cov = (gf @ model_cov).reshape(bins * n_y, -1)
    moments = []
    for s_part, gm, sgm in ((s_gam, gf.conj(), sgf.conj()), (s_rel, gf, sgf)):
        gm2 = gm.reshape(bins * n_y, -1).T
        mom = np.einsum("lam,ab->lamb", s_part, eye).reshape(bins * n_y, -1)
        mom = mom - gm_inv @ sgm.reshape(bins * n_y, -1).T - sgm_inv @ gm2 + gm_cov @ gm2
        moments.append(mom.reshape(bins, n_y, bins, n_y))
    filt = 1.0 - a[None, :] * np.exp(-1j * w)[:, None]
    gam = filt[:, :, None, None] * moments[0] * filt.conj()[None, None, :, :]
    rel = filt[:, :, None, None] * moments[1] * filt[None, None, :, :]
    return np.asarray(gam), np.asarray(rel)


def _window_columns(n_bins: int, half: int, rows: int, bins: int) -> FloatArray:
    """``K[:rows, :bins]`` of the smoothing `_smooth` applies with half-width `half`
    over `n_bins` bins: ``K*x`` at bin k is ``sum_l K_kl x_l``."""
    if half >= n_bins - 1:
        return np.full((rows, bins), 1.0 / n_bins)
    window = _window(half)
    k = np.arange(rows)[:, None]
    col = np.arange(bins)[None, :]

    def _w(off: NDArray[np.int_]) -> FloatArray:
        return np.where(np.abs(off) <= half, window[np.clip(off + half, 0, 2 * half)], 0.0)

    # bin l reached directly, through its reflection about bin 0 (l > 0), and about
    # the last bin, as `mirror_smooth` pads
    top = 2 * (n_bins - 1) - col
    out = _w(col - k) + np.where(col > 0, _w(-col - k), 0.0)
    return np.asarray(out + np.where(top != col, _w(top - k), 0.0), dtype=np.float64)


def _band_variance(
    z: NDArray[np.complex128],
    weights: FloatArray,
    gam: NDArray[np.complex128],
    rel: NDArray[np.complex128],
    level: NDArray[np.complex128],
    root_keep: FloatArray,
    n: int,
) -> FloatArray:
    """Per parameter, the variance of the low band's share of ``B^_jj``.

    With ``Y_k = z_k^* z_k^T`` (`z` (rows, n_y, p): the carried sensitivities over
    the filter and the window's normaliser, times the bin weight's square root)
    and `weights` ``K[:rows, :bins]``, ``B^_jj = sum_k sum_l K_kl Y_k . I_l``, so
    the band's share is ``Q = sum_l w_l^H A_l w_l`` with ``A_l = conj(R_l) / n``
    and ``R_l = sum_k K_kl Y_k``. For Gaussian ``w`` (Isserlis) ``Var Q = tr(A Gam
    A Gam) + tr(Rel^* A Rel A^T)`` and ``E Q = tr(A Gam)`` under the model; the
    variance is scaled by ``(Q^ / E Q)^2`` to the data's level: ``Q^`` is the
    band's share of ``B^_jj`` as the estimate itself puts it, each bin k's
    smoothed whitened spectrum over its normaliser (`level`, (rows, n_y, n_y))
    times bin l's share ``sqrt(k_la k_lb)`` (`root_keep`, (bins, n_y)), so that
    a band spanning every bin has ``Q^ = B^_jj`` and ``nu >= 1``.
    """
    bins, n_y = gam.shape[:2]
    size = bins * n_y
    flat_gam = gam.reshape(bins, n_y, size)
    rel_conj = np.moveaxis(rel.conj().reshape(size, bins, n_y), 1, 0)  # (m, la, c)
    rel_l = np.moveaxis(rel.reshape(size, bins, n_y), 1, 0)  # (l, mb, d)
    out = np.zeros(z.shape[-1])
    for j in range(z.shape[-1]):
        zj = z[:, :, j]
        yj = (zj.conj()[:, :, None] * zj[:, None, :]).reshape(zj.shape[0], -1)
        r = (weights.T @ yj).reshape(bins, n_y, n_y)
        seen = (weights.T @ (yj * level.reshape(yj.shape))).reshape(bins, n_y, n_y)
        expected = float(np.sum(seen * root_keep[:, :, None] * root_keep[:, None, :]).real)
        aj = r.conj() / n
        # with A block-diagonal, as (bins n_y, bins n_y) matrices
        ag = np.matmul(aj, flat_gam).reshape(size, size)  # A Gam
        mean = float(np.trace(ag).real)
        if mean <= 0:
            continue
        ca = np.moveaxis(np.matmul(rel_conj, aj), 0, 1).reshape(size, size)  # Rel^* A
        cat = np.moveaxis(np.matmul(rel_l, aj.transpose(0, 2, 1)), 0, 1)  # Rel A^T
        var = np.sum(ag * ag.T).real + np.sum(ca * cat.reshape(size, size).T).real
        out[j] = var * (expected / mean) ** 2
    return out


def _lag_one(u: list[FloatArray]) -> FloatArray:
    """Each output's lag-one correlation, pooled over the records."""
    c0 = np.asarray(sum(np.einsum("tk,tk->k", v, v) for v in u), dtype=np.float64)
    c1 = np.asarray(sum(np.einsum("tk,tk->k", v[:-1], v[1:]) for v in u), dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(c0 > 0, c1 / c0, 0.0), dtype=np.float64)


def _expected_lag_one(keeps: list[FloatArray], u: list[FloatArray], a: FloatArray) -> FloatArray:
    """The residuals' lag-one correlation the AR(1) model `a` and the fit predict."""
    c0 = np.zeros(a.shape)
    c1 = np.zeros(a.shape)
    for keep, v in zip(keeps, u, strict=True):
        size = 2 * v.shape[0]
        w = 2.0 * np.pi * np.arange(keep.shape[0]) / size
        filt = 1.0 - a[None, :] * np.exp(-1j * w)[:, None]
        twice = np.full(keep.shape[0], 2.0)
        twice[0] = twice[-1] = 1.0
        power = twice[:, None] * keep / np.abs(filt) ** 2
        c0 += power.sum(axis=0)
        c1 += (power * np.cos(w)[:, None]).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(c0 > 0, c1 / c0, 0.0), dtype=np.float64)


def _cap(u: list[FloatArray]) -> float:
    """The largest |a| allowed: ``1 - 2 pi / n`` for the longest record (see
    `colored_covariance`)."""
    n = max(v.shape[0] for v in u)
    return float(max(1.0 - 2.0 * np.pi / n, 0.0))


def _smooth(x: NDArray[np.generic], half: int) -> NDArray[np.generic]:
    """Epanechnikov smoothing of one-sided spectra along axis 0, reflected at both ends
    (a real series' spectrum is even and periodic); the flat mean when `half` spans
    the band."""
    from ._searches import mirror_smooth

    n_bins = x.shape[0]
    if half >= n_bins - 1:
        return np.broadcast_to(x.mean(axis=0), x.shape).copy()
    return mirror_smooth(x, _window(half))


def _window(half: int) -> FloatArray:
    """The Epanechnikov window's weights at offsets ``-half .. half`` bins, summing to one."""
    d = np.arange(-half, half + 1)
    w = 1.0 - (d / (half + 1.0)) ** 2
    return np.asarray(w / w.sum(), dtype=np.float64)


def colored_covariance(
    sensitivities: list[FloatArray],
    residuals: list[FloatArray],
    m_inv: FloatArray,
    *,
    known: list[NDArray[np.complex128]] | None = None,
    estimated_weights: bool = False,
    rcond: float | None = None,
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
        Per record, the expected cross-periodogram (over ``2 n_t`` points, over
        ``n_t``) of a part of the residuals whose covariance the caller adds
        itself, such as integrated input noise (`aeroid.check_compatibility`).
        It is whitened and taken off the smoothed periodogram before the
        division by ``K*k`` (it carries the fit's projection), so it is not
        counted twice. The difference is unbiased but noisy where the known
        part dominates, and may be indefinite: the caller makes the sum
        positive semi-definite (clipping this part alone would bias it up).
    estimated_weights : bool
        Each output's weight was estimated from these residuals (output error's
        maximum likelihood): the covariance carries the scatter that adds.
    rcond : float, optional
        `m_inv` is the pseudo-inverse of ``M`` that `aeroid._linalg.information_inverse`
        takes with this cut (0 for the exact inverse): the sandwich is then formed
        over an orthonormal basis of the sensitivities (`information_basis`), so
        near-collinear sensitivities keep their digits. None: `m_inv` holds more
        than ``M`` (a prior, forgetting) and is used as given.

    Returns
    -------
    cov, nu : the covariance (p, p) and per-parameter Satterthwaite degrees of
    freedom (p,) of its diagonal: a standard error is ``sqrt(cov_jj)``, and its
    95 % interval takes Student's t quantile with ``nu_j`` degrees of freedom
    (`aeroid._stats.t_quantile`), not 1.96.

    Notes
    -----
    ``B`` needs the noise spectrum where the sensitivities have their energy;
    for constants and slow sensitivities that is near zero frequency, where the
    residuals are least like the noise: the fit removed the noise's component
    in the span of ``G`` (at w = 0 a constant removes all of it, so a sum of
    the residual autocorrelation over all lags, SIDPAC's, is nearly zero
    there), and where slowly drifting residuals have a peak narrower than any
    window. Both are met as Andrews & Monahan (1992) prescribe: prewhiten,
    smooth, recolour.

    *Prewhitening.* Each output ``a`` gets an AR(1) filter ``1 - a_a e^{-iw}``.
    Its coefficient starts at the residuals' pooled lag-one correlation, which
    under-reads the noise's (the fit took the slowest part of the noise), and
    is moved (`_AR_STEPS` fixed-point steps) until the lag-one correlation the
    model predicts for the *residuals*, ``sum_w E[I_u(w)] cos w / sum_w E[I_u(w)]``
    with the expectation below, is the one seen. It is held within ``|a| <= 1 -
    2 pi / n`` (n the longest record): a root nearer the unit circle makes a
    peak narrower than the record's first Fourier frequency, which the record
    cannot tell from a trend, and there the recoloured spectrum at w = 0 is at
    most twice the model's at that first frequency (Andrews & Monahan cap at a
    fixed 0.97 for the same reason, the recolouring gain ``1 / (1 - a)^2``
    resting on the last digits of a noisy estimate; a fixed cap would truncate
    a 50 Hz record's true 0.99).

    *Smoothing with the fit's leverage.* With ``S`` the model's covariance (one
    AR(1) per output, level the whitened residuals' mean square), ``H`` the
    fit's projection and ``d_w`` the Fourier vector, the residual periodogram
    ``I_u = d' u u' d / n`` has expectation

        E[I_u(w)]_aa = d'(S - 2 H S + H S H) d / n
                     = Fej_a(w) - 2 Re G~_a M^-1 (S G)~_a^H / n
                       + G~_a M^-1 (G' S G) M^-1 G~_a^H / n  =  F_a(w) k_a(w),

    ``Fej`` the Fejer mean of the model spectrum ``F_a``; all terms exact
    through Toeplitz products by FFT (`_model_keeps`). For white noise ``k =
    1 - L`` with ``L_aa(w) = G~_a M^-1 G~_a^H / n`` the leverage of frequency w
    (they sum to ``tr(M^-1 M) = p`` over the n Fourier frequencies). The
    whitened periodogram ``|1 - a e^{-iw}|^2 I_u`` then has expectation
    ``F_e k`` with ``F_e`` the whitened spectrum, flat where the model holds and
    slowly varying where it does not, so it is estimated by smoothing both and
    dividing, ``F_e^ = K*(|1 - a e^{-iw}|^2 I_u) / K*k`` (cross terms by the
    geometric mean of their outputs' factors), and recoloured, ``F^ = F_e^ /
    ((1 - a_a e^{-iw})(1 - a_b e^{iw}))``. Near w = 0 it borrows from
    neighbouring frequencies the fit left alone, with the model's shape rather
    than a flat one; with white residuals (``a = 0``) and the window the whole
    band it is exactly ``SSE / (N - p)``, the classical variance with its
    classical degrees of freedom. That is the whole degrees-of-freedom
    correction for the projection: each frequency loses the fraction of a
    degree of freedom the fit took from it, no more (no ``N_eff / (N_eff - p)``
    factor on top, which would count the loss twice).

    *The window* is the quadratic-spectral kernel's (Epanechnikov in
    frequency), its bandwidth half Andrews' (1991) AR(1) plug-in from the
    (unwhitened) residuals' lag-one correlations (see ``_NARROW``), widened
    until every smoothed ``K*k`` holds at least one bin's worth of data.
    Andrews & Monahan take the plug-in of the whitened series instead; here it
    widened the window 2-40x on SIDPAC's flights (their whitened residuals are
    far from white: AR(1) plus sensor noise is over-whitened) and the 95 %
    coverage of biases under AR(1) phi = 0.99 noise fell to 0.55-0.83, so the
    window stays as local as the colour of the residuals themselves asks.
    Sensitivities and residuals are transformed over 2n points, so the
    circular products are the record's linear sums.

    The spectrum is estimated from a finite band, so ``B^_jj`` is itself
    random: a weighted sum of the whitened periodogram's bins, smoothed by the
    window and recoloured, ``B^_jj = sum_l R_l . I_l`` with ``R_l`` the window's
    weights mapped back to bin l. Its Satterthwaite degrees of freedom are ``nu_j
    = 2 B_jj^2 / Var(B^_jj)``. Away from w = 0 each bin is taken as ``F chi2_2 /
    2`` and independent of the others, padded bins counted at half (two share one
    bin's information). In the low band -- the bins whose periodogram enters the
    estimate within the window of w = 0 (`_band_bins`, at most `_BAND_SIZE` bin
    and output pairs), where constants and slow sensitivities have their weight
    -- that is wrong: the 2n padding correlates neighbouring bins, and the fit's
    projection and the prewhitening leave them far from independent chi2_2 / 2
    (bin 0 of a fitted constant holds almost nothing), so independent bins
    overstate a bias's nu and understate its t quantile. There the variance is
    the exact one of a Gaussian quadratic form, ``Var Q = tr(A Gam A Gam) +
    tr(Rel^* A Rel A^T)`` (Isserlis), with ``Gam = E[w w^H]`` and ``Rel = E[w
    w^T]`` of the whitened transform under the fitted AR(1) model and the
    projection (`_band_moments`, exact as `_model_keeps` is), scaled from the
    model's level to the data's. Narrow windows (strong colour) give few
    degrees of freedom and a wide t interval; white residuals with a whole-band
    window give the classical N - p. Standard errors do not depend on it.

    *Estimated weights* (`estimated_weights`): feasible GLS widens this fixed-
    weight covariance where one output's noise is slow; `aeroid._weighting`
    measures by how much, and each variance is multiplied by that ratio.
    """
    p = m_inv.shape[0]
    cov = np.zeros((p, p))
    var_terms = np.zeros(p)
    n_y = residuals[0].shape[1] if residuals else 0
    a = _prewhitening(residuals) if _PREWHITEN and n_y else np.zeros(n_y)
    scale = _lag_scale(residuals)
    if known is not None and len(known) != len(residuals):
        raise ValueError("known: one expected periodogram per record")
    # the projection is taken over `span` with inner matrix `inner`; `to_params` maps a
    # transform over `span` to the parameters (G M^+ = span to_params)
    span, inner, to_params = sensitivities, m_inv, m_inv
    if rcond is not None and p and np.all(np.isfinite(m_inv)):
        span, to_params = information_basis(sensitivities, rcond)
        inner = np.eye(to_params.shape[0])
    model = _model_keeps(span, residuals, inner, a)
    if np.any(a != 0.0):
        # the fit took the noise's slowest part, so the residuals' lag-one correlation
        # under-reads the noise's: move a until the model's residuals have the one seen
        seen = _lag_one(residuals)
        cap = _cap(residuals)
        for _ in range(_AR_STEPS):
            a = np.clip(a + seen - _expected_lag_one(model.keeps, residuals, a), -cap, cap)
            model = _model_keeps(span, residuals, inner, a)
    spectra: list[NDArray[np.complex128]] = []
    for i, (g, u) in enumerate(zip(span, residuals, strict=True)):
        n = u.shape[0]
        size = 2 * n
        n_bins = size // 2 + 1
        gf, filt, twice = _bins(g, a, size)  # (n_bins, n_y, r), the filter, bin weights
        uf = np.fft.rfft(u, size, axis=0)  # (n_bins, n_y)
        vf = np.matmul(gf, to_params)  # sensitivities carried through M^-1
        keep = model.keeps[i]
        wf = uf * filt
        pgram = np.einsum("ka,kb->kab", wf, wf.conj()) / n
        # half-width in bins of 2 pi / size: 6 pi / (5 S) rad/sample
        half = n_bins if scale <= 0 else int(np.ceil(3.0 * size / (5.0 * np.pi * _NARROW * scale)))
        half = max(half, 1)
        while True:
            kept = np.asarray(_smooth(keep, half), dtype=np.float64)
            if half >= n_bins - 1 or np.min(kept) * (half + 1) >= 1.0:
                break  # every estimate rests on at least one bin's worth of data
            half *= 2
        norm = np.sqrt(np.maximum(kept, 1e-300))
        # recolour: the whitened estimate through the inverse filter on both sides
        denom = (norm * filt)[:, :, None] * (norm * filt).conj()[:, None, :]
        smoothed = np.asarray(_smooth(pgram, half), dtype=np.complex128)
        spec = total = smoothed / denom
        spectra.append(total)
        if known is not None:
            # unbiased bin by bin; negative where noise outweighs the remainder, so
            # only the summed covariance is made positive semi-definite (below)
            kf = filt[:, :, None] * np.asarray(known[i]) * filt.conj()[:, None, :]
            spec = total - np.asarray(_smooth(kf, half), dtype=np.complex128) / denom

        # per-bin contributions to the covariance (one-sided: inner bins count twice)
        cov += np.einsum("kap,kab,kbq->pq", vf.conj(), spec, vf * twice[:, None, None]).real
        # Satterthwaite: the diagonal's per-bin parts, each a smoothed mean of
        # periodogram bins of unit relative variance (relative to the whole
        # residual spectrum, a known part included), mapped back to those bins
        diag = np.einsum("kap,kab,kbp->kp", vf.conj(), total, vf).real * twice[:, None]
        spread = np.asarray(_smooth(diag, half), dtype=np.float64)
        bins = min(n_bins, _band_bins(half), max(_BAND_SIZE // max(n_y, 1), 2))
        rows = n_bins if bins + 2 * half + 1 >= n_bins else bins + half
        if rows > _BAND_ROWS:  # a window this wide spreads the band's share thin
            bins = 0
        var_terms += (size / n) * np.sum(spread[bins:] ** 2, axis=0)
        if bins:
            # the low band exactly: there the padded bins overlap and the fit's
            # projection couples them, so they are neither independent nor chi2_2 / 2
            z = (vf / (norm * filt).conj()[:, :, None])[:rows]
            z = z * np.sqrt(twice[:rows])[:, None, None]
            level = smoothed[:rows] / (norm[:rows, :, None] * norm[:rows, None, :])
            gam, rel = _band_moments(
                gf[:bins], model.sgf[i][:bins], n, a, model.level, inner, model.cov
            )
            weights = _window_columns(n_bins, half, rows, bins)
            root_keep = np.sqrt(keep[:bins])
            var_terms += _band_variance(z, weights, gam, rel, level, root_keep, n)
    cov = 0.5 * (cov + cov.T)
    var = np.abs(np.diag(cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        nu = np.where(var_terms > 0, 2.0 * var**2 / var_terms, np.inf)
    if estimated_weights:
        from ._weighting import weighting_spread

        root = np.sqrt(weighting_spread(sensitivities, spectra, m_inv))
        cov = cov * root[:, None] * root[None, :]  # correlations as at fixed weights
    return np.asarray(cov, dtype=np.float64), np.asarray(nu, dtype=np.float64)


def frequency_sandwich(
    jac: FloatArray,
    res: FloatArray,
    m_inv: FloatArray,
    omega: FloatArray,
    span: float,
    *,
    nyquist: float = np.inf,
    estimated_weights: tuple[str, NDArray[np.complex128]] | None = None,
    rcond: float | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The same ``M^-1 B M^-1`` for an estimator that works on chosen frequencies,
    and each parameter's degrees of freedom.

    Frequency-domain estimators fit Fourier transforms at chosen frequencies,
    where the transforms at distinct frequencies of the ``k/T`` grid are nearly
    independent however coloured the residuals are in time. ``B`` needs the
    noise's cross-spectrum at each chosen frequency, estimated from the
    residuals there, corrected for what the fit removed exactly as
    `colored_covariance` does (``E[u u'] = F (1 - L)`` with ``L`` that
    frequency's leverage, a matrix over its real-stacked rows, so ``u`` is
    scaled by ``(1 - L)^-1/2``), and smoothed over the neighbouring chosen
    frequencies with the house window (`_window`, half-width `_NEIGHBOURS`).

    Parameters
    ----------
    jac : (M, 2r, p) array
        Per frequency, the weighted sensitivities of r complex equations, stacked
        as their real parts, then their imaginary parts.
    res : (M, 2r) array
        Per frequency, the weighted residuals, stacked the same way.
    m_inv : (p, p) array
        The (pseudo-)inverse of ``M = sum J'J``.
    omega : (M,) array
        The frequencies, rad/s, in any order.
    span : float
        The record's length ``T``, s: frequencies closer than ``2 pi/T`` share
        their noise (`off_grid`).
    nyquist : float, optional
        The record's Nyquist frequency ``pi/dt``, rad/s, where a caller may fit
        it: the transform there is real, as at zero frequency.
    estimated_weights : (str, (r, r) complex array), optional
        The weighting was estimated from these residuals, as the inverse of this
        form of their covariance (``"hermitian"``, ``"sidpac"``, ``"real"``) before
        the whitening whose inverse is the array: the covariance carries the
        scatter that adds (`aeroid._weighting`).
    rcond : float, optional
        As `colored_covariance`'s: `m_inv` is the information's pseudo-inverse
        with this cut, and the sandwich is formed over an orthonormal basis.

    Returns
    -------
    cov, nu : the covariance (p, p) and per-parameter Satterthwaite degrees of
    freedom (p,) of its diagonal.

    Notes
    -----
    *The spectrum.* A transform away from zero and Nyquist frequency is
    circular complex Gaussian: its real and imaginary parts each carry half of
    the cross-spectrum ``S = E[e e^H]``, so ``B = sum_m 1/2 Re W_m^H S_m W_m``
    with ``W`` the complex sensitivities (a real transform, at either end,
    carries all of it and counts once). One frequency's residual outer product
    ``e e^H`` is an unbiased estimate of ``S`` with two degrees of freedom; a
    parameter whose information sits at the few frequencies of a lightly damped
    mode would rest on those few. The noise spectrum is smoother than the
    response the frequencies were chosen to resolve, so each frequency's ``S``
    is the window's mean over it and one neighbour either side in frequency
    order (weights 0.3, 0.4, 0.3; renormalised at the ends of the band). Over a
    flat stretch that is unbiased, and it triples the information behind each
    estimate; at a sharp peak of the noise it borrows from the flanks, with the
    weight the window gives them.

    *Off the grid* (frequencies closer than ``2 pi/T``, as SIDPAC's ``fdoe``
    examples choose them) neighbouring transforms share the noise: for noise
    whose spectrum is flat across a few bins ``E[e_j e_k^H] = kappa_jk S``,
    ``kappa_jk = e^{-i dw T/2} sinc(dw T/2)`` the finite record's kernel
    (``dw = omega_j - omega_k``; zero for distinct frequencies on the grid), so
    ``B`` gains the pairs ``1/2 Re W_j^H kappa_jk S_jk W_k`` with ``S_jk`` the
    mean of the two frequencies' estimates. There the fit also takes more of
    each residual than its own leverage says (fewer independent pieces of noise
    than rows), so the residuals are scaled by the diagonal blocks of ``(I - H)
    K (I - H)`` instead of ``I - L`` (`aeroid._record_kernel.kept_off_grid`),
    which they are on the grid.

    *Degrees of freedom.* Parameter j's variance estimate is a sum of Hermitian
    forms of the residuals, ``sum_k e_k^H A_k e_k`` with ``A_k = sum_m s_mk f_m
    c_m c_m^H`` (``c_m = W_m M^-1 e_j``, ``s`` the smoothing weights, ``f_m =
    1/2`` for a complex transform); a circular Gaussian form has mean ``tr(A
    S)`` and variance ``tr(A S A S)`` (twice that for a real one), and forms at
    frequencies off the grid covary by ``|kappa_jk|^2 tr(A_j S A_k S)``.
    Satterthwaite's ``nu_j = 2 mean^2 / Var`` is estimated with the smoothed
    ``S``, less the spread of the estimates themselves: ``E[S^ A S^] = S A S
    (1 + sum_k s_mk^2)`` for one output (``E|e|^4 = 2 S^2``; more outputs make
    it an upper bound, so fewer degrees of freedom) and ``E[mean^2] = mean^2 +
    Var``, hence ``nu = 2 mean^2 / Var - 2``. That is two per frequency, less
    two, where the information is spread evenly on the grid; ``2 / sum s^2 =
    5.9`` where one frequency carries it over a flat spectrum (two from that
    frequency alone); about twice as many as the record holds bins however
    finely frequencies are packed into it.
    """
    omega = np.asarray(omega, dtype=np.float64)
    n_f, rows, _ = jac.shape
    r = rows // 2
    order = np.argsort(omega, kind="stable")
    jac, res, omega = jac[order], res[order], omega[order]
    grid = off_grid(omega, span)
    # the projection over `basis` with inner matrix `inner`; jac M^+ = basis to_params
    basis, inner, to_params = jac, m_inv, m_inv
    if rcond is not None and m_inv.size and np.all(np.isfinite(m_inv)):
        (basis,), to_params = information_basis([jac], rcond)
        inner = np.eye(to_params.shape[0])
    if grid is None:
        lev = np.einsum("mrn,nk,msk->mrs", basis, inner, basis)
        kept = np.eye(rows)[None] - 0.5 * (lev + lev.transpose(0, 2, 1))
    else:
        kept = kept_off_grid(basis, inner, omega, span)
    w, v = np.linalg.eigh(kept)
    # a frequency that alone fixes an unknown (1 - L ~ 0) keeps its plain residual
    scale = np.where(w > 1e-9, 1.0 / np.sqrt(np.maximum(w, 1e-300)), 1.0)
    u = np.einsum("mrs,ms,mts,mt->mr", v, scale, v, res)
    W = basis[:, :r] + 1j * basis[:, r:]  # (M, r, k)
    e = u[:, :r] + 1j * u[:, r:]  # (M, r)
    # the transforms at zero and Nyquist frequency are real: all their noise is in
    # their real rows
    real = (omega == 0.0) | (omega >= nyquist * (1.0 - 1e-12))
    f = np.where(real, 1.0, 0.5)
    weights = _neighbour_weights(n_f)
    S = _neighbour_sum(e[:, :, None] * e.conj()[:, None, :], weights)  # (M, r, r)
    SW = S @ W  # (M, r, p)
    meat = (
        (f[:, None, None] * W.conj()).reshape(-1, W.shape[2]).T @ SW.reshape(-1, W.shape[2])
    ).real
    cT = np.einsum("mrp,pq->mqr", W, to_params)  # c_m = W_m M^-1 e_q, (M, p, r)
    fcc = f[:, None, None, None] * cT[..., :, None] * cT.conj()[..., None, :]  # (M, p, r, r)
    A = _neighbour_sum(fcc, weights, adjoint=True)
    AS = A @ S[:, None]  # A_k S_k per parameter, (M, p, r, r)
    mean = np.einsum("mqrr->q", AS).real
    # the smoothed estimate's own spread inflates tr(ASAS) by 1 + sum s^2 (exactly for
    # one output, in excess for more: fewer degrees of freedom, the cautious side)
    inflation = (1.0 + np.sum(weights**2, axis=1)) / np.where(real, 2.0, 1.0)
    var = (AS * AS.swapaxes(-1, -2)).sum(axis=(-1, -2)).real / inflation[:, None]
    var = var.sum(axis=0)
    if grid is not None:
        shared, pairs = overlap_terms(W, S, AS, omega, span)
        meat = meat + shared
        var = var + pairs
    meat = 0.5 * (meat + meat.T)
    cov = np.asarray(to_params.T @ meat @ to_params, dtype=np.float64)
    if estimated_weights is not None:
        from ._weighting import KERNEL_ROOT_LIMIT, frequency_weighting_spread

        # the whole kernel (M x M) only where its square root is affordable
        near = grid is not None and n_f <= KERNEL_ROOT_LIMIT
        kappa = record_kernel(omega, slice(None), span) + np.eye(n_f) if near else None
        form, unwhiten = estimated_weights
        spread = frequency_weighting_spread(
            jac[:, :r] + 1j * jac[:, r:], S, m_inv, real, form, unwhiten=unwhiten, kernel=kappa
        )
        cov = cov * np.sqrt(spread)[:, None] * np.sqrt(spread)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        nu = np.where(var > 0, 2.0 * mean**2 / var - 2.0, np.inf)
    return cov, np.asarray(np.maximum(nu, 1.0), dtype=np.float64)


def _neighbour_weights(n: int) -> FloatArray:
    """(n, 2h + 1): frequency m's weights on its neighbours m - h .. m + h (the house
    window, half-width `_NEIGHBOURS`), zero beyond the band and renormalised to one."""
    h = min(_NEIGHBOURS, max(n - 1, 0))
    base = _window(h)
    idx = np.arange(n)[:, None] + np.arange(-h, h + 1)[None, :]
    wts = np.where((idx >= 0) & (idx < n), base[None, :], 0.0)
    return np.asarray(wts / wts.sum(axis=1, keepdims=True), dtype=np.float64)


def _neighbour_sum(
    x: NDArray[np.complex128], weights: FloatArray, *, adjoint: bool = False
) -> NDArray[np.complex128]:
    """``y_m = sum_d s_m,d x_{m+d}`` along axis 0 (`_neighbour_weights`), or with
    `adjoint` its transpose, ``y_k = sum_m s_m,k-m x_m``."""
    h = (weights.shape[1] - 1) // 2
    n = x.shape[0]
    out = np.zeros_like(x)
    shape = (-1,) + (1,) * (x.ndim - 1)
    for j, d in enumerate(range(-h, h + 1)):
        lo, hi = max(0, -d), min(n, n - d)
        w = weights[lo:hi, j].reshape(shape)
        if adjoint:
            out[lo + d : hi + d] += w * x[lo:hi]
        else:
            out[lo:hi] += w * x[lo + d : hi + d]
    return out
