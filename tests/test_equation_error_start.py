"""`identify(start="equation_error")`: start values from a regression of the state equations."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _aircraft_data import LATERAL_LINEAR as LATERAL

from aeroid import FlightData, IdentificationError, Model, identify
from aeroid.errors import ChannelError
from aeroid.estimation.identification import _equation_error_start
from aeroid.models import catalog
from aeroid.models.aircraft import lateral_linear

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = catalog.SHORT_PERIOD_TRUTH


def _lateral_flight(seed: int) -> tuple[Model, FlightData]:
    model = lateral_linear(V0=60.0, parameters=LATERAL)
    t = np.arange(751) / 50.0
    da = catalog.multisine(t, [0.2, 0.5, 0.9, 1.4, 2.1], 0.02)
    dr = catalog.doublet(t, start=4.0, width=1.0, amplitude=0.06)
    sim = model.simulate(t, np.column_stack([da, dr]), method="exact")
    rng = np.random.default_rng(seed)
    noise = {"beta": 0.002, "p": 0.005, "r": 0.003, "phi": 0.003}
    channels = {"delta_a": da, "delta_r": dr}
    for name, sd in noise.items():
        channels[name] = sim.output(name) + sd * rng.standard_normal(t.size)
    return model, FlightData(t, channels, {})


def _quiet_identify(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a fit from a bad start may warn; judged below
        return identify(*args, **kwargs)


def test_sign_flipped_start_short_period():
    data = catalog.short_period_flight(seed=0)
    flipped = {n: -TRUTH[n] for n in NAMES}
    # from the flipped start the plain fit stalls on a diverging simulation: refused
    with pytest.raises(IdentificationError, match="diverges from the record"):
        _quiet_identify(catalog.short_period(), data, flipped)
    r = identify(catalog.short_period(), data, flipped, start="equation_error")
    assert r.success
    for n in NAMES:
        assert abs(r.parameters[n] - TRUTH[n]) < 3 * r.stderr[n]
    # the same optimum as a fit from a good start
    good = identify(catalog.short_period(), data, NAMES)
    for n in NAMES:
        assert r.parameters[n] == pytest.approx(good.parameters[n], rel=1e-5)


def test_zero_start_multi_output_lateral():
    model, data = _lateral_flight(7)
    zeros = dict.fromkeys(LATERAL, 0.0)
    # from all zeros some derivatives multiply states that have not moved: unseen at the
    # start, they once took the rounding of a minimum-norm step over their zero scale and
    # left the fit stuck far off; held until the others move them, the plain fit arrives
    # too, and the equation-error start as well
    plain = _quiet_identify(model, data, zeros, x0=np.zeros(4))
    r = identify(model, data, zeros, x0=np.zeros(4), start="equation_error")
    for fit in (plain, r):
        assert fit.success
        z = [abs(fit.parameters[n] - v) / fit.stderr[n] for n, v in LATERAL.items()]
        assert max(z) < 3.5  # 12 parameters: a max |z| beyond 3.5 has probability ~0.5 %


def test_start_values_on_noise_free_data_are_the_truth():
    # noise-free states of a linear model: the regression gives the truth up to the
    # differentiation error of the smoothed derivatives
    data = catalog.short_period_flight(noise={}, elevator=None)
    t = data.time
    u = catalog.multisine(t, [0.3, 0.7, 1.2, 1.9], 0.02)
    data = catalog.short_period_flight(noise={}, elevator=u)
    model = catalog.short_period()
    start = _equation_error_start(model, [data], NAMES, dict.fromkeys(NAMES, 0.0), {}, {})
    for n in NAMES:
        assert start[n] == pytest.approx(TRUTH[n], rel=0.02)


def test_parameters_outside_the_state_equations_keep_their_start():
    def dyn(t, x, u, p):
        return np.array([p["a"] * x[0] + p["b"] * u[0]])

    def meas(t, x, u, p):
        return np.array([x[0] + p["offset"]])

    model = Model(["y"], ["u"], {"a": -1.0, "b": 1.0, "offset": 0.0}, dyn, ["y"], meas)
    t = np.arange(401) / 50.0
    u = catalog.multisine(t, [0.2, 0.6, 1.1], 0.5)
    sim = Model(["y"], ["u"], {"a": -2.0, "b": 3.0}, lambda t, x, u, p: p["a"] * x + p["b"] * u)
    y = sim.simulate(t, u, method="exact").output("y")
    data = FlightData(t, {"u": u, "y": y}, {})
    start = _equation_error_start(
        model,
        [data],
        ["a", "b", "offset"],
        {"a": 0.0, "b": 0.0, "offset": 0.25},
        {},
        {"a": (-1.5, 0.0)},
    )
    assert start["offset"] == 0.25
    assert start["b"] == pytest.approx(3.0, rel=0.02)
    assert start["a"] == -1.5  # clipped into its bounds


def test_equation_error_start_errors():
    data = catalog.short_period_flight(seed=0)
    with pytest.raises(IdentificationError, match="start 'regression' is unknown"):
        identify(catalog.short_period(), data, NAMES, start="regression")
    # first-order lag tau y' = K u - y: not linear in tau
    t = np.arange(201) / 50.0
    lag = catalog.first_order()
    rec = FlightData(t, {"u": np.sin(t), "y": np.cos(t)}, {})
    with pytest.raises(IdentificationError, match=r"not linear in parameters \['tau'\]"):
        identify(lag, rec, ["K", "tau"], start="equation_error")
    partial = FlightData(data.time, {"elevator": data["elevator"], "q": data["q"]}, {})
    with pytest.raises(ChannelError, match="alpha"):
        identify(catalog.short_period(), partial, NAMES, start="equation_error")


def test_measured_derivative_channels_give_the_exact_regression():
    # with exact <state>_dot channels on a noise-free record the regression is exact
    t = np.arange(301) / 50.0
    u = catalog.multisine(t, [0.3, 0.7, 1.2], 0.02)
    truth = catalog.short_period(TRUTH)
    sim = truth.simulate(t, u, method="exact")
    x = sim.states.T
    xdot = np.asarray(truth.dynamics(t, x, u[None, :], dict(TRUTH)))
    channels = {"elevator": u, "alpha": x[0], "q": x[1], "alpha_dot": xdot[0], "q_dot": xdot[1]}
    data = FlightData(t, channels, {})
    model = catalog.short_period()
    start = _equation_error_start(model, [data], NAMES, dict.fromkeys(NAMES, 0.0), {}, {})
    for n in NAMES:
        assert start[n] == pytest.approx(TRUTH[n], rel=1e-9)
