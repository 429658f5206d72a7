"""The engine's gyroscopic moment in the aircraft models (issue 51: the c172x's propeller)."""

from __future__ import annotations

import math

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
    six_dof,
    trim,
)

V0 = 53.6
H = 3000.0  # kg m^2/s: a large propeller's angular momentum (Navion-like aircraft)


def _constants(h: float = H) -> AircraftConstants:
    return AircraftConstants(**BASE, Ixz=80.0, rho=1.225, engine_momentum=h)


def _parts(h: float = H, alpha0: float = 0.0) -> tuple[aeroid.Model, aeroid.Model]:
    gyro = h != 0.0
    lon = longitudinal(
        _constants(h),
        V0=V0,
        parameters=LONG,
        outputs=("V", "alpha", "theta", "q"),
        surfaces=("delta_e", "r") if gyro else ("delta_e",),
    )
    lat = lateral(
        _constants(h),
        V0=V0,
        alpha0=alpha0,
        theta0=alpha0,
        parameters=LAT,
        outputs=("beta", "p", "r", "phi"),
        surfaces=("delta_a", "delta_r", "q") if gyro else ("delta_a", "delta_r"),
    )
    return lon, lat


def test_the_gyroscopic_moment_is_minus_omega_cross_h():
    # Stevens & Lewis: M_gyro = -ω × (h, 0, 0) = (0, -h r, h q)
    c = _constants()
    lon, lat = _parts()
    p = {**lon.parameters, **lat.parameters}
    x = np.array([V0, 0.05, 0.05, 0.1])
    r = 0.2
    q_dot = [lon.dynamics(0.0, x, np.array([0.0, rate, 0.0]), p)[3] for rate in (0.0, r)]
    assert q_dot[1] - q_dot[0] == pytest.approx(-H * r / c.Iyy, rel=1e-12)
    xl = np.array([0.02, 0.1, -0.05, 0.1])
    q = 0.3
    rates = [lat.dynamics(0.0, xl, np.array([0.0, 0.0, rate]), p) for rate in (0.0, q)]
    gamma = c.Ixx * c.Izz - c.Ixz**2
    np.testing.assert_allclose(
        rates[1][1:3] - rates[0][1:3],
        [c.Ixz * H * q / gamma, c.Ixx * H * q / gamma],
        rtol=1e-12,
    )
    # the six-degree-of-freedom model carries the same two terms
    full = {**LONG, **LAT}
    with_h = six_dof(c, V0=V0, parameters=full)
    without = six_dof(_constants(0.0), V0=V0, parameters=full)
    x6 = np.array([V0, 1.0, 2.0, 0.1, q, r, 0.1, 0.05, 0.0])
    u6 = np.zeros(len(with_h.controls))
    diff = with_h.dynamics(0.0, x6, u6, full) - without.dynamics(0.0, x6, u6, full)
    i = list(with_h.states).index
    assert diff[i("q")] == pytest.approx(-H * r / c.Iyy, rel=1e-12)
    assert diff[i("r")] == pytest.approx(c.Ixx * H * q / gamma, rel=1e-12)
    assert diff[i("p")] == pytest.approx(c.Ixz * H * q / gamma, rel=1e-12)
    assert "hE" in with_h.equations and "hE" not in without.equations


def test_each_part_needs_the_other_axis_rate_and_decoupled_feeds_it():
    with pytest.raises(aeroid.ModelDefinitionError, match=r"engine_momentum.*'r'"):
        longitudinal(_constants(), V0=V0)
    with pytest.raises(aeroid.ModelDefinitionError, match="'q'"):
        lateral(_constants(), V0=V0)
    with pytest.raises(aeroid.ModelDefinitionError, match="engine_momentum"):
        AircraftConstants(**BASE, rho=1.225, engine_momentum=math.nan)
    both = decoupled(*_parts())
    # r and q are the parts' states, not controls of the stacked model
    assert both.controls == ("delta_e", "thrust", "delta_a", "delta_r")
    spec = {
        "aircraft": "decoupled",
        "longitudinal": {
            "aircraft": "longitudinal",
            "V0": V0,
            "constants": {**BASE, "rho": 1.225, "engine_momentum": H},
            "surfaces": ["delta_e", "r"],
        },
        "lateral": {
            "aircraft": "lateral",
            "V0": V0,
            "constants": {**BASE, "rho": 1.225, "engine_momentum": H},
            "surfaces": ["delta_a", "delta_r", "q"],
        },
    }
    assert model_from_config(spec).controls == both.controls


@pytest.mark.slow
def test_the_derivatives_are_recovered_with_the_term_and_biased_without(monkeypatch):
    # seeded recovery: an elevator 3-2-1-1 and aileron and rudder doublets flown by the
    # coupled model with a propeller's gyroscopic moment; output error with the term finds
    # the moment derivatives within three standard errors, without it the pitch rate's
    # yaw and the yaw rate's pitch go into the lateral damping and control terms
    monkeypatch.setattr(_compiled, "ENABLED", False)
    tr = trim(_parts(0.0)[0])  # wings level, r = 0: the same trim with the term
    alpha0 = float(tr.x0[1])
    truth = decoupled(*_parts(H, alpha0))
    t = np.arange(0.0, 14.0 + 1e-9, 0.05)
    U = coupled_inputs(tr.controls, t)
    x0 = np.concatenate([tr.x0, np.zeros(4)])
    sim = truth.simulate(t, U, x0, method="rk4")
    # the elevator alone yaws it through the propeller
    assert np.max(np.abs(sim.state("r")[t < 8.0])) > 0.03
    noise = {"V": 0.1, "alpha": 0.002, "theta": 0.002, "q": 0.005}
    noise.update(beta=0.002, p=0.005, r=0.005, phi=0.002)
    data = sim.to_flight_data(noise=noise, seed=11)
    names = ("Cm_alpha", "Cm_q", "Cm_delta_e", "Cl_beta", "Cl_p", "Cl_delta_a")
    names += ("Cn_beta", "Cn_r", "Cn_delta_r")
    values = {k: truth.parameters[k] for k in names}
    guess = {k: 0.8 * v for k, v in values.items()}
    res = aeroid.identify(truth, data, guess, x0=x0)
    for k, v in values.items():
        assert abs(res.parameters[k] - v) < 3 * res.stderr[k], (k, res.parameters[k], v)
    blind = aeroid.identify(decoupled(*_parts(0.0, alpha0)), data, guess, x0=x0)
    for k in ("Cl_p", "Cn_r"):
        assert abs(blind.parameters[k] / values[k] - 1.0) > 0.15, (k, blind.parameters[k])
        assert abs(res.parameters[k] / values[k] - 1.0) < 0.05, (k, res.parameters[k])
