"""The numpy searches and transforms of a first fit's error bars (`aeroid._searches`)
against closed forms, and against SciPy's routines they stand in for."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from aeroid._searches import bounded_minimum, dct2, mirror_smooth, nelder_mead


def test_bounded_minimum_finds_a_parabola_vertex_and_an_end() -> None:
    res = bounded_minimum(lambda b: (b - 0.3) ** 2 + 1.0, -1.0, 2.0, xatol=1e-8)
    assert res.x[0] == pytest.approx(0.3, abs=1e-7)
    assert res.fun == pytest.approx(1.0, abs=1e-12)
    # a minimum outside the interval: the search ends at the nearer end
    edge = bounded_minimum(lambda b: b, 0.5, 1.5, xatol=1e-8)
    assert edge.x[0] == pytest.approx(0.5, abs=1e-6)


def test_nelder_mead_finds_a_quadratic_minimum() -> None:
    h = np.array([[3.0, 1.0], [1.0, 2.0]])
    c = np.array([1.0, -2.0])
    best = -np.linalg.solve(h, c) / 2.0
    res = nelder_mead(
        lambda x: float(x @ h @ x + c @ x),
        np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 2.0]]),
        xatol=1e-9,
        fatol=1e-12,
        maxfev=2000,
    )
    np.testing.assert_allclose(res.x, best, atol=1e-7)
    # the evaluations budget is a hard limit
    short = nelder_mead(lambda x: float(x @ x), np.eye(3)[:, :2] + 5.0, maxfev=7)
    assert short.nfev == 7


def test_dct2_is_the_orthonormal_cosine_transform() -> None:
    rng = np.random.default_rng(0)
    for n in (1, 2, 5, 8, 33):
        x = rng.standard_normal((3, n))
        k = np.arange(n)[:, None]
        j = np.arange(n)[None, :]
        basis = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * j + 1) / (2 * n))
        basis[0] /= np.sqrt(2.0)
        np.testing.assert_allclose(dct2(x), x @ basis.T, atol=1e-13)


def test_mirror_smooth_reflects_about_the_edge_samples() -> None:
    rng = np.random.default_rng(1)
    n, half = 12, 5
    x = rng.standard_normal((n, 2)) + 1j * rng.standard_normal((n, 2))
    w = rng.uniform(0.1, 1.0, half + 1)
    weights = np.concatenate([w[:0:-1], w])
    expected = np.zeros_like(x)
    for i in range(n):
        for d in range(-half, half + 1):
            j = i + d
            j = -j if j < 0 else (2 * (n - 1) - j if j > n - 1 else j)
            expected[i] += weights[d + half] * x[j]
    np.testing.assert_allclose(mirror_smooth(x, weights), expected, atol=1e-13)


def test_a_wide_window_is_smoothed_by_fft_to_rounding(monkeypatch) -> None:
    """A long record's spectrum (1e5 samples: a window thousands of bins wide) took
    equation error a minute in the per-offset loop; the FFT convolution equals it."""
    import aeroid._searches as searches

    rng = np.random.default_rng(3)
    n, half = 6000, 700
    x = np.exp(3.0 * rng.standard_normal((n, 2, 1)))  # periodogram-like: decades apart
    xc = x + 1j * rng.standard_normal((n, 2, 1))
    w = 1.0 - (np.arange(-half, half + 1) / (half + 1.0)) ** 2
    fast = [mirror_smooth(x, w), mirror_smooth(xc, w)]
    monkeypatch.setattr(searches, "_DIRECT_HALF", 10**9)
    slow = [mirror_smooth(x, w), mirror_smooth(xc, w)]
    for a, b in zip(fast, slow, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_the_same_answers_as_scipy() -> None:
    from scipy.fft import dct
    from scipy.ndimage import convolve1d
    from scipy.optimize import minimize, minimize_scalar

    rng = np.random.default_rng(2)
    for _ in range(40):
        c = rng.standard_normal(4)

        def f(b: float, c: np.ndarray = c) -> float:
            return float(
                np.sin(3 * b + c[0]) + c[1] * b * b + 0.3 * np.cos(7 * b + c[2]) + c[3] * b
            )

        lo, hi = sorted(rng.uniform(-3, 3, 2))
        ref = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
        got = bounded_minimum(f, lo, hi, xatol=1e-6)
        assert got.x[0] == pytest.approx(float(ref.x), abs=1e-12)
        a = rng.standard_normal((2, 2))
        h = a @ a.T + 0.1 * np.eye(2)
        g = rng.standard_normal(2)

        def q(x: np.ndarray, h: np.ndarray = h, g: np.ndarray = g) -> float:
            return float(x @ h @ x + g @ x + 0.5 * np.sin(3 * x[0]) * np.cos(2 * x[1]))

        simplex = rng.standard_normal(2) + np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 2.0]])
        maxfev = int(rng.integers(5, 100))
        options = {"xatol": 5e-3, "fatol": 1e-3, "maxfev": maxfev, "initial_simplex": simplex}
        ref_nm = minimize(q, simplex[0], method="Nelder-Mead", options=options)
        got_nm = nelder_mead(q, simplex, xatol=5e-3, fatol=1e-3, maxfev=maxfev)
        np.testing.assert_allclose(got_nm.x, ref_nm.x, rtol=0, atol=1e-12)
    x = rng.standard_normal((4, 301))
    np.testing.assert_allclose(dct2(x), dct(x, type=2, norm="ortho", axis=1), atol=1e-13)
    d = np.arange(-20, 21)
    w = 1.0 - (d / 21.0) ** 2
    y = rng.standard_normal((200, 3))
    np.testing.assert_allclose(
        mirror_smooth(y, w), convolve1d(y, w, axis=0, mode="mirror"), atol=1e-12
    )


@pytest.mark.skipif(sys.platform == "win32", reason="fresh interpreter per check")
def test_coloured_error_bars_import_no_scipy() -> None:
    """A fit whose residuals are coloured computes its error bars without importing
    SciPy (its optimiser, FFT and image filters cost more than the fit)."""
    code = """
import sys
import numpy as np
import aeroid

def dyn(t, x, u, p):
    return np.array([p["a"] * x[0] + p["b"] * u[0]])

rng = np.random.default_rng(0)
t = np.arange(600) * 0.02
u = np.sign(np.sin(2 * np.pi * t / 3.0))
model = aeroid.Model(["x"], ["u"], {"a": -1.0, "b": 2.0}, dyn)
y = model.simulate(t, {"u": u}, np.array([0.0])).outputs[:, 0]
drift = np.cumsum(rng.standard_normal(t.size)) * 0.002  # strongly coloured residuals
data = aeroid.FlightData(time=t, channels={"u": u, "x": y + drift})
before = set(sys.modules)
res = aeroid.identify(model, data, {"a": -0.8, "b": 1.5}, error_bars="colored")
assert np.all(np.isfinite(list(res.stderr.values())))
new = set(sys.modules) - before
print(sorted(m for m in new if m.split(".")[0] in ("scipy", "jax", "matplotlib")))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize(("n", "segment"), [(3000, 256), (1001, 64), (515, 63)])
def test_welch_density_is_scipys_welch(n: int, segment: int) -> None:
    from scipy.signal import welch

    from aeroid._searches import welch_density

    rng = np.random.default_rng(n)
    x = np.cumsum(rng.normal(size=n)) * 0.1 + rng.normal(size=n) + 0.01 * np.arange(n)
    _, expected = welch(x, fs=1.0, window="hann", nperseg=segment, detrend="linear")
    np.testing.assert_allclose(welch_density(x, segment), expected, rtol=1e-10, atol=1e-14)


def test_white_noise_density_is_twice_its_variance() -> None:
    from aeroid._searches import welch_density

    x = np.random.default_rng(3).normal(scale=2.0, size=200_000)
    dens = welch_density(x, 512)[1:-1]
    # one-sided density of white noise of variance 4 at unit rate: 8, to 1 % over the band
    assert np.mean(dens) == pytest.approx(8.0, rel=0.01)
