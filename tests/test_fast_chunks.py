"""Speed paths of a first fit that must not change its numbers (issue 47): large
batches evaluated in cache-sized runs, and Newton's chord sweeps over the record."""

from __future__ import annotations

from typing import Any

import numpy as np
from test_fast_shooting import FIT, TRUTH, X0, _controls, _model

from aeroid.models import _batch_function
from aeroid.models import shooting as _shooting
from aeroid.models._batch_function import BatchFunction


def _f(t: Any, x: Any, u: Any, p: Any) -> Any:
    return np.array([np.sin(x[0]) * p["a"] + u[0] * t, x[1] * x[0] - p["b"]])


def test_large_batches_run_in_runs_with_the_same_values() -> None:
    n = _batch_function._CHUNK_ABOVE + 3 * _batch_function._CHUNK // 2
    rng = np.random.default_rng(0)
    t = rng.uniform(0.0, 10.0, n)
    x = rng.standard_normal((2, n))
    u = rng.standard_normal((1, n))
    p = {"a": rng.standard_normal(n), "b": np.broadcast_to(0.5, (n,))}
    f = BatchFunction(_f, 2, ("a", "b"))
    got = f.at_times(t, x, u, p)
    assert f.time_broadcasts is not False
    np.testing.assert_array_equal(got, _f(t, x, u, p))


def test_a_wrong_shape_in_a_run_is_still_caught() -> None:
    n = _batch_function._CHUNK_ABOVE + 10

    def bad(t: Any, x: Any, u: Any, p: Any) -> Any:
        # right at one time, or on a whole large batch; wrong on a run of it
        return np.array([x[0], x[0]]) if np.ndim(t) == 0 or np.size(t) > 20000 else x[:1]

    f = BatchFunction(bad, 2, ())
    t = np.repeat(np.arange(10.0), -(-n // 10))[:n]
    out = f.at_times(t, np.ones((1, n)), np.zeros((0, n)), {})
    # the array call failed in one run: the function is called at one time at a time
    assert f.time_broadcasts is False
    np.testing.assert_array_equal(out, np.ones((2, n)))


def test_chord_sweeps_give_the_jacobian_of_a_fresh_linearisation() -> None:
    t = np.arange(301) * 0.05
    u = _controls(t)
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    moved = {k: (1.03 * v if k in FIT else v) for k, v in TRUTH.items()}
    warm = _model("chord_warm")
    _shooting.output_sensitivities(warm, t, u, X0, TRUTH, FIT, [0], 2, steps)
    # the next point starts from the last trajectory and its Jacobians (chord sweeps)
    got = _shooting.output_sensitivities(warm, t, u, X0, moved, FIT, [0], 2, steps)
    fresh = _shooting.output_sensitivities(
        _model("chord_fresh"), t, u, X0, moved, FIT, [0], 2, steps
    )
    assert got is not None and fresh is not None
    np.testing.assert_allclose(got[0], fresh[0], rtol=1e-12, atol=1e-13)
    scale = np.max(np.abs(fresh[1]), axis=(0, 1))
    assert np.max(np.abs(got[1] - fresh[1]) / scale) < 1e-8


def test_compat_model_takes_fixed_parameters_as_numbers_with_the_same_values() -> None:
    from aeroid.estimation._compat_model import (
        _WIND,
        OUTPUT_CHANNELS,
        STATES,
        _kinematics,
        _sensors,
    )

    rng = np.random.default_rng(3)
    n = 50
    x = np.array([60.0, 1.0, 3.0, 0.1, 0.05, 0.3, 1000.0])[:, None] + 0.1 * rng.standard_normal(
        (7, n)
    )
    c = np.concatenate([0.1 * rng.standard_normal((6, n)), x + 0.01], axis=0)
    for zeros in (True, False):
        values = {"g": 9.81}
        for s in STATES:
            values[f"m_{s}"] = 0.0 if zeros else float(s in ("phi", "theta"))
        for w in _WIND:
            values[w] = 0.0 if zeros else rng.uniform(-5, 5)
        for ch in ("p", "q", "r", "ax", "ay", "az"):
            values[f"b_{ch}"], values[f"k_{ch}"] = rng.uniform(-0.01, 0.01, 2)
        for o in OUTPUT_CHANNELS:
            values[f"b_{o}"], values[f"k_{o}"], values[f"y0_{o}"] = rng.uniform(-0.1, 0.1, 3)
            values[f"tau_{o}"] = 0.0 if zeros else rng.uniform(0, 0.1)
        fixed = {k: np.broadcast_to(np.float64(v), (n,)) for k, v in values.items()}
        full = {k: np.full(n, v) for k, v in values.items()}
        for fn in (_kinematics, _sensors):
            np.testing.assert_array_equal(fn(None, x, c, fixed), fn(None, x, c, full))


def test_the_scatter_after_a_pass_at_its_point_reuses_it() -> None:
    t = np.arange(201) * 0.05
    u = _controls(t)
    inv = np.array([1.0 / 0.002**2, 1.0 / 0.004**2, 0.0, 1.0 / 0.003**2, 1.0 / 0.02**2])
    sigma = np.array([0.001, 0.002, 0.0])
    steps = 1e-6 * np.maximum(np.abs([TRUTH[n] for n in FIT]), 1e-3)
    fresh = _shooting.input_noise_scatter(
        _model("scatter_fresh"), t, u, X0, TRUTH, FIT, [0], 2, inv, sigma
    )
    model = _model("scatter_again")
    _shooting.output_sensitivities(model, t, u, X0, TRUTH, FIT, [0], 2, steps)
    calls = []
    original = _shooting._linearised

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(len(args[6]))  # the parameter columns of each sweep
        return original(*args, **kwargs)

    _shooting._linearised = counted  # type: ignore[assignment]
    try:
        again = _shooting.input_noise_scatter(model, t, u, X0, TRUTH, FIT, [0], 2, inv, sigma)
    finally:
        _shooting._linearised = original  # type: ignore[assignment]
    assert calls == [0]  # one sweep, for the control columns alone
    assert fresh is not None and again is not None
    np.testing.assert_allclose(again[0], fresh[0], rtol=1e-12, atol=1e-14)
    scale = np.max(np.abs(fresh[1]), axis=(0, 1))
    assert np.max(np.abs(again[1] - fresh[1]) / scale) < 1e-8
    d = np.sqrt(np.diag(fresh[2]))
    np.testing.assert_allclose(again[2] / np.outer(d, d), fresh[2] / np.outer(d, d), atol=1e-8)


def test_a_compiled_fit_serves_its_result_simulation_without_stepping(monkeypatch: Any) -> None:
    import pytest

    pytest.importorskip("jax")
    from test_fast_shooting import _flight

    import aeroid
    from aeroid.models import compiled as _compiled
    from aeroid.models import integration as _integrate

    model = _model("compiled_result")
    data = _flight(model, seed=5)
    guess = {k: 1.2 * TRUTH[k] for k in FIT}
    opts = {"simulate_options": {"method": "rk4", "substeps": 2}}
    from aeroid._threads import wait_background

    aeroid.identify(model, data, guess, **opts)
    aeroid.identify(model, data, guess, **opts)  # the second fit queues the compilation
    assert wait_background(120.0)
    fit = aeroid.identify(model, data, guess, **opts)  # the third runs it
    assert _compiled._CACHE[model].get("sensitivities_compiled")
    assert not _compiled._CACHE[model].get("compiled_once")  # no compiled rollouts yet
    stepped = []
    original = _integrate.rk4

    def counted(*args: Any, **kwargs: Any) -> Any:
        stepped.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(_integrate, "rk4", counted)
    u = np.column_stack([data[c] for c in model.controls])
    x0 = np.asarray([fit.initial_states[0][s] for s in model.states])
    sim = model.simulate(data.time, u, x0, fit.parameters, method="rk4", substeps=2)
    assert not stepped  # the states of the fit's last compiled pass
    monkeypatch.setattr(_integrate, "rk4", original)
    monkeypatch.setattr(_compiled, "ENABLED", False)  # numpy's RK4, step by step
    ref = model.simulate(data.time, u, x0, fit.parameters, method="rk4", substeps=2)
    np.testing.assert_allclose(sim.outputs, ref.outputs, rtol=1e-10, atol=1e-12)
