"""Issue 49, "Silent or wrong": numbers that cannot be trusted are refused by name, with
no numpy warning leaking on the way."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _compat_flight import simulated_flight

from aeroid import FlightData, check_compatibility, identify, load_flight_test
from aeroid.errors import ChannelError, DataFormatError, IdentificationError


@pytest.fixture(scope="module")
def flight():
    return simulated_flight(duration=10.0, rate=25.0)


@pytest.mark.parametrize(
    ("channel", "moving"),
    [("alpha", "'q', 'az' move"), ("phi", "'p' moves"), ("theta", "'q' moves")],
)
def test_a_fitted_channel_held_at_zero_is_named_not_a_nan_at_index_0(flight, channel, moving):
    # alpha at 0 used to end in "channel 'alpha': non-finite value at index 0" and three
    # leaked overflow warnings
    dead = FlightData(flight.time, {**flight.channels, channel: np.zeros(flight.n_samples)})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(
            ChannelError, match=rf"channel '{channel}' \({channel}\): holds 0 .* while {moving}"
        ):
            check_compatibility(dead, max_passes=1, n_draws=2)


@pytest.mark.parametrize("channel", ["q", "az"])
def test_a_rate_or_acceleration_frozen_at_a_reading_is_named(flight, channel):
    # a gyro stuck at 0.5 rad/s returned success with only a drift warning
    frozen = FlightData(flight.time, {**flight.channels, channel: np.full(flight.n_samples, 0.5)})
    with pytest.raises(
        ChannelError, match=rf"channel '{channel}' \({channel}\): holds 0\.5 .* stuck or held"
    ):
        check_compatibility(frozen, max_passes=1, n_draws=2)


def test_a_symmetric_flights_zero_lateral_channels_are_not_called_stuck(flight):
    n = flight.n_samples
    lateral = ("p", "r", "ay", "beta", "phi", "psi")
    symmetric = FlightData(flight.time, {**flight.channels, **{c: np.zeros(n) for c in lateral}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # drift warnings of a short record: not the point
        assert check_compatibility(symmetric, max_passes=1, n_draws=2) is not None


def test_a_lateral_model_with_held_controls_is_refused_naming_them():
    from aeroid.models.aircraft import lateral_linear

    model = lateral_linear(V0=30.0, outputs=["beta", "p", "r"])
    t = np.arange(0.0, 6.0, 0.02)
    held = {"delta_a": np.full(t.size, 0.03), "delta_r": np.full(t.size, -0.02)}
    sim = model.simulate(t, held).to_flight_data()
    rng = np.random.default_rng(5)
    record = FlightData(
        t, {**{k: sim[k] + 1e-4 * rng.standard_normal(t.size) for k in ("beta", "p", "r")}, **held}
    )
    names = ["L_p", "L_delta_a", "N_r", "N_delta_r"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the refusal comes before any numpy overflow
        with pytest.raises(
            IdentificationError, match=r"no excitation: .*'delta_a' = 0\.03, 'delta_r' = -0\.02"
        ):
            identify(model, record, names)


def _back(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[20:] -= 0.7  # the clock steps back 0.7 s at 2 s
    return t


def test_a_parquet_clock_stepping_back_is_refused_not_sorted(tmp_path):
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    t = _back(np.arange(0.0, 4.0, 0.1))
    path = tmp_path / "back.parquet"
    pq.write_table(pa.table({"time": t, "q": np.sin(t)}), path)
    with pytest.raises(DataFormatError, match=r"back\.parquet: time: not strictly increasing"):
        load_flight_test(path)


def test_a_mat_clock_stepping_back_is_refused_not_sorted(tmp_path):
    import scipy.io

    t = _back(np.arange(0.0, 4.0, 0.1))
    path = tmp_path / "back.mat"
    scipy.io.savemat(path, {"time": t, "q": np.sin(t)})
    with pytest.raises(DataFormatError, match=r"back\.mat: time: not strictly increasing"):
        load_flight_test(path, channels=["q"])
