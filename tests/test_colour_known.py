"""The coloured-residual kernel with a known part of the residual spectrum taken off.

`colored_covariance(..., known=...)` estimates the covariance of the part of the
noise that the caller does not add itself. With residuals ``white + AR(1)`` and the
AR(1) part's exact expected periodogram (through the fit's projection) given as
known, the kernel's mean over seeds is the white part's classical covariance
``s^2 (X'X)^-1``; without it, the full sandwich, three to four times larger here.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import toeplitz
from scipy.signal import butter, lfilter

from aeroid import _colour

N, SEEDS, PHI, SD_AR = 400, 200, 0.5, 1.0


def _design() -> np.ndarray:
    rng = np.random.default_rng(0)
    b, a = butter(2, 0.2)
    x = np.column_stack([np.ones(N), *(lfilter(b, a, rng.standard_normal(N)) for _ in range(2))])
    return x / np.linalg.norm(x, axis=0)


def _known(x: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """E of the AR(1) residual's periodogram over 2N points, divided by N."""
    cov = SD_AR**2 * toeplitz(PHI ** np.arange(N))
    keep = np.eye(N) - x @ inv @ x.T
    left = keep @ cov @ keep
    dft = np.fft.rfft(np.eye(N), 2 * N, axis=0)  # (N + 1, N)
    return np.einsum("kt,ts,ks->k", dft, left, dft.conj())[:, None, None] / N


def test_a_known_part_is_not_counted_twice() -> None:
    x = _design()
    inv = np.linalg.inv(x.T @ x)
    known = _known(x, inv)
    white, plain = np.zeros(3), np.zeros(3)
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        w = rng.standard_normal(N)
        w[0] /= np.sqrt(1 - PHI**2)
        ar = lfilter([1.0], [1.0, -PHI], w) * np.sqrt(1 - PHI**2) * SD_AR
        e = rng.standard_normal(N) + ar
        u = e - x @ (inv @ (x.T @ e))
        cov, nu = _colour.colored_covariance([x[:, None, :]], [u[:, None]], inv, known=[known])
        white += np.diag(cov) / SEEDS
        plain += np.diag(_colour.colored_covariance([x[:, None, :]], [u[:, None]], inv)[0]) / SEEDS
        assert np.all(np.isfinite(nu) & (nu > 0))
    ratio = white / np.diag(inv)  # the white part's variance is 1
    # The slopes: a seed's estimate scatters by about 0.5, the mean of 200 by 0.036;
    # 0.1 is about three of those.
    assert np.all(np.abs(ratio[1:] - 1.0) < 0.1), ratio
    # The constant has its weight at w = 0, where the AR(1) part is three times the
    # white one: a seed scatters by about 1.4, the mean of 200 by 0.1 (unclipped,
    # the estimate is unbiased; it may be negative for one seed).
    assert 0.7 < ratio[0] < 1.35, ratio
    # without the known part the sandwich holds the AR(1) share as well
    assert np.all(plain > 2.5 * white), (plain, white)


def test_known_needs_one_periodogram_per_record() -> None:
    x = _design()
    inv = np.linalg.inv(x.T @ x)
    u = np.zeros((N, 1))
    try:
        _colour.colored_covariance(
            [x[:, None, :]] * 2, [u, u], inv, known=[np.zeros((N + 1, 1, 1))]
        )
    except ValueError as exc:
        assert "known" in str(exc)
    else:
        raise AssertionError("accepted one periodogram for two records")
