"""The scatter that estimating the output weighting from the residuals adds.

`colored_covariance` and `frequency_sandwich` give an estimate's covariance
``M^-1 B M^-1`` at fixed weights. Output error weights the outputs by the
inverse of their residuals' own covariance (maximum likelihood; in the time
domain each output by its mean square, in the frequency domain by the full
cross-covariance of the transforms), which is feasible GLS: the weights move
with the noise. To first order that adds nothing (Kackar & Harville, 1984:
with white noise the residuals, hence the weights, are independent of the
estimate), but coloured noise ties them together: a record whose slow noise
lies along a slow sensitivity loses it to the fit, that output's residual
mean square falls, its weight rises, and the estimate leans on the very
output that misled it. Where an output's noise has few degrees of freedom
this is not small: on SIDPAC's oe_lat flight it multiplies a side-force
derivative's spread by 1.6, as refits of the flight's own residuals also
show.

Both front ends (`weighting_spread` for time histories,
`frequency_weighting_spread` for chosen frequencies) measure it the same way,
on the estimator linearised at the estimate, in the weighted units the
caller's ``M`` has (the weighting there is the identity). With ``G_k`` (n_y,
p) the complex sensitivities at sample or frequency k and ``e_k`` the noise,

    theta(W) = (Re sum_ab W_ab T_ab)^-1 Re sum_ab W_ab c_ab,
    T_ab = sum_k conj(G_ka) G_kb',  c_ab = sum_k conj(G_ka) e_kb,

and the weighting at its fixed point ``W = form(S^(theta))^-1``, with ``S^ =
(1/K) sum_k r_k r_k^H`` of the residuals ``r_k = e_k - G_k theta``, expanded
in ``E_ab = sum_k e_ka conj(e_kb)``, ``c`` and ``T``: only these few sums of
each draw enter, however long the record. Gaussian noise with the estimated
spectrum is drawn `_DRAWS` times with a fixed seed (the same data give the
same bars); the estimates at the identity and at the fixed point see the same
draws, so the ratio of their spreads is far steadier than either spread, and
the caller multiplies each variance by it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
# b draws' sums: c_ab (b, n_y, n_y, r) and E_ab (b, n_y, n_y)
Draw = Callable[[np.random.Generator, int], tuple[ComplexArray, ComplexArray]]

# Gaussian records per spread, drawn in batches: at least `_MIN_DRAWS`, then more
# until every ratio's relative standard error is below `_RATIO_ERROR` (the ratio of
# two spreads over the same draws is far steadier than either), at most `_DRAWS`.
_DRAWS = 400
_MIN_DRAWS = 100
_DRAW_BATCH = 50
# Most elements of one batch's (draws, 2n, n_y) arrays: records longer than this holds
# at `_DRAW_BATCH` draws are drawn in smaller batches (the same statistics, less memory)
_DRAW_ELEMENTS = 1 << 24
_RATIO_ERROR = 0.02
# The weighting's fixed point is iterated until no weight moves by more than this
# relative step (a ratio of spreads needs no more).
_TOL = 1e-6
# Callers pass the kernel of at most this many frequencies off the k/T grid (its
# square root is cubic in their number); beyond, the draws take them as independent.
KERNEL_ROOT_LIMIT = 1500
# What the fitted weighting is of the residual covariance S^ (its inverse weights).
FORMS = ("diagonal", "hermitian", "sidpac", "real")


def _spectral_roots(spec: ComplexArray) -> ComplexArray:
    """A square root ``L L^H = F`` of each bin's cross-spectrum (positive semi-definite)."""
    scale = np.maximum(np.einsum("kaa->k", spec).real, 1e-300)
    eye = np.eye(spec.shape[1])
    try:
        return np.linalg.cholesky(spec + 1e-12 * scale[:, None, None] * eye)
    except np.linalg.LinAlgError:  # rank-deficient to rounding: clip the eigenvalues
        lam, vec = np.linalg.eigh(spec)
        return vec * np.sqrt(np.clip(lam, 0.0, None))[:, None, :]


def _canonical(leverage: FloatArray) -> NDArray[np.intp]:
    """An order of the outputs fixed by their own data, not by their place: each
    output's share of the fit's leverage, which neither their place, their units nor
    the parameters' change. The draws follow it, so the same noise goes to the same
    output however the outputs and parameters are written, and so do the bars."""
    return np.argsort(np.round(leverage, 9), kind="stable")


def _basis(m_inv: FloatArray) -> FloatArray:
    """The estimable subspace: every weighting with positive weights has the same one
    (none where the inverse failed)."""
    if not np.all(np.isfinite(m_inv)):
        return np.zeros((m_inv.shape[0], 0))
    lam, vec = np.linalg.eigh(m_inv)
    if not lam.size or lam.max() <= 0:
        return np.asarray(vec[:, :0], dtype=np.float64)
    return np.asarray(vec[:, lam > lam.max() * 1e-13], dtype=np.float64)


def weighting_spread(
    sensitivities: list[FloatArray],
    spectra: list[ComplexArray],
    m_inv: FloatArray,
    *,
    draws: int = _DRAWS,
    seed: int = 0,
    tol: float = _RATIO_ERROR,
) -> FloatArray:
    """Time histories, each output weighted by its own residual mean square: each
    parameter's variance with the weights re-estimated over its variance at fixed
    weights.

    `sensitivities` (n, n_y, p) and `spectra` ((n + 1, n_y, n_y), on the ``2 n``
    bins of `colored_covariance`) per record; the weights are pooled over the
    records, as output error's are. Each draw is the first ``n`` samples of a
    ``2n``-point circular record, as the spectrum's bins are, so its
    autocovariance is the spectrum's at every lag of the record (``n`` points
    alone would wrap the slowest noise around). Parameters outside the span of
    ``M`` (held or unidentifiable) get a ratio of one.
    """
    p = m_inv.shape[0]
    n_y = sensitivities[0].shape[1]
    basis = _basis(m_inv)
    r = basis.shape[1]
    if r == 0 or not all(np.all(np.isfinite(spec)) for spec in spectra):
        return np.ones(p)
    order = _canonical(sum(np.einsum("tap,pq,taq->a", g, m_inv, g) for g in sensitivities))
    sensitivities = [g[:, order] for g in sensitivities]
    spectra = [
        spec[:, order][:, :, order] for spec in spectra
    ]  # nothing to draw from: the bars at fixed weights
    if _apart(sum(np.einsum("tap,tap->ap", g, g) for g in sensitivities)):
        return np.ones(p)
    info = np.zeros((n_y, n_y, r, r), dtype=np.complex128)
    diag = np.arange(n_y)
    records = []
    for g, spec in zip(sensitivities, spectra, strict=True):
        gb = np.ascontiguousarray(np.moveaxis(g @ basis, 1, 0))  # (n_y, n, r)
        info[diag, diag] += np.matmul(np.swapaxes(gb, 1, 2), gb)
        records.append((gb, np.sqrt(2 * g.shape[0]) * _spectral_roots(spec)))

    def draw(rng: np.random.Generator, b: int) -> tuple[ComplexArray, ComplexArray]:
        cross = np.zeros((b, n_y, n_y, r), dtype=np.complex128)
        squares = np.zeros((b, n_y, n_y), dtype=np.complex128)
        for gb, root in records:
            n, n_bins = gb.shape[1], root.shape[0]
            z = _complex_normal(rng, (b, n_bins, n_y))
            z[:, 0] = rng.standard_normal((b, n_y))
            z[:, -1] = rng.standard_normal((b, n_y))
            x = np.matmul(root, z[..., None])[..., 0]  # (b, bins, n_y)
            e = np.fft.irfft(x, 2 * n, axis=1)[:, :n, :]
            e_t = np.ascontiguousarray(np.moveaxis(e, 2, 0))  # (n_y, b, n)
            cross[:, diag, diag] += np.moveaxis(np.matmul(e_t, gb), 0, 1)
            squares[:, diag, diag] += np.einsum("abt,abt->ba", e_t, e_t)
        return cross, squares

    count = sum(g.shape[0] for g in sensitivities)
    # a long record's draws in smaller batches: a batch's arrays are (draws, 2n, n_y)
    longest = max(2 * g.shape[0] * n_y for g in sensitivities)
    batch = int(np.clip(_DRAW_ELEMENTS // longest, 1, _DRAW_BATCH))
    return _spread(
        basis, info, count, "diagonal", p, draw, draws=draws, seed=seed, tol=tol, batch=batch
    )


def frequency_weighting_spread(
    sensitivities: ComplexArray,
    spectrum: ComplexArray,
    m_inv: FloatArray,
    real: NDArray[np.bool_],
    form: str,
    *,
    unwhiten: ComplexArray | None = None,
    kernel: ComplexArray | None = None,
    draws: int = _DRAWS,
    seed: int = 0,
    tol: float = _RATIO_ERROR,
) -> FloatArray:
    """Chosen frequencies, the outputs weighted by the inverse of `form` of their
    transforms' residual covariance: each parameter's variance with the weighting
    re-estimated over its variance at the fitted one.

    `sensitivities` (M, n_y, p) complex and `spectrum` (M, n_y, n_y) per frequency
    (``E[e e^H]``), in the weighted units; `real` marks the frequencies whose
    transform is real (zero and Nyquist). `unwhiten` (n_y, n_y) is ``L`` of the
    weighted residuals ``u = L^-1 v``: `form` applies to the covariance of ``v``
    (``"sidpac"`` and ``"real"`` do not commute with a complex ``L``), and the
    weighting of ``u`` is ``L^H form(L S^_u L^H)^-1 L``. `kernel` (M, M), when
    the frequencies are off the ``k/T`` grid, is the white-noise transforms'
    correlation
    ``kappa`` (`aeroid._colour`): draw j is then ``L_j sum_k (kappa^1/2)_jk
    z_k``, so neighbouring transforms share their noise as the sandwich has
    them do (without it, independent: see `KERNEL_ROOT_LIMIT`). Parameters
    outside the span of ``M`` get a ratio of one.
    """
    if form not in FORMS:
        raise ValueError(f"form: expected one of {FORMS}, got {form!r}")
    p = m_inv.shape[0]
    m, n_y, _ = sensitivities.shape
    basis = _basis(m_inv)
    r = basis.shape[1]
    if r == 0 or not np.all(np.isfinite(spectrum)):
        return np.ones(p)
    if _apart(np.einsum("kap,kap->ap", sensitivities.conj(), sensitivities).real):
        return np.ones(p)
    order = _canonical(np.einsum("kap,pq,kaq->a", sensitivities.conj(), m_inv, sensitivities).real)
    sensitivities, spectrum = sensitivities[:, order], spectrum[:, order][:, :, order]
    if unwhiten is not None:
        unwhiten = unwhiten[np.ix_(order, order)]
    g = sensitivities @ basis  # (M, n_y, r)
    info = np.einsum("kap,kbq->abpq", g.conj(), g)
    root = _spectral_roots(spectrum)
    mix = None
    if kernel is not None:
        lam, vec = np.linalg.eigh(kernel)
        mix = (vec * np.sqrt(np.clip(lam, 0.0, None))) @ vec.conj().T

    def draw(rng: np.random.Generator, b: int) -> tuple[ComplexArray, ComplexArray]:
        z = _complex_normal(rng, (b, m, n_y))
        if mix is not None:
            z = np.einsum("jk,dka->dja", mix, z)
        e = np.matmul(root, z[..., None])[..., 0]  # (b, M, n_y)
        # a real transform carries all of its spectrum in its real part
        e[:, real] = np.sqrt(2.0) * e[:, real].real
        cross = np.einsum("kap,dkb->dabp", g.conj(), e)
        return cross, np.einsum("dka,dkb->dab", e, e.conj())

    return _spread(
        basis, info, m, form, p, draw, unwhiten=unwhiten, draws=draws, seed=seed, tol=tol
    )


def _apart(seen: FloatArray) -> bool:
    """Whether no parameter is seen by two outputs (`seen` (n_y, p): each output's
    sum of squared sensitivities): then each output's parameters are fitted by it
    alone, its weight only scales their information, and re-estimating the
    weights changes no estimate."""
    live = seen > 1e-12 * np.max(seen, initial=0.0)
    return bool(np.all(np.sum(live, axis=0) <= 1))


def _complex_normal(rng: np.random.Generator, shape: tuple[int, ...]) -> ComplexArray:
    """Circular complex Gaussian draws with ``E|z|^2 = 1``."""
    z = rng.standard_normal((*shape, 2)).view(np.complex128)[..., 0]
    return np.asarray(z * np.sqrt(0.5), dtype=np.complex128)


def _spread(
    basis: FloatArray,
    info: ComplexArray,
    count: int,
    form: str,
    p: int,
    draw: Draw,
    *,
    unwhiten: ComplexArray | None = None,
    draws: int = _DRAWS,
    seed: int = 0,
    tol: float = _RATIO_ERROR,
    batch: int = _DRAW_BATCH,
) -> FloatArray:
    """Per parameter, the spread at the weighting's fixed point over that at the
    identity, over batches of `draw` (`batch` draws each) until its relative standard
    error is below `tol` (after `_MIN_DRAWS`) or `draws` are spent."""
    rng = np.random.default_rng(seed)
    fixed: list[FloatArray] = []
    free: list[FloatArray] = []
    ratio = np.ones(p)
    done = 0
    while done < draws:
        b = min(batch, draws - done)
        cross, squares = draw(rng, b)
        if not np.all(np.abs(np.einsum("daa->da", squares)) > 0):
            return np.ones(p)  # an output without noise: nothing to weigh
        try:
            held, refit = _estimates(info, cross, squares, count, form, unwhiten)
        except np.linalg.LinAlgError:  # a weighting that loses the span: keep the fixed bars
            return np.ones(p)
        fixed.append(held @ basis.T)
        free.append(refit @ basis.T)
        done += b
        if done >= min(_MIN_DRAWS, draws):
            ratio, error = _ratio(np.concatenate(fixed), np.concatenate(free))
            if np.all(error <= tol * ratio):
                break
    return ratio


def _ratio(fixed: FloatArray, free: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each column's variance ratio, free over fixed, and its standard error (the
    delta method for a ratio of two means of squares over the same draws); one
    where a column does not vary."""
    a = (free - free.mean(axis=0)) ** 2
    b = (fixed - fixed.mean(axis=0)) ** 2
    mean_b = b.mean(axis=0)
    live = mean_b > 1e-300 * np.maximum(a.mean(axis=0), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(live, a.mean(axis=0) / mean_b, 1.0)
        error = np.where(live, np.std(a - ratio * b, axis=0) / (np.sqrt(a.shape[0]) * mean_b), 0.0)
    ok = np.isfinite(ratio)
    return np.where(ok, ratio, 1.0), np.where(ok, error, 0.0)


def _estimates(
    info: ComplexArray,
    cross: ComplexArray,
    squares: ComplexArray,
    count: int,
    form: str,
    unwhiten: ComplexArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Per draw, the estimate at the identity weighting and at its fixed point."""
    n_y = info.shape[0]
    eye = np.eye(n_y)
    fixed = np.linalg.solve(np.einsum("aapq->pq", info).real, np.einsum("daap->pd", cross).real).T
    theta = fixed
    weights = np.broadcast_to(eye, (theta.shape[0], n_y, n_y))
    r = info.shape[2]
    flat_info = info.reshape(n_y * n_y, r * r)
    conj_rows = info.conj().reshape(n_y * n_y * r, r)
    for _step in range(50):
        # S^_ab = (E_ab - theta' conj(c_ab) - theta' c_ba + theta' conj(T_ab) theta) / K
        lin = (cross * theta[:, None, None, :]).sum(axis=-1)
        tq = (conj_rows @ theta.T).reshape(n_y, n_y, r, -1)  # conj(T_ab) theta per draw
        quad = np.einsum("abpd,dp->dab", tq, theta)
        s_hat = (squares - lin.conj() - lin.swapaxes(1, 2) + quad) / count
        if form == "diagonal":
            new = eye / np.einsum("daa->da", s_hat).real[:, :, None]
        else:
            big = s_hat if unwhiten is None else unwhiten @ s_hat @ unwhiten.conj().T
            if form == "sidpac":
                big = big.conj()
            elif form == "real":
                big = big.real.astype(np.complex128)
            new = np.linalg.inv(big)
            if unwhiten is not None:
                new = unwhiten.conj().T @ new @ unwhiten
        mw = (new.reshape(-1, n_y * n_y) @ flat_info).real.reshape(-1, r, r)
        rhs = (new[..., None] * cross).sum(axis=(1, 2)).real
        theta = np.linalg.solve(mw, rhs[..., None])[..., 0]
        done = np.max(np.abs(new - weights)) < _TOL * np.max(np.abs(new))
        weights = new
        if done:
            break
    return np.asarray(fixed, dtype=np.float64), np.asarray(theta, dtype=np.float64)
