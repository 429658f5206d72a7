"""check_data_quality: each fault injected into a clean synthetic channel is found, and
clean data raises no flag."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid import (
    ChannelError,
    DataFormatError,
    DataQualityReport,
    FlightData,
    FlightLog,
    LogChannel,
    check_data_quality,
)

FS = 100.0
N = 4000


def _clean(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """40 s at 100 Hz of a slow manoeuvre with a little sensor noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    x = np.sin(2 * np.pi * 0.5 * t) + 0.3 * np.sin(2 * np.pi * 2.0 * t)
    return t, x + 0.01 * rng.standard_normal(N)


def _log(**channels: tuple[np.ndarray, np.ndarray]) -> FlightLog:
    return FlightLog({n: LogChannel(n, t, v) for n, (t, v) in channels.items()}, (), {})


def test_clean_data_flags_nothing():
    t, x = _clean()
    data = FlightData(t, {"q": x, "r": _clean(1)[1]})
    report = check_data_quality(data)
    assert isinstance(report, DataQualityReport)
    assert report.ok and report.flagged == () and report.flags["q"] == ()
    q = report["q"]
    assert q.rate == pytest.approx(FS) and q.jitter < 1e-9
    assert (q.duplicates, q.non_increasing, q.dropouts, q.saturation) == (0, 0, 0, 0.0)
    assert q.longest_gap == pytest.approx(1 / FS)
    assert q.alias_fraction < 1e-3
    assert "no flags" in report.summary()


def test_jitter_is_std_over_median_of_steps():
    rng = np.random.default_rng(3)
    sigma = 0.2
    steps = (1 + sigma * rng.standard_normal(N - 1)).clip(0.3, 1.7) / FS
    t = np.concatenate([[0.0], np.cumsum(steps)])
    report = check_data_quality(_log(x=(t, _clean()[1])))
    c = report["x"]
    # the sample std of N steps is within a few sigma / sqrt(2N) of sigma
    assert c.jitter == pytest.approx(sigma, abs=5 * sigma / math.sqrt(2 * N))
    assert c.flags == ("jitter",)
    assert check_data_quality(_log(x=(t, _clean()[1])), jitter_limit=0.3).ok


def test_duplicated_and_backward_stamps_are_counted():
    t, x = _clean()
    t = t.copy()
    t[[100, 500, 900]] = t[[99, 499, 899]]  # three repeated stamps
    t[[2000, 2001]] = t[[2001, 2000]]  # two stamps swapped: one step goes backwards
    report = check_data_quality(_log(x=(t, x)))
    c = report["x"]
    assert c.duplicates == 3
    assert c.non_increasing == int(np.count_nonzero(np.diff(t) < 0)) == 1
    assert set(c.flags) == {"duplicate_stamps", "non_increasing_stamps"}
    assert c.rate == pytest.approx(FS)


def test_dropouts_and_longest_gap():
    t, x = _clean()
    keep = np.ones(N, dtype=bool)
    keep[1000:1050] = False  # 0.5 s lost
    keep[3000:3002] = False  # 3 steps long: not above 3 x the median step
    keep[3500:3503] = False  # 4 steps long: a dropout
    report = check_data_quality(_log(x=(t[keep], x[keep])))
    c = report["x"]
    assert c.dropouts == 2
    assert c.longest_gap == pytest.approx(0.51)
    # the two dropouts are left out of the jitter; the 3-step gap is not
    steps = np.diff(t[keep])
    regular = steps[steps < 0.035]
    assert regular.size == steps.size - 2
    assert c.jitter == pytest.approx(np.std(regular) / 0.01, rel=1e-9)
    assert c.flags == ("dropouts",)


def test_saturation_share_matches_the_clipped_samples():
    t = np.arange(N) / FS
    raw = 1.5 * np.sin(2 * np.pi * 0.5 * t)
    clipped = raw.clip(-1.0, 1.0)
    report = check_data_quality(FlightData(t, {"elevator": clipped}))
    c = report["elevator"]
    # every clipped stretch is ~36 samples long, far above the 5-sample run
    assert c.saturation == np.mean(np.abs(raw) >= 1.0)
    # the continuous-time share: 1 - (2/pi) asin(1/1.5)
    assert c.saturation == pytest.approx(1 - 2 / np.pi * np.arcsin(1 / 1.5), abs=2 / FS)
    assert c.flags == ("saturation",)
    # a single sample at each extreme is not saturation
    assert check_data_quality(FlightData(t, {"x": raw})).ok


def test_aliasing_is_energy_near_nyquist():
    t, x = _clean()
    # a 53 Hz vibration sampled at 100 Hz folds to 47 Hz, inside the top 10 % (45-50 Hz)
    folded = x + np.sin(2 * np.pi * 53.0 * t)
    report = check_data_quality(FlightData(t, {"clean": x, "folded": folded}))
    assert report["clean"].flags == ()
    c = report["folded"]
    # the tone has power 1/2 of the total 1/2 + (1 + 0.09)/2
    assert c.alias_fraction == pytest.approx(0.5 / (0.5 + 1.09 / 2), abs=0.02)
    assert c.flags == ("aliasing",)
    assert report.flagged == ("folded",) and not report.ok
    table = report.summary()
    assert "| folded |" in table and "- aliasing:" in table


def test_white_noise_puts_the_band_share_near_nyquist():
    rng = np.random.default_rng(7)
    t = np.arange(N) / FS
    c = check_data_quality(FlightData(t, {"n": rng.standard_normal(N)}))["n"]
    # Welch segments of 256 samples: the top 10 % holds 13 of 128 non-DC bins
    assert c.alias_fraction == pytest.approx(13 / 128, abs=0.02)
    assert c.flags == ()


def test_log_channels_are_checked_on_their_own_stamps():
    pytest.importorskip("pyulog")
    log = aeroid.read_log(Path(__file__).parent / "data" / "px4" / "sample_log_small.ulg")
    names = ["vehicle_angular_velocity.xyz[0]", "vehicle_status.nav_state"]
    report = check_data_quality(log, channels=names)
    gyro = report["vehicle_angular_velocity.xyz[0]"]
    assert (
        150 < gyro.rate < 1000
        and gyro.n_samples == log["vehicle_angular_velocity.xyz[0]"].time.size
    )
    assert "constant" in report["vehicle_status.nav_state"].flags  # MANUAL throughout
    assert report.source == "sample_log_small.ulg"


def test_bad_input_is_refused_clearly():
    t, x = _clean()
    data = FlightData(t, {"x": x})
    with pytest.raises(DataFormatError, match="expected a FlightData or a FlightLog"):
        check_data_quality({"x": x})  # type: ignore[arg-type]
    with pytest.raises(ChannelError, match="'y' not found"):
        check_data_quality(data, channels=["y"])
    with pytest.raises(DataFormatError, match="dropout_factor"):
        check_data_quality(data, dropout_factor=0.5)
    with pytest.raises(DataFormatError, match="saturation_run"):
        check_data_quality(data, saturation_run=2.5)
    one = _log(a=(np.array([1.0]), np.array([2.0])))
    assert check_data_quality(one, channels=["a"])["a"].flags == ("too_few_samples",)
    # in a whole log, a topic logged once is what it is, not a defect
    assert check_data_quality(one)["a"].notes == ("one_sample",)


def test_a_doublet_from_trim_is_not_saturation_but_a_clipped_one_is():
    t = np.arange(N) / FS
    # trim, then a doublet of +-1 for 2 s each, then trim: plateaus everywhere
    doublet = np.where((t >= 5) & (t < 7), 1.0, 0.0) - np.where((t >= 7) & (t < 9), 1.0, 0.0)
    c = check_data_quality(FlightData(t, {"elevator": 0.1 + doublet}))["elevator"]
    assert c.saturation == pytest.approx(400 / N)  # the share at the extremes is reported
    assert "saturation" not in c.flags
    # a smooth input clipped at its limits has no plateau elsewhere: flagged
    raw = 1.5 * np.sin(2 * np.pi * 0.5 * t) + 0.01 * np.random.default_rng(1).standard_normal(N)
    assert "saturation" in check_data_quality(FlightData(t, {"x": raw.clip(-1, 1)}))["x"].flags


# -- a whole log, judged as a log ------------------------------------------------------


def _px4_stamps(rate: float, duration: float, rng: np.random.Generator) -> np.ndarray:
    """Stamps as PX4's logger writes a fast topic: on the publisher's own period, with a
    sample overwritten before the logger's loop came round now and then (a step of two
    periods), and the stream starting 0.15 s after the first sample it subscribed to."""
    n = int(duration * rate)
    missed = rng.random(n) < 0.3
    missed[1:] &= ~missed[:-1]  # the logger's loop is faster than two periods
    t = np.flatnonzero(~missed) / rate
    return np.concatenate([[t[0] - 0.15], t]) + 10.0


def _planted_log(seed: int = 0) -> FlightLog:
    """A log of five topics with one defect planted per channel (see the test)."""
    rng = np.random.default_rng(seed)
    chans: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    t = _px4_stamps(400.0, 20.0, rng)
    wave = np.sin(2 * np.pi * 0.7 * t)
    noisy = wave + 0.01 * rng.standard_normal(t.size)
    chans["imu.p"] = (t, noisy)  # clean, on PX4-like stamps
    q = wave + 0.01 * rng.standard_normal(t.size)
    q[t.size // 2] = np.nan
    chans["imu.q"] = (t, q)  # one NaN mid-flight
    r = wave + 0.01 * rng.standard_normal(t.size)
    mid = int(np.searchsorted(t, 18.0))
    r[mid : mid + 60] = r[mid]  # stuck for 60 samples (~0.2 s) mid-flight
    chans["imu.r"] = (t, r)
    chans["imu.device_id"] = (t, np.full(t.size, 4242.0))  # an id: constant by design
    chans["imu.temperature"] = (t, np.full(t.size, np.nan))  # never set
    ta = 10.0 + np.arange(1000) / 50.0
    ta = np.delete(ta, np.s_[500:525])  # half a second lost mid-flight
    chans["air.v"] = (ta, 20 + np.sin(ta) + 0.01 * rng.standard_normal(ta.size))
    ts = 10.0 + np.arange(2000) / 100.0
    chans["servo.aileron"] = (ts, (1.5 * np.sin(2 * np.pi * 0.5 * ts)).clip(-1, 1))  # clipped
    chans["servo.armed"] = (ts, (ts > 12.0).astype(float))  # a boolean at its two states
    tc = 10.0 + np.cumsum((1 + 0.3 * rng.standard_normal(2000)).clip(0.55, 1.45)) / 100.0
    chans["clock.x"] = (tc, np.sin(tc) + 0.01 * rng.standard_normal(tc.size))  # wandering clock
    # an estimator on a 200 Hz IMU: two or three IMU periods a step (1 or 1.5 median steps)
    te = 10.0 + np.cumsum(rng.choice([2, 3], size=1500, p=[0.7, 0.3])) / 200.0
    chans["ekf.x"] = (te, np.cos(te) + 0.01 * rng.standard_normal(te.size))
    chans["mission.id"] = (np.array([3.0]), np.array([7.0]))  # logged once
    return _log(**chans)


def test_a_whole_log_finds_each_planted_defect_and_notes_the_rest():
    log = _planted_log()
    report = check_data_quality(log)
    assert report.whole_log
    expected = {
        "imu.p": (),
        "imu.q": ("non_finite",),
        "imu.r": ("frozen",),
        "imu.device_id": (),
        "imu.temperature": (),
        "air.v": ("dropouts",),
        "servo.aileron": ("saturation",),
        "servo.armed": (),
        "clock.x": ("jitter",),
        "ekf.x": (),
        "mission.id": (),
    }
    assert dict(report.flags) == expected
    assert report["imu.q"].non_finite == 1
    assert report["imu.r"].frozen == pytest.approx(59 / 400, rel=0.5)  # 59 steps of 1-2 periods
    assert dict(report.notes) == {
        "constant": ("imu.device_id",),
        "never_set": ("imu.temperature",),
        "one_sample": ("mission.id",),
    }
    # PX4's logging (steps of one or two periods, the stream starting late) is no defect
    assert report["imu.p"].jitter > 0.3 and report["imu.p"].off_period < 0.01
    assert report["ekf.x"].jitter > 0.2 and report["ekf.x"].off_period < 1e-9
    assert report["imu.p"].dropouts == 1  # the start-up hole, counted but not flagged
    # ranked: values lost or stuck first, then holes, clipping, timing
    assert [f for f, _ in report.ranked] == [
        "non_finite",
        "frozen",
        "dropouts",
        "saturation",
        "jitter",
    ]
    text = report.summary()
    assert text.index("1. non_finite: 1 — imu (1)") < text.index("5. jitter: 1 — clock (1)")
    assert "- constant: 1 channels in 1 topics" in text and "| imu.p |" not in text
    # the same channels chosen one by one keep the per-channel rules
    chosen = check_data_quality(log, channels=list(log.channels))
    assert not chosen.whole_log
    assert chosen["imu.device_id"].flags == ("jitter", "dropouts", "constant")
    assert "jitter" in chosen["imu.p"].flags and "saturation" in chosen["servo.armed"].flags
    assert "jitter" in chosen["ekf.x"].flags
    assert chosen["mission.id"].flags == ("too_few_samples",)
    # ... and count the NaN of a chosen channel as the whole log does, flagged there too
    for name, count in (("imu.q", 1), ("imu.temperature", log["imu.temperature"].time.size)):
        assert chosen[name].non_finite == report[name].non_finite == count
        assert chosen[name].flags[0] == "non_finite"
    assert report["imu.temperature"].flags == ()  # never set: a whole log's note


def test_a_chosen_log_channel_half_nan_is_counted_and_not_ok():
    t = np.arange(0, 20, 0.01)
    x = np.where(t > 10, np.nan, np.sin(2 * np.pi * 0.5 * t))
    log = _log(**{"imu.q": (t, x), "imu.p": (t, np.sin(t))})
    chosen = check_data_quality(log, channels=["imu.q"])
    assert chosen["imu.q"].non_finite == 999 and "non_finite" in chosen["imu.q"].flags
    assert not chosen.ok
    assert check_data_quality(log, channels=["imu.p"]).ok


@pytest.mark.parametrize("seed", range(5))
def test_frozen_needs_a_run_its_own_repeats_do_not_explain(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    noisy = np.sin(t) + 0.01 * rng.standard_normal(N)
    # a quantised signal repeats its neighbours often: long runs are its shape
    quantised = np.round(np.sin(0.2 * t) * 20)
    stepped = 0.1 + np.where((t > 5) & (t < 7), 1.0, 0.0) - np.where((t > 7) & (t < 9), 1.0, 0.0)
    report = check_data_quality(_log(noisy=(t, noisy), q=(t, quantised), s=(t, stepped)))
    assert report.ok, report.flags
    stuck = noisy.copy()
    stuck[2000:2006] = stuck[2000]  # six samples: 1e-3 chance needs n p^5 < 1e-3, p = 0
    assert check_data_quality(_log(x=(t, stuck)))["x"].flags == ("frozen",)


def test_the_shipped_px4_log_before_and_after():
    pytest.importorskip("pyulog")
    log = aeroid.read_log(Path(__file__).parent / "data" / "px4" / "sample_log_small.ulg")
    before = check_data_quality(log, channels=list(log.channels))  # the per-channel rules
    assert len(before.channels) == 1162 and len(before.flagged) == 1003
    # 26 of them for their NaN alone (37 channels hold NaN: PX4's unset fields)
    nan_only = [n for n, c in before.channels.items() if c.flags == ("non_finite",)]
    assert len(nan_only) == 26
    assert sum(c.non_finite > 0 for c in before.channels.values()) == 37
    after = check_data_quality(log)
    assert len(after.flagged) < 100  # 76: clipping, timing of 3 topics, frozen, a hole
    notes = after.notes
    assert (len(notes["constant"]), len(notes["one_sample"]), len(notes["never_set"])) == (
        624,
        145,
        37,
    )
    flags = {f for f, _ in after.ranked}
    assert not flags & {"constant", "too_few_samples"}
    # the 400 Hz gyro, logged at one or two publication periods, is not jitter, nor the
    # 100 Hz estimator stepping two or three periods of its 200 Hz IMU
    for name in ("vehicle_angular_velocity.xyz[0]", "estimator_status.states[0]"):
        assert after[name].flags == () and after[name].jitter > 0.1
        assert after[name].off_period < 0.05
    # the one hole inside a stream: ekf_gps_drift, 1.2 s
    assert set(dict(after.ranked)["dropouts"]) == {
        n for n in log.channels if n.startswith("ekf_gps_drift.")
    }
    # PX4 leaves unset fields NaN: noted, not flagged
    assert "battery_status.temperature" in notes["never_set"]


@pytest.mark.parametrize("sigma", [0.15, 0.3, 1.0])
def test_a_wandering_clock_fits_no_period_of_a_whole_log(sigma):
    # stamps scattered about a uniform grid by sigma steps fit none of the periods
    # (median / k, k = 1..4): the steps scatter by sigma sqrt(2) median steps, k sigma
    # sqrt(2) periods, wrapped to at most about 0.29 (uniform over a period)
    rng = np.random.default_rng(11)
    t = (np.arange(3000) + sigma * rng.standard_normal(3000)) / 100.0
    t.sort()
    c = check_data_quality(_log(x=(t, np.sin(t))))["x"]
    assert "jitter" in c.flags and c.off_period > 0.12


def test_quality_options_of_the_wrong_kind_are_named():
    t = np.arange(200) * 0.01
    data = aeroid.FlightData(t, {"x": np.sin(t)})
    with pytest.raises(aeroid.ChannelError, match="channels: expected channel names, got 5"):
        aeroid.check_data_quality(data, channels=5)
    with pytest.raises(aeroid.DataFormatError, match=r"dropout_factor: expected a number in \(1"):
        aeroid.check_data_quality(data, dropout_factor=1.0)  # "> 1": a regular step is no gap
    with pytest.raises(aeroid.DataFormatError, match="jitter_limit"):
        aeroid.check_data_quality(data, jitter_limit="0.1")
