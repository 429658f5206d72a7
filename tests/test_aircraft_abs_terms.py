"""Terms in |x| in the aircraft models' expansions (``"abs(beta)"``, issue 51)."""

from __future__ import annotations

import numpy as np
import pytest
from _aircraft_data import BASE, LAT, LONG

import aeroid
from aeroid.errors import ModelDefinitionError
from aeroid.models import compiled as _compiled
from aeroid.models.aircraft import AircraftConstants, lateral, longitudinal, six_dof, trim

V0 = 53.6
CONSTANTS = AircraftConstants(**BASE, rho=1.225)
# drag V-shaped in the sideslip (a fuselage's, CD = k |beta|), acting above the cg
V_DRAG = {"CD_abs_beta": 0.3, "Cm_abs_beta": 0.15}
TERMS = {
    "CD": ("0", "alpha", "delta_e", "abs(beta)"),
    "Cm": ("0", "alpha", "q", "delta_e", "abs(beta)"),
}


def _model(**parameters: float) -> aeroid.Model:
    return longitudinal(
        CONSTANTS,
        V0=V0,
        terms=TERMS,
        parameters={**LONG, **parameters},
        surfaces=("delta_e", "beta"),
        outputs=("V", "alpha", "theta", "q"),
    )


def test_names_units_and_equations_of_absolute_terms() -> None:
    m = longitudinal(
        CONSTANTS,
        V0=V0,
        terms={"CD": ("0", "abs(beta)", "abs(beta)*alpha", " abs( beta ) * delta_e")},
        surfaces=("delta_e", "beta"),
    )
    assert [n for n in m.parameters if n.startswith("CD")] == [
        "CD_0",
        "CD_abs_beta",
        "CD_abs_beta_alpha",
        "CD_abs_beta_delta_e",
    ]
    assert m.parameter_units["CD_abs_beta"] == "1/rad"
    assert m.parameter_units["CD_abs_beta_alpha"] == "1/rad²"
    assert "CD_abs_beta |β| + CD_abs_beta_alpha |β| α" in m.equations
    # a rate's absolute value is as dimensionless as the rate
    lat = lateral(CONSTANTS, V0=V0, alpha0=0.05, theta0=0.05, terms={"Cn": ("0", "abs(p)")})
    assert lat.parameter_units["Cn_abs_p"] == "1/rad"
    assert "Cn_abs_p |p b/(2V0)|" in lat.equations
    six = six_dof(CONSTANTS, V0=V0, terms={"CY": ("0", "beta", "abs(beta)")})
    assert "CY_abs_beta" in six.parameters


@pytest.mark.parametrize(
    ("term", "match"),
    [
        ("abs(", r"'abs\(' is not the absolute value of a regressor"),
        ("abs(foo)", r"'abs\(foo\)' is not the absolute value"),
        ("abs(beta", r"'abs\(beta' is not the absolute value"),
        ("abs(abs(beta))", r"'abs\(abs\(beta\)\)'"),
        ("alpha*abs()", r"'alpha\*abs\(\)': 'abs\(\)'"),
        ("absbeta", r"'absbeta' uses \['absbeta'\]"),
    ],
)
def test_a_bad_absolute_term_is_refused_by_name(term: str, match: str) -> None:
    with pytest.raises(ModelDefinitionError, match=r"terms\['CD'\]: " + match):
        longitudinal(CONSTANTS, V0=V0, terms={"CD": ("0", term)}, surfaces=("delta_e", "beta"))


def test_alpha_dot_and_abs_named_surfaces_are_refused() -> None:
    with pytest.raises(ModelDefinitionError, match="absolute value of alpha_dot"):
        longitudinal(CONSTANTS, V0=V0, terms={"Cm": ("0", "abs(alpha_dot)")})
    # a surface abs_beta would name its term as abs(beta) names CD_abs_beta
    with pytest.raises(ModelDefinitionError, match="surfaces: 'abs_beta'"):
        longitudinal(CONSTANTS, V0=V0, surfaces=("delta_e", "abs_beta"))


def test_the_absolute_term_is_even_and_linear_in_its_parameter() -> None:
    m = _model(**V_DRAG)
    p = dict(m.parameters)
    x = np.array([V0, 0.05, 0.05, 0.0])
    f = [m.dynamics(0.0, x, np.array([0.0, b, 1000.0]), p) for b in (-0.1, 0.0, 0.1)]
    np.testing.assert_array_equal(f[0], f[2])
    # V-dot: the drag's closed form, q S CD_abs_beta |beta| / m slower than at beta = 0
    qS = 0.5 * 1.225 * V0**2 * BASE["S"]
    assert f[0][0] - f[1][0] == pytest.approx(-qS * 0.3 * 0.1 / BASE["mass"], rel=1e-12)
    # and its pitch, q S c Cm_abs_beta |beta| / Iyy
    assert f[0][3] - f[1][3] == pytest.approx(qS * BASE["cbar"] * 0.15 * 0.1 / BASE["Iyy"])


def test_jax_differentiates_the_absolute_value_as_its_sign() -> None:
    from aeroid.models._jax_translation import _translate
    from aeroid.models.jax_compiled import require_jax

    try:
        jax, jnp = require_jax()
    except aeroid.errors.AdapterError:
        pytest.skip("jax is not installed")
    m = _model(**V_DRAG)
    p = dict(m.parameters)
    f = _translate(m.dynamics, jnp)
    x = jnp.array([V0, 0.05, 0.05, 0.0])
    qS = 0.5 * 1.225 * V0**2 * BASE["S"]
    rates = jax.jit(lambda u: f(0.0, x, u, p))
    slopes = jax.jit(jax.jacfwd(lambda u: f(0.0, x, u, p)))
    for beta in (-0.1, -1e-9, 0.0, 1e-9, 0.1):
        u = jnp.array([0.0, beta, 1000.0])
        np.testing.assert_allclose(
            np.asarray(rates(u)), m.dynamics(0.0, np.asarray(x), np.asarray(u), p), rtol=1e-12
        )
        dv = float(slopes(u)[0, 1])
        # d|beta|/dbeta = sign(beta), zero at zero as a central difference says
        assert dv == pytest.approx(-qS * 0.3 * np.sign(beta) / BASE["mass"], rel=1e-12, abs=0.0)


def _rudder_sideslip(t: np.ndarray) -> np.ndarray:
    """A rudder doublet's sideslip, both signs, fed to the longitudinal part."""
    beta = 0.08 * np.sin(2 * np.pi * 0.4 * (t - 4.0)) * ((t >= 4.0) & (t < 9.0))
    return beta - 0.06 * np.sin(2 * np.pi * 0.3 * (t - 12.0)) * ((t >= 12.0) & (t < 16.0))


@pytest.mark.parametrize("seed", [3, 11])
def test_a_v_shaped_sideslip_drag_is_recovered(monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    # seeded recovery, on the Navion-like aircraft's longitudinal model flown through a
    # sideslip of both signs (given as an input) and an elevator 3-2-1-1: CD_abs_beta and
    # Cm_abs_beta within three standard errors of the truth (each a 0.3 % miss at
    # this many samples), from the airspeed and the pitch
    monkeypatch.setattr(_compiled, "ENABLED", False)
    tr = trim(longitudinal(CONSTANTS, V0=V0, parameters=LONG))
    m = _model(**V_DRAG)
    t = np.arange(0.0, 18.0 + 1e-9, 0.05)
    de = np.full(t.size, tr.controls["delta_e"])
    for start, end, sign in ((1, 4, 1), (4, 6, -1), (6, 7, 1), (7, 8, -1)):
        de[(t >= 0.5 + start * 0.4) & (t < 0.5 + end * 0.4)] += 0.03 * sign
    U = np.column_stack([de, _rudder_sideslip(t), np.full(t.size, tr.controls["thrust"])])
    sim = m.simulate(t, U, tr.x0, method="rk4")
    assert V0 - np.min(sim.state("V")) > 0.3  # the sideslip alone slows it
    noise = {"V": 0.05, "alpha": 0.002, "theta": 0.002, "q": 0.005}
    data = sim.to_flight_data(noise=noise, seed=seed)
    guess = {"CD_0": 0.02, "CD_alpha": 0.2, "Cm_0": 0.04, "Cm_alpha": -0.6}
    guess.update(CD_abs_beta=0.0, Cm_abs_beta=0.0, Cm_q=-8.0, Cm_delta_e=-0.8)
    res = aeroid.identify(m, data, guess, x0=tr.x0, start="equation_error")
    truth = {**LONG, **V_DRAG}
    for k in guess:
        assert abs(res.parameters[k] - truth[k]) < 3 * res.stderr[k], (k, res.parameters[k])
    for k, v in V_DRAG.items():
        assert res.stderr[k] < 0.1 * v, (k, res.stderr[k])


def test_lateral_terms_take_absolute_values_too() -> None:
    lat = lateral(
        CONSTANTS,
        V0=V0,
        alpha0=0.0,
        theta0=0.0,
        terms={"Cn": ("0", "beta", "p", "r", "delta_a", "delta_r", "abs(beta)")},
        parameters={**LAT, "Cn_abs_beta": 0.01},
    )
    odd = lateral(CONSTANTS, V0=V0, alpha0=0.0, theta0=0.0, parameters=LAT)
    x = np.array([0.05, 0.0, 0.0, 0.0])
    u = np.zeros(2)
    # the |beta| term's yaw acceleration, q S b Cn_abs_beta |beta| / Izz, at either sign
    added = [
        lat.dynamics(0.0, s * x, u, dict(lat.parameters))
        - odd.dynamics(0.0, s * x, u, dict(odd.parameters))
        for s in (1.0, -1.0)
    ]
    qSb = 0.5 * 1.225 * V0**2 * BASE["S"] * BASE["b"]
    expected = np.array([0.0, 0.0, qSb * 0.01 * 0.05 / BASE["Izz"], 0.0])
    for a in added:
        np.testing.assert_allclose(a, expected, rtol=1e-9, atol=1e-15)
