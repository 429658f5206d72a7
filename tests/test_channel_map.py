"""Channel maps: log channels to model names, unit conversions, windows, segmentation."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid.errors import AeroidError, ChannelError, DataFormatError
from aeroid.io.channel_map import (
    UNIT_CONVERSIONS,
    ChannelMap,
    ChannelSpec,
    apply_channel_map,
    flight_windows,
    load_mapped,
)
from aeroid.io.data import FlightData
from aeroid.models.catalog import first_order

ROOT = Path(__file__).resolve().parents[1]
PX4 = ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg"
ROLL = {
    "y": {"channel": "vehicle_angular_velocity.xyz[0]", "unit": "rad/s"},
    "u": {"channel": "actuator_controls_0.control[0]"},
}
# the settings that pick out the PX4 sample log's roll-control pulses (a 6.5 s log)
PX4_SEGMENTS = {
    "inputs": ["u"],
    "margin": 0.2,
    "min_duration": 0.1,
    "trim_window": 2.0,
    "energy_window": 0.2,
}

# the synthetic log's truth: p_dot = L_P p + L_DELTA delta_a
L_P, L_DELTA = -6.0, 20.0
AMP = math.radians(4.0)
PULSES = ((10.0, 2.0), (30.0, 2.0))  # (start, length) of each one-cycle sine, s
T_START = 3.0  # the log's clock starts at 3 s (time since boot)


def _aileron(t: np.ndarray) -> np.ndarray:
    out = np.zeros_like(t)
    for t0, length in PULSES:
        inside = (t >= t0) & (t <= t0 + length)
        out = out + np.where(inside, AMP * np.sin(2 * np.pi * (t - t0) / length), 0.0)
    return out


def _write_log(path: Path, *, seed: int = 0, noise: float = 0.002) -> None:
    """An HDF5 log: a 400 Hz gyro in deg/s, a 100 Hz aileron in centidegrees, a mode flag."""
    h5py = pytest.importorskip("h5py")
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    t_gyro = T_START + np.arange(0.0, 47.0, 1 / 400)
    sol = solve_ivp(
        lambda t, x: [L_P * x[0] + L_DELTA * float(_aileron(np.array([t]))[0])],
        (t_gyro[0], t_gyro[-1]),
        [0.0],
        t_eval=t_gyro,
        rtol=1e-10,
        atol=1e-12,
        max_step=0.01,
    )
    p = sol.y[0] + noise * rng.standard_normal(t_gyro.size)
    t_rc = T_START + np.arange(0.0, 47.0, 1 / 100)
    # a little noise on the stick: excitation is measured against the input's own floor
    aileron_cdeg = np.degrees(_aileron(t_rc)) * 100.0 + 0.5 * rng.standard_normal(t_rc.size)
    with h5py.File(path, "w") as f:
        imu = f.create_group("imu")
        imu["time"] = t_gyro
        imu["p"] = np.degrees(p)
        imu["p"].attrs["units"] = "deg/s"
        rc = f.create_group("rc")
        rc["time"] = t_rc
        rc["aileron"] = aileron_cdeg
        rc["mode"] = ((t_rc >= 25.0) & (t_rc < 40.0)).astype(float)


SYNTH_MAP = {
    "p": {"channel": "imu.p", "unit": "deg/s"},
    "delta_a": {"channel": "rc.aileron", "unit": "cdeg"},
}


@pytest.fixture(scope="module")
def synthetic_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "roll.h5"
    _write_log(path)
    return path


# -- conversions --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("unit", "raw", "expected", "si"),
    [
        ("deg", 180.0, math.pi, "rad"),
        ("cdeg", 18000.0, math.pi, "rad"),
        ("deg/s", 90.0, math.pi / 2, "rad/s"),
        ("us", 1500.0, 1.5e-3, "s"),
        ("ms", 250.0, 0.25, "s"),
        ("ft", 1000.0, 304.8, "m"),
        ("kt", 3600.0, 1852.0, "m/s"),  # a knot is one nautical mile (1852 m) an hour
        ("g", 2.0, 2 * 9.80665, "m/s2"),
        ("rad/s", 0.3, 0.3, "rad/s"),
    ],
)
def test_unit_conversions_to_si(unit, raw, expected, si):
    data = FlightData([0.0, 1.0], {"x": [raw, -raw]}, {"x": unit})
    out = apply_channel_map(data, {"model_x": {"channel": "x", "unit": unit}})
    assert out["model_x"] == pytest.approx([expected, -expected], rel=1e-12)
    assert out.units["model_x"] == si
    assert out.metadata["channel_map"]["model_x"]["unit"] == unit


def test_sign_scale_and_offset_and_the_recorded_choices():
    data = FlightData(
        [0.0, 1.0, 2.0], {"a": [1.0, 2.0, 4.0], "b": [10.0, 0.0, -10.0]}, {"a": "deg"}
    )
    out = apply_channel_map(
        data,
        {
            "flipped": {"channel": "a", "sign": -1},
            "negated": {"channel": "a", "scale": -1},
            "geared": {"channel": "a", "unit": "deg", "scale": 0.5, "offset": 0.1},
            "b": "b",
        },
    )
    assert out["flipped"] == pytest.approx([-1.0, -2.0, -4.0])
    assert np.array_equal(out["flipped"], out["negated"])
    # sign * scale * factor * raw + offset
    assert out["geared"] == pytest.approx(0.5 * np.radians([1.0, 2.0, 4.0]) + 0.1)
    assert out.names == ("flipped", "negated", "geared", "b")
    # a flip keeps the unit, a conversion gives SI, a scale alone leaves it unknown
    assert out.units == {"flipped": "deg", "negated": "deg", "geared": "rad"}
    assert out.metadata["channel_map"]["geared"] == {
        "channel": "a",
        "unit": "deg",
        "scale": 0.5,
        "offset": 0.1,
        "sign": 1,
    }
    import json

    json.dumps(dict(out.metadata), allow_nan=False)  # plain JSON: it enters the load key


def test_bad_maps_are_refused_with_what_is_wrong():
    data = FlightData([0.0, 1.0], {"gyro_x": [0.0, 1.0]})
    with pytest.raises(DataFormatError, match=r"'degs'.*did you mean.*known units: cdeg"):
        apply_channel_map(data, {"p": {"channel": "gyro_x", "unit": "degs"}})
    with pytest.raises(ChannelError, match=r"'gyro_y' not found.*close names: \['gyro_x'\]"):
        apply_channel_map(data, {"p": "gyro_y"})
    with pytest.raises(DataFormatError, match="sign: expected 1 or -1"):
        ChannelSpec("p", "gyro_x", sign=2)
    with pytest.raises(DataFormatError, match="unknown keys"):
        ChannelMap.from_config({"p": {"channel": "gyro_x", "gain": 2.0}})
    with pytest.raises(DataFormatError, match="'channel'"):
        ChannelMap.from_config({"p": {"unit": "deg"}})
    assert set(UNIT_CONVERSIONS) >= {"deg", "cdeg", "us", "ms", "ft", "kt", "g", "deg/s"}


# -- the real PX4 log ---------------------------------------------------------------


def test_px4_window_loads_the_mapped_channels_on_their_grid():
    pytest.importorskip("pyulog")
    data = load_mapped(PX4, ROLL, sample_rate=100.0, window=[23.4, 25.0])
    assert data.names == ("y", "u")
    assert data.n_samples == 161 and data.time[0] == pytest.approx(23.4)
    assert data.time[-1] == pytest.approx(25.0)
    assert data.units == {"y": "rad/s"}
    assert data.metadata["window"] == {"t0": 23.4, "t1": 25.0, "way": "time"}
    assert data.metadata["channel_map"]["y"]["channel"] == "vehicle_angular_velocity.xyz[0]"
    # the same samples as resampling the log's channel directly inside the window
    log = aeroid.read_log(PX4)
    direct = aeroid.resample(
        log, {"y": "vehicle_angular_velocity.xyz[0]"}, rate=100.0, t0=23.4, t1=25.0
    )
    assert np.array_equal(data["y"], direct["y"])
    # the roll actuator is a normalised command and the roll rate a few mrad/s
    assert np.all(np.abs(data["u"]) < 1.0) and np.max(np.abs(data["y"])) < 0.05
    flipped = load_mapped(
        PX4,
        {"y": {"channel": "vehicle_angular_velocity.xyz[0]", "sign": -1}},
        sample_rate=100.0,
        window=[23.4, 25.0],
    )
    assert np.array_equal(flipped["y"], -data["y"])


def test_px4_windows_from_events_and_from_excitation():
    pytest.importorskip("pyulog")
    hop = load_mapped(
        PX4,
        ROLL,
        sample_rate=100.0,
        window={
            "events": ["[INFO] [commander] Takeoff detected", "[INFO] [commander] Landing detected"]
        },
    )
    # the log's own event stamps (seconds since boot)
    assert hop.metadata["window"]["t0"] == pytest.approx(22.683736)
    assert hop.metadata["window"]["t1"] == pytest.approx(23.827776)
    windows = flight_windows(PX4, PX4_SEGMENTS, channels=ROLL)
    assert len(windows) == 2
    # a log already read gives the same windows (the pre-flight checks pass theirs)
    assert flight_windows(aeroid.read_log(PX4), PX4_SEGMENTS, channels=ROLL) == windows
    # the two roll-command pulses (23.73 s and 24.33 s) fall in the first window
    assert windows[0][0] < 23.7 and windows[0][1] > 24.4
    span = (20.326716, 26.825311)  # where both mapped channels have samples (IMU sample times)
    assert all(span[0] <= t0 < t1 <= span[1] for t0, t1 in windows)
    for t0, t1 in windows:  # each window loads as a flight
        assert load_mapped(PX4, ROLL, sample_rate=100.0, window=[t0, t1]).duration > 0.5


def test_px4_bad_inputs_name_the_fault():
    pytest.importorskip("pyulog")
    with pytest.raises(ChannelError, match=r"xyz\[3\]' not found.*close names"):
        load_mapped(PX4, {"y": {"channel": "vehicle_angular_velocity.xyz[3]"}}, sample_rate=100.0)
    with pytest.raises(DataFormatError, match="inverted"):
        load_mapped(PX4, ROLL, sample_rate=100.0, window=[25.0, 23.4])
    with pytest.raises(DataFormatError, match=r"not inside the span \[20.3267, 26.8253\]"):
        load_mapped(PX4, ROLL, sample_rate=100.0, window=[10.0, 25.0])
    with pytest.raises(AeroidError, match="no known conversion"):
        load_mapped(PX4, {"y": {"channel": "vehicle_angular_velocity.xyz[0]", "unit": "rpm"}})
    with pytest.raises(DataFormatError, match="unknown keys"):
        flight_windows(PX4, {"inputs": ["u"], "treshold": 3.0}, channels=ROLL)


def test_first_order_roll_fit_on_the_px4_log_converges_with_negative_roll_damping():
    """tau y' = K u - y is p_dot = L_p p + L_delta delta_a with L_p = -1/tau.

    The sample log is a short hop: two roll-command pulses of a few hundredths
    move the roll rate by a few mrad/s, so the fit is poorly determined (its
    standard errors are several times the estimates); what it must show is a
    converged fit with a stable vehicle's sign, found from different starts.
    """
    pytest.importorskip("pyulog")
    data = load_mapped(PX4, ROLL, sample_rate=100.0, window=[23.4, 25.0])
    fits = []
    for start in ({"K": 2.0, "tau": 0.5}, {"K": -0.05, "tau": 0.05}):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            fit = aeroid.identify(
                first_order(**start), data, ["K", "tau"], estimate_x0=True, estimate_bias=True
            )
        assert fit.success
        fits.append(fit)
    a, b = (f.parameters for f in fits)
    assert a["tau"] == pytest.approx(b["tau"], rel=1e-3) and a["K"] == pytest.approx(
        b["K"], rel=1e-3
    )
    l_p = -1.0 / a["tau"]
    assert -50.0 < l_p < -1.0  # roll damping of a small multirotor: a few per second
    assert np.all(np.isfinite(list(fits[0].stderr.values())))


# -- a synthetic log with a known truth -----------------------------------------------


def test_synthetic_log_windows_and_seeded_recovery_of_the_roll_derivatives(synthetic_log):
    # the two pulses, found from the aileron's excitation (model name as the input)
    windows = flight_windows(synthetic_log, {"inputs": ["delta_a"]}, channels=SYNTH_MAP)
    assert len(windows) == 2
    for (t0, t1), (start, length) in zip(windows, PULSES, strict=True):
        assert t0 < start + 0.05 and t1 > start + length - 0.05
        assert start - 1.5 < t0 and t1 < start + length + 1.5  # 1 s margins
    # a mode channel's window
    moded = load_mapped(
        synthetic_log, SYNTH_MAP, sample_rate=100.0, window={"mode": ["rc.mode", 1]}
    )
    assert moded.metadata["window"]["t0"] == pytest.approx(25.0)
    assert moded.metadata["window"]["t1"] == pytest.approx(39.99)
    # deg/s and centidegrees become rad/s and rad
    data = load_mapped(synthetic_log, SYNTH_MAP, sample_rate=100.0, window=[8.0, 15.0])
    assert data.units == {"p": "rad/s", "delta_a": "rad"}
    assert np.max(np.abs(data["delta_a"])) == pytest.approx(AMP, rel=0.01)
    flight = FlightData(data.time, {"y": data["p"], "u": data["delta_a"]})
    fit = aeroid.identify(first_order(K=1.0, tau=0.5), flight, ["K", "tau"])
    assert fit.success
    truth = {"K": -L_DELTA / L_P, "tau": -1.0 / L_P}
    for name, value in truth.items():
        # 4 standard errors, plus 0.5 % for the resampler's filtering of the gyro
        assert abs(fit.parameters[name] - value) < 4 * fit.stderr[name] + 5e-3 * abs(value)


def test_quality_is_checked_on_the_logs_own_stamps_inside_the_window(synthetic_log):
    plain_load = load_mapped(synthetic_log, SYNTH_MAP, sample_rate=100.0, window=[8.0, 15.0])
    assert "quality" not in plain_load.metadata
    data = load_mapped(
        synthetic_log, SYNTH_MAP, sample_rate=100.0, window=[8.0, 15.0], quality=True
    )
    np.testing.assert_array_equal(data["p"], plain_load["p"])
    q = data.metadata["quality"]
    assert list(q.channels) == ["imu.p", "rc.aileron"]  # the log's names, as read
    # 7 s of the 400 Hz gyro and the 100 Hz stick, not the 100 Hz grid they land on
    assert q["imu.p"].n_samples in (2800, 2801) and q["imu.p"].rate == pytest.approx(400.0)
    assert q["rc.aileron"].n_samples in (700, 701) and q["rc.aileron"].rate == pytest.approx(100)
    assert q.ok
    # limits are passed through; an unknown one is named before the file is read
    strict = load_mapped(
        synthetic_log, SYNTH_MAP, sample_rate=100.0, window=[8.0, 15.0], quality={"jitter_limit": 0}
    )
    assert strict.metadata["quality"].thresholds["jitter_limit"] == 0.0
    with pytest.raises(DataFormatError, match=r"unknown limit.*'jitter'"):
        load_mapped(Path("no-such-file.h5"), SYNTH_MAP, quality={"jitter": 0.1})


def test_quality_of_a_table_flags_a_dropout_by_its_column(tmp_path):
    t = np.arange(0.0, 20.0, 0.01)
    t = np.delete(t, np.s_[800:850])  # half a second missing
    path = tmp_path / "gappy.csv"
    np.savetxt(
        path,
        np.column_stack([t, np.sin(t), np.cos(t)]),
        delimiter=",",
        header="time,q,de",
        comments="",
    )
    data = load_mapped(path, {"q": "q", "de": "elevator"}, quality=True)
    q = data.metadata["quality"]
    assert set(q.channels) == {"q", "elevator"}
    assert q["q"].dropouts == 1 and q["q"].longest_gap == pytest.approx(0.51)
    assert "dropouts" in q["q"].flags


def _renamed_table(tmp_path: Path) -> Path:
    path = tmp_path / "renamed.csv"
    rows = [f"{0.02 * i:.2f},{0.01 * i},{0.1 + 0.01 * i},{0.5 * i}" for i in range(5)]
    path.write_text("time,de,aoa,qq\n" + "\n".join(rows) + "\n")
    return path


def test_a_plain_map_reads_one_way_round_in_every_reader(tmp_path):
    """{model_name: channel} (ChannelMap's reading) and {column: name} (the table's) give
    the same record in load_flight_test, load_mapped, apply_channel_map and the campaign's
    loader options: the side naming the file's columns is the channel side."""
    path = _renamed_table(tmp_path)
    forward = {"elevator": "de", "alpha": "aoa", "q": "qq"}
    backward = {v: k for k, v in forward.items()}
    raw = aeroid.load_flight_test(path)
    for m in (forward, backward):
        for data in (
            aeroid.load_flight_test(path, channels=m),
            load_mapped(path, m),
            load_mapped(path, m, window=[0.0, 0.08]),  # the ChannelMap path
            apply_channel_map(raw, m),
        ):
            assert set(data.names) == {"elevator", "alpha", "q"}
            np.testing.assert_array_equal(data["alpha"], raw["aoa"])
            np.testing.assert_array_equal(data["q"], raw["qq"])
    # a name paired with itself reads the same either way
    same = aeroid.load_flight_test(path, channels={"de": "de", "aoa": "alpha"})
    assert set(same.names) == {"de", "alpha"}


def test_a_plain_map_that_reads_both_ways_is_refused(tmp_path):
    path = _renamed_table(tmp_path)
    raw = aeroid.load_flight_test(path)
    # a cycle of the file's own columns: either reading would be applied silently
    cycle = {"de": "aoa", "aoa": "qq", "qq": "de"}
    for call in (
        lambda: aeroid.load_flight_test(path, channels=cycle),
        lambda: load_mapped(path, cycle),
        lambda: load_mapped(path, cycle, window=[0.0, 0.08]),
        lambda: apply_channel_map(raw, cycle),
    ):
        with pytest.raises(
            DataFormatError, match=r"of the file on both sides, so it reads both ways"
        ):
            call()
    # a map with no side all columns names what is missing
    with pytest.raises(ChannelError, match="'dee' not found"):
        aeroid.load_flight_test(path, channels={"elevator": "dee", "alpha": "aoa"})
