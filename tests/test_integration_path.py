"""The automatic RK4 step follows the path, not only its start; no solver spins on NaN."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import FlightData, Model, SimulationError, identify, sensitivities, validate
from aeroid.models import integration

TRUTH = {"c": 10.0, "b": 10.0}


def _cubic(values: dict[str, float]) -> Model:
    # -c x^3: no mode at all at rest, a stiff one (-3 c x^2, about -90 /s) once x grows
    return Model(
        states=["x"],
        controls=["u"],
        parameters=values,
        dynamics=lambda t, x, u, p: np.array([-p["c"] * x[0] ** 3 + p["b"] * u[0]]),
    )


def _record(rate: float) -> FlightData:
    t = np.arange(0.0, 4.0, 1.0 / rate)
    u = np.where((t > 0.5) & (t < 2.5), 5.0, 0.0)
    exact = _cubic(TRUTH).simulate(t, {"u": u}, x0=[0.0], method="DOP853", rtol=1e-11, atol=1e-13)
    return FlightData(t, {"x": exact.state("x"), "u": u})


@pytest.mark.parametrize("rate", [10.0, 20.0, 50.0])
def test_a_path_that_stiffens_is_simulated_and_fitted_to_the_truth(rate):
    data = _record(rate)
    # the rule at the start (x = 0) alone asks for one substep, which at 20 Hz
    # oscillates and at 10 Hz diverges
    f = _cubic(TRUTH)._dynamics_batch
    p = {k: np.array([v]) for k, v in TRUTH.items()}
    u = data.array(["u"])[None]
    assert integration.auto_substeps(f, data.time, np.zeros((1, 1)), u, p) == 1
    states = data.array(["x"])
    assert integration.trajectory_substeps(f, data.time, states, u[0], p) > 1
    checked = validate(_cubic(TRUTH), data, TRUTH)
    assert checked.metrics["x"].rmse < 1e-6
    fit = identify(_cubic({"c": 8.0, "b": 8.0}), data, ["c", "b"])
    assert fit.success
    for name, value in TRUTH.items():
        assert fit.parameters[name] == pytest.approx(value, rel=1e-5)
    sens = sensitivities(_cubic(TRUTH), data, ["c", "b"], noise={"x": 0.01})
    step = 1e-4 * TRUTH["c"]
    sides = [
        _cubic({**TRUTH, "c": TRUTH["c"] + d}).simulate(
            data.time, {"u": data["u"]}, x0=[0.0], method="DOP853", rtol=1e-11, atol=1e-13
        )
        for d in (step, -step)
    ]
    central = (sides[0].state("x") - sides[1].state("x")) / (2 * step)
    np.testing.assert_allclose(sens.sensitivity("x", "c"), central, rtol=1e-3, atol=1e-6)


@pytest.mark.parametrize("method", ["RK45", "DOP853", "Radau", "BDF", "LSODA", "auto"])
@pytest.mark.parametrize("late", [False, True])
def test_dynamics_that_turn_nan_fail_at_once_naming_the_state(method, late):
    def f(t, x, u, p):
        bad = np.any(np.asarray(t) > 0.5) if late else True
        return np.array([-p["k"] * x[0] + (np.nan if bad else 0.0)])

    model = Model(states=["x"], controls=[], parameters={"k": 1.0}, dynamics=f)
    # named with the time the solver got to (an implicit method returns no states)
    when = r"0\.[567]" if late else r"0(\.1)?"
    with pytest.raises(
        SimulationError,
        match=rf"(state 'x' is|states \['x'\] are) not finite (at|from) t = {when} s",
    ):
        model.simulate(np.linspace(0.0, 1.0, 11), x0=[1.0], method=method)


def test_the_kalman_filter_steps_as_finely_as_the_path_asks():
    from aeroid import filter_states

    data = _record(20.0)
    noisy = data.with_channels(
        {"x": data["x"] + np.random.default_rng(0).normal(0.0, 0.01, data.n_samples)}
    )
    model = _cubic(TRUTH)
    run = dict(process_noise={"x": 1e-6}, measurement_noise={"x": 1e-4})
    filtered = filter_states(model, noisy, None, **run)
    # one substep (the rule at rest) diverged: innovations 10^4 times their variance
    assert 0.7 < float(np.var(filtered.innovation("x"))) / 1e-4 < 1.3
    assert np.sqrt(np.mean((filtered.smoothed_state("x") - data["x"]) ** 2)) < 0.01
    fit = identify(_cubic({"c": 8.0, "b": 8.0}), noisy, ["c", "b"], method="filter_error", **run)
    for name, value in TRUTH.items():
        assert fit.parameters[name] == pytest.approx(value, rel=0.03)


def test_a_noisy_fit_and_the_posterior_step_as_finely_as_the_path_asks():
    from aeroid import Normal, infer

    data = _record(20.0)
    noisy = data.with_channels(
        {"x": data["x"] + np.random.default_rng(0).normal(0.0, 0.01, data.n_samples)}
    )
    # with one substep the cost is too rough to descend: the fit stopped 12 % off
    fit = identify(_cubic({"c": 8.0, "b": 8.0}), noisy, ["c", "b"], x0=[0.0], estimate_x0=False)
    assert fit.success
    for name, value in TRUTH.items():
        assert abs(fit.parameters[name] - value) < 4 * fit.stderr[name]
    # the sampler's compiled programs read the modes at the start: c came out near 5
    post = infer(
        _cubic({"c": 8.0, "b": 8.0}),
        noisy,
        {"c": Normal(10.0, 3.0), "b": Normal(10.0, 3.0)},
        noise={"x": 0.01},
        x0=[0.0],
        initial=fit,
        n_steps=300,
        seed=0,
    )
    for name, value in TRUTH.items():
        assert abs(post.parameters[name] - value) < 4 * post.stderr[name]


def test_a_refit_on_a_finer_step_keeps_only_its_own_warnings():
    # near-discontinuous friction: the first fit, on the start's coarse step, stops
    # without converging and warns so; the refit on the step the fitted path asks for
    # converges, and the result's flag and warnings must agree
    import warnings

    def friction(t, x, u, p):
        slip = np.tanh(x[1] / 0.002)
        return np.array([x[1], -p["k"] * x[0] - p["c"] * x[1] - p["Fc"] * slip + u[0]])

    model = Model(["x", "v"], ["F"], {"k": 4.0, "c": 0.2, "Fc": 0.2}, friction, name="slip")
    t = np.arange(0.0, 10.0, 0.02)
    pulses = ((0.5, 2.0, 1.0), (2.0, 3.0, -1.0), (3.0, 3.5, 1.0), (3.5, 4.0, -1.0))
    force = np.zeros_like(t)
    for a, b, sign in pulses:
        force = np.where((t >= a) & (t < b), 2.0 * sign, force)
    truth = {"k": 5.0, "c": 0.3, "Fc": 0.4}
    sim = model.simulate(t, {"F": force}, [0.0, 0.0], truth, rtol=1e-10, atol=1e-12)
    rng = np.random.default_rng(1)
    channels = {"x": sim.states[:, 0] + 0.005 * rng.standard_normal(t.size)}
    channels["v"] = sim.states[:, 1] + 0.01 * rng.standard_normal(t.size)
    data = FlightData(t, {**channels, "F": force})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = identify(model, data, list(truth))
    assert fit.success, fit.message
    assert not [w for w in caught if "success=False" in str(w.message)]
    for k, v in truth.items():
        assert abs(fit.parameters[k] - v) < 4.0 * fit.stderr[k], k


def test_exact_on_a_jittered_grid_blames_the_grid_not_the_model():
    def f(t, x, u, p):
        return np.stack([-p["a"] * x[0] + u[0]])

    model = Model(states=["x"], controls=["u"], parameters={"a": 1.0}, dynamics=f, linear=True)
    t = np.arange(101) * 0.02 + np.random.default_rng(0).uniform(-1e-4, 1e-4, 101)
    t[0] = 0.0
    with pytest.raises(
        SimulationError, match="takes at most 64 distinct sample intervals; this time grid has 100"
    ):
        model.simulate(t, np.sin(t)[:, None], method="exact")
    model.simulate(t, np.sin(t)[:, None], method="auto")  # RK4 takes it
