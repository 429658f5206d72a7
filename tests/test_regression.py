"""Equation-error and stepwise regression against closed forms and seeded truths."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

import aeroid
from aeroid import ChannelError, DataFormatError, FlightData, IdentificationError
from aeroid.estimation.regression import (
    RegressionResult,
    candidate_pool,
    equation_error,
    spline_terms,
    stepwise_regression,
)

THETA = np.array([0.5, -1.0, 2.0])  # const, a, b


def _design(rng: np.random.Generator, n: int) -> np.ndarray:
    """Two smooth, correlated regressors (AR(1) with correlation times 9 and 19 samples)."""
    x1 = scipy.signal.lfilter([0.2], [1, -0.8], rng.standard_normal(n)) * 3
    x2 = scipy.signal.lfilter([0.1], [1, -0.9], rng.standard_normal(n)) * 3 + 0.3 * x1
    return np.column_stack([x1, x2])


def _ar1(rng: np.random.Generator, n: int, phi: float, sigma: float) -> np.ndarray:
    return scipy.signal.lfilter([np.sqrt(1 - phi**2)], [1, -phi], rng.standard_normal(n)) * sigma


# -- equation error ------------------------------------------------------------------------


def test_matches_closed_form_least_squares() -> None:
    rng = np.random.default_rng(0)
    x = _design(rng, 500)
    z = THETA[0] + x @ THETA[1:] + 0.1 * rng.standard_normal(500)
    res = equation_error(x, z, ["a", "b"], error_bars="white")
    full = np.column_stack([np.ones(500), x])
    theta, *_ = np.linalg.lstsq(full, z, rcond=None)
    est = np.array([res.parameters[k] for k in ("const", "a", "b")])
    np.testing.assert_allclose(est, theta, rtol=1e-12, atol=1e-12)
    v = z - full @ theta
    s2 = v @ v / (500 - 3)
    cov = s2 * np.linalg.inv(full.T @ full)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-10)
    np.testing.assert_allclose(res.covariance_white, cov, rtol=1e-10)
    np.testing.assert_allclose(res.residuals, v, atol=1e-12)
    sst = np.sum((z - z.mean()) ** 2)
    assert res.r_squared == pytest.approx(1 - (v @ v) / sst, rel=1e-12)
    assert res.f_statistic == pytest.approx((sst - v @ v) / 2 / s2, rel=1e-10)
    # Klein & Morelli's predicted squared error: SSE/N + sigma_max^2 p / N
    assert res.pse == pytest.approx((v @ v) / 500 + sst / 500 * 3 / 500, rel=1e-12)
    assert res.fit_error == pytest.approx(np.sqrt(s2), rel=1e-12)


def test_noise_free_data_recover_the_truth_exactly() -> None:
    rng = np.random.default_rng(1)
    x = _design(rng, 300)
    z = THETA[0] + x @ THETA[1:]
    res = equation_error({"a": x[:, 0], "b": x[:, 1], "Cm": z}, "Cm", ["a", "b"])
    np.testing.assert_allclose(list(res.parameters.values()), THETA, rtol=1e-12, atol=1e-12)
    assert res.response_name == "Cm"
    assert res.r_squared == pytest.approx(1.0, abs=1e-12)


def test_unbiased_with_noise_free_regressors() -> None:
    x = _design(np.random.default_rng(2), 400)
    full = np.column_stack([np.ones(400), x])
    rng = np.random.default_rng(3)
    est = np.array(
        [
            list(
                equation_error(x, full @ THETA + 0.2 * rng.standard_normal(400)).parameters.values()
            )
            for _ in range(200)
        ]
    )
    sd = 0.2 * np.sqrt(np.diag(np.linalg.inv(full.T @ full)))
    # the mean of 200 estimates lies within 4 standard errors of the mean
    assert np.all(np.abs(est.mean(axis=0) - THETA) < 4 * sd / np.sqrt(200))
    # and their scatter is the classical sigma^2 (X'X)^-1 (chi-square, 199 dof: +-20 %)
    np.testing.assert_allclose(est.std(axis=0, ddof=1), sd, rtol=0.2)


def _coverage(
    phi: float, n: int = 1000, seeds: int = 200, error_bars: str = "colored"
) -> tuple[np.ndarray, np.ndarray]:
    """Per-parameter coverage of the corrected and of the classical 95 % intervals."""
    hits = np.zeros((seeds, 3), dtype=bool)
    hits_white = np.zeros((seeds, 3), dtype=bool)
    for seed in range(seeds):
        rng = np.random.default_rng(1000 + seed)
        x = _design(rng, n)
        z = THETA[0] + x @ THETA[1:] + _ar1(rng, n, phi, 0.1)
        res = equation_error(x, z, error_bars=error_bars)
        est = np.array(list(res.parameters.values()))
        hits[seed] = np.abs(est - THETA) < np.array(list(res.margin(0.95).values()))
        white = 1.96 * np.sqrt(np.diag(res.covariance_white))
        hits_white[seed] = np.abs(est - THETA) < white
    return hits.mean(axis=0), hits_white.mean(axis=0)


def test_error_bars_cover_with_white_residuals() -> None:
    cover, cover_white = _coverage(0.0)
    # 600 intervals: the pooled coverage has a binomial SD of 0.9 %
    assert 0.93 <= cover.mean() <= 0.97, cover
    assert np.all(cover >= 0.90), cover
    np.testing.assert_allclose(cover, cover_white, atol=0.01)  # nothing to correct


def test_error_bars_cover_with_ar1_residuals() -> None:
    cover, cover_white = _coverage(0.9)
    assert cover.mean() >= 0.90, cover
    assert np.all(cover >= 0.86), cover
    # the classical bars, blind to the colour, are far too narrow here
    assert cover_white.mean() < 0.6, cover_white


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_output_errors_correction_covers_white_and_ar1_residuals(phi: float) -> None:
    # error_bars="reml": output error's AR(1) + white REML sandwich; the Satterthwaite
    # widening leans conservative, so up to 98 % (2 binomial SDs above 96 %) is allowed
    cover, _ = _coverage(phi, error_bars="reml")
    assert 0.93 <= cover.mean() <= 0.98, cover
    assert np.all(cover >= 0.90), cover


def test_reml_error_bars_are_output_errors_own() -> None:
    # the same sandwich identify applies to its residuals, for one output and unit weights
    from aeroid.estimation._noise_model import _colored_covariance as output_error_covariance

    rng = np.random.default_rng(5)
    x = _design(rng, 800)
    z = THETA[0] + x @ THETA[1:] + _ar1(rng, 800, 0.8, 0.1)
    res = equation_error(x, z, error_bars="reml")
    assert res.error_bars == "reml"
    xc = np.column_stack([np.ones(800), x])
    inv = np.linalg.inv(xc.T @ xc)
    want, _, nu = output_error_covariance(
        [xc[:, None, :]], [np.asarray(res.residuals)[:, None]], np.ones(1), inv
    )
    np.testing.assert_allclose(res.covariance, want, rtol=1e-9)
    np.testing.assert_allclose(list(res.degrees_of_freedom.values()), nu, rtol=1e-9)
    assert np.all(np.diag(res.covariance) > np.diag(res.covariance_white))  # coloured: wider


def test_a_hand_built_constant_column_is_named_with_the_remedy() -> None:
    rng = np.random.default_rng(2)
    x = np.column_stack([np.ones(200), _design(rng, 200)])  # SIDPAC style: ones included
    z = x @ THETA + 0.01 * rng.standard_normal(200)
    with pytest.raises(IdentificationError, match=r"'x1' is constant .*intercept=False"):
        equation_error(x, z)
    own = equation_error(x, z, intercept=False)
    np.testing.assert_allclose(list(own.parameters.values()), THETA, atol=0.01)


@pytest.mark.parametrize("n", [301, 1000])
def test_colored_covariance_with_a_flat_spectrum_is_the_classical_one(
    n: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # white residuals, a whole-band window: the spectrum is flat, sum_k G~'G~ / N = X'X
    # (Parseval over the 2n-point transform), so the sandwich is s^2 (X'X)^-1 exactly
    # for s^2 = the leverage-corrected periodogram mean (the kernel without its AR(1)
    # prewhitening, which tests/test_colour_prewhitening.py checks)
    from aeroid import _colour, _stats

    rng = np.random.default_rng(9)
    x = np.column_stack([np.ones(n), _design(rng, n)])
    inv = np.linalg.inv(x.T @ x)
    v = rng.standard_normal(n)
    v -= x @ (inv @ (x.T @ v))  # least-squares residuals
    cov_pw, nu_pw = _colour.colored_covariance([x[:, None, :]], [v[:, None]], inv)
    monkeypatch.setattr(_colour, "_PREWHITEN", False)
    cov, nu = _colour.colored_covariance([x[:, None, :]], [v[:, None]], inv)
    # the flat window's estimate: mean periodogram over mean (1 - leverage), one-sided bins
    size = 2 * n
    uf = np.fft.rfft(v, size)
    gf = np.fft.rfft(x, size, axis=0)
    lev = np.einsum("kp,pq,kq->k", gf, inv, gf.conj()).real / n
    scale = _colour._NARROW * _colour._lag_scale([v[:, None]])
    if scale * 5.0 * np.pi / (3.0 * size) < 1.0 / (size // 2):
        s2 = np.mean(np.abs(uf) ** 2 / n) / np.mean(1.0 - lev)
        np.testing.assert_allclose(cov, s2 * inv, rtol=1e-9)
    # and in any window, white residuals give the classical bars to within sampling:
    # each variance rests on nu_j degrees of freedom (relative sd sqrt(2 / nu_j))
    s2_classical = float(v @ v) / (n - 3)
    for c, d in ((cov, nu), (cov_pw, nu_pw)):
        rel = np.diag(c) / (s2_classical * np.diag(inv)) - 1.0
        assert np.all(np.abs(rel) <= 3.0 * np.sqrt(2.0 / d)), (rel, d)
        # white residuals keep enough degrees of freedom that the t widening is below
        # 5 % (the constant's rests on the bins of the window at w = 0, exactly counted)
        assert np.all(_stats.t_quantile(d) < 1.05 * 1.959964)
    # prewhitening white residuals changes the bars by little
    np.testing.assert_allclose(np.diag(cov_pw), np.diag(cov), rtol=0.1)


def test_colored_covariance_is_the_frequency_domain_double_sum(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the sandwich is (1/N) sum_k V~_k^H F^_k V~_k over the 2n-point transform, each
    # bin's F^ the smoothed periodogram over the smoothed (1 - leverage) (without the
    # prewhitening; with it, tests/test_colour_prewhitening.py)
    from aeroid import _colour

    monkeypatch.setattr(_colour, "_PREWHITEN", False)
    rng = np.random.default_rng(4)
    n = 400
    x = np.column_stack([np.ones(n), _design(rng, n)])
    inv = np.linalg.inv(x.T @ x)
    v = _ar1(rng, n, 0.8, 1.0)
    v -= x @ (inv @ (x.T @ v))
    cov, _ = _colour.colored_covariance([x[:, None, :]], [v[:, None]], inv)
    size = 2 * n
    full_u = np.fft.fft(v, size)
    full_x = np.fft.fft(x, size, axis=0) @ inv
    lev = np.einsum("kp,kp->k", full_x, np.fft.fft(x, size, axis=0).conj()).real / n
    one_sided = size // 2 + 1
    half = 1
    scale = _colour._NARROW * _colour._lag_scale([v[:, None]])
    half = max(1, int(np.ceil(3.0 * size / (5.0 * np.pi * scale))))
    while True:
        kept = _colour._smooth(np.clip(1 - lev[:one_sided], 0, 1)[:, None], half)[:, 0]
        if half >= one_sided - 1 or kept.min() * (half + 1) >= 1.0:
            break
        half *= 2
    spec = _colour._smooth((np.abs(full_u[:one_sided]) ** 2 / n)[:, None], half)[:, 0] / kept
    both = np.concatenate([spec, spec[1:-1][::-1]])  # the even two-sided spectrum
    want = np.einsum("k,kp,kq->pq", both, full_x.conj(), full_x).real / size
    np.testing.assert_allclose(cov, want, rtol=1e-9)


def test_expressions_and_flight_data() -> None:
    t = np.arange(200) * 0.02
    rng = np.random.default_rng(4)
    alpha, q, v = rng.normal(0.1, 0.02, 200), rng.normal(0, 0.1, 200), rng.normal(50, 1, 200)
    cm = 0.01 - 0.5 * alpha + 2.0 * alpha**2 - 3.0 * q / v + 0.7 * alpha * q
    data = FlightData(t, {"alpha": alpha, "q": q, "V": v, "Cm": cm})
    res = equation_error(data, "Cm", ["alpha", "alpha^2", "q/V", "alpha*q"])
    np.testing.assert_allclose(
        [res.parameters[k] for k in ("const", "alpha", "alpha^2", "q/V", "alpha*q")],
        [0.01, -0.5, 2.0, -3.0, 0.7],
        rtol=1e-9,
        atol=1e-11,
    )
    same = equation_error(
        data, "Cm", {"a": "alpha", "a2": "alpha**2", "qv": q / v, "aq": "alpha*q"}
    )
    assert same.parameters["a2"] == pytest.approx(2.0, rel=1e-9)
    np.testing.assert_array_equal(res.time, t)
    scaled = equation_error(data, "2*Cm", ["alpha"], intercept=False)
    assert scaled.parameter_names == ("alpha",)


def test_state_derivative_from_smoothed_data() -> None:
    # alpha_dot = Z_alpha alpha + q on the noise-free truth case: differentiate, regress
    from aeroid.io.smoothing import differentiate
    from aeroid.models import catalog

    data = differentiate(catalog.short_period_flight(noise={}), "alpha")
    res = equation_error(data, "alpha_dot", ["alpha", "q"], intercept=False)
    assert res.parameters["alpha"] == pytest.approx(catalog.SHORT_PERIOD_TRUTH["Z_alpha"], abs=1e-4)
    assert res.parameters["q"] == pytest.approx(1.0, abs=1e-4)


def test_frequency_domain_agrees_with_time_domain_noise_free() -> None:
    rng = np.random.default_rng(5)
    n, dt = 1500, 0.02
    x = _design(rng, n) + 0.4  # offsets leak into f > 0: the constant term takes them
    z = THETA[0] + x @ THETA[1:]
    t_dom = equation_error(x, z, ["a", "b"])
    freq = np.arange(0.1, 2.0, 0.04)  # evenly spaced: chirp-z transform
    f_dom = equation_error(x, z, ["a", "b"], domain="frequency", frequencies=freq, dt=dt)
    uneven = np.sort(rng.uniform(0.1, 2.0, 30))  # direct sum
    f_dir = equation_error(x, z, ["a", "b"], domain="frequency", frequencies=uneven, dt=dt)
    for res in (f_dom, f_dir):
        np.testing.assert_allclose(
            list(res.parameters.values()), list(t_dom.parameters.values()), rtol=1e-9, atol=1e-10
        )
        assert res.domain == "frequency" and res.error_bars == "colored"
    assert f_dom.residuals.dtype == np.complex128 and f_dom.n_samples == freq.size
    # the transform itself: chirp-z equals the direct sum
    direct = dt * np.exp(-2j * np.pi * np.outer(freq, np.arange(n) * dt)) @ z
    np.testing.assert_allclose(f_dom.response, direct, rtol=1e-9, atol=1e-12)


def test_frequency_domain_constant_without_content() -> None:
    # at multiples of 1/(N dt) a constant's transform vanishes: it is left out
    rng = np.random.default_rng(8)
    x = rng.standard_normal((500, 2))
    z = 3.0 + x @ THETA[1:]
    res = equation_error(x, z, domain="frequency", frequencies=np.arange(0.1, 3.0, 0.1), dt=0.02)
    assert res.parameter_names == ("x1", "x2")
    np.testing.assert_allclose(list(res.parameters.values()), THETA[1:], rtol=1e-9)
    with pytest.raises(IdentificationError, match="'c'"):
        equation_error(
            np.column_stack([x, np.ones(500)]),
            z,
            ["a", "b", "c"],
            intercept=False,
            domain="frequency",
            frequencies=np.arange(0.1, 3.0, 0.1),
            dt=0.02,
        )


def test_frequency_domain_error_bars_cover() -> None:
    freq = np.arange(0.1, 3.0, 0.05)
    hits = []
    for seed in range(60):
        rng = np.random.default_rng(2000 + seed)
        x = _design(rng, 1000)
        z = THETA[0] + x @ THETA[1:] + 0.1 * rng.standard_normal(1000)
        res = equation_error(x, z, domain="frequency", frequencies=freq, dt=0.02)
        # these frequencies are multiples of 1/(N dt): the constant drops out
        assert res.parameter_names == ("x1", "x2")
        est = np.array(list(res.parameters.values()))
        hits.append(np.abs(est - THETA[1:]) < 1.96 * np.array(list(res.stderr.values())))
    # 120 intervals: binomial SD 2 %; residual variance counted per real component
    assert 0.90 <= np.mean(hits) <= 0.99


def _frequency_coverage(phi: float, spacing: float, error_bars: str) -> np.ndarray:
    """Per slope, how often the 95 % interval of Fourier transform regression covers
    the truth over 300 records with AR(1) residuals; `spacing` in bins of 1/(N dt)."""
    n, dt = 1000, 0.02
    freq = np.arange(0.1, 3.0, spacing / (n * dt))
    hits = []
    for seed in range(300):
        rng = np.random.default_rng(2000 + seed)
        x = _design(rng, n)
        z = THETA[0] + x @ THETA[1:] + _ar1(rng, n, phi, 0.1)
        res = equation_error(
            x, z, domain="frequency", frequencies=freq, dt=dt, error_bars=error_bars
        )
        half = res.margin()
        est = np.array([res.parameters[k] for k in ("x1", "x2")])
        hits.append(np.abs(est - THETA[1:]) < np.array([half["x1"], half["x2"]]))
    return np.asarray(np.mean(hits, axis=0))


@pytest.mark.parametrize(
    ("phi", "spacing"), [(0.0, 1.0), (0.9, 1.0), (0.0, 0.4), (0.9, 0.4), (0.99, 0.4)]
)
def test_frequency_domain_default_bars_cover_coloured_and_closely_spaced(
    phi: float, spacing: float
) -> None:
    # the frequency sandwich: each frequency's own residual spectrum, and the noise
    # that frequencies 0.4 bins apart (SIDPAC's choice) share through the kernel;
    # 300 records: binomial SD 1.3 % at 0.95
    cover = _frequency_coverage(phi, spacing, "colored")
    assert np.all(cover >= 0.905) and np.all(cover <= 0.995), cover


def test_frequency_domain_white_bars_miss_what_the_sandwich_counts() -> None:
    # the classical formula on the same records counts shared noise once per frequency
    assert np.max(_frequency_coverage(0.9, 0.4, "white")) < 0.85


def test_frequency_domain_refuses_reml() -> None:
    x = _design(np.random.default_rng(1), 300)
    with pytest.raises(DataFormatError, match="reml"):
        equation_error(
            x, x @ THETA[1:], domain="frequency", frequencies=[0.2, 0.4], dt=0.02, error_bars="reml"
        )


def test_result_record() -> None:
    rng = np.random.default_rng(6)
    x = _design(rng, 200)
    res = equation_error(x, x @ THETA[1:] + 0.1 * rng.standard_normal(200), ["a", "b"])
    assert isinstance(res, RegressionResult)
    with pytest.raises(ValueError):
        res.residuals[0] = 1.0
    with pytest.raises(TypeError):
        res.parameters["a"] = 0.0  # type: ignore[index]
    text = res.summary()
    assert "| a " in text and "R²" in text and "PSE" in text
    fig = res.plot()
    assert len(fig.axes) == 3


def test_bad_input() -> None:
    rng = np.random.default_rng(7)
    x = _design(rng, 100)
    z = x[:, 0]
    with pytest.raises(IdentificationError, match="'c'"):
        equation_error(np.column_stack([x, x[:, 0] + x[:, 1]]), z, ["a", "b", "c"])
    with pytest.raises(IdentificationError, match="'z0'"):
        equation_error(np.column_stack([x, np.zeros(100)]), z, ["a", "b", "z0"])
    with pytest.raises(DataFormatError, match="twice"):
        equation_error(x, z, ["a", "a"])
    with pytest.raises(DataFormatError, match="2 names"):
        equation_error(x, z, ["a"])
    data = FlightData(np.arange(100) * 0.1, {"a": x[:, 0], "z": z})
    with pytest.raises(ChannelError, match="'nope'"):
        equation_error(data, "z", ["a*nope"])
    with pytest.raises(ChannelError, match="constant term, added by intercept=True"):
        equation_error(data, "z", ["a", "const"])
    with pytest.raises(DataFormatError, match=r"'a\^0.5'.*non-finite"):
        equation_error(data, "z", ["a^0.5"])  # negative samples
    with pytest.raises(DataFormatError, match="power"):
        equation_error(data, "z", ["a^b"])
    with pytest.raises(DataFormatError, match="frequencies"):
        equation_error(data, "z", ["a"], domain="frequency")
    with pytest.raises(DataFormatError, match="domain"):
        equation_error(data, "z", ["a"], domain="laplace")
    with pytest.raises(DataFormatError, match="dt"):
        equation_error(x, z, domain="frequency", frequencies=[0.1, 0.2, 0.3])
    with pytest.raises(DataFormatError, match="samples"):
        equation_error(data, z[:50], ["a"])
    with pytest.raises(IdentificationError, match="samples"):
        equation_error(x[:2], z[:2])
    # complex samples would lose their imaginary part in a cast
    with pytest.raises(DataFormatError, match="complex"):
        equation_error(x + 1j, z)
    with pytest.raises(DataFormatError, match="response: complex"):
        equation_error(x, z + 1j)
    with pytest.raises(DataFormatError, match=r"data\['a'\]: complex"):
        equation_error({"a": x[:, 0] + 1j, "z": z}, "z", ["a"])
    with pytest.raises(DataFormatError, match=r"data\['b'\]: 99 samples where data\['a'\] has 100"):
        equation_error({"a": x[:, 0], "b": x[:99, 1], "z": z}, "z", ["a"])
    with pytest.raises(DataFormatError, match="no channels"):
        equation_error({}, "z", ["a"])
    with pytest.raises(DataFormatError, match="regressors: expected names"):
        equation_error(data, "z", 5)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match="dt: expected a positive number"):
        equation_error({"a": x[:, 0], "z": z}, "z", ["a"], dt=-5.0)
    with pytest.raises(DataFormatError, match="dt: expected a positive number"):
        equation_error(x, z, domain="frequency", frequencies=[0.1, 0.2, 0.3], dt="0.02")
    with pytest.raises(DataFormatError, match=r"dt: 5\.0 contradicts"):
        equation_error(data, "z", ["a"], dt=5.0)
    with pytest.raises(DataFormatError, match="frequencies: not numeric"):
        equation_error(data, "z", ["a"], domain="frequency", frequencies="abc")
    with pytest.raises(DataFormatError, match="intercept: expected True or False"):
        equation_error(x, z, intercept="no")  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match="regressor 'a': its sum of squares overflows"):
        equation_error({"a": x[:, 0] * 1e200, "b": x[:, 1], "z": z}, "z", ["a", "b"])
    # a channel of a mapping with a gap in it, named directly (not only in expressions)
    gappy = {"a": np.where(np.arange(100) == 7, np.nan, x[:, 0]), "b": x[:, 1], "z": z}
    for fit in (equation_error, stepwise_regression):
        with pytest.raises(DataFormatError, match="regressor 'a': non-finite value at sample 7"):
            fit(gappy, "z", ["a", "b"])
    with pytest.raises(DataFormatError, match="response 'a': non-finite value at sample 7"):
        equation_error(gappy, "a", ["b"])


# -- stepwise regression ---------------------------------------------------------------------

N_SEEDS, N_SAMPLES, DT = 100, 1000, 0.02
TRUE_CM = {"alpha": -0.6, "qhat": -9.0, "de": -1.1}


def _flights() -> tuple[dict[str, np.ndarray], np.ndarray]:
    """A short-period manoeuvre per seed (rows), simulated exactly (zero-order hold)."""
    rng = np.random.default_rng(11)
    t = np.arange(N_SAMPLES) * DT
    de = np.zeros((N_SEEDS, N_SAMPLES))
    for a, b, v in [(1, 4, 0.03), (4, 6, -0.03), (6, 7, 0.03), (7, 8, -0.03), (11, 14, -0.02)]:
        de[:, (t >= a) & (t < b)] = v
    de += np.repeat(rng.normal(0, 0.005, (N_SEEDS, N_SAMPLES // 25)), 25, axis=1)
    a_mat = np.array([[-1.2, 1.0], [-8.0, -2.5]])
    b_vec = np.array([-0.1, -12.0])
    big = scipy.linalg.expm(np.block([[a_mat, b_vec[:, None]], [np.zeros((1, 3))]]) * DT)
    phi, gam = big[:2, :2], big[:2, 2]
    x = np.zeros((N_SEEDS, 2))
    states = np.empty((N_SEEDS, N_SAMPLES, 2))
    for k in range(N_SAMPLES):
        states[:, k] = x
        x = x @ phi.T + de[:, k : k + 1] * gam
    alpha = states[..., 0] + 0.08  # trim angle of attack
    qhat = states[..., 1] * 1.5 / (2 * 40.0)
    phase = rng.uniform(0, 2 * np.pi, (N_SEEDS, 3))
    lat = {
        "beta": 0.01 * np.sin(2 * np.pi * 0.3 * t + phase[:, :1]),
        "phat": 0.01 * np.sin(2 * np.pi * 0.5 * t + phase[:, 1:2]),
        "rhat": 0.005 * np.sin(2 * np.pi * 0.2 * t + phase[:, 2:]),
        "da": np.repeat(rng.normal(0, 0.01, (N_SEEDS, N_SAMPLES // 50)), 50, axis=1),
        "dr": np.repeat(rng.normal(0, 0.01, (N_SEEDS, N_SAMPLES // 50)), 50, axis=1),
    }
    cm = 0.02 + TRUE_CM["alpha"] * alpha + TRUE_CM["qhat"] * qhat + TRUE_CM["de"] * de
    cm = cm + 0.004 * rng.standard_normal(cm.shape)
    return {"alpha": alpha, "qhat": qhat, "de": de, **lat}, cm


def _pool(sig: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    one = {k: v[i] for k, v in sig.items()}
    pool = candidate_pool(one, ["alpha", "qhat", "de"])  # 3 linear, 3 squares, 3 products
    pool.update(spline_terms(one["alpha"], [0.06, 0.1]))
    pool.update({k: one[k] for k in ("beta", "phat", "rhat", "da", "dr")})
    pool["alpha*beta"] = one["alpha"] * one["beta"]
    pool["alpha^3"] = one["alpha"] ** 3
    pool["alpha^2*de"] = one["alpha"] ** 2 * one["de"]
    pool["de^3"] = one["de"] ** 3
    return pool


def test_stepwise_finds_the_true_terms() -> None:
    sig, cm = _flights()
    found, kept = 0, {}
    for i in range(N_SEEDS):
        pool = _pool(sig, i)
        assert len(pool) == 20
        res = stepwise_regression(pool, cm[i], pool)
        found += set(TRUE_CM) <= set(res.selected)
        for term in res.selected:
            kept[term] = kept.get(term, 0) + 1
        if i == 0:
            for k, v in TRUE_CM.items():
                assert abs(res.parameters[k] - v) < 4 * res.stderr[k]
    assert found >= 95
    spurious = {k: c for k, c in kept.items() if k not in TRUE_CM}
    assert all(c <= 10 for c in spurious.values()), spurious


def test_stepwise_steps_and_orthogonal_option() -> None:
    sig, cm = _flights()
    pool = _pool(sig, 0)
    res = stepwise_regression(pool, cm[0], pool)
    assert res.steps[0].action == "start" and res.steps[0].n_terms == 1
    entered = [s.term for s in res.steps if s.action == "enter"]
    assert set(TRUE_CM) <= set(entered)
    pses = [s.pse for s in res.steps]
    assert all(b < a for a, b in itertools.pairwise(pses))  # each entry helps
    assert all(s.f_value > 4 for s in res.steps[1:] if s.action == "enter")
    assert res.regression.parameter_names[0] == "const"
    assert "| enter" in res.summary()
    assert len(res.plot().axes) == 3
    ortho = stepwise_regression(pool, cm[0], pool, orthogonalize=True)
    assert set(TRUE_CM) <= set(ortho.selected) and ortho.orthogonalized
    forced = stepwise_regression(pool, cm[0], pool, forced=["dr"])
    assert "dr" in forced.regression.parameter_names and "dr" not in forced.selected


def test_stepwise_removes_a_term_made_redundant() -> None:
    # x3 explains z on its own until x1 and x2, which make it up, are both in
    rng = np.random.default_rng(12)
    x1, x2 = rng.standard_normal(500), rng.standard_normal(500)
    x3 = x1 + x2 + 0.5 * rng.standard_normal(500)
    z = x1 + x2 + 0.05 * rng.standard_normal(500)
    res = stepwise_regression({"x1": x1, "x2": x2, "x3": x3}, z, {"x1": x1, "x2": x2, "x3": x3})
    actions = [(s.action, s.term) for s in res.steps]
    assert ("enter", "x3") in actions and ("remove", "x3") in actions
    assert set(res.selected) == {"x1", "x2"}
    removal = next(s for s in res.steps if s.action == "remove")
    assert removal.f_value < 4


def test_candidate_helpers() -> None:
    a = np.array([0.0, 0.05, 0.1, 0.2])
    s = spline_terms(a, [0.1], name="alpha")
    np.testing.assert_allclose(s["(alpha-0.1)+"], [0, 0, 0, 0.1], atol=1e-15)
    s2 = spline_terms(a, [0.05], degree=2)
    np.testing.assert_allclose(s2["(alpha-0.05)+^2"], [0, 0, 0.05**2, 0.15**2])
    pool = candidate_pool({"a": a, "b": 2 * a}, ["a", "b"], cubes=True, splines={"a": [0.1]})
    assert list(pool) == ["a", "b", "a^2", "b^2", "a*b", "a^3", "b^3", "(a-0.1)+"]
    np.testing.assert_allclose(pool["a*b"], 2 * a**2)


def test_stepwise_bad_input() -> None:
    x = {"a": np.arange(10.0), "b": np.arange(10.0) ** 2}
    with pytest.raises(DataFormatError, match="f_out"):
        stepwise_regression(x, np.ones(10), x, f_in=2, f_out=4)
    with pytest.raises(DataFormatError, match="forced"):
        stepwise_regression(x, np.ones(10), x, forced=["c"])
    z = np.random.default_rng(0).standard_normal(10)
    for options, match in [
        ({"f_in": "a"}, "f_in, f_out: need numbers"),
        ({"f_in": None}, "f_in, f_out: need numbers"),
        ({"f_in": "4"}, "f_in, f_out: need numbers"),  # text is not read as a number
        ({"f_out": "1"}, "f_in, f_out: need numbers"),
        ({"max_steps": 0}, "max_steps must be a positive integer, got 0"),
        ({"max_steps": 1.7}, "max_steps must be a positive integer, got 1.7"),
        ({"max_steps": "a"}, "max_steps"),
        ({"forced": 5}, "forced: expected candidate names"),
        ({"forced": ["a", "a"]}, "forced: 'a' is listed twice"),
        ({"orthogonalize": "no"}, "orthogonalize: expected True or False"),
    ]:
        with pytest.raises(DataFormatError, match=match):
            stepwise_regression(x, z, x, **options)


def test_candidate_pool_and_splines_bad_input() -> None:
    alpha = np.linspace(-0.1, 0.3, 50)
    data = {"alpha": alpha, "q": np.cos(alpha)}
    for call, match in [
        (lambda: spline_terms(alpha, [np.nan]), "knots of alpha: expected finite numbers"),
        (lambda: spline_terms(alpha, [-np.inf]), "knots of alpha: expected finite numbers"),
        (lambda: spline_terms(alpha, ["a"]), "knots of alpha"),
        (lambda: spline_terms(alpha, 0.1), "knots of alpha: expected a sequence"),
        (lambda: spline_terms(alpha, [0.05, 0.05]), "0.05 is given twice"),
        (lambda: spline_terms(alpha + 1j, [0.1]), "complex"),
        (lambda: spline_terms(alpha * 1e3, [0.1], degree=1000), "overflows"),
        (lambda: candidate_pool(data, 5), "variables: expected channel names"),
        (lambda: candidate_pool(data, [1, 2]), "variables: expected channel names"),
        (lambda: candidate_pool(data, ["alpha", "alpha"]), "'alpha' is listed twice"),
        (lambda: candidate_pool({}, ["alpha"]), "no channels"),
        (lambda: candidate_pool({**data, "q": data["q"][:-5]}, ["alpha", "q"]), r"data\['q'\]"),
        (lambda: candidate_pool({**data, "q": "hello"}, ["alpha", "q"]), r"data\['q'\]"),
        (lambda: candidate_pool(data, ["alpha"], splines={"alpha": [np.nan]}), "knots of alpha"),
        (lambda: candidate_pool(data, ["alpha"], splines=5), "splines: expected a mapping"),
    ]:
        with pytest.raises(DataFormatError, match=match):
            call()


def test_public_entry_points_limit_blas_threads():
    # wrapped by `small_blas`, as every numerical entry point of the library
    for fn in (equation_error, stepwise_regression):
        assert hasattr(fn, "__wrapped__"), fn.__name__


def _complex_problem(
    rng: np.random.Generator, m: int, r: int, p: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Random complex sensitivities W (m, r, p) and residuals e (m, r), and their real
    stacking (real parts, then imaginary parts) as the estimators pass them."""
    W = rng.standard_normal((m, r, p)) + 1j * rng.standard_normal((m, r, p))
    e = rng.standard_normal((m, r)) + 1j * rng.standard_normal((m, r))
    jac = np.concatenate([W.real, W.imag], axis=1)
    res = np.concatenate([e.real, e.imag], axis=1)
    return W, e, jac, res


def _corrected(
    jac: np.ndarray, res: np.ndarray, inv: np.ndarray, kappa: np.ndarray | None = None
) -> np.ndarray:
    """Each frequency's residual scaled by (1 - L)^-1/2, back to complex; with the
    transforms' correlation `kappa` (M, M), by the inverse root of the diagonal block of
    (I - H) K (I - H), formed densely (K: kappa as a complex product on each
    frequency's real and imaginary rows)."""
    m, rows, _ = jac.shape
    r = rows // 2
    if kappa is None:
        lev = np.einsum("mrn,nk,msk->mrs", jac, inv, jac)
        kept = np.eye(rows)[None] - 0.5 * (lev + lev.transpose(0, 2, 1))
    else:
        eye = np.eye(r)
        big = np.zeros((m * rows, m * rows))
        for j in range(m):
            for k in range(m):
                c = kappa[j, k]
                big[j * rows : (j + 1) * rows, k * rows : (k + 1) * rows] = np.block(
                    [[c.real * eye, -c.imag * eye], [c.imag * eye, c.real * eye]]
                )
        flat = jac.reshape(m * rows, -1)
        rest = np.eye(m * rows) - flat @ inv @ flat.T
        full = rest @ big @ rest
        kept = np.array(
            [full[k * rows : (k + 1) * rows, k * rows : (k + 1) * rows] for k in range(m)]
        )
    w, v = np.linalg.eigh(kept)
    u = np.einsum("mrs,ms,mts,mt->mr", v, 1.0 / np.sqrt(w), v, res)
    return np.asarray(u[:, :r] + 1j * u[:, r:])


def _neighbour_matrix(m: int) -> np.ndarray:
    """(m, m): frequency k's weights 0.3, 0.4, 0.3 on k - 1, k, k + 1, renormalised at
    the ends of the band."""
    wts = np.zeros((m, m))
    for k in range(m):
        idx = [j for j in (k - 1, k, k + 1) if 0 <= j < m]
        raw = np.array([0.4 if j == k else 0.3 for j in idx])
        wts[k, idx] = raw / raw.sum()
    return wts


def _smoothed(e: np.ndarray) -> np.ndarray:
    """Each frequency's cross-spectrum: the neighbours' mean of the outer products."""
    return np.asarray(np.einsum("kj,jr,js->krs", _neighbour_matrix(e.shape[0]), e, e.conj()))


def test_frequency_sandwich_is_the_smoothed_leverage_corrected_spectrum() -> None:
    # each frequency's cross-spectrum S_m from its leverage-corrected residuals and its
    # neighbours', half in each of its real and imaginary rows: B = sum 1/2 Re W^H S W
    from aeroid import _colour

    rng = np.random.default_rng(3)
    m, r, p = 40, 2, 3
    W, _, jac, res = _complex_problem(rng, m, r, p)
    inv = np.linalg.inv(np.einsum("mrp,mrq->pq", jac, jac))
    omega = 2 * np.pi / 10.0 * np.arange(3.0, 3.0 + m)  # the k/T grid of 10 s
    S = _smoothed(_corrected(jac, res, inv))
    meat = sum(0.5 * (W[k].conj().T @ S[k] @ W[k]).real for k in range(m))
    cov, nu = _colour.frequency_sandwich(jac, res, inv, omega, 10.0)
    np.testing.assert_allclose(cov, inv @ meat @ inv, rtol=1e-10)
    # the frequencies' order is their own, not the caller's
    perm = rng.permutation(m)
    again = _colour.frequency_sandwich(jac[perm], res[perm], inv, omega[perm], 10.0)
    np.testing.assert_allclose(again[0], cov, rtol=1e-10)
    np.testing.assert_allclose(again[1], nu, rtol=1e-10)
    # Satterthwaite: variance j is sum_k e_k^H A_k e_k, A_k = sum_m s_mk c_m c_m^H / 2
    # (c_m = W_m M^-1 e_j); a circular form's mean is tr(A S), its variance tr(ASAS),
    # both estimated with the smoothed S
    wts = _neighbour_matrix(m)
    c = np.einsum("mrp,pq->mrq", W, inv)
    for j in range(p):
        A = [sum(wts[mm, k] * 0.5 * np.outer(c[mm, :, j], c[mm, :, j].conj()) for mm in range(m))
             for k in range(m)]  # fmt: skip
        mean = sum(np.trace(A[k] @ S[k]).real for k in range(m))
        # less its estimate's own spread, 1 + sum s^2 (from E|e|^4 = 2 S^2), and the
        # spread of the mean's square (E[x^2] = mean^2 + var)
        q = np.sum(wts**2, axis=1)
        var = sum(np.trace(A[k] @ S[k] @ A[k] @ S[k]).real / (1 + q[k]) for k in range(m))
        np.testing.assert_allclose(nu[j], 2 * mean**2 / var - 2, rtol=1e-10)


def test_frequency_sandwich_degrees_of_freedom_count_the_frequencies_that_inform() -> None:
    # information spread evenly over m frequencies gives two degrees of freedom each
    # (real and imaginary parts); one frequency alone gives what it and its
    # neighbours hold, 2 / (0.3^2 + 0.4^2 + 0.3^2) over a flat spectrum
    from aeroid import _colour

    m = 200
    omega = 2 * np.pi / 50.0 * np.arange(1.0, 1.0 + m)
    jac = np.concatenate([np.ones((m, 1, 1)), np.zeros((m, 1, 1))], axis=1)
    inv = np.array([[1.0 / m]])
    nus = []
    for seed in range(50):
        res = np.random.default_rng(seed).standard_normal((m, 2))
        nus.append(_colour.frequency_sandwich(jac, res, inv, omega, 50.0)[1][0])
    assert 0.9 * 2 * m < np.median(nus) < 1.1 * 2 * m
    lone = np.zeros((m, 2, 1))
    lone[7] = 1.0  # sensitivity 1 + i
    flat = np.column_stack([np.ones(m), np.zeros(m)])
    _, nu = _colour.frequency_sandwich(lone, flat, np.array([[0.5]]), omega, 50.0)
    assert nu[0] == pytest.approx(2.0 / 0.34)


def test_frequency_sandwich_counts_a_real_transform_once() -> None:
    # at zero and Nyquist frequency the transform is real: its one row carries all of
    # the noise
    from aeroid import _colour

    rng = np.random.default_rng(4)
    m, p = 6, 2
    _, _, jac, res = _complex_problem(rng, m, 1, p)
    jac[[0, -1], 1], res[[0, -1], 1] = 0.0, 0.0
    omega = 2 * np.pi / 10.0 * np.arange(m)
    inv = np.linalg.inv(np.einsum("mrp,mrq->pq", jac, jac))
    S = _smoothed(_corrected(jac, res, inv))
    W = jac[:, 0] + 1j * jac[:, 1]
    f = np.array([1.0] + [0.5] * (m - 2) + [1.0])
    meat = sum(f[k] * S[k, 0, 0].real * np.outer(W[k].conj(), W[k]).real for k in range(m))
    nyquist = float(omega[-1])
    cov, _ = _colour.frequency_sandwich(jac, res, inv, omega, 10.0, nyquist=nyquist)
    np.testing.assert_allclose(cov, inv @ meat @ inv, rtol=1e-10)


@pytest.mark.parametrize("block", [2_000_000, 50])
def test_frequency_sandwich_off_the_grid_adds_each_pairs_covariance(
    block: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # off the k/T grid the transforms share the noise: the meat gains, for each pair
    # j != k, 1/2 Re W_j^H kappa_jk S_jk W_k with S_jk the mean of the two smoothed
    # cross-spectra, and the fit's share of each residual is that of the shared noise
    from aeroid import _colour, _record_kernel

    monkeypatch.setattr(_record_kernel, "_KERNEL_BLOCK", block)  # one block, or one row each
    rng = np.random.default_rng(8)
    m, r, p = 12, 2, 3
    W, _, jac, res = _complex_problem(rng, m, r, p)
    inv = np.linalg.inv(np.einsum("mrp,mrq->pq", jac, jac))
    omega = np.linspace(1.0, 3.0, m)
    half = 0.5 * (omega[:, None] - omega[None, :]) * 4.0
    kappa = np.exp(-1j * half) * np.sinc(half / np.pi)
    S = _smoothed(_corrected(jac, res, inv, kappa))
    meat = np.zeros((p, p))
    for j in range(m):
        for k in range(m):
            s_jk = S[j] if j == k else 0.5 * (S[j] + S[k])
            meat += 0.5 * (W[j].conj().T @ (kappa[j, k] * s_jk) @ W[k]).real
    meat = 0.5 * (meat + meat.T)
    cov, nu = _colour.frequency_sandwich(jac, res, inv, omega, 4.0)
    np.testing.assert_allclose(cov, inv @ meat @ inv, rtol=1e-10, atol=1e-14)
    # shared noise leaves fewer degrees of freedom than the same frequencies on a grid
    spread = 2 * np.pi / 4.0 * np.arange(3.0, 3.0 + m)
    assert np.all(nu < _colour.frequency_sandwich(jac, res, inv, spread, 4.0)[1])


def test_absolute_values_of_channels_as_regressors() -> None:
    # a V-shaped response (sideslip drag, 0.17 |beta|): stepwise selection over a pool
    # with squares and absolute values takes |beta|, not beta^2, and equation error
    # recovers its slope within three standard errors; over seeds
    taken, inside = 0, 0
    n_seeds = 20
    for seed in range(n_seeds):
        rng = np.random.default_rng(seed)
        beta = 0.1 * np.sin(np.linspace(0.0, 6 * np.pi, 400)) + 0.02 * rng.standard_normal(400)
        alpha = 0.05 + 0.02 * rng.standard_normal(400)
        cd = 0.03 + 0.17 * np.abs(beta) + 0.3 * alpha + 0.002 * rng.standard_normal(400)
        data = {"beta": beta, "alpha": alpha}
        pool = candidate_pool(data, ["beta", "alpha"], absolutes=["beta"])
        assert list(pool)[-2:] == ["abs(beta)", "abs(beta)*alpha"]
        res = stepwise_regression({**data, "cd": cd}, "cd", list(pool))
        taken += "abs(beta)" in res.selected and "beta^2" not in res.selected
        fit = equation_error({**data, "cd": cd}, "cd", ["abs(beta)", "alpha"], error_bars="white")
        inside += abs(fit.parameters["abs(beta)"] - 0.17) < 3 * fit.stderr["abs(beta)"]
    assert taken == n_seeds
    # 3 sigma: a miss in 0.27 % of seeds, two or more in 20 seeds at 0.1 %
    assert inside >= n_seeds - 1
    np.testing.assert_array_equal(pool["abs(beta)*alpha"], np.abs(beta) * alpha)
    fit = equation_error({**data, "cd": cd}, "cd", ["abs(beta)*alpha"], error_bars="white")
    assert "abs(beta)*alpha" in fit.parameters
    with pytest.raises(ChannelError, match="'abs\\(gamma\\)' takes the absolute value of 'gamma'"):
        equation_error({**data, "cd": cd}, "cd", ["abs(gamma)"])
    with pytest.raises(DataFormatError, match="cannot parse 'abs\\(beta'"):
        equation_error({**data, "cd": cd}, "cd", ["abs(beta"])
    with pytest.raises(DataFormatError, match="absolutes: \\['gamma'\\] are not among"):
        candidate_pool(data, ["beta", "alpha"], absolutes=["gamma"])
    assert list(candidate_pool(data, ["beta"], absolutes=True, squares=False)) == [
        "beta",
        "abs(beta)",
    ]


def test_a_dangling_power_and_a_name_for_a_level_are_refused() -> None:
    rng = np.random.default_rng(0)
    data = FlightData(np.arange(50) * 0.1, {"z": rng.normal(size=50), "a": rng.normal(size=50)})
    for expr in ("a**", "a^"):
        with pytest.raises(DataFormatError, match="cannot parse 'a\\^'"):
            equation_error(data, "z", [expr])
    fit = equation_error(data, "z", ["a"])
    with pytest.raises(IdentificationError, match="level must lie strictly between 0 and 1"):
        fit.interval("a")  # type: ignore[arg-type]


def test_sample_counts_and_frequencies_are_checked_before_anything_else() -> None:
    """Found by an independent suite: no samples ended stepwise regression in a
    ZeroDivisionError, one sample was blamed on a "constant" regressor, a repeated
    frequency counted as new equations (an exact fit with 4e-16 error bars), and
    frequencies given to a time-domain fit were dropped in silence."""
    rng = np.random.default_rng(0)
    d = {"a": rng.standard_normal(100), "q": rng.standard_normal(100)}
    d["z"] = 1.0 + d["a"] - 2.0 * d["q"]
    with pytest.raises(IdentificationError, match="0 samples"):
        stepwise_regression({"a": np.zeros(0), "z": np.zeros(0)}, "z", ["a"])
    with pytest.raises(IdentificationError, match="1 samples cannot fit 3 parameters"):
        equation_error({k: v[:1] for k, v in d.items()}, "z", ["a", "q"])
    with pytest.raises(DataFormatError, match="repeated"):
        equation_error(d, "z", ["a", "q"], domain="frequency", frequencies=[0.3] * 3, dt=0.1)
    with pytest.raises(DataFormatError, match="frequencies: used with domain='frequency'"):
        equation_error(d, "z", ["a", "q"], frequencies=[0.1, 0.2], dt=0.1)


def test_a_dataframe_is_read_by_its_column_names():
    # a table's columns carry names: asked for in another order they must not be
    # relabelled by position (before: x1 and x2 swapped, success reported)
    pd = pytest.importorskip("pandas")
    rng = np.random.default_rng(0)
    x1, x2 = rng.normal(size=200), rng.normal(size=200)
    z = 1.0 + 2.0 * x1 - 5.0 * x2 + 0.1 * rng.normal(size=200)
    frame = pd.DataFrame({"x1": x1, "x2": x2, "z": z})
    truth = aeroid.equation_error({"x1": x1, "x2": x2, "z": z}, "z", ["x2", "x1"])
    for fit in (
        aeroid.equation_error(frame, "z", ["x2", "x1"]),
        aeroid.equation_error(frame, z, ["x2", "x1"]),
        aeroid.equation_error(frame, "z"),
        aeroid.stepwise_regression(frame, "z", ["x2", "x1"]),
    ):
        assert fit.parameters["x1"] == pytest.approx(truth.parameters["x1"], rel=1e-12)
        assert fit.parameters["x2"] == pytest.approx(truth.parameters["x2"], rel=1e-12)
    rls = aeroid.recursive_least_squares(frame, "z", ["x2", "x1"])
    assert rls.parameters["x1"] == pytest.approx(2.0, abs=0.05)
    assert rls.parameters["x2"] == pytest.approx(-5.0, abs=0.05)
    with pytest.raises(aeroid.DataFormatError, match="columns"):
        aeroid.equation_error(pd.DataFrame([[1.0, 2.0]] * 5, columns=["a", "a"]), "a")
