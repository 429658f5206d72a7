"""A record's clock and declared units: what a flight computer's epoch time (1.7e9 s,
whose last digit is 2.4e-7 s) or a unit in the file must not change."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _compat_flight import simulated_flight

import aeroid
from aeroid.models import catalog

EPOCH = 1.7e9


def _on_clock(d: aeroid.FlightData, t0: float) -> aeroid.FlightData:
    return aeroid.FlightData(d.time + t0, dict(d.channels), dict(d.units), {})


def test_a_delay_fit_on_an_epoch_clock():
    """The delayed control is shifted from the record's start: at 1.7e9 s the fit
    returned its starting guess with success=True (t - tau rounded the derivative's
    step away); now it is the fit at t0 = 0."""
    d = catalog.short_period_flight(seed=7)
    m = catalog.short_period(catalog.SHORT_PERIOD_GUESS)
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    kw = {"time_delays": {"elevator": 0.02}, "estimate_bias": True}
    a = aeroid.identify(m, d, names, **kw)
    b = aeroid.identify(m, _on_clock(d, EPOCH), names, **kw)
    for k, v in a.parameters.items():
        assert b.parameters[k] == pytest.approx(v, abs=1e-4 * a.stderr[k]), k
        assert b.stderr[k] == pytest.approx(a.stderr[k], rel=1e-3), k


def test_frequency_domain_regression_takes_an_epoch_clock():
    """The uniform-grid test is FlightData's (1 % of a step): the same record on an
    epoch clock was refused as not uniformly sampled."""
    d = catalog.short_period_flight(seed=7)
    freq = np.arange(0.1, 2.0, 0.05)
    kw = {"domain": "frequency", "frequencies": freq}
    a = aeroid.equation_error(d, "q", ["alpha", "elevator"], **kw)
    b = aeroid.equation_error(_on_clock(d, EPOCH), "q", ["alpha", "elevator"], **kw)
    for k, v in a.parameters.items():
        assert b.parameters[k] == pytest.approx(v, rel=1e-5, abs=1e-8), k


def test_compatibility_refuses_rates_declared_in_degrees():
    d = simulated_flight(10.0, 50.0, errors={}, seed=4)
    q_deg = np.degrees(d.channels["q"])
    dd = aeroid.FlightData(d.time, {**d.channels, "q": q_deg}, {"q": "deg/s"}, {})
    with pytest.raises(aeroid.DataFormatError, match=r"'q' \(q\): declared in 'deg/s'"):
        aeroid.check_compatibility(dd)
    ax_g = d.channels["ax"] / 9.80665
    dg = aeroid.FlightData(d.time, {**d.channels, "ax": ax_g}, {"ax": "g"}, {})
    with pytest.raises(aeroid.DataFormatError, match=r"'ax' \(ax\): declared in 'g'"):
        aeroid.check_compatibility(dg)


def test_a_csv_time_column_declared_in_milliseconds(tmp_path: Path):
    t = np.arange(0.0, 2000.0, 20.0)
    path = tmp_path / "ms.csv"
    lines = ["# units: " + json.dumps({"time": "ms", "q": "rad/s"}), "time,q"]
    lines += [f"{a},{np.sin(a / 1000.0)}" for a in t]
    path.write_text("\n".join(lines) + "\n")
    d = aeroid.load_flight_test(path)
    np.testing.assert_allclose(d.time, t / 1000.0)
    assert d.sample_rate == pytest.approx(50.0)
    bad = tmp_path / "bad.csv"
    bad.write_text("# units: " + json.dumps({"time": "deg"}) + "\ntime,q\n1,2\n2,3\n3,4\n")
    with pytest.raises(aeroid.DataFormatError, match="not a unit of time"):
        aeroid.load_flight_test(bad)


@pytest.mark.filterwarnings("ignore::aeroid.IdentifiabilityWarning")
def test_a_held_out_window_is_named_to_the_millisecond():
    """``:g`` printed the last quarter of a 10-s record at 1e6 s as [1.00001e+06,
    1.00001e+06]."""
    d = catalog.short_period_flight(seed=7)
    assert d.duration == pytest.approx(10.0)
    m = catalog.short_period(catalog.SHORT_PERIOD_GUESS)
    late = _on_clock(d, 1e6)
    fit = aeroid.identify(m, late, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
    v = aeroid.validate(m, late, fit, holdout={"fraction": 0.25})
    assert v.prediction.source == "window [1000007.5, 1000010] s"
