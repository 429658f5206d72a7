"""Summaries print an undefined value (NaN) as "—", never as the number ``nan``."""

from __future__ import annotations

import math

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog


def _nan_cells(text: str) -> list[str]:
    return [line for line in text.splitlines() if "nan" in line.replace("|", " ").split()]


def test_bandwidth_without_omega_180_prints_undefined_rows():
    # θ/δe of the README truth: the phase tends to −180° and never crosses it, so the
    # gain bandwidth, ω_180 and τ_p are undefined; the phase bandwidth is 4.199 rad/s
    b = aeroid.bandwidth(([-9.0, -10.8], [1.0, 3.7, 9.0, 0.0]), kind="attitude")
    assert math.isnan(b.omega_180) and math.isnan(b.bandwidth_gain)
    assert math.isnan(b.phase_delay)
    assert b.bandwidth_phase == pytest.approx(4.199, abs=5e-4)
    text = b.summary()
    assert _nan_cells(text) == []
    cells = {
        ln.split("|")[1].strip(): ln.split("|")[2].strip()
        for ln in text.splitlines()
        if ln.startswith("| ")
    }
    assert cells["gain bandwidth (6 dB margin) [rad/s]"] == "—"
    assert cells["ω_180 [rad/s]"] == "—" and cells["phase delay τ_p [s]"] == "—"
    assert cells["phase bandwidth (45° margin) [rad/s]"] == "4.199"


def test_fmt_prints_nan_as_a_dash_and_keeps_infinity():
    from aeroid._records import fmt, fmt_fixed

    assert fmt(float("nan")) == "—" and fmt(None) == "—"  # type: ignore[arg-type]
    assert fmt(np.float64("nan"), 3) == "—"
    assert fmt(float("inf")) == "inf" and fmt(-np.inf) == "-inf"  # an unbounded bar
    assert fmt(1234.5678) == "1235" and fmt(0.012345, 3) == "0.0123"
    assert fmt_fixed(float("nan"), 1) == "—" and fmt_fixed(75.94, 1) == "75.9"


def test_validation_of_a_constant_output_prints_fit_undefined():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=1)
    result = aeroid.identify(model, data, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
    channels = dict(data.channels)
    channels["q"] = np.zeros(data.time.size)  # a dead gyro: the fit % has no denominator
    dead = aeroid.FlightData(data.time, channels, data.units)
    validation = aeroid.validate(model, dead, result)
    assert math.isnan(validation.metrics["q"].fit)
    text = validation.summary()
    assert _nan_cells(text) == []
    (q_row,) = [ln for ln in text.splitlines() if ln.startswith("| q ")]
    assert q_row.split("|")[4].strip() == "—"
    report = aeroid.report(validation)
    assert _nan_cells(report) == []
    assert "q: fit undefined (the output is constant)" in report


def test_quality_of_a_constant_channel_prints_alias_share_undefined():
    t = np.linspace(0.0, 10.0, 501)
    quality = aeroid.check_data_quality(aeroid.FlightData(t, {"c": np.zeros_like(t)}))
    assert math.isnan(quality.channels["c"].alias_fraction)
    text = quality.summary()
    assert _nan_cells(text) == []
    (row,) = [ln for ln in text.splitlines() if ln.startswith("| c ")]
    assert row.split("|")[10].strip() == "—"
