"""Standard aircraft models (`aeroid.models.aircraft`) against textbook closed forms."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest
from _aircraft_data import BASE, LAT, LONG

import aeroid
from aeroid import ModelDefinitionError, SimulationError
from aeroid.models import compiled as _compiled
from aeroid.models.aircraft import (
    AircraftConstants,
    AircraftModel,
    isa_density,
    lateral,
    lateral_linear,
    linearize,
    longitudinal,
    longitudinal_linear,
    six_dof,
    trim,
)

G = 9.80665
V0 = 53.6
# The Navion-like aircraft of _aircraft_data, with a product of inertia added.
CONSTANTS = AircraftConstants(**BASE, Ixz=80.0, rho=1.225)
LAT_TERMS = {k: ("beta", "p", "r", "delta_a", "delta_r") for k in ("CY", "Cl", "Cn")}
QBAR = 0.5 * 1.225 * V0**2


def constants(**changes: object) -> AircraftConstants:
    kw: dict[str, object] = {**BASE, "Ixz": 80.0, "rho": 1.225}
    kw.update(changes)
    return AircraftConstants(**kw)


def long_model(c: AircraftConstants = CONSTANTS, **kw: object) -> AircraftModel:
    return longitudinal(c, V0=V0, parameters=LONG, **kw)


def six_model(c: AircraftConstants = CONSTANTS, **kw: object) -> AircraftModel:
    return six_dof(c, V0=V0, parameters={**LONG, **LAT}, **kw)


# -- constants -------------------------------------------------------------------------------


def test_isa_density_matches_the_standard_table():
    # ICAO standard atmosphere: sea level, 5 km, tropopause, 20 km
    assert isa_density(0.0) == pytest.approx(1.225, rel=1e-4)
    assert isa_density(5000.0) == pytest.approx(0.73612, rel=1e-4)
    assert isa_density(11000.0) == pytest.approx(0.36392, rel=1e-4)
    assert isa_density(20000.0) == pytest.approx(0.088035, rel=1e-4)
    assert constants(rho=None, altitude=5000.0).density() == isa_density(5000.0)
    assert constants(rho=1.1, altitude=5000.0).density() == 1.1


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"mass": 0.0}, "mass"),
        ({"Iyy": -1.0}, "Iyy"),
        ({"S": float("nan")}, "S"),
        ({"cbar": "wide"}, "cbar"),
        ({"Ixz": 1500.0}, "Ixz"),  # Ixx Izz < Ixz²: not positive definite
        ({"Izz": 7000.0}, "triangle"),  # Izz > Ixx + Iyy: no rigid body
        ({"Ixz": 1500.0, "b": float("nan")}, "Ixz"),  # checked without the span too
        ({"mass": True}, "mass"),  # float() read a flag as 1 kg
        ({"Iyy": "3000"}, "Iyy"),  # and text as a number
        ({"Izz": 7000.0, "b": float("nan")}, "triangle"),
        ({"rho": None}, "rho"),
        ({"rho": -1.0}, "rho"),
        ({"rho": None, "altitude": 30000.0}, "altitude"),
        ({"accel_position": (1.0, 2.0)}, "accel_position"),
        ({"beta_vane_position": (1.0, float("inf"), 0.0)}, "beta_vane_position"),
        ({"thrust_offset": float("nan")}, "thrust_offset"),
    ],
)
def test_constants_reject_bad_values_naming_the_field(change, field):
    with pytest.raises(ModelDefinitionError, match=field):
        constants(**change)


def test_constants_are_exported_and_frozen():
    assert aeroid.AircraftConstants is AircraftConstants
    with pytest.raises(AttributeError):
        CONSTANTS.mass = 2.0


# -- model construction -----------------------------------------------------------------------


def test_models_are_genuine_models_with_chosen_terms_and_equations():
    m = longitudinal(
        CONSTANTS,
        V0=V0,
        terms={"CL": ["0", "alpha", "alpha*delta_e"], "Cm": ["alpha", "V", "q"]},
    )
    assert isinstance(m, aeroid.Model)
    assert m.parameter_names == (
        "CD_0",
        "CD_alpha",
        "CD_delta_e",
        "CL_0",
        "CL_alpha",
        "CL_alpha_delta_e",
        "Cm_alpha",
        "Cm_V",
        "Cm_q",
    )
    text = m.summary()
    for piece in ("q̇ = (q̄ S c̄ Cm + T dT)/Iyy", "CL_alpha_delta_e α delta_e", "Cm_q q c̄/(2V)"):
        assert piece in text
    assert "Ixx ṗ - Ixz ṙ = q̄ S b Cl + (Iyy - Izz) q r + Ixz p q" in six_model().summary()
    assert "Cn_delta_r delta_r" in lateral(CONSTANTS, V0=V0).summary()
    assert "q̇ = ΣM" in longitudinal_linear(V0=V0).summary()


def test_content_changes_the_version_so_cached_results_are_not_reused():
    a, b = long_model(), long_model(constants(mass=1300.0))
    assert a.dynamics_source == b.dynamics_source
    assert a.version != b.version
    assert long_model().version == a.version


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"terms": {"CL": ["alpha", "beta"]}}, "beta"),
        ({"terms": {"CQ": ["alpha"]}}, "CQ"),
        ({"terms": {"CL": ["alpha", "alpha"]}}, "twice"),
        ({"parameters": {"Cn_r": 1.0}}, "Cn_r"),
        ({"outputs": ["ay"]}, "ay"),
        ({"outputs": ["h"]}, "h"),
        ({"accel_units": "ft/s2"}, "accel_units"),
        ({"V0": 0.0}, "V0"),
        ({"surfaces": ["alpha"]}, "alpha"),
    ],
)
def test_bad_model_definitions_are_named(kwargs, match):
    kw = {"V0": V0, **kwargs}
    with pytest.raises(ModelDefinitionError, match=match):
        longitudinal(CONSTANTS, **kw)


def test_dynamics_broadcast_over_parameter_batches():
    m = six_model()
    tr = trim(m)
    batch = {"Cm_q": np.array([-9.0, -10.0, -11.0])}
    t = np.linspace(0.0, 1.0, 11)
    U = np.tile(tr.u0, (t.size, 1))
    res = m.simulate_batch(t, U, tr.x0 + 0.01, batch, method="rk4")
    assert m._dynamics_batch.broadcasts and m._measurement_batch.broadcasts
    for i, cmq in enumerate(batch["Cm_q"]):
        one = m.simulate(t, U, tr.x0 + 0.01, {"Cm_q": cmq}, method="rk4")
        np.testing.assert_allclose(res.outputs[i], one.outputs, rtol=1e-12, atol=1e-12)


# -- trim ---------------------------------------------------------------------------------------


def test_longitudinal_trim_zeroes_the_derivatives_and_balances_forces():
    c = constants(thrust_angle=0.04, thrust_offset=-0.2)
    m = long_model(c)
    tr = trim(m, 60.0, gamma=0.05)
    assert tr.trimmed == ("V", "alpha", "q")
    for k in ("V", "alpha", "theta", "q"):
        assert abs(tr.derivatives[k]) < 1e-10
    alpha, de, T = tr.states["alpha"], tr.controls["delta_e"], tr.controls["thrust"]
    assert tr.states["theta"] == pytest.approx(alpha + 0.05, abs=1e-14)
    qS = 0.5 * 1.225 * 60.0**2 * c.S
    CL = LONG["CL_0"] + LONG["CL_alpha"] * alpha + LONG["CL_delta_e"] * de
    CD = LONG["CD_0"] + LONG["CD_alpha"] * alpha + LONG["CD_delta_e"] * de
    Cm = LONG["Cm_0"] + LONG["Cm_alpha"] * alpha + LONG["Cm_delta_e"] * de
    W = c.mass * G
    # forces along and normal to the flight path, moments about the c.g.
    assert T * math.cos(alpha + 0.04) - qS * CD - W * math.sin(0.05) == pytest.approx(0, abs=1e-7)
    assert qS * CL + T * math.sin(alpha + 0.04) - W * math.cos(0.05) == pytest.approx(0, abs=1e-7)
    assert qS * c.cbar * Cm - 0.2 * T == pytest.approx(0, abs=1e-7)


def test_trim_and_linearize_name_bad_solver_options():
    """Found by an independent suite: a fractional max_iterations raised a bare TypeError,
    a negative tolerance blamed the model ("no trim"), a thrust the trim solves for was
    dropped in silence, and linearize(step="x") raised numpy's UFuncTypeError."""
    from aeroid.models.aircraft import decoupled, lateral

    m = long_model()
    for options, match in (
        ({"max_iterations": 1.5}, "max_iterations"),
        ({"max_iterations": 0}, "max_iterations"),
        ({"tolerance": -1.0}, "tolerance"),
        ({"tolerance": float("nan")}, "tolerance"),
        ({"controls": {"thrust": 1e5}}, r"solves for \['thrust'\]"),
    ):
        with pytest.raises(ModelDefinitionError, match=match):
            trim(m, 60.0, **options)
    tr = trim(m, 60.0)
    for bad in ("x", 0.0, float("nan"), 2.0):
        with pytest.raises(ModelDefinitionError, match="step"):
            linearize(m, tr, step=bad)
    both = decoupled(m, lateral(CONSTANTS, V0=60.0))
    with pytest.raises(ModelDefinitionError, match="'decoupled' aircraft model is not trimmed"):
        trim(both)


def test_channel_units_follow_the_constants_unit_system():
    """With g = 32.174 the models compute in feet and seconds; the labels (which validate
    and the plots print) said m/s², m/s and N."""
    from aeroid.models.aircraft import lateral_linear, longitudinal_linear

    us = longitudinal_linear(V0=176.0, g=32.174, outputs=["V", "az"])
    assert us.channel_units["az"] == "ft/s²" and us.channel_units["V"] == "ft/s"
    assert lateral_linear(V0=176.0, g=32.174, outputs=["ay"]).channel_units["ay"] == "ft/s²"
    si = longitudinal_linear(V0=50.0, outputs=["V", "az"])
    assert si.channel_units["az"] == "m/s²" and si.channel_units["V"] == "m/s"
    assert long_model(constants(g=32.174)).channel_units["V"] == "ft/s"
    in_g = longitudinal_linear(V0=176.0, g=32.174, outputs=["az"], accel_units="g")
    assert in_g.channel_units["az"] == "g"


def test_glide_trim_without_thrust_is_the_lift_to_drag_angle():
    m = longitudinal(CONSTANTS, V0=V0, parameters=LONG, thrust=False)
    tr = trim(m)
    alpha, de = tr.states["alpha"], tr.controls["delta_e"]
    CL = LONG["CL_0"] + LONG["CL_alpha"] * alpha + LONG["CL_delta_e"] * de
    CD = LONG["CD_0"] + LONG["CD_alpha"] * alpha + LONG["CD_delta_e"] * de
    assert tr.unknowns["gamma"] == pytest.approx(-math.atan(CD / CL), rel=1e-9)


def test_six_dof_trim_equals_the_longitudinal_trim():
    t6, tl = trim(six_model()), trim(long_model())
    for k in ("u", "v", "w", "p", "q", "r"):
        assert abs(t6.derivatives[k]) < 1e-10
    assert t6.outputs["alpha"] == pytest.approx(tl.states["alpha"], abs=1e-10)
    assert t6.outputs["V"] == pytest.approx(V0, rel=1e-12)
    assert t6.controls["delta_e"] == pytest.approx(tl.controls["delta_e"], abs=1e-10)
    assert t6.controls["thrust"] == pytest.approx(tl.controls["thrust"], rel=1e-10)
    assert abs(t6.states["v"]) < 1e-10 and abs(t6.controls["delta_r"]) < 1e-10


def test_lateral_trim_with_asymmetric_constants_solves_the_linear_balance():
    terms = {k: ("0", "beta", "p", "r", "delta_a", "delta_r") for k in ("CY", "Cl", "Cn")}
    consts = {"CY_0": 0.01, "Cl_0": -0.004, "Cn_0": 0.003}
    m = lateral(CONSTANTS, V0=V0, terms=terms, parameters={**LAT, **consts})
    tr = trim(m)
    for k in ("beta", "p", "r", "phi"):
        assert abs(tr.derivatives[k]) < 1e-10
    # wings level, no rates: CY = Cl = Cn = 0, linear in (β, δa, δr)
    M = np.array(
        [[LAT[f"{c}_{v}"] for v in ("beta", "delta_a", "delta_r")] for c in ("CY", "Cl", "Cn")]
    )
    want = np.linalg.solve(M, -np.array([consts["CY_0"], consts["Cl_0"], consts["Cn_0"]]))
    got = [tr.states["beta"], tr.controls["delta_a"], tr.controls["delta_r"]]
    np.testing.assert_allclose(got, want, rtol=1e-8)


def test_linear_models_trim_at_zero_and_impossible_trims_fail_clearly():
    tr = trim(longitudinal_linear(V0=V0, parameters={"M_alpha": -5.0, "M_delta_e": -8.0}))
    assert np.all(tr.x0 == 0.0) and abs(tr.controls["delta_e"]) < 1e-12
    no_elevator = dict(LONG, CL_delta_e=0.0, Cm_delta_e=0.0, Cm_alpha=0.0, Cm_0=0.1)
    with pytest.raises(SimulationError, match="trim"):
        trim(longitudinal(CONSTANTS, V0=V0, parameters=no_elevator))
    with pytest.raises(ModelDefinitionError, match="V0"):
        trim(lateral(CONSTANTS, V0=V0), 40.0)


def test_a_root_of_the_trim_equations_outside_the_envelope_is_no_trim():
    """Found by an independent suite: at 5 m/s a Navion-like model (linear lift, CL = 46
    needed) "trimmed" at alpha = 680 deg with the elevator at -503 deg, success; with no
    lift but the elevator's, at thrust -8699 N. The equations are periodic in the angles
    and linear in the surfaces, so such roots exist where no flight condition does."""
    c = aeroid.AircraftConstants(mass=1247.4, Iyy=4067.5, S=17.09, cbar=1.737, rho=1.225)
    navion = {"CD_0": 0.05, "CD_alpha": 0.33, "CL_0": 0.41, "CL_alpha": 4.44}
    navion |= {"CL_delta_e": 0.355, "Cm_alpha": -0.683, "Cm_q": -14.3, "Cm_delta_e": -0.923}
    m = longitudinal(c, V0=53.6, parameters=navion)
    # the lift at 20 m/s: alpha below stall on this model's line, a trim
    tr = trim(m, V=20.0)
    qS = 0.5 * 1.225 * 20.0**2 * 17.09
    lift = qS * (0.41 + 4.44 * tr.states["alpha"] + 0.355 * tr.controls["delta_e"])
    assert abs(tr.states["alpha"]) < 0.5 * math.pi
    assert lift + tr.controls["thrust"] * math.sin(tr.states["alpha"]) == pytest.approx(
        1247.4 * 9.80665, rel=1e-8
    )
    with pytest.raises(SimulationError, match=r"alpha = 680\.5 deg.*no flight condition"):
        trim(m, V=5.0)
    with pytest.warns(UserWarning, match="needs thrust -8699 "):
        trim(m, parameters={"CL_0": 0.0, "CL_alpha": 0.0})


# -- modes of the linearised models ------------------------------------------------------------


def _residualised(A: np.ndarray, slow: list[int]) -> np.ndarray:
    """The slow block with the fast states in quasi-steady state (singular perturbation)."""
    fast = [i for i in range(A.shape[0]) if i not in slow]
    Aff = A[np.ix_(fast, fast)]
    return A[np.ix_(slow, slow)] - A[np.ix_(slow, fast)] @ np.linalg.solve(
        Aff, A[np.ix_(fast, slow)]
    )


def test_longitudinal_derivatives_have_their_closed_forms():
    m = long_model()
    tr = trim(m)
    lin = linearize(m, tr)
    alpha0, T = tr.states["alpha"], tr.controls["thrust"]
    c = CONSTANTS
    qS = QBAR * c.S
    assert lin.derivative("q", "alpha") == pytest.approx(
        qS * c.cbar * LONG["Cm_alpha"] / c.Iyy, rel=1e-7
    )
    M_q = qS * c.cbar**2 * LONG["Cm_q"] / (2 * V0 * c.Iyy)
    assert lin.derivative("q", "q") == pytest.approx(M_q, rel=1e-7)
    Z_alpha = -(qS * LONG["CL_alpha"] + T * math.cos(alpha0)) / (c.mass * V0)
    assert lin.derivative("alpha", "alpha") == pytest.approx(Z_alpha, rel=1e-7)
    Z_q = -qS * LONG["CL_q"] * c.cbar / (2 * V0 * c.mass * V0)
    assert lin.derivative("alpha", "q") == pytest.approx(1.0 + Z_q, rel=1e-7)
    assert lin.derivative("V", "theta") == pytest.approx(-G, rel=1e-7)
    assert lin.derivative("q", "delta_e") == pytest.approx(
        qS * c.cbar * LONG["Cm_delta_e"] / c.Iyy, rel=1e-7
    )


def test_short_period_and_phugoid_against_the_classical_approximations():
    # a stiff pitch (large |Cm_alpha|, small |Cm_q|): Lanchester's assumptions hold
    stiff = dict(LONG, Cm_alpha=-3.0, Cm_q=-2.0)
    for params, lanchester_tol in ((LONG, None), (stiff, 0.04)):
        m = longitudinal(CONSTANTS, V0=V0, parameters=params)
        lin = linearize(m, trim(m))
        A = lin.A
        ev = lin.eigenvalues
        sp, ph = ev[np.argmax(np.abs(ev))], ev[np.argmin(np.abs(ev))]
        # short period: the 2x2 (α, q) approximation; its error is of order
        # (ω_ph/ω_sp)² plus the speed coupling, well under 2 % here
        sp2 = np.linalg.eigvals(A[np.ix_([1, 3], [1, 3])])[0]
        assert abs(sp2) == pytest.approx(abs(sp), rel=0.02)
        assert -sp2.real / abs(sp2) == pytest.approx(-sp.real / abs(sp), rel=0.02)
        # phugoid: ω² = -g Z_V M_α / (M_α - Z_α M_q), Lanchester's -g Z_V = 2 g²/V²
        # corrected for the quasi-steady pitch response (α follows q through M_q)
        Z_V, Z_a, M_a, M_q = A[1, 0], A[1, 1], A[3, 1], A[3, 3]
        w_ph = math.sqrt(-G * Z_V * M_a / (M_a - Z_a * M_q))
        assert abs(ph) == pytest.approx(w_ph, rel=0.02)
        assert -G * Z_V == pytest.approx(2 * G**2 / V0**2, rel=0.05)
        if lanchester_tol is not None:
            # the neglected term Z_α M_q / M_α is 2 % of M_α here
            assert abs(ph) == pytest.approx(math.sqrt(2) * G / V0, rel=lanchester_tol)


def test_lateral_modes_against_the_classical_approximations():
    # stability axes (α0 = θ0 = 0), where the textbook approximations are written
    m = lateral(CONSTANTS, V0=V0, terms=LAT_TERMS, parameters=LAT)
    lin = linearize(m, trim(m))
    A = lin.A
    ev = lin.eigenvalues
    Y_b, g_V = A[0, 0], A[0, 3]
    L_b, L_p, L_r = A[1, 0], A[1, 1], A[1, 2]
    N_b, N_p, N_r = A[2, 0], A[2, 1], A[2, 2]
    assert g_V == pytest.approx(G / V0, rel=1e-7)
    # the primed derivatives: Ixx ṗ - Ixz ṙ = L, Izz ṙ - Ixz ṗ = N solved for ṗ, ṙ
    c = CONSTANTS
    gamma = c.Ixx * c.Izz - c.Ixz**2
    for j, v in ((0, "beta"), (1, "p"), (2, "r")):
        scale = QBAR * c.S * c.b * (1.0 if v == "beta" else c.b / (2 * V0))
        L, N = scale * LAT[f"Cl_{v}"], scale * LAT[f"Cn_{v}"]
        assert A[1, j] == pytest.approx((c.Izz * L + c.Ixz * N) / gamma, rel=1e-7)
        assert A[2, j] == pytest.approx((c.Ixz * L + c.Ixx * N) / gamma, rel=1e-7)
    assert Y_b == pytest.approx(QBAR * c.S * LAT["CY_beta"] / (c.mass * V0), rel=1e-7)
    real = np.sort(ev[np.abs(ev.imag) < 1e-12].real)
    roll, spiral = real[0], real[-1]
    dutch = ev[ev.imag > 1e-12][0]
    # roll subsidence ≈ L_p (error of order the Dutch-roll coupling L_β N_p / N_β L_p)
    assert roll == pytest.approx(L_p, rel=0.03)
    # spiral ≈ -(g/V)(L_β N_r - L_r N_β)/(L_β N_p - L_p N_β): it neglects Y_β and the
    # residual roll/yaw dynamics, about 10 % for this aircraft
    spiral_approx = -g_V * (L_b * N_r - L_r * N_b) / (L_b * N_p - L_p * N_b)
    assert spiral == pytest.approx(spiral_approx, rel=0.15)
    assert spiral == pytest.approx(_residualised(A, [3])[0, 0], rel=0.08)
    # Dutch roll: ω² ≈ N_β + Y_β N_r (β-r approximation, neglecting the roll coupling
    # through L_β, known to be 10-20 % off in frequency on light aircraft)
    w_dr = math.sqrt(N_b + Y_b * N_r)
    assert abs(dutch) == pytest.approx(w_dr, rel=0.15)
    # with the roll mode in quasi-steady state (ṗ = 0) the frequency is within 1 %
    red = np.linalg.eigvals(_residualised(A, [0, 2, 3]))
    assert abs(red[np.argmax(red.imag)]) == pytest.approx(abs(dutch), rel=0.01)
    # the weakly coupled case: no dihedral effect, no adverse yaw from roll rate
    weak = lateral(CONSTANTS, V0=V0, terms=LAT_TERMS, parameters=dict(LAT, Cl_beta=0.0, Cn_p=0.0))
    lw = linearize(weak, trim(weak))
    dw = lw.eigenvalues[lw.eigenvalues.imag > 1e-12][0]
    Aw = lw.A
    assert abs(dw) == pytest.approx(math.sqrt(Aw[2, 0] + Aw[0, 0] * Aw[2, 2]), rel=0.01)


def test_dimensional_linear_models_reproduce_the_linearised_nonlinear_ones():
    m = long_model()
    tr = trim(m)
    A = linearize(m, tr).A
    B = linearize(m, tr).B
    lin = longitudinal_linear(
        V0=V0,
        terms={"X": ["V", "alpha", "delta_e"], "Z": ["V", "alpha", "q", "delta_e"]},
        parameters={
            "X_V": A[0, 0],
            "X_alpha": A[0, 1] - G,  # the model adds g cos γ0 (θ - α)
            "X_delta_e": B[0, 0],
            "Z_V": A[1, 0],
            "Z_alpha": A[1, 1],
            "Z_q": A[1, 3] - 1.0,
            "Z_delta_e": B[1, 0],
            "M_V": A[3, 0],
            "M_alpha": A[3, 1],
            "M_q": A[3, 3],
            "M_delta_e": B[3, 0],
        },
    )
    got = linearize(lin, np.zeros(4), np.zeros(1))
    np.testing.assert_allclose(got.A, A, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.B[:, 0], B[:, 0], rtol=1e-9, atol=1e-12)
    ml = lateral(CONSTANTS, V0=V0, alpha0=0.05, theta0=0.08, terms=LAT_TERMS, parameters=LAT)
    la = linearize(ml, trim(ml))
    ll = lateral_linear(
        V0=V0,
        alpha0=0.05,
        theta0=0.08,
        terms={"Y": ["beta", "p", "r", "delta_r"]},
        parameters={
            "Y_beta": la.A[0, 0],
            "Y_p": la.A[0, 1] - math.sin(0.05),
            "Y_r": la.A[0, 2] + math.cos(0.05),
            "Y_delta_r": la.B[0, 1],
            **{
                f"{eq}_{v}": la.A[i, j]
                for eq, i in (("L", 1), ("N", 2))
                for v, j in (("beta", 0), ("p", 1), ("r", 2))
            },
            **{
                f"{eq}_{v}": la.B[i, j]
                for eq, i in (("L", 1), ("N", 2))
                for v, j in (("delta_a", 0), ("delta_r", 1))
            },
        },
    )
    got = linearize(ll, np.zeros(4), np.zeros(2))
    np.testing.assert_allclose(got.A, la.A, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.B, la.B, rtol=1e-9, atol=1e-12)


# -- six degrees of freedom vs the stability-axis models -------------------------------------------


def test_six_dof_reproduces_the_longitudinal_model_on_symmetric_motion():
    c = constants(thrust_angle=0.03, thrust_offset=0.15, accel_position=(0.4, 0.0, 0.2))
    outs = ("V", "alpha", "theta", "q", "q_dot", "ax", "az", "gamma")
    lon = longitudinal(c, V0=V0, parameters=LONG, outputs=outs, with_altitude=True)
    six = six_dof(c, V0=V0, parameters={**LONG, **LAT}, outputs=(*outs, "h"), position=True)
    tr = trim(lon)
    t = np.linspace(0.0, 6.0, 61)
    de = tr.controls["delta_e"] + 0.04 * ((t >= 1) & (t < 2)) - 0.04 * ((t >= 2) & (t < 3))
    T = tr.controls["thrust"] * (1.0 + 0.2 * (t >= 4))
    sl = lon.simulate(t, np.column_stack([de, T]), tr.x0, method="DOP853", rtol=1e-12, atol=1e-12)
    V, a, th = tr.states["V"], tr.states["alpha"], tr.states["theta"]
    x6 = [V * math.cos(a), 0, V * math.sin(a), 0, 0, 0, 0, th, 0, 0, 0, 0]
    U6 = np.column_stack([de, 0 * t, 0 * t, T])
    s6 = six.simulate(t, U6, x6, method="DOP853", rtol=1e-12, atol=1e-12)
    assert np.ptp(sl.state("alpha")) > 0.02  # the manoeuvre does excite the motion
    for k in outs:
        np.testing.assert_allclose(
            s6.output(k),
            sl.output(k),
            rtol=0,
            atol=1e-8 * max(1.0, np.max(np.abs(sl.output(k)))),
            err_msg=k,
        )
    np.testing.assert_allclose(s6.output("h"), sl.state("h"), atol=1e-8 * 50)
    for k in ("v", "p", "r", "phi", "psi"):
        assert np.max(np.abs(s6.state(k))) < 1e-12


def test_six_dof_lateral_dynamics_equal_the_lateral_model_at_trim():
    # the lateral model is the six-degree model's lateral block at trim (β = v / V0)
    six = six_model()
    tr = trim(six)
    A6 = linearize(six, tr, step=1e-6)
    alpha0, theta0 = tr.outputs["alpha"], tr.states["theta"]
    lat = lateral(CONSTANTS, V0=V0, alpha0=alpha0, theta0=theta0, terms=LAT_TERMS, parameters=LAT)
    Al = linearize(lat, trim(lat))
    idx = [six.states.index(s) for s in ("v", "p", "r", "phi")]
    S = np.diag([V0, 1.0, 1.0, 1.0])  # δv = V0 δβ
    A_block = np.linalg.solve(S, A6.A[np.ix_(idx, idx)] @ S)
    np.testing.assert_allclose(A_block, Al.A, rtol=1e-8, atol=1e-10)
    B_block = np.linalg.solve(S, A6.B[np.ix_(idx, [1, 2])])
    np.testing.assert_allclose(B_block, Al.B, rtol=1e-8, atol=1e-10)


# -- sensors --------------------------------------------------------------------------------------


def _random_states(model: AircraftModel, rng: np.random.Generator, n: int) -> np.ndarray:
    tr = trim(model)
    return tr.x0[:, None] * (
        1 + 0.1 * rng.standard_normal((model.n_states, n))
    ) + 0.1 * rng.standard_normal((model.n_states, n))


def _call(fun, X, U, model):
    P = {k: np.full(X.shape[1], v) for k, v in model.parameters.items()}
    return np.asarray(fun(0.0, X, U, P))


def test_accelerometers_measure_the_specific_force_from_the_motion():
    rng = np.random.default_rng(4)
    n = 20
    # six-dof: a = v̇ + ω × v - g_body, from the state derivatives
    six = six_model(outputs=("ax", "ay", "az"))
    X = _random_states(six, rng, n)
    U = rng.normal(0.0, 0.05, (4, n)) + np.array([[0.0], [0.0], [0.0], [1500.0]])
    xd = _call(six.dynamics, X, U, six)
    y = _call(six.measurement, X, U, six)
    u, v, w, p, q, r, phi, th = X[:8]
    fx = xd[0] - r * v + q * w + G * np.sin(th)
    fy = xd[1] - p * w + r * u - G * np.cos(th) * np.sin(phi)
    fz = xd[2] - q * u + p * v - G * np.cos(th) * np.cos(phi)
    np.testing.assert_allclose(y, np.stack([fx, fy, fz]), rtol=1e-10, atol=1e-10)
    # longitudinal: (u, w) = V (cos α, sin α)
    lon = long_model(outputs=("ax", "az"), accel_units="g")
    X = _random_states(lon, rng, n)
    U = np.stack([rng.normal(0, 0.05, n), rng.uniform(0, 3000, n)])
    xd, y = _call(lon.dynamics, X, U, lon), _call(lon.measurement, X, U, lon)
    V, a, th, q = X
    ud = xd[0] * np.cos(a) - V * np.sin(a) * xd[1]
    wd = xd[0] * np.sin(a) + V * np.cos(a) * xd[1]
    fx = ud + q * V * np.sin(a) + G * np.sin(th)
    fz = wd - q * V * np.cos(a) - G * np.cos(th)
    np.testing.assert_allclose(y * G, np.stack([fx, fz]), rtol=1e-10, atol=1e-10)
    # lateral (small perturbations, v = V0 β): a_y = V0 (β̇ - p sin α0 + r cos α0) - g cos θ0 sin φ
    lat = lateral(CONSTANTS, V0=V0, alpha0=0.05, theta0=0.1, outputs=("ay",), parameters=LAT)
    X = rng.normal(0.0, 0.1, (4, n))
    U = rng.normal(0.0, 0.05, (2, n))
    xd, y = _call(lat.dynamics, X, U, lat), _call(lat.measurement, X, U, lat)
    _, p, r, phi = X
    fy = V0 * (xd[0] - p * math.sin(0.05) + r * math.cos(0.05)) - G * math.cos(0.1) * np.sin(phi)
    np.testing.assert_allclose(y[0], fy, rtol=1e-10, atol=1e-10)


def test_sensor_position_corrections_on_a_pure_rotation():
    rng = np.random.default_rng(7)
    ra = np.array([0.8, -0.3, 0.25])
    outs = ("ax", "ay", "az", "p_dot", "q_dot", "r_dot")
    at_cg = six_model(outputs=outs)
    off = six_model(constants(accel_position=tuple(ra)), outputs=outs)
    X = _random_states(at_cg, rng, 12)
    X[3:6] = rng.normal(0.0, 1.0, (3, 12))  # brisk rotation
    U = rng.normal(0.0, 0.05, (4, 12)) + np.array([[0.0], [0.0], [0.0], [1000.0]])
    y0, y1 = _call(at_cg.measurement, X, U, at_cg), _call(off.measurement, X, U, off)
    w, wd = X[3:6].T, y0[3:6].T
    expect = np.cross(wd, ra) + np.cross(w, np.cross(w, ra))
    np.testing.assert_allclose((y1[:3] - y0[:3]).T, expect, rtol=1e-10, atol=1e-10)
    # longitudinal: ax = ax_cg - q² xa + q̇ za, az = az_cg - q² za - q̇ xa
    lc = long_model(outputs=("ax", "az", "q_dot"))
    lo = long_model(constants(accel_position=(0.8, 0.0, 0.25)), outputs=("ax", "az", "q_dot"))
    X = _random_states(lc, rng, 12)
    U = np.stack([rng.normal(0, 0.05, 12), rng.uniform(0, 3000, 12)])
    y0, y1 = _call(lc.measurement, X, U, lc), _call(lo.measurement, X, U, lo)
    q, qd = X[3], y0[2]
    np.testing.assert_allclose(y1[0] - y0[0], -(q**2) * 0.8 + qd * 0.25, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(y1[1] - y0[1], -(q**2) * 0.25 - qd * 0.8, rtol=1e-10, atol=1e-12)
    # lateral: ay = ay_cg + ṙ xa - (p² + r²) ya - ṗ za
    lat0 = lateral(CONSTANTS, V0=V0, parameters=LAT, outputs=("ay", "p_dot", "r_dot"))
    lat1 = lateral(constants(accel_position=tuple(ra)), V0=V0, parameters=LAT, outputs=("ay",))
    X = rng.normal(0.0, 0.5, (4, 12))
    U = rng.normal(0.0, 0.05, (2, 12))
    y0, y1 = _call(lat0.measurement, X, U, lat0), _call(lat1.measurement, X, U, lat1)
    p, r = X[1], X[2]
    expect_y = y0[2] * ra[0] - (p**2 + r**2) * ra[1] - y0[1] * ra[2]
    np.testing.assert_allclose(y1[0] - y0[0], expect_y, rtol=1e-10, atol=1e-12)


def test_air_data_vanes_see_the_local_flow():
    rng = np.random.default_rng(11)
    rv, rb = np.array([2.5, 0.4, -0.3]), np.array([2.0, -0.6, 0.5])
    six = six_model(
        constants(alpha_vane_position=tuple(rv), beta_vane_position=tuple(rb)),
        outputs=("alpha", "beta"),
    )
    X = _random_states(six, rng, 10)
    X[3:6] = rng.normal(0.0, 0.5, (3, 10))
    U = np.zeros((4, 10))
    y = _call(six.measurement, X, U, six)
    vel, w = X[:3].T, X[3:6].T
    local_a = vel + np.cross(w, rv)
    local_b = vel + np.cross(w, rb)
    np.testing.assert_allclose(y[0], np.arctan2(local_a[:, 2], local_a[:, 0]), rtol=1e-12)
    np.testing.assert_allclose(
        y[1], np.arcsin(local_b[:, 1] / np.linalg.norm(local_b, axis=1)), rtol=1e-12
    )
    # small angles and rates: Klein & Morelli's α_v ≈ α - xα q / V (third order here)
    lon = long_model(constants(alpha_vane_position=(2.5, 0.0, 0.0)), outputs=("alpha",))
    x = np.array([[V0], [0.0], [0.0], [1e-3]])
    y = _call(lon.measurement, x, np.array([[0.0], [0.0]]), lon)
    assert y[0, 0] == pytest.approx(-2.5e-3 / V0, rel=1e-9)


# -- identification ------------------------------------------------------------------------------------


def test_longitudinal_coefficients_are_recovered_from_noisy_data(monkeypatch):
    # the numpy path: compiling a fresh model costs more than this short fit
    monkeypatch.setattr(_compiled, "ENABLED", False)
    model = longitudinal(
        CONSTANTS, V0=V0, parameters=LONG, outputs=("V", "alpha", "theta", "q", "az")
    )
    tr = trim(model)
    t = np.arange(0.0, 8.0 + 1e-9, 0.05)
    de = np.full(t.size, tr.controls["delta_e"])
    for start, end, sign in ((1, 4, 1), (4, 6, -1), (6, 7, 1), (7, 8, -1)):  # 3-2-1-1
        de[(t >= start * 0.6) & (t < end * 0.6)] += 0.03 * sign
    U = np.column_stack([de, np.full(t.size, tr.controls["thrust"])])
    sim = model.simulate(t, U, tr.x0, method="rk4")
    noise = {"V": 0.1, "alpha": 0.002, "theta": 0.002, "q": 0.005, "az": 0.1}
    data = sim.to_flight_data(noise=noise, seed=3)
    truth = {k: LONG[k] for k in ("CL_alpha", "Cm_alpha", "Cm_q", "Cm_delta_e")}
    guess = {k: 0.8 * v for k, v in truth.items()}
    res = aeroid.identify(model, data, guess, x0=tr.x0)
    for k, v in truth.items():
        assert abs(res.parameters[k] - v) < 3 * res.stderr[k], (k, res.parameters[k], res.stderr[k])
        assert res.stderr[k] < 0.05 * abs(v)


ALPHA_DOT_TERMS = {
    "CD": ("0", "alpha", "delta_e"),
    "CL": ("0", "alpha", "q", "alpha_dot", "delta_e"),
    "Cm": ("0", "alpha", "q", "alpha_dot", "delta_e"),
}


def alpha_dot_model(**kw: object) -> AircraftModel:
    values = {**LONG, "CL_alpha_dot": 1.7, "Cm_alpha_dot": -4.4}
    return longitudinal(CONSTANTS, V0=V0, terms=ALPHA_DOT_TERMS, parameters=values, **kw)


def test_alpha_dot_terms_solve_the_implicit_alpha_equation():
    # alpha-dot appears on both sides once CL has an alpha-dot term; the model's alpha-dot
    # must satisfy the equation it is in, and q-dot must use that same alpha-dot
    m = alpha_dot_model(outputs=("az", "q_dot"))
    rng = np.random.default_rng(11)
    X = np.array([V0, 0.05, 0.04, 0.0])[:, None] + rng.normal(
        0, [[2], [0.05], [0.05], [0.2]], (4, 8)
    )
    U = np.vstack([rng.normal(0.0, 0.05, 8), rng.uniform(500, 2000, 8)])
    P = dict(m.parameters)
    V, alpha, theta, q = X
    de, T = U
    xdot = m.dynamics(0.0, X, U, P)
    ad = xdot[1]
    qbar_S = 0.5 * 1.225 * V**2 * CONSTANTS.S
    hat = ad * CONSTANTS.cbar / (2 * V)
    CL = P["CL_0"] + P["CL_alpha"] * alpha + P["CL_q"] * q * CONSTANTS.cbar / (2 * V)
    CL = CL + P["CL_alpha_dot"] * hat + P["CL_delta_e"] * de
    rhs = q + (G * np.cos(theta - alpha) - (qbar_S * CL + T * np.sin(alpha)) / CONSTANTS.mass) / V
    np.testing.assert_allclose(ad, rhs, rtol=1e-13, atol=1e-15)
    Cm = P["Cm_0"] + P["Cm_alpha"] * alpha + P["Cm_q"] * q * CONSTANTS.cbar / (2 * V)
    Cm = Cm + P["Cm_alpha_dot"] * hat + P["Cm_delta_e"] * de
    np.testing.assert_allclose(xdot[3], qbar_S * CONSTANTS.cbar * Cm / CONSTANTS.Iyy, rtol=1e-13)
    np.testing.assert_allclose(m.measurement(0.0, X, U, P)[1], xdot[3], rtol=1e-13)
    # without the alpha-dot terms the model is the lumped one, value for value
    zero = {**P, "CL_alpha_dot": 0.0, "Cm_alpha_dot": 0.0}
    np.testing.assert_allclose(m.dynamics(0.0, X, U, zero), long_model().dynamics(0.0, X, U, LONG))
    assert "Cm_alpha_dot α̇ c̄/(2V)" in m.summary()
    assert m.parameter_units["Cm_alpha_dot"] == "1/rad"


def test_alpha_dot_only_enters_alone_and_only_where_it_exists():
    with pytest.raises(ModelDefinitionError, match="alpha_dot may only enter alone"):
        longitudinal(CONSTANTS, V0=V0, terms={"Cm": ["alpha*alpha_dot"]})
    with pytest.raises(ModelDefinitionError, match="alpha_dot"):
        lateral(CONSTANTS, V0=V0, alpha0=0.0, theta0=0.0, terms={"Cn": ["alpha_dot"]})


def test_alpha_dot_and_pitch_damping_are_separated_by_a_rich_noise_free_input(monkeypatch):
    # alpha-dot and q nearly move together; with two input frequencies and no noise the
    # fit still tells Cm_q from Cm_alpha_dot (and CL_q from CL_alpha_dot: truth unchanged)
    monkeypatch.setattr(_compiled, "ENABLED", False)
    m = alpha_dot_model(outputs=("V", "alpha", "theta", "q", "az"))
    tr = trim(m)
    t = np.arange(0.0, 12.0 + 1e-9, 0.02)
    de = (
        tr.controls["delta_e"]
        + 0.02 * np.sin(2.0 * t) * (t < 6)
        + 0.02 * np.sign(np.sin(5.0 * t)) * (t >= 6)
    )
    U = np.column_stack([de, np.full(t.size, tr.controls["thrust"])])
    data = m.simulate(t, U, tr.x0, method="rk4").to_flight_data()
    names = ("CL_alpha", "Cm_alpha", "Cm_q", "Cm_alpha_dot", "Cm_delta_e")
    guess = {k: 0.7 * m.parameters[k] for k in names}
    res = aeroid.identify(m, data, guess, x0=tr.x0)
    for k in names:
        assert res.parameters[k] == pytest.approx(m.parameters[k], rel=1e-4), k


def _rebound(fun, jnp):
    """`fun` with the module's numpy replaced by `jnp` (what array-API compilation does)."""
    glb = dict(fun.__globals__, np=jnp)
    return types.FunctionType(fun.__code__, glb, fun.__name__, fun.__defaults__, fun.__closure__)


def test_model_functions_trace_under_jax_numpy():
    # written with module-level np only, the functions run on jax.numpy unchanged
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    jnp = jax.numpy
    rng = np.random.default_rng(5)
    models = [
        six_model(constants(accel_position=(0.3, 0.1, 0.2), alpha_vane_position=(2, 0, 0))),
        long_model(with_altitude=True, outputs=("V", "alpha", "q_dot", "ax", "az", "h", "gamma")),
        alpha_dot_model(outputs=("V", "alpha", "q_dot", "ax", "az")),
        lateral(CONSTANTS, V0=V0, alpha0=0.05, theta0=0.05, parameters=LAT, with_heading=True),
        longitudinal_linear(V0=V0, gamma0=0.1, parameters={"M_alpha": -5.0, "X_V": -0.1}),
        lateral_linear(V0=V0, parameters={"L_p": -8.0, "N_beta": 4.0}),
    ]
    for m in models:
        tr = trim(m)
        X = tr.x0[:, None] + 0.05 * rng.standard_normal((m.n_states, 6))
        U = tr.u0[:, None] + 0.01 * rng.standard_normal((m.n_controls, 6))
        P = {k: np.full(6, v) for k, v in m.parameters.items()}
        for fun in (m.dynamics, m.measurement):
            rebound = _rebound(fun, jnp)
            jax.make_jaxpr(rebound)(0.0, X, U, P)  # traces: no Python branch on a value
            got = np.asarray(rebound(0.0, jnp.asarray(X), jnp.asarray(U), P))
            np.testing.assert_allclose(got, fun(0.0, X, U, P), rtol=1e-12, atol=1e-12)


# -- models from a campaign config ---------------------------------------------------------------------

_YAML = """\
model:
  aircraft: longitudinal
  V0: 53.6
  constants: {{mass: {mass}, Ixx: 1421, Iyy: 4067, Izz: 4786, Ixz: 80, S: 17.09, b: 10.18,
              cbar: 1.74, altitude: 1500, accel_position: [0.3, 0.0, 0.1]}}
  terms: {{CD: ["0", alpha], CL: ["0", alpha, q, delta_e], Cm: ["0", alpha, q, delta_e]}}
  parameters: {{CL_alpha: 4.4, Cm_alpha: -0.7, Cm_q: -10}}
  outputs: [V, alpha, theta, q, az]
store: store
flights: [flight.csv]
stages:
  identify: {{parameters: [CL_alpha, Cm_alpha, Cm_q, Cm_delta_e]}}
"""


def test_a_campaign_config_defines_an_aircraft_model_by_name(tmp_path):
    from aeroid.models.aircraft import model_from_config
    from aeroid.pipeline.plans.config import load_config
    from aeroid.pipeline.running.runner import plan, resolve_model

    (tmp_path / "flight.csv").write_text(
        "time,V,alpha,theta,q,az,delta_e,thrust\n0,1,2,3,4,5,6,7\n"
    )
    keys = []
    for i, mass in enumerate((1247, 1247, 1300)):
        cfg = tmp_path / f"c{i}.yaml"
        cfg.write_text(_YAML.format(mass=mass))
        config = load_config(cfg)
        model = resolve_model(config.model, config.base_dir)
        assert isinstance(model, AircraftModel) and model.kind == "longitudinal"
        assert model.constants is not None and model.constants.mass == mass
        assert model.constants.density() == pytest.approx(isa_density(1500.0))
        assert model.parameters["Cm_q"] == -10.0 and "CD_delta_e" not in model.parameters
        keys.append(next(t.key for t in plan(config).tasks if t.stage == "identify"))
    assert keys[0] == keys[1] != keys[2]  # keyed by content: the mass changes the key
    with pytest.raises(ModelDefinitionError, match="wingspan"):
        model_from_config({"aircraft": "lateral", "V0": 50, "wingspan": 3})
    with pytest.raises(ModelDefinitionError, match="missing"):
        model_from_config({"aircraft": "six_dof", "V0": 50, "constants": {"mass": 3, "rho": 1}})
    with pytest.raises(ModelDefinitionError, match="aircraft"):
        model_from_config({"aircraft": "helicopter"})
    with pytest.raises(aeroid.ConfigError, match="model: aircraft"):
        resolve_model({"aircraft": "helicopter"})
    lin = model_from_config({"aircraft": "lateral_linear", "V0": 50, "parameters": {"L_p": -3}})
    assert lin.parameters["L_p"] == -3.0


def _body_to_earth(phi: float, theta: float, psi: float) -> np.ndarray:
    cf, sf, ct, st, cp, sp = (
        math.cos(phi),
        math.sin(phi),
        math.cos(theta),
        math.sin(theta),
        math.cos(psi),
        math.sin(psi),
    )
    return np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )


def test_torque_free_tumbling_conserves_angular_momentum_and_energy():
    # no aerodynamic moments (all coefficients zero): Euler's equations with Ixz and the
    # Euler-angle kinematics keep the Earth-axis angular momentum and the energy fixed
    c = constants(Ixz=300.0)
    m = six_dof(c, V0=V0, outputs=("p", "q", "r", "phi", "theta", "psi"))
    t = np.linspace(0.0, 3.0, 31)
    x0 = [V0, 0.0, 0.0, 0.6, -0.4, 0.5, 0.1, 0.2, 0.3]
    sim = m.simulate(t, np.zeros((t.size, 4)), x0, method="DOP853", rtol=1e-12, atol=1e-12)
    inertia = c.inertia_tensor()
    w = sim.outputs[:, :3]
    assert np.ptp(sim.output("phi")) > 0.5  # it does tumble
    H = np.array(
        [
            _body_to_earth(*angles) @ inertia @ wi
            for wi, angles in zip(w, sim.outputs[:, 3:], strict=True)
        ]
    )
    energy = np.einsum("ti,ij,tj->t", w, inertia, w)
    np.testing.assert_allclose(
        H, np.broadcast_to(H[0], H.shape), rtol=0, atol=1e-8 * np.linalg.norm(H[0])
    )
    np.testing.assert_allclose(energy, energy[0], rtol=1e-9)


def test_trim_and_linearize_limit_blas_threads():
    # wrapped by `small_blas`, as every numerical entry point of the library
    for fn in (trim, linearize):
        assert hasattr(fn, "__wrapped__"), fn.__name__
    assert "Raises" in trim.__doc__  # the docstring survives the wrapper


def test_decoupled_nonlinear_model_translates_to_jax():
    pytest.importorskip("jax")
    from aeroid.models.aircraft import decoupled

    both = decoupled(longitudinal(CONSTANTS, V0=V0), lateral(CONSTANTS, V0=V0, alpha0=0.05))
    t = np.linspace(0.0, 2.0, 101)
    u = np.column_stack([np.full(t.size, 0.01 * k) for k in range(len(both.controls))])
    x0 = np.array([V0, 0.05, 0.05, 0.0, 0.01, 0.0, 0.0, 0.0])
    p = {k: 0.01 for k in both.parameters}
    # the stacked model translates to JAX (its controls picked row by row), so the
    # nonlinear filters' compiled propagation is used for it
    step = _compiled.interval_propagator(both, t, u, x0, p, 1)
    assert step is not None


def test_decoupled_model_stacks_the_two_sets_of_equations_exactly():
    from aeroid.models.aircraft import decoupled, model_from_config

    lon = longitudinal_linear(V0=V0, parameters={"Z_alpha": -1.2, "M_alpha": -4.0, "M_q": -2.0})
    lat = lateral_linear(V0=V0, alpha0=0.05, theta0=0.04, parameters={"L_p": -8.0, "N_r": -0.9})
    both = decoupled(lon, lat)
    assert both.states == (*lon.states, *lat.states)
    assert both.controls == ("delta_e", "delta_a", "delta_r")
    rng = np.random.default_rng(0)
    x = rng.normal(size=len(both.states))
    u = rng.normal(size=len(both.controls))
    p = dict(both.parameters)
    n = len(lon.states)
    expected = np.concatenate(
        [lon.dynamics(0.0, x[:n], u[:1], p), lat.dynamics(0.0, x[n:], u[1:], p)]
    )
    np.testing.assert_array_equal(both.dynamics(0.0, x, u, p), expected)
    # batched columns, as the integrators call it
    X = rng.normal(size=(len(both.states), 5))
    U = rng.normal(size=(len(both.controls), 5))
    cols = np.stack([both.dynamics(0.0, X[:, j], U[:, j], p) for j in range(5)], axis=1)
    np.testing.assert_allclose(both.dynamics(0.0, X, U, p), cols, rtol=1e-14)
    # simulation equals the two parts simulated separately
    t = np.linspace(0.0, 5.0, 251)
    controls = {"delta_e": 0.02 * np.sin(t), "delta_a": 0.03 * np.cos(2 * t), "delta_r": 0.01 * t}
    sim = both.simulate(t, controls)
    lon_sim = lon.simulate(t, {"delta_e": controls["delta_e"]})
    lat_sim = lat.simulate(t, {k: controls[k] for k in ("delta_a", "delta_r")})
    n_lon = len(lon.output_names)
    np.testing.assert_allclose(sim.outputs[..., :n_lon], lon_sim.outputs, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sim.outputs[..., n_lon:], lat_sim.outputs, rtol=1e-9, atol=1e-12)
    # from a config mapping, and mistakes named
    spec = {
        "aircraft": "decoupled",
        "longitudinal": {"aircraft": "longitudinal_linear", "V0": V0},
        "lateral": {"aircraft": "lateral_linear", "V0": V0},
    }
    assert model_from_config(spec).kind == "decoupled"
    with pytest.raises(ModelDefinitionError, match="longitudinal"):
        model_from_config({"aircraft": "decoupled", "lateral": spec["lateral"]})
    with pytest.raises(ModelDefinitionError, match="lateral"):
        decoupled(lon, lon)


# -- parameter units ----------------------------------------------------------------------


def test_parameter_units_follow_from_the_equations_and_regressors():
    lon = longitudinal_linear(
        V0=V0,
        terms={"X": ["0", "V", "alpha", "q"], "Z": ["V", "q"], "M": ["V", "alpha", "q", "delta_e"]},
    )
    u = lon.parameter_units
    # V dot in m/s2, alpha dot in 1/s (rad/s), q dot in 1/s2, over m/s, rad and rad/s
    assert (u["X_0"], u["X_V"], u["X_alpha"], u["X_q"]) == ("m/s²", "1/s", "m/s²", "m/s")
    assert (u["Z_V"], u["Z_q"]) == ("1/m", "-")
    assert (u["M_V"], u["M_alpha"], u["M_q"], u["M_delta_e"]) == ("1/(m s)", "1/s²", "1/s", "1/s²")
    lat = lateral_linear(V0=V0)
    assert lat.parameter_units["Y_beta"] == "1/s" and lat.parameter_units["L_p"] == "1/s"
    assert lat.parameter_units["N_delta_r"] == "1/s²"
    # non-dimensional coefficients: per radian for angles and for the scaled rates
    # (q c/(2V) is an angle: Klein & Morelli and Jategaonkar quote Cm_q per rad)
    cl = longitudinal(
        CONSTANTS,
        V0=V0,
        parameters=LONG,
        terms={"CL": ["0", "alpha", "q", "delta_e", "alpha*alpha"]},
    )
    assert cl.parameter_units["CL_0"] == "-" and cl.parameter_units["CL_q"] == "1/rad"
    assert cl.parameter_units["CL_alpha"] == "1/rad"
    assert cl.parameter_units["CL_alpha_alpha"] == "1/rad²"
    assert cl.parameter_units["Cm_delta_e"] == "1/rad"
    assert set(cl.parameter_units) == set(cl.parameters)
    both = aeroid.models.aircraft.decoupled(lon, lat)
    assert dict(both.parameter_units) == {**u, **lat.parameter_units}
    # constants in feet and pounds (g in ft/s²): the parameters' units too, as the
    # channels' (found by an independent suite: X_alpha labelled m/s² beside V in ft/s)
    us = longitudinal_linear(V0=176.0, g=32.174, terms={"X": ["alpha"], "M": ["V", "q"]})
    assert (us.parameter_units["X_alpha"], us.parameter_units["M_V"]) == ("ft/s²", "1/(ft s)")
    assert us.channel_units["V"] == "ft/s" and "g = 32.174 ft/s²" in us.summary()


def test_an_identification_result_carries_the_models_units():
    model = longitudinal_linear(
        V0=V0, parameters={"M_alpha": -5.0, "M_q": -2.0, "M_delta_e": -8.0, "Z_alpha": -1.0}
    )
    t = np.arange(0.0, 10.0, 0.02)
    de = np.where((t > 1) & (t < 2), 0.02, 0.0) - np.where((t > 2) & (t < 3), 0.02, 0.0)
    sim = model.simulate(t, de[:, None], np.zeros(4))
    data = aeroid.FlightData(t, {**{s: sim.state(s) for s in model.states}, "delta_e": de})
    fit = aeroid.identify(model, data, ["M_alpha", "M_q"])
    assert dict(fit.parameter_units) == {"M_alpha": "1/s²", "M_q": "1/s"}
    fig = fit.plot()
    # the estimates' forest plot labels each row with its value and unit
    labels = [t.get_text() for ax in fig.axes for t in ax.get_yticklabels()]
    assert any(lab.startswith("M_alpha") and lab.endswith("[1/s²]") for lab in labels)
    assert any(lab.startswith("M_q") and lab.endswith("[1/s]") for lab in labels)
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_channel_units_label_a_record_that_gives_none():
    lon = longitudinal(CONSTANTS, V0=V0, parameters=LONG, accel_units="g")
    u = lon.channel_units
    assert (u["V"], u["alpha"], u["q"], u["q_dot"], u["az"], u["delta_e"]) == (
        "m/s",
        "rad",
        "rad/s",
        "rad/s²",
        "g",
        "rad",
    )
    lin = longitudinal_linear(V0=V0, parameters={"M_alpha": -5.0, "M_q": -2.0, "M_delta_e": -8.0})
    t = np.arange(0.0, 4.0, 0.02)
    de = np.where((t > 1) & (t < 2), 0.02, 0.0)
    sim = lin.simulate(t, de[:, None], np.zeros(4))
    plain = aeroid.FlightData(t, {**{s: sim.state(s) for s in lin.states}, "delta_e": de})
    v = aeroid.validate(lin, plain, dict(lin.parameters))
    assert v.units["q"] == "rad/s" and v.units["V"] == "m/s" and v.units["delta_e"] == "rad"
    # a unit the record states that contradicts the model's is refused, as identify does
    given = aeroid.FlightData(plain.time, dict(plain.channels), units={"q": "deg/s"})
    with pytest.raises(aeroid.IdentificationError, match="'q' is stated in 'deg/s'"):
        aeroid.validate(lin, given, dict(lin.parameters))


# -- textbook set-ups: accelerations of the linear models, US units, rate reference -------------


def test_linear_models_give_the_specific_forces_in_either_unit():
    # az = V0 ΣZ (α̇ = q + ΣZ ...: ΣZ is Z/(m V0)), ay = V0 ΣY; in g divided by g
    Z = {"Z_V": -0.01, "Z_alpha": -1.1, "Z_q": -0.02, "Z_delta_e": -0.1}
    for g, units, scale in ((9.80665, "m/s2", 1.0), (32.174, "g", 1.0 / 32.174)):
        lon = longitudinal_linear(
            V0=100.0,
            g=g,
            terms={"X": ["V"], "Z": ["V", "alpha", "q", "delta_e"], "M": ["alpha"]},
            parameters=Z,
            outputs=["alpha", "az"],
            accel_units=units,
        )
        lin = linearize(lon, np.zeros(4), np.zeros(1))
        want = 100.0 * scale * np.array([Z["Z_V"], Z["Z_alpha"], 0.0, Z["Z_q"]])
        np.testing.assert_allclose(lin.C[1], want, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lin.D[1, 0], 100.0 * scale * Z["Z_delta_e"], rtol=1e-9)
        lat = lateral_linear(
            V0=100.0,
            g=g,
            terms={"Y": ["beta", "delta_r"]},
            parameters={"Y_beta": -0.2, "Y_delta_r": 0.05},
            outputs=["beta", "ay"],
            accel_units=units,
        )
        lin = linearize(lat, np.zeros(4), np.zeros(2))
        np.testing.assert_allclose(lin.C[1], [-20.0 * scale, 0, 0, 0], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lin.D[1], [0.0, 5.0 * scale], rtol=1e-9, atol=1e-12)
    with pytest.raises(ModelDefinitionError, match="accel_units"):
        lateral_linear(V0=100.0, accel_units="ft/s2")
    with pytest.raises(ModelDefinitionError, match="g: must be positive"):
        longitudinal_linear(V0=100.0, g=-9.8)


def test_accelerations_in_g_use_the_constants_gravity():
    # US units: constants in slug, ft, g = 32.174 ft/s^2; an output in g divides by that g
    us = AircraftConstants(
        mass=85.4, Ixx=1048.0, Iyy=3000.0, Izz=3530.0, S=184.0, b=33.4, cbar=5.7,
        rho=0.002377, g=32.174,
    )  # fmt: skip
    for make in (
        lambda u: longitudinal(us, V0=176.0, parameters=LONG, accel_units=u),
        lambda u: lateral(us, V0=176.0, terms=LAT_TERMS, parameters=LAT, accel_units=u),
    ):
        native, in_g = make("m/s2"), make("g")
        tr = trim(native)
        a = linearize(native, tr)
        b = linearize(in_g, tr)
        rows = [i for i, o in enumerate(native.output_names) if o in ("ax", "ay", "az")]
        assert rows
        np.testing.assert_allclose(b.C[rows], a.C[rows] / 32.174, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(b.D[rows], a.D[rows] / 32.174, rtol=1e-9, atol=1e-15)


def test_rate_reference_chooses_the_airspeed_of_the_nondimensional_rate():
    # q̇ = q̄ S c̄ Cm / Iyy with Cm = Cm_q q c̄ / (2 V_ref): off the reference speed the two
    # forms differ by exactly the ratio V / V0
    params = {"Cm_q": -12.0}
    terms = {"CD": ["0"], "CL": ["alpha"], "Cm": ["q"]}
    x = np.array([1.2 * V0, 0.05, 0.05, 0.3])
    u = np.array([0.0, 0.0])
    got = {}
    for ref in ("V", "V0"):
        m = longitudinal(
            CONSTANTS, V0=V0, terms=terms, parameters=params, outputs=["q_dot"],
            rate_reference=ref,
        )  # fmt: skip
        got[ref] = float(np.asarray(m.measurement(0.0, x, u, dict(m.parameters)))[0])
    qbar_S_c = 0.5 * 1.225 * x[0] ** 2 * BASE["S"] * BASE["cbar"]
    expect_V = qbar_S_c * params["Cm_q"] * x[3] * BASE["cbar"] / (2 * x[0]) / BASE["Iyy"]
    assert got["V"] == pytest.approx(expect_V, rel=1e-12)
    assert got["V0"] == pytest.approx(expect_V * 1.2, rel=1e-12)
    with pytest.raises(ModelDefinitionError, match="rate_reference"):
        longitudinal(CONSTANTS, V0=V0, rate_reference="Vtrue")


def test_a_longitudinal_model_needs_no_lateral_constants():
    lon_only = AircraftConstants(
        mass=BASE["mass"], Iyy=BASE["Iyy"], S=BASE["S"], cbar=BASE["cbar"], rho=1.225
    )
    m = longitudinal(lon_only, V0=V0, parameters=LONG)
    assert np.isfinite(linearize(m, trim(m)).A).all()
    with pytest.raises(ModelDefinitionError, match="Ixx, Izz, b"):
        lateral(lon_only, V0=V0)
    with pytest.raises(ModelDefinitionError, match="six-degree-of-freedom model needs"):
        six_dof(lon_only, V0=V0)
    with pytest.raises(ModelDefinitionError, match="Iyy: required"):
        AircraftConstants(mass=1.0, S=1.0, cbar=1.0, rho=1.0)
    from aeroid.models.aircraft import model_from_config

    cfg = {k: lon_only_value for k, lon_only_value in (("mass", 1.0), ("Iyy", 2.0), ("S", 1.0))}
    with pytest.raises(ModelDefinitionError, match="cbar"):
        model_from_config({"aircraft": "longitudinal", "V0": 50, "constants": {**cfg, "rho": 1}})
    ok = model_from_config(
        {"aircraft": "longitudinal", "V0": 50, "constants": {**cfg, "cbar": 1.0, "rho": 1}}
    )
    assert ok.kind == "longitudinal"


def test_the_linear_models_print_their_own_regressors():
    # perturbations in m/s, rad and rad/s times dimensional derivatives: no V/V0 - 1, no
    # nondimensional rates (those are the nonlinear models' regressors)
    from aeroid.models.aircraft import lateral_linear, longitudinal_linear

    longitudinal = longitudinal_linear(V0=50.0).summary()
    assert "ΣX = X_V V + X_alpha α" in longitudinal and "M_q q +" in longitudinal
    lateral = lateral_linear(V0=50.0).summary()
    assert "L_p p + L_r r" in lateral
    for text in (longitudinal, lateral):
        assert "V/V0" not in text and "/(2V)" not in text


def test_linearize_names_a_point_that_does_not_fit_as_documented():
    from aeroid.errors import ModelDefinitionError
    from aeroid.models.aircraft import linearize, longitudinal_linear

    model = longitudinal_linear(V0=50.0)
    with pytest.raises(ModelDefinitionError, match="x0: expected 4 values"):
        linearize(model, [1.0, 2.0])
    with pytest.raises(ModelDefinitionError, match="unknown states \\['bogus'\\]"):
        linearize(model, {"bogus": 0.0})


def test_a_surface_named_as_a_state_says_how_to_use_it_as_an_input() -> None:
    from aeroid.models import aircraft

    with pytest.raises(ModelDefinitionError, match=r"'beta'.*name it otherwise.*'beta_m'"):
        aircraft.lateral_linear(V0=60.0, surfaces=("delta_a", "delta_r", "beta"))
