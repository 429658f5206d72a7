"""Sensitivities, Fisher information and Cramér–Rao bounds."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid import ChannelError, FlightData, IdentifiabilityWarning, IdentificationError, Model
from aeroid.models import catalog
from aeroid.uncertainty.sensitivity import SensitivityResult, sensitivities

NOISE = {"alpha": 0.005, "q": 0.01}


class Wrapped:
    """A stepped black box (SimulatorModel) around a Model: no batching, no dynamics."""

    def __init__(self, model: Model) -> None:
        self._m = model
        self.name = "wrapped"
        self.controls = tuple(model.controls)
        self.outputs = model.output_names
        self.parameters = dict(model.parameters)
        self.calls = 0

    def simulate(self, time, controls=None, x0=None, parameters=None, **options):
        self.calls += 1
        return self._m.simulate(time, controls, x0, parameters, method="exact")

    def simulate_data(self, data, *, x0=None, parameters=None, **options):
        return self.simulate(data.time, data, x0, parameters)


def step_record(K: float = 2.0, tau: float = 0.5) -> FlightData:
    t = np.linspace(0.0, 4.0, 401)
    return FlightData(t, {"u": np.ones_like(t), "y": K * (1 - np.exp(-t / tau))})


def test_first_order_step_partials_match_closed_form():
    # y = K (1 - e^{-t/τ}):  dy/dK = 1 - e^{-t/τ},  dy/dτ = -K t e^{-t/τ} / τ²
    K, tau = 2.0, 0.5
    data = step_record(K, tau)
    t = data.time
    res = sensitivities(catalog.first_order(K, tau), data, noise={"y": 0.1})
    d_k = 1 - np.exp(-t / tau)
    d_tau = -K * t * np.exp(-t / tau) / tau**2
    np.testing.assert_allclose(res.sensitivity("y", "K"), d_k, rtol=1e-3, atol=1e-3 * d_k.max())
    np.testing.assert_allclose(
        res.sensitivity("y", "tau"), d_tau, rtol=1e-3, atol=1e-3 * np.abs(d_tau).max()
    )
    # Fisher information and the Cramér–Rao bound from the same closed forms
    s = np.column_stack([d_k, d_tau])
    fisher = s.T @ s / 0.1**2
    np.testing.assert_allclose(res.fisher_information, fisher, rtol=1e-3)
    crb = np.sqrt(np.diag(np.linalg.inv(fisher)))
    np.testing.assert_allclose([res.cramer_rao_bound[n] for n in ("K", "tau")], crb, rtol=1e-3)
    np.testing.assert_allclose(res.norms["K"], np.sqrt(fisher[0, 0]), rtol=1e-3)
    assert res.identifiable and res.unidentifiable == ()
    assert res.noise_source == "given"


def test_step_works_at_zero_parameter():
    # an offset b = 0 added to the lag: y' = (K u - y + b)/τ, dy/db = 1 - e^{-t/τ}
    model = Model(
        states=["y"],
        controls=["u"],
        parameters={"K": 2.0, "tau": 0.5, "b": 0.0},
        dynamics=lambda t, x, u, p: np.array([(p["K"] * u[0] - x[0] + p["b"]) / p["tau"]]),
    )
    data = step_record()
    res = sensitivities(model, data, ["b"], noise={"y": 0.1})
    expected = 1 - np.exp(-data.time / 0.5)
    np.testing.assert_allclose(res.sensitivity("y", "b"), expected, rtol=1e-3, atol=1e-6)


def test_columns_come_from_one_batched_simulation(monkeypatch, sp_noisy, sp_truth):
    calls = []
    original = Model.simulate_batch

    def counting(self, time, controls, x0, parameters, **kw):
        calls.append(max(np.size(v) for v in parameters.values()))
        return original(self, time, controls, x0, parameters, **kw)

    monkeypatch.setattr(Model, "simulate_batch", counting)
    sensitivities(catalog.short_period(), sp_noisy, values=sp_truth, noise=NOISE)
    assert calls == [9]  # 2 x 4 central-difference columns + the nominal, in one call


def test_values_from_a_result_and_parameter_subset(sp_noisy, sp_truth):
    class Fake:
        def __init__(self):
            self.parameters = dict(sp_truth)

    a = sensitivities(
        catalog.short_period(), sp_noisy, ["M_q", "M_delta"], values=Fake(), noise=NOISE
    )
    b = sensitivities(
        catalog.short_period(), sp_noisy, ["M_q", "M_delta"], values=sp_truth, noise=NOISE
    )
    assert a.parameter_names == ("M_q", "M_delta")
    assert a.fisher_information.shape == (2, 2)
    np.testing.assert_array_equal(a.fisher_information, b.fisher_information)
    assert a.values["M_q"] == sp_truth["M_q"]


def test_a_posterior_plugs_in_like_a_fit(sp_noisy, sp_truth):
    """The spec: a posterior "plugs into validate, sensitivities, and propagate exactly
    like a least-squares fit"; its sigma_<output> noise estimates are not parameters."""
    model = catalog.short_period(sp_truth)
    post = aeroid.infer(
        model, sp_noisy, {"M_q": aeroid.Normal(-2.0, 2.0)}, n_steps=200, seed=0, progress=False
    )
    assert "sigma_alpha" in post.parameters
    by_result = sensitivities(model, sp_noisy, post, noise=NOISE)
    by_values = sensitivities(model, sp_noisy, ["M_q"], values=post, noise=NOISE)
    assert by_result.parameter_names == ("M_q",)
    np.testing.assert_array_equal(by_result.fisher_information, by_values.fisher_information)


def test_crb_matches_monte_carlo_spread_of_least_squares():
    # Self-contained pin: the bound equals the spread of output-error estimates over
    # seeded noise. 40 fits give the sample std to ~11 % (1/sqrt(2*39)); rel 0.3 is ~2.7σ.
    import scipy.optimize

    K, tau, sigma = 2.0, 0.5, 0.05
    model = catalog.first_order(K, tau)
    t = np.linspace(0.0, 3.0, 151)
    u = np.where(t >= 0.2, 1.0, 0.0)
    clean = model.simulate(t, u, [0.0], method="exact").output("y")
    data = FlightData(t, {"u": u, "y": clean})
    res = sensitivities(model, data, noise={"y": sigma})
    rng = np.random.default_rng(11)
    est = []
    for _ in range(40):
        y = clean + sigma * rng.standard_normal(t.size)

        def resid(theta, y=y):
            p = {"K": theta[0], "tau": theta[1]}
            return model.simulate(t, u, [0.0], p, method="exact").output("y") - y

        est.append(scipy.optimize.least_squares(resid, [K, tau]).x)
    spread = np.std(np.array(est), axis=0, ddof=1)
    np.testing.assert_allclose(
        spread, [res.cramer_rao_bound["K"], res.cramer_rao_bound["tau"]], rtol=0.3
    )


def test_crb_matches_identify_classical_covariance(sp_noisy):
    identify = getattr(aeroid, "identify", None)
    if identify is None:
        pytest.skip("aeroid.identify not available yet")
    model = catalog.short_period()
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    fit = identify(model, sp_noisy, names)
    res = sensitivities(model, sp_noisy, names, values=fit)  # the noise the fit weighed by
    assert res.noise_source == "fit"
    # replayed from the fit's start, its estimated initial states taken out: its bars
    white = np.sqrt(np.diag(fit.covariance_white))
    np.testing.assert_allclose([res.cramer_rao_bound[n] for n in names], white, rtol=1e-6)


def test_unidentifiable_combination_warns_and_is_flagged():
    # Only the product a*b enters the dynamics; c does not enter at all.
    model = Model(
        states=["y"],
        controls=["u"],
        parameters={"a": 1.5, "b": 2.0, "tau": 0.5, "c": 1.0},
        dynamics=lambda t, x, u, p: np.array([(p["a"] * p["b"] * u[0] - x[0]) / p["tau"]]),
    )
    data = step_record()
    with pytest.warns(IdentifiabilityWarning, match=r"a \+ b") as rec:
        res = sensitivities(model, data, noise={"y": 0.1})
    assert "c" in str(rec[0].message)
    assert not res.identifiable
    assert set(map(frozenset, res.unidentifiable)) == {frozenset({"a", "b"}), frozenset({"c"})}
    assert np.isinf(res.cramer_rao_bound["a"]) and np.isinf(res.cramer_rao_bound["c"])
    assert np.isfinite(res.cramer_rao_bound["tau"])
    assert "Not identifiable" in res.summary()


def test_simulator_model_is_looped_and_agrees(sp_noisy, sp_truth):
    model = catalog.short_period()
    box = Wrapped(model)
    a = sensitivities(box, sp_noisy, values=sp_truth, noise=NOISE, x0=[0.0, 0.0])
    b = sensitivities(model, sp_noisy, values=sp_truth, noise=NOISE, x0=[0.0, 0.0])
    assert box.calls == 9
    np.testing.assert_allclose(a.sensitivities, b.sensitivities, rtol=1e-6, atol=1e-9)
    assert "member by member" in a.method


def test_noise_estimated_from_residuals(sp_noisy, sp_truth):
    res = sensitivities(catalog.short_period(), sp_noisy, values=sp_truth)
    assert res.noise_source == "residuals"
    # 501 samples: the RMS of the noise estimates σ to ~3 % (1/sqrt(2*501)); 15 % is generous
    np.testing.assert_allclose([res.noise["alpha"], res.noise["q"]], [0.005, 0.01], rtol=0.15)


def test_noise_free_data_fall_back_to_unit_noise(sp_clean, sp_truth):
    with pytest.warns(UserWarning, match="unit noise"):
        res = sensitivities(catalog.short_period(), sp_clean, values=sp_truth)
    assert res.noise_source == "unit"
    assert dict(res.noise) == {"alpha": 1.0, "q": 1.0}


def test_result_is_frozen_and_summarised(sp_noisy, sp_truth):
    res = sensitivities(catalog.short_period(), sp_noisy, values=sp_truth, noise=NOISE)
    assert isinstance(res, SensitivityResult)
    with pytest.raises(ValueError):
        res.fisher_information[0, 0] = 1.0
    with pytest.raises(TypeError):
        res.cramer_rao_bound["M_q"] = 1.0  # type: ignore[index]
    text = res.summary()
    assert "Cramér–Rao" in text and "M_delta" in text and "identifiable" in text
    assert res.correlation.shape == (4, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sensitivities(catalog.short_period(), sp_noisy, values=sp_truth, noise=NOISE)


def test_outputs_subset(sp_noisy, sp_truth):
    res = sensitivities(catalog.short_period(), sp_noisy, values=sp_truth, noise={"q": 0.01})
    assert res.output_names == ("q",)
    assert res.sensitivities.shape == (sp_noisy.n_samples, 1, 4)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"parameters": ["M_x"]}, IdentificationError, "M_x"),
        ({"noise": {"alpha": -1.0, "q": 0.01}}, IdentificationError, "alpha"),
        ({"noise": {"beta": 0.1}}, IdentificationError, "beta"),
        ({"outputs": ["q"], "noise": {"alpha": 0.005}}, IdentificationError, "'q'"),
        ({"outputs": ["nz"]}, ChannelError, "nz"),
        ({"relative_step": 0.0}, IdentificationError, "relative_step"),
        ({"values": {"M_x": 1.0}}, IdentificationError, "M_x"),
        ({"simulate_options": {"methd": "rk4"}}, IdentificationError, "method"),
    ],
)
def test_bad_arguments_raise(sp_noisy, kwargs, error, match):
    kwargs = {"noise": NOISE, **kwargs}
    with pytest.raises(error, match=match):
        sensitivities(catalog.short_period(), sp_noisy, **kwargs)


def test_missing_control_and_bad_lookup(sp_noisy, sp_truth):
    data = FlightData(sp_noisy.time, {"alpha": sp_noisy["alpha"], "q": sp_noisy["q"]})
    with pytest.raises(ChannelError, match="elevator"):
        sensitivities(catalog.short_period(), data, noise=NOISE)
    res = sensitivities(catalog.short_period(), sp_noisy, values=sp_truth, noise=NOISE)
    with pytest.raises(ChannelError, match="theta"):
        res.sensitivity("theta", "M_q")
    with pytest.raises(IdentificationError, match="M_x"):
        res.sensitivity("q", "M_x")


def test_parameter_values_given_where_names_go_are_used_as_the_values():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=3)
    # held initial states: a dict of values then starts where the fit did
    fit = aeroid.identify(model, data, ["M_q", "M_delta"], estimate_x0=False)
    by_values = aeroid.sensitivities(model, data, ["M_q", "M_delta"], values=fit)
    for given in (fit, dict(fit.parameters)):
        s = aeroid.sensitivities(model, data, given)
        assert list(s.parameter_names) == ["M_q", "M_delta"]
        assert s.values == by_values.values and s.values["M_q"] == fit.parameters["M_q"]
        np.testing.assert_allclose(s.fisher_information, by_values.fisher_information, rtol=1e-12)
    with pytest.raises(IdentificationError, match="either as `parameters` or as `values`"):
        aeroid.sensitivities(model, data, dict(fit.parameters), values=fit)


# -- input audit ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"relative_step": "1e-6"}, "relative_step"),
        ({"relative_step": True}, "relative_step"),
        ({"outputs": []}, "outputs"),
        ({"noise": {"alpha": True, "q": 0.01}}, r"noise\['alpha'\]"),
        ({"simulate_options": {"method": "RK45", "rtol": -1.0}}, r"simulate_options\['rtol'\]"),
        ({"simulate_options": {"substeps": True}}, r"simulate_options\['substeps'\]"),
    ],
)
def test_bad_arguments_name_the_culprit(kwargs, culprit):
    data = catalog.short_period_flight(seed=0)
    with pytest.raises(aeroid.IdentificationError, match=culprit):
        sensitivities(catalog.short_period(), data, ["M_q"], **kwargs)
