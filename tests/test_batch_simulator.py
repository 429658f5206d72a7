"""`BatchSimulator`: `simulate_batch` on one record with its arguments checked once.

Its plain calls must be `simulate_batch` bit for bit; its compiled `outputs` (a sampler's
path: parameters to outputs in one compiled call, the RK4 substeps decided in the
program) must equal the numpy RK4 to rounding, with the same substeps, and reject the
same members; `infer` must sample the same chain either way.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid.models import compiled as _compiled
from aeroid.models import integration as _integrate
from aeroid.models.batch_simulator import BatchSimulator

pytest.importorskip("jax")

T = np.arange(301) * 0.02
X0 = np.array([0.3, 0.0])


def _pendulum_dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    # a damped pendulum driven by a torque: nonlinear in the angle (no short-period form)
    angle, rate = x
    return np.array([rate, -p["w2"] * np.sin(angle) - p["c"] * rate + p["b"] * u[0]])


def _pendulum_measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
    angle, rate = x
    # the log of the rate's size: not finite where a member's rate runs off to inf
    return np.array([angle, rate, np.log1p(rate * rate), np.cos(angle) + p["bias"]])


def _pendulum() -> aeroid.Model:
    return aeroid.Model(
        ["angle", "rate"],
        ["torque"],
        {"w2": 9.0, "c": 0.4, "b": 2.0, "bias": 0.0},
        _pendulum_dynamics,
        ["angle_m", "rate_m", "energy_m", "cos_m"],
        _pendulum_measurement,
        name="pendulum",
    )


def _torque(t: np.ndarray) -> np.ndarray:
    return (0.5 * np.sign(np.sin(2.0 * np.pi * t / 2.0)) * (t < 4.0))[:, None]


def _same(a: aeroid.BatchSimulation, b: aeroid.BatchSimulation) -> None:
    for name in ("time", "states", "outputs", "ok", "fail_time"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.failure == b.failure


@pytest.mark.parametrize("enabled", [False, True])
def test_calls_are_simulate_batch_bit_for_bit(monkeypatch: Any, enabled: bool) -> None:
    monkeypatch.setattr(_compiled, "ENABLED", enabled)
    model = _pendulum()
    u = _torque(T)
    sim = BatchSimulator(model, T, u, X0, method="auto")
    batches: list[dict[str, Any]] = [
        {"w2": np.array([9.0, 16.0, 4.0]), "c": 0.2},
        {"c": np.array([0.1])},
        {},
        {"w2": np.array([9.0, 1e300]), "b": np.array([2.0, 3.0])},  # the second diverges
    ]
    for params in batches * 2:  # again: nothing a call caches changes the next
        _same(sim(params), model.simulate_batch(T, u, X0, params, method="auto"))
    # per-member controls and initial states, and options
    u3 = np.stack([u, 2.0 * u, -u])
    x3 = {"angle": 0.1}
    sim3 = BatchSimulator(model, T, u3, x3, method="rk4", substeps=2)
    got = sim3({"c": np.array([0.1, 0.2, 0.3])})
    _same(
        got,
        model.simulate_batch(T, u3, x3, {"c": np.array([0.1, 0.2, 0.3])}, substeps=2, method="rk4"),
    )


def test_a_linear_model_keeps_its_exact_solution() -> None:
    model = aeroid.models.catalog.short_period()
    t = np.arange(201) * 0.05
    u = np.where((t > 1.0) & (t < 2.0), 0.05, 0.0)[:, None]
    sim = BatchSimulator(model, t, u, None, repeated=10**6)
    params = {"M_q": np.array([-2.0, -3.0, -4.0])}
    want = model.simulate_batch(t, u, None, params)
    for _ in range(2):
        np.testing.assert_array_equal(sim.outputs(params, [0, 1]), want.outputs[:, :, [0, 1]])


def test_the_arguments_are_checked_once_naming_the_culprit() -> None:
    model = _pendulum()
    with pytest.raises(aeroid.SimulationError, match="time"):
        BatchSimulator(model, T[::-1], _torque(T), X0)
    with pytest.raises(aeroid.SimulationError, match="controls"):
        BatchSimulator(model, T, np.zeros((T.size, 3)), X0)
    with pytest.raises(aeroid.SimulationError, match="substeps"):
        BatchSimulator(model, T, _torque(T), X0, substeps=0)
    sim = BatchSimulator(model, T, _torque(T), X0)
    with pytest.raises(aeroid.SimulationError, match="not parameters"):
        sim({"w3": 1.0})
    with pytest.raises(aeroid.SimulationError, match="batch sizes disagree"):
        sim({"w2": np.ones(2), "c": np.ones(3)})


def _numpy_outputs(model: aeroid.Model, params: dict, index: list[int], substeps: Any) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old = _compiled.ENABLED
        _compiled.ENABLED = False
        try:
            res = model.simulate_batch(T, _torque(T), X0, params, method="rk4", substeps=substeps)
        finally:
            _compiled.ENABLED = old
    y = res.outputs[:, :, index]
    y[~res.ok] = np.nan
    return y


@pytest.mark.parametrize("w2", [9.0, 900.0])
def test_compiled_outputs_equal_numpy_to_rounding_with_the_same_substeps(w2: float) -> None:
    # w2 = 900: a stiff pendulum (30 rad/s at 50 Hz) that the rule gives several substeps
    model = _pendulum()
    u = _torque(T)
    # the last member's torque gain drives it off to inf (its start is like the others')
    params = {"w2": np.array([w2, 1.1 * w2, 0.9 * w2, w2]), "b": np.array([2.0, 1.0, 3.0, 1e300])}
    f = model._dynamics_batch
    p = {
        k: np.broadcast_to(np.asarray(params.get(k, v), float), (4,))
        for k, v in model.parameters.items()
    }
    x = np.repeat(X0[:, None], 4, axis=1)
    m = _integrate.auto_substeps(f, T, x, np.broadcast_to(u, (4, *u.shape)), p)
    assert (m == 1) == (w2 == 9.0)
    sim = BatchSimulator(model, T, u, X0, repeated=10**6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.outputs(params, [0, 2])  # the first call shows the model nonlinear
        got = sim.outputs(params, [0, 2])
    assert _compiled._entry(model)["compiled_once"]  # the compiled program ran
    want = _numpy_outputs(model, params, [0, 2], m)
    # the last member diverges: NaN in both
    assert np.all(np.isnan(got[3])) and np.all(np.isnan(want[3]))
    scale = np.max(np.abs(want[:3]), axis=1, keepdims=True)
    assert np.max(np.abs(got[:3] - want[:3]) / scale) < 1e-11
    # one substep more or less moves the outputs far more than rounding
    other = _numpy_outputs(model, params, [0, 2], m + 1)
    assert np.max(np.abs(other[:3] - want[:3]) / scale) > 1e-9


def test_infer_samples_the_same_chain_compiled_or_not(monkeypatch: Any) -> None:
    model = _pendulum()
    truth = {"w2": 9.0, "c": 0.4}
    sim = model.simulate(T, {"torque": _torque(T)[:, 0]}, X0, truth, method="rk4", substeps=1)
    rng = np.random.default_rng(3)
    y = sim.outputs + 0.01 * rng.standard_normal(sim.outputs.shape)
    data = aeroid.FlightData(
        T, {"torque": _torque(T)[:, 0], **{n: y[:, j] for j, n in enumerate(model.output_names)}}
    )
    kw: dict[str, Any] = dict(
        parameters={"w2": aeroid.Normal(9.0, 3.0), "c": aeroid.Normal(0.5, 0.5)},
        outputs=["angle_m", "rate_m"],
        noise={"angle_m": 0.01, "rate_m": 0.01},
        x0=X0,
        n_walkers=8,
        n_steps=40,
        seed=11,
        move="de",
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast = aeroid.infer(model, data, **kw)
        assert _compiled._entry(model).get("compiled_once")  # 80 batches: compiled at once
        monkeypatch.setattr(_compiled, "ENABLED", False)
        slow = aeroid.infer(_pendulum(), data, **kw)
    # log-densities equal to rounding, so every accept/reject decision is the same
    np.testing.assert_array_equal(fast.samples, slow.samples)
    np.testing.assert_allclose(fast.log_prob, slow.log_prob, rtol=1e-10)


def test_smaller_batches_after_a_batch_share_its_program() -> None:
    model = _pendulum()
    sim = BatchSimulator(model, T, _torque(T), X0, repeated=10**6)
    params = {"w2": np.array([9.0, 8.0, 10.0, 9.5]), "c": np.array([0.4, 0.3, 0.5, 0.45])}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.outputs(params, [1])
        four = sim.outputs(params, [1])
        fewer = [sim.outputs({k: v[:n] for k, v in params.items()}, [1]) for n in (3, 1)]
    program = _compiled._shared(model)[("outputs", (-1, (1,)))]
    assert program._cache_size() == 1  # batches of 3 and 1 padded to 4: no compilation
    for got in fewer:
        np.testing.assert_array_equal(got, four[: got.shape[0]])


def test_the_rule_picks_each_batch_program_after_a_stiff_one() -> None:
    # The sampler's batches run the one-substep program, which also returns the rule's
    # count; a batch the rule gives more substeps runs the looped program, and from then
    # on the rule is asked first. Each batch must come out as the program of its count.
    model = _pendulum()
    u = _torque(T)
    sim = BatchSimulator(model, T, u, X0, repeated=10**6)
    soft = {"w2": np.array([9.0, 9.9, 8.1, 9.5])}
    stiff = {"w2": np.array([900.0, 990.0, 810.0, 950.0])}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.outputs(soft, [0, 1])  # the first call shows the model nonlinear
        before = sim.outputs(soft, [0, 1])
        assert not _compiled._entry(model).get(("stiff", (0, 1)))
        hard = sim.outputs(stiff, [0, 1])
        assert _compiled._entry(model)[("stiff", (0, 1))]
        after = sim.outputs(soft, [0, 1])
        fixed = BatchSimulator(_pendulum(), T, u, X0, substeps=1, repeated=10**6)
        fixed.outputs(soft, [0, 1])
        one = fixed.outputs(soft, [0, 1])
    # the one-substep batches: the same program before and after, and as with substeps=1
    np.testing.assert_array_equal(after, before)
    np.testing.assert_array_equal(before, one)
    p = {k: np.broadcast_to(np.asarray(v, float), (4,)) for k, v in model.parameters.items()}
    p.update(stiff)
    x = np.repeat(X0[:, None], 4, axis=1)
    m = _integrate.auto_substeps(model._dynamics_batch, T, x, np.broadcast_to(u, (4, *u.shape)), p)
    assert m > 1
    want = _numpy_outputs(model, stiff, [0, 1], m)
    scale = np.max(np.abs(want), axis=1, keepdims=True)
    assert np.max(np.abs(hard - want) / scale) < 1e-11
    other = _numpy_outputs(model, stiff, [0, 1], m + 1)
    assert np.max(np.abs(other - want) / scale) > 1e-9


@pytest.mark.parametrize("how", ["linear", "cubic"])
def test_a_sampler_batch_refills_the_rows_of_the_last(monkeypatch: Any, how: str) -> None:
    # Batches of the same parameter names and size write only their own columns into
    # the rows of the last one: the same rows, so the same outputs bit for bit as a
    # batch built afresh; other batches (another size, values of other types) do not.
    # Cubic controls too: they never take the exact solution of a linear model, so the
    # model need not be shown nonlinear first (the demo's infer, aileron and rudder cubic)
    model = _pendulum()
    u = _torque(T)
    rng = np.random.default_rng(5)
    batches = [
        {"w2": 9.0 + rng.standard_normal(4), "c": 0.4 + 0.1 * rng.standard_normal(4)}
        for _ in range(3)
    ]
    others = [
        {"w2": batches[0]["w2"][:3], "c": batches[0]["c"][:3]},  # another size
        {"w2": list(batches[1]["w2"]), "c": batches[1]["c"]},  # a list
        {"w2": 9.5, "c": batches[2]["c"]},  # a scalar
    ]
    calls: list[int] = []
    full = _compiled.rk4_outputs

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return full(*args, **kwargs)

    monkeypatch.setattr(_compiled, "rk4_outputs", counted)
    sim = BatchSimulator(model, T, u, X0, repeated=10**6, control_interpolation=how)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = [sim.outputs(b, [1, 3]) for b in batches]
        assert len(calls) == 1  # the first batch built its rows; the next two refilled them
        got += [sim.outputs(b, [1, 3]) for b in others]
        assert len(calls) == 4
        for b, y in zip(batches + others, got, strict=True):
            fresh = BatchSimulator(_pendulum(), T, u, X0, repeated=10**6, control_interpolation=how)
            np.testing.assert_array_equal(y, fresh.outputs(b, [1, 3]))


@pytest.mark.parametrize("method", ["RK45", "Radau", "LSODA"])
def test_a_diverging_member_leaves_the_others_of_a_solve_ivp_batch(method):
    # x' = k x^2 from 1 blows up at t = 1/k: the member with k = 0.3 is finite to 2 s,
    # and must be the same in the batch as alone (before: both marked failed)
    def f(t, x, u, p):
        return np.stack([p["k"] * x[0] ** 2])

    m = aeroid.Model(states=["a"], controls=[], parameters={"k": 1.0}, dynamics=f, name="blow")
    t = np.arange(0.0, 2.0, 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = m.simulate_batch(t, None, [1.0], {"k": np.array([0.3, 1.0])}, method=method)
    assert list(batch.ok) == [True, False]
    np.testing.assert_allclose(batch.states[0, :, 0], 1.0 / (1.0 - 0.3 * t), rtol=1e-5)
    assert 0.95 <= batch.fail_time[1] <= 1.05


@pytest.mark.parametrize("method", ["BDF", "LSODA"])
def test_an_implicit_solver_names_where_it_failed_not_the_start(method):
    def f(t, x, u, p):
        return np.stack([x[0]])  # overflows float64 at t = 709.8 s

    m = aeroid.Model(states=["a"], controls=[], parameters={}, dynamics=f, name="grow")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(aeroid.SimulationError, match=r"t = 7(09|10) s"):
            m.simulate(np.arange(0.0, 720.0, 1.0), x0=[1.0], method=method)
