"""Compiled simulation of numpy-written nonlinear models (aeroid.models.compiled).

The compiled RK4 must reproduce the numpy RK4 (states, outputs), its
sensitivities must match finite differences of the numpy path,
and `identify` must give the same estimates and standard errors either way.
Models JAX cannot trace, and a missing JAX, fall back to numpy.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid._threads import wait_background
from aeroid.models import compiled as _compiled

pytest.importorskip("jax")

RHO, S, CBAR, MASS, IYY, G = 1.225, 16.2, 1.5, 1100.0, 1800.0, 9.81
TRUTH = {
    "CD0": 0.03,
    "CD_alpha": 0.25,
    "CL0": 0.25,
    "CL_alpha": 4.8,
    "CL_q": 7.0,
    "CL_de": 0.4,
    "Cm0": 0.02,
    "Cm_alpha": -0.7,
    "Cm_q": -12.0,
    "Cm_de": -1.1,
}
OUTPUTS = ["V", "alpha", "theta", "q", "qdot", "ax", "az"]
X0 = np.array([40.0, 0.06, 0.06, 0.0])
FIT = ["CD0", "CL_alpha", "CL_de", "Cm0", "Cm_alpha", "Cm_q", "Cm_de"]


def _coefficients(x: Any, u: Any, p: Any) -> Any:
    V, alpha, _theta, q = x
    qbar = 0.5 * RHO * V**2
    qh = q * CBAR / (2.0 * V)
    CD = p["CD0"] + p["CD_alpha"] * alpha
    CL = p["CL0"] + p["CL_alpha"] * alpha + p["CL_q"] * qh + p["CL_de"] * u[0]
    Cm = p["Cm0"] + p["Cm_alpha"] * alpha + p["Cm_q"] * qh + p["Cm_de"] * u[0]
    return qbar, CD, CL, Cm


def _dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    V, alpha, theta, q = x
    qbar, CD, CL, Cm = _coefficients(x, u, p)
    thrust = u[1]
    v_dot = (thrust * np.cos(alpha) - qbar * S * CD) / MASS - G * np.sin(theta - alpha)
    a_dot = q + (-thrust * np.sin(alpha) - qbar * S * CL) / (MASS * V)
    a_dot = a_dot + G * np.cos(theta - alpha) / V
    return np.array([v_dot, a_dot, q, qbar * S * CBAR * Cm / IYY])


def _measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
    V, alpha, theta, q = x
    qbar, CD, CL, Cm = _coefficients(x, u, p)
    ax = (qbar * S * (CL * np.sin(alpha) - CD * np.cos(alpha)) + u[1]) / MASS
    az = qbar * S * (-CL * np.cos(alpha) - CD * np.sin(alpha)) / MASS
    return np.array([V, alpha, theta, q, qbar * S * CBAR * Cm / IYY, ax, az])


def _untraceable(t: Any, x: Any, u: Any, p: Any) -> Any:
    # a Python branch on the state: fine for numpy batches, untraceable by JAX
    if np.any(np.abs(x[1]) > 1e3):
        raise ValueError("angle of attack out of range")
    return _dynamics(t, x, u, p)


def _longitudinal(dynamics: Any = _dynamics, name: str = "lon") -> aeroid.Model:
    return aeroid.Model(
        ["V", "alpha", "theta", "q"],
        ["de", "thrust"],
        dict(TRUTH),
        dynamics,
        outputs=OUTPUTS,
        measurement=_measurement,
        name=name,
    )


def _controls(t: np.ndarray) -> np.ndarray:
    de = -0.05 + 0.02 * np.sign(np.sin(2 * np.pi * t / 3.0)) * ((t > 1.0) & (t < 13.0))
    thrust = 2200.0 + 300.0 * ((t > 14.0) & (t < 17.0))
    return np.stack([de, thrust], axis=1)


def _flight(model: aeroid.Model, seed: int) -> aeroid.FlightData:
    t = np.arange(201) * 0.1
    u = _controls(t)
    sim = model.simulate(t, {"de": u[:, 0], "thrust": u[:, 1]}, X0, method="rk4", substeps=8)
    rng = np.random.default_rng(seed)
    sigma = np.array([0.2, 0.002, 0.002, 0.003, 0.01, 0.05, 0.1])
    bias = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.1, -0.2])
    y = sim.outputs + rng.standard_normal(sim.outputs.shape) * sigma + bias
    channels = {n: y[:, j] for j, n in enumerate(OUTPUTS)}
    channels.update(de=u[:, 0], thrust=u[:, 1])
    return aeroid.FlightData(time=t, channels=channels)


@pytest.fixture(scope="module")
def lon() -> aeroid.Model:
    return _longitudinal()


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    scale = np.max(np.abs(b), axis=tuple(range(b.ndim - 1)), keepdims=True) + 1e-300
    return float(np.max(np.abs(a - b) / scale))


def test_translated_rk4_matches_numpy_rk4(lon: aeroid.Model, monkeypatch: Any) -> None:
    t = np.arange(201) * 0.1
    u = _controls(t)
    params = {"Cm_q": np.array([-12.0, -10.0, -14.0]), "CL_alpha": np.array([4.8, 5.0, 4.5])}
    x0 = X0[None, :] + np.array([[0.0], [1.0], [-2.0]])
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    fast = lon.simulate_batch(t, u, x0, params, method="rk4", substeps=3)
    assert _compiled._CACHE[lon][("fn", "dynamics")] is not None  # it compiled
    monkeypatch.setattr(_compiled, "ENABLED", False)
    slow = lon.simulate_batch(t, u, x0, params, method="rk4", substeps=3)
    assert fast.ok.all() and slow.ok.all()
    assert _rel(fast.states, slow.states) < 1e-12
    assert _rel(fast.outputs, slow.outputs) < 1e-12
    # and both converge to the adaptive solution (the step really is RK4 with 3 substeps)
    ref = lon.simulate(t, u, X0, {"Cm_q": -12.0, "CL_alpha": 4.8})
    assert _rel(fast.states[0], ref.states) < 1e-5


def test_sensitivities_match_finite_differences(lon: aeroid.Model, monkeypatch: Any) -> None:
    t = np.arange(201) * 0.1
    u = _controls(t)
    p = dict(TRUTH)
    opts = {"method": "auto", "substeps": 2}
    got = _compiled.output_sensitivities(lon, t, u, X0, p, FIT, [0, 1], opts)
    assert got is not None
    y, jac = got
    assert jac.shape == (201, 7, len(FIT) + 2)
    monkeypatch.setattr(_compiled, "ENABLED", False)
    base = lon.simulate_batch(t, u, X0, {k: np.array([v]) for k, v in p.items()}, **opts)
    assert _rel(y, base.outputs[0]) < 1e-12
    # Richardson-extrapolated central differences of the numpy path: error O(h^4)
    cols = [*FIT, "x0.V", "x0.alpha"]
    for c, name in enumerate(cols):
        if name not in ("CD0", "Cm_q", "Cm_de", "x0.alpha"):
            continue  # a few columns keep the test short
        value = p[name] if c < len(FIT) else X0[c - len(FIT)]
        h = 1e-3 * max(abs(value), 0.1)

        def sim(delta: float, name: str = name, c: int = c) -> np.ndarray:
            pp = {k: np.array([v]) for k, v in p.items()}
            x = X0.copy()
            if c < len(FIT):
                pp[name] = pp[name] + delta
            else:
                x[c - len(FIT)] += delta
            return np.asarray(lon.simulate_batch(t, u, x, pp, **opts).outputs[0])

        d1 = (sim(h) - sim(-h)) / (2 * h)
        d2 = (sim(h / 2) - sim(-h / 2)) / h
        fd = (4 * d2 - d1) / 3
        assert _rel(jac[:, :, c], fd) < 1e-8, name


def _fit(model: aeroid.Model, data: aeroid.FlightData, gradient: str) -> Any:
    guess = {k: 1.15 * TRUTH[k] for k in FIT}
    return aeroid.identify(
        model,
        data,
        guess,
        estimate_bias=["ax", "az"],
        estimate_x0=["V", "alpha"],
        gradient=gradient,
        tolerance=1e-12,
    )


@pytest.mark.slow
def test_identify_compiled_equals_numpy(lon: aeroid.Model, monkeypatch: Any) -> None:
    data = _flight(lon, seed=3)
    fast = _fit(lon, data, "auto")
    assert getattr(fast, "success", True)
    monkeypatch.setattr(_compiled, "ENABLED", False)
    slow = _fit(_longitudinal(name="lon_numpy"), data, "fd")
    # Near the optimum the cost changes by (step/stderr)^2: a Gauss-Newton stop can place
    # the estimate only to about 1e-6 of a standard error, whatever the Jacobian.
    for k in FIT:
        assert abs(fast.parameters[k] - slow.parameters[k]) < 1e-5 * slow.stderr[k], k
        assert fast.parameters[k] == pytest.approx(slow.parameters[k], rel=1e-7), k
        # the numpy path's finite-difference Jacobian is itself good to about 1e-8
        assert fast.stderr[k] == pytest.approx(slow.stderr[k], rel=1e-6), k
        # and the seeded truth is recovered
        assert abs(fast.parameters[k] - TRUTH[k]) < 4.0 * fast.stderr[k], k
    for k, v in fast.extra_stderr.items():
        assert v == pytest.approx(slow.extra_stderr[k], rel=1e-6), k
    assert abs(fast.biases[0]["ax"] - slow.biases[0]["ax"]) < 1e-5 * slow.extra_stderr["bias[0].ax"]


def test_untraceable_model_falls_back(monkeypatch: Any) -> None:
    model = _longitudinal(_untraceable, name="untraceable")
    t = np.arange(201) * 0.1
    u = _controls(t)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    fast = model.simulate_batch(t, u, X0, {}, method="rk4", substeps=2)
    assert _compiled._CACHE[model][("fn", "dynamics")] is None  # decided: numpy
    assert _compiled.output_sensitivities(model, t, u, X0, TRUTH, FIT, [], {}) is None
    monkeypatch.setattr(_compiled, "ENABLED", False)
    slow = model.simulate_batch(t, u, X0, {}, method="rk4", substeps=2)
    np.testing.assert_allclose(fast.states, slow.states, rtol=1e-13)  # both numpy


@pytest.mark.slow
def test_untraceable_model_identify_recovers_truth(monkeypatch: Any) -> None:
    # compiling from the first fit on: the translation is tried and refused
    monkeypatch.setattr(_compiled, "SENSITIVITIES_AFTER_CALLS", 0)
    model = _longitudinal(_untraceable, name="untraceable_fit")
    data = _flight(model, seed=5)
    guess = {k: 1.1 * TRUTH[k] for k in FIT[:4]}
    res = aeroid.identify(
        model, data, guess, estimate_bias=["ax", "az"], estimate_x0=True, gradient="auto"
    )
    assert _compiled._CACHE[model][("fn", "dynamics")] is None
    for k in FIT[:4]:
        assert abs(res.parameters[k] - TRUTH[k]) < 4.0 * res.stderr[k], k


def test_first_fit_runs_in_numpy_and_a_later_one_compiles() -> None:
    # a short record's first fit never waits for a compilation; once fitted twice it
    # compiles in the background, and the next fit lands on the same estimate (the same RK4 rollout, exact vs batched
    # finite-difference sensitivities)
    model = _longitudinal(name="numpy_first")
    data = _flight(model, seed=7)
    guess = {k: 1.1 * TRUTH[k] for k in FIT[:4]}
    first = aeroid.identify(model, data, guess, estimate_bias=["ax", "az"])
    assert ("fn", "dynamics") not in _compiled._CACHE[model]
    aeroid.identify(model, data, guess, estimate_bias=["ax", "az"])  # queues it
    assert wait_background(120.0)  # compiled in the background
    second = aeroid.identify(model, data, guess, estimate_bias=["ax", "az"])
    assert _compiled._CACHE[model].get("sensitivities_compiled")
    for k in FIT[:4]:
        assert abs(first.parameters[k] - second.parameters[k]) < 1e-3 * first.stderr[k], k
        assert first.stderr[k] == pytest.approx(second.stderr[k], rel=1e-3), k


def test_dynamics_written_in_jax_compile_for_the_first_fit() -> None:
    # a jax.numpy function (here with a jax.lax.cond, which JAX compiles afresh on every
    # eager call) is never stepped through numpy's loops: the first fit compiles, and
    # lands on the truth of the noise-free record
    import jax
    import jax.numpy as jnp

    def pendulum(t: Any, x: Any, u: Any, p: Any) -> Any:
        damping = jax.lax.cond(x[1] > 0, lambda: p["c"], lambda: 1.5 * p["c"])
        return jnp.array([x[1], -p["a"] * jnp.sin(x[0]) - damping * x[1] + p["b"] * u[0]])

    model = aeroid.Model(
        ["theta", "omega"], ["tau"], {"a": 9.0, "c": 0.5, "b": 2.0}, pendulum, name="lax"
    )
    t = np.arange(41) * 0.05
    u = np.where(t < 1.0, 1.0, -1.0)
    sim = model.simulate(t, {"tau": u}, [0.1, 0.0], {"a": 9.5}, method="rk4", substeps=3)
    data = aeroid.FlightData(t, {"theta": sim.states[:, 0], "omega": sim.states[:, 1], "tau": u})
    fit = aeroid.identify(
        model, data, ["a"], estimate_x0=False, simulate_options={"method": "rk4", "substeps": 3}
    )
    assert _compiled._CACHE[model].get("sensitivities_compiled")
    assert fit.parameters["a"] == pytest.approx(9.5, rel=1e-8)


def test_numpy_paths_call_a_jax_function_through_its_compilation() -> None:
    # called point by point (a function that does not broadcast), a jax.numpy function
    # is traced once per shape, not dispatched op by op (each jax.lax.cond a compilation)
    import jax
    import jax.numpy as jnp

    traces = [0]

    def damped(t: Any, x: Any, u: Any, p: Any) -> Any:
        traces[0] += 1  # runs when JAX traces the function, or on every eager call
        c = jax.lax.cond(x[1] > 0, lambda: p["c"], lambda: 1.5 * p["c"])
        return jnp.array([x[1], -p["a"] * jnp.sin(x[0]) - c * x[1] + u[0]])

    model = aeroid.Model(["th", "w"], ["u"], {"a": 9.0, "c": 0.5}, damped, name="cond")
    f = model._dynamics_batch
    p = {"a": np.array([9.0, 9.5]), "c": np.array([0.5, 0.4])}
    x = np.array([[0.1, 0.2], [0.3, -0.1]])
    first = f(0.0, x, np.zeros((1, 2)), p)
    traced = traces[0]
    for k in range(20):
        again = f(0.01 * k, x, np.zeros((1, 2)), p)
    np.testing.assert_allclose(again[:, 0], [0.3, -9.0 * np.sin(0.1) - 0.5 * 0.3], rtol=1e-12)
    np.testing.assert_allclose(again[:, 1], [-0.1, -9.5 * np.sin(0.2) + 1.5 * 0.4 * 0.1])
    assert first.shape == (2, 2) and traces[0] == traced  # no call traced it again


def test_dynamics_in_jax_that_do_not_trace_are_named_once() -> None:
    # a Python `if` on a state: JAX cannot trace it, and numpy's loops run it through
    # JAX's dispatcher a point at a time; the user is told so, once, at their own line
    import warnings

    import jax.numpy as jnp

    def friction(t: Any, x: Any, u: Any, p: Any) -> Any:
        slip = p["mu"] if x[1] > 0 else -p["mu"]
        return jnp.stack([x[1], -p["k"] * jnp.sin(x[0]) - slip + u[0]])

    model = aeroid.Model(["th", "w"], ["u"], {"k": 9.0, "mu": 0.3}, friction, name="slip")
    t = np.arange(30) * 0.05
    u = {"u": np.sin(t)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            model.simulate(t, u, [0.1, 0.0], method="rk4", substeps=1)
    said = [w for w in caught if "cannot trace it" in str(w.message)]
    assert len(said) == 1 and "model 'slip'" in str(said[0].message)
    assert said[0].filename == __file__
    traced = aeroid.Model(["x"], ["u"], {"k": 0.7}, lambda t, x, u, p: -p["k"] * x, name="ok")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(3):
            traced.simulate(t, u, [1.0], method="rk4", substeps=1)


def test_non_finite_dynamics_still_name_the_time(monkeypatch: Any) -> None:
    def blows_up(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array([np.where(t > 2.0, np.nan, -p["k"] * x[0])])

    model = aeroid.Model(["v"], [], {"k": 0.5}, blows_up, name="blows_up")
    t = np.linspace(0.0, 5.0, 51)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    fast = model.simulate_batch(t, None, [1.0], {}, method="rk4", substeps=2)
    assert _compiled._CACHE[model][("fn", "dynamics")] is not None
    monkeypatch.setattr(_compiled, "ENABLED", False)
    slow = model.simulate_batch(t, None, [1.0], {}, method="rk4", substeps=2)
    assert not fast.ok[0] and not slow.ok[0]
    assert fast.fail_time[0] == slow.fail_time[0] == pytest.approx(2.1)  # first NaN sample
    monkeypatch.setattr(_compiled, "ENABLED", True)
    with pytest.raises(aeroid.SimulationError, match=r"2\.1"):
        model.simulate(t, None, [1.0], method="rk4", substeps=2)


def test_without_jax_numpy_path(monkeypatch: Any) -> None:
    monkeypatch.setitem(sys.modules, "jax", None)
    monkeypatch.setitem(sys.modules, "jax.numpy", None)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    model = _longitudinal(name="no_jax")
    t = np.arange(101) * 0.1
    u = _controls(t)
    res = model.simulate_batch(t, u, X0, {}, method="rk4", substeps=2)
    assert res.ok[0]
    assert _compiled._CACHE[model][("fn", "dynamics")] is None
    assert _compiled.output_sensitivities(model, t, u, X0, TRUTH, FIT, [], {}) is None
    monkeypatch.setattr(_compiled, "ENABLED", False)
    ref = model.simulate_batch(t, u, X0, {}, method="rk4", substeps=2)
    np.testing.assert_allclose(res.states, ref.states, rtol=1e-13)  # both numpy


def test_interval_propagator_matches_rk4_and_its_jacobian(lon: aeroid.Model) -> None:
    t = np.arange(21) * 0.1
    u = _controls(t)
    prop = _compiled.interval_propagator(lon, t, u, X0, dict(TRUTH), 4)
    assert prop is not None
    rng = np.random.default_rng(1)
    pts = X0[None, :] + 0.01 * rng.standard_normal((5, 4))
    pmat = np.tile(np.array(list(TRUTH.values())), (5, 1))
    nxt, phi = prop(3, pts, pmat, jacobian=True)
    for b in range(5):
        ref = lon.simulate_batch(t[3:5], u[3:5], pts[b], {}, method="rk4", substeps=4).states[0, 1]
        np.testing.assert_allclose(nxt[b], ref, rtol=1e-13)
        for j in range(4):
            h = 1e-6 * max(abs(pts[b, j]), 1.0)
            e = np.zeros(4)
            e[j] = h
            up = prop(3, (pts[b] + e)[None], pmat[:1])[0]
            dn = prop(3, (pts[b] - e)[None], pmat[:1])[0]
            np.testing.assert_allclose(phi[b, :, j], (up - dn) / (2 * h), rtol=1e-6, atol=1e-9)


def test_switch_at_a_sample_time_agrees_with_numpy(monkeypatch: Any) -> None:
    # A burnout written with np.where traces; both paths must see the switch one-sided
    # at the sample time where it happens, as the numpy RK4 does.
    def burn(t: Any, x: Any, u: Any, p: Any) -> Any:
        thrust = np.where(t < 2.0, p["T"], 0.0)
        return np.array([thrust - p["k"] * x[0] * np.abs(x[0])])

    model = aeroid.Model(["v"], [], {"T": 5.0, "k": 0.1}, burn, name="burnout")
    t = np.arange(81) * 0.05  # t = 2 s is a sample
    params = {"k": np.array([0.1, 0.12])}
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    fast = model.simulate_batch(t, None, [0.0], params, method="rk4", substeps=2)
    assert _compiled._CACHE[model][("fn", "dynamics")] is not None  # it compiled
    monkeypatch.setattr(_compiled, "ENABLED", False)
    slow = model.simulate_batch(t, None, [0.0], params, method="rk4", substeps=2)
    assert _rel(fast.states, slow.states) < 1e-12
    # and the step is taken on the right side: coasting after t = 2 s
    ref = model.simulate(t, None, [0.0], {"k": 0.1}, method="RK45")
    assert _rel(fast.states[0], ref.states) < 1e-5


def test_probe_compiles_no_rollout(monkeypatch: Any) -> None:
    # The probe only asks which path the integrator takes: even a model past the
    # compilation threshold compiles no rollout for its two-sample record.
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    model = _longitudinal(name="probed")
    t = np.arange(51) * 0.1
    got = _compiled.output_sensitivities(model, t, _controls(t), X0, TRUTH, FIT, [], {})
    assert got is not None
    assert not any(isinstance(k, tuple) and k[0] == "states" for k in _compiled._CACHE[model])


def _decay_factory(rate: float, gain: float, flag: bool = False) -> aeroid.Model:
    """Models that differ only in the numbers their functions close over (and a flag)."""

    def dyn(t: Any, x: Any, u: Any, p: Any) -> Any:
        push = -gain if flag else gain
        return np.array([-p["k"] * rate * x[0] ** 3 + push * u[0]])

    def meas(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array([gain * x[0] + p["b"]])

    return aeroid.Model(["x"], ["u"], {"k": 1.0, "b": 0.0}, dyn, ["y"], meas)


def test_models_of_one_structure_share_a_compilation_and_keep_their_numbers(
    monkeypatch: Any,
) -> None:
    # two models from one factory: one compiled function, each model's own constants
    t = np.arange(101) * 0.05
    u = np.sin(t)[:, None]
    opts = {"method": "rk4", "substeps": 2}
    results = {}
    models = {
        "a": _decay_factory(0.5, 2.0),
        "b": _decay_factory(1.5, 0.5),
        "flipped": _decay_factory(0.5, 2.0, flag=True),
    }
    for name, m in models.items():
        results[name] = _compiled.output_sensitivities(
            m, t, u, np.array([1.0]), {"k": 0.8, "b": 0.1}, ["k", "b"], [0], opts
        )
    assert _compiled._shared(models["a"]) is _compiled._shared(models["b"])
    assert _compiled._shared(models["a"]) is not _compiled._shared(models["flipped"])
    assert _compiled._shared(models["a"])[("sensitivities", None)] is not None
    monkeypatch.setattr(_compiled, "ENABLED", False)
    for name, m in models.items():
        got = results[name]
        assert got is not None
        ref = m.simulate_batch(t, u, [1.0], {"k": np.array([0.8]), "b": np.array([0.1])}, **opts)
        assert _rel(got[0], ref.outputs[0]) < 1e-12, name
        assert np.allclose(got[1][:, 0, 1], 1.0)  # dy/db


def test_a_number_used_in_python_control_flow_keeps_the_model_compiling(
    monkeypatch: Any,
) -> None:
    # a closed-over number that a Python `if` reads cannot be lifted: the plain
    # translation (the number baked in) still compiles the model
    limit = 0.5

    def dyn(t: Any, x: Any, u: Any, p: Any) -> Any:
        k = p["k"] * 2.0 if limit > 1.0 else p["k"]
        return np.array([-k * x[0] ** 3 + u[0]])

    m = aeroid.Model(["x"], ["u"], {"k": 1.0}, dyn)
    t = np.arange(51) * 0.1
    u = np.cos(t)[:, None]
    got = _compiled.output_sensitivities(m, t, u, np.array([0.2]), {"k": 0.7}, ["k"], [], {})
    assert got is not None
    entry = _compiled._CACHE[m]
    assert entry[("lifted", "dynamics")] is False and entry[("fn", "dynamics")] is not None
    monkeypatch.setattr(_compiled, "ENABLED", False)
    ref = m.simulate_batch(t, u, [0.2], {"k": np.array([0.7])}, method="rk4")
    assert _rel(got[0], ref.outputs[0]) < 1e-12


def _sensor_model() -> aeroid.Model:
    # A pendulum read through a sensor with a scale factor and an offset; its
    # damping switches above a rate the test never reaches (read inside np.where).
    def dyn(t: Any, x: Any, u: Any, p: Any) -> Any:
        angle, rate = x
        damping = np.where(np.abs(rate) > 50.0, p["c_hi"], p["c"])
        return np.array([rate, -p["w2"] * np.sin(angle) - damping * rate + u[0]])

    def meas(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array([(1.0 + p["k"]) * x[0] + p["b"], x[1] + 0.1 * u[0]])

    params = {"w2": 4.0, "c": 0.3, "c_hi": 0.9, "k": 0.05, "b": 0.02}
    return aeroid.Model(["angle", "rate"], ["u"], params, dyn, ["angle_m", "rate_m"], meas)


def _numpy_outputs(m: aeroid.Model, t: Any, u: Any, x0: Any, p: Any) -> np.ndarray:
    before = _compiled.ENABLED
    _compiled.ENABLED = False
    try:
        sim = m.simulate_batch(t, u, x0, {k: np.array([v]) for k, v in p.items()}, method="rk4")
    finally:
        _compiled.ENABLED = before
    return np.asarray(sim.outputs[0])


def test_parameters_only_the_measurement_reads_match_finite_differences() -> None:
    m = _sensor_model()
    t = np.arange(301) * 0.02
    u = (0.5 * np.sin(3.0 * t) + 0.2 * (t > 2.0))[:, None]
    x0 = np.array([0.3, 0.0])
    p = dict(m.parameters)
    names = ["w2", "c", "c_hi", "k", "b"]
    got = _compiled.output_sensitivities(m, t, u, x0, p, names, [0], {"method": "rk4"})
    assert got is not None
    # the sensor's scale factor and offset are not propagated through the states; the
    # switched damping is (read by the dynamics, even where it does not act)
    dynamic = _compiled._dynamic_parameters(m, t, x0, u)
    assert [m.parameter_names[i] for i in dynamic] == ["w2", "c", "c_hi"]
    y, jac = got
    assert _rel(y, _numpy_outputs(m, t, u, x0, p)) < 1e-12
    for c, name in enumerate([*names, "x0.angle"]):
        h = 1e-5 * max(abs(p.get(name, x0[0])), 0.1)

        def sim(delta: float, name: str = name) -> np.ndarray:
            pp, xx = dict(p), x0.copy()
            if name in pp:
                pp[name] += delta
            else:
                xx[0] += delta
            return _numpy_outputs(m, t, u, xx, pp)

        fd = (sim(h) - sim(-h)) / (2 * h)
        if name == "c_hi":
            assert np.all(jac[:, :, c] == 0.0) and np.all(fd == 0.0)
            continue
        assert _rel(jac[:, :, c], fd) < 1e-6, name
    # the arrays handed out are shared with a caller at the same point: read-only
    assert not jac.flags.writeable


def test_a_simulation_at_the_last_sensitivity_point_reuses_its_states() -> None:
    # a fit's result is simulated at the estimate its last sensitivity pass rolled out:
    # the states come from that pass, also when only the sensor's parameters differ
    m = _sensor_model()
    t = np.arange(301) * 0.02
    u = (0.5 * np.sin(3.0 * t) + 0.2 * (t > 2.0))[:, None]
    x0 = np.array([0.3, 0.0])
    p = dict(m.parameters)
    got = _compiled.output_sensitivities(m, t, u, x0, p, ["w2", "k"], [0], {"method": "rk4"})
    assert got is not None
    rolled = _compiled._LAST_SENSITIVITIES[4][2]

    def states(pp: dict[str, float], xx: np.ndarray = x0) -> np.ndarray:
        P = {k: np.array([v]) for k, v in pp.items()}
        traj = _compiled.rk4_states(m, t, xx[:, None].copy(), u[None], P, 1)
        assert traj is not None and bool(traj.ok[0])
        return np.asarray(traj.states[0])

    assert np.shares_memory(states({**p, "k": 0.0, "b": 1.0}), rolled)
    for moved, xx in (({**p, "w2": 4.5}, x0), (p, np.array([0.2, 0.0]))):
        other = states(moved, xx)
        assert not np.shares_memory(other, rolled)
        assert np.max(np.abs(other - rolled)) > 1e-3
    # a recomputed rollout agrees with the reused one
    _compiled._LAST_SENSITIVITIES.clear()
    assert _rel(states(p), rolled) < 1e-12


def test_input_noise_scatter_is_the_exact_linear_covariance() -> None:
    # The adjoint pass against the definition: build the outputs' response to every
    # control sample by central differences of the numpy simulation, G[k, j], then
    # Q = Z' diag(sigma^2) Z with Z[j] = sum_k G[k, j]' R^-1 J[k].
    m = _sensor_model()
    t = np.arange(41) * 0.05
    u = (0.5 * np.sin(3.0 * t))[:, None]
    x0 = np.array([0.3, 0.1])
    p = dict(m.parameters)
    names = ["w2", "c", "b"]
    inverse = np.array([1.0 / 0.01**2, 1.0 / 0.02**2])
    sigma = np.array([0.05])
    got = _compiled.input_noise_scatter(m, t, u, x0, p, names, [0], 1, inverse, sigma)
    assert got is not None
    _, jac, scatter = got
    eps = 1e-6
    z = np.zeros((t.size, jac.shape[2]))
    for j in range(t.size):
        du = np.zeros_like(u)
        du[j, 0] = eps
        g = (_numpy_outputs(m, t, u + du, x0, p) - _numpy_outputs(m, t, u - du, x0, p)) / (2 * eps)
        z[j] = np.einsum("ky,y,kyc->c", g, inverse, jac)
    expected = (z * sigma[0]).T @ (z * sigma[0])
    assert np.allclose(scatter, expected, rtol=1e-7, atol=1e-9 * np.max(np.abs(expected)))


def test_output_error_stops_when_the_next_step_would_change_nothing() -> None:
    # An offset alone is linear in the outputs: one Gauss-Newton step lands on the
    # optimum, and the fit stops there without simulating a further, empty step.
    m = _sensor_model()
    t = np.arange(401) * 0.02
    u = (0.5 * np.sin(3.0 * t))[:, None]
    truth = {**m.parameters, "b": 0.2}
    y = _numpy_outputs(m, t, u, np.array([0.3, 0.0]), truth)
    y = y + 0.01 * np.random.default_rng(1).standard_normal(y.shape)
    data = aeroid.FlightData(t, {"u": u[:, 0], "angle_m": y[:, 0], "rate_m": y[:, 1]})
    fit = aeroid.identify(m, data, {"b": 0.0}, x0={"angle": 0.3, "rate": 0.0})
    assert fit.success and fit.n_iterations == 1
    assert abs(fit.parameters["b"] - 0.2) < 3 * fit.stderr["b"]
