"""Output-error identification: truth recovery, traps, options and error paths."""

from __future__ import annotations

import warnings
from types import MappingProxyType

import numpy as np
import pytest

import aeroid
from aeroid import (
    ChannelError,
    FlightData,
    IdentifiabilityWarning,
    IdentificationError,
    Model,
    identify,
)
from aeroid.models import catalog

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = catalog.SHORT_PERIOD_TRUTH


def test_noise_free_recovery(sp_model, sp_clean):
    r = identify(sp_model, sp_clean, NAMES)
    assert r.success and r.identifiable and r.method == "output_error"
    for n in NAMES:
        assert r.parameters[n] == pytest.approx(TRUTH[n], rel=1e-4)


def test_noisy_recovery_within_3_sigma_and_5_percent(sp_model, sp_noisy):
    r = identify(sp_model, sp_noisy, NAMES)
    for n in NAMES:
        assert abs(r.parameters[n] - TRUTH[n]) < 3 * r.stderr[n]
        assert r.parameters[n] == pytest.approx(TRUTH[n], rel=0.05)
    # the noise covariance is estimated from the residuals (maximum likelihood)
    np.testing.assert_allclose(np.sqrt(np.diag(r.noise_covariance)), [0.005, 0.01], rtol=0.1)
    assert r.covariance.shape == (4, 4) and not r.covariance.flags.writeable
    np.testing.assert_allclose(np.diag(r.correlation), 1.0)
    assert "| Z_alpha" in r.summary() and "Standard errors" in r.summary()


def _scaled_model():
    def dyn(t, x, u, p):
        alpha, q = x[0], x[1]
        return np.array(
            [
                p["Z_alpha"] * alpha + q,
                p["M_alpha"] * alpha + p["M_q"] * q + 1000.0 * p["M_delta_k"] * u[0],
            ]
        )

    guess = dict(catalog.SHORT_PERIOD_GUESS)
    guess["M_delta_k"] = guess.pop("M_delta") / 1000.0
    return Model(["alpha", "q"], ["elevator"], guess, dyn)


def test_reparameterisation_by_1000_changes_nothing(sp_model, sp_noisy):
    base = identify(sp_model, sp_noisy, NAMES)
    scaled = identify(_scaled_model(), sp_noisy, ["Z_alpha", "M_alpha", "M_q", "M_delta_k"])
    for n in ["Z_alpha", "M_alpha", "M_q"]:
        assert scaled.parameters[n] == pytest.approx(base.parameters[n], rel=1e-4)
        assert scaled.stderr[n] == pytest.approx(base.stderr[n], rel=1e-4)
    assert 1000 * scaled.parameters["M_delta_k"] == pytest.approx(
        base.parameters["M_delta"], rel=1e-4
    )
    assert 1000 * scaled.stderr["M_delta_k"] == pytest.approx(base.stderr["M_delta"], rel=1e-4)


def test_parameter_starting_at_zero_is_estimated():
    # Trap 12b: a pitching-moment offset M_0 whose guess is exactly 0.0.
    def dyn(t, x, u, p):
        alpha, q = x[0], x[1]
        return np.array(
            [
                p["Z_alpha"] * alpha + q,
                p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0] + p["M_0"],
            ]
        )

    truth = {**TRUTH, "M_0": 0.02}
    m_true = Model(["alpha", "q"], ["elevator"], truth, dyn)
    t = np.arange(0, 10.0001, 0.02)
    u = catalog.doublet(t)
    data = m_true.simulate(t, u, method="exact").to_flight_data()
    guess = Model(["alpha", "q"], ["elevator"], {**catalog.SHORT_PERIOD_GUESS, "M_0": 0.0}, dyn)
    r = identify(guess, data, [*NAMES, "M_0"])
    assert r.success
    assert r.parameters["M_0"] == pytest.approx(0.02, rel=1e-4)


def test_iteration_limit_flags_instead_of_raising(sp_model, sp_noisy):
    # Trap 12e: the partial fit is returned, flagged, with a warning.
    with pytest.warns(UserWarning, match="iteration limit"):
        r = identify(sp_model, sp_noisy, NAMES, max_iterations=1)
    assert r.success is False and r.n_iterations == 1
    assert "Not converged" in r.summary()


@pytest.mark.parametrize("method", ["output_error", "filter_error"])
def test_converging_on_the_last_allowed_iteration_is_success(sp_model, sp_noisy, method):
    # the free fit converges after n iterations; a limit of n reaches the same point
    # (same cost to the bit) and is converged too, a limit of n - 1 is flagged
    kw = {} if method == "output_error" else {"process_noise": {"alpha": 0.0, "q": 1e-4}}
    free = identify(sp_model, sp_noisy, NAMES, method=method, **kw)
    n = free.n_iterations
    assert free.success and n > 1
    capped = identify(sp_model, sp_noisy, NAMES, method=method, max_iterations=n, **kw)
    assert capped.success and capped.message == free.message == f"converged after {n} iterations"
    assert capped.cost == free.cost and capped.parameters == free.parameters
    with pytest.warns(UserWarning, match="iteration limit"):
        short = identify(sp_model, sp_noisy, NAMES, method=method, max_iterations=n - 1, **kw)
    assert not short.success


def test_unidentifiable_sum_warns_and_flags(sp_noisy):
    def dyn(t, x, u, p):
        alpha, q = x[0], x[1]
        return np.array(
            [
                p["Z_alpha"] * alpha + q,
                (p["Ma1"] + p["Ma2"]) * alpha + p["M_q"] * q + p["M_delta"] * u[0],
            ]
        )

    m = Model(
        ["alpha", "q"], ["elevator"], {**catalog.SHORT_PERIOD_GUESS, "Ma1": -2.0, "Ma2": -2.0}, dyn
    )
    with pytest.warns(IdentifiabilityWarning, match="Ma1 \\+ Ma2"):
        r = identify(m, sp_noisy, ["Z_alpha", "Ma1", "Ma2", "M_q", "M_delta"])
    assert r.identifiable is False
    assert ("Ma1", "Ma2") in r.unidentifiable
    assert np.isinf(r.stderr["Ma1"]) and np.isfinite(r.stderr["M_q"])
    assert "Not identifiable" in r.summary()


def test_initial_state_and_bias_estimation():
    model = catalog.short_period(TRUTH)
    t = np.arange(0, 8.0001, 0.02)
    u = catalog.doublet(t)
    sim = model.simulate(t, u, {"alpha": 0.03, "q": -0.02}, method="exact")
    data = FlightData(t, {"elevator": u, "alpha": sim.output("alpha") + 0.01, "q": sim.output("q")})
    r = identify(
        catalog.short_period(),
        data,
        NAMES,
        x0={"alpha": 0.0, "q": 0.0},
        estimate_x0=True,
        estimate_bias=["alpha"],
    )
    assert r.initial_states[0]["alpha"] == pytest.approx(0.03, rel=1e-4)
    assert r.initial_states[0]["q"] == pytest.approx(-0.02, rel=1e-4)
    assert r.biases[0]["alpha"] == pytest.approx(0.01, rel=1e-4)
    for n in NAMES:
        assert r.parameters[n] == pytest.approx(TRUTH[n], rel=1e-4)
    assert set(r.extra_stderr) == {"x0[0].alpha", "x0[0].q", "bias[0].alpha"}


def test_several_manoeuvres_share_parameters():
    model = catalog.short_period(TRUTH)
    datas = []
    for i, (start, amp, x0q) in enumerate([(1.0, 0.05, 0.0), (0.5, -0.03, 0.05)]):
        t = np.arange(0, 6.0001, 0.02)
        u = catalog.doublet(t, start=start, amplitude=amp)
        sim = model.simulate(t, u, {"alpha": 0.0, "q": x0q}, method="exact")
        noisy = sim.to_flight_data(noise={"alpha": 0.005, "q": 0.01}, seed=10 + i)
        datas.append(noisy.with_channels({"q": noisy["q"] + 0.02 * i}))
    r = identify(catalog.short_period(), datas, NAMES, estimate_x0=["q"], estimate_bias=["q"])
    assert len(r.initial_states) == 2 and len(r.biases) == 2
    for n in NAMES:
        assert abs(r.parameters[n] - TRUTH[n]) < 3 * r.stderr[n]
    assert abs(r.biases[1]["q"] - r.biases[0]["q"] - 0.02) < 3 * np.hypot(
        r.extra_stderr["bias[0].q"], r.extra_stderr["bias[1].q"]
    )


def test_fixed_weights_and_white_error_bars(sp_model, sp_noisy):
    free = identify(sp_model, sp_noisy, NAMES)
    w = identify(sp_model, sp_noisy, NAMES, weights={"alpha": 1 / 0.005**2, "q": 1 / 0.01**2})
    for n in NAMES:
        assert w.parameters[n] == pytest.approx(free.parameters[n], rel=0.02)
    white = identify(sp_model, sp_noisy, NAMES, error_bars="white")
    assert white.error_bars == "white"
    np.testing.assert_allclose(white.covariance, white.covariance_white)


def test_colored_residuals_widen_the_bars(sp_model):
    data = catalog.short_period_flight(seed=3, colored=0.9)
    r = identify(sp_model, data, NAMES)
    assert r.error_bars == "colored"
    for n in NAMES:
        assert r.stderr[n] > 1.5 * r.stderr_white[n]


def test_crb_matches_monte_carlo_scatter(sp_model):
    # The classical bound against the scatter of 40 seeded fits: with 40 samples the
    # sample standard deviation is within about ±2.5 * (1/sqrt(80)) = ±28 % at 99 %.
    est = []
    for s in range(40):
        est.append(
            list(
                identify(
                    sp_model, catalog.short_period_flight(seed=100 + s), NAMES
                ).parameters.values()
            )
        )
    r = identify(sp_model, catalog.short_period_flight(seed=99), NAMES, error_bars="white")
    np.testing.assert_allclose(np.std(est, axis=0, ddof=1), list(r.stderr.values()), rtol=0.3)


def test_simulator_model_is_fitted_by_looping():
    class Stepped:
        """A stand-in black box around the truth model (no simulate_batch)."""

        name = "stepped"
        controls = ("elevator",)
        outputs = ("alpha", "q")

        def __init__(self):
            self._m = catalog.short_period({**TRUTH, "M_alpha": -4.0, "M_delta": -6.0})
            self.parameters = dict(self._m.parameters)

        def simulate(self, time, controls=None, x0=None, parameters=None, **options):
            return self._m.simulate(time, controls, x0, parameters, method="exact")

        def simulate_data(self, data, *, x0=None, parameters=None, **options):
            return self._m.simulate_data(data, x0=x0, parameters=parameters, method="exact")

    sim = Stepped()
    assert isinstance(sim, aeroid.SimulatorModel)
    r = identify(sim, catalog.short_period_flight(noise={}), ["M_alpha", "M_delta"])
    assert r.parameters["M_alpha"] == pytest.approx(-6.0, rel=1e-3)
    with pytest.raises(IdentificationError, match="continuous dynamics"):
        identify(
            sim,
            catalog.short_period_flight(noise={}),
            ["M_alpha"],
            method="filter_error",
            process_noise={"q": 1e-4},
        )
    # it exposes no states: asking for its initial states to be estimated was ignored
    with pytest.raises(IdentificationError, match="estimate_x0: a SimulatorModel starts"):
        identify(sim, catalog.short_period_flight(noise={}), ["M_alpha"], estimate_x0=True)
    r2 = identify(sim, catalog.short_period_flight(noise={}), ["M_alpha"], estimate_x0=[])
    assert r2.initial_states == ({},)


@pytest.mark.parametrize(
    ("kwargs", "error", "fragment"),
    [
        ({"parameters": ["M_beta"]}, IdentificationError, "'M_beta' is not a parameter"),
        ({"parameters": []}, IdentificationError, "at least one"),
        ({"parameters": {"M_q": float("nan")}}, IdentificationError, "not finite"),
        ({"method": "equation_error"}, IdentificationError, "unknown"),
        ({"gradient": "magic"}, IdentificationError, "unknown"),
        ({"error_bars": "pink"}, IdentificationError, "unknown"),
        ({"outputs": ["beta"]}, IdentificationError, "'beta' is not one of"),
        ({"simulate_options": {"step": 1}}, IdentificationError, "unknown keys"),
        (
            {"method": "filter_error", "weights": {"q": 1.0}},
            IdentificationError,
            "measurement_noise",
        ),
        ({"process_noise": {"q": 1.0}}, IdentificationError, "filter_error' only"),
        ({"weights": {"alpha": 1.0, "q": -1.0}}, IdentificationError, "positive"),
        ({"estimate_x0": ["theta"]}, IdentificationError, "'theta' is not one of"),
    ],
)
def test_argument_errors(sp_model, sp_noisy, kwargs, error, fragment):
    kw = {"parameters": NAMES, **kwargs}
    params = kw.pop("parameters")
    with pytest.raises(error, match=fragment):
        identify(sp_model, sp_noisy, params, **kw)


def test_missing_channel_names_it(sp_model, sp_noisy):
    data = FlightData(sp_noisy.time, {"alpha": sp_noisy["alpha"], "q": sp_noisy["q"]})
    with pytest.raises(ChannelError, match="control 'elevator'"):
        identify(sp_model, data, NAMES)


def test_diverging_start_is_an_identification_error(sp_noisy):
    m = catalog.short_period({**catalog.SHORT_PERIOD_GUESS, "M_q": 400.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(IdentificationError, match="cannot be simulated at the initial"):
            identify(m, sp_noisy, NAMES, simulate_options={"method": "rk4"})


def test_parameter_sets_are_plain_read_only_dicts(sp_model, sp_noisy):
    # the convention: plain dict[str, float] at every user boundary, immutable inside records
    import copy
    import json
    import pickle

    r = identify(sp_model, sp_noisy, ["M_q", "M_alpha"])
    for p in (r.parameters, r.stderr, r.stderr_white, r.all_parameters, sp_model.parameters):
        assert isinstance(p, dict)
        assert json.loads(json.dumps(p)) == p
        assert pickle.loads(pickle.dumps(p)) == p and copy.deepcopy(p) == p
        for change in (
            lambda p: p.__setitem__("M_q", 0.0),
            lambda p: p.update(M_q=0.0),
            lambda p: p.pop("M_q"),
            lambda p: p.clear(),
        ):
            with pytest.raises(TypeError, match="frozen"):
                change(p)
        mine = dict(p)  # a copy is an ordinary dict
        mine["M_q"] = 0.0
    assert r.parameters["M_q"] != 0.0
    assert {**r.parameters, "M_q": 1.0}["M_q"] == 1.0


def test_functions_given_a_fit_start_its_records_where_it_did(sp_model):
    # filter_states, frequency_response, sensitivities and infer take the fit's initial
    # state for a record it was fitted to, and the record's own start for any other
    from aeroid.io.data import fingerprint
    from aeroid.models import catalog

    fitted = catalog.short_period_flight(seed=1)
    other = catalog.short_period_flight(seed=2)
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    fit = identify(sp_model, fitted, names, estimate_x0=True)
    assert fit.data_fingerprints == (fingerprint(fitted),)
    x0 = dict(fit.initial_states[0])
    noise = {
        "process_noise": {"alpha": 1e-8, "q": 1e-8},
        "measurement_noise": {"alpha": 2.5e-5, "q": 1e-4},
    }
    sd = {"alpha": 0.005, "q": 0.01}

    def runs(data, **start):
        return (
            aeroid.filter_states(sp_model, data, fit, **noise, **start).smoothed_states,
            aeroid.frequency_response(sp_model, data, fit, min_coherent=1, **start)
            .channels[0]
            .model_magnitude,
            # the simulated outputs: at the fit its estimated start is a nuisance the
            # information leaves out, while a start given is held known
            aeroid.sensitivities(sp_model, data, names, values=fit, noise=sd, **start).outputs,
            aeroid.infer(
                sp_model,
                data,
                {"M_q": aeroid.Normal(-2.0, 2.0)},
                noise=sd,
                initial=fit,
                n_walkers=8,
                n_steps=20,
                seed=3,
                **start,
            ).log_prob,
        )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # short chains, few coherent frequencies
        for got, want in zip(runs(fitted), runs(fitted, x0=x0), strict=True):
            np.testing.assert_array_equal(got, want)
        first = {s: float(fitted[s][0]) for s in ("alpha", "q")}
        assert not np.array_equal(runs(fitted)[0], runs(fitted, x0=first)[0])
        mine = {s: float(other[s][0]) for s in ("alpha", "q")}
        for got, want in zip(runs(other), runs(other, x0=mine), strict=True):
            np.testing.assert_array_equal(got, want)


def _first(data, n):
    return FlightData(data.time[:n], {k: v[:n] for k, v in data.channels.items()})


def test_fewer_measurements_than_unknowns_is_refused(sp_model, sp_noisy):
    # 2 samples x 2 outputs cannot determine 4 parameters (the fit used to "succeed")
    with pytest.raises(
        IdentificationError, match=r"4 unknowns \(parameters 4\): 2 samples x 2 outputs = 4"
    ):
        identify(sp_model, _first(sp_noisy, 2), NAMES, estimate_x0=False)
    # by default the measured initial states count too
    with pytest.raises(
        IdentificationError,
        match=r"6 unknowns \(parameters 4 \+ initial states 2\): 3 samples x 2 outputs = 6",
    ):
        identify(sp_model, _first(sp_noisy, 3), NAMES)
    with pytest.raises(
        IdentificationError, match=r"6 unknowns \(parameters 4 \+ biases 2\): 3 samples"
    ):
        identify(sp_model, _first(sp_noisy, 3), NAMES, estimate_bias=True, estimate_x0=False)
    # two records of two samples: enough for 4 parameters, not with their initial states
    with pytest.raises(IdentificationError, match=r"initial states 4\): 4 samples x 2"):
        identify(sp_model, [_first(sp_noisy, 2)] * 2, NAMES, estimate_x0=True)
    with pytest.raises(
        IdentificationError,
        match=r"parameters 1 \+ process-noise intensities 2 \+ measurement-noise variances 2",
    ):
        identify(
            sp_model,
            _first(sp_noisy, 2),
            ["M_q"],
            method="filter_error",
            estimate_process_noise=True,
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        held = identify(sp_model, _first(sp_noisy, 3), NAMES, estimate_x0=False)
        assert held.parameter_names == tuple(NAMES)


def test_overflowing_data_is_an_error_not_a_success(sp_model, sp_noisy):
    # the outputs overflow; the elevator keeps its input (a constant one is no excitation)
    huge = FlightData(
        sp_noisy.time,
        {k: v if k == "elevator" else v * 0 + 1e300 for k, v in sp_noisy.channels.items()},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy's own overflow warnings
        with pytest.raises(IdentificationError, match=r"not finite .* outputs \['alpha', 'q'\]"):
            identify(sp_model, huge, NAMES)


def test_a_non_finite_end_of_fit_is_flagged(sp_model, sp_noisy):
    from dataclasses import replace

    from aeroid.estimation.identification import _finish

    fit = identify(sp_model, sp_noisy, NAMES)
    broken = replace(fit, parameters={**fit.parameters, "M_q": float("nan")})
    with pytest.warns(UserWarning, match="non-finite"):
        out = _finish(broken, [sp_noisy], None, {})
    assert not out.success and "non-finite" in out.message
    assert _finish(fit, [sp_noisy], None, {}).success


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"weights": "x"}, r"weights: expected a mapping .* got 'x'"),
        ({"weights": {"alpha": "x", "q": 1.0}}, r"weights\['alpha'\]: expected a number, got 'x'"),
        ({"weights": [[1.0, 2.0], [2.0, 1.0]]}, r"positive definite; .* eigenvalue is -1"),
        ({"weights": [[1.0, 2.0], [0.0, 1.0]]}, r"symmetric, but \[0, 1\] = 2\.0"),
        ({"weights": [[1.0, 0.1], [0.1, 1.0]]}, "correlated measurement noise"),
        ({"x0": "abc"}, r"x0: expected a mapping .* got 'abc'"),
        ({"x0": {"alpha": "abc"}}, r"x0\['alpha'\]: expected a number"),
        ({"x0": {"alpha": float("nan")}}, r"x0: the initial value of \['alpha'\] is not finite"),
        ({"max_iterations": 2.5}, r"max_iterations must be a positive integer, got 2\.5$"),
        ({"max_iterations": "5"}, "max_iterations must be a positive integer"),
        ({"tolerance": "x"}, "tolerance must be positive"),
        ({"estimate_bias": 3}, "estimate_bias: expected True, False or a list"),
    ],
)
def test_wrong_argument_types_name_the_argument(sp_model, sp_noisy, kwargs, fragment):
    with pytest.raises(IdentificationError, match=fragment):
        identify(sp_model, sp_noisy, NAMES, **kwargs)


@pytest.mark.parametrize("model", [None, "short_period", {"parameters": {}}])
def test_a_model_is_required(sp_noisy, model):
    with pytest.raises(IdentificationError, match=r"model: expected an aeroid\.Model"):
        identify(model, sp_noisy, NAMES)


def test_a_stepped_simulator_that_raises_at_the_start_is_named_with_its_error():
    class Duck:  # written to take an array of controls; it is given a mapping
        name = "duck"
        controls = ("elevator",)
        outputs = ("alpha", "q")
        parameters = MappingProxyType({"M_q": -1.5})

        def simulate(self, time, controls=None, x0=None, parameters=None, **options):
            return np.asarray(controls, dtype=float) * 2.0

        def simulate_data(self, data, *, x0=None, parameters=None, **options):
            return self.simulate(data.time, data.array(["elevator"]), x0, parameters)

    data = catalog.short_period_flight(seed=0, duration=2.0)
    with pytest.raises(
        IdentificationError, match=r"'duck' cannot .* \(its simulate raised TypeError"
    ):
        aeroid.identify(Duck(), data, ["M_q"])


@pytest.mark.parametrize(
    ("phi", "log_ratio"), [(0.999, -14.0), (0.95, 0.3), (0.3, 10.0), (-0.98, -2.0), (0.0, 1.0)]
)
def test_spectral_reml_criterion_matches_the_dense_formula(phi, log_ratio):
    # N large enough that the spectral bins are interpolated (not kept sample by sample):
    # (N - r) log RSS + log det S + log det X'S^-1 X for S = AR(1) + white, dense
    from scipy.linalg import toeplitz

    from aeroid.estimation._noise_model import _arw_criterion, _arw_prepare

    rng = np.random.default_rng(2)
    n, rank = 700, 3
    z = rng.standard_normal((n, rank + 1))
    z[:, 0] = np.cumsum(z[:, 0]) / 10.0  # slow content, where phi near 1 matters
    ratio = np.exp(log_ratio)
    s = toeplitz(phi ** np.arange(n)) / (1.0 - phi**2) + ratio * np.eye(n)
    chol = np.linalg.cholesky(z.T @ np.linalg.solve(s, z))
    dense = (
        (n - rank) * np.log(chol[-1, -1] ** 2)
        + np.linalg.slogdet(s)[1]
        + 2.0 * np.sum(np.log(np.diag(chol)[:rank]))
    )
    prepared = _arw_prepare(z)
    assert prepared.nodes.size < n / 2  # interpolated, not sample by sample
    x = np.array([np.arctanh(phi), log_ratio])
    value, rss = _arw_criterion(x, [prepared], n - rank, rank)
    assert value == pytest.approx(dense, rel=1e-9, abs=1e-8)
    assert rss == pytest.approx(chol[-1, -1] ** 2, rel=1e-8)


# -- input audit ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"parameters": {"M_q": True}}, "initial guess of 'M_q'"),
        ({"parameters": {"M_q": "-2"}}, "initial guess of 'M_q'"),
        ({"tolerance": "1e-3"}, "tolerance"),
        ({"tolerance": True}, "tolerance"),
        ({"tolerance": float("inf")}, "tolerance"),
        ({"simulate_options": {"method": "RK45", "rtol": -1.0}}, r"simulate_options\['rtol'\]"),
        ({"simulate_options": {"substeps": True}}, r"simulate_options\['substeps'\]"),
        ({"simulate_options": {"substeps": 10**8}}, r"simulate_options\['substeps'\]"),
        ({"simulate_options": {"method": "foo"}}, r"simulate_options\['method'\]"),
    ],
)
def test_identify_refuses_bad_options(kwargs, culprit):
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    parameters = kwargs.pop("parameters", ["M_q", "M_delta"])
    with pytest.raises(IdentificationError, match=culprit):
        aeroid.identify(model, data, parameters, **kwargs)


def test_identify_outputs_as_one_name():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    a = aeroid.identify(model, data, ["M_q", "M_delta"], outputs="q")
    b = aeroid.identify(model, data, ["M_q", "M_delta"], outputs=["q"])
    assert a.parameters == b.parameters


def test_default_initial_state_estimates_the_fitted_states_only():
    # x is fitted (its first sample is data like the rest); w is measured but neither
    # fitted nor seen in x: it starts from its first sample, with no warning about it
    def dyn(t, x, u, p):
        return np.array([p["a"] * x[0] + p["b"] * u[0], 0.3 * x[0] - 0.5 * x[1]])

    model = Model(["x", "w"], ["u"], {"a": -1.0, "b": 2.0}, dyn, outputs=["x"], name="lag")
    t = np.arange(0.0, 20.0, 0.02)
    u = np.sin(1.3 * t) + np.sign(np.sin(0.4 * t))
    sim = model.simulate(t, {"u": u}, x0=[0.0, 0.0])
    rng = np.random.default_rng(0)
    noisy = sim.states + 0.01 * rng.standard_normal(sim.states.shape)
    noisy[0, 0] = 0.03  # a first sample 3 noise SDs off the true start, 0
    data = FlightData(t, {"u": u, "x": noisy[:, 0], "w": noisy[:, 1]})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = identify(model, data, {"a": -0.8, "b": 1.5})
    assert fit.initial_states[0]["w"] == data["w"][0]
    assert abs(fit.initial_states[0]["x"]) < 0.01  # the record, not its first sample
    held = identify(model, data, {"a": -0.8, "b": 1.5}, estimate_x0=False)
    assert held.initial_states[0] == {"x": data["x"][0], "w": data["w"][0]}


def test_partial_weights_and_a_delay_start_off_the_record_are_refused():
    model = catalog.short_period(catalog.SHORT_PERIOD_GUESS)
    data = catalog.short_period_flight(seed=58)  # 10 s
    with pytest.raises(IdentificationError, match=r"no weight for fitted output\(s\) \['q'\]"):
        identify(model, data, NAMES, weights={"alpha": 1 / 0.005**2})
    # held at one end of the record throughout, the control moved M_delta to 1e135
    with pytest.raises(IdentificationError, match="a start of 20 s shifts the control off"):
        identify(model, data, NAMES, time_delays={"elevator": 20.0})


def test_interval_covers_the_initial_states_and_biases_margin_covers():
    model = catalog.short_period(catalog.SHORT_PERIOD_GUESS)
    fit = identify(model, catalog.short_period_flight(seed=58), NAMES, estimate_bias=True)
    interval, margin = fit.interval(), fit.margin()
    assert set(interval) == set(margin) and "bias[0].q" in interval and "x0[0].q" in interval
    lo, hi = interval["bias[0].q"]
    assert (lo + hi) / 2 == pytest.approx(fit.biases[0]["q"])
    assert (hi - lo) / 2 == pytest.approx(margin["bias[0].q"])


def test_a_start_that_fails_names_the_states_no_record_measures():
    """An unmeasured state starts at zero: a six-degree model fitted to V, alpha and beta
    without u, v, w divides by V = 0; the message pointed at the parameters only."""

    def f(t, x, u, p):
        return np.array([-0.1 * x[0], p["a"] * x[1] + u[0]])

    def h(t, x, u, p):
        return np.array([x[1] / x[0]])

    model = aeroid.Model(["V", "x"], ["u"], {"a": -1.0}, f, outputs=["y"], measurement=h)
    t = np.linspace(0.0, 2.0, 41)
    data = FlightData(t, {"u": np.sin(t), "y": np.sin(t) / 30.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(aeroid.AeroidError, match=r"states \['V', 'x'\] are in no record"):
            identify(model, data, ["a"])
    fit = identify(model, data, ["a"], x0={"V": 30.0, "x": 0.0}, estimate_x0=False)
    assert np.isfinite(fit.parameters["a"])
