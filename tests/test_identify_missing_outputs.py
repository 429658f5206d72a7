"""identify with default outputs names a model output the record lacks (finding
bb27_report 3: a CSV whose q column is headed Q fitted alpha alone, silently)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.estimation._excitation import warn_missing_outputs
from aeroid.models import aircraft, catalog

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]


def _renamed(tmp_path, header: str) -> aeroid.FlightData:
    """The README's flight written as CSV, its header rewritten."""
    path = tmp_path / "flight.csv"
    catalog.short_period_flight(seed=42).to_csv(path)
    text = path.read_text(encoding="utf-8")
    assert "time,elevator,alpha,q" in text
    path.write_text(text.replace("time,elevator,alpha,q", header), encoding="utf-8")
    return aeroid.load_flight_test(path)


def test_a_misnamed_output_column_is_named(tmp_path):
    data = _renamed(tmp_path, "time,elevator,alpha,Q")
    with pytest.warns(UserWarning) as caught:
        fit = aeroid.identify(catalog.short_period(), data, NAMES)
    said = [str(w.message) for w in caught]
    missing = [m for m in said if "not in the record" in m]
    assert missing == [
        "identify: model output 'q' not in the record (channels: Q, alpha, elevator); "
        "the record has 'Q', not 'q'; fitting alpha only (pass outputs= to choose the outputs)"
    ]
    assert fit.output_names == ("alpha",)
    assert "Outputs fitted: alpha." in fit.summary()


def test_outputs_chosen_or_all_present_say_nothing(tmp_path):
    data = _renamed(tmp_path, "time,elevator,alpha,Q")
    model = catalog.short_period()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = aeroid.identify(model, data, NAMES, outputs=["alpha"], max_iterations=200)
        full = aeroid.identify(model, catalog.short_period_flight(seed=42), NAMES)
    assert fit.output_names == ("alpha",)
    assert "Outputs fitted: alpha, q." in full.summary()


def test_many_channels_are_listed_briefly():
    t = np.linspace(0.0, 1.0, 11)
    channels = {f"c{k:02d}": np.zeros_like(t) for k in range(20)}
    data = aeroid.FlightData(time=t, channels={**channels, "alpha": t, "elevator": t})
    with pytest.warns(
        UserWarning,
        match=r"channels: alpha, c00, .*, c10, \.\.\. \(22 in all\)\); fitting alpha only",
    ):
        warn_missing_outputs(catalog.short_period(), [data], ["alpha"])


def test_an_aircraft_models_measurement_outputs_are_optional():
    """longitudinal's default outputs add q_dot, ax and az to its states: a record of
    the states alone is the normal case, a record without a state is not."""
    model = aircraft.longitudinal(
        aircraft.AircraftConstants(
            mass=1247.0, Ixx=1421.0, Iyy=4067.0, Izz=4786.0, S=17.09, b=10.18, cbar=1.74, rho=1.2
        ),
        V0=50.0,
    )
    assert {"q_dot", "ax", "az"} <= set(model.outputs)
    t = np.linspace(0.0, 1.0, 11)
    states = {n: np.zeros_like(t) for n in ("V", "alpha", "theta", "q")}
    data = aeroid.FlightData(time=t, channels=states)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_missing_outputs(model, [data], ["V", "alpha", "theta", "q"])
    del states["theta"]
    data = aeroid.FlightData(time=t, channels=states)
    with pytest.warns(UserWarning, match=r"model output 'theta' not in the record"):
        warn_missing_outputs(model, [data], ["V", "alpha", "q"])


def test_an_output_one_record_of_several_lacks_is_named(tmp_path):
    misnamed = _renamed(tmp_path, "time,elevator,alpha,Q")
    with pytest.warns(UserWarning, match=r"model output 'q' not in every record") as caught:
        aeroid.identify(
            catalog.short_period(),
            [catalog.short_period_flight(seed=1), misnamed],
            NAMES,
            max_iterations=5,
        )
    # pointed at the caller's line, not into the library
    assert any(w.filename == __file__ for w in caught if "not in every" in str(w.message))


def test_a_hole_in_the_stamps_is_named():
    # found by an independent suite: 30 samples dropped inside the doublet (rows with
    # NaN removed), identify flew across on straight-line controls, M_alpha 36 bars
    # off, success and no word
    model = catalog.short_period()
    flight = catalog.short_period_flight(seed=42)
    keep = np.ones(flight.n_samples, bool)
    keep[100:130] = False
    holed = aeroid.FlightData(flight.time[keep], {k: flight[k][keep] for k in flight.names})
    with pytest.warns(
        UserWarning,
        match=r"1 hole in its time stamps, the longest 0\.62 s at t = 1\.98 s \(31 median",
    ) as got:
        aeroid.identify(model, holed, ["M_alpha", "M_delta"])
    assert got[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an even grid, and a jittered one: no hole
        aeroid.identify(model, flight, ["M_alpha", "M_delta"])
        jitter = flight.time + np.random.default_rng(0).uniform(-0.004, 0.004, flight.n_samples)
        aeroid.identify(model, aeroid.FlightData(jitter, dict(flight.channels)), ["M_alpha"])
