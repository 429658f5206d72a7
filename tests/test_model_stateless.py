"""Models without states: outputs algebraic in the measured controls and the parameters.

Jategaonkar's output-error method applies unchanged to a model with no state
equations (Flight Vehicle System Identification, 2nd ed., chapter 4, test
cases 23, 24 and 27: aerodynamic coefficients from measured alpha, rates and
controls). The case here is Kirchhoff's flow separation in its quasi-steady
form, nonlinear in two of its parameters:
``CL = CL0 + CLa alpha (1 + sqrt(X))^2 / 4`` with
``X = (1 - tanh(a1 (alpha - astar))) / 2``. Before states could be empty, users
carried one idle state (``x' = 0``) that no output reads; the fits must agree
with that workaround to 1e-10, and the seeded truth must sit inside the 95 %
intervals at the binomial rate.
"""

from __future__ import annotations

import subprocess
import sys
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid import FilterError, IdentificationError, ModelDefinitionError, SimulationError

TRUTH = {"CL0": 0.2, "CLa": 5.0, "a1": 30.0, "astar": 0.3}
START = {"CL0": 0.25, "CLa": 4.5, "a1": 25.0, "astar": 0.28}
NOISE = 0.01
DT = 0.02
N = 1001


def _lift(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
    alpha = u[0]
    sep = 0.5 * (1.0 - np.tanh(p["a1"] * (alpha - p["astar"])))
    return np.array([p["CL0"] + p["CLa"] * alpha * (1.0 + np.sqrt(sep)) ** 2 / 4.0])


def _stateless(measurement: Any = _lift) -> aeroid.Model:
    return aeroid.Model(
        states=[],
        controls=["alpha"],
        parameters=TRUTH,
        outputs=["CL"],
        measurement=measurement,
        name="stall",
    )


def _idle() -> aeroid.Model:
    """The old workaround: one state that never moves and that no output reads."""
    return aeroid.Model(
        states=["idle"],
        controls=["alpha"],
        parameters=TRUTH,
        dynamics=lambda t, x, u, p: 0.0 * x,
        outputs=["CL"],
        measurement=_lift,
        name="stall",
    )


def _alpha(phase: float = 0.0) -> np.ndarray:
    """A slow pull through the stall and back with a small wobble on it."""
    t = DT * np.arange(N)
    ramp = 0.5 - 0.5 * np.cos(2.0 * np.pi * t / t[-1])
    return 0.05 + 0.35 * ramp + 0.01 * np.sin(7.0 * t + phase)


def _flight(seed: int, phase: float = 0.0) -> aeroid.FlightData:
    alpha = _alpha(phase)
    clean = _lift(0.0, np.zeros((0, N)), alpha[None], TRUTH)[0]
    noisy = clean + NOISE * np.random.default_rng(seed).standard_normal(N)
    return aeroid.FlightData(time=DT * np.arange(N), channels={"alpha": alpha, "CL": noisy})


def test_simulation_is_the_measurement_at_each_sample():
    m = _stateless()
    alpha = _alpha()
    want = _lift(0.0, None, alpha[None], TRUTH)[0]
    for method in ("RK45", "LSODA", "rk4", "rk4_hold", "euler", "auto"):
        sim = m.simulate(DT * np.arange(N), {"alpha": alpha}, method=method)
        assert sim.states.shape == (N, 0)
        np.testing.assert_allclose(sim.output("CL"), want, rtol=1e-15, atol=0)
    batch = m.simulate_batch(DT * np.arange(N), {"alpha": alpha}, None, {"CLa": [4.0, 6.0]})
    np.testing.assert_allclose(
        batch.outputs[1, :, 0] - batch.outputs[0, :, 0], 2.0 * (want - 0.2) / 5.0, rtol=1e-12
    )
    assert m.dynamics is None and m.n_states == 0


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"error_bars": "white"},
        {"gradient": "fd"},
        {"bounds": {"a1": (None, 29.0)}},  # active: the truth is 30
        {"estimate_bias": ["CL"], "fixed": "CL0"},
        {"time_delays": ["alpha"]},
        {"records": 2},
    ],
    ids=["default", "white", "fd", "bounds", "bias", "delay", "two-records"],
)
def test_the_same_fit_as_the_idle_state_workaround(options):
    options = dict(options)
    data: Any = [_flight(0), _flight(1, 1.0)] if options.pop("records", 1) == 2 else _flight(0)
    start = {k: v for k, v in START.items() if k != options.pop("fixed", None)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours = aeroid.identify(_stateless(), data, start, **options)
        idle = aeroid.identify(_idle(), data, start, **options)
    assert ours.all_parameters.keys() == idle.all_parameters.keys()
    for k, v in idle.all_parameters.items():
        assert ours.all_parameters[k] == pytest.approx(v, rel=1e-10, abs=1e-14), k
    for k, v in idle.stderr.items():
        assert ours.stderr[k] == pytest.approx(v, rel=1e-10, abs=1e-14), k


def test_validation_and_sensitivities_match_the_workaround():
    data = _flight(0)
    fit = aeroid.identify(_stateless(), data, START)
    idle = aeroid.identify(_idle(), data, START)
    a, b = aeroid.validate(_stateless(), data, fit), aeroid.validate(_idle(), data, idle)
    np.testing.assert_allclose(a.residuals, b.residuals, rtol=0, atol=1e-12)
    assert a.metrics["CL"].rmse == pytest.approx(b.metrics["CL"].rmse, rel=1e-10)
    sa = aeroid.sensitivities(_stateless(), data, fit)
    sb = aeroid.sensitivities(_idle(), data, idle)
    np.testing.assert_allclose(sa.sensitivities, sb.sensitivities, rtol=1e-8, atol=1e-12)


def test_frequency_domain_fit_matches_the_workaround():
    # y = k u + c: no states, so no record-end unknowns (the idle state's drop by the Wald test)
    def gain(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        return np.array([p["k"] * u[0] + p["c"]])

    rng = np.random.default_rng(0)
    t = 0.01 * np.arange(2001)
    u = np.convolve(rng.standard_normal(t.size), np.ones(5) / 5, mode="same")
    y = 2.0 * u + 0.1 + 0.01 * rng.standard_normal(t.size)
    data = aeroid.FlightData(time=t, channels={"a": u, "y": y})
    fits = []
    for states, dynamics in (([], None), (["idle"], lambda t, x, u, p: 0.0 * x)):
        model = aeroid.Model(
            states, ["a"], {"k": 1.0, "c": 0.0}, dynamics, outputs=["y"], measurement=gain
        )
        fits.append(aeroid.identify_frequency_domain(model, data, ["k"]))
    assert fits[0].parameters["k"] == pytest.approx(fits[1].parameters["k"], rel=1e-10)
    assert fits[0].stderr["k"] == pytest.approx(fits[1].stderr["k"], rel=1e-10)
    assert abs(fits[0].parameters["k"] - 2.0) < 4 * fits[0].stderr["k"]


def test_two_records_recover_the_truth_with_tighter_bars():
    one = aeroid.identify(_stateless(), _flight(2), START)
    two = aeroid.identify(_stateless(), [_flight(2), _flight(3, 1.0)], START)
    for k, v in TRUTH.items():
        # 4.4 sigma: a miss in any of the four by chance has probability below 1e-4
        assert abs(two.parameters[k] - v) < 4.4 * two.stderr[k], k
        # twice the samples of the same manoeuvre: bars about 1/sqrt(2) as wide
        assert two.stderr[k] / one.stderr[k] == pytest.approx(2**-0.5, rel=0.05), k


def test_intervals_cover_the_truth_at_the_binomial_rate():
    # each parameter's 95 % interval over 200 seeds: the hit count is binomial(200, 0.95),
    # 190 +- 3.1; 95 % +- 4 standard errors (88.8-100 %) fails a calibrated method with
    # probability below 1e-4 per parameter
    seeds = 200
    model = _stateless()
    hits = dict.fromkeys(TRUTH, 0)
    est = {k: [] for k in TRUTH}
    for seed in range(seeds):
        r = aeroid.identify(model, _flight(100 + seed), START)
        half = r.margin(0.95)
        for k, v in TRUTH.items():
            hits[k] += abs(r.parameters[k] - v) <= half[k]
            est[k].append(r.parameters[k])
    floor = 0.95 - 4 * np.sqrt(0.95 * 0.05 / seeds)
    for k, v in TRUTH.items():
        assert hits[k] / seeds >= floor, (k, hits[k])
        # unbiased: the mean within 4 standard errors of the mean
        spread = np.std(est[k], ddof=1)
        assert abs(np.mean(est[k]) - v) < 4 * spread / np.sqrt(seeds), k


def test_identify_on_a_model_without_states_compiles_nothing():
    # a fresh process: three fits and a batch simulation never import JAX's compiler
    code = (
        "import sys, numpy as np\n"
        "sys.path.insert(0, '.')\n"
        "import tests.test_model_stateless as T, aeroid\n"
        "m = T._stateless()\n"
        "for s in range(3): aeroid.identify(m, T._flight(s), T.START)\n"
        "aeroid.validate(m, T._flight(0), None)\n"
        "print('jax' in sys.modules); sys.exit(1 if 'jax' in sys.modules else 0)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_jax_gradient_agrees_with_the_default():
    jnp = pytest.importorskip("jax.numpy")

    def lift(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        sep = 0.5 * (1.0 - jnp.tanh(p["a1"] * (u[0] - p["astar"])))
        return jnp.array([p["CL0"] + p["CLa"] * u[0] * (1.0 + jnp.sqrt(sep)) ** 2 / 4.0])

    data = _flight(0)
    exact = aeroid.identify(_stateless(lift), data, START, gradient="jax")
    default = aeroid.identify(_stateless(), data, START)
    for k in TRUTH:
        # central differences against JAX's exact derivatives: the same optimum
        assert exact.parameters[k] == pytest.approx(default.parameters[k], rel=1e-9), k
        assert exact.stderr[k] == pytest.approx(default.stderr[k], rel=1e-6), k
    sim = aeroid.simulate_rk4(_stateless(lift), data.time, data, parameters=default)
    want = _stateless().simulate_data(data, parameters=default).output("CL")
    np.testing.assert_allclose(sim.output("CL"), want, rtol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({}, "give h"),  # no measurement
        ({"measurement": _lift, "dynamics": lambda t, x, u, p: [1.0]}, "returned 1 values"),
    ],
)
def test_definition_refusals(kwargs, fragment):
    base: dict[str, Any] = {"states": [], "controls": ["alpha"], "parameters": TRUTH}
    base["outputs"] = ["CL"]
    with pytest.raises(ModelDefinitionError, match=fragment):
        aeroid.Model(**base, **kwargs)
    with pytest.raises(ModelDefinitionError, match="dynamics=None only"):
        aeroid.Model(["x"], [], {"k": 1.0})


def test_what_needs_states_is_refused_by_name():
    m, data = _stateless(), _flight(0)
    t = data.time
    for x0 in ([0.0], {"x": 1.0}, [[1.0], None]):
        with pytest.raises(IdentificationError, match=r"x0: model 'stall' has no states"):
            aeroid.identify(m, data, START, x0=x0)
    with pytest.raises(SimulationError, match=r"x0: model 'stall' has no states"):
        m.simulate(t, data, [1.0])
    for empty in (None, {}, [], np.zeros(0)):
        m.simulate(t, data, empty)  # nothing given: accepted
    aeroid.identify(m, data, START, x0={}, estimate_x0=False)
    for est in (True, ["idle"]):
        with pytest.raises(IdentificationError, match="no initial state to estimate"):
            aeroid.identify(m, data, START, estimate_x0=est)
    with pytest.raises(IdentificationError, match=r"estimate_bias\['CL'\].*no states"):
        aeroid.identify(m, data, START, estimate_bias={"CL": "state"})
    with pytest.raises(IdentificationError, match=r"method='filter_error'.*no states"):
        aeroid.identify(m, data, START, method="filter_error", process_noise={})
    with pytest.raises(FilterError, match=r"no states.*nothing to estimate"):
        aeroid.filter_states(m, data, process_noise={}, measurement_noise={"CL": NOISE**2})


def test_an_estimated_holdout_start_fits_only_the_shifts_without_states() -> None:
    # nothing to start: the held-out prediction fits one shift per output, and the
    # model's own parameters are held
    rng = np.random.default_rng(11)
    n = 400
    t = np.arange(n) * 0.05
    a = np.sin(0.9 * t) + 0.2 * rng.standard_normal(n)
    y = 1.0 + 2.0 * a + 0.01 * rng.standard_normal(n)
    y[300:] += 0.05  # the held-out quarter sits 0.05 higher (another trim)
    data = aeroid.FlightData(t, {"alpha": a, "CL": y})
    model = aeroid.Model(
        states=[],
        controls=["alpha"],
        parameters={"C0": 1.0, "Ca": 1.0},
        outputs=["CL"],
        measurement=lambda t, x, u, p: np.stack([p["C0"] + p["Ca"] * u[0]]),
    )
    fit = aeroid.identify(model, data, ["C0", "Ca"])
    v = aeroid.validate(model, data, fit, holdout={"fraction": 0.25}, holdout_start="estimated")
    assert dict(v.prediction.initial_state) == {}
    shift = 0.05 - (fit.parameters["C0"] - 1.0) - (fit.parameters["Ca"] - 2.0) * a[300:].mean()
    assert v.prediction.shifts["CL"] == pytest.approx(shift, abs=3e-3)
