"""Newton's method over the whole RK4 record (aeroid.models.shooting, issue 47): the same
rollout as the step-by-step RK4, its sensitivities, and the numpy first fit."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid._threads import wait_background
from aeroid.models import compiled as _compiled
from aeroid.models import shooting as _shooting
from aeroid.models.integration import auto_substeps

# A lateral-directional nonlinear model (not the short period): sideslip, roll and yaw
# rates and bank angle, with an aileron and a rudder and a time-varying airspeed.
TRUTH = {
    "Yb": -0.25,
    "Lb": -12.0,
    "Lp": -2.4,
    "Lr": 0.9,
    "Lda": 9.0,
    "Nb": 4.5,
    "Np": -0.15,
    "Nr": -0.5,
    "Ndr": -3.0,
    "g_V": 9.81,
}
FIT = ["Lb", "Lp", "Lr", "Lda", "Nb", "Nr", "Ndr"]
X0 = np.array([0.01, 0.0, 0.0, 0.05])


def _dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    beta, pr, r, phi = x
    da, dr, V = u
    sb = np.sin(beta)
    return np.array(
        [
            p["Yb"] * sb + pr * np.sin(0.06) - r + p["g_V"] / V * np.sin(phi) * np.cos(beta),
            p["Lb"] * sb + p["Lp"] * pr + p["Lr"] * r + p["Lda"] * da,
            p["Nb"] * beta + p["Np"] * pr + p["Nr"] * r + p["Ndr"] * dr + 0.2 * pr * r,
            pr + r * np.tan(0.06) * np.cos(phi),
        ]
    )


def _measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
    beta, pr, r, phi = x
    V = u[2]
    ay = V * (p["Yb"] * np.sin(beta)) / 9.81
    return np.array([beta, pr, r, phi, ay])


def _model(name: str) -> aeroid.Model:
    return aeroid.Model(
        ["beta", "p", "r", "phi"],
        ["da", "dr", "V"],
        dict(TRUTH),
        _dynamics,
        outputs=["beta", "p", "r", "phi", "ay"],
        measurement=_measurement,
        name=name,
    )


def _controls(t: np.ndarray) -> np.ndarray:
    da = 0.05 * np.sign(np.sin(2 * np.pi * t / 3.0)) * (t < 8)
    dr = 0.04 * np.sign(np.sin(2 * np.pi * t / 4.1)) * ((t > 6) & (t < 14))
    V = 60.0 + 2.0 * np.sin(0.3 * t)
    return np.column_stack([da, dr, V])


def _flight(model: aeroid.Model, seed: int, gain: float = 1.0) -> aeroid.FlightData:
    t = np.arange(401) * 0.05
    u = _controls(t) * np.array([gain, gain, 1.0])
    sim = model.simulate(t, u, X0, method="rk4", substeps=2)
    rng = np.random.default_rng(seed)
    y = sim.outputs + rng.standard_normal(sim.outputs.shape) * np.array(
        [0.002, 0.004, 0.003, 0.003, 0.02]
    )
    channels = {"da": u[:, 0], "dr": u[:, 1], "V": u[:, 2]}
    channels.update({o: y[:, j] for j, o in enumerate(model.outputs)})
    return aeroid.FlightData(time=t, channels=channels)


def test_newton_rollout_is_the_rk4_rollout() -> None:
    model = _model("shoot_rollout")
    t = np.arange(301) * 0.05
    u = _controls(t)
    for m in (1, 3):
        ref = model.simulate_batch(t, u, X0, {}, method="rk4", substeps=m)
        steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
        got = _shooting.output_sensitivities(model, t, u, X0, TRUTH, FIT, [0, 3], m, steps)
        assert got is not None
        y, jac = got
        # Newton's fixed point is the RK4 recursion itself: equal to rounding
        np.testing.assert_allclose(y, ref.outputs[0], rtol=1e-12, atol=1e-14)
        assert jac.shape == (t.size, 5, len(FIT) + 2)


def test_sensitivities_match_differences_of_the_rollout() -> None:
    model = _model("shoot_jacobian")
    t = np.arange(201) * 0.05
    u = _controls(t)
    m = 2
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    got = _shooting.output_sensitivities(model, t, u, X0, TRUTH, FIT, [1], m, steps)
    assert got is not None
    _, jac = got
    for c, name in enumerate([*FIT, "x0.p"]):
        h = 1e-5 if name == "x0.p" else 1e-5 * abs(TRUTH[name])
        ys = []
        for sign in (1.0, -1.0):
            p = dict(TRUTH)
            x0 = X0.copy()
            if name == "x0.p":
                x0[1] += sign * h
            else:
                p[name] += sign * h
            ys.append(model.simulate_batch(t, u, x0, p, method="rk4", substeps=m).outputs[0])
        fd = (ys[0] - ys[1]) / (2 * h)
        scale = np.max(np.abs(fd))
        assert np.max(np.abs(jac[:, :, c] - fd)) < 1e-6 * scale, name


def test_each_new_point_starts_from_the_last_and_agrees() -> None:
    # a fit's next point: the guess is the last trajectory moved to first order
    model = _model("shoot_warm")
    t = np.arange(201) * 0.05
    u = _controls(t)
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    _shooting.output_sensitivities(model, t, u, X0, TRUTH, FIT, [], 2, steps)
    moved = {k: (1.05 * v if k in FIT else v) for k, v in TRUTH.items()}
    got = _shooting.output_sensitivities(model, t, u, X0, moved, FIT, [], 2, steps)
    assert got is not None
    ref = model.simulate_batch(t, u, X0, moved, method="rk4", substeps=2)
    np.testing.assert_allclose(got[0], ref.outputs[0], rtol=1e-12, atol=1e-14)


def test_dynamics_without_array_times_step_instead() -> None:
    def scalar_time(t: Any, x: Any, u: Any, p: Any) -> Any:
        k = 2.0 if float(t) > 5.0 else 1.0  # needs one time per call
        return _dynamics(t, x, u, p) * k

    model = aeroid.Model(
        ["beta", "p", "r", "phi"],
        ["da", "dr", "V"],
        dict(TRUTH),
        scalar_time,
        outputs=["beta", "p", "r", "phi", "ay"],
        measurement=_measurement,
        name="shoot_scalar_time",
    )
    t = np.arange(201) * 0.05
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    got = _shooting.output_sensitivities(model, t, _controls(t), X0, TRUTH, FIT, [], 2, steps)
    assert got is None
    assert model._dynamics_batch.time_broadcasts is False


def test_a_diverging_rollout_is_not_settled() -> None:
    def unstable(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array([x[0] ** 2])

    model = aeroid.Model(["x"], [], {"k": 1.0}, unstable, name="shoot_blowup")
    t = np.linspace(0.0, 3.0, 31)
    got = _shooting.output_sensitivities(
        model, t, np.zeros((31, 0)), np.array([1.0]), {"k": 1.0}, ["k"], [], 2, np.array([1e-6])
    )
    assert got is None  # x = 1 / (1 - t) has no RK4 trajectory past t = 1 either


def test_first_fit_in_numpy_agrees_with_the_compiled_second() -> None:
    pytest.importorskip("jax")
    model = _model("shoot_fit")
    data = _flight(model, seed=3)
    guess = {k: 1.2 * TRUTH[k] for k in FIT}
    opts = {"simulate_options": {"method": "rk4", "substeps": 2}}
    first = aeroid.identify(model, data, guess, **opts)
    assert not _compiled._CACHE[model].get("sensitivities_compiled")
    assert "x" not in model.states  # (the model is the lateral one)
    aeroid.identify(model, data, guess, **opts)  # queues the compilation
    assert wait_background(120.0)
    second = aeroid.identify(model, data, guess, **opts)
    assert _compiled._CACHE[model].get("sensitivities_compiled")
    for k in FIT:
        assert abs(first.parameters[k] - TRUTH[k]) < 4.0 * first.stderr[k], k
        assert abs(first.parameters[k] - second.parameters[k]) < 1e-4 * first.stderr[k], k
        assert first.stderr[k] == pytest.approx(second.stderr[k], rel=1e-5), k


def test_input_noise_scatter_matches_the_compiled_adjoint() -> None:
    pytest.importorskip("jax")
    model = _model("shoot_scatter")
    t = np.arange(201) * 0.05
    u = _controls(t)
    inv = np.array([1.0 / 0.002**2, 1.0 / 0.004**2, 0.0, 1.0 / 0.003**2, 1.0 / 0.02**2])
    sigma = np.array([0.001, 0.002, 0.0])
    got = _shooting.input_noise_scatter(model, t, u, X0, TRUTH, FIT, [0], 2, inv, sigma)
    assert got is not None
    _compiled._entry(model)["sensitivities_compiled"] = True  # the compiled adjoint
    _compiled._entry(model)[("background", "input_noise")] = "ready"
    ref = _compiled.input_noise_scatter(model, t, u, X0, TRUTH, FIT, [0], 2, inv, sigma)
    assert ref is not None
    np.testing.assert_allclose(got[0], ref[0], rtol=1e-12, atol=1e-14)
    for c in range(got[1].shape[2]):
        scale = np.max(np.abs(ref[1][:, :, c]))
        assert np.max(np.abs(got[1][:, :, c] - ref[1][:, :, c])) < 1e-6 * scale
    d = np.sqrt(np.diag(ref[2]))
    np.testing.assert_allclose(got[2] / np.outer(d, d), ref[2] / np.outer(d, d), atol=1e-6)


def test_the_result_simulation_reuses_the_last_rollout() -> None:
    model = _model("shoot_last")
    t = np.arange(201) * 0.05
    u = _controls(t)
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    _shooting.output_sensitivities(model, t, u, X0, TRUTH, FIT, [], 2, steps)
    P = {k: np.array([v]) for k, v in TRUTH.items()}
    known = _shooting.last_states(model, t, X0[:, None], u[None], P, 2)
    assert known is not None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = aeroid.models.integration.rk4(model._dynamics_batch, t, X0[:, None], u[None], P, 2)
    np.testing.assert_allclose(known, ref.states[0], rtol=1e-12, atol=1e-15)
    P["Lp"] = np.array([-2.5])  # another point: not this rollout
    assert _shooting.last_states(model, t, X0[:, None], u[None], P, 2) is None


def test_auto_substeps_are_those_of_the_compiled_path() -> None:
    model = _model("shoot_substeps")
    t = np.arange(101) * 0.05
    u = _controls(t)
    p1 = {k: np.array([v]) for k, v in TRUTH.items()}
    m = auto_substeps(model._dynamics_batch, t, X0[:, None].copy(), u[None], p1)
    assert _compiled.rk4_substeps(model, t, u, X0, TRUTH, {}) == m
    assert _compiled.rk4_substeps(model, t, u, X0, TRUTH, {"substeps": 5}) == 5


@pytest.mark.parametrize("n", [1, 2, 7, 1000])
@pytest.mark.parametrize("phi", [0.0, 0.6, -0.9, 0.995])
def test_blocked_ar1_recursion_is_the_plain_loop(n: int, phi: float) -> None:
    from aeroid.estimation._noise_model import _ar1_recursion

    r = np.random.default_rng(n).standard_normal((n, 3))
    ref = np.empty_like(r)
    y = np.zeros(3)
    for t in range(n):
        y = r[t] + phi * y
        ref[t] = y
    np.testing.assert_allclose(_ar1_recursion(r, phi), ref, rtol=1e-12, atol=1e-12)


def test_a_parameter_read_in_a_branch_keeps_its_column() -> None:
    # "stall" acts only while x > 0.5, early in the record: the jittered probe points
    # alone could miss it; the trajectory's own steps do not
    def stalling(t: Any, x: Any, u: Any, p: Any) -> Any:
        extra = np.where(x[0] > 0.5, p["stall"] * (x[0] - 0.5) ** 2, 0.0)
        return np.array([-p["k"] * x[0] + extra + u[0]])

    model = aeroid.Model(["x"], ["u"], {"k": 0.8, "stall": -0.6}, stalling, name="shoot_branch")
    t = np.arange(201) * 0.05
    u = 0.05 * np.sin(t)[:, None]
    params = {"k": 0.8, "stall": -0.6}
    got = _shooting.output_sensitivities(
        model, t, u, np.array([1.0]), params, ["k", "stall"], [], 2, np.array([1e-6, 1e-6])
    )
    assert got is not None
    for c, name in enumerate(["k", "stall"]):
        ys = []
        for sign in (1.0, -1.0):
            p = dict(params)
            p[name] += sign * 1e-5
            ys.append(model.simulate_batch(t, u, [1.0], p, method="rk4", substeps=2).outputs[0])
        fd = (ys[0] - ys[1]) / 2e-5
        assert np.max(np.abs(fd)) > 1e-3
        assert np.max(np.abs(got[1][:, :, c] - fd)) < 1e-6 * np.max(np.abs(fd)), name


def test_two_manoeuvres_each_start_from_their_own_last_trajectory() -> None:
    model = _model("shoot_two")
    datas = [_flight(model, seed=11), _flight(model, seed=12, gain=-0.7)]
    guess = {k: 1.2 * TRUTH[k] for k in FIT}
    opts = {"simulate_options": {"method": "rk4", "substeps": 2}}
    res = aeroid.identify(model, datas, guess, **opts)
    assert not _compiled._CACHE[model].get("sensitivities_compiled")  # numpy throughout
    assert len({id(e[1]) for e in _shooting._RECENT if e[0]() is model}) == 2
    for k in FIT:
        assert abs(res.parameters[k] - TRUTH[k]) < 4.0 * res.stderr[k], k
