"""Data compatibility with sensors off the centre of gravity and with several records:
seeded recovery of injected sensor errors on simulated flights, closed forms of the
lever-arm terms, and the options' checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _compat_flight import BIASES, simulated_flight, truth
from scipy.integrate import quad

from aeroid import FlightData
from aeroid.errors import DataFormatError, IdentificationError
from aeroid.estimation import _compat_model as cm
from aeroid.estimation.compatibility import check_compatibility

# ATTAS's accelerometer package and nose-boom vanes (Jategaonkar's FVSysID, case 22)
ACCEL = (-1.01, 0.886, 0.103)
BOOM = (13.08, -0.01, -0.027)
GEOMETRY = {"accel_position": ACCEL, "alpha_vane_position": BOOM, "beta_vane_position": BOOM}
INJECTED = {**BIASES, "k_alpha": 0.05}


@pytest.fixture(autouse=True, scope="module")
def _numpy_simulation():
    # as in test_compatibility: the numpy path keeps the fits free of compilation time
    try:
        from aeroid.models import compiled as _compiled
    except ImportError:
        yield
        return
    before = _compiled.ENABLED
    _compiled.ENABLED = False
    yield
    _compiled.ENABLED = before


@pytest.fixture(scope="module")
def off_centre():
    data = simulated_flight(20.0, 25.0, errors=INJECTED, seed=5, **GEOMETRY)
    return data, check_compatibility(data, **GEOMETRY), check_compatibility(data)


def _z(result, truth):
    return {n: (result.parameters[n] - truth.get(n, 0.0)) / result.stderr[n] for n in truth}


def test_sensors_off_the_cg_are_fitted_back_with_their_positions(off_centre):
    _, with_positions, _ = off_centre
    assert with_positions.success and with_positions.identifiable
    for name, z in _z(with_positions, INJECTED).items():
        # ten estimates, one seed: 3.5 sigma leaves a 0.5 % false alarm
        assert abs(z) < 3.5, (name, z)
        assert with_positions.stderr[name] < 0.2 * abs(INJECTED[name]), name


def test_sensors_off_the_cg_bias_the_fit_that_ignores_them(off_centre):
    _, right, wrong = off_centre
    # the 13 m boom turns q into an angle of attack of q x / V: the scale factor and
    # offset of alpha take it, many of the right fit's error bars away from the truth
    for name in ("k_alpha", "b_alpha"):
        assert abs(wrong.parameters[name] - INJECTED[name]) > 10 * right.stderr[name], name


def test_measured_angular_accelerations_stand_in_for_differentiated_rates():
    data = simulated_flight(20.0, 25.0, errors=INJECTED, seed=5, rate_derivatives=True, **GEOMETRY)
    measured = check_compatibility(data, **GEOMETRY)
    plain = FlightData(data.time, {k: v for k, v in data.channels.items() if "_dot" not in k})
    differentiated = check_compatibility(plain, **GEOMETRY)
    for name in INJECTED:
        assert abs(measured.parameters[name] - INJECTED[name]) < 3.5 * measured.stderr[name]
        # the Fourier derivative of the noisy rates moves no estimate by a fifth of a bar
        shift = measured.parameters[name] - differentiated.parameters[name]
        assert abs(shift) < 0.2 * measured.stderr[name], name


def test_flank_angle_vane():
    data = simulated_flight(20.0, 25.0, errors=INJECTED, seed=6, sideslip="atan", **GEOMETRY)
    r = check_compatibility(data, sideslip="atan", **GEOMETRY)
    assert r.success
    for name, z in _z(r, INJECTED).items():
        assert abs(z) < 3.5, (name, z)


def test_zero_positions_are_todays_fit_bit_for_bit():
    data = simulated_flight(12.0, 25.0, errors=INJECTED, seed=3)
    today = check_compatibility(data)
    zero = check_compatibility(
        data,
        accel_position=(0.0, 0.0, 0.0),
        alpha_vane_position=[0, 0, 0],
        beta_vane_position=np.zeros(3),
        sideslip="asin",
    )
    assert zero.parameters == today.parameters
    assert zero.stderr == today.stderr
    np.testing.assert_array_equal(zero.reconstructed, today.reconstructed)
    np.testing.assert_array_equal(zero.covariance, today.covariance)


def _sensor_point(p_extra):
    rng = np.random.default_rng(2)
    K = 30
    x = np.vstack(
        [
            60.0 + rng.standard_normal(K),
            2.0 * rng.standard_normal(K),
            5.0 + rng.standard_normal(K),
            0.3 * rng.standard_normal((3, K)),
            1000.0 + rng.standard_normal(K),
        ]
    )
    c = np.vstack([0.3 * rng.standard_normal((3, K)), rng.standard_normal((3, K)), x])
    p = {n: 0.0 for n in cm.SENSOR_PARAMETERS}
    p.update({f"y0_{o}": 0.0 for o in cm.OUTPUT_CHANNELS})
    p.update({f"m_{s}": 0.0 for s in cm.STATES})
    p.update({"g": 9.80665, "b_p": 0.01, "b_q": -0.02, "b_r": 0.015, **p_extra})
    return x, c, p


def test_vane_angles_are_those_of_the_air_velocity_at_the_vane():
    r_a, r_b = (11.0, -0.5, 0.3), (9.0, 0.7, -0.4)
    geometry = {
        **dict(zip(cm.ALPHA_POSITION, r_a, strict=True)),
        **dict(zip(cm.BETA_POSITION, r_b, strict=True)),
    }
    for sideslip in ("asin", "atan"):
        extra = {**geometry, **({cm._SIDESLIP_ATAN: 1.0} if sideslip == "atan" else {})}
        x, c, p = _sensor_point(extra)
        y = cm._sensors(0.0, x, c, p)
        omega = (c[:3] - np.array([[0.01], [-0.02], [0.015]])).T
        at_a = x[:3].T + np.cross(omega, r_a)
        at_b = x[:3].T + np.cross(omega, r_b)
        np.testing.assert_allclose(y[1], np.arctan2(at_a[:, 2], at_a[:, 0]), rtol=0, atol=1e-14)
        beta = (
            np.arctan2(at_b[:, 1], at_b[:, 0])
            if sideslip == "atan"
            else np.arcsin(at_b[:, 1] / np.linalg.norm(at_b, axis=1))
        )
        np.testing.assert_allclose(y[2], beta, rtol=0, atol=1e-14)
        np.testing.assert_allclose(y[0], np.linalg.norm(x[:3], axis=0), rtol=1e-15)
        # the closed-form sensor Jacobian steps aside for central differences
        assert cm._sensors_jacobian(np.zeros(30), x, c, p, ("b_alpha",)) is None


def test_accelerometer_lever_arm_and_its_jacobian():
    lever = (-1.5, 0.9, 0.4)
    x, c, p = _sensor_point(dict(zip(cm.ACCEL_POSITION, lever, strict=True)))
    _, _, _, AX, AY, AZ = cm._rates(c, p)
    omega = (c[:3] - np.array([[0.01], [-0.02], [0.015]])).T
    centripetal = np.cross(omega, np.cross(omega, lever))
    np.testing.assert_allclose(np.stack([AX, AY, AZ]), c[3:6] - centripetal.T, atol=1e-14)
    names = ("b_p", "b_q", "b_r", "b_ax", "k_q", "g")
    got = cm._kinematics_jacobian(np.zeros(30), x, c, p, names)
    assert got is not None
    _, _, fp, fu = got
    step = 1e-6
    for j in range(6):  # the rates and specific forces
        up, down = c.copy(), c.copy()
        up[j] += step
        down[j] -= step
        diff = (cm._kinematics(0.0, x, up, p) - cm._kinematics(0.0, x, down, p)) / (2 * step)
        np.testing.assert_allclose(fu[:, :, j], diff.T, rtol=1e-6, atol=1e-7)
    for j, n in enumerate(names):
        up, down = dict(p), dict(p)
        up[n] += step
        down[n] -= step
        diff = (cm._kinematics(0.0, x, c, up) - cm._kinematics(0.0, x, c, down)) / (2 * step)
        np.testing.assert_allclose(fp[:, :, j], diff.T, rtol=1e-6, atol=1e-7)


def test_three_records_share_their_sensor_errors():
    setups = ((20.0, 11, 1500.0), (25.0, 12, 1800.0), (15.0, 13, 1200.0))
    records = [simulated_flight(T, 25.0, errors=INJECTED, seed=s, h0=h0) for T, s, h0 in setups]
    results = check_compatibility(records)
    assert isinstance(results, tuple) and len(results) == 3
    first = results[0]
    assert first.success
    for name, z in _z(first, INJECTED).items():
        assert abs(z) < 3.5, (name, z)
    for r, (T, _, h0) in zip(results, setups, strict=True):
        assert r.parameters == first.parameters  # shared
        assert r.time[-1] == pytest.approx(T)
        # each record its own initial state within its bars (the simulation's height
        # starts at h0 a second before the record)
        start = h0 + quad(lambda s: truth(np.atleast_1d(s))["hdot"][0], -1.0, 0.0)[0]
        assert abs(r.initial_states["h"] - start) < 3.5 * r.initial_state_stderr["h"]
    # bars of the air-data errors, which the measurement noise sets, shrink as the
    # square root of the samples (to a quarter); those of the inertial sensors, set
    # here by 40 draws of integrated input noise (22 % scatter on a bar), shrink too
    alone = check_compatibility(records[1])
    ratio = math.sqrt(sum(r.time.size for r in results) / records[1].n_samples)
    for name in INJECTED:
        shrink = alone.stderr[name] / first.stderr[name]
        if name in ("b_V", "b_alpha", "b_beta", "k_alpha"):
            assert 0.75 * ratio < shrink < 1.25 * ratio, name
        else:
            assert 1.0 < shrink < 1.25 * ratio, name


def test_one_record_in_a_list_is_the_single_fit():
    data = simulated_flight(12.0, 25.0, errors=INJECTED, seed=3)
    (listed,) = check_compatibility([data])
    single = check_compatibility(data)
    for name in single.parameter_names:
        assert listed.parameters[name] == pytest.approx(single.parameters[name], rel=1e-9)
        assert listed.stderr[name] == pytest.approx(single.stderr[name], rel=1e-6)


@pytest.fixture(scope="module")
def small():
    return simulated_flight(6.0, 25.0, seed=8)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"accel_position": (1.0, 2.0)}, IdentificationError, r"accel_position.*\(x, y, z\)"),
        ({"alpha_vane_position": (1.0, np.nan, 0.0)}, IdentificationError, "alpha_vane_position"),
        ({"beta_vane_position": "nose"}, IdentificationError, "beta_vane_position"),
        ({"sideslip": "atan2"}, IdentificationError, "sideslip"),
    ],
)
def test_bad_sensor_options_are_named(small, kwargs, error, match):
    with pytest.raises(error, match=match):
        check_compatibility(small, **kwargs)


def test_bad_records_are_named(small):
    with pytest.raises(DataFormatError, match=r"data\[1\]: expected FlightData, got dict"):
        check_compatibility([small, dict(small.channels)])
    with pytest.raises(DataFormatError, match="empty"):
        check_compatibility([])
    with pytest.raises(DataFormatError, match="expected FlightData or a sequence"):
        check_compatibility("flight.csv")
    no_beta = FlightData(small.time, {k: v for k, v in small.channels.items() if k != "beta"})
    with pytest.raises(DataFormatError, match=r"data\[1\].*lacks \['beta'\]"):
        check_compatibility([small, no_beta])
    with pytest.raises(IdentificationError, match="scale_about"):
        check_compatibility([small, small], scale_about="initial")
    assert isinstance(small, FlightData)


@pytest.mark.filterwarnings("ignore::aeroid.errors.ResidualDriftWarning")  # held off-start
def test_initial_states_held_per_record(small):
    other = simulated_flight(6.0, 25.0, seed=9, h0=1900.0)
    starts = [{"h": 1500.5, "u": 45.0}, {"h": 1900.5, "u": 45.0}]
    results = check_compatibility([small, other], estimate=["b_q"], estimate_x0=False, x0=starts)
    for r, given in zip(results, starts, strict=True):
        assert r.initial_states["h"] == given["h"]
        assert r.initial_states["u"] == given["u"]
    with pytest.raises(IdentificationError, match=r"x0: expected one mapping per record \(2\)"):
        check_compatibility([small, other], x0=starts[:1])
