"""RocketPy adapter: builder-parameterised flights, sampling, and a recovered drag scale.

Everything runs offline: a standard-atmosphere `Environment` and a motor
defined from a thrust-curve array built here.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

import aeroid

rocketpy = pytest.importorskip("rocketpy")

from aeroid.adapters.rocketpy import RocketpyModel, rocketpy_flight_data  # noqa: E402

ENV = rocketpy.Environment(latitude=0.0, longitude=0.0, elevation=0.0)  # ISA, no download
MOTOR = rocketpy.GenericMotor(
    thrust_source=np.array([[0.0, 0.0], [0.05, 300.0], [1.5, 250.0], [2.0, 0.0]]),
    burn_time=2.0,
    chamber_radius=0.03,
    chamber_height=0.3,
    chamber_position=0.0,
    propellant_initial_mass=0.4,
    nozzle_radius=0.02,
    dry_mass=0.5,
    center_of_dry_mass_position=0.0,
    dry_inertia=(0.01, 0.01, 0.001),
    nozzle_position=-0.15,
    coordinate_system_orientation="nozzle_to_combustion_chamber",
)


def build(params, max_time=4.0):
    """A 2 kg sounding rocket whose constant drag coefficient is scaled by ``drag_scale``."""
    cd = 0.5 * params["drag_scale"]
    rocket = rocketpy.Rocket(
        radius=0.04,
        mass=2.0,
        inertia=(0.3, 0.3, 0.002),
        power_off_drag=cd,
        power_on_drag=cd,
        center_of_mass_without_motor=0.6,
        coordinate_system_orientation="tail_to_nose",
    )
    rocket.add_motor(MOTOR, position=0.0)
    rocket.add_nose(length=0.2, kind="vonKarman", position=1.2)
    rocket.add_trapezoidal_fins(n=4, root_chord=0.12, tip_chord=0.06, span=0.08, position=0.15)
    return rocketpy.Flight(
        rocket=rocket,
        environment=ENV,
        rail_length=2.0,
        inclination=85.0,
        heading=0.0,
        rtol=1e-9,
        atol=1e-9,
        max_time=max_time,
        terminate_on_apogee=True,
    )


@pytest.fixture(scope="module")
def model():
    return RocketpyModel(
        build,
        parameters={"drag_scale": 1.0},
        outputs={"altitude_m": "altitude", "vz_m_s": "vz"},
        flight_options={"max_time": 4.0},
        name="sounding_rocket",
    )


TIME = np.arange(1, 9) * 0.5  # 0.5 ... 4 s: boost and early coast, where drag matters


def test_is_a_simulator_model_and_deterministic(model):
    assert isinstance(model, aeroid.SimulatorModel)
    assert model.controls == () and model.outputs == ("altitude_m", "vz_m_s")
    a = model.simulate(TIME, None, None, {"drag_scale": 1.2})
    b = model.simulate(TIME, None, None, {"drag_scale": 1.2}, method="RK45")  # accepted, no effect
    assert np.array_equal(a.outputs, b.outputs)
    flight = build({"drag_scale": 1.2})
    np.testing.assert_allclose(a.output("altitude_m"), flight.altitude(TIME), rtol=1e-12)
    assert np.all(np.diff(a.output("altitude_m")) > 0)  # still climbing


@pytest.mark.slow
def test_injected_drag_scale_is_recovered(model):
    truth = 1.15
    data = model.simulate(TIME, None, None, {"drag_scale": truth}).to_flight_data()
    result = aeroid.identify(model, data, ["drag_scale"])
    assert result.parameters["drag_scale"] == pytest.approx(truth, rel=3e-2)


def test_callable_outputs_and_flight_data():
    flight = build({"drag_scale": 1.0})
    data = rocketpy_flight_data(flight, sample_rate=5.0)
    assert data.names == ("altitude", "vz", "speed", "az")
    assert data.units["altitude"] == "m" and data.units["vz"] == "m/s"
    np.testing.assert_allclose(data.time, np.arange(21) * 0.2, atol=1e-12)  # t_final = max_time = 4
    np.testing.assert_allclose(data["vz"], flight.vz(data.time), rtol=1e-12)
    assert data.metadata["source"] == "rocketpy"
    custom = rocketpy_flight_data(
        flight,
        time=[0.5, 1.0, 2.0],
        channels={"h_ft": lambda f, t: f.altitude(t) / 0.3048, "q_Pa": "dynamic_pressure"},
        units={"h_ft": "ft"},
    )
    np.testing.assert_allclose(custom["h_ft"], flight.altitude([0.5, 1.0, 2.0]) / 0.3048)
    assert dict(custom.units) == {"h_ft": "ft", "q_Pa": "Pa"}


def test_errors_are_named(model):
    with pytest.raises(aeroid.SimulationError, match=r"leaves the flight's span"):
        model.simulate([1.0, 2.0, 9.0])
    with pytest.raises(aeroid.SimulationError, match="no states"):
        model.simulate(TIME, None, [0.0])
    with pytest.raises(aeroid.SimulationError, match="'mass'"):
        model.simulate(TIME, None, None, {"mass": 3.0})
    with pytest.raises(aeroid.AdapterError, match="valid options"):
        model.simulate(TIME, bogus=True)
    with pytest.raises(aeroid.AdapterError, match="no time function 'altitud'"):
        RocketpyModel(build, {"drag_scale": 1.0}, {"h": "altitud"}).simulate(TIME)

    def broken(params):
        raise ValueError("no motor")

    with pytest.raises(aeroid.SimulationError, match=r"builder.*no motor"):
        RocketpyModel(broken, {"drag_scale": 1.0}, {"h": "altitude"}).simulate(TIME)
    with pytest.raises(aeroid.AdapterError, match=r"not a rocketpy.Flight"):
        RocketpyModel(lambda p: 42, {"k": 1.0}, {"h": "altitude"}).simulate(TIME)
    with pytest.raises(aeroid.AdapterError, match="outputs"):
        RocketpyModel(build, {"drag_scale": 1.0}, {})
    with pytest.raises(aeroid.AdapterError, match="sample_rate"):
        rocketpy_flight_data(build({"drag_scale": 1.0}), sample_rate=0.0)


def test_missing_rocketpy_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rocketpy", None)
    with pytest.raises(aeroid.AdapterError, match=r'pip install "aeroid\[rocketpy\]"'):
        RocketpyModel(build, {"drag_scale": 1.0}, {"h": "altitude"})
