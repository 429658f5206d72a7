"""AR(1) prewhitening of the coloured-residual kernel (`aeroid._colour`).

The kernel smooths the periodogram of residuals whitened by one AR(1) filter
per output and recolours the estimate; the leverage correction is the residual
periodogram's exact expectation under that AR(1) model (`_model_keeps`), which
these tests pin to the dense formula ``d'(I - H) S (I - H)d / n``, and the
estimate of a constant's variance under slow AR(1) noise to its exact value.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import toeplitz
from scipy.signal import butter, lfilter

from aeroid import _colour


def _design(rng: np.random.Generator, n: int, k: int = 2) -> np.ndarray:
    b, a = butter(2, 0.05)
    cols = [lfilter(b, a, rng.standard_normal(n + 200))[200:] for _ in range(k)]
    return np.column_stack([np.ones(n), *cols])


def _ar1_cov(n: int, phi: float, innovation: float) -> np.ndarray:
    return innovation / (1.0 - phi**2) * toeplitz(phi ** np.arange(n))


def _dense_expectation(g: np.ndarray, m_inv: np.ndarray, covs: list[np.ndarray]) -> np.ndarray:
    """E of each output's residual periodogram over 2n points (divided by n), dense."""
    n, n_y, p = g.shape
    stacked = g.transpose(1, 0, 2).reshape(n_y * n, p)  # output-major rows
    s = np.zeros((n_y * n, n_y * n))
    for a, c in enumerate(covs):
        s[a * n : (a + 1) * n, a * n : (a + 1) * n] = c
    keep = np.eye(n_y * n) - stacked @ m_inv @ stacked.T
    left = keep @ s @ keep
    dft = np.fft.rfft(np.eye(n), 2 * n, axis=0)  # (n + 1, n)
    out = np.empty((n + 1, n_y))
    for a in range(n_y):
        block = left[a * n : (a + 1) * n, a * n : (a + 1) * n]
        out[:, a] = np.einsum("kt,ts,ks->k", dft, block, dft.conj()).real / n
    return out


@pytest.mark.parametrize("phis", [(0.9,), (0.95, -0.3)])
def test_model_leverage_is_the_exact_expected_periodogram(phis: tuple[float, ...]) -> None:
    rng = np.random.default_rng(3)
    n = 160
    x = _design(rng, n)
    n_y = len(phis)
    g = np.stack([x * (1.0 + 0.5 * a) for a in range(n_y)], axis=1)  # (n, n_y, p)
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    a = np.array(phis)
    resid = rng.standard_normal((n, n_y))
    level = _colour._innovations([resid], a)
    keep = _colour._model_keeps([g], [resid], m_inv, a).keeps[0]
    covs = [_ar1_cov(n, phi, lv) for phi, lv in zip(phis, level, strict=True)]
    want = _dense_expectation(g, m_inv, covs)
    w = 2.0 * np.pi * np.arange(n + 1) / (2 * n)
    spectrum = level[None, :] / np.abs(1.0 - a[None, :] * np.exp(-1j * w)[:, None]) ** 2
    np.testing.assert_allclose(keep * spectrum, want, rtol=1e-8, atol=1e-10 * want.max())


def test_white_model_leverage_is_one_less_the_leverage() -> None:
    rng = np.random.default_rng(4)
    n = 120
    x = _design(rng, n)
    m_inv = np.linalg.inv(x.T @ x)
    keep = _colour._model_keeps(
        [x[:, None, :]], [rng.standard_normal((n, 1))], m_inv, np.zeros(1)
    ).keeps
    want = _dense_expectation(x[:, None, :], m_inv, [np.eye(n)])
    np.testing.assert_allclose(keep[0], want, rtol=1e-9, atol=1e-12)


def test_the_filter_is_held_inside_the_records_resolution() -> None:
    # an integrated random walk's lag-one correlation is 1 - O(1/n^2): the filter
    # stops at 1 - 2 pi / n
    rng = np.random.default_rng(5)
    n = 500
    walk = np.cumsum(np.cumsum(rng.standard_normal(n)))
    a = _colour._prewhitening([(walk - walk.mean())[:, None]])
    assert a[0] == pytest.approx(1.0 - 2.0 * np.pi / n)
    assert np.all(np.abs(_colour._prewhitening([rng.standard_normal((n, 2))])) < 0.2)


@pytest.mark.slow
def test_variances_under_slow_ar1_noise_are_unbiased() -> None:
    # A constant and two slow regressors under AR(1) noise with phi = 0.99 (correlation
    # time 199 samples, 10 in the record): the kernel's variance over the exact one,
    # averaged over 200 seeds. A seed's ratio is skewed and scatters by up to 1.3 for
    # the constant (few degrees of freedom at w = 0), the mean by 0.09; 0.3 is over
    # three of those.
    n, phi, seeds = 2000, 0.99, 200
    exact_s = _ar1_cov(n, phi, 1.0 - phi**2)
    ratios = np.zeros(3)
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        x = _design(rng, n)
        inv = np.linalg.inv(x.T @ x)
        e = lfilter([1.0], [1.0, -phi], rng.standard_normal(n + 2000))[2000:]
        e *= np.sqrt(1.0 - phi**2)
        v = e - x @ (inv @ (x.T @ e))
        exact = np.diag(inv @ x.T @ exact_s @ x @ inv)
        cov, nu = _colour.colored_covariance([x[:, None, :]], [v[:, None]], inv)
        assert np.all(np.isfinite(nu) & (nu > 0))
        ratios += np.diag(cov) / exact / seeds
    assert np.all(np.abs(ratios - 1.0) < 0.3), ratios
