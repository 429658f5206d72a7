"""A stepped simulator (SimulatorModel) in validate's holdout paths, and its failures
(a raise, None, the wrong shape, non-finite outputs) named in every path."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid import FlightData, SimulationError
from aeroid.models import catalog

K, TAU = 2.0, 0.5


def _lag_step(a: float, b: float, h: float, x: float, u0: float, u1: float) -> float:
    """One exact step of x' = a x + b u with u linear from u0 to u1 over h."""
    phi = np.exp(a * h)
    g0 = (phi - 1.0) / a  # integral of e^(a r) over [0, h]
    g1 = (g0 - h) / (a * h)  # integral of e^(a (h - s)) s / h over [0, h]
    return float(phi * x + b * (u0 * g0 + (u1 - u0) * g1))


class Lag:
    """A hand-written stepped simulator of tau y' = K u - y (exact for linear inputs),
    which starts at the record's first sample of y, or at zero on a bare grid."""

    name = "stepped_lag"
    controls = ("u",)
    outputs = ("y",)

    def __init__(self) -> None:
        self.parameters = {"K": K, "tau": TAU}

    def run(self, time: Any, u: Any, y0: float, parameters: Any) -> aeroid.SimulationResult:
        p = {**self.parameters, **dict(parameters or {})}
        t = np.asarray(time, dtype=float)
        u = np.asarray(u, dtype=float)
        y = np.empty(t.size)
        y[0] = y0
        for k in range(t.size - 1):
            y[k + 1] = _lag_step(
                -1.0 / p["tau"], p["K"] / p["tau"], t[k + 1] - t[k], y[k], u[k], u[k + 1]
            )
        return aeroid.SimulationResult(
            t, np.zeros((t.size, 0)), y[:, None], u[:, None], (), ("y",), ("u",)
        )

    def simulate(self, time, controls=None, x0=None, parameters=None, **options):
        return self.run(time, controls["u"], 0.0 if x0 is None else x0["y"], parameters)

    def simulate_data(self, data, *, x0=None, parameters=None, **options):
        y0 = float(data["y"][0]) if x0 is None else x0["y"]
        return self.run(data.time, data["u"], y0, parameters)


def _record(duration: float = 20.0, seed: int = 3) -> FlightData:
    t = np.linspace(0.0, duration, int(duration * 50) + 1)
    u = 0.3 * np.sin(0.7 * t) + 0.2 * np.sin(2.3 * t + 1.0)
    sim = catalog.first_order(K, TAU).simulate(t, {"u": u}, {"y": 0.0}, method="exact")
    y = sim.output("y") + 0.02 * np.random.default_rng(seed).standard_normal(t.size)
    return FlightData(t, {"u": u, "y": y})


@pytest.mark.parametrize("holdout", [{"fraction": 0.25}, {"t0": 12.0, "t1": 20.0}, "record"])
def test_validate_holdout_of_a_stepped_simulator_equals_the_model(holdout):
    # The simulator starts the held-out data at its first sample, as the Model does
    # from its measured state: the two predictions agree to the integrator's accuracy.
    data = _record()
    if holdout == "record":
        holdout = _record(8.0, seed=4)
    values = {"K": 1.9, "tau": 0.55}
    v_model = aeroid.validate(catalog.first_order(), data, values, holdout=holdout)
    v_sim = aeroid.validate(Lag(), data, values, holdout=holdout)
    rmse = v_sim.prediction.metrics["y"].rmse
    assert rmse == pytest.approx(v_model.prediction.metrics["y"].rmse, rel=1e-9)
    assert rmse > 0.02  # the 10 % wrong parameters show beyond the noise
    # and with the fit of the simulator itself (the record's first 12 s)
    fit = aeroid.identify(Lag(), data.window(0.0, 12.0), ["K", "tau"])
    v_fit = aeroid.validate(Lag(), data, fit, holdout=holdout)
    v_values = aeroid.validate(Lag(), data, dict(fit.parameters), holdout=holdout)
    assert v_fit.prediction.metrics["y"].rmse == v_values.prediction.metrics["y"].rmse
    # the noise floor: the true parameters predict to within the noise's 0.02 RMS
    assert v_fit.prediction.metrics["y"].rmse < 0.025


def test_validate_estimated_start_of_a_stepped_simulator_is_refused_by_name():
    with pytest.raises(aeroid.IdentificationError, match="holdout_start"):
        aeroid.validate(Lag(), _record(), {}, holdout={"fraction": 0.25}, holdout_start="estimated")


class NanFrom6(Lag):
    def run(self, time, u, y0, parameters):
        r = super().run(time, u, y0, parameters)
        y = r.outputs.copy()
        y[r.time >= 6.0] = np.nan
        return aeroid.SimulationResult(r.time, r.states, y, r.controls, (), ("y",), ("u",))


class Raises(Lag):
    def run(self, time, u, y0, parameters):
        raise RuntimeError("solver blew up")


class ReturnsNone(Lag):
    def run(self, time, u, y0, parameters):
        return None


class OneShort(Lag):
    def run(self, time, u, y0, parameters):
        return super().run(np.asarray(time)[:-1], np.asarray(u)[:-1], y0, parameters)


PATHS = {
    "identify": lambda m, d: aeroid.identify(m, d, ["K", "tau"]),
    "sensitivities": lambda m, d: aeroid.sensitivities(m, d, ["K", "tau"]),
    "validate": lambda m, d: aeroid.validate(m, d, {"K": 1.9}),
    "frequency_response": lambda m, d: aeroid.frequency_response(m, d),
}


def _raise(path: str, model: Any) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SimulationError) as err:
            PATHS[path](model, _record(10.0))
    return str(err.value)


@pytest.mark.parametrize("path", list(PATHS))
def test_non_finite_outputs_of_a_stepped_simulator_are_named_with_their_time(path):
    message = _raise(path, NanFrom6())
    assert "'stepped_lag'" in message
    assert "output 'y' is not finite from t = 6 s" in message


def test_non_finite_prediction_of_a_stepped_simulator_is_named():
    # the fit window (before 6 s) simulates; the held-out record does not
    class NanLate(Lag):
        def simulate_data(self, data, *, x0=None, parameters=None, **options):
            r = super().simulate_data(data, x0=x0, parameters=parameters)
            y = np.where(r.time >= 6.0, np.nan, r.outputs[:, 0])[:, None]
            return aeroid.SimulationResult(r.time, r.states, y, r.controls, (), ("y",), ("u",))

    data = _record(10.0)
    with pytest.raises(SimulationError, match="output 'y' is not finite from t = 6 s"):
        aeroid.validate(NanLate(), data.window(0.0, 5.0), {}, holdout=data)


FAULTS = [
    (Raises(), "its simulate raised RuntimeError: solver blew up"),
    (ReturnsNone(), "its simulate returned NoneType, not a SimulationResult"),
    (OneShort(), r"outputs of shape (500, 1); 501 times and the 1 outputs ['y'] need"),
    (NanFrom6(), "output 'y' is not finite from t = 6 s"),
]


@pytest.mark.parametrize(("model", "what"), FAULTS)
def test_infer_names_what_a_failing_stepped_simulator_did(model, what):
    # every walker's simulation fails alike: the refusal carries the simulator's fault
    priors = {"K": aeroid.Normal(K, 0.5), "tau": aeroid.Normal(TAU, 0.1)}
    with pytest.raises(aeroid.InferenceError) as err:
        aeroid.infer(model, _record(10.0), priors, n_walkers=8, n_steps=20, seed=0)
    assert "'stepped_lag'" in str(err.value) and what in str(err.value), str(err.value)


@pytest.mark.parametrize("path", list(PATHS))
@pytest.mark.parametrize(
    ("model", "what"),
    [
        (Raises(), "its simulate raised RuntimeError: solver blew up"),
        (ReturnsNone(), "its simulate returned NoneType, not a SimulationResult"),
        (OneShort(), r"outputs of shape (500, 1); 501 times and the 1 outputs ['y'] need"),
    ],
)
def test_a_failing_stepped_simulator_is_a_simulation_error_naming_it(path, model, what):
    message = _raise(path, model)
    assert "'stepped_lag'" in message and what in message, message


@pytest.mark.parametrize(
    ("field", "shape", "names"),
    [
        ("outputs", (500, 2), ("a", "b")),  # a row short of the time grid
        ("outputs", (501, 2), ("a",)),  # a column without a name
        ("states", (501, 1), ()),
        ("controls", (501,), ("u",)),
    ],
)
def test_simulation_result_refuses_rows_or_columns_its_time_and_names_do_not_match(
    field, shape, names
):
    t = np.linspace(0.0, 10.0, 501)
    arrays = {
        "states": np.zeros((501, 0)),
        "outputs": np.zeros((501, 2)),
        "controls": np.zeros((501, 1)),
    }
    labels = {"state_names": (), "output_names": ("a", "b"), "control_names": ("u",)}
    arrays[field] = np.zeros(shape)
    labels[field[:-1] + "_names"] = names
    with pytest.raises(SimulationError, match=f"SimulationResult: {field} has shape"):
        aeroid.SimulationResult(time=t, **arrays, **labels)
