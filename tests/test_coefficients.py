"""Force and moment coefficients from measured motion against closed-form forces."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import ChannelError, DataFormatError, FlightData, ModelDefinitionError
from aeroid.models.aircraft import AircraftConstants
from aeroid.models.coefficients import coefficients_from_data

DT = 0.01
T = np.arange(0.0, 8.0 + DT / 2, DT)
AC = AircraftConstants(
    mass=1200.0, Ixx=1400.0, Iyy=1800.0, Izz=2900.0, Ixz=90.0, S=16.2, b=10.9, cbar=1.5, rho=1.1
)


def _truth(
    lever: tuple[float, float, float] = (0.0, 0.0, 0.0), ac: AircraftConstants = AC
) -> tuple[dict, dict]:
    """Motion whose coefficients are known functions of time, and those coefficients."""
    # rates are sine series over the record: the Fourier smoother differentiates them exactly
    w = 2 * np.pi / T[-1]
    V = 50.0 + 2.0 * np.sin(w * T)
    alpha = 0.08 + 0.03 * np.sin(2 * w * T)
    p, pd = 0.2 * np.sin(3 * w * T), 0.2 * 3 * w * np.cos(3 * w * T)
    q, qd = 0.1 * np.sin(2 * w * T), 0.1 * 2 * w * np.cos(2 * w * T)
    r, rd = 0.05 * np.sin(w * T), 0.05 * w * np.cos(w * T)
    qs = 0.5 * AC.rho * V**2 * AC.S
    thrust = 1500.0 + 100.0 * np.cos(w * T)
    fx, fy, fz = -800 + 200 * np.sin(w * T), 300 * np.cos(2 * w * T), -11000 + 900 * np.sin(w * T)
    # forces -> specific forces at the CG, plus what an offset accelerometer also senses
    # the thrust line tilted up by sigma and passing d below the CG
    sigma, d = ac.thrust_angle, ac.thrust_offset
    tx, tz = thrust * np.cos(sigma), -thrust * np.sin(sigma)
    acc = np.column_stack([(fx + tx) / AC.mass, fy / AC.mass, (fz + tz) / AC.mass])
    om, omd, arm = np.column_stack([p, q, r]), np.column_stack([pd, qd, rd]), np.array(lever)
    acc = acc + np.cross(omd, arm) + np.cross(om, np.cross(om, arm))
    # moments from Euler's equations with the product of inertia Ixz
    roll = AC.Ixx * pd - AC.Ixz * (rd + p * q) + (AC.Izz - AC.Iyy) * q * r
    # the engine's gyroscopic moment -omega x h (h along body x) is no aerodynamic one
    h = ac.engine_momentum
    pitch = AC.Iyy * qd + (AC.Ixx - AC.Izz) * p * r + AC.Ixz * (p**2 - r**2) - thrust * d + h * r
    yaw = AC.Izz * rd - AC.Ixz * (pd - q * r) + (AC.Iyy - AC.Ixx) * p * q - h * q
    cx, cz = fx / qs, fz / qs
    truth = {
        "CX": cx,
        "CY": fy / qs,
        "CZ": cz,
        "CL": -cz * np.cos(alpha) + cx * np.sin(alpha),
        "CD": -cx * np.cos(alpha) - cz * np.sin(alpha),
        "Cl": roll / (qs * AC.b),
        "Cm": pitch / (qs * AC.cbar),
        "Cn": yaw / (qs * AC.b),
    }
    chans = {"V": V, "alpha": alpha, "p": p, "q": q, "r": r, "T": thrust}
    chans.update(ax=acc[:, 0], ay=acc[:, 1], az=acc[:, 2], p_dot=pd, q_dot=qd, r_dot=rd)
    return chans, truth


def test_coefficients_match_closed_form() -> None:
    chans, truth = _truth()
    out = coefficients_from_data(FlightData(T, chans), AC, thrust="T")
    for name, value in truth.items():
        np.testing.assert_allclose(out[name], value, rtol=1e-12, atol=1e-14, err_msg=name)
    np.testing.assert_allclose(out["qbar"], 0.5 * 1.1 * chans["V"] ** 2, rtol=1e-14)


def test_a_tilted_offset_thrust_line_is_removed() -> None:
    ac = AircraftConstants(
        mass=AC.mass, Ixx=AC.Ixx, Iyy=AC.Iyy, Izz=AC.Izz, Ixz=AC.Ixz, S=AC.S, b=AC.b,
        cbar=AC.cbar, rho=AC.rho, thrust_angle=0.05, thrust_offset=0.3,
    )  # fmt: skip
    chans, truth = _truth(ac=ac)
    out = coefficients_from_data(FlightData(T, chans), ac, thrust="T")
    for name, value in truth.items():
        np.testing.assert_allclose(out[name], value, rtol=1e-12, atol=1e-14, err_msg=name)
    # the line matters: taken along the x axis through the CG, CZ and Cm are off
    plain = coefficients_from_data(FlightData(T, chans), AC, thrust="T")
    assert np.max(np.abs(plain["Cm"] - truth["Cm"])) > 1e-3
    assert np.max(np.abs(plain["CZ"] - truth["CZ"])) > 1e-3


def test_the_engines_gyroscopic_moment_is_removed() -> None:
    # before: Cm off by h r / (qbar S cbar), 40 % of its variation on a real model's record
    ac = AircraftConstants(
        mass=AC.mass, Ixx=AC.Ixx, Iyy=AC.Iyy, Izz=AC.Izz, Ixz=AC.Ixz, S=AC.S, b=AC.b,
        cbar=AC.cbar, rho=AC.rho, engine_momentum=400.0,
    )  # fmt: skip
    chans, truth = _truth(ac=ac)
    out = coefficients_from_data(FlightData(T, chans), ac, thrust="T")
    for name in ("Cm", "Cn", "Cl"):
        np.testing.assert_allclose(out[name], truth[name], rtol=1e-12, atol=1e-14, err_msg=name)
    plain = coefficients_from_data(FlightData(T, chans), AC, thrust="T")
    assert np.max(np.abs(plain["Cm"] - truth["Cm"])) > 5e-4  # h r / (qbar S cbar)
    assert np.max(np.abs(plain["Cn"] - truth["Cn"])) > 1e-4


def test_accelerometer_offset_and_derived_rates() -> None:
    chans, truth = _truth(lever=(0.8, -0.1, 0.3))
    for k in ("p_dot", "q_dot", "r_dot"):
        del chans[k]
    ac = AircraftConstants(
        mass=AC.mass,
        Ixx=AC.Ixx,
        Iyy=AC.Iyy,
        Izz=AC.Izz,
        Ixz=AC.Ixz,
        S=AC.S,
        b=AC.b,
        cbar=AC.cbar,
        rho=AC.rho,
        accel_position=(0.8, -0.1, 0.3),
    )
    out = coefficients_from_data(FlightData(T, chans), ac, thrust="T")
    assert {"p_dot", "q_dot", "r_dot"} <= set(out.names)
    for name, value in truth.items():
        scale = np.max(np.abs(value))
        # the smoothed angular accelerations are exact here up to round-off
        np.testing.assert_allclose(out[name], value, rtol=0, atol=1e-7 * scale, err_msg=name)
    # ignoring the offset leaves a lever-arm error of the size of omega^2 r / g
    plain = coefficients_from_data(FlightData(T, chans), AC, thrust="T")
    assert np.max(np.abs(plain["CX"] - truth["CX"])) > 1e-3


def test_units_in_g_renamed_channels_and_subset() -> None:
    chans, truth = _truth()
    renamed = {("airspeed" if k == "V" else k): v for k, v in chans.items()}
    for k in ("ax", "ay", "az"):
        renamed[k] = chans[k] / AC.g
    out = coefficients_from_data(
        FlightData(T, renamed),
        AC,
        thrust=chans["T"],
        accel_in_g=True,
        channels={"V": "airspeed"},
        outputs=["CZ", "Cm"],
    )
    np.testing.assert_allclose(out["CZ"], truth["CZ"], rtol=1e-12)
    np.testing.assert_allclose(out["Cm"], truth["Cm"], rtol=1e-12, atol=1e-15)
    assert "CX" not in out and "Cl" not in out


def test_bad_input() -> None:
    chans, _ = _truth()
    data = FlightData(T, {k: v for k, v in chans.items() if k != "q"})
    with pytest.raises(ChannelError, match="'q'"):
        coefficients_from_data(data, AC, outputs=["Cm"])
    with pytest.raises(DataFormatError, match="unknown coefficient"):
        coefficients_from_data(FlightData(T, chans), AC, outputs=["CQ"])
    with pytest.raises(DataFormatError, match="AircraftConstants"):
        coefficients_from_data(FlightData(T, chans), {"mass": 1.0})  # type: ignore[arg-type]
    bad = dict(chans, V=np.zeros(T.size))
    with pytest.raises(DataFormatError, match="airspeed"):
        coefficients_from_data(FlightData(T, bad), AC)
    full = FlightData(T, chans)
    with pytest.raises(DataFormatError, match="outputs: expected coefficient names"):
        coefficients_from_data(full, AC, outputs=5)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match="channels: expected a mapping"):
        coefficients_from_data(full, AC, channels=["V"])  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match=r"thrust: .* got None"):
        coefficients_from_data(full, AC, thrust=None)
    with pytest.raises(DataFormatError, match="thrust: complex"):
        coefficients_from_data(full, AC, thrust=chans["T"] + 1j)
    # one name is one coefficient, not its letters
    assert "CL" in coefficients_from_data(full, AC, outputs="CL", thrust="T")


def test_an_unknown_method_is_refused_though_no_rate_is_differentiated() -> None:
    chans, _ = _truth()  # the record carries p_dot, q_dot and r_dot already
    with pytest.raises(DataFormatError, match="method: expected 'fourier' or 'local'"):
        coefficients_from_data(FlightData(T, chans), AC, thrust="T", method="bogus")


def test_moments_about_the_point_where_the_force_acts_vanish() -> None:
    # an aerodynamic force acting at r (no moment about r) turns the body through
    # M_cg = r x F alone; referred to r, every moment coefficient is zero
    rng = np.random.default_rng(4)
    n = 50
    force = np.column_stack(
        [rng.normal(-800, 50, n), rng.normal(0, 300, n), rng.normal(-9e3, 400, n)]
    )
    r = np.array([1.3, -0.4, 0.6])
    moment = np.cross(r, force)
    inertia = np.array([[AC.Ixx, 0, -AC.Ixz], [0, AC.Iyy, 0], [-AC.Ixz, 0, AC.Izz]])
    omd = np.linalg.solve(inertia, moment.T).T  # at rest: I w_dot = M
    zero = np.zeros(n)
    chans = {"V": np.full(n, 60.0), "alpha": np.full(n, 0.05), "p": zero, "q": zero, "r": zero}
    chans.update(p_dot=omd[:, 0], q_dot=omd[:, 1], r_dot=omd[:, 2])
    chans.update(ax=force[:, 0] / AC.mass, ay=force[:, 1] / AC.mass, az=force[:, 2] / AC.mass)
    data = FlightData(np.arange(n) * DT, chans)
    about_r = coefficients_from_data(data, AC, moment_reference=r)
    about_cg = coefficients_from_data(data, AC)
    qs = 0.5 * AC.rho * 60.0**2 * AC.S
    for name, k, ref in (("Cl", 0, AC.b), ("Cm", 1, AC.cbar), ("Cn", 2, AC.b)):
        np.testing.assert_allclose(about_r[name], 0.0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(about_cg[name], moment[:, k] / (qs * ref), rtol=1e-12)
    # the forces themselves do not move; zero is the centre of gravity, bit for bit
    np.testing.assert_array_equal(about_r["CZ"], about_cg["CZ"])
    same = coefficients_from_data(data, AC, moment_reference=(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(same["Cm"], about_cg["Cm"])


def test_a_density_channel_sets_the_dynamic_pressure() -> None:
    chans, truth = _truth()
    rho = 1.1 * (1.0 + 0.05 * np.sin(np.linspace(0.0, 3.0, T.size)))
    data = FlightData(T, {**chans, "rho": rho})
    out = coefficients_from_data(data, AC, thrust="T", density="rho")
    np.testing.assert_allclose(out["qbar"], 0.5 * rho * chans["V"] ** 2, rtol=1e-14)
    for name, value in truth.items():  # the truth was made with 1.1
        np.testing.assert_allclose(out[name], value * 1.1 / rho, rtol=1e-12, err_msg=name)
    const = coefficients_from_data(FlightData(T, chans), AC, thrust="T", density=1.1)
    np.testing.assert_allclose(const["Cm"], truth["Cm"], rtol=1e-12)


def test_density_and_reference_point_refusals() -> None:
    chans, _ = _truth()
    data = FlightData(T, chans)
    with pytest.raises(DataFormatError, match="density"):
        coefficients_from_data(data, AC, thrust="T", density=-1.0)
    with pytest.raises(ChannelError, match="rho"):
        coefficients_from_data(data, AC, thrust="T", density="rho")
    with pytest.raises(DataFormatError, match="moment_reference"):
        coefficients_from_data(data, AC, thrust="T", moment_reference=(1.0, 2.0))
    with pytest.raises(DataFormatError, match="moment_reference"):
        coefficients_from_data(data, AC, thrust="T", moment_reference=(1.0, np.nan, 0.0))
    moments_only = FlightData(T, {k: chans[k] for k in ("V", "p", "q", "r")})
    with pytest.raises(ChannelError, match="moment_reference"):
        coefficients_from_data(moments_only, AC, outputs=["Cm"], moment_reference=(1.0, 0, 0))


def test_a_longitudinal_record_gives_cm_without_the_lateral_constants() -> None:
    # constants without Ixx, Izz and b (a longitudinal model's) and a record without p
    # and r: Cm = (Iyy q' - T d) / (qbar S cbar), the pitch equation with p = r = 0
    lon = AircraftConstants(
        mass=AC.mass, Iyy=AC.Iyy, S=AC.S, cbar=AC.cbar, rho=AC.rho, thrust_offset=0.1
    )
    chans, truth = _truth()
    record = {k: chans[k] for k in ("V", "alpha", "q", "q_dot", "ax", "az", "T")}
    out = coefficients_from_data(FlightData(T, record), lon, thrust="T")
    assert {"CL", "CD", "Cm"} <= set(out.names) and not {"Cl", "Cn"} & set(out.names)
    qbar = 0.5 * AC.rho * chans["V"] ** 2
    expected = (AC.Iyy * chans["q_dot"] - 0.1 * chans["T"]) / (qbar * AC.S * AC.cbar)
    np.testing.assert_allclose(out["Cm"], expected, rtol=1e-12)
    np.testing.assert_allclose(out["CL"], truth["CL"], rtol=1e-9, atol=1e-12)
    # full constants read the same record the same way (its coupling terms are zero)
    full = coefficients_from_data(FlightData(T, record), AC, outputs=["Cm"])
    np.testing.assert_allclose(full["Cm"], AC.Iyy * chans["q_dot"] / (qbar * AC.S * AC.cbar))


def test_moments_with_roll_and_yaw_rates_name_the_constants_they_lack() -> None:
    lon = AircraftConstants(mass=AC.mass, Iyy=AC.Iyy, S=AC.S, cbar=AC.cbar, rho=AC.rho)
    chans, truth = _truth()
    data = FlightData(T, chans)
    with pytest.raises(ModelDefinitionError, match=r"Ixx, Izz not given, and Cm needs them"):
        coefficients_from_data(data, lon, outputs=["CL", "Cm"], thrust="T")
    with pytest.raises(ModelDefinitionError, match=r"Ixx, Izz, b not given, and Cl, Cn need"):
        coefficients_from_data(data, lon, outputs=["Cl", "Cn"])
    # by default every coefficient the channels and the constants allow: the forces
    out = coefficients_from_data(data, lon, thrust="T")
    assert not {"Cl", "Cm", "Cn"} & set(out.names)
    np.testing.assert_allclose(out["CD"], truth["CD"], rtol=1e-9, atol=1e-12)
