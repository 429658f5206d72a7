"""The residual noise model behind output error's drift warning: each output's
residual as an AR(1) disturbance plus white sensor noise, fitted by restricted
maximum likelihood, and the exact sandwich covariance it implies.

The library's coloured error bars come from `aeroid._colour`; this model serves
the drift warning (a correlation time beyond the record is a wandering offset
the fit does not absorb) and ``equation_error(error_bars="reml")``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ResidualDriftWarning

FloatArray = NDArray[np.float64]

# The AR(1) coefficient is kept inside the unit circle only by numerical resolution:
# a residual indistinguishable from a random walk gets enormous, not capped, error bars.
_PHI_LIMIT = 1.0 - 1e-6
# Search range of log(white variance / AR innovation variance) in the noise model.
_LOG_RATIO = (-14.0, 10.0)
# Initial Nelder–Mead simplex around a start, in (atanh phi, log ratio).
_SIMPLEX = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 2.0]])


def _bandwidth(v: FloatArray) -> tuple[int, float]:
    """Lag window and correlation time of residuals `v` (n_t, n_y).

    The correlation time is the largest AR(1) value ``(1 + rho)/(1 - rho)`` over
    the outputs whose lag-one autocorrelation is significant (above 3/sqrt(N));
    1 when none is, which `fit_output_error` reads as white residuals. The
    window is Andrews' (1991) AR(1) plug-in bandwidth for the Bartlett kernel,
    ``1.1447 (alpha N)^(1/3)`` with ``alpha = mean 4 rho^2 / (1 - rho^2)^2`` over
    the standardised outputs.
    """
    n = v.shape[0]
    c0 = np.einsum("tk,tk->k", v, v)
    c1 = np.einsum("tk,tk->k", v[:-1], v[1:])
    live = c0 > 0
    if n < 3 or not np.any(live):
        return 0, 1.0
    rho = np.clip(c1[live] / c0[live], -_PHI_LIMIT, _PHI_LIMIT)
    significant = rho > 3.0 / np.sqrt(n)
    tau = float(np.max((1.0 + rho) / (1.0 - rho), initial=1.0, where=significant))
    alpha = float(np.mean(4.0 * rho**2 / (1.0 - rho**2) ** 2))
    lags = int(np.floor(1.1447 * (alpha * n) ** (1.0 / 3.0)))
    return min(lags, n - 1), tau


def _ar1_criterion(
    b: float,
    s_mom: FloatArray,
    d_mom: FloatArray,
    e_mom: FloatArray,
    dof: int,
    n_man: int,
    rank: int,
) -> float:
    """REML criterion of a pure AR(1) at ``phi = tanh(b)`` from moments (see `_noise_model`)."""
    p = float(np.tanh(b))
    mat = (1.0 - p) ** 2 * s_mom + p * d_mom + p * (1.0 - p) * e_mom
    try:
        chol = np.linalg.cholesky(mat)
    except np.linalg.LinAlgError:
        return float(np.inf)
    diag = np.diag(chol)
    rss = max(float(diag[-1]) ** 2, 1e-300)
    return float(dof * np.log(rss) - n_man * np.log1p(-p * p) + 2.0 * np.sum(np.log(diag[:rank])))


# Chebyshev nodes per spectral bin, and the ratio of a bin's distance from the nearer
# end of the spectrum [0, 4] at its far and near sides (see `_arw_prepare`).
_CHEB = 17
_BIN_RATIO = 2.0
_CHUNK = 1024


@dataclass
class _Spectral:
    """One manoeuvre's REML design ``Z`` in the eigenbasis of the AR(1) precision."""

    n: int
    nodes: FloatArray  # (n_nodes,) eigenvalues of the Neumann Laplacian
    table: FloatArray  # (n_nodes, n_tri + 2 q + 4 + 1) interpolated moments
    z_ends: FloatArray  # (2, q): the first and last rows of Z
    q: int
    upper: tuple[NDArray[np.intp], NDArray[np.intp]]  # np.triu_indices(q)


def _arw_prepare(z: FloatArray) -> _Spectral:
    """Moments of ``z`` (n, q) that give ``Z' (S + ratio I)^-1 Z`` for every AR(1) +
    white noise model in O(q^2) work per model, independent of n.

    The AR(1) precision (unit innovations) is ``L'L = (1 - phi)^2 I + phi D +
    phi (1 - phi) E`` with D the Neumann Laplacian (the negative second
    difference inside, first differences at the ends), which the orthonormal
    DCT-II diagonalises exactly (eigenvalues ``lam_j = 4 sin^2(pi j / 2n)``),
    and E the two end samples (rank 2, handled by Woodbury). Every quantity
    the criterion needs is then a sum over j of a rational function of lam_j
    (or its logarithm) times fixed per-j terms (``zh_j zh_j'``, ``zh_j f_j'``,
    ``f_j f_j'``, 1; zh the transformed Z, f the transformed end vectors). Those
    functions have their only singularity off [0, 4] (at lam < 0 for phi > 0,
    lam > 4 for phi < 0); on bins whose distance from the nearer end of [0, 4]
    grows by at most a factor 2 across the bin, polynomial interpolation at 17
    Chebyshev points converges to rounding (the pole is at least 3 half-widths
    from the bin's centre), so each bin's sum is that of its interpolant,
    ``sum_m w(x_m) [sum_j l_m(lam_j) a_j]`` with the bracket precomputed.
    Bins with no more samples than nodes keep their samples.
    """
    from .._searches import dct2

    n, q = z.shape
    # transformed along rows of z', so that every per-sample product below is a
    # contiguous run of samples
    zh = dct2(z.T)  # (q, n)
    unit = np.zeros((2, n))
    unit[0, 0] = 1.0
    unit[1, -1] = 1.0
    fh = dct2(unit)
    lam = 4.0 * np.sin(0.5 * np.pi * np.arange(n) / n) ** 2
    iu, ju = np.triu_indices(q)
    n_tri = iu.size
    width = n_tri + 2 * q + 5
    scratch = np.empty((width, min(n, _CHUNK)))

    def rows(first: int, stop: int) -> FloatArray:
        """The per-j terms of samples first..stop-1, as (samples, terms), in `scratch`
        (the whole table would hold q^2/2 numbers per sample, and fresh memory that
        size costs page faults)."""
        m = stop - first
        a, f = zh[:, first:stop], fh[:, first:stop]
        out = scratch[:, :m]
        col = 0
        for i in range(q):  # the triangle in np.triu_indices order, row by row
            np.multiply(a[i], a[i:], out=out[col : col + q - i])
            col += q - i
        for i in range(q):
            np.multiply(a[i], f, out=out[col : col + 2])
            col += 2
        for i in range(2):
            np.multiply(f[i], f, out=out[col : col + 2])
            col += 2
        out[-1] = 1.0
        return out.T

    dist = np.minimum(lam, 4.0 - lam)
    side = lam > 2.0
    with np.errstate(divide="ignore"):
        level = np.where(dist > 0, np.floor(np.log(2.0 / dist) / np.log(_BIN_RATIO)), -1.0)
    key = np.where(dist > 0, 2.0 * level + side, -1.0)
    nodes: list[FloatArray] = []
    table: list[FloatArray] = []
    k = np.arange(_CHEB)
    cheb = np.cos((2 * k + 1) * np.pi / (2 * _CHEB))
    bary = (-1.0) ** k * np.sin((2 * k + 1) * np.pi / (2 * _CHEB))
    # lam increases with j, so every bin is a run of consecutive j
    cuts = np.flatnonzero(np.diff(key)) + 1
    for first, stop in zip([0, *cuts.tolist()], [*cuts.tolist(), n], strict=True):
        if stop - first <= _CHEB:
            nodes.append(lam[first:stop])
            table.append(rows(first, stop).copy())
            continue
        lo, hi = float(lam[first]), float(lam[stop - 1])
        x = 0.5 * (lo + hi) + 0.5 * (hi - lo) * cheb
        acc = np.zeros((_CHEB, width))
        for c0 in range(first, stop, _CHUNK):
            c1 = min(c0 + _CHUNK, stop)
            diff = lam[c0:c1, None] - x[None, :]
            exact = diff == 0.0
            diff[exact] = 1.0
            basis = bary / diff
            hit = np.any(exact, axis=1)
            basis[hit] = exact[hit].astype(np.float64)  # a sample on a node takes its value
            basis /= basis.sum(axis=1, keepdims=True)
            acc += basis.T @ rows(c0, c1)
        nodes.append(x)
        table.append(acc)
    return _Spectral(
        n=n,
        nodes=np.concatenate(nodes),
        table=np.concatenate(table, axis=0),
        z_ends=np.ascontiguousarray(z[[0, -1]]),
        q=q,
        upper=(iu, ju),
    )


def _arw_criterion(x: FloatArray, zs: list[_Spectral], dof: int, rank: int) -> tuple[float, float]:
    """REML criterion of AR(1) + white noise at ``(atanh phi, log ratio)`` and the
    generalised-least-squares residual sum (innovation-variance units); `zs`
    from `_arw_prepare`, one per manoeuvre.

    ``Z'(S + ratio I)^-1 Z = Z'(I + ratio L'L)^-1 L'L Z`` with ``S^-1 = L'L``;
    in the DCT basis of `_arw_prepare`, with ``c = (1 - phi)^2 + phi lam``,
    ``b = 1 + ratio c``, ``g = phi (1 - phi)`` and ``K = I + ratio g F'B^-1 F``
    (2 x 2), Woodbury gives ``Zh'(c/b)Zh + (Zh'F/b) K^-1 (g F'Z - ratio g
    F'(c/b)Zh)`` and ``log det(I + ratio L'L) = sum log b + log det K``.
    """
    b_max = float(np.arctanh(_PHI_LIMIT))
    phi = float(np.tanh(np.clip(x[0], -b_max, b_max)))
    ratio = float(np.exp(np.clip(x[1], *_LOG_RATIO)))
    q = zs[0].q
    iu, ju = zs[0].upper
    n_tri = iu.size
    g = phi * (1.0 - phi)
    mat = np.zeros((q, q))
    logdet = 0.0
    for sp in zs:
        weights = np.empty((3, sp.nodes.size))
        c = np.multiply(sp.nodes, phi, out=weights[0])
        c += (1.0 - phi) ** 2
        bb = np.multiply(c, ratio, out=weights[2])
        bb += 1.0
        if not bb.min() > 0:
            return float(np.inf), 0.0
        np.divide(1.0, bb, out=weights[1])
        c *= weights[1]  # c / b
        np.log(bb, out=bb)
        sums = weights @ sp.table  # (3, columns)
        tri = sums[0, :n_tri]
        s1 = np.empty((q, q))
        s1[iu, ju] = tri
        s1[ju, iu] = tri
        x_cb = sums[0, n_tri : n_tri + 2 * q].reshape(q, 2)
        x_b = sums[1, n_tri : n_tri + 2 * q].reshape(q, 2)
        f00, f01, f10, f11 = (ratio * g * sums[1, n_tri + 2 * q : n_tri + 2 * q + 4]).tolist()
        # K = I + ratio g F'B^-1 F (2 x 2), positive definite with B
        k00, k01, k10, k11 = 1.0 + f00, f01, f10, 1.0 + f11
        det_k = k00 * k11 - k01 * k10
        if not det_k > 0:
            return float(np.inf), 0.0
        rhs = g * sp.z_ends - ratio * g * x_cb.T  # (2, q)
        corr = np.empty_like(rhs)
        corr[0] = (k11 * rhs[0] - k01 * rhs[1]) / det_k
        corr[1] = (k00 * rhs[1] - k10 * rhs[0]) / det_k
        mat += s1 + x_b @ corr
        logdet += float(sums[2, -1]) + float(np.log(det_k)) - float(np.log1p(-phi * phi))
    try:
        chol = np.linalg.cholesky(0.5 * (mat + mat.T))
    except np.linalg.LinAlgError:
        return float(np.inf), 0.0
    diag_c = np.diag(chol)
    rss = max(float(diag_c[-1]) ** 2, 1e-300)
    return float(dof * np.log(rss) + logdet + 2.0 * np.sum(np.log(diag_c[:rank]))), rss


def _noise_model(
    jacobians: list[FloatArray], residuals: list[FloatArray]
) -> tuple[FloatArray, FloatArray, FloatArray, list[tuple[FloatArray, FloatArray, FloatArray]]]:
    """Per-output noise model ``e = s + w``: s an AR(1) (coefficient phi,
    innovation variance qa), w white (variance qw), fitted by restricted ML.

    For output k the residual is ``v_k = e_k - X_k d`` whatever the joint fit
    did, with ``X_k`` the output's sensitivity columns, so the error contrasts
    orthogonal to span(X_k) have a likelihood that depends on the noise alone
    (REML): the part of the noise the fit absorbed is accounted for exactly,
    where the sample autocorrelation of the residuals is biased low by
    O(tau/N) of ``1 - phi`` (Cheang & Reinsel 2000 on REML for AR errors).
    ``-2 log L_R = (N - r) log RSS + log det S + log det X'S^-1 X`` with the
    variance profiled out and RSS the generalised-least-squares residual sum.
    The white part matters: sensor noise under a slow disturbance makes a
    pure AR(1) fit trade the low-frequency shape for the high-frequency floor
    and underestimate the correlation time severalfold. A pure AR(1) fit from
    moments (``Z'L'LZ = (1 - phi)^2 S + phi D + phi (1 - phi) E`` of
    ``Z = [X, v]``, D and E the moments of the differences and of the end
    samples) starts a Nelder–Mead search over (atanh phi, log qw/qa).
    Manoeuvres share the model.

    Also returns, per output, the estimated covariance of (atanh phi, log
    qw/qa) from the curvature of the REML criterion, the two steps used, and
    the noise model (phi, qa, qw) at those steps either side of the estimate:
    what `_colored_covariance` needs to carry the noise model's own
    uncertainty into the error bars.
    """
    from .._searches import bounded_minimum, nelder_mead

    n_y = residuals[0].shape[1]
    n_tot = sum(v.shape[0] for v in residuals)
    n_man = len(residuals)
    b_max = float(np.arctanh(_PHI_LIMIT))
    phi = np.zeros(n_y)
    qa = np.zeros(n_y)
    qw = np.zeros(n_y)
    spread: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    for k in range(n_y):
        spread.append((np.zeros((2, 2)), np.ones(2), np.zeros((4, 3))))
        gram = sum(jac[:, k, :].T @ jac[:, k, :] for jac in jacobians)
        evals, evecs = np.linalg.eigh(gram)
        # (no columns where every estimate sits on a bound: rank 0)
        keep = evals > 1e-10 * max(float(evals[-1]) if evals.size else 0.0, 0.0)
        # an orthonormal basis of span(X_k): the same REML, well conditioned
        basis = evecs[:, keep] / np.sqrt(evals[keep])
        rank = basis.shape[1]
        vv = sum(float(v[:, k] @ v[:, k]) for v in residuals)
        if vv <= 0.0 or n_tot - rank < 3 or min(v.shape[0] for v in residuals) < 3:
            qa[k] = vv / max(n_tot - rank, 1)
            continue
        size = rank + 1
        zs: list[_Spectral] = []
        s_mom = np.zeros((size, size))
        d_mom = np.zeros((size, size))
        e_mom = np.zeros((size, size))
        for jac, v in zip(jacobians, residuals, strict=True):
            z = np.empty((v.shape[0], size))
            z[:, :rank] = jac[:, k, :] @ basis
            z[:, rank] = v[:, k] / np.sqrt(vv)
            zs.append(_arw_prepare(z))
            dz = np.diff(z, axis=0)
            s_mom += z.T @ z
            d_mom += dz.T @ dz
            e_mom += np.outer(z[0], z[0]) + np.outer(z[-1], z[-1])
        moments = (s_mom, d_mom, e_mom, n_tot - rank, n_man, rank)
        grid = np.linspace(-b_max, b_max, 57)
        vals = np.array([_ar1_criterion(float(g), *moments) for g in grid])
        i = int(np.argmin(vals))
        res = bounded_minimum(
            lambda b, mom=moments: _ar1_criterion(float(b), *mom),
            float(grid[max(i - 1, 0)]),
            float(grid[min(i + 1, grid.size - 1)]),
            xatol=1e-6,
        )
        b0 = float(res.x[0]) if float(res.fun) <= vals[i] else float(grid[i])
        best_x = np.array([b0, _LOG_RATIO[0]])
        best_f = _arw_criterion(best_x, zs, n_tot - rank, rank)[0]
        # The white floor pulls a pure AR(1) fit towards zero; the search also starts
        # from the moment solution ``phi = c2/c1``, ``qw = c0 - c1/phi`` of the lags.
        c = [sum(float(v[: v.shape[0] - j, k] @ v[j:, k]) for v in residuals) for j in range(3)]
        starts = [(b0, -4.0)]
        if c[1] > 0 and 0 < c[2] < c[1]:
            phi_m = c[2] / c[1]
            white = c[0] - c[1] / phi_m
            innov = c[1] / phi_m * (1 - phi_m**2)
            if white > 0 and innov > 0:
                starts.append((float(np.arctanh(phi_m)), float(np.log(white / innov))))
        for start in starts:
            fit = nelder_mead(
                lambda x, z_=zs, r_=rank: _arw_criterion(x, z_, n_tot - r_, r_)[0],
                np.add(start, _SIMPLEX),
                xatol=5e-3,
                fatol=1e-3,
                maxfev=100,
            )
            if float(fit.fun) < best_f:
                best_x, best_f = np.asarray(fit.x, dtype=np.float64), float(fit.fun)

        def model_at(
            x: FloatArray,
            z_: list[_Spectral] = zs,
            r_: int = rank,
            vv_: float = vv,
        ) -> FloatArray:
            rss = _arw_criterion(x, z_, n_tot - r_, r_)[1]
            q_a = rss * vv_ / (n_tot - r_)
            p = float(np.tanh(np.clip(x[0], -b_max, b_max)))
            return np.array([p, q_a, q_a * float(np.exp(np.clip(x[1], *_LOG_RATIO)))])

        phi[k], qa[k], qw[k] = model_at(best_x)
        # curvature of -2 log L_R by central differences: Cov(x) = 2 H^-1
        steps = np.array([0.05, 0.25])
        hess = np.zeros((2, 2))
        for i in range(2):
            for j in range(2):
                acc = 0.0
                for si, sj, sign in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
                    x = best_x.copy()
                    x[i] += si * steps[i]
                    x[j] += sj * steps[j]
                    acc += sign * _arw_criterion(x, zs, n_tot - rank, rank)[0]
                hess[i, j] = acc / (4.0 * steps[i] * steps[j])
        ev, vec = np.linalg.eigh(0.5 * (hess + hess.T))
        # a flat direction (the white part absent) carries no information and,
        # the error bars being flat along it too, no spread either
        inv = np.where(ev > 1e-8 * max(float(ev[-1]), 1e-300), 1.0 / np.where(ev > 0, ev, 1.0), 0.0)
        points = np.array(
            [
                model_at(best_x + sign * steps[i] * np.eye(2)[i])
                for i in range(2)
                for sign in (1, -1)
            ]
        )
        spread[k] = (2.0 * (vec * inv) @ vec.T, steps, points)
    return phi, qa, qw, spread


def _recolour(w: FloatArray, phi: FloatArray) -> FloatArray:
    """``G = L^-T W`` per output, so that ``W' S W = G' G`` for the AR(1) correlation S.

    Backwards ``g(t) = w(t) + phi g(t + 1)``, then ``g(0) /= sqrt(1 - phi^2)``.
    """
    g = np.empty_like(w)
    for k in range(w.shape[1]):
        g[::-1, k, :] = _ar1_recursion(w[::-1, k, :], float(phi[k]))
        g[0, k, :] /= np.sqrt((1.0 - phi[k]) * (1.0 + phi[k]))
    return g


def _ar1_recursion(r: FloatArray, phi: float) -> FloatArray:
    """``y[t] = r[t] + phi y[t - 1]`` (y[-1] = 0) down the rows of r (N, c).

    In blocks of L ~ sqrt(N) rows: each block from a zero start by one product
    with the matrix of powers ``phi^(i - j)``, then the blocks' carries in a loop
    of N / L steps (what `scipy.signal.lfilter` computes, without importing
    SciPy's signal package: over half a second of a first fit).
    """
    n, c = r.shape
    if n == 0:
        return r.copy()
    size = math.isqrt(n - 1) + 1
    nb = -(-n // size)
    padded = np.zeros((nb * size, c))
    padded[:n] = r
    blocks = padded.reshape(nb, size, c)
    lag = np.arange(size)[:, None] - np.arange(size)[None, :]
    with np.errstate(under="ignore"):
        powers = np.where(lag >= 0, float(phi) ** np.maximum(lag, 0), 0.0)
        local = np.matmul(powers, blocks)  # each block from a zero start
        rise = float(phi) ** np.arange(1, size + 1)  # phi^(i + 1): a carry's weight
    out = np.empty_like(local)
    carry = np.zeros(c)
    for b in range(nb):
        out[b] = local[b] + rise[:, None] * carry[None, :]
        carry = out[b, -1]
    return np.asarray(out.reshape(nb * size, c)[:n], dtype=np.float64)


def _cross_covariances(
    residuals: list[FloatArray], phi: FloatArray, qa: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Cross-output covariances of the AR innovations and of the white parts.

    After whitening each output by its own phi, ``eps = a + w_t - phi w_(t-1)``
    has lag-0 covariance ``Qa + Qw (1 + phi_k phi_l)`` and lag-one covariances
    ``-phi_l Qw`` and ``-phi_k Qw``: this gives the correlations, which are
    projected onto valid (positive semidefinite) ones and scaled to the REML
    variances on the diagonal.
    """
    eps = [_ar1_filter_columns(v, phi) for v in residuals]
    n_tot = sum(e.shape[0] for e in eps)
    g0 = sum(e.T @ e for e in eps) / n_tot
    g1 = sum(e[:-1].T @ e[1:] for e in eps) / n_tot
    s = phi[:, None] + phi[None, :]
    ok_s = np.abs(s) > 1e-3
    w_emp = np.where(ok_s, -(g1 + g1.T) / np.where(ok_s, s, 1.0), 0.0)
    a_emp = g0 - w_emp * (1.0 + np.outer(phi, phi))
    out = []
    for emp, var in ((a_emp, qa), (w_emp, qw)):
        d = np.sqrt(np.clip(np.diag(emp), 0.0, None))
        both = np.outer(d > 0, d > 0)
        dd = np.where(d > 0, d, 1.0)
        corr = np.where(both, np.clip(emp / np.outer(dd, dd), -1.0, 1.0), 0.0)
        np.fill_diagonal(corr, 1.0)
        ev, vec = np.linalg.eigh(corr)
        corr = (vec * np.clip(ev, 0.0, None)) @ vec.T
        dn = np.sqrt(np.clip(np.diag(corr), 1e-300, None))
        sd = np.sqrt(var)
        out.append(corr / np.outer(dn, dn) * np.outer(sd, sd))
    return out[0], out[1]


def _ar1_filter_columns(v: FloatArray, phi: FloatArray) -> FloatArray:
    """Prais–Winsten whitening of each column of `v` by its own coefficient."""
    e = np.empty_like(v)
    e[0] = np.sqrt((1.0 - phi) * (1.0 + phi)) * v[0]
    e[1:] = (1.0 - phi) * v[1:] + phi * np.diff(v, axis=0)
    return e


def _colored_covariance(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray, m_inv: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Covariance for coloured residuals: ``M^-1 [J' R^-1 Sigma R^-1 J] M^-1``, each
    output's AR(1) coefficient and each parameter's degrees of freedom.

    Morelli's correction (Klein & Morelli ch. 6; SIDPAC's colores) puts the
    full-record sample autocorrelation of the residuals in ``Sigma``. With
    strongly coloured residuals that fails where it matters: the fit absorbs
    the noise lying in the span of the sensitivities, which for slow noise is
    much of its power at the frequencies the parameters are fitted at, so the
    residual correlation is biased low there (the plain outer-product
    sandwich is identically zero, ``J'R^-1 v = 0``, and the full-record
    correlation acts as a Bartlett window as long as the record, which in
    expectation keeps about a third of a bias's variance: fixed-b theory,
    Kiefer & Vogelsang 2005); lag windows
    (Bartlett/Parzen with Andrews' plug-in bandwidth) trade that absorption
    bias against truncation bias and cannot win both when N/tau is close to
    the number of parameters; and a degrees-of-freedom factor only rescales
    whatever bias is left, blowing up as N/tau approaches that number.

    Here ``Sigma`` is a parametric model of each output's noise, an AR(1)
    disturbance plus white sensor noise, fitted by restricted maximum
    likelihood (`_noise_model`), which accounts exactly for the dimensions
    the fit removed and needs no window; the cross-output correlations come
    from the whitened residuals (`_cross_covariances`). The sandwich is then
    exact for that model: ``J'R^-1 Sigma R^-1 J = G' Qa G + W' Qw W`` with
    ``W = R^-1 J`` and ``G = L^-T W`` (`_recolour`), O(N n_y p^2) with no loop
    over lags. Nothing is capped or floored. Spectra far from that shape (a
    narrow resonance in the residuals) are outside the model.

    The noise model is estimated from N/tau correlation times, so each
    variance is itself uncertain; the delta method through the REML
    curvature gives its variance and Satterthwaite's degrees of freedom
    ``nu = 2 V^2 / Var(V)``, returned with the covariance: the result's
    intervals take Student's t with them.
    """
    phi, qa, qw, spread = _noise_model(jacobians, residuals)
    sandwich = _Sandwich(jacobians, r, m_inv, phi)
    cov = sandwich.covariance(residuals, qa, qw)
    # The noise model is itself estimated (from some N/tau correlation times), so
    # each variance is uncertain; its delta-method variance gives Satterthwaite
    # degrees of freedom nu, with which the result's intervals take the t quantile.
    var = np.diag(cov)
    var_var = np.zeros_like(var)
    for k, (cov_x, steps, points) in enumerate(spread):
        grad = np.zeros((2, var.size))
        for i in range(2):
            diags = []
            for point in points[2 * i : 2 * i + 2]:
                model = [phi.copy(), qa.copy(), qw.copy()]
                for arr, value in zip(model, point, strict=True):
                    arr[k] = value
                diags.append(sandwich.variances(residuals, *model))
            grad[i] = (diags[0] - diags[1]) / (2.0 * steps[i])
        var_var += np.einsum("ij,ik,kj->j", grad, cov_x, grad)
    ok = (var > 0) & (var_var > 0)
    nu = np.where(ok, 2.0 * var**2 / np.where(ok, var_var, 1.0), np.inf)
    # Below one degree of freedom the t quantile grows without bound (a noise model
    # fitted to less than one correlation time, or to an output the fit leaves
    # almost noise-free); one degree of freedom is the widest interval that still
    # has a finite meaning.
    nu = np.maximum(nu, 1.0)
    return np.asarray(cov, dtype=np.float64), phi, np.asarray(nu, dtype=np.float64)


class _Sandwich:
    """``M^-1 [G' Qa G + W' Qw W] M^-1`` for noise models (phi, qa, qw) near one estimate.

    With ``V_k = W_k M^-1``, output k's weighted sensitivities carried through
    ``M^-1``, and ``H_k = L_k^-T V_k`` recoloured by its phi (`_recolour` acts on
    time alone, so it commutes with ``M^-1``), the covariance is ``sum_kl Qa_kl
    H_k'H_l + Qw_kl V_k'V_l``: formed in full once, at the estimate. The
    Satterthwaite differences of `_colored_covariance` need only its diagonal,
    ``sum_kl Qa_kl sum_t H_k * H_l + ...`` from per-pair column sums, where a
    model that moves one output's phi changes that output's row of pairs:
    O(N n_y p) work per model instead of O(N n_y p^2).
    """

    def __init__(
        self, jacobians: list[FloatArray], r: FloatArray, m_inv: FloatArray, phi: FloatArray
    ) -> None:
        self.phi = phi.copy()
        self.vs = [np.matmul(jac / r[None, :, None], m_inv) for jac in jacobians]
        self.hs = [_recolour(v, phi) for v in self.vs]
        self.dv = _pair_sums(self.vs)
        self.dh = _pair_sums(self.hs)

    def covariance(self, residuals: list[FloatArray], qa: FloatArray, qw: FloatArray) -> FloatArray:
        """The full covariance at the estimate's phi."""
        cov_a, cov_w = _cross_covariances(residuals, self.phi, qa, qw)
        n_y, n_par = self.vs[0].shape[1:]
        total = np.zeros((n_par, n_par))
        for arrays, q in ((self.hs, cov_a), (self.vs, cov_w)):
            for a in arrays:
                mixed = np.tensordot(q, a, axes=([1], [1]))  # (n_y, n_t, p): sum_l q_kl A_l
                for k in range(n_y):
                    total += a[:, k, :].T @ mixed[k]
        return np.asarray(0.5 * (total + total.T), dtype=np.float64)

    def variances(
        self, residuals: list[FloatArray], phi: FloatArray, qa: FloatArray, qw: FloatArray
    ) -> FloatArray:
        """The covariance's diagonal for a model near the estimate."""
        cov_a, cov_w = _cross_covariances(residuals, phi, qa, qw)
        moved = np.flatnonzero(phi != self.phi).tolist()
        dh = self.dh
        if moved:
            dh = dh.copy()
            rows = {k: np.zeros(dh.shape[1:]) for k in moved}
            for v, h in zip(self.vs, self.hs, strict=True):
                new = {k: _recolour(v[:, k : k + 1, :], phi[k : k + 1])[:, 0, :] for k in moved}
                for k, hk in new.items():
                    row = np.einsum("ta,tla->la", hk, h)
                    for j, hj in new.items():  # moved partners take their new columns
                        row[j] = np.einsum("ta,ta->a", hk, hj)
                    rows[k] += row
            for k, row in rows.items():
                dh[k] = row
                dh[:, k] = row
        return np.asarray(
            np.einsum("kl,kla->a", cov_a, dh) + np.einsum("kl,kla->a", cov_w, self.dv),
            dtype=np.float64,
        )


def _pair_sums(arrays: list[FloatArray]) -> FloatArray:
    """``D[k, l, :] = sum_t a[t, k, :] * a[t, l, :]`` summed over `arrays` (n_t, n_y, p)."""
    n_y, n_par = arrays[0].shape[1:]
    total = np.zeros((n_par, n_y, n_y))
    for a in arrays:
        at = np.ascontiguousarray(a.transpose(2, 0, 1))  # (p, n_t, n_y): a product per parameter
        total += np.matmul(at.transpose(0, 2, 1), at)
    return np.ascontiguousarray(total.transpose(1, 2, 0))


def _state_biased_outputs(mans: Sequence[Any], states: list[str], outputs: list[str]) -> set[int]:
    """Outputs whose own state equation carries an estimated bias (``estimate_bias=
    {name: 'state'}``): `identify` adds it as a constant state ``bias.<name>`` (with
    leading underscores where that name was taken) whose initial value is estimated."""
    from ._identification_record import STATE_BIAS_PREFIX as _STATE_BIAS_PREFIX

    found: set[int] = set()
    for m in mans:
        for j in m.x0_free:
            name = states[j].lstrip("_")
            if name.startswith(_STATE_BIAS_PREFIX):
                target = name[len(_STATE_BIAS_PREFIX) :]
                if target in outputs:
                    found.add(outputs.index(target))
    return found


def _offset_outputs(jacobians: Sequence[FloatArray] | None) -> set[int]:
    """Outputs on which one of the model's own parameters is an output bias: its
    sensitivity (`jacobians`, per record (n_t, n_y, p)) is the same at every sample
    on that output and nothing on any other, as a ``b_az`` added to ``az`` is."""
    found: set[int] = set()
    if not jacobians:
        return found
    g = np.concatenate([np.asarray(j, dtype=np.float64) for j in jacobians])
    size = np.max(np.abs(g), axis=0)  # (n_y, p)
    for j in range(g.shape[2]):
        live = np.flatnonzero(size[:, j] > 1e-9 * np.max(size[:, j], initial=0.0))
        if live.size != 1:
            continue
        k = int(live[0])
        column = g[:, k, j]
        # relative to its size: a finite-difference sensitivity carries rounding
        if np.ptp(column) <= 1e-6 * size[k, j]:
            found.add(k)
    return found


def _warn_unabsorbed_drift(
    phi: FloatArray,
    mans: Sequence[Any],
    outputs: list[str],
    cov: FloatArray,
    cov_white: FloatArray,
    names: list[str],
    states: list[str] | None = None,
    jacobians: Sequence[FloatArray] | None = None,
    exact: set[int] | None = None,
) -> None:
    """Warn when an output's residual drifts like a random walk over the record: the
    coloured error bars then widen, most on the parameter named. An output bias
    (`estimate_bias`) absorbs a constant offset; a bias on the output's state equation
    (``estimate_bias={name: 'state'}``) absorbs a ramp but not a wandering offset; a
    wandering one (turbulence, unmodelled slow dynamics) is process noise, which
    filter error models. Outputs with an output bias are not named: their drift is
    what that bias is for. A parameter of the model that is an output bias (its
    sensitivity, in `jacobians`, a constant on that output alone) counts as one."""
    n_t = sum(m.time.size for m in mans)
    with np.errstate(divide="ignore"):
        tau = np.where(phi > 0, -1.0 / np.log(np.clip(phi, 1e-300, None)), 0.0)
    biased = {k for m in mans for k in m.bias_free}
    skip = biased | (exact or set())
    drifting = [outputs[k] for k in range(phi.size) if tau[k] > n_t and k not in skip]
    if drifting:  # a model's own bias parameters are looked for only then
        offsets = _offset_outputs(jacobians)
        drifting = [o for o in drifting if outputs.index(o) not in offsets]
    if not drifting:
        return
    via_state = _state_biased_outputs(mans, states or [], outputs)
    white = np.diag(cov_white)
    ok = np.flatnonzero(white > 0)
    if ok.size == 0:
        return
    ratio = np.diag(cov)[ok] / white[ok]
    worst = int(ok[np.argmax(ratio)])
    widening = float(np.sqrt(np.max(ratio)))
    # the drift itself is what is told (tau beyond the record); the widening it
    # causes is reported, not a gate: a sound correction need not widen much
    bare = [o for o in drifting if outputs.index(o) not in via_state]
    stated = [o for o in drifting if outputs.index(o) in via_state]
    told = []
    if bare:
        told.append(
            f"no output bias is estimated on {bare} (estimate_bias={bare} absorbs a constant "
            "offset; a bias term in the model's own state equations, a ramp)"
        )
    if stated:
        told.append(
            f"the bias estimated on the state equation of {stated} absorbs a ramp, not this "
            "wandering offset"
        )
    warnings.warn(
        ResidualDriftWarning(
            f"identify: the residuals of {drifting} drift like a random walk over the "
            f"record; {'; '.join(told)}. The coloured error bars are up to "
            f"{widening:.2g}x the white ones (on {names[worst]}). A wandering offset "
            "(turbulence, unmodelled slow dynamics) is process noise: method='filter_error'",
            tuple(drifting),
            widening,
        ),
        stacklevel=5,  # here, fit_output_error, identify, its BLAS wrapper, the caller
    )
