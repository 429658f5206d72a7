"""A decoupled aircraft model whose lateral part takes the longitudinal alpha (issue 51)."""

from __future__ import annotations

import numpy as np
import pytest
from _aircraft_data import BASE, LAT, LONG, coupled_inputs

import aeroid
from aeroid.models import compiled as _compiled
from aeroid.models.aircraft import (
    AircraftConstants,
    decoupled,
    lateral,
    longitudinal,
    model_from_config,
    trim,
)

V0 = 53.6
# a Navion-like aircraft (Nelson's data) whose lift rolls and yaws it: the roll an
# off-centre centre of gravity 0.1 m out on a 10 m span gives, about CL_alpha / 100
CONSTANTS = AircraftConstants(**BASE, Ixz=80.0, rho=1.225)
ROLL_BY_LIFT = {"Cl_alpha": 0.045, "Cn_alpha": -0.012}
LAT_TERMS = {
    "CY": ("0", "beta", "p", "r", "delta_a", "delta_r"),
    "Cl": ("0", "beta", "p", "r", "delta_a", "delta_r", "alpha"),
    "Cn": ("0", "beta", "p", "r", "delta_a", "delta_r", "alpha"),
}


def _parts(alpha0: float = 0.0) -> tuple[aeroid.Model, aeroid.Model]:
    lon = longitudinal(CONSTANTS, V0=V0, parameters=LONG, outputs=("V", "alpha", "theta", "q"))
    values = {**LAT, **ROLL_BY_LIFT}
    # the constant terms hold the trim: the lift's roll at the trim alpha is trimmed out
    values.update(Cl_0=-values["Cl_alpha"] * alpha0, Cn_0=-values["Cn_alpha"] * alpha0)
    lat = lateral(
        CONSTANTS,
        V0=V0,
        alpha0=alpha0,
        theta0=alpha0,
        terms=LAT_TERMS,
        parameters=values,
        surfaces=("delta_a", "delta_r", "alpha"),
        outputs=("beta", "p", "r", "phi"),
    )
    return lon, lat


def test_a_lateral_input_named_after_a_longitudinal_state_is_fed_that_state():
    lon, lat = _parts()
    both = decoupled(lon, lat)
    # alpha is the longitudinal state, not a control of the stacked model
    assert both.controls == ("delta_e", "thrust", "delta_a", "delta_r")
    assert both.states == (*lon.states, *lat.states)
    assert "Cl_alpha" in both.parameters and "input alpha" in both.equations
    rng = np.random.default_rng(0)
    p = dict(both.parameters)
    n = len(lon.states)
    i_alpha = lon.states.index("alpha")
    for shape in ((), (5,)):
        x = rng.normal(size=(len(both.states), *shape))
        u = rng.normal(size=(len(both.controls), *shape))
        lat_u = np.stack([u[2], u[3], x[i_alpha]])
        expected = np.concatenate(
            [lon.dynamics(0.0, x[:n], u[:2], p), lat.dynamics(0.0, x[n:], lat_u, p)]
        )
        np.testing.assert_array_equal(both.dynamics(0.0, x, u, p), expected)
        np.testing.assert_array_equal(
            both.measurement(0.0, x, u, p),
            np.concatenate(
                [lon.measurement(0.0, x[:n], u[:2], p), lat.measurement(0.0, x[n:], lat_u, p)]
            ),
        )
    # an angle of attack alone rolls it
    assert lat.dynamics(0.0, np.zeros(4), np.array([0.0, 0.0, 0.1]), p)[1] != 0.0


def test_the_same_coupling_from_a_config_and_a_bad_name_is_refused():
    _, lat = _parts()
    spec = {
        "aircraft": "decoupled",
        "longitudinal": {"aircraft": "longitudinal", "V0": V0, "constants": {**BASE, "rho": 1.225}},
        "lateral": {
            "aircraft": "lateral",
            "V0": V0,
            "constants": {**BASE, "rho": 1.225},
            "surfaces": ["delta_a", "delta_r", "alpha"],
            "terms": {k: list(v) for k, v in LAT_TERMS.items()},
        },
    }
    both = model_from_config(spec)
    assert "alpha" not in both.controls and "Cn_alpha" in both.parameters
    # a lateral model alone takes alpha as a measured input (the textbooks' pseudo-control)
    assert "alpha" in lat.controls
    # an input named after a state of its own part is refused
    with pytest.raises(aeroid.ModelDefinitionError, match="beta"):
        lateral(CONSTANTS, V0=V0, surfaces=("delta_a", "beta"))


@pytest.mark.slow
def test_the_roll_by_lift_is_recovered_from_an_elevator_input(monkeypatch):
    # seeded recovery: an elevator 3-2-1-1 moves alpha, which rolls and yaws the
    # aircraft through Cl_alpha and Cn_alpha, with an aileron and a rudder doublet;
    # output error on the coupled model finds them within three standard errors
    monkeypatch.setattr(_compiled, "ENABLED", False)
    lon0, _ = _parts()
    tr = trim(lon0)
    alpha0 = float(tr.x0[lon0.states.index("alpha")])
    lon, lat = _parts(alpha0)
    both = decoupled(lon, lat)
    t = np.arange(0.0, 14.0 + 1e-9, 0.05)
    U = coupled_inputs(tr.controls, t)
    x0 = np.concatenate([tr.x0, np.zeros(4)])
    sim = both.simulate(t, U, x0, method="rk4")
    # the elevator alone rolls it: phi moves by degrees before the aileron doublet
    assert np.max(np.abs(sim.state("phi")[t < 8.0])) > np.radians(1.0)
    noise = {
        "V": 0.1,
        "alpha": 0.002,
        "theta": 0.002,
        "q": 0.005,
        "beta": 0.002,
        "p": 0.005,
        "r": 0.005,
        "phi": 0.002,
    }
    data = sim.to_flight_data(noise=noise, seed=11)
    names = ("Cl_beta", "Cl_p", "Cl_delta_a", "Cn_beta", "Cn_r", "Cn_delta_r", *ROLL_BY_LIFT)
    truth = {k: both.parameters[k] for k in names}
    guess = {k: 0.7 * v for k, v in truth.items()}
    guess.update(Cl_alpha=0.0, Cn_alpha=0.0)
    res = aeroid.identify(both, data, guess, x0=x0)
    for k, v in truth.items():
        assert abs(res.parameters[k] - v) < 3 * res.stderr[k], (k, res.parameters[k], res.stderr[k])
    for k in ROLL_BY_LIFT:
        assert res.stderr[k] < 0.2 * abs(truth[k]), (k, res.stderr[k])


def test_the_coupled_model_translates_to_jax():
    # the state fed as an input is picked row by row too, so the nonlinear filters'
    # compiled propagation is used for it
    pytest.importorskip("jax")
    lon, lat = _parts(0.05)
    both = decoupled(lon, lat)
    t = np.linspace(0.0, 2.0, 101)
    u = np.column_stack([np.full(t.size, 0.01 * k) for k in range(len(both.controls))])
    x0 = np.array([V0, 0.05, 0.05, 0.0, 0.01, 0.0, 0.0, 0.0])
    p = {k: 0.01 for k in both.parameters}
    assert _compiled.interval_propagator(both, t, u, x0, p, 1) is not None


@pytest.mark.slow
def test_the_drag_of_sideslip_is_recovered_through_the_fed_beta(monkeypatch):
    # the other way round: the longitudinal part takes the lateral beta, and a drag
    # term "beta*beta" (drag is even in the sideslip) slows the aircraft in a rudder
    # doublet, and pitches it (that drag acting above the centre of gravity); seeded
    # recovery of CD_beta_beta and Cm_beta_beta from the airspeed and the pitch within
    # three standard errors, on the Navion-like aircraft (not the demo's c172x)
    monkeypatch.setattr(_compiled, "ENABLED", False)
    drag = {"CD_beta_beta": 1.2, "Cm_beta_beta": 0.6}
    terms = {
        "CD": ("0", "alpha", "delta_e", "beta*beta"),
        "Cm": ("0", "alpha", "q", "delta_e", "beta*beta"),
    }
    lon0 = longitudinal(CONSTANTS, V0=V0, parameters=LONG, outputs=("V", "alpha", "theta", "q"))
    tr = trim(lon0)
    lon = longitudinal(
        CONSTANTS,
        V0=V0,
        terms=terms,
        parameters={**LONG, **drag},
        surfaces=("delta_e", "beta"),
        outputs=("V", "alpha", "theta", "q"),
    )
    lat = lateral(CONSTANTS, V0=V0, parameters=LAT, outputs=("beta", "p", "r", "phi"))
    both = decoupled(lon, lat)
    assert both.controls == ("delta_e", "thrust", "delta_a", "delta_r")
    assert "input beta" in both.equations
    t = np.arange(0.0, 12.0 + 1e-9, 0.05)
    dr = 0.05 * (((t >= 1.0) & (t < 2.5)) * 1.0 - ((t >= 2.5) & (t < 4.0)))
    dr += 0.05 * (((t >= 6.0) & (t < 7.5)) * 1.0 - ((t >= 7.5) & (t < 9.0)))
    U = np.column_stack(
        [
            np.full(t.size, tr.controls["delta_e"]),
            np.full(t.size, tr.controls["thrust"]),
            np.zeros(t.size),
            dr,
        ]
    )
    x0 = np.concatenate([tr.x0, np.zeros(4)])
    sim = both.simulate(t, U, x0, method="rk4")
    beta = sim.state("beta")
    assert 0.05 < np.max(np.abs(beta)) < 0.15
    # the sideslip alone slows it: without the term the airspeed would hold the trim's
    assert V0 - np.min(sim.state("V")) > 0.3
    noise = dict.fromkeys(("alpha", "theta", "beta", "phi"), 0.002)
    noise.update(V=0.05, q=0.005, p=0.005, r=0.005)
    data = sim.to_flight_data(noise=noise, seed=5)
    guess = {"CD_0": 0.02, "CD_alpha": 0.2, "CD_beta_beta": 0.0, "Cm_beta_beta": 0.0}
    guess.update(Cm_0=0.04, Cn_beta=0.05)
    res = aeroid.identify(both, data, guess, x0=x0)
    truth = {**LONG, **LAT, **drag}
    for k in guess:
        assert abs(res.parameters[k] - truth[k]) < 3 * res.stderr[k], (k, res.parameters[k])
    for k, v in drag.items():
        assert res.stderr[k] < 0.1 * v, (k, res.stderr[k])


def _flown(alpha0: float = 0.0, terms=LAT_TERMS) -> aeroid.Model:
    # the lateral part given the airspeed flown: V among its inputs
    return lateral(
        CONSTANTS,
        V0=V0,
        alpha0=alpha0,
        theta0=alpha0,
        terms=terms,
        parameters={**LAT, **ROLL_BY_LIFT},
        surfaces=("delta_a", "delta_r", "alpha", "V"),
        outputs=("beta", "p", "r", "phi", "ay"),
    )


def test_a_lateral_model_given_the_airspeed_flies_it():
    # closed forms: at V0 it is the trim speed's model; at 2 V0 a moment of a surface
    # grows with q̄ (x4), the damping q̄ b/2V (x2), the side force over m V (x2), the
    # gravity's g/V (x1/2)
    at_trim = lateral(
        CONSTANTS,
        V0=V0,
        terms=LAT_TERMS,
        parameters={**LAT, **ROLL_BY_LIFT},
        surfaces=("delta_a", "delta_r", "alpha"),
        outputs=("beta", "p", "r", "phi", "ay"),
    )
    flown = _flown()
    assert "V" in flown.equations and "V" in flown.controls
    rng = np.random.default_rng(3)
    x, u = rng.normal(size=(4, 7)) * 0.1, rng.normal(size=(3, 7)) * 0.1
    p = dict(flown.parameters)
    u_V0 = np.vstack([u, np.full(7, V0)])
    for f, g in ((flown.dynamics, at_trim.dynamics), (flown.measurement, at_trim.measurement)):
        np.testing.assert_allclose(f(0.0, x, u_V0, p), g(0.0, x, u, p), rtol=1e-13, atol=1e-15)

    def rates(**on: float) -> tuple[np.ndarray, np.ndarray]:
        values = dict.fromkeys(p, 0.0) | on
        state = np.array([0.02, 0.1, 0.0, 0.05 if "phi" in on else 0.0])
        ctrl = np.array([0.03, 0.0, 0.0, V0])
        one = flown.dynamics(0.0, state, ctrl, values)
        two = flown.dynamics(0.0, state, ctrl * np.array([1, 1, 1, 2.0]), values)
        return one, two

    one, two = rates(Cl_delta_a=0.1)
    assert two[1] == pytest.approx(4.0 * one[1], rel=1e-12)
    one, two = rates(Cl_p=-0.5)
    assert two[1] == pytest.approx(2.0 * one[1], rel=1e-12)
    one, two = rates(CY_beta=-0.6)
    assert two[0] == pytest.approx(2.0 * one[0], rel=1e-12)
    one, two = rates(phi=1.0)  # no coefficient: the beta equation's gravity alone
    assert two[0] == pytest.approx(0.5 * one[0], rel=1e-12) and one[0] != 0.0


def test_decoupled_feeds_the_longitudinal_airspeed_and_trims():
    lon, _ = _parts()
    lat = _flown()
    both = decoupled(lon, lat)
    assert "V" not in both.controls and "input V" in both.equations
    n = len(lon.states)
    rng = np.random.default_rng(5)
    x = rng.normal(size=(len(both.states), 4)) * 0.1
    x[lon.states.index("V")] = V0 + rng.normal(size=4)
    u = rng.normal(size=(len(both.controls), 4)) * 0.1
    p = dict(both.parameters)
    lat_u = np.stack([u[2], u[3], x[lon.states.index("alpha")], x[lon.states.index("V")]])
    np.testing.assert_array_equal(
        both.dynamics(0.0, x, u, p)[n:], lat.dynamics(0.0, x[n:], lat_u, p)
    )
    # alone, it trims at its V0 unless told the airspeed
    tr = trim(lat)
    assert tr.controls["V"] == V0
    assert all(abs(tr.derivatives[s]) < 1e-9 for s in ("beta", "p", "r"))
    with pytest.raises(aeroid.ModelDefinitionError, match="V0"):
        trim(lat, V=V0 + 1.0)


def test_the_airspeed_fed_model_translates_to_jax():
    pytest.importorskip("jax")
    lon, _ = _parts(0.05)
    both = decoupled(lon, _flown(0.05))
    t = np.linspace(0.0, 2.0, 101)
    u = np.column_stack([np.full(t.size, 0.01 * k) for k in range(len(both.controls))])
    x0 = np.array([V0, 0.05, 0.05, 0.0, 0.01, 0.0, 0.0, 0.0])
    p = {k: 0.01 for k in both.parameters}
    assert _compiled.interval_propagator(both, t, u, x0, p, 1) is not None
