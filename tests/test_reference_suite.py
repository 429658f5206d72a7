"""The SIDPAC reference suite (tests/reference) skips cleanly and its Monte Carlo keeps spectra."""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
REF = HERE / "reference"
sys.path.insert(0, str(REF))

import _sidpac as S  # noqa: E402


def _env_without_data() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != S.ENV}
    env["PYTHONPATH"] = str(HERE.parent)
    return env


def test_runner_skips_cleanly_without_the_data_folder() -> None:
    out = subprocess.run(
        [sys.executable, str(REF / "run_all.py"), "--mc", "0"],
        env=_env_without_data(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "skipped" in out.stdout and S.ENV in out.stdout


def test_a_case_script_skips_cleanly_without_the_data_folder() -> None:
    out = subprocess.run(
        [sys.executable, str(REF / "ref_example_5p1.py")],
        env=_env_without_data(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "skipped example_5p1" in out.stdout


def test_a_missing_file_is_a_skip_naming_it(tmp_path: pathlib.Path) -> None:
    import ref_example_5p1

    try:
        ref_example_5p1.run(tmp_path, mc=0)
    except S.SkipCase as exc:
        assert "example_5p1_results.mat" in str(exc)
    else:
        raise AssertionError("an empty folder must raise SkipCase")


def test_surrogates_keep_auto_and_cross_periodograms() -> None:
    # two correlated coloured outputs; every bin 1..n/2 keeps |X_a|^2 and X_a X_b*
    rng = np.random.default_rng(3)
    n = 512
    e = rng.normal(size=(n, 2))
    a = np.convolve(e[:, 0], [1.0, 0.8, 0.5], mode="same")
    v = np.column_stack([a, 0.6 * a + 0.3 * e[:, 1]])
    s = S.phase_surrogate(v, rng)
    fv, fs = np.fft.rfft(v, axis=0), np.fft.rfft(s, axis=0)
    k = slice(1, None)
    np.testing.assert_allclose(np.abs(fs[k]) ** 2, np.abs(fv[k]) ** 2, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        fs[k, 0] * np.conj(fs[k, 1]), fv[k, 0] * np.conj(fv[k, 1]), rtol=1e-9, atol=1e-9
    )
    # the phases really change, and the surrogate is a new signal
    assert np.max(np.abs(s - v)) > 0.5 * np.std(v)
    # the same seed gives the same surrogate
    np.testing.assert_array_equal(
        S.phase_surrogate(v, np.random.default_rng(7)),
        S.phase_surrogate(v, np.random.default_rng(7)),
    )


def test_surrogate_zero_bin_carries_the_low_frequency_power_on_average() -> None:
    # a zero-mean record: the zero bin gets mean power (and cross-power) of the 3 lowest bins
    rng = np.random.default_rng(5)
    n = 256
    v = rng.normal(size=(n, 2))
    v[:, 1] += 0.5 * v[:, 0]
    v -= v.mean(axis=0)
    fv = np.fft.rfft(v, axis=0)
    target = np.real(fv[1:4, :, None] * np.conj(fv[1:4, None, :])).mean(axis=0)
    draws = np.array([np.fft.rfft(S.phase_surrogate(v, rng), axis=0)[0].real for _ in range(4000)])
    got = draws.T @ draws / len(draws)
    # 4000 draws: relative sampling error of a second moment about sqrt(2/4000) ~ 2 %
    np.testing.assert_allclose(got, target, rtol=0.1, atol=0.1 * np.abs(target).max())


def test_monte_carlo_of_a_regression_matches_ordinary_least_squares_on_white_noise() -> None:
    # white residuals: the surrogate scatter of a slope is sigma / sqrt(sum x^2)
    rng = np.random.default_rng(11)
    n = 400
    x = rng.normal(size=n)
    fitted = 2.0 * x
    resid = 0.1 * rng.normal(size=n)
    resid -= (
        x * (x @ resid) / (x @ x)
    )  # residuals orthogonal to the regressor, as a fit leaves them

    def refit(z: np.ndarray) -> dict[str, float]:
        return {"slope": float(x @ z / (x @ x))}

    sd = S.monte_carlo(refit, fitted, resid, 400, seed=1)["slope"]
    expected = np.sqrt(np.mean(resid**2) / (x @ x))
    # 400 refits: the standard deviation is known to about 1/sqrt(2*399) ~ 3.5 %; allow 5 sigma
    assert abs(sd / expected - 1.0) < 0.18


def test_rows_fill_the_derived_columns() -> None:
    r = S.row(
        "c",
        "p",
        sidpac=1.0,
        sidpac_se_white=0.1,
        sidpac_se_corrected=0.2,
        ours=1.3,
        ours_se=0.3,
        mc_se=0.15,
    )
    assert set(S.KEYS) <= set(r)
    assert (
        np.isclose(r["delta_sigma"], 1.5)
        and np.isclose(r["se_ratio"], 1.5)
        and np.isclose(r["mc_ratio"], 2.0)
    )
    assert np.isclose(S.sidpac_mc_ratio(r), 0.2 / 0.15)


def test_numpy_m_colores_equals_the_direct_double_sum() -> None:
    # the FFT form against sum_i sum_j W_i' Rvv(|i-j|) W_j on a small problem
    rng = np.random.default_rng(1)
    n, no, npar = 40, 2, 3
    s = rng.normal(size=(n, no, npar))
    v = rng.normal(size=(n, no))
    rr = np.diag([0.5, 2.0])
    corrected, white = S.m_colores(s, v, rr)
    w = np.einsum("ab,ibp->iap", np.linalg.inv(rr), s)
    minv = np.linalg.inv(np.einsum("iap,iaq->pq", s, w))
    rvv = np.array(
        [
            [[v[k:, a] @ v[: n - k, b] / (n - k) for b in range(no)] for a in range(no)]
            for k in range(n)
        ]
    )
    total = sum(w[i].T @ rvv[abs(i - j)] @ w[j] for i in range(n) for j in range(n))
    np.testing.assert_allclose(white, minv, rtol=1e-10)
    np.testing.assert_allclose(corrected, minv @ total @ minv, rtol=1e-9, atol=1e-14)


def test_numpy_r_colores_white_is_ordinary_least_squares() -> None:
    rng = np.random.default_rng(2)
    X = np.column_stack([rng.normal(size=200), np.ones(200)])
    z = X @ [1.0, 2.0] + rng.normal(size=200)
    corrected, white = S.r_colores(X, z)
    v = z - X @ np.linalg.lstsq(X, z, rcond=None)[0]
    xtxi = np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(white, (v @ v) / 198 * xtxi, rtol=1e-10)
    # the sandwich over the biased autocorrelation, summed sample by sample
    acf = [v[k:] @ v[: 200 - k] / 200 for k in range(200)]
    middle = sum(np.outer(X[i], X[j]) * acf[abs(i - j)] for i in range(200) for j in range(200))
    np.testing.assert_allclose(corrected, xtxi @ middle @ xtxi, rtol=1e-9)
    # (SIDPAC's own saved r_colores errors are matched to 1e-13 by ref_example_5p2 on real data)


def test_linear_mc_is_the_monte_carlo_of_a_linear_fit() -> None:
    # coloured residuals of a fit with a constant and a slow regressor: the surrogate
    # scatter of a linear estimator is the raw-periodogram sandwich linear_mc gives
    rng = np.random.default_rng(12)
    n = 300
    x = np.column_stack([np.ones(n), np.cumsum(rng.normal(size=n)) / np.sqrt(n)])
    inv = np.linalg.inv(x.T @ x)
    e = np.convolve(rng.normal(size=n + 20), np.ones(20) / 20, mode="valid")[:n]
    resid = e - x @ (inv @ (x.T @ e))
    var, dof = S.linear_mc([x[:, None, :]], [resid[:, None]], inv)
    draws = np.array([inv @ (x.T @ S.phase_surrogate(resid, rng)) for _ in range(4000)])
    # 4000 draws: a second moment to about sqrt(2/4000) ~ 2.2 %; allow over 4 of those
    np.testing.assert_allclose(np.mean(draws**2, axis=0), var, rtol=0.1)
    assert np.all((dof > 1.0) & (dof < n))
    lo, hi = S.chi2_band(4.0)
    assert 0.0 < lo < 1.0 < hi  # sqrt(chi2_4 / 4) spans about 0.35-1.66
    assert np.isclose(lo, np.sqrt(0.4844 / 4.0), rtol=1e-3) and np.isclose(
        hi, np.sqrt(11.1433 / 4.0), rtol=1e-3
    )


def test_recorder_annotates_rows_with_the_kernels_figures() -> None:
    import aeroid

    rng = np.random.default_rng(13)
    n = 400
    data = {"x": np.cumsum(rng.normal(size=n)) / 20.0}
    data["z"] = (
        1.0 + 2.0 * data["x"] + np.convolve(rng.normal(size=n + 9), np.ones(10) / 10, "valid")
    )
    with S.ColourRecorder() as rec:
        res = aeroid.equation_error(data, "z", ["x"])
    rows = [
        S.row(
            "c",
            k,
            sidpac=None,
            sidpac_se_white=None,
            sidpac_se_corrected=None,
            ours=res.parameters[k],
            ours_se=res.stderr[k],
        )
        for k in res.parameters
    ]
    rec.annotate(rows)
    for r in rows:
        assert r["lin_se"] > 0 and r["lin_dof"] > 0
        assert np.isclose(r["ours_dof"], res.degrees_of_freedom[r["parameter"]])
        assert np.isclose(r["lin_ratio"], r["ours_se"] / r["lin_se"])
    import aeroid._colour as colour

    assert colour.colored_covariance.__name__ == "colored_covariance"  # restored


@pytest.mark.slow
def test_the_monte_carlo_under_reads_a_constant_under_slow_ar1_noise() -> None:
    # The suite's Monte Carlo keeps the residuals' periodogram (which the fit emptied
    # near w = 0) and fills bin 0 from the three lowest bins (a flat extrapolation).
    # Under AR(1) noise with phi = 0.99 on 1000 samples (true spectrum at w = 0 2.3x
    # the mean of those bins) its first-order variance of a constant is about 0.46 of
    # the exact one, averaged over 100 seeds (a seed scatters by about 1, the mean by
    # 0.1): where residuals drift, a constant's Monte Carlo figure is low by itself.
    from scipy.linalg import toeplitz
    from scipy.signal import butter, lfilter

    n, phi, seeds = 1000, 0.99, 100
    cov = toeplitz(phi ** np.arange(n))
    ratio = np.zeros(3)
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        b, a = butter(2, 0.05)
        slow = [lfilter(b, a, rng.normal(size=n + 200))[200:] for _ in range(2)]
        x = np.column_stack([np.ones(n), *slow])
        inv = np.linalg.inv(x.T @ x)
        e = lfilter([1.0], [1.0, -phi], rng.normal(size=n + 3000))[3000:] * np.sqrt(1 - phi**2)
        v = e - x @ (inv @ (x.T @ e))
        exact = np.diag(inv @ x.T @ cov @ x @ inv)
        ratio += S.linear_mc([x[:, None, :]], [v[:, None]], inv)[0] / exact / seeds
    print(ratio)
    assert ratio[0] < 0.75, ratio
    assert np.all(np.abs(ratio[1:] - 1.0) < 0.2), ratio


def test_fvsysid_oem_of_a_static_linear_output_is_least_squares() -> None:
    # no states: output error is least squares; the Cramer-Rao covariance is
    # s^2 (X'X)^-1 with s^2 the mean squared residual (FVSysID's R divides by N)
    import _fvsysid as F

    rng = np.random.default_rng(5)
    n = 300
    u = rng.normal(size=(n, 1))
    z = 1.5 * u - 0.4 + 0.05 * rng.normal(size=(n, 1))

    def none(x: np.ndarray, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.zeros((0, p.shape[1]))

    def obs(x: np.ndarray, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return (p[0] * uu[0] + p[1])[None, :]

    fit = F.ml_oem(none, obs, np.zeros(0), u, z, 0.1, [1.0, 0.0])
    x = np.column_stack([u[:, 0], np.ones(n)])
    beta = np.linalg.lstsq(x, z[:, 0], rcond=None)[0]
    s2 = np.mean((z[:, 0] - x @ beta) ** 2)
    np.testing.assert_allclose(fit.p, beta, rtol=1e-6)
    np.testing.assert_allclose(fit.crb, s2 * np.linalg.inv(x.T @ x), rtol=1e-4)
    assert fit.cost[-1] <= fit.cost[0]


def test_fvsysid_oem_recovers_a_first_order_system() -> None:
    # x' = a x + b u, y = x: a seeded record, truth within 4 Cramer-Rao sigmas
    import _fvsysid as F

    rng = np.random.default_rng(8)
    n, dt = 400, 0.05
    u = np.sign(np.sin(np.arange(n) * dt * 1.3))[:, None]

    def f(x: np.ndarray, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return p[0] * x + p[1] * uu[0]

    def g(x: np.ndarray, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return x

    truth = np.array([[-2.0], [3.0]])
    y = F.simulate(f, g, np.zeros(1), u, dt, truth)[:, :, 0]
    z = y + 0.02 * rng.normal(size=y.shape)
    fit = F.ml_oem(f, g, np.zeros(1), u, z, dt, [-1.0, 1.0], tolerance=1e-10)
    assert np.all(np.abs(fit.p - truth[:, 0]) < 4.0 * fit.se)
    held = F.ml_oem(f, g, np.zeros(1), u, z, dt, [-2.0, 1.0], free=[False, True])
    assert held.p[0] == -2.0 and held.se[0] == 0.0 and held.se[1] > 0.0


def test_fvsysid_oem_segment_biases_are_least_squares_with_dummies() -> None:
    # two segments, a shared slope and a bias per segment (bx): least squares on
    # [u, segment 1 dummy, segment 2 dummy]; the Cramer-Rao covariance s^2 (X'X)^-1
    import _fvsysid as F

    rng = np.random.default_rng(11)
    n = 200
    us = [rng.normal(size=(n, 1)) for _ in range(2)]
    zs = [
        1.5 * u + c + 0.05 * rng.normal(size=(n, 1)) for u, c in zip(us, (-0.4, 0.7), strict=True)
    ]

    def obs(x: None, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return (uu[:, 0:1] * p[0] + p[1])[:, None, :]

    fit = F.ml_oem(None, obs, None, us, zs, 0.1, [1.0], bx=[[0.0], [0.0]], free_bx=[[True]] * 2)
    x = np.zeros((2 * n, 3))
    x[:, 0] = np.concatenate(us)[:, 0]
    x[:n, 1] = x[n:, 2] = 1.0
    z = np.concatenate(zs)[:, 0]
    beta = np.linalg.lstsq(x, z, rcond=None)[0]
    s2 = np.mean((z - x @ beta) ** 2)
    np.testing.assert_allclose([fit.p[0], *fit.bx[:, 0]], beta, rtol=1e-6)
    np.testing.assert_allclose(fit.crb, s2 * np.linalg.inv(x.T @ x), rtol=1e-4)
    assert fit.names == ("p1", "bx[0].0", "bx[1].0")


def test_fvsysid_oem_bounded_slope_sits_on_its_bound() -> None:
    # z = 1.5 u - 0.4 with the slope bounded above at 1.2: the slope ends on the
    # bound (zero deviation) and the intercept is the mean of z - 1.2 u
    import _fvsysid as F

    rng = np.random.default_rng(12)
    n = 300
    u = rng.normal(size=(n, 1)) + 0.5
    z = 1.5 * u - 0.4 + 0.05 * rng.normal(size=(n, 1))

    def obs(x: None, uu: np.ndarray, p: np.ndarray) -> np.ndarray:
        return (uu[:, 0:1] * p[0] + p[1])[:, None, :]

    box = (np.array([-np.inf, -np.inf]), np.array([1.2, np.inf]))
    fit = F.ml_oem(None, obs, None, u, z, 0.1, [1.0, 0.0], bounds=box)
    assert fit.p[0] == 1.2 and fit.active[0] == 1 and fit.se[0] == 0.0
    np.testing.assert_allclose(fit.p[1], np.mean(z[:, 0] - 1.2 * u[:, 0]), rtol=1e-6)
    assert fit.se[1] > 0.0
