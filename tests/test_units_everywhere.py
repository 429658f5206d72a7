"""A record that states a channel in deg for a model in rad is refused by every path
that flies the model on it, as identify refuses it (before: sensitivities gave a
Cramér-Rao bound 57 times too small, validate an RMSE of 0.47 on an exact record)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import aircraft as ac


def _records():
    model = ac.lateral_linear(V0=50.0, parameters={"L_p": -8.4, "L_delta_a": -29.0})
    t = np.arange(0.0, 4.0, 0.02)
    u = np.zeros((t.size, 2))
    u[10:20, 0] = 0.02
    u[60:70, 1] = -0.03
    y = model.simulate(t, u).outputs
    channels = {n: y[:, i] for i, n in enumerate(model.outputs)}
    deg = aeroid.FlightData(
        t,
        {**channels, "delta_a": np.degrees(u[:, 0]), "delta_r": np.degrees(u[:, 1])},
        units={"delta_a": "deg", "delta_r": "deg"},
    )
    return model, deg


PATHS = {
    "identify": lambda m, d: aeroid.identify(m, d, ["L_p"]),
    "sensitivities": lambda m, d: aeroid.sensitivities(m, d, ["L_p"]),
    "validate": lambda m, d: aeroid.validate(m, d),
    "filter_states": lambda m, d: aeroid.filter_states(
        m, d, process_noise={"p": 1e-4}, measurement_noise={o: 1e-6 for o in m.outputs}
    ),
    "frequency_response": lambda m, d: aeroid.frequency_response(m, d),
    "simulate_data": lambda m, d: m.simulate_data(d),
}


@pytest.mark.parametrize("path", list(PATHS))
def test_a_control_in_degrees_is_refused_by_every_path(path):
    model, deg = _records()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(aeroid.AeroidError, match=r"'delta_a' is stated in 'deg' but the model"):
            PATHS[path](model, deg)


def test_a_table_of_controls_and_a_labelled_start_are_read_by_name():
    # a DataFrame's columns and a Series' labels in another order than the model's
    # were read by position: aileron and rudder swapped without a word
    pd = pytest.importorskip("pandas")
    model = ac.lateral_linear(V0=50.0, parameters={"L_p": -8.4, "L_delta_a": -29.0})
    t = np.arange(0.0, 3.0, 0.02)
    da, dr = 0.02 * np.sin(2.0 * t), -0.03 * np.cos(1.3 * t)
    start = {"beta": 0.01, "p": 0.05, "r": -0.02, "phi": 0.1}
    want = model.simulate(t, {"delta_a": da, "delta_r": dr}, start).outputs
    frame = pd.DataFrame({"delta_r": dr, "delta_a": da})
    series = pd.Series({"phi": 0.1, "r": -0.02, "p": 0.05, "beta": 0.01})
    np.testing.assert_array_equal(model.simulate(t, frame, series).outputs, want)


def test_a_record_on_another_clock_is_no_control_history():
    model = ac.lateral_linear(V0=50.0)
    t = np.arange(0.0, 3.0, 0.02)
    record = aeroid.FlightData(
        t + 100.0, {"delta_a": np.zeros(t.size), "delta_r": np.zeros(t.size)}
    )
    with pytest.raises(aeroid.SimulationError, match="its own time grid"):
        model.simulate(t, record)
    with pytest.raises(aeroid.SimulationError, match="its own time grid"):
        model.simulate(t[:50], record)
    model.simulate(t + 100.0, record)  # its own grid is fine
