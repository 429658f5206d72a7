"""PX4 topics on their sample stamps; a corrupt ULog said so."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from aeroid import FlightLog, LogChannel
from aeroid.errors import DataFormatError
from aeroid.io.channel_map import flight_windows, load_mapped
from aeroid.io.logs import read_log
from aeroid.io.resampling import resample

PX4 = Path(__file__).resolve().parent / "data" / "px4" / "sample_log_small.ulg"


def test_px4_topics_are_stamped_with_their_sample_times() -> None:
    pytest.importorskip("pyulog")
    log = read_log(PX4)
    air = log.channels["vehicle_air_data.baro_alt_meter"]
    sampled = log.channels["vehicle_air_data.timestamp_sample"].values / 1e6
    # the air data's publication stamp lies a whole baro period (20 ms) after its sample
    np.testing.assert_array_equal(air.time, sampled)
    assert log.metadata["stamps"]["vehicle_air_data"] == "timestamp_sample"
    # the controls carry the stamp of the gyro sample they were computed from
    gyro = log.channels["vehicle_angular_velocity.xyz[0]"].time
    controls = log.channels["actuator_controls_0.control[0]"].time
    assert gyro.shape == controls.shape and np.mean(gyro == controls) > 0.99
    # a topic without the field, or published twice per sample, keeps its own stamps
    assert log.metadata["stamps"]["vehicle_status"] == "timestamp"
    assert log.metadata["stamps"]["actuator_controls_1"] == "timestamp"
    assert np.all(np.diff(log.channels["actuator_controls_1.control[0]"].time) > 0)
    d = load_mapped(
        PX4,
        {"p": "vehicle_angular_velocity.xyz[0]", "h": "vehicle_air_data.baro_alt_meter"},
        sample_rate=50.0,
        window=[21.0, 26.0],
    )
    assert d.metadata["stamps"] == {
        "vehicle_angular_velocity.xyz[0]": "timestamp_sample",
        "vehicle_air_data.baro_alt_meter": "timestamp_sample",
    }


def test_a_corrupt_ulog_warns_and_records_an_event(tmp_path: Path) -> None:
    pytest.importorskip("pyulog")
    raw = bytearray(PX4.read_bytes())
    raw[len(raw) // 2 : len(raw) // 2 + 200] = b"\xff" * 200
    bad = tmp_path / "corrupt.ulg"
    bad.write_bytes(bytes(raw))
    with pytest.warns(UserWarning, match="corrupt.ulg: pyulog found the file corrupt"):
        log = read_log(bad)
    assert [e.value for e in log.events if e.kind == "corruption"] == [
        "file corrupt: damaged data skipped"
    ]
    assert log.metadata["file_corruption"] is True
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the intact file says nothing
        good = read_log(PX4)
    assert not [e for e in good.events if e.kind == "corruption"]
    assert "file_corruption" not in good.metadata


def test_a_mode_window_is_clipped_to_the_mapped_channels() -> None:
    pytest.importorskip("pyulog")
    roll = {"y": "vehicle_angular_velocity.xyz[0]", "u": "actuator_controls_0.control[0]"}
    # MANUAL is on from 20.2207 s, before the gyro's first sample (20.326716 s)
    d = load_mapped(PX4, roll, sample_rate=100.0, window={"mode": "MANUAL"}, max_gap=np.inf)
    window = d.metadata["window"]
    assert (window["t0"], window["t1"]) == (20.326716, 26.825311)
    assert window["found"] == [20.220673, 1194.367328]  # its open end: the last stamp
    assert [(window["t0"], window["t1"])] == flight_windows(PX4, {"mode": "MANUAL"}, channels=roll)
    # a window in seconds is still refused outside the span
    with pytest.raises(DataFormatError, match="not inside the span"):
        load_mapped(PX4, roll, sample_rate=100.0, window=[20.2, 22.0])


def test_the_log_channel_doc_says_what_resample_does_with_backward_stamps() -> None:
    t = np.array([0.0, 0.2, 0.1, 0.3, 0.4, 0.5])
    log = FlightLog({"x": LogChannel("x", t, np.arange(6.0))})
    d = resample(log, ["x"], rate=10)
    assert d.metadata["resampling"]["channels"]["x"]["reordered_stamps"] == 1
    doc = " ".join((LogChannel.__doc__ or "").split())
    assert "`resample` sorts a channel whose time steps back" in doc
