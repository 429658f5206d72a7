"""Cubic controls in the compiled (JAX) programs: the same RK4 steps as numpy's.

The programs take the controls' excess over straight lines per interval beside
them (`control_excess`, zero for straight lines). With the cubic they must agree
with the numpy RK4 to rounding (rollouts, sampler outputs, filter passes) and
their sensitivities with the derivative of the numpy simulation; the closed-form
tests of `test_control_interpolation` pass through them too.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import test_control_interpolation as closed

from aeroid import FlightData, Model, identify
from aeroid.errors import IdentificationError
from aeroid.estimation import _ekf_compiled
from aeroid.estimation import _filter_steady as steady
from aeroid.estimation.filtering import build_problem, run_filter
from aeroid.models import compiled as _compiled
from aeroid.models import integration as _integrate
from aeroid.models.batch_simulator import BatchSimulator
from aeroid.models.integration import control_excess, controls_at

pytest.importorskip("jax")

TRUTH = {"za": 1.4, "zu": -0.3, "ma": -6.0, "mq": -2.5, "mu": -8.0}
X0 = np.array([0.05, 0.0])


def _dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    alpha, q = x
    a_dot = q - p["za"] * np.sin(alpha) + p["zu"] * u[1] * np.cos(alpha)
    q_dot = p["ma"] * np.sin(alpha) + p["mq"] * q + p["mu"] * u[0] * (1.0 + 0.3 * alpha**2)
    return np.array([a_dot, q_dot])


def _measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
    alpha, q = x
    q_dot = p["ma"] * np.sin(alpha) + p["mq"] * q + p["mu"] * u[0] * (1.0 + 0.3 * alpha**2)
    return np.array([alpha, q, q_dot])


def _model(name: str) -> Model:
    return Model(
        ["alpha", "q"],
        ["de", "dt"],
        dict(TRUTH),
        _dynamics,
        outputs=["alpha", "q", "qdot"],
        measurement=_measurement,
        name=name,
    )


def _record(n: int = 151, dt: float = 0.04) -> tuple[np.ndarray, np.ndarray]:
    """Smooth controls sampled coarsely (1.3 rad per sample at the top): the cubic and
    the straight lines differ visibly."""
    t = np.arange(n) * dt
    u = np.stack(
        [0.05 * np.sin(4.0 * t) + 0.03 * np.sin(11.0 * t + 0.4), 0.1 * np.cos(7.0 * t)],
        axis=1,
    )
    return t, u


CUBIC: list[Any] = ["cubic", ("cubic", "linear")]


@pytest.fixture
def compiled_now(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, int]]:
    """Compile from the first call on (foreground), counting the compiled programs run
    with cubic controls."""
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    monkeypatch.setattr(_compiled, "SENSITIVITIES_AFTER_CALLS", 0)
    monkeypatch.setattr(_compiled, "BACKGROUND", False)
    seen = {"states": 0, "sensitivities": 0, "interval": 0, "ekf": 0, "predictor": 0}

    def spy(name: str, fn: Any, pos: int) -> Any:
        def wrapped(*args: Any, **kw: Any) -> Any:
            got = fn(*args, **kw)
            how = args[pos] if len(args) > pos else kw.get("interpolation", "linear")
            if got is not None and how != "linear":
                seen[name] += 1
            return got

        return wrapped

    monkeypatch.setattr(_compiled, "rk4_states", spy("states", _compiled.rk4_states, 6))
    monkeypatch.setattr(
        _compiled, "_sensitivities", spy("sensitivities", _compiled._sensitivities, 8)
    )
    monkeypatch.setattr(
        _compiled, "interval_propagator", spy("interval", _compiled.interval_propagator, 6)
    )
    monkeypatch.setattr(_ekf_compiled, "ekf_pass", spy("ekf", _ekf_compiled.ekf_pass, 11))
    predictor = steady._compiled_predictor

    def counted(prob: Any, *args: Any) -> Any:
        got = predictor(prob, *args)
        if got is not None and prob.interpolation != "linear":
            seen["predictor"] += 1
        return got

    monkeypatch.setattr(steady, "_compiled_predictor", counted)
    yield seen


def test_excess_is_zero_for_straight_lines_and_the_cubic_otherwise():
    t, u = _record(21)
    assert np.array_equal(control_excess(t, u), np.zeros((20, 2, 2)))
    e = control_excess(t, u, ("linear", "cubic"))
    assert np.array_equal(e[:, :, 0], np.zeros((20, 2))) and np.all(e[:, :, 1] != 0.0)
    # the node a program builds from it is `controls_at`'s cubic
    s = 0.25
    node = u[:-1] + s * (u[1:] - u[:-1]) + s * (1 - s) * ((1 - s) * e[:, 0] - s * e[:, 1])
    want = controls_at(t, u, t[:-1] + s * np.diff(t), ("linear", "cubic"))
    np.testing.assert_allclose(node, want, rtol=0, atol=1e-15)


@pytest.mark.parametrize("how", CUBIC)
@pytest.mark.parametrize("substeps", [1, 3])
def test_compiled_rollout_is_numpy_rk4_with_the_cubic(how, substeps):
    model = _model("roll")
    t, u = _record()
    P = {k: np.array([v, 1.1 * v]) for k, v in TRUTH.items()}
    x0 = np.repeat(X0[:, None], 2, axis=1)
    for U in (np.repeat(u[None], 2, axis=0), np.stack([u, 0.7 * u])):  # shared, per member
        got = _compiled.rk4_states(model, t, x0, U, P, substeps, how)
        assert got is not None
        want = _integrate.rk4(model._dynamics_batch, t, x0, U, P, substeps, how)
        straight = _integrate.rk4(model._dynamics_batch, t, x0, U, P, substeps)
        np.testing.assert_allclose(got.states, want.states, rtol=0, atol=1e-13)
        assert np.max(np.abs(straight.states - want.states)) > 1e-5


@pytest.mark.parametrize("how", CUBIC)
def test_compiled_sampler_outputs_are_simulate_batch_with_the_cubic(how, monkeypatch):
    model = _model("sampler")
    t, u = _record()
    mapping = {"de": how} if isinstance(how, str) else dict(zip(model.controls, how, strict=True))
    batch = {"mq": np.array([-2.5, -2.0, -3.0]), "mu": np.array([-8.0, -7.0, -9.0])}
    want = model.simulate_batch(t, u, X0, batch, method="rk4", control_interpolation=mapping)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    sim = BatchSimulator(model, t, u, X0, method="rk4", control_interpolation=mapping)
    sim.repeated = 10
    fast = sim._compiled_outputs(batch, [0, 1, 2])
    assert fast is not None  # the compiled program ran
    np.testing.assert_allclose(fast, want.outputs, rtol=0, atol=1e-12)
    # and `simulate_batch` itself, once compiled, runs the same program
    again = model.simulate_batch(t, u, X0, batch, method="rk4", control_interpolation=mapping)
    assert _compiled._entry(model).get("compiled_once")
    np.testing.assert_allclose(again.outputs, want.outputs, rtol=0, atol=1e-12)


def _richardson(model: Model, t: Any, u: Any, name: str, opts: dict[str, Any]) -> Any:
    """d outputs / d parameter of the numpy simulation: central differences at h and
    h/2 extrapolated (error h^4)."""

    def diff(h: float) -> Any:
        p = {name: np.array([TRUTH[name] + h, TRUTH[name] - h])}
        y = model.simulate_batch(t, u, X0, p, **opts).outputs
        return (y[0] - y[1]) / (2 * h)

    h = 1e-3 * abs(TRUTH[name])
    return (4.0 * diff(h / 2) - diff(h)) / 3.0


@pytest.mark.parametrize("how", CUBIC)
def test_output_error_sensitivities_are_the_derivative_of_the_cubic(how, monkeypatch):
    model = _model("sens")
    t, u = _record()
    opts = {"method": "rk4", "substeps": 2, "control_interpolation": how}
    monkeypatch.setattr(_compiled, "SENSITIVITIES_AFTER_CALLS", 0)
    got = _compiled.output_sensitivities(model, t, u, X0, TRUTH, ["ma", "mu"], [0], opts)
    assert got is not None
    y, J = got
    monkeypatch.setattr(_compiled, "ENABLED", False)
    plain = model.simulate_batch(t, u, X0, {}, **opts)
    np.testing.assert_allclose(y, plain.outputs[0], rtol=0, atol=1e-13)
    for c, name in enumerate(["ma", "mu"]):
        want = _richardson(model, t, u, name, opts)
        scale = np.max(np.abs(want), axis=0)
        assert np.max(np.abs(J[:, :, c] - want) / scale) < 1e-9
    # the straight lines' sensitivities differ: the program took the cubic
    monkeypatch.setattr(_compiled, "ENABLED", True)
    lin = {**opts, "control_interpolation": "linear"}
    _, J_lin = _compiled.output_sensitivities(model, t, u, X0, TRUTH, ["ma", "mu"], [0], lin)
    assert np.max(np.abs(J_lin[:, :, 1] - J[:, :, 1])) > 1e-3 * np.max(np.abs(J[:, :, 1]))


def test_output_error_recovers_the_truth_compiled_and_in_numpy(compiled_now, monkeypatch):
    # noise-free outputs simulated with the cubic: the fit returns the truth both ways
    model = _model("oe")
    t, u = _record()
    y = model.simulate(t, u, X0, method="rk4", control_interpolation="cubic").outputs
    data = FlightData(t, {"de": u[:, 0], "dt": u[:, 1], "alpha": y[:, 0], "q": y[:, 1]})
    opts = {"method": "rk4", "control_interpolation": "cubic"}
    fits = {}
    for path in ("compiled", "numpy"):
        if path == "numpy":
            monkeypatch.setattr(_compiled, "ENABLED", False)
        start = {k: 0.9 * TRUTH[k] for k in ("ma", "mq", "mu")}
        r = identify(model, data, start, outputs=["alpha", "q"], simulate_options=opts)
        fits[path] = r.parameters
    assert compiled_now["sensitivities"] > 0
    for name in ("ma", "mq", "mu"):
        for path in fits:
            assert fits[path][name] == pytest.approx(TRUTH[name], rel=1e-7), (path, name)


def _filter_problem(how: Any) -> tuple[Any, ...]:
    model = _model("kf")
    t, u = _record()
    rng = np.random.default_rng(3)
    y = model.simulate(t, u, X0, method="rk4", control_interpolation=how).outputs
    data = FlightData(
        t,
        {
            "de": u[:, 0],
            "dt": u[:, 1],
            "alpha": y[:, 0] + 1e-3 * rng.standard_normal(t.size),
            "q": y[:, 1] + 1e-3 * rng.standard_normal(t.size),
        },
    )
    prob, R = build_problem(
        model,
        data,
        outputs=["alpha", "q"],
        measurement_noise={"alpha": 1e-6, "q": 1e-6},
        x0=None,
        P0=None,
        substeps=2,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=IdentificationError,
        control_interpolation=how,
    )
    B = 2
    params = {k: np.array([v, 1.05 * v]) for k, v in TRUTH.items()}
    Qc = np.repeat(np.diag([1e-5, 1e-3])[None], B, axis=0)
    x0 = np.repeat(prob.x0[None], B, axis=0)
    P0 = np.repeat(prob.P0[None], B, axis=0)
    Rb = np.repeat(R[None], B, axis=0)
    return model, prob, (prob, params, Qc, Rb, x0, P0)


@pytest.mark.parametrize("how", CUBIC)
def test_filter_passes_compiled_are_the_numpy_ones_with_the_cubic(how, compiled_now, monkeypatch):
    model, prob, args = _filter_problem(how)
    ekf = run_filter(*args)
    assert compiled_now["ekf"] > 0 and compiled_now["interval"] > 0
    predictor = steady.steady_pass(*args)
    assert compiled_now["predictor"] > 0
    start = steady.start_states(prob, TRUTH, args[2][0])
    assert start is not None and compiled_now["states"] > 0
    monkeypatch.setattr(_compiled, "ENABLED", False)
    for fast, plain in ((ekf, run_filter(*args)), (predictor, steady.steady_pass(*args))):
        assert np.all(fast.ok) and np.all(plain.ok)
        np.testing.assert_allclose(fast.nu, plain.nu, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast.xf, plain.xf, rtol=0, atol=1e-12)
    sim = model.simulate(prob.time, prob.U, prob.x0, method="rk4", substeps=2)
    cubic = model.simulate(
        prob.time, prob.U, prob.x0, method="rk4", substeps=2, control_interpolation=how
    )
    np.testing.assert_allclose(start, cubic.states, rtol=0, atol=1e-13)
    assert np.max(np.abs(sim.states - cubic.states)) > 1e-5


def test_filter_error_likelihood_compiled_is_the_numpy_one(compiled_now, monkeypatch):
    model, prob, _ = _filter_problem("cubic")
    data = FlightData(
        prob.time,
        {"de": prob.U[:, 0], "dt": prob.U[:, 1], "alpha": prob.Y[:, 0], "q": prob.Y[:, 1]},
    )
    kw: dict[str, Any] = {
        "method": "filter_error",
        "process_noise": {"alpha": 1e-5, "q": 1e-3},
        "measurement_noise": {"alpha": 1e-6, "q": 1e-6},
        "filter_options": {"control_interpolation": "cubic", "substeps": 2},
        "max_iterations": 3,
    }
    fast = identify(model, data, ["ma", "mu"], **kw)
    assert compiled_now["predictor"] > 0
    monkeypatch.setattr(_compiled, "ENABLED", False)
    plain = identify(model, data, ["ma", "mu"], **kw)
    # the passes agree to rounding; the forward differences of the likelihood (steps
    # 1e-5 of a parameter) magnify that to about 1e-9 in a Gauss-Newton step
    assert fast.cost == pytest.approx(plain.cost, rel=1e-10)
    for name in ("ma", "mu"):
        assert fast.parameters[name] == pytest.approx(plain.parameters[name], rel=1e-6)
        assert fast.stderr[name] == pytest.approx(plain.stderr[name], rel=1e-5)


@pytest.fixture
def fresh_models(monkeypatch: pytest.MonkeyPatch) -> None:
    """The closed-form tests' models anew: nothing compiled or decided before."""
    monkeypatch.setattr(
        closed, "INTEGRATOR", Model(["x"], ["u"], {"g": 1.0}, closed._integrator, name="i2")
    )
    monkeypatch.setattr(
        closed, "LAG", Model(["x"], ["u"], {"a": 2.0, "b": 1.0}, closed._lag, name="lag2")
    )


def test_closed_form_simulations_through_the_compiled_rollout(compiled_now, fresh_models):
    closed.test_convergence_order_of_the_integral_of_a_sine("rk4")
    closed.test_a_cubic_input_is_integrated_exactly_inside_the_record()
    closed.test_a_mapping_names_the_cubic_controls()
    assert compiled_now["states"] >= 5


def test_closed_form_filter_through_the_compiled_pass(compiled_now, fresh_models):
    closed.test_filter_states_propagates_the_cubic()
    assert compiled_now["ekf"] > 0


@pytest.mark.parametrize("method", ["output_error", "filter_error"])
def test_closed_form_control_derivative_through_the_compiled_programs(
    method, compiled_now, fresh_models
):
    closed.test_a_control_derivative_from_a_coarse_sine(method)
    if method == "output_error":
        assert compiled_now["sensitivities"] > 0
    else:  # the fit's steady-gain predictor, its start rollout and filter passes
        assert compiled_now["predictor"] > 0 and compiled_now["interval"] > 0


def test_validate_simulates_with_the_fits_controls():
    # a record the model flew with cubic controls, noise-free: validate's simulation with
    # the same `simulate_options` leaves no residual, with straight lines it does
    from aeroid import validate

    model = _model("validate")
    t, u = _record()
    y = model.simulate(t, u, X0, method="rk4", control_interpolation={"de": "cubic"}).outputs
    data = FlightData(t, {"de": u[:, 0], "dt": u[:, 1], "alpha": y[:, 0], "q": y[:, 1]})
    opts = {"method": "rk4", "control_interpolation": {"de": "cubic"}}
    same = validate(model, data, dict(TRUTH), x0=X0, simulate_options=opts)
    straight = validate(model, data, dict(TRUTH), x0=X0, simulate_options={"method": "rk4"})
    assert np.max(np.abs(same.residuals)) < 1e-12
    assert np.max(np.abs(straight.residuals)) > 1e-5


def _jnp_model() -> Model:
    import jax.numpy as jnp

    def dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
        a_dot = x[1] - p["za"] * jnp.sin(x[0]) + p["zu"] * u[1] * jnp.cos(x[0])
        q_dot = p["ma"] * jnp.sin(x[0]) + p["mq"] * x[1] + p["mu"] * u[0] * (1 + 0.3 * x[0] ** 2)
        return jnp.stack([a_dot, q_dot])

    return Model(["alpha", "q"], ["de", "dt"], dict(TRUTH), dynamics, name="jnp")


@pytest.mark.parametrize("substeps", [1, 3, 10])
def test_gradient_jax_rollout_and_jacobian_take_the_cubic(substeps, monkeypatch):
    from aeroid.models import jax_compiled

    model = _jnp_model()
    t, u = _record()
    how = {"de": "cubic", "dt": "cubic"}
    got = jax_compiled.rollout(
        model, t, u, X0, TRUTH, substeps=substeps, control_interpolation=how
    )[2]
    want = model.simulate(
        t, u, X0, method="rk4", substeps=substeps, control_interpolation=how
    ).states
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    y, J = jax_compiled.outputs_and_jacobian(
        model, t, u, X0, TRUTH, ["mu"], substeps=substeps, control_interpolation=how
    )
    opts = {"method": "rk4", "substeps": substeps, "control_interpolation": how}
    monkeypatch.setattr(_compiled, "ENABLED", False)
    d = _richardson(model, t, u, "mu", opts)
    assert np.max(np.abs(J[:, :, 0] - d)) < 1e-9 * np.max(np.abs(d))
    batch = jax_compiled.batch_outputs(
        model, t, u, X0, {"mu": np.array([-8.0])}, substeps=substeps, control_interpolation=how
    )
    np.testing.assert_allclose(batch[0], y, rtol=0, atol=1e-14)


def test_gradient_jax_fit_recovers_the_truth_with_the_cubic():
    model = _jnp_model()
    t, u = _record()
    y = model.simulate(t, u, X0, method="rk4", substeps=2, control_interpolation="cubic")
    data = FlightData(
        t, {"de": u[:, 0], "dt": u[:, 1], "alpha": y.states[:, 0], "q": y.states[:, 1]}
    )
    start = {k: 0.9 * TRUTH[k] for k in ("ma", "mq", "mu")}
    opts = {"substeps": 2, "control_interpolation": "cubic"}
    r = identify(model, data, start, gradient="jax", simulate_options=opts)
    for name in start:
        assert r.parameters[name] == pytest.approx(TRUTH[name], rel=1e-7)


def test_the_jax_likelihood_takes_the_cubic():
    # infer's backend="jax" and the numpy one (its compiled sampler batches) score the
    # same cubic controls; straight lines score otherwise
    from aeroid.uncertainty._posterior import _Posterior
    from aeroid.uncertainty.priors import Normal

    model = _jnp_model()
    t, u = _record()
    y = model.simulate(t, u, X0, method="rk4", substeps=2, control_interpolation="cubic")
    data = FlightData(
        t, {"de": u[:, 0], "dt": u[:, 1], "alpha": y.states[:, 0], "q": y.states[:, 1]}
    )
    priors = {"ma": Normal(-6.0, 3.0), "mu": Normal(-8.0, 4.0)}
    kw: dict[str, Any] = {"outputs": None, "noise": {"alpha": 1e-3, "q": 1e-3}, "x0": X0}
    cubic = {"substeps": 2, "control_interpolation": {"de": "cubic", "dt": "cubic"}}
    jx = _Posterior(model, data, priors, backend="jax", simulate_options=cubic, **kw)
    npy = _Posterior(model, data, priors, backend="numpy", simulate_options=cubic, **kw)
    straight = _Posterior(
        model, data, priors, backend="jax", simulate_options={"substeps": 2}, **kw
    )
    theta = np.array([[-6.0, -8.0], [-5.5, -8.5]])
    a, b, c = jx(theta), npy(theta), straight(theta)
    np.testing.assert_allclose(a, b, rtol=1e-10)
    assert a[0] > c[0] + 1.0  # the truth scores best with the controls it flew
