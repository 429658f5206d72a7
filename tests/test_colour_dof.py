"""The Satterthwaite degrees of freedom of the coloured-residual error bars.

``nu_j = 2 B_jj^2 / Var(B^_jj)``; near w = 0 the variance is the exact one of a
Gaussian quadratic form in the low band's periodogram bins (`_band_moments`,
`_band_variance`), pinned here against dense matrices, a Monte Carlo of the
quadratic form, and white residuals' classical N - p.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import toeplitz

from aeroid import _colour
from aeroid._ar1_forms import ar1_bilinear


def _problem(n: int, a: np.ndarray, level: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """A constant and a slope on output 0, a slope and a wave on output 1, and the
    dense AR(1) covariance S and residual projector of their least-squares fit."""
    rng = np.random.default_rng(seed)
    t = np.linspace(-1.0, 1.0, n)
    g = np.zeros((n, 2, 4))
    g[:, 0, 0] = 1.0
    g[:, 0, 1] = t
    g[:, 1, 2] = t + 0.1 * rng.standard_normal(n)
    g[:, 1, 3] = np.sin(5.0 * t)
    g[:, 1, 0] = 0.3  # the constant seen on both outputs couples them through M
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    s = np.zeros((2 * n, 2 * n))
    for k in range(2):
        idx = np.arange(n) * 2 + k  # (t, output) flattened time-major
        s[np.ix_(idx, idx)] = level[k] / (1.0 - a[k] ** 2) * toeplitz(a[k] ** np.arange(n))
    gm = g.reshape(2 * n, 4)
    resid = np.eye(2 * n) - gm @ m_inv @ gm.T
    return {"g": g, "m_inv": m_inv, "s": s, "gm": gm, "resid": resid}


def _fourier(n: int, bins: int, a: np.ndarray) -> np.ndarray:
    """The map (bins n_y, n n_y) from residuals to their whitened padded transform."""
    w = 2.0 * np.pi * np.arange(bins) / (2 * n)
    d = np.exp(-1j * np.outer(w, np.arange(n)))  # (bins, n)
    out = np.zeros((bins, 2, n, 2), dtype=complex)
    for k in range(2):
        out[:, k, :, k] = (1.0 - a[k] * np.exp(-1j * w))[:, None] * d
    return out.reshape(bins * 2, n * 2)


def _moments(
    p: dict[str, np.ndarray], n: int, bins: int, a: np.ndarray, level: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    g, m_inv, s, gm = p["g"], p["m_inv"], p["s"], p["gm"]
    gf = np.fft.rfft(g, 2 * n, axis=0)[:bins]
    sgf = np.fft.rfft((s @ gm).reshape(n, 2, 4), 2 * n, axis=0)[:bins]
    model_cov = m_inv @ gm.T @ s @ gm @ m_inv
    return _colour._band_moments(gf, sgf, n, a, level, m_inv, model_cov)


def test_band_moments_are_the_dense_covariances() -> None:
    # E[w w^H] = F (I-H) S (I-H)' F^H and E[w w^T] = F (I-H) S (I-H)' F^T, dense
    n, bins = 40, 6
    a, level = np.array([0.8, -0.3]), np.array([1.0, 0.5])
    p = _problem(n, a, level)
    gam, rel = _moments(p, n, bins, a, level)
    f = _fourier(n, bins, a)
    cov_u = p["resid"] @ p["s"] @ p["resid"].T
    np.testing.assert_allclose(gam.reshape(2 * bins, -1), f @ cov_u @ f.conj().T, atol=1e-9)
    np.testing.assert_allclose(rel.reshape(2 * bins, -1), f @ cov_u @ f.T, atol=1e-9)
    # the low bins of a real record are far from circular: E[w w^T] is not small
    assert np.abs(rel[0, 0, 0, 0]) == pytest.approx(np.abs(gam[0, 0, 0, 0]), rel=1e-9)


def test_band_variance_is_the_gaussian_quadratic_forms() -> None:
    # Q = u' W u with W = Re(F^H A F): Var Q = 2 tr((W Sigma)^2), E Q = tr(W Sigma)
    n, bins, half = 40, 6, 2
    a, level = np.array([0.8, -0.3]), np.array([1.0, 0.5])
    p = _problem(n, a, level)
    gam, rel = _moments(p, n, bins, a, level)
    rng = np.random.default_rng(1)
    n_bins = n + 1
    rows = bins + half
    z = rng.standard_normal((rows, 2, 4)) + 1j * rng.standard_normal((rows, 2, 4))
    weights = _colour._window_columns(n_bins, half, rows, bins)
    level = np.broadcast_to(np.eye(2), (rows, 2, 2)).astype(complex)
    var = _colour._band_variance(z, weights, gam, rel, level, np.ones((bins, 2)), n)
    f = _fourier(n, bins, a)
    cov_u = p["resid"] @ p["s"] @ p["resid"].T
    for j in range(4):
        y = np.einsum("ka,kb->kab", z[:, :, j].conj(), z[:, :, j])
        r = np.einsum("kl,kab->lab", weights, y)
        big = np.zeros((2 * bins, 2 * bins), dtype=complex)
        for i in range(bins):
            big[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = r[i].conj() / n
        w_real = (f.conj().T @ big @ f).real
        w_real = 0.5 * (w_real + w_real.T)
        ws = w_real @ cov_u
        # scaled from the model's mean to the estimate's share, here sum_l tr R_l
        scale = np.einsum("laa->", r).real / np.trace(ws)
        assert var[j] == pytest.approx(2.0 * np.trace(ws @ ws) * scale**2, rel=1e-9)


def test_window_columns_are_the_smoothing() -> None:
    for n_bins, half, bins in ((50, 3, 8), (50, 20, 12), (50, 49, 10), (30, 14, 30), (9, 3, 9)):
        dense = np.asarray(_colour._smooth(np.eye(n_bins)[:, :bins], half))
        cols = _colour._window_columns(n_bins, half, n_bins, bins)
        np.testing.assert_allclose(cols, dense, atol=1e-15)


def test_band_variance_matches_monte_carlo() -> None:
    # a constant and a slope under AR(1) phi = 0.9 noise: the low band's share of B^_jj
    # drawn 4000 times from the model and fitted, against the formula's mean and
    # variance, within four standard errors of the sample's variance
    n, bins, half, draws = 200, 8, 3, 4000
    a, level = np.array([0.9, 0.9]), np.array([1.0, 1.0])
    p = _problem(n, a, level, seed=2)
    gam, rel = _moments(p, n, bins, a, level)
    size = 2 * n
    n_bins = n + 1
    gf, filt, twice = _colour._bins(p["g"], a, size)
    vf = gf @ p["m_inv"]
    z = (vf / filt.conj()[:, :, None] * np.sqrt(twice)[:, None, None])[: bins + half]
    weights = _colour._window_columns(n_bins, half, bins + half, bins)
    level = np.broadcast_to(np.eye(2), (bins + half, 2, 2)).astype(complex)
    var = _colour._band_variance(z, weights, gam, rel, level, np.ones((bins, 2)), n)
    rng = np.random.default_rng(3)
    chol = np.linalg.cholesky(p["s"])
    u = (p["resid"] @ chol @ rng.standard_normal((2 * n, draws))).T.reshape(draws, n, 2)
    wf = np.fft.rfft(u, size, axis=1)[:, :bins] * filt[None, :bins]  # (draws, bins, n_y)
    for j in range(4):
        y = np.einsum("ka,kb->kab", z[:, :, j].conj(), z[:, :, j])
        r = np.einsum("kl,kab->lab", weights, y)
        q = np.einsum("lab,dla,dlb->d", r, wf, wf.conj()).real / n
        mean = np.einsum("lab,lbla->", r.conj(), gam).real / n  # the model's E Q
        model_var = var[j] * (mean / np.einsum("laa->", r).real) ** 2
        assert abs(q.mean() - mean) <= 4.0 * q.std() / np.sqrt(draws)
        se = np.sqrt(np.mean((q - q.mean()) ** 4) - q.var() ** 2) / np.sqrt(draws)
        assert abs(q.var() - model_var) <= 4.0 * se, (j, q.var(), model_var, se)


def _white_residuals(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Least-squares residuals of `x` whose lag-one correlation is exactly zero."""
    inv = np.linalg.inv(x.T @ x)

    def proj(v: np.ndarray) -> np.ndarray:
        return v - x @ (inv @ (x.T @ v))

    def lag(v: np.ndarray, w: np.ndarray) -> float:
        return float(v[:-1] @ w[1:] + w[:-1] @ v[1:])

    n = x.shape[0]
    e = proj(rng.standard_normal(n))
    # a second direction of the opposite lag-one sign, so that a real root exists
    f = proj((-1.0) ** np.arange(n) if e[:-1] @ e[1:] > 0 else np.cos(3.0 * np.arange(n) / n))
    roots = np.roots([f[:-1] @ f[1:], lag(e, f), e[:-1] @ e[1:]])
    return e + float(roots[np.isreal(roots)].real[0]) * f


@pytest.mark.parametrize("n", [60, 120])
def test_white_residuals_give_the_classical_n_minus_p(n: int) -> None:
    # no lag-one correlation: no prewhitening and a window over the whole band, whose
    # estimate is the leverage-corrected mean periodogram ~ SSE / (N - p) on N - p
    # degrees of freedom (the independent-bin count gave the N + 1 bins instead)
    rng = np.random.default_rng(n)
    t = np.linspace(-1.0, 1.0, n)
    x = np.column_stack([np.ones(n), t, np.sin(7.0 * t)])
    u = _white_residuals(x, rng)
    assert abs(u[:-1] @ u[1:]) < 1e-10 * (u @ u)
    inv = np.linalg.inv(x.T @ x)
    _, nu = _colour.colored_covariance([x[:, None, :]], [u[:, None]], inv)
    np.testing.assert_allclose(nu, n - 3, rtol=0.01)


@pytest.mark.parametrize("a", [0.0, 0.6, 0.97, -0.4])
def test_ar1_bilinear_forms_are_the_dense_double_sums(a: float) -> None:
    # d_l' S d_m^* and d_l' S d_m in closed form against the matrices themselves,
    # on and off the diagonal (z = 1 on it: the arithmetico-geometric branch)
    n, bins = 37, 9
    w = 2.0 * np.pi * np.arange(bins) / (2 * n)
    S = 1.7 * toeplitz(a ** np.arange(n))
    d = np.exp(-1j * np.outer(w, np.arange(n)))  # rows d_l
    np.testing.assert_allclose(
        ar1_bilinear(w, n, a, 1.7, conjugate=False), d @ S @ d.conj().T, atol=1e-11
    )
    np.testing.assert_allclose(ar1_bilinear(w, n, a, 1.7, conjugate=True), d @ S @ d.T, atol=1e-11)
