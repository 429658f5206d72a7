"""Flight-log readers: PX4 ULog, ArduPilot DataFlash (binary and text), HDF5, MATLAB v7.3."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid import ChannelError, DataFormatError, FlightLog, LogChannel, LogEvent

pytest.importorskip("pyulog")
pytest.importorskip("pymavlink")
h5py = pytest.importorskip("h5py")

ULOG = Path(__file__).parent / "data" / "px4" / "sample_log_small.ulg"


# -- a DataFlash writer (the format: ArduPilot's LogStructure.h, pymavlink's DFReader) --

# struct code per DataFlash format character, and the scale pymavlink applies
_CODES = {
    "b": ("b", 1.0),
    "B": ("B", 1.0),
    "h": ("h", 1.0),
    "H": ("H", 1.0),
    "i": ("i", 1.0),
    "I": ("I", 1.0),
    "f": ("f", 1.0),
    "d": ("d", 1.0),
    "Q": ("Q", 1.0),
    "q": ("q", 1.0),
    "c": ("h", 0.01),
    "C": ("H", 0.01),
    "e": ("i", 0.01),
    "E": ("I", 0.01),
    "L": ("i", 1e-7),
    "n": ("4s", 1.0),
    "N": ("16s", 1.0),
    "Z": ("64s", 1.0),
    "M": ("b", 1.0),
}


class DataFlash:
    """Messages of a DataFlash log, written as binary (.bin) or text (.log)."""

    def __init__(self) -> None:
        self.formats: dict[str, tuple[int, str, list[str]]] = {}
        self.lines: list[tuple[str, list[object]]] = []
        self.define("FMT", 128, "BBnNZ", "Type,Length,Name,Format,Columns", emit=False)

    def define(self, name: str, type_id: int, fmt: str, columns: str, *, emit: bool = True):
        self.formats[name] = (type_id, fmt, columns.split(","))
        if emit or name == "FMT":
            length = 3 + struct.calcsize("<" + "".join(_CODES[c][0] for c in fmt))
            self.lines.append(("FMT", [type_id, length, name, fmt, columns]))

    def add(self, name: str, *values: object) -> None:
        self.lines.append((name, list(values)))

    def binary(self) -> bytes:
        out = bytearray()
        for name, values in self.lines:
            type_id, fmt, _ = self.formats[name]
            packed = []
            for c, v in zip(fmt, values, strict=True):
                code, scale = _CODES[c]
                if code.endswith("s"):
                    packed.append(str(v).encode())
                elif scale != 1.0:
                    packed.append(round(float(v) / scale))  # type: ignore[arg-type]
                else:
                    packed.append(v)
            body = struct.pack("<" + "".join(_CODES[c][0] for c in fmt), *packed)
            out += bytes([0xA3, 0x95, type_id]) + body
        return bytes(out)

    def text(self) -> str:
        return "".join(
            f"{name}, {', '.join(str(v) for v in values)}\n" for name, values in self.lines
        )


def _ardupilot_log(n: int = 200) -> tuple[DataFlash, dict[str, np.ndarray]]:
    """400 Hz IMU in two instances, 10 Hz attitude with units, MODE and MSG events."""
    log = DataFlash()
    log.define("UNIT", 177, "QbZ", "TimeUS,Id,Label")
    log.define("MULT", 178, "Qbd", "TimeUS,Id,Mult")
    log.define("FMTU", 179, "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
    log.define("IMU", 150, "QBfff", "TimeUS,I,GyrX,GyrY,AccZ")
    log.define("ATT", 151, "Qccf", "TimeUS,Roll,Pitch,Yaw")
    log.define("MODE", 152, "QMBB", "TimeUS,Mode,ModeNum,Rsn")
    log.define("MSG", 153, "QZ", "TimeUS,Message")
    for uid, label in (
        (ord("s"), "s"),
        (ord("E"), "rad/s"),
        (ord("o"), "m/s/s"),
        (ord("d"), "deg"),
        (ord("#"), "instance"),
        (ord("-"), ""),
    ):
        log.add("UNIT", 1_000_000, uid, label)
    log.add("MULT", 1_000_000, ord("F"), 1e-6)
    log.add("MULT", 1_000_000, ord("-"), 0.0)
    log.add("FMTU", 1_000_000, 150, "s#EEo", "F----")
    log.add("FMTU", 1_000_000, 151, "sddd", "F---")
    rng = np.random.default_rng(1)
    t_imu = 2_000_000 + 2500 * np.arange(n)  # µs, 400 Hz
    gyr = rng.standard_normal((2, n, 3)).astype(np.float32)
    t_att = 2_000_000 + 100_000 * np.arange(n // 40)
    roll = np.round(rng.uniform(-30, 30, t_att.size), 2)
    log.add("MODE", 2_000_000, 0, 0, 1)
    log.add("MSG", 2_100_000, "ArduPlane V4.5.0")
    for k in range(n):
        for inst in (0, 1):
            log.add("IMU", int(t_imu[k]), inst, *(float(x) for x in gyr[inst, k]))
        if k % 40 == 0:
            j = k // 40
            log.add("ATT", int(t_att[j]), float(roll[j]), -1.5, 90.0)
        if k == n // 2:
            log.add("MODE", int(t_imu[k]), 10, 10, 2)
    truth = {
        "t_imu": t_imu / 1e6,
        "gyr": gyr,
        "t_att": t_att / 1e6,
        "roll": roll,
        "mode_time": t_imu[n // 2] / 1e6,
    }
    return log, truth


@pytest.fixture(scope="module")
def dataflash_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("df")
    log, truth = _ardupilot_log()
    (d / "flight.bin").write_bytes(log.binary())
    (d / "flight.log").write_text(log.text())
    return d, truth


@pytest.mark.parametrize("name", ["flight.bin", "flight.log"])
def test_dataflash_round_trip(dataflash_files, name):
    d, truth = dataflash_files
    log = aeroid.read_log(d / name)
    assert isinstance(log, FlightLog)
    gyr_y = log["IMU.GyrY"]
    np.testing.assert_allclose(gyr_y.time, truth["t_imu"], rtol=0, atol=1e-12)
    # float32 on disk: exact in binary; the text writer prints the float32's repr
    np.testing.assert_allclose(gyr_y.values, truth["gyr"][0, :, 1], rtol=1e-6)
    np.testing.assert_allclose(log["IMU[1].AccZ"].values, truth["gyr"][1, :, 2], rtol=1e-6)
    assert gyr_y.unit == "rad/s" and log["IMU.AccZ"].unit == "m/s/s"
    assert gyr_y.rate == pytest.approx(400.0)
    roll = log["ATT.Roll"]
    # 'c' columns are centi-units scaled by pymavlink: 12.34 is stored as 1234
    np.testing.assert_allclose(roll.values, truth["roll"], atol=1e-9)
    np.testing.assert_allclose(roll.time, truth["t_att"], atol=1e-12)
    assert roll.unit == "deg" and log["ATT.Pitch"].values[0] == pytest.approx(-1.5)
    modes = [e for e in log.events if e.kind == "mode"]
    assert [round(e.time, 6) for e in modes] == [2.0, round(truth["mode_time"], 6)]
    assert modes[1].value.endswith("(mode 10)")
    assert any(e.kind == "message" and "ArduPlane" in e.value for e in log.events)
    assert "MODE.ModeNum" in log.channels and "FMTU.FmtType" not in log.channels


def test_dataflash_binary_cut_mid_message_keeps_whole_messages(dataflash_files, tmp_path):
    d, truth = dataflash_files
    raw = (d / "flight.bin").read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(raw[:-7])  # the last IMU message loses its tail
    log = aeroid.read_log(cut)
    assert log["IMU[1].GyrX"].time.size == truth["t_imu"].size - 1
    np.testing.assert_allclose(log["IMU.GyrX"].values, truth["gyr"][0, :, 0], rtol=1e-6)


def test_format_is_sniffed_from_magic_bytes_not_suffix(dataflash_files, tmp_path):
    d, _ = dataflash_files
    renamed = tmp_path / "flight.dat"
    renamed.write_bytes((d / "flight.bin").read_bytes())
    assert aeroid.read_log(renamed).metadata["format"] == "dataflash"
    ulog_as_bin = tmp_path / "px4.bin"
    ulog_as_bin.write_bytes(ULOG.read_bytes())
    assert aeroid.read_log(ulog_as_bin).metadata["format"] == "ulog"


# -- PX4 ULog -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def px4():
    return aeroid.read_log(ULOG)


def test_ulog_channels_rates_and_units(px4):
    listing = aeroid.list_channels(ULOG)
    assert listing.format == "ulog" and len(listing) == len(px4.channels) > 500
    for name in (
        "vehicle_angular_velocity.xyz[0]",
        "sensor_combined.gyro_rad[0]",
        "sensor_combined.accelerometer_m_s2[2]",
        "vehicle_attitude.q[0]",
        "actuator_outputs.output[0]",
        "actuator_outputs_1.output[0]",  # the second instance of a multi-instance topic
    ):
        assert name in listing
    # PX4 logs rate loops in the hundreds of Hz, attitude and IMU near 200 Hz here
    assert 150 < listing.rate("vehicle_angular_velocity.xyz[0]") < 1000
    assert 100 < listing.rate("sensor_combined.gyro_rad[0]") < 1000
    assert 0.5 < listing.rate("vehicle_status.nav_state") < 10
    assert px4["vehicle_angular_velocity.xyz[1]"].unit == "rad/s"
    assert px4["sensor_combined.accelerometer_m_s2[0]"].unit == "m/s^2"
    assert px4["sensor_combined.gyro_rad[2]"].unit == "rad/s"  # not "rad" from its suffix
    assert px4["vehicle_attitude_setpoint.roll_body"].unit == "rad"
    assert px4["vehicle_attitude.q[0]"].unit == ""  # a quaternion: no unit claimed
    table = listing.summary()
    assert table.splitlines()[2].startswith("| channel | rate (Hz)")
    assert "| vehicle_angular_velocity.xyz[0] |" in table


def test_ulog_values_are_physical(px4):
    # a unit quaternion, gravity on the accelerometers, rates of a small vehicle
    q = np.column_stack([px4[f"vehicle_attitude.q[{i}]"].values for i in range(4)])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    acc = np.column_stack(
        [px4[f"sensor_combined.accelerometer_m_s2[{i}]"].values for i in range(3)]
    )
    assert 8.0 < float(np.median(np.linalg.norm(acc, axis=1))) < 11.6
    gyro = px4["vehicle_angular_velocity.xyz[0]"]
    assert np.all(np.abs(gyro.values) < 35.0)  # below the gyro's 2000 deg/s range
    assert np.all(np.diff(gyro.time) >= 0) and gyro.time[0] > 0  # seconds since boot
    out = px4["actuator_outputs.output[0]"].values
    assert np.all((out >= 0) & (out <= 2200))  # PWM microseconds or 0 when disarmed


def test_ulog_events(px4):
    kinds = {e.kind for e in px4.events}
    assert {"mode", "message"} <= kinds
    assert any("Takeoff detected" in e.value for e in px4.events)
    assert [e.time for e in px4.events] == sorted(e.time for e in px4.events)
    first_mode = next(e for e in px4.events if e.kind == "mode")
    assert first_mode.value.endswith("(nav_state 0)") and first_mode.value.startswith("MANUAL")


def test_truncated_and_unknown_files_are_refused(tmp_path):
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(ULOG.read_bytes()[:60])
    with pytest.raises(DataFormatError, match=r"cut\.ulg: .*no data"):
        aeroid.read_log(cut)
    short = tmp_path / "short.ulg"
    short.write_bytes(b"ULo")
    with pytest.raises(DataFormatError, match=r"short\.ulg: not a ulog file.*3 bytes"):
        aeroid.read_log(short)
    odd = tmp_path / "flight.xyz"
    odd.write_bytes(b"\x00\x01 some bytes")
    with pytest.raises(DataFormatError, match=r"flight\.xyz: unknown log format"):
        aeroid.read_log(odd)
    with pytest.raises(DataFormatError, match="unknown log format 'px5'"):
        aeroid.read_log(ULOG, format="px5")
    with pytest.raises(DataFormatError, match="no such file"):
        aeroid.read_log(tmp_path / "none.ulg")
    with pytest.raises(DataFormatError, match=r"not a dataflash file"):
        aeroid.read_log(ULOG, format="dataflash")


def test_missing_library_names_the_extra(monkeypatch, tmp_path):
    import sys

    monkeypatch.setitem(sys.modules, "pyulog", None)  # import fails as if not installed
    with pytest.raises(DataFormatError, match=r'pip install "aeroid\[logs\]"'):
        aeroid.read_log(ULOG)


# -- HDF5 and MATLAB v7.3 ---------------------------------------------------------------


def test_hdf5_groups_units_and_time_units(tmp_path):
    t_ms = np.arange(0, 2000, 10.0)  # 100 Hz in milliseconds
    path = tmp_path / "flight.h5"
    with h5py.File(path, "w") as f:
        f["time"] = t_ms
        f["time"].attrs["units"] = "ms"
        f["alpha"] = np.sin(t_ms / 1e3)
        f["alpha"].attrs["units"] = "rad"
        f["imu/t"] = np.arange(800) / 400.0
        f["imu/gyro"] = np.arange(2400.0).reshape(800, 3)
        f["imu/gyro"].attrs["unit"] = b"rad/s"
        f["label"] = np.bytes_("flight 7")
        f["odd"] = np.ones(7)
    log = aeroid.read_log(path)
    assert log.metadata["format"] == "hdf5"
    np.testing.assert_allclose(log["alpha"].time, t_ms / 1e3)
    assert log["alpha"].unit == "rad" and log["alpha"].rate == pytest.approx(100.0)
    np.testing.assert_array_equal(log["imu.gyro[2]"].values, np.arange(2400.0)[2::3])
    assert log["imu.gyro[0]"].unit == "rad/s" and log["imu.gyro[1]"].rate == pytest.approx(400.0)
    assert "label" not in log.channels and "odd" in log.metadata["skipped"]
    assert set(log.channels) == {"alpha", "imu.gyro[0]", "imu.gyro[1]", "imu.gyro[2]"}
    with pytest.raises(DataFormatError, match=r"flight\.h5: no time dataset.*time_column"):
        aeroid.read_log(path, time_column="clock")
    # load_flight_test: a mapping either way round; one time axis or a sample rate
    data = aeroid.load_flight_test(path, channels={"alpha": "a"})
    assert data.names == ("a",) and data.units["a"] == "rad"
    np.testing.assert_allclose(data.time, t_ms / 1e3)
    with pytest.raises(DataFormatError, match=r"'alpha' \(100 Hz\) and 'imu.gyro\[0\]' \(400 Hz\)"):
        aeroid.load_flight_test(path, channels=["alpha", "imu.gyro[0]"])
    with pytest.raises(DataFormatError, match="time_column applies to HDF5 files only"):
        aeroid.load_flight_test(ULOG, time_column="t", channels=["vehicle_status.nav_state"])


def _matlab_v73(path: Path, t: np.ndarray, p: np.ndarray, q_row: np.ndarray) -> None:
    """The layout MATLAB's save -v7.3 writes: 512-byte header, arrays transposed, classes."""
    with h5py.File(path, "w", userblock_size=512) as f:
        f["t"] = t.reshape(1, -1)  # a MATLAB column vector n x 1 is stored 1 x n
        f["t"].attrs["MATLAB_class"] = np.bytes_("double")
        f.create_group("flight").attrs["MATLAB_class"] = np.bytes_("struct")
        f["flight/p"] = p.reshape(1, -1)
        f["flight/q"] = q_row.reshape(-1, 1)  # a MATLAB row vector 1 x n is stored n x 1
        f["flight/uv"] = np.vstack([p, 2 * p])  # MATLAB n x 2 stored 2 x n
        for name in ("flight/p", "flight/q", "flight/uv"):
            f[name].attrs["MATLAB_class"] = np.bytes_("double")
        f["name"] = np.array([[ord(c)] for c in "run1"], dtype=np.uint16)
        f["name"].attrs["MATLAB_class"] = np.bytes_("char")
    header = (
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Wed Nov 25 2026 HDF5 schema 1.00 ."
    )
    with open(path, "r+b") as f:
        f.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM")


def test_matlab_v73_vectors_struct_and_matrix(tmp_path):
    t = np.linspace(0.0, 1.0, 51)
    path = tmp_path / "flight.mat"
    _matlab_v73(path, t, np.sin(t), np.cos(t))
    log = aeroid.read_log(path)
    assert log.metadata["format"] == "matlab"
    np.testing.assert_allclose(log["flight.p"].values, np.sin(t))
    np.testing.assert_allclose(log["flight.q"].values, np.cos(t))
    np.testing.assert_allclose(log["flight.uv_1"].values, 2 * np.sin(t))
    np.testing.assert_allclose(log["flight.q"].time, t)
    assert "name" not in log.channels
    # one time for all: load_flight_test gives FlightData without resampling
    data = aeroid.load_flight_test(path, channels={"flight.p": "p", "flight.q": "q"})
    assert data.names == ("p", "q") and data.metadata["format"] == "matlab"
    np.testing.assert_allclose(data["q"], np.cos(t))
    np.testing.assert_allclose(data.time, t)


def test_truncated_hdf5_is_refused(tmp_path):
    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(1000.0)
        f["x"] = np.arange(1000.0)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(path.read_bytes()[:3000])
    with pytest.raises(DataFormatError, match=r"cut\.h5: not a readable HDF5 file"):
        aeroid.read_log(cut)


# -- load_flight_test on a log --------------------------------------------------------


def test_load_flight_test_on_a_log_needs_channels_and_a_rate(tmp_path):
    with pytest.raises(
        ChannelError, match=r"'vehicle_angular_velocity.xyz\[7\]' not found.*close names"
    ):
        aeroid.load_flight_test(
            ULOG, channels=["vehicle_angular_velocity.xyz[7]"], sample_rate=100.0
        )
    with pytest.raises(DataFormatError, match="sample_rate"):
        aeroid.load_flight_test(
            ULOG, channels=["vehicle_angular_velocity.xyz[0]", "vehicle_attitude.q[0]"]
        )


def test_load_flight_test_resamples_a_log():
    pytest.importorskip("aeroid.io.resampling")
    names = {"p": "vehicle_angular_velocity.xyz[0]", "q0": "vehicle_attitude.q[0]"}
    # the log's gyro topic starts with a 0.16 s hole: refused by default, bridged on request
    with pytest.raises(DataFormatError, match=r"sample_log_small\.ulg: channel .*gap"):
        aeroid.load_flight_test(ULOG, channels=names, sample_rate=100.0)
    data = aeroid.load_flight_test(
        ULOG, channels=names, sample_rate=100.0, max_gap=float("inf"), units={"q0": "-"}
    )
    assert data.names == ("p", "q0")
    assert data.sample_rate == pytest.approx(100.0, rel=1e-6)
    assert data.units["p"] == "rad/s" and data.units["q0"] == "-"
    assert data.metadata["source"] == "sample_log_small.ulg"
    log = aeroid.read_log(ULOG)
    src = log["vehicle_attitude.q[0]"]
    # the resampled attitude stays within the range the log spans
    assert (
        src.values.min() - 1e-9 <= data["q0"].min() and data["q0"].max() <= src.values.max() + 1e-9
    )


def test_a_whole_log_loads_what_can_be_resampled_over_its_bulk():
    log = aeroid.read_log(ULOG)
    with pytest.warns(UserWarning) as caught:
        data = aeroid.load_flight_test(ULOG, sample_rate=100)
    (warning,) = [w for w in caught if "left out" in str(w.message)]  # one warning
    text = str(warning.message)
    left = data.metadata["resampling"]["left_out"]
    counts: dict[str, int] = {}
    for why in left.values():
        counts[why] = counts.get(why, 0) + 1
    for why, k in counts.items():
        assert f"{why} ({k})" in text
    assert f"{len(left)} of {len(log.channels)} channels left out" in text
    assert len(data.channels) + len(left) == len(log.channels)
    assert len(data.channels) > 800  # of 1162
    # why each is left out
    assert left["battery_status.temperature"] == "NaN or inf"  # PX4 never set it
    assert left["mission.count"] == "one sample"
    assert left["yaw_estimator_status.yaw[0]"] == "outside the span"  # logged for 1 s
    assert left["ekf_gps_drift.hpos_drift_rate"] == "a gap in the span"  # 1.2 s hole
    # the span: from the last of the kept topics to start (the 1 Hz sensors start a
    # second after the rest) to the first to end: 5 of the log's 6.5 s, where every
    # channel's common span is about 1 s
    a, b = data.metadata["resampling"]["window"]
    assert a == max(log[n].time[0] for n in data.channels) > 21.3
    assert b <= min(log[n].time[-1] for n in data.channels) and b - a > 4.9
    spans = [
        (c.time[0], c.time[-1])
        for n, c in log.channels.items()
        if n in data.channels or left[n] in ("outside the span", "a gap in the span")
    ]
    common = min(e for _, e in spans) - max(s for s, _ in spans)
    assert common == pytest.approx(1.0, abs=0.1)  # what every channel covers
    # the gyro on the grid is exactly what a strict load of it over that span gives
    gyro = "vehicle_angular_velocity.xyz[0]"
    alone = aeroid.load_flight_test(ULOG, channels=[gyro], sample_rate=100, t0=a, t1=b)
    np.testing.assert_array_equal(data[gyro], alone[gyro])
    assert data.units[gyro] == "rad/s"
    # channels= keeps the strict rule: an error naming the channel
    with pytest.raises(DataFormatError, match=r"'battery_status.temperature': nan value"):
        aeroid.load_flight_test(ULOG, channels=["battery_status.temperature"], sample_rate=100)


def test_the_readme_whole_log_snippet_runs(monkeypatch, capsys):
    import re

    text = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    (block,) = [b for b in re.findall(r"```py\n(.*?)```", text, flags=re.S) if "read_log" in b]
    monkeypatch.chdir(Path(__file__).parents[1])  # the snippet runs from a clone's root
    namespace: dict[str, object] = {}
    with pytest.warns(UserWarning, match="336 of 1162 channels left out"):
        exec(compile(block, "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    assert "76 of 1162 channels flagged" in out and "1. frozen" in out
    assert "- constant: 624 channels" in out
    data = namespace["data"]
    assert len(data.channels) == 826  # type: ignore[attr-defined]
    assert data.time[0] == pytest.approx(21.33, abs=0.005)  # type: ignore[attr-defined]
    assert data.time[-1] == pytest.approx(26.29, abs=0.01)  # type: ignore[attr-defined]


def _topics_file(path: Path, spans: dict[str, tuple[float, float]]) -> Path:
    """An HDF5 log with one group per topic, each a 50 Hz sine over its span."""
    with h5py.File(path, "w") as f:
        for topic, (start, end) in spans.items():
            t = np.arange(start, end + 1e-9, 0.02)
            f[f"{topic}/time"] = t
            f[f"{topic}/x"] = np.sin(t)
    return path


def test_the_whole_log_span_is_the_most_topic_seconds(tmp_path):
    # ten topics over [0, 10] s, one over [4, 5] s: the common span would be 1 s; the
    # chosen one keeps ten topics for 10 s and leaves the short one out
    spans = {f"t{i}": (0.0, 10.0) for i in range(10)}
    path = _topics_file(tmp_path / "a.h5", {**spans, "event": (4.0, 5.0)})
    with pytest.warns(UserWarning, match=r"1 of 11 channels left out: outside the span \(1\)"):
        data = aeroid.load_flight_test(path, sample_rate=25)
    assert data.time[0] == 0.0 and data.time[-1] == pytest.approx(10.0)
    assert data.metadata["resampling"]["left_out"] == {"event.x": "outside the span"}
    # a topic that starts 0.5 s late costs 5 % of the span and is worth 1/11 of the
    # topics: it is kept (10.5 topic-seconds gained); one that starts 2 s late is not
    late = _topics_file(tmp_path / "b.h5", {**spans, "late": (0.5, 10.0)})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left out: no warning
        data = aeroid.load_flight_test(late, sample_rate=25)
    assert data.time[0] == pytest.approx(0.5) and len(data.channels) == 11
    later = _topics_file(tmp_path / "c.h5", {**spans, "late": (2.0, 10.0)})
    with pytest.warns(UserWarning, match="outside the span"):
        data = aeroid.load_flight_test(later, sample_rate=25)
    assert data.time[0] == 0.0 and "late.x" not in data.channels
    # t0/t1 fix the span; what does not cover it is left out
    data = aeroid.load_flight_test(later, sample_rate=25, t0=3.0, t1=9.0)  # all cover it
    assert len(data.channels) == 11 and (data.time[0], data.time[-1]) == (3.0, 9.0)
    with pytest.warns(UserWarning, match=r"1 of 11 channels left out: outside the span \(1\)"):
        data = aeroid.load_flight_test(later, sample_rate=25, t0=1.0)
    assert data.time[0] == 1.0 and data.time[-1] == pytest.approx(10.0)
    # bad options are named before anything is resampled
    with pytest.raises(DataFormatError, match=r"c\.h5: sample_rate: expected a positive"):
        aeroid.load_flight_test(later, sample_rate=0)
    with pytest.raises(DataFormatError, match=r"c\.h5: t0: expected a finite time"):
        aeroid.load_flight_test(later, sample_rate=25, t0="start")
    with pytest.raises(DataFormatError, match=r"c\.h5: max_gap: expected a positive"):
        aeroid.load_flight_test(later, sample_rate=25, max_gap=-1.0)
    # nothing that can be resampled: an error, not an empty record
    empty = tmp_path / "empty.h5"
    with h5py.File(empty, "w") as f:
        f["t/time"] = np.arange(10.0)
        f["t/x"] = np.full(10, np.nan)
    with pytest.raises(DataFormatError, match=r"empty\.h5: no channel of the log can be"):
        aeroid.load_flight_test(empty, sample_rate=5)


def test_records_are_exported():
    from aeroid.io.logs import listing as listing_of

    ch = LogChannel("a.b", [0.0, 1.0], [1.0, 2.0], "m")
    log = FlightLog({"a.b": ch}, (LogEvent(0.5, "mode", "MANUAL"),), {"source": "x"})
    listing = listing_of(log)
    assert listing.names == ("a.b",) and listing.rate("a.b") == pytest.approx(1.0)
    assert not listing.rates.flags.writeable


def test_a_format_record_that_lies_about_its_length_is_refused(tmp_path):
    log, _ = _ardupilot_log(80)
    # the IMU's FMT record claims two bytes more than its format packs
    for i, (name, values) in enumerate(log.lines):
        if name == "FMT" and values[2] == "IMU":
            log.lines[i] = ("FMT", [values[0], values[1] + 2, *values[2:]])
    path = tmp_path / "lying.bin"
    path.write_bytes(log.binary())
    with pytest.raises(DataFormatError, match=r"lying\.bin: message IMU: its FMT record declares"):
        aeroid.read_log(path)
