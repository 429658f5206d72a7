"""Parameter bounds, fixed parameters, state-equation biases and option readings of `identify`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from aeroid import FlightData, IdentificationError, Model, identify
from aeroid.errors import ConfigError
from aeroid.models import catalog

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = catalog.SHORT_PERIOD_TRUTH


def _with_nominal(model: Model, **values: float) -> Model:
    """The same model with other nominal (hence fixed) parameter values."""
    return Model(
        model.states,
        model.controls,
        {**model.parameters, **values},
        model.dynamics,
        outputs=model.outputs,
        measurement=model.measurement,
        name=model.name,
    )


def _first(data: FlightData, seconds: float) -> FlightData:
    keep = data.time <= data.time[0] + seconds + 1e-9
    return FlightData(data.time[keep], {c: data[c][keep] for c in data.channels})


# -- bounds: active, inactive, conditional covariance -----------------------------------


@pytest.fixture(scope="module")
def sp_fits():
    """The short-period noisy record fitted without bounds and with M_q >= -2.3 (the
    unconstrained optimum is -2.45)."""
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    free = identify(model, data, NAMES)
    bounded = identify(model, data, NAMES, bounds={"M_q": (-2.3, None)})
    return model, data, free, bounded


def test_a_violated_bound_is_met_exactly_and_reported_active(sp_fits):
    _, _, free, r = sp_fits
    assert free.parameters["M_q"] < -2.4  # the unconstrained optimum lies outside
    assert r.success
    assert r.parameters["M_q"] == -2.3  # exactly at the bound, not near it
    assert dict(r.active_bounds) == {"M_q": "lower"}
    assert dict(r.bounds) == {"M_q": (-2.3, math.inf)}
    # held at the bound: conditional error bars, zero for the held parameter
    assert r.stderr["M_q"] == 0.0
    j = r.parameter_names.index("M_q")
    assert np.all(r.covariance[j] == 0) and np.all(r.covariance[:, j] == 0)
    assert all(r.stderr[n] > 0 for n in NAMES if n != "M_q")
    # the constrained optimum cannot fit better than the free one
    assert r.cost >= free.cost
    text = r.summary()
    assert "at lower" in text and "conditional on the bound" in text


def test_every_trial_point_of_a_bounded_fit_lies_inside_the_box(monkeypatch, sp_noisy):
    from aeroid.estimation import _output_error

    seen = []
    evaluate = _output_error._Problem.evaluate

    def spy(self, theta, steps):
        seen.append(np.array(theta[: self.layout.n_p]))
        return evaluate(self, theta, steps)

    monkeypatch.setattr(_output_error._Problem, "evaluate", spy)
    box = {"M_q": (-2.3, -1.0), "M_alpha": (-5.5, None)}
    r = identify(catalog.short_period(), sp_noisy, NAMES, bounds=box, gradient="fd")
    assert dict(r.active_bounds) == {"M_q": "lower", "M_alpha": "lower"}
    assert len(seen) > r.n_iterations
    points = np.array(seen)
    for name, (lo, hi) in box.items():
        col = points[:, NAMES.index(name)]
        assert np.all(col >= lo) and (hi is None or np.all(col <= hi))


def test_an_upper_bound_is_met_exactly_from_a_start_inside():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    start = {**catalog.SHORT_PERIOD_GUESS, "Z_alpha": -1.5}
    r = identify(model, data, start, bounds={"Z_alpha": (None, -1.3)})
    assert r.parameters["Z_alpha"] == -1.3
    assert dict(r.active_bounds) == {"Z_alpha": "upper"}


def test_bounds_that_stay_inactive_change_nothing(sp_fits):
    model, data, free, _ = sp_fits
    r = identify(
        model,
        data,
        NAMES,
        bounds={"M_q": (-100.0, 0.0), "Z_alpha": (None, 5.0), "M_delta": (-50, None)},
    )
    assert dict(r.active_bounds) == {}
    for n in NAMES:
        assert r.parameters[n] == pytest.approx(free.parameters[n], rel=1e-10, abs=1e-12)
    np.testing.assert_allclose(r.covariance, free.covariance, rtol=1e-10)
    assert "| bounds" in r.summary() and "at lower" not in r.summary()


def test_error_bars_at_an_active_bound_are_those_of_the_fit_with_it_fixed():
    # coloured residuals, so the correction's sandwich is checked on the reduced problem too
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=3, colored=0.8)
    bounded = identify(model, data, NAMES, bounds={"M_q": (-2.3, None)}, tolerance=1e-12)
    assert dict(bounded.active_bounds) == {"M_q": "lower"}
    assert bounded.error_bars == "colored"
    others = ["Z_alpha", "M_alpha", "M_delta"]
    fixed = identify(_with_nominal(model, M_q=-2.3), data, others, tolerance=1e-12)
    assert fixed.fixed["M_q"] == -2.3
    idx = [bounded.parameter_names.index(n) for n in others]
    for n in others:
        assert bounded.parameters[n] == pytest.approx(fixed.parameters[n], rel=1e-7)
    np.testing.assert_allclose(bounded.covariance[np.ix_(idx, idx)], fixed.covariance, rtol=1e-5)
    np.testing.assert_allclose(
        bounded.covariance_white[np.ix_(idx, idx)], fixed.covariance_white, rtol=1e-5
    )


@pytest.mark.parametrize(
    ("bounds", "match"),
    [
        ({"M_z": (None, 0.0)}, r"bounds: 'M_z' is not a parameter of model"),
        ({"M_delta": (None, 0.0)}, r"bounds: 'M_delta' is not estimated \(it stays fixed"),
        (
            {"M_q": (0.0, -5.0)},
            r"bounds\['M_q'\]: the lower bound 0 must be below the upper bound -5",
        ),
        ({"M_q": (-2.0, -2.0)}, r"bounds\['M_q'\]: the lower bound -2 must be below"),
        ({"M_q": (math.inf, None)}, r"bounds\['M_q'\]: the lower bound inf must be below"),
        ({"M_q": (float("nan"), 0.0)}, r"bounds\['M_q'\]: the lower bound must be a number"),
        ({"M_q": (None, "zero")}, r"bounds\['M_q'\]: the upper bound must be a number"),
        ({"M_q": (True, None)}, r"bounds\['M_q'\]: the lower bound must be a number"),
        ({"M_q": -2.0}, r"bounds\['M_q'\]: expected \(lower, upper\)"),
        ({"M_q": (None, 0.0, 1.0)}, r"bounds\['M_q'\]: expected \(lower, upper\)"),
        ({"M_q": (-3.0, -2.0)}, r"bounds\['M_q'\]: the initial value -1.5 lies outside"),
        ([("M_q", (None, 0.0))], r"bounds: expected a dict of parameter name"),
    ],
)
def test_bad_bounds_are_refused_naming_the_parameter(sp_noisy, bounds, match):
    with pytest.raises(IdentificationError, match=match):
        identify(catalog.short_period(), sp_noisy, ["Z_alpha", "M_alpha", "M_q"], bounds=bounds)


def test_a_start_on_the_bound_is_allowed_and_open_sides_may_be_infinite(sp_noisy):
    r = identify(
        catalog.short_period(), _first(sp_noisy, 4.0), NAMES, bounds={"M_q": (-math.inf, -1.5)}
    )
    assert r.parameters["M_q"] <= -1.5
    assert r.bounds["M_q"] == (-math.inf, -1.5)


# -- a nonlinear model ---------------------------------------------------------------


def _pendulum(params: dict[str, float], xp: Any = np) -> Model:
    """Nonlinear, with a measurement function; ``xp=jax.numpy`` for gradient="jax"."""

    def f(t, x, u, p):
        return xp.array([x[1], -p["w2"] * xp.sin(x[0]) - p["c"] * x[1] + p["b"] * u[0]])

    def h(t, x, u, p):
        return xp.array([x[0], x[1], -p["w2"] * xp.sin(x[0]) - p["c"] * x[1] + p["b"] * u[0]])

    return Model(
        ["theta", "omega"],
        ["torque"],
        params,
        f,
        outputs=["theta", "omega", "omega_dot"],
        measurement=h,
        name="pendulum",
    )


PENDULUM_TRUTH = {"w2": 9.0, "c": 0.4, "b": 2.0}


def _pendulum_flight(seed: int) -> FlightData:
    t = np.linspace(0.0, 8.0, 321)
    u = np.where((t > 0.5) & (t < 1.5), 1.0, 0.0) - np.where((t > 3.0) & (t < 3.6), 1.5, 0.0)
    sim = _pendulum(PENDULUM_TRUTH).simulate(t, u, [0.3, 0.0], rtol=1e-10, atol=1e-12)
    rng = np.random.default_rng(seed)
    noise = {"theta": 0.01, "omega": 0.02, "omega_dot": 0.1}
    channels = {"torque": u}
    for name, sd in noise.items():
        channels[name] = sim.output(name) + sd * rng.standard_normal(t.size)
    return FlightData(t, channels)


def test_bounded_fit_of_a_nonlinear_model_recovers_the_truth_and_meets_a_violated_bound():
    model = _pendulum({"w2": 6.0, "c": 0.1, "b": 1.0})
    data = _pendulum_flight(seed=11)
    names = list(PENDULUM_TRUTH)
    x0 = {"theta": 0.3, "omega": 0.0}
    box = {"c": (0.0, None), "w2": (1.0, 20.0)}
    r = identify(model, data, names, x0=x0, bounds=box, gradient="fd")
    assert r.success and not r.active_bounds
    for n in names:
        assert abs(r.parameters[n] - PENDULUM_TRUTH[n]) < 3 * r.stderr[n]
    # a damping limit below the truth is met exactly and flagged
    capped = identify(model, data, names, x0=x0, bounds={"c": (0.0, 0.3)}, gradient="fd")
    assert capped.parameters["c"] == 0.3
    assert dict(capped.active_bounds) == {"c": "upper"} and capped.stderr["c"] == 0.0


# -- fixed parameters -------------------------------------------------------------------


def test_parameters_not_named_stay_fixed_at_their_nominal_values(sp_clean):
    # fixed at the truth, the others are recovered from noise-free data
    model = _with_nominal(catalog.short_period(), M_q=TRUTH["M_q"])
    r = identify(model, sp_clean, ["Z_alpha", "M_alpha", "M_delta"])
    assert dict(r.fixed) == {"M_q": TRUTH["M_q"]}
    assert r.all_parameters["M_q"] == TRUTH["M_q"]
    for n in ("Z_alpha", "M_alpha", "M_delta"):
        assert r.parameters[n] == pytest.approx(TRUTH[n], rel=1e-5)
    # fixed at a wrong value, it stays there and the others absorb the error
    wrong = identify(catalog.short_period(), sp_clean, ["Z_alpha", "M_alpha", "M_delta"])
    assert wrong.fixed["M_q"] == catalog.SHORT_PERIOD_GUESS["M_q"]
    assert wrong.parameters["M_alpha"] != pytest.approx(TRUTH["M_alpha"], rel=1e-3)


# -- biases on the state equations --------------------------------------------------------

LAT_TRUTH = {
    "Y_beta": -0.2,
    "L_beta": -8.0,
    "L_p": -4.0,
    "L_r": 1.0,
    "L_da": 12.0,
    "L_dr": 1.5,
    "N_beta": 3.5,
    "N_p": -0.2,
    "N_r": -0.6,
    "N_da": -0.5,
    "N_dr": -4.0,
}
LAT_FREE = ["L_beta", "L_p", "L_da", "N_beta", "N_r", "N_dr"]


def _lateral(params: dict[str, float]) -> Model:
    def f(t, x, u, p):
        beta, pr, r = x[0], x[1], x[2]
        ail, rud = u[0], u[1]
        return np.array(
            [
                p["Y_beta"] * beta - r,
                p["L_beta"] * beta
                + p["L_p"] * pr
                + p["L_r"] * r
                + p["L_da"] * ail
                + p["L_dr"] * rud
                + p.get("b_p", 0.0),
                p["N_beta"] * beta
                + p["N_p"] * pr
                + p["N_r"] * r
                + p["N_da"] * ail
                + p["N_dr"] * rud
                + p.get("b_r", 0.0),
            ]
        )

    return Model(["beta", "p", "r"], ["aileron", "rudder"], params, f, name="lateral")


def _lateral_flight(seed: int, b_p: float, b_r: float, shift: float) -> FlightData:
    t = np.arange(0.0, 10.0 + 1e-9, 0.04)
    ail = 0.05 * (
        np.where((t > 1 + shift) & (t < 2 + shift), 1.0, 0.0)
        - np.where((t > 2 + shift) & (t < 3 + shift), 1.0, 0.0)
    )
    rud = 0.05 * (np.where((t > 5) & (t < 6), 1.0, 0.0) - np.where((t > 6) & (t < 7), 1.0, 0.0))
    truth = _lateral({**LAT_TRUTH, "b_p": b_p, "b_r": b_r})
    sim = truth.simulate(
        t, {"aileron": ail, "rudder": rud}, [0.0, 0.0, 0.0], rtol=1e-10, atol=1e-12
    )
    rng = np.random.default_rng(seed)
    channels = {"aileron": ail, "rudder": rud}
    for name, sd in (("beta", 0.002), ("p", 0.005), ("r", 0.003)):
        channels[name] = sim.state(name) + sd * rng.standard_normal(t.size)
    return FlightData(t, channels)


def test_state_equation_biases_are_recovered_per_manoeuvre():
    biases = [(0.05, -0.02), (-0.03, 0.015)]
    datas = [_lateral_flight(20 + i, bp, br, shift=0.5 * i) for i, (bp, br) in enumerate(biases)]
    guess = {**LAT_TRUTH, **{n: 0.7 * LAT_TRUTH[n] for n in LAT_FREE}}
    model = _lateral(guess)
    zero = {"beta": 0.0, "p": 0.0, "r": 0.0}
    r = identify(
        model,
        datas,
        LAT_FREE,
        x0=[zero, zero],
        estimate_bias={"p": "state", "r": "state", "beta": "output"},
        bounds={"L_p": (None, 0.0), "N_r": (None, 0.0)},
        error_bars="white",
    )
    assert r.success and not r.active_bounds
    for n in LAT_FREE:
        assert abs(r.parameters[n] - LAT_TRUTH[n]) < 3 * r.stderr[n], n
    for i, (bp, br) in enumerate(biases):
        assert set(r.biases[i]) == {"beta", "state.p", "state.r"}
        assert set(r.initial_states[i]) == {"beta", "p", "r"}
        for key, truth in (("p", bp), ("r", br)):
            est, se = r.biases[i][f"state.{key}"], r.extra_stderr[f"bias[{i}].state.{key}"]
            assert abs(est - truth) < 3 * se, (i, key)
            assert abs(est) > 3 * se  # a real recovery, not a zero within the noise
        assert abs(r.biases[i]["beta"]) < 3 * r.extra_stderr[f"bias[{i}].beta"]
    # without the state biases the same fit is visibly wrong
    plain = identify(model, datas, LAT_FREE, x0=[zero, zero], error_bars="white")
    assert plain.cost > r.cost + 50


def test_a_state_bias_on_a_nonlinear_model_with_a_measurement_function():
    # a constant derivative bias on omega is a constant torque offset 0.1 / b
    t = np.linspace(0.0, 8.0, 321)
    u = np.where((t > 0.5) & (t < 1.5), 1.0, 0.0) - np.where((t > 3.0) & (t < 3.6), 1.5, 0.0)
    truth = _pendulum(PENDULUM_TRUTH)
    sim = truth.simulate(t, u + 0.1 / PENDULUM_TRUTH["b"], [0.3, 0.0], rtol=1e-10, atol=1e-12)
    rng = np.random.default_rng(3)
    channels = {"torque": u}
    for name, sd in (("theta", 0.01), ("omega", 0.02)):
        channels[name] = sim.output(name) + sd * rng.standard_normal(t.size)
    r = identify(
        _pendulum({"w2": 6.0, "c": 0.1, "b": 1.0}),
        FlightData(t, channels),
        list(PENDULUM_TRUTH),
        x0={"theta": 0.3, "omega": 0.0},
        outputs=["theta", "omega"],
        estimate_bias={"omega": "state"},
        gradient="fd",
    )
    est, se = r.biases[0]["state.omega"], r.extra_stderr["bias[0].state.omega"]
    assert abs(est - 0.1) < 3 * se and se < 0.02
    for n in PENDULUM_TRUTH:
        assert abs(r.parameters[n] - PENDULUM_TRUTH[n]) < 3 * r.stderr[n]


def test_state_bias_options_are_checked(sp_noisy):
    model = catalog.short_period()
    with pytest.raises(
        IdentificationError, match=r"estimate_bias\['q'\]: expected 'output' or 'state'"
    ):
        identify(model, sp_noisy, NAMES, estimate_bias={"q": "bogus"})
    with pytest.raises(IdentificationError, match=r"estimate_bias: 'theta' is not a state"):
        identify(model, sp_noisy, NAMES, estimate_bias={"theta": "state"})
    with pytest.raises(IdentificationError, match=r"need a Model .*not|gradient='auto' or 'fd'"):
        identify(model, sp_noisy, NAMES, estimate_bias={"q": "state"}, gradient="jax")
    # filter error estimates biases (tests/test_filter_error_bias.py), not initial states
    with pytest.raises(IdentificationError, match=r"estimate_x0 applies to method='output_error'"):
        identify(
            model,
            sp_noisy,
            NAMES,
            method="filter_error",
            process_noise={"q": 1e-6},
            estimate_x0=True,
        )


def test_a_state_and_an_output_bias_on_the_same_name(sp_clean):
    r = identify(
        catalog.short_period(),
        _first(sp_clean, 6.0),
        NAMES,
        estimate_bias={"q": ["state", "output"]},
    )
    assert set(r.biases[0]) == {"q", "state.q"}
    # noise-free data from a bias-free truth: both come out zero
    assert abs(r.biases[0]["q"]) < 1e-6 and abs(r.biases[0]["state.q"]) < 1e-6


# -- x0 for several manoeuvres ----------------------------------------------------------------


def test_x0_lists_are_read_per_manoeuvre_or_as_one_state(sp_clean):
    model = catalog.short_period()
    datas = [_first(sp_clean, 3.0), _first(sp_clean, 3.0)]
    fit = {"max_iterations": 3, "tolerance": 1e-3}
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the iteration cap
        # a flat list of n_states numbers is one state for every manoeuvre, even when
        # its length also equals the number of manoeuvres
        shared = identify(model, datas, NAMES, x0=[0.01, 0.02], **fit)
        assert [dict(s) for s in shared.initial_states] == [{"alpha": 0.01, "q": 0.02}] * 2
        each = identify(model, datas, NAMES, x0=[{"alpha": 0.0, "q": 0.1}, {"q": 0.2}], **fit)
        assert [dict(s) for s in each.initial_states] == [
            {"alpha": 0.0, "q": 0.1},
            {"alpha": 0.0, "q": 0.2},
        ]
        rows = identify(model, datas, NAMES, x0=np.array([[0.1, 0.2], [0.3, 0.4]]), **fit)
        assert [dict(s) for s in rows.initial_states] == [
            {"alpha": 0.1, "q": 0.2},
            {"alpha": 0.3, "q": 0.4},
        ]
        mixed = identify(model, datas, NAMES, x0=[None, [0.0, 0.5]], **fit)
        assert dict(mixed.initial_states[1]) == {"alpha": 0.0, "q": 0.5}
        assert dict(mixed.initial_states[0]) == {
            "alpha": float(datas[0]["alpha"][0]),
            "q": float(datas[0]["q"][0]),
        }
    with pytest.raises(
        IdentificationError,
        match=r"x0: got 3 numbers; expected 2 values for states \['alpha', 'q'\] \(read as one "
        r"initial state for every manoeuvre\), or a list of 2 initial states",
    ):
        identify(model, datas, NAMES, x0=[0.0, 0.1, 0.2])
    with pytest.raises(IdentificationError, match=r"x0: got a list of 3 initial states for 2"):
        identify(model, datas, NAMES, x0=[{"q": 0.0}] * 3)


def test_x0_numbers_per_manoeuvre_for_a_one_state_model():
    model = Model(["v"], ["u"], {"k": 0.5}, lambda t, x, u, p: -p["k"] * x + u, name="decay")
    t = np.linspace(0.0, 4.0, 81)
    datas = []
    for v0 in (1.0, 2.0):
        sim = model.simulate(t, np.zeros_like(t), [v0], {"k": 0.8}, rtol=1e-10, atol=1e-12)
        datas.append(FlightData(t, {"u": np.zeros_like(t), "v": sim.state("v")}))
    r = identify(model, datas, ["k"], x0=[1.0, 2.0])
    assert [s["v"] for s in r.initial_states] == [1.0, 2.0]
    assert r.parameters["k"] == pytest.approx(0.8, rel=1e-4)


# -- gradient="jax" and simulate_options -----------------------------------------------------


def test_jax_gradient_refuses_integrator_options_it_cannot_honour(sp_noisy):
    pytest.importorskip("jax")
    for key, value in (("rtol", 1e-8), ("method", "rk45"), ("atol", 1e-9)):
        with pytest.raises(
            IdentificationError, match=rf"simulate_options \['{key}'\] do not apply"
        ):
            identify(
                catalog.short_period(),
                sp_noisy,
                NAMES,
                gradient="jax",
                simulate_options={key: value},
            )
    with pytest.raises(IdentificationError, match=r"substeps'\] must be a positive integer"):
        identify(
            catalog.short_period(),
            sp_noisy,
            NAMES,
            gradient="jax",
            simulate_options={"substeps": 0},
        )


def test_jax_gradient_honours_substeps():
    jnp = pytest.importorskip("jax.numpy")
    from aeroid.models import jax_compiled as _jax

    def lag(t, x, u, p):
        return jnp.array([-p["k"] * x[0] + p["b"] * u[0]])

    model = Model(["v"], ["u"], {"k": 1.0, "b": 1.0}, lag, name="lag")
    t = np.arange(0.0, 10.0 + 1e-9, 0.25)  # coarse: one RK4 step per sample is visibly off
    u = np.sin(1.3 * t) + (t > 2.0)
    truth = Model(["v"], ["u"], {"k": 2.0, "b": 1.5}, lambda t, x, u, p: -p["k"] * x + p["b"] * u)
    v = truth.simulate(t, u, [0.0], rtol=1e-10, atol=1e-12).state("v")
    data = FlightData(t, {"u": u, "v": v + 0.01 * np.random.default_rng(0).standard_normal(t.size)})
    fits = {}
    for m in (1, 3):
        r = identify(
            model, data, ["k", "b"], x0=[0.0], gradient="jax", simulate_options={"substeps": m}
        )
        _, _, _, y = _jax.rollout(model, t, u[:, None], [0.0], r.all_parameters, substeps=m)
        np.testing.assert_allclose(r.residuals[0], data.array(["v"]) - y, rtol=0, atol=1e-12)
        fits[m] = r
    assert fits[1].parameters["k"] != pytest.approx(fits[3].parameters["k"], rel=1e-6)


# -- filter error ----------------------------------------------------------------------------


def test_filter_error_meets_a_violated_bound_exactly():
    model = catalog.short_period()
    data = _first(catalog.short_period_flight(seed=0), 6.0)
    noise = {
        "process_noise": {"alpha": 1e-8, "q": 1e-8},
        "measurement_noise": {"alpha": 2.5e-5, "q": 1e-4},
    }
    free = identify(model, data, NAMES, method="filter_error", **noise)
    lower = free.parameters["M_q"] + 0.1
    start = {**catalog.SHORT_PERIOD_GUESS}
    r = identify(model, data, start, method="filter_error", bounds={"M_q": (lower, None)}, **noise)
    assert r.parameters["M_q"] == lower
    assert dict(r.active_bounds) == {"M_q": "lower"} and r.stderr["M_q"] == 0.0
    assert all(r.stderr[n] > 0 for n in NAMES if n != "M_q")
    assert r.cost >= free.cost
    same = identify(model, data, NAMES, method="filter_error", bounds={"M_q": (-50, 0)}, **noise)
    assert not same.active_bounds
    for n in NAMES:
        assert same.parameters[n] == pytest.approx(free.parameters[n], rel=1e-10)


# -- the pipeline --------------------------------------------------------------------------


def _campaign(tmp_path, identify_options: str):
    cfg = tmp_path / "camp.yaml"
    cfg.write_text(
        "model: short_period\nstore: store\n"
        "flights: [{simulated: {n_flights: 1, seed: 1, duration: 6.0}}]\n"
        f"stages:\n  identify: {identify_options}\n"
    )
    return cfg


def test_bounds_in_a_pipeline_config_are_validated_keyed_and_passed_through(tmp_path):
    from aeroid.pipeline import open_store, plan
    from aeroid.pipeline.running.runner import execute_task
    from aeroid.pipeline.stages.library_stages import IdentifyOptions

    with pytest.raises(
        ConfigError,
        match=r"camp.yaml: stages.identify.bounds: M_q: the lower bound 0.0 must be below the "
        r"upper bound -1.0",
    ):
        plan(_campaign(tmp_path, "{bounds: {M_q: [0.0, -1.0]}}"))
    with pytest.raises(
        ConfigError, match=r"stages.identify.bounds.M_q: must be a finite|finite number"
    ):
        plan(_campaign(tmp_path, "{bounds: {M_q: [.nan, 0.0]}}"))
    # unset, the option stays out of the key (stored results keep their keys)
    assert "bounds" not in IdentifyOptions().key_document()
    names = "parameters: [Z_alpha, M_alpha, M_q, M_delta]"
    keys = {}
    for label, extra in (("none", ""), ("bounded", ", bounds: {M_q: [-1.52, null]}")):
        p = plan(_campaign(tmp_path, "{" + names + extra + "}"))
        keys[label] = {t.step: t for t in p.tasks if t.flight is not None}
    assert keys["none"]["identify"].key != keys["bounded"]["identify"].key
    assert keys["none"]["load"].key == keys["bounded"]["load"].key
    tasks = keys["bounded"]
    root = str(tmp_path / "store")
    loaded = execute_task(tasks["load"], root)
    status = execute_task(tasks["identify"], root, loaded)
    assert status["status"] == "computed", status.get("error")
    fit = open_store(root).load(tasks["identify"].key, "identify")
    # this flight's M_q optimum (about -1.58) lies below the bound
    assert fit.parameters["M_q"] == -1.52
    assert dict(fit.active_bounds) == {"M_q": "lower"}
    assert dict(fit.bounds) == {"M_q": (-1.52, math.inf)}


def test_every_estimate_on_its_bound_gives_zero_bars_not_an_error():
    # the coloured bars' noise model then has no free column at all
    def roll(t, x, u, p):
        return np.array([p["L_p"] * x[0] + p["L_delta"] * u[0]])

    model = Model(["p"], ["a"], {"L_p": -2.0, "L_delta": 5.0}, roll, name="roll")
    t = np.arange(0.0, 10.0, 0.02)
    a = np.sin(t)
    sim = model.simulate(t, {"a": a}, [0.0], {"L_delta": 8.0})
    noisy = sim.states[:, 0] + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    data = FlightData(t, {"p": noisy, "a": a})
    fit = identify(model, data, ["L_delta"], x0={"p": 0.0}, bounds={"L_delta": (None, 6.0)})
    assert fit.parameters["L_delta"] == 6.0 and fit.active_bounds == {"L_delta": "upper"}
    assert fit.stderr["L_delta"] == 0.0 and "at upper" in fit.summary()
