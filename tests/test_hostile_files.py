"""Damaged and unusual flight files: each is read exactly or refused naming the file,
the column or the dataset at fault."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid.errors import DataFormatError


def _px4_log() -> Path:
    found = sorted(Path(__file__).resolve().parent.glob("data/**/*.ulg"))
    if not found:
        pytest.skip("no ULog in tests/data")
    return found[0]


def test_parquet_with_a_column_name_twice_is_refused_naming_it(tmp_path: Path) -> None:
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    path = tmp_path / "twice.parquet"
    arrays = [pa.array([0.0, 0.1, 0.2]), pa.array([1.0, 2.0, 3.0]), pa.array([4.0, 5.0, 6.0])]
    pq.write_table(pa.Table.from_arrays(arrays, names=["time", "x", "x"]), path)
    with pytest.raises(DataFormatError, match=r"twice.parquet: duplicate column names \['x'\]"):
        aeroid.load_flight_test(path)


def test_ulog_topic_without_its_timestamp_field_is_refused_naming_the_topic(
    tmp_path: Path,
) -> None:
    pytest.importorskip("pyulog")
    raw = _px4_log().read_bytes()
    at = raw.find(b"uint64_t timestamp;")
    damaged = tmp_path / "damaged.ulg"
    damaged.write_bytes(raw[:at] + b"uint64_t timeXtamp;" + raw[at + 19 :])
    for read in (aeroid.read_log, aeroid.load_flight_test, aeroid.list_channels):
        with pytest.raises(DataFormatError, match=r"damaged.ulg: ULog topic '\w+' has no"):
            read(damaged)


def test_hdf5_scalar_beside_channels_is_no_channel_and_nan_stamps_are_named(
    tmp_path: Path,
) -> None:
    h5py = pytest.importorskip("h5py")
    t = np.linspace(0.0, 1.0, 11)
    path = tmp_path / "scalar.h5"
    with h5py.File(path, "w") as f:
        f["imu/time"], f["imu/gyro"], f["imu/gain"] = t, np.sin(t), 3.0
    log = aeroid.read_log(path)
    assert sorted(log.channels) == ["imu.gyro"]
    np.testing.assert_array_equal(log.channels["imu.gyro"].values, np.sin(t))
    t[3] = np.nan
    path = tmp_path / "nan.h5"
    with h5py.File(path, "w") as f:
        f["imu/time"], f["imu/gyro"] = t, np.sin(t)
    for read in (aeroid.read_log, aeroid.load_flight_test):
        with pytest.raises(DataFormatError, match=r"nan.h5: time dataset .*index 3 is not finite"):
            read(path)
    with pytest.raises(DataFormatError, match=r"log channel 'g'.*index 3 is not finite"):
        aeroid.LogChannel("g", t, np.zeros(11))


@pytest.mark.parametrize("scale", [1e300, 1e306, 1e308])
def test_resampling_is_linear_up_to_the_largest_floats(scale: float) -> None:
    t = np.linspace(0.0, 10.0, 1001)
    unit = np.asarray(aeroid.resample({"x": (t, np.sin(t))}, ["x"], rate=50)["x"])
    big = np.asarray(aeroid.resample({"x": (t, scale * np.sin(t))}, ["x"], rate=50)["x"])
    np.testing.assert_allclose(big / scale, unit, rtol=0, atol=1e-14)


def test_csv_time_as_iso_8601_stamps_becomes_seconds_from_the_first(tmp_path: Path) -> None:
    path = tmp_path / "stamps.csv"
    path.write_text(
        "time,x\n2024-01-01T00:00:59.900,1\n2024-01-01T00:01:00.000,2\n2024-01-01T00:01:00.250,3\n"
    )
    data = aeroid.load_flight_test(path)
    np.testing.assert_allclose(np.asarray(data.time), [0.0, 0.1, 0.35], atol=1e-12)
    np.testing.assert_array_equal(np.asarray(data["x"]), [1.0, 2.0, 3.0])
    path.write_text("time,x\n2024-01-01T00:00:00.1,1\n2024-01-01T00:00:00.2,abc\n")
    with pytest.raises(DataFormatError, match=r"row 3, column 'x': non-numeric \('abc'\)"):
        aeroid.load_flight_test(path)
