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
    assert check_data_quality(one)["a"].flags == ("too_few_samples",)


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
