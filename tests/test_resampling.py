"""Multi-rate channels on one grid: accuracy against closed forms, and the refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

import aeroid
from aeroid import ChannelError, DataFormatError, FlightData, resample
from aeroid.io._logtypes import FlightLog, LogChannel, LogEvent

FREQS = (0.3, 1.7, 4.1, 7.3, 9.9)  # all below 0.4 x the new Nyquist (10 Hz at 50 Hz)
AMPS = (1.0, 0.7, 0.5, 0.4, 0.3)


def _signal(t: np.ndarray, phases: np.ndarray) -> np.ndarray:
    return sum(
        a * np.sin(2 * np.pi * f * t + p) for f, a, p in zip(FREQS, AMPS, phases, strict=True)
    )


def _phases(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0, 2 * np.pi, len(FREQS))


def _interior(data: FlightData, name: str) -> np.ndarray:
    """Grid points more than one filter half-length from the ends."""
    edge = data.metadata["resampling"]["channels"][name]["anti_alias"]["edge_s"]
    return (data.time > data.time[0] + edge) & (data.time < data.time[-1] - edge)


def _relative_rms(error: np.ndarray, signal: np.ndarray) -> float:
    return float(np.sqrt(np.mean(error**2)) / np.sqrt(np.mean(signal**2)))


@pytest.mark.parametrize("t0", [0.0, 0.0137])  # grid on source stamps, and between them
def test_decimation_400_to_50_hz_keeps_a_band_limited_signal_to_1e_3(t0):
    phases = _phases()
    t = np.arange(40 * 400 + 1) / 400.0
    out = resample({"x": (t, _signal(t, phases))}, ["x"], rate=50, t0=t0)
    inner = _interior(out, "x")
    truth = _signal(out.time[inner], phases)
    err = _relative_rms(out["x"][inner] - truth, truth)
    assert err <= 1e-3
    # the design's ripple (80 dB) is what bounds it, with room to spare
    assert err <= 3e-5
    assert out.sample_rate == pytest.approx(50.0)
    assert out.time[0] == t0


def test_linear_after_the_filter_obeys_the_interpolation_bound():
    # |error| <= sum_i A_i (w_i h)^2 / 8 for linear interpolation of the filtered
    # 400 Hz samples, plus the filter's ripple (1e-4 per unit amplitude)
    phases = _phases(1)
    t = np.arange(20 * 400 + 1) / 400.0
    out = resample({"x": (t, _signal(t, phases))}, ["x"], rate=50, t0=0.0137, method="linear")
    inner = _interior(out, "x")
    err = np.abs(out["x"][inner] - _signal(out.time[inner], phases))
    h = 1 / 400.0
    bound = sum(
        a * (2 * np.pi * f * h) ** 2 / 8 for f, a in zip(FREQS, AMPS, strict=True)
    ) + 1e-4 * sum(AMPS)
    assert err.max() <= bound
    assert err.max() >= 0.3 * bound  # the bound is the right size: linear is not exact here


def test_decimation_removes_what_would_alias():
    # tones above the new Nyquist frequency would fold into the band (26 Hz onto
    # 24 Hz, 40 Hz onto 10 Hz at 50 Hz); the filter is 80 dB (1e-4) down from 25 Hz
    t = np.arange(20 * 400 + 1) / 400.0
    for f in (25.0, 26.0, 40.0, 150.0):
        x = np.sin(2 * np.pi * f * t + 0.3)
        out = resample({"x": (t, x)}, ["x"], rate=50, t0=0.0013)
        assert np.abs(out["x"][_interior(out, "x")]).max() <= 1e-4, f
    # and a tone at 0.75 x the new Nyquist passes within the passband ripple
    y = np.sin(2 * np.pi * 18.75 * t)
    out = resample({"y": (t, y)}, ["y"], rate=50, t0=0.0021)
    inner = _interior(out, "y")
    assert np.abs(out["y"][inner] - np.sin(2 * np.pi * 18.75 * out.time[inner])).max() <= 5e-4


def test_decimation_from_jittered_stamps():
    # non-uniform stamps go first to a uniform grid at the median rate
    phases = _phases(2)
    rng = np.random.default_rng(3)
    t = np.arange(30 * 400 + 1) / 400.0 + rng.uniform(-0.3, 0.3, 30 * 400 + 1) / 400.0
    out = resample({"x": (t, _signal(t, phases))}, ["x"], rate=50)
    inner = _interior(out, "x")
    truth = _signal(out.time[inner], phases)
    assert _relative_rms(out["x"][inner] - truth, truth) <= 1e-3
    record = out.metadata["resampling"]["channels"]["x"]
    assert record["uniformized"] is True and record["method"] == "cubic"


def test_upsampling_linear_and_cubic_meet_their_error_bounds():
    # sin(w t) sampled at 10 Hz, put on 100 Hz: linear error <= (w h)^2 / 8 and
    # reaches about that at mid-steps near the peaks; not-a-knot cubic is
    # within 5/384 (w h)^4 away from the ends
    w, h = 2 * np.pi * 0.5, 0.1
    t = np.arange(0, 20 + h / 2, h)
    lin = resample({"s": (t, np.sin(w * t))}, ["s"], rate=100)
    err = np.abs(lin["s"] - np.sin(w * lin.time))
    bound = (w * h) ** 2 / 8
    assert err.max() <= bound * (1 + 1e-9)
    assert err.max() >= 0.95 * bound
    cub = resample({"s": (t, np.sin(w * t))}, ["s"], rate=100, method="cubic")
    inner = (cub.time > 2) & (cub.time < 18)
    err = np.abs(cub["s"] - np.sin(w * cub.time))[inner]
    assert err.max() <= 5 / 384 * (w * h) ** 4 * 1.05
    assert lin.metadata["resampling"]["channels"]["s"]["anti_alias"] is None


@pytest.mark.parametrize("method", ["auto", "linear", "cubic", "hold"])
def test_a_constant_stays_exactly_constant(method):
    rng = np.random.default_rng(4)
    fast = np.arange(4001) / 400 + rng.uniform(-0.4, 0.4, 4001) / 400  # uniformised, filtered
    slow = np.arange(0, 10.01, 0.1)
    dup = np.repeat(np.arange(0, 10.01, 0.05), 2)  # every stamp twice
    log = {
        "fast": (fast, np.full(fast.size, 0.1 + 0.2)),
        "slow": (slow, np.full(slow.size, -1.234567)),
        "dup": (dup, np.full(dup.size, 0.1)),
    }
    out = resample(log, ["fast", "slow", "dup"], rate=50, method=method)
    assert np.all(out["fast"] == 0.1 + 0.2)
    assert np.all(out["slow"] == -1.234567)
    assert np.all(out["dup"] == 0.1)


def test_log_units_mapping_and_metadata_are_recorded():
    t400 = np.arange(0, 12, 1 / 400)
    t10 = np.arange(0.05, 12, 0.1)
    log = FlightLog(
        {
            "IMU.GyrY": LogChannel("IMU.GyrY", t400, np.sin(t400), "rad/s"),
            "ARSP.Airspeed": LogChannel("ARSP.Airspeed", t10, 20 + 0 * t10, "m/s"),
        },
        (LogEvent(3.0, "mode", "SYSID"), LogEvent(9.0, "mode", "FBWA")),
        {"source": "flight.bin", "format": "dataflash", "handle": object()},
    )
    out = resample(log, {"q": "IMU.GyrY", "V": "ARSP.Airspeed"}, rate=50)
    assert out.names == ("q", "V")
    assert dict(out.units) == {"q": "rad/s", "V": "m/s"}
    meta = dict(out.metadata)
    json.dumps(meta, allow_nan=False)  # plain JSON: it enters the load key
    rs = meta["resampling"]
    assert rs["rate_hz"] == 50.0 and rs["mapping"] == {"q": "IMU.GyrY", "V": "ARSP.Airspeed"}
    assert rs["method"] == "auto"
    # default span: where both channels have samples
    assert out.time[0] == pytest.approx(0.05) and out.time[-1] <= t10[-1]
    q, v = rs["channels"]["q"], rs["channels"]["V"]
    assert q["source_rate_hz"] == pytest.approx(400) and v["source_rate_hz"] == pytest.approx(10)
    design = q["anti_alias"]
    assert design["taps"] % 2 == 1 and design["stopband_edge_hz"] == 25.0
    assert design["passband_edge_hz"] == 20.0 and design["attenuation_db"] == 80.0
    assert v["anti_alias"] is None and v["method"] == "linear"
    assert meta["source"] == "flight.bin" and "handle" not in meta
    assert meta["events"] == [[3.0, "mode", "SYSID"], [9.0, "mode", "FBWA"]]
    assert aeroid.resample is resample


def test_window_t0_t1_narrow_the_span_and_must_lie_inside_it():
    t = np.arange(0, 10, 0.01)
    log = {"a": (t, t), "b": (t + 2, t)}
    out = resample(log, ["a", "b"], rate=20, t0=3, t1=5)
    assert out.time[0] == 3 and out.time[-1] == pytest.approx(5)
    np.testing.assert_allclose(out["a"], out.time, atol=1e-12)
    with pytest.raises(DataFormatError, match=r"t0 = 1.0 s is before channel 'b' starts \(2 s\)"):
        resample(log, ["a", "b"], rate=20, t0=1.0)
    with pytest.raises(DataFormatError, match=r"t1 = 11.5 s is after channel 'a' ends"):
        resample(log, ["a", "b"], rate=20, t1=11.5)
    with pytest.raises(DataFormatError, match="do not overlap"):
        resample({"a": (t, t), "b": (t + 20, t)}, ["a", "b"], rate=20)


def test_a_gap_is_reported_not_bridged():
    t = np.arange(0, 10, 0.01)
    t = t[(t < 3.2) | (t >= 3.7)]  # 0.5 s without samples after 3.19
    log = {"IMU.AccX": (t, np.cos(t))}
    with pytest.raises(DataFormatError, match=r"'IMU.AccX'.*gap of 0.51 s.*t = 3.19 s"):
        resample(log, ["IMU.AccX"], rate=50)
    # the default limit is 5 median steps; a larger max_gap or a window around it passes
    # (the filter reaches half its length, 0.5 s here, beyond the window)
    assert resample(log, ["IMU.AccX"], rate=50, t1=2.5).time[-1] == pytest.approx(2.5)
    with pytest.raises(DataFormatError, match="gap"):
        resample(log, ["IMU.AccX"], rate=50, max_gap=0.5)
    out = resample(log, ["IMU.AccX"], rate=50, max_gap=float("inf"))
    record = out.metadata["resampling"]["channels"]["IMU.AccX"]
    assert record["max_gap_s"] == "inf"
    assert record["bridged_gaps"] == [[pytest.approx(3.19), pytest.approx(0.51)]]
    json.dumps(dict(out.metadata), allow_nan=False)
    assert resample(log, ["IMU.AccX"], rate=50, max_gap={"IMU.AccX": 0.6}).n_samples == 500


def test_a_missing_channel_names_close_ones():
    log = {"IMU.GyrX": ([0, 1], [0, 0]), "IMU.GyrY": ([0, 1], [0, 0]), "GPS.Alt": ([0, 1], [0, 0])}
    with pytest.raises(ChannelError, match=r"'IMU.GyroY' not found.*did you mean.*'IMU.GyrY'"):
        resample(log, ["IMU.GyroY"], rate=10)
    with pytest.raises(ChannelError, match="'q'"):
        resample(FlightLog({}), {"q": "q"}, rate=10)


def test_duplicate_and_out_of_order_stamps_are_averaged_sorted_and_recorded():
    t = np.arange(0, 5.001, 0.01)
    x = 2.0 * t
    # a repeated stamp whose two readings straddle the line, and two swapped samples
    t2 = np.concatenate((t, [t[100]]))
    x2 = np.concatenate((x, [x[100] - 0.5]))
    x2[100] += 0.5
    t2[[200, 201]] = t2[[201, 200]]
    x2[[200, 201]] = x2[[201, 200]]
    out = resample({"x": (t2, x2)}, ["x"], rate=20)
    np.testing.assert_allclose(out["x"], 2.0 * out.time, atol=1e-12)
    record = out.metadata["resampling"]["channels"]["x"]
    assert record["duplicate_stamps"] == 1 and record["reordered_stamps"] == 2


def test_nan_values_name_the_channel_and_the_time():
    t = np.arange(0, 5, 0.01)
    x = np.sin(t)
    x[123] = np.nan
    with pytest.raises(DataFormatError, match=r"channel 'baro.alt': nan value at t = 1.23 s"):
        resample({"baro.alt": (t, x)}, ["baro.alt"], rate=10)
    t = t.copy()
    t[5] = np.inf
    with pytest.raises(DataFormatError, match="'v': non-finite time stamp at index 5"):
        resample({"v": (t, np.zeros(t.size))}, ["v"], rate=10)


def test_hold_keeps_a_mode_channel_and_does_not_limit_the_span():
    t = np.arange(0, 20, 0.01)
    log = {
        "att.q": (t, np.sin(t)),
        "status.nav_state": ([0.0, 5.3, 12.1], [1.0, 14.0, 2.0]),  # logged on change
    }
    out = resample(log, ["att.q", "status.nav_state"], rate=50, method={"status.nav_state": "hold"})
    mode = out["status.nav_state"]
    assert out.time[-1] == pytest.approx(19.98)
    assert set(np.unique(mode)) == {1.0, 14.0, 2.0}
    assert np.all(mode[(out.time >= 5.3) & (out.time < 12.1)] == 14.0)
    assert np.all(mode[out.time < 5.3] == 1.0) and np.all(mode[out.time >= 12.1] == 2.0)
    assert out.metadata["resampling"]["channels"]["status.nav_state"]["method"] == "hold"


def test_flight_data_and_log_channels_are_accepted_in_place_of_a_log():
    t = np.arange(0, 4, 0.01)
    data = FlightData(t, {"a": np.sin(t)}, {"a": "deg"})
    out = resample(data, ["a"], rate=25)
    assert out.units["a"] == "deg" and out.n_samples == 100
    chan = LogChannel("a", t, np.cos(t), "rad")
    assert resample({"a": chan}, ["a"], rate=25).units["a"] == "rad"
    assert resample({"a": (t, np.cos(t), "V")}, "a", rate=25).units["a"] == "V"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rate": 0}, "rate: expected a positive number in Hz"),
        ({"rate": float("nan")}, "rate"),
        ({"rate": 10, "method": "spline"}, "method for 'a': expected one of"),
        ({"rate": 10, "method": {"b": "hold"}}, r"method: names \['b'\] are not among"),
        ({"rate": 10, "max_gap": -1.0}, "max_gap for 'a'"),
        ({"rate": 1000, "t0": 0.0, "t1": 0.0005}, "fewer than 2 samples"),
        ({"rate": 10, "t0": "start"}, "t0: expected a finite time in seconds, got 'start'"),
        ({"rate": 10, "t0": "1"}, "t0: expected a finite time in seconds, got '1'"),
        ({"rate": 10, "t1": float("nan")}, "t1: expected a finite time"),
    ],
)
def test_bad_options_are_named(kwargs, message):
    t = np.arange(0, 4, 0.01)
    with pytest.raises(DataFormatError, match=message):
        resample({"a": (t, t)}, ["a"], **kwargs)


def test_bad_channels_and_logs_are_named():
    t = np.arange(0, 4, 0.01)
    with pytest.raises(DataFormatError, match="no channel chosen"):
        resample({"a": (t, t)}, [], rate=10)
    with pytest.raises(DataFormatError, match="'a' is listed twice"):
        resample({"a": (t, t)}, ["a", "a"], rate=10)
    with pytest.raises(DataFormatError, match="log: expected a FlightLog"):
        resample([t, t], ["a"], rate=10)
    with pytest.raises(DataFormatError, match="channel 'a': time and values must be 1-D"):
        resample({"a": (t, t[:-1])}, ["a"], rate=10)
    with pytest.raises(DataFormatError, match="channel 'a': expected a LogChannel"):
        resample({"a": t}, ["a"], rate=10)
    with pytest.raises(DataFormatError, match="at least 2 distinct time stamps"):
        resample({"a": ([1.0, 1.0], [2.0, 3.0])}, ["a"], rate=10)
    with pytest.raises(DataFormatError, match="channel 'a': complex values are not supported"):
        resample({"a": (t, t + 1j)}, ["a"], rate=10)


def test_a_rate_beyond_any_sane_grid_is_refused_before_allocating():
    t = np.arange(0, 20, 0.01)
    with pytest.raises(DataFormatError, match=r"rate: 1e\+09 Hz .* makes 1.999e\+10 samples per"):
        resample({"a": (t, np.sin(t))}, ["a"], rate=1e9)
    with pytest.raises(DataFormatError, match=r"rate: 1e\+300 Hz"):
        resample({"a": (t, np.sin(t))}, ["a"], rate=1e300)


# -- numpy FIR design and convolution against scipy.signal ---------------------------------------


@pytest.mark.parametrize(
    ("source", "rate"), [(400, 50), (100, 50), (1000, 10), (250, 100), (50.3, 10)]
)
def test_anti_alias_design_matches_scipy_firwin(source: float, rate: float) -> None:
    import scipy.signal

    from aeroid.io.resampling import design_anti_alias

    nyq = rate / 2.0
    width = (nyq - 0.8 * nyq) / (source / 2.0)
    numtaps, beta = scipy.signal.kaiserord(80.0, width)
    numtaps = int(numtaps) | 1
    ref = scipy.signal.firwin(numtaps, 0.9 * nyq, window=("kaiser", beta), fs=source)
    taps, design = design_anti_alias(source, rate)
    assert design["taps"] == numtaps
    assert design["beta"] == pytest.approx(beta, rel=1e-15)
    assert np.abs(taps - ref).max() <= 1e-14


@pytest.mark.parametrize(
    ("n", "k"), [(10, 5), (100, 65), (259, 65), (260, 65), (5000, 64), (12345, 333)]
)
def test_fir_convolution_matches_numpy_and_scipy(n: int, k: int) -> None:
    import scipy.signal

    from aeroid.io._regrid import _convolve_valid

    rng = np.random.default_rng(n * k)
    x, h = rng.standard_normal(n), rng.standard_normal(k)
    got = _convolve_valid(x, h)
    scale = np.abs(h).sum() * np.abs(x).max()
    assert np.abs(got - np.convolve(x, h, "valid")).max() <= 1e-14 * scale
    assert np.abs(got - scipy.signal.oaconvolve(x, h, "valid")).max() <= 1e-14 * scale


def test_a_clock_that_jumps_back_is_refused_not_interleaved():
    # two stretches joined with the second starting 0.7 s before the first ends: sorting
    # would interleave them into a saw-tooth
    t = np.r_[np.arange(0, 5, 0.01), np.arange(4.3, 8, 0.01)]
    with pytest.raises(DataFormatError, match=r"'x': time steps back by 0\.69 s at sample 500"):
        resample({"x": (t, np.sin(t))}, ["x"], rate=50)
    # a single stale stamp re-sent late still sorts into place
    t1 = np.r_[np.arange(0, 5, 0.01), [1.005]]
    out = resample({"x": (t1, np.sin(t1))}, ["x"], rate=50)
    assert out.metadata["resampling"]["channels"]["x"]["reordered_stamps"] == 1


@pytest.mark.parametrize("source_rate", [60.0, 75.0, 51.0])
@pytest.mark.parametrize("freq", [10.0, 15.0, 19.0])
def test_near_rate_decimation_keeps_the_flat_band(source_rate: float, freq: float) -> None:
    # a four-point cubic on the filtered samples drooped at a few samples per
    # cycle: 60 -> 50 Hz kept 0.924 of a 15 Hz tone and 0.849 of a 19 Hz one
    t = np.arange(0.0, 30.0, 1.0 / source_rate)
    out = resample({"x": (t, np.sin(2 * np.pi * freq * t + 0.3))}, ["x"], rate=50, t0=0.0071)
    inner = _interior(out, "x")
    tt = out.time[inner]
    basis = np.column_stack([np.sin(2 * np.pi * freq * tt), np.cos(2 * np.pi * freq * tt)])
    (s, c), *_ = np.linalg.lstsq(basis, out["x"][inner], rcond=None)
    assert abs(np.hypot(s, c) - 1.0) < 1e-3
    assert abs(np.arctan2(c, s) - 0.3) < 1e-3  # no delay
    assert out.metadata["resampling"]["channels"]["x"]["interpolation"].startswith("band-limited")


def test_band_limited_evaluation_keeps_a_line_exactly_at_any_offset() -> None:
    t = np.arange(0.0, 20.0, 1.0 / 60.0)
    out = resample({"x": (t, 0.3 - 2.0 * t)}, ["x"], rate=50, t0=0.013)
    np.testing.assert_allclose(out["x"], 0.3 - 2.0 * out.time, atol=1e-11)


@pytest.mark.parametrize("source", [49.6, 50.0, 50.25, 50.5, 50.9])
def test_a_source_at_about_the_grids_rate_keeps_its_band(source):
    # found by an independent suite: from 50.25-50.5 Hz to 50 Hz the channel was
    # interpolated straight across (19 Hz kept 0.61 of its amplitude); stamps offset
    # from the grid's by 10 ms, a 10 Hz tone lost 0.18
    t = np.arange(0.0, 20.0, 1.0 / source) + 0.01
    for f in (5.0, 10.0, 19.0):
        out = resample({"x": (t, np.sin(2 * np.pi * f * t + 0.4))}, ["x"], rate=50.0, t0=1.0)
        inner = _interior(out, "x")
        g = out.time[inner]
        A = np.c_[np.sin(2 * np.pi * f * g + 0.4), np.cos(2 * np.pi * f * g + 0.4)]
        gain, quad = np.linalg.lstsq(A, out["x"][inner], rcond=None)[0]
        assert gain == pytest.approx(1.0, abs=1e-4) and abs(quad) < 1e-4
    # stamps that are the grid's points: copied
    same = np.arange(0.0, 10.0, 0.02)
    out = resample({"x": (same, np.sin(same))}, ["x"], rate=50.0)
    assert out.metadata["resampling"]["channels"]["x"]["method"] == "linear"
    np.testing.assert_allclose(out["x"], np.sin(same[: out.time.size]), atol=1e-12)
