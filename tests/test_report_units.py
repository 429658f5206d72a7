"""The units report() prints: declared first, a guess only where the record's units
make it right, and marked as a guess (findings bb27_report 1 and 2)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid._units import guessed_units, parameter_units
from aeroid.models import aircraft, catalog
from aeroid.pipeline.stages._campaign_tables import campaign_units, identification_brief

G = 9.80665
LONGITUDINAL_TRUTH = {
    "X_V": -0.03,
    "X_alpha": 5.0,
    "X_delta_e": 0.5,
    "Z_V": -0.004,
    "Z_alpha": -1.2,
    "Z_delta_e": -0.1,
    "M_V": 0.0,
    "M_alpha": -6.0,
    "M_q": -2.5,
    "M_delta_e": -9.0,
}
CONSTANTS = aircraft.AircraftConstants(
    mass=1247.0, Ixx=1421.0, Iyy=4067.0, Izz=4786.0, S=17.09, b=10.18, cbar=1.74, rho=1.225
)


def _short_period(t, x, u, p):
    alpha, q = x
    return np.array(
        [p["Z_alpha"] * alpha + q, p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0]]
    )


def _longitudinal(t, x, u, p):
    # Klein & Morelli's small-perturbation equations, as `longitudinal_linear` writes them
    V, alpha, theta, q = x
    return np.array(
        [
            p["X_V"] * V + p["X_alpha"] * alpha + p["X_delta_e"] * u[0] - G * (theta - alpha),
            q + p["Z_V"] * V + p["Z_alpha"] * alpha + p["Z_delta_e"] * u[0],
            q,
            p["M_V"] * V + p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta_e"] * u[0],
        ]
    )


def _unit_column(text: str) -> dict[str, str]:
    """The unit column of the report's estimates table, by parameter."""
    lines = text.splitlines()
    at = next(k for k, ln in enumerate(lines) if ln.startswith("| parameter | unit"))
    out = {}
    for ln in lines[at + 2 :]:
        if not ln.startswith("|"):
            break
        cells = [c.strip() for c in ln.strip("|").split("|")]
        out[cells[0]] = cells[1]
    return out


def _degree_record(alpha_unit: str, q_unit: str, elevator_unit: str) -> aeroid.FlightData:
    """The README's flight with its channels in the units given (deg or rad)."""
    d = catalog.short_period_flight(seed=42)
    scale = {"rad": 1.0, "rad/s": 1.0, "deg": 180.0 / np.pi, "deg/s": 180.0 / np.pi}
    units = {"alpha": alpha_unit, "q": q_unit, "elevator": elevator_unit}
    channels = {n: np.asarray(d.channels[n]) * scale[u] for n, u in units.items()}
    return aeroid.FlightData(time=d.time, channels=channels, units=units)


def test_a_guess_needs_radians_or_comes_from_the_record_units():
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta", "M_elevator"]
    radians = {"alpha": "rad", "q": "rad/s", "elevator": "rad"}
    assert guessed_units(names, radians) == {
        "Z_alpha": "1/s",
        "M_alpha": "1/s²",
        "M_q": "1/s",
        "M_delta": "1/s²",  # no channel 'delta': the radian table
        "M_elevator": "1/s²",
    }
    # alpha and q in degrees: a ratio of two degree channels is still 1/s or 1/s²,
    # the elevator's derivative is (deg/s²)/rad, and M_delta cannot be read
    mixed = {"alpha": "deg", "q": "deg/s", "elevator": "rad"}
    assert guessed_units(names, mixed) == {
        "Z_alpha": "1/s",
        "M_alpha": "1/s²",
        "M_q": "1/s",
        "M_elevator": "deg/(s² rad)",
    }
    assert guessed_units(["M_elevator"], {"q": "rad/s", "elevator": "deg"}) == {
        "M_elevator": "rad/(s² deg)"
    }
    # nothing known of the record, or a channel in a unit not read: no angle guesses
    assert guessed_units(names, None) == {}
    assert "M_delta" not in guessed_units(names, {**radians, "flap": "percent"})
    assert guessed_units(["CL_0", "tau_elevator"], None) == {"CL_0": "-", "tau_elevator": "s"}
    # declared units win over any guess
    assert parameter_units(["M_q"], {"M_q": "rad/s per rad/s"}, radians) == {
        "M_q": "rad/s per rad/s"
    }


@pytest.mark.parametrize(
    "build",
    [
        lambda: aircraft.longitudinal_linear(V0=50.0),
        lambda: aircraft.lateral_linear(V0=50.0),
        lambda: aircraft.longitudinal(CONSTANTS, V0=50.0),
        lambda: aircraft.lateral(CONSTANTS, V0=50.0),
        lambda: aircraft.six_dof(CONSTANTS, V0=50.0),
    ],
    ids=["longitudinal_linear", "lateral_linear", "longitudinal", "lateral", "six_dof"],
)
def test_every_guess_agrees_with_the_library_models(build):
    """Fitted by hand-written copies of the library's equations, on records in the
    models' own channel units, every parameter gets the unit the library declares
    (the old name table said 1/s for X_alpha, - for CL_alpha: m/s², 1/rad)."""
    model = build()
    declared = dict(model.parameter_units)
    assert declared and set(declared) == set(model.parameters)
    assert guessed_units(list(model.parameters), dict(model.channel_units)) == declared


def test_report_prints_no_unit_a_degree_record_makes_wrong():
    """alpha, q in deg, the elevator in rad: M_delta is (deg/s²)/rad, 57.3 times its
    value in 1/s², and the report used to label it 1/s²."""
    model = aeroid.Model(
        states=["alpha", "q"],
        controls=["elevator"],
        parameters={"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -300.0},
        dynamics=_short_period,
    )
    data = _degree_record("deg", "deg/s", "rad")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = aeroid.identify(model, data, list(model.parameters))
    assert dict(fit.units) == {"alpha": "deg", "q": "deg/s", "elevator": "rad"}
    # the number the unit is about: the radian fit's M_delta (-9.007) times 180/pi
    assert fit.parameters["M_delta"] == pytest.approx(-516.1, abs=0.1)
    for text in (
        aeroid.report(aeroid.validate(model, data, fit), fit),
        aeroid.report(identification=fit),
    ):
        units = _unit_column(text)
        assert units["M_delta"] == "—"
        assert units["M_alpha"] == "1/s² (guessed)" and units["Z_alpha"] == "1/s (guessed)"
        assert "A unit marked (guessed) is read from the parameter's name" in text
    # the elevator in deg, alpha and q in rad: rad/s² per deg, not 1/s² either
    data = _degree_record("rad", "rad/s", "deg")
    start = {**model.parameters, "M_delta": -0.15}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = aeroid.identify(model, data, start)
    assert fit.parameters["M_delta"] == pytest.approx(-0.1572, abs=1e-3)
    assert _unit_column(aeroid.report(identification=fit))["M_delta"] == "—"


def test_report_labels_a_hand_written_longitudinal_model_as_the_library_does():
    model = aeroid.Model(
        states=["V", "alpha", "theta", "q"],
        controls=["delta_e"],
        parameters=LONGITUDINAL_TRUTH,
        dynamics=_longitudinal,
    )
    t = np.linspace(0.0, 20.0, 1001)
    de = np.where((t > 1) & (t < 2), 0.02, 0.0) - np.where((t >= 2) & (t < 3), 0.02, 0.0)
    states = np.asarray(model.simulate(t, de[:, None]).states)
    rng = np.random.default_rng(1)
    channels = {
        n: states[:, i] + 1e-3 * rng.normal(size=t.size) for i, n in enumerate(model.states)
    }
    channels["delta_e"] = de
    units = {"V": "m/s", "alpha": "rad", "theta": "rad", "q": "rad/s", "delta_e": "rad"}
    data = aeroid.FlightData(time=t, channels=channels, units=units)
    names = ["X_alpha", "X_delta_e", "M_alpha", "M_delta_e"]
    fit = aeroid.identify(model, data, names)
    shown = _unit_column(aeroid.report(identification=fit))
    library = aircraft.longitudinal_linear(V0=50.0).parameter_units
    assert library["X_alpha"] == library["X_delta_e"] == "m/s²"
    assert shown == {n: f"{library[n]} (guessed)" for n in names}
    # the library's own model: declared, so not marked
    lib = aircraft.longitudinal_linear(V0=50.0, parameters=LONGITUDINAL_TRUTH)
    fit = aeroid.identify(lib, data, names)
    text = aeroid.report(identification=fit)
    assert _unit_column(text) == {n: library[n] for n in names}
    assert "(guessed)" not in text


def test_the_campaign_keeps_a_guess_only_where_the_flights_agree():
    fit = aeroid.identify(catalog.short_period(), catalog.short_period_flight(seed=3), ["M_q"])
    brief = identification_brief(fit)
    assert brief["units"] == {} and brief["guessed_units"] == {"M_q": "1/s"}
    other = {"units": {"L_p": "1/s"}, "guessed_units": {"M_q": "1/s", "M_alpha": "1/s²"}}
    assert campaign_units([brief, None, other]) == (
        {"L_p": "1/s", "M_q": "1/s", "M_alpha": "1/s²"},
        {"M_q", "M_alpha"},
    )
    # a flight in degrees that reads another unit: none is printed
    degrees = {"units": {}, "guessed_units": {"M_q": "rad/(s deg)"}}
    assert campaign_units([brief, degrees]) == ({}, set())


def test_a_unit_the_fit_declares_holds_for_the_inference_too():
    """The demo's flight with an inference of Cm_q, Cm_delta_e: the inference declares
    no units, and its name guess (the old table's '-') replaced the fit's 1/rad."""
    from types import SimpleNamespace

    from aeroid.reports.reporting import _report_units

    fit = SimpleNamespace(
        parameter_names=("Cm_q", "Cm_delta_e"),
        parameter_units={"Cm_q": "-", "Cm_delta_e": "1/rad"},
        units={"q": "rad/s", "delta_e": "rad"},
    )
    posterior = SimpleNamespace(parameter_names=("Cm_delta_e", "M_q"), parameter_units={})
    units, guessed = _report_units(None, fit, None, None, posterior)
    assert units == {
        "q": "rad/s",
        "delta_e": "rad",
        "Cm_q": "-",
        "Cm_delta_e": "1/rad",
        "M_q": "1/s",
    }
    assert guessed == {"M_q"}
