"""PX4 topics on their sample stamps; a corrupt ULog said so."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from aeroid.io.channel_map import load_mapped
from aeroid.io.logs import read_log

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
