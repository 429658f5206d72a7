"""validate: Ljung–Box against its closed form, bias intervals, fit, input correlation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from aeroid import FlightData, IdentificationError, Model, identify, validate
from aeroid.models import catalog
from aeroid.uncertainty.validation import ljung_box


def test_ljung_box_closed_form():
    x = np.array([1.0, -1.0, 1.0, -1.0])
    # mean 0, r1 = -3/4, r2 = 2/4: Q = N(N+2)(r1^2/(N-1) + r2^2/(N-2))
    q, p = ljung_box(x, 2)
    expected = 4 * 6 * (0.75**2 / 3 + 0.5**2 / 2)
    assert q == pytest.approx(expected, rel=1e-12)
    assert p == pytest.approx(scipy.stats.chi2.sf(expected, 2), rel=1e-12)


def test_exact_model_fits_100_percent(sp_clean):
    v = validate(catalog.short_period(catalog.SHORT_PERIOD_TRUTH), sp_clean, None)
    for m in v.metrics.values():
        assert m.fit == pytest.approx(100.0, abs=1e-4) and m.rmse < 1e-8
    assert "| alpha" in v.summary()


def test_whiteness_false_alarm_rate_is_nominal():
    # White residuals: Ljung–Box rejects at 5 %. Over 200 series the rejection count
    # is Binomial(200, 0.05): mean 10, sd 3.1; accept 2..22 (about ±2.6 sd).
    rng = np.random.default_rng(0)
    rejections = sum(ljung_box(rng.standard_normal(500), 20)[1] < 0.05 for _ in range(200))
    assert 2 <= rejections <= 22
    ar = np.zeros(500)
    e = rng.standard_normal(500)
    for k in range(1, 500):
        ar[k] = 0.8 * ar[k - 1] + e[k]
    assert ljung_box(ar, 20)[1] < 1e-6


def test_bias_interval_coverage_with_coloured_residuals():
    # Residual = constant bias + AR(1) noise; the interval uses an effective sample
    # size, so it should cover the bias in ~95 % of 200 seeds (binomial sd 1.5 %).
    model = catalog.short_period(catalog.SHORT_PERIOD_TRUTH)
    hits = 0
    for s in range(200):
        noisy = catalog.short_period_flight(seed=s, colored=0.7)
        d = noisy.with_channels({"q": noisy["q"] + 0.003})
        lo, hi = validate(model, d, None).metrics["q"].bias_ci
        hits += lo <= 0.003 <= hi
    assert 0.90 <= hits / 200 <= 0.99


def test_bias_interval_holds_when_the_record_is_a_few_samples_worth():
    # AR(1) phi = 0.97 over 501 samples: about 8 effective samples, so the interval needs
    # Student's t on their degrees of freedom and the variance the mean did not take
    # (with z and the plain sample variance it covered 0.900 of these 400 records)
    model = Model(["y"], ["u"], {"k": 1.0}, lambda t, x, u, p: np.array([0.0 * x[0]]))
    n, hits = 501, 0
    for seed in range(400):
        rng = np.random.default_rng(seed)
        w = rng.standard_normal(n)
        e = np.empty(n)
        e[0] = w[0] / np.sqrt(1.0 - 0.97**2)
        for k in range(1, n):
            e[k] = 0.97 * e[k - 1] + w[k]
        d = FlightData(np.arange(n) * 0.02, {"y": e, "u": np.zeros(n)})
        lo, hi = validate(model, d, {"k": 1.0}, x0=[0.0]).metrics["y"].bias_ci
        hits += lo <= 0.0 <= hi
    # binomial sd of a 95 % coverage over 400 records: 1.1 %; +-3 of it
    assert 0.917 <= hits / 400 <= 0.983, hits / 400


def test_wrong_model_shows_input_correlation_and_colour(sp_noisy):
    wrong = catalog.short_period({**catalog.SHORT_PERIOD_TRUTH, "M_delta": -5.0})
    v = validate(wrong, sp_noisy, None)
    assert v.metrics["q"].input_correlated and not v.metrics["q"].white
    right = validate(catalog.short_period(catalog.SHORT_PERIOD_TRUTH), sp_noisy, None)
    assert not right.metrics["q"].input_correlated


def test_accepts_identification_result_with_biases(sp_model):
    noisy = catalog.short_period_flight(seed=2)
    d = noisy.with_channels({"alpha": noisy["alpha"] + 0.02})
    r = identify(sp_model, d, list(catalog.SHORT_PERIOD_TRUTH), estimate_bias=["alpha"])
    v = validate(sp_model, d, r)
    assert abs(v.metrics["alpha"].bias) < 1e-3
    assert v.residuals.shape == (d.n_samples, 2) and not v.residuals.flags.writeable


def test_argument_errors(sp_model, sp_noisy):
    with pytest.raises(IdentificationError, match="confidence"):
        validate(sp_model, sp_noisy, None, confidence=1.5)
    with pytest.raises(IdentificationError, match="not a parameter"):
        validate(sp_model, sp_noisy, {"nope": 1.0})
    with pytest.raises(IdentificationError, match="'beta' is not an output"):
        validate(sp_model, sp_noisy, None, outputs=["beta"])
    with pytest.raises(Exception, match="control 'elevator'"):
        validate(sp_model, FlightData(sp_noisy.time, {"q": sp_noisy["q"]}), None)


@pytest.mark.slow
def test_a_correct_model_fitted_with_its_initial_state_is_white_at_the_nominal_rate():
    # The truth model on white noise: each output passes Ljung-Box at 5 %, so both pass
    # in 0.95^2 = 90.25 % of flights. Over 150 flights the binomial sd is 2.4 %; the bound
    # sits 3 sd below. Started from the first noisy sample instead of the estimated state,
    # the model's transient away from the true trajectory colours the residuals more often.
    model = catalog.short_period()
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    n = 150
    white = {False: 0, True: 0}
    for seed in range(n):
        data = catalog.short_period_flight(seed=seed)
        for estimate in (False, True):
            fit = identify(model, data, names, estimate_x0=estimate)
            v = validate(model, data, fit)
            white[estimate] += all(m.white for m in v.metrics.values())
    assert white[True] / n >= 0.9025 - 3 * np.sqrt(0.9025 * 0.0975 / n)
    assert white[False] < white[True]


def _flight_from(x0: dict[str, float], seed: int) -> FlightData:
    # the truth model flown from a non-zero initial state, with the usual sensor noise
    model = catalog.short_period(catalog.SHORT_PERIOD_TRUTH)
    t = np.arange(501) / 50.0
    u = catalog.doublet(t)
    sim = model.simulate(t, u, x0, method="exact")
    rng = np.random.default_rng(seed)
    return FlightData(
        t,
        {
            "elevator": u,
            "alpha": sim.output("alpha") + 0.005 * rng.standard_normal(t.size),
            "q": sim.output("q") + 0.01 * rng.standard_normal(t.size),
        },
    )


def test_validation_starts_where_the_fit_did_on_its_own_record_only():
    model = catalog.short_period()
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    fitted = catalog.short_period_flight(seed=1)
    fit = identify(model, fitted, names, estimate_x0=True, estimate_bias=True)
    x0, bias = dict(fit.initial_states[0]), dict(fit.biases[0])
    own = validate(model, fitted, fit)
    np.testing.assert_array_equal(
        own.simulated[0], [x0["alpha"] + bias["alpha"], x0["q"] + bias["q"]]
    )
    # another manoeuvre, flown from alpha = 0.05 rad: predicted from its own measured start,
    # without the biases estimated for the fitted record
    other = _flight_from({"alpha": 0.05, "q": 0.0}, seed=2)
    v = validate(model, other, fit)
    np.testing.assert_array_equal(v.simulated[0], other.array(["alpha", "q"])[0])
    assert v.metrics["alpha"].rmse < 1.5 * 0.005 and v.metrics["q"].rmse < 1.5 * 0.01
    # started where the fit started its own record, the prediction misses by the offset
    wrong = validate(model, other, fit, x0=x0)
    assert wrong.metrics["alpha"].rmse > 1.5 * v.metrics["alpha"].rmse
    assert v.metrics["alpha"].white and not wrong.metrics["alpha"].white
    # a result stored before records were fingerprinted applies its first manoeuvre's values
    import dataclasses

    old = dataclasses.replace(fit, data_fingerprints=())
    shifted = wrong.simulated + np.array([bias["alpha"], bias["q"]])
    np.testing.assert_array_equal(validate(model, other, old).simulated, shifted)


def test_whiteness_lags_must_be_an_integer_and_is_clamped_to_the_record(sp_model):
    data = catalog.short_period_flight(duration=5.0, sample_rate=20.0, seed=0)  # 101 samples
    with pytest.warns(UserWarning, match=r"whiteness_lags=10000 is beyond .* 101 .*using 99 lags"):
        assert validate(sp_model, data, None, whiteness_lags=10000).whiteness_lags == 99
    with pytest.raises(
        IdentificationError, match=r"whiteness_lags must be a positive integer, got 2\.5"
    ):
        validate(sp_model, data, None, whiteness_lags=2.5)
    with pytest.warns(UserWarning, match=r"whiteness_lags=100 is beyond .*using 99 lags"):
        assert validate(sp_model, data, None, whiteness_lags=100).whiteness_lags == 99
    # the default adapts to a short record instead of failing on it
    short = FlightData(data.time[:12], {k: v[:12] for k, v in data.channels.items()})
    assert validate(sp_model, short, None).whiteness_lags == 10
    assert validate(sp_model, data, None).whiteness_lags == 20


@pytest.mark.parametrize("model", [None, "short_period"])
def test_a_model_is_required(sp_noisy, model):
    with pytest.raises(IdentificationError, match=r"model: expected an aeroid\.Model"):
        validate(model, sp_noisy, None)


def test_whiteness_lags_beyond_the_record_are_clamped_loudly_and_match_the_largest_allowed(
    sp_model,
):
    import warnings

    data = catalog.short_period_flight(duration=2.0, sample_rate=20.0, seed=3)  # 41 samples
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the largest allowed lag count is taken silently
        exact = validate(sp_model, data, None, whiteness_lags=39)
    with pytest.warns(UserWarning, match=r"whiteness_lags=500 is beyond the record's 41 samples"):
        clamped = validate(sp_model, data, None, whiteness_lags=500)
    assert clamped.whiteness_lags == exact.whiteness_lags == 39
    for name, m in clamped.metrics.items():
        assert m.ljung_box_q == exact.metrics[name].ljung_box_q
        assert m.ljung_box_p == exact.metrics[name].ljung_box_p


def test_ljung_box_p_value_matches_scipy_for_odd_and_even_lags():
    rng = np.random.default_rng(11)
    x = rng.standard_normal(300)
    for lags in (1, 2, 7, 20, 51):
        q, p = ljung_box(x, lags)
        assert p == pytest.approx(scipy.stats.chi2.sf(q, lags), rel=1e-12)


# -- input audit ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"confidence": "0.9"}, "confidence"),
        ({"outputs": []}, "outputs"),
        ({"simulate_options": {"zz": 1}}, "simulate_options"),
        ({"simulate_options": [1]}, "simulate_options"),
        ({"simulate_options": {"method": "RK45", "rtol": -1.0}}, r"simulate_options\['rtol'\]"),
    ],
)
def test_validate_refuses_bad_options(kwargs, culprit):
    with pytest.raises(IdentificationError, match=culprit):
        validate(catalog.short_period(), catalog.short_period_flight(seed=0), **kwargs)


def test_validate_refuses_two_sample_record():
    data = catalog.short_period_flight(seed=0).window(0.0, 0.02)
    with pytest.raises(IdentificationError, match="data: validation needs at least 3 samples"):
        validate(catalog.short_period(), data)


def test_validate_outputs_as_one_name():
    model, data = catalog.short_period(), catalog.short_period_flight(seed=0)
    assert validate(model, data, outputs="q").output_names == ("q",)


def _ar1_noise(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    w = rng.standard_normal(n)
    e = np.empty(n)
    e[0] = w[0]
    for k in range(1, n):
        e[k] = phi * e[k - 1] + np.sqrt(1.0 - phi**2) * w[k]
    return e


def _input_correlated_count(phi: float, gain: float, seeds: int) -> int:
    # the exact model y = a u flown with a 2 s doublet at 50 Hz; the residual is
    # gain * (input 5 samples earlier) + 0.05 * AR(1) noise independent of the input
    def h(t, x, u, p):
        return np.array([p["a"] * u[0]])

    from aeroid import Model

    m = Model(states=[], controls=["u"], parameters={"a": 1.0}, outputs=["y"], measurement=h)
    t = np.arange(1000) * 0.02
    u = catalog.doublet(t, start=2.0, width=2.0, amplitude=1.0)
    lagged = np.concatenate([np.zeros(5), u[:-5]])
    hits = 0
    for s in range(seeds):
        e = gain * lagged + 0.05 * _ar1_noise(np.random.default_rng(s), t.size, phi)
        v = validate(m, FlightData(t, {"u": u, "y": u + e}), {"a": 1.0})
        hits += v.metrics["y"].input_correlated
    return hits


def test_input_correlation_false_alarm_rate_with_coloured_residuals():
    # Residuals independent of the input: the bound is a 5 % test, so over 200 seeds the
    # count is at most Binomial(200, 0.05): mean 10, sd 3.1; allow 3 sd above. Before
    # the residuals were prewhitened, AR(1) 0.9 residuals against a doublet were flagged
    # in 151 of 200 seeds (Bartlett: the cross-correlation's variance is then ~19/N).
    limit = 200 * 0.05 + 3 * np.sqrt(200 * 0.05 * 0.95)
    assert _input_correlated_count(0.9, 0.0, 200) <= limit
    assert _input_correlated_count(0.0, 0.0, 200) <= limit


def test_input_correlation_still_flags_a_true_relation_in_coloured_residuals():
    # residual = 0.3 * lagged input + AR(1) 0.9 noise, or white noise: flagged every time
    assert _input_correlated_count(0.9, 0.3, 20) == 20
    assert _input_correlated_count(0.0, 0.3, 20) == 20
