"""AeroSandbox adapter: a genuine Model from AeroBuildup tables, trimmed, with recoverable scales."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog

asb = pytest.importorskip("aerosandbox")

from aeroid.adapters.aerosandbox import aerosandbox_model  # noqa: E402


def _airplane(cg_x: float = 0.08):
    """A small trainer: cambered wing, symmetric tail with an elevator, CG at 27 % MAC."""
    wing_af, tail_af = asb.Airfoil("naca2412"), asb.Airfoil("naca0010")
    return asb.Airplane(
        name="trainer",
        xyz_ref=[cg_x, 0.0, 0.0],
        wings=[
            asb.Wing(
                name="wing",
                symmetric=True,
                xsecs=[
                    asb.WingXSec(xyz_le=[0.0, 0.0, 0.0], chord=0.3, airfoil=wing_af),
                    asb.WingXSec(xyz_le=[0.02, 1.0, 0.05], chord=0.2, airfoil=wing_af),
                ],
            ),
            asb.Wing(
                name="htail",
                symmetric=True,
                xsecs=[
                    asb.WingXSec(
                        xyz_le=[1.0, 0.0, 0.0],
                        chord=0.18,
                        airfoil=tail_af,
                        control_surfaces=[
                            asb.ControlSurface(name="elevator", symmetric=True, hinge_point=0.7)
                        ],
                    ),
                    asb.WingXSec(xyz_le=[1.02, 0.4, 0.0], chord=0.12, airfoil=tail_af),
                ],
            ),
        ],
    )


KW = dict(mass=3.0, Iyy=1.5, velocity=20.0, altitude=100.0)


@pytest.fixture(scope="module")
def airplane():
    return _airplane()


@pytest.fixture(scope="module")
def model(airplane):
    # a small table keeps AeroBuildup quick: 2 deg in alpha, 5 deg in elevator
    return aerosandbox_model(
        airplane, **KW, alpha_range=(-4.0, 10.0), n_alpha=8, elevator_range=(-10, 10), n_elevator=5
    )


def _manoeuvre(model, duration=4.0):
    trim = model.dynamics.trim
    t = np.arange(round(duration * 50) + 1) / 50.0
    u = trim["elevator"] + catalog.doublet(t, start=0.5, width=0.5, amplitude=np.radians(2.0))
    return t, u, [trim[s] for s in model.states]


def test_returns_a_genuine_trimmed_model(model):
    assert isinstance(model, aeroid.Model)
    assert model.states == ("V", "alpha", "q", "theta")
    assert model.controls == ("elevator",)
    assert set(model.parameters) == {"CL_scale", "CD_scale", "Cm_scale", "CL_q", "Cm_q", "thrust"}
    assert model.parameters["Cm_q"] < 0  # the tail damps pitch
    trim = model.dynamics.trim
    t = np.linspace(0.0, 2.0, 51)
    x0 = [trim[s] for s in model.states]
    steady = model.simulate(t, np.full(t.size, trim["elevator"]), x0)
    np.testing.assert_allclose(steady.states, np.tile(x0, (t.size, 1)), atol=1e-9)
    assert model.parameters["thrust"] == pytest.approx(trim["thrust"])


def test_tables_are_aerobuildup_values(model, airplane):
    dyn = model.dynamics
    i, j = 3, 1
    deflected = airplane.with_control_deflections({"elevator": float(dyn.elevator_deg[j])})
    aero = asb.AeroBuildup(
        airplane=deflected,
        op_point=asb.OperatingPoint(
            atmosphere=asb.Atmosphere(altitude=100.0), velocity=20.0, alpha=float(dyn.alpha_deg[i])
        ),
    ).run()
    cl, cd, cm = dyn.coefficients(np.radians(dyn.alpha_deg[i]), np.radians(dyn.elevator_deg[j]))
    assert float(cl) == pytest.approx(float(np.ravel(aero["CL"])[0]), rel=1e-9)
    assert float(cd) == pytest.approx(float(np.ravel(aero["CD"])[0]), rel=1e-9)
    assert float(cm) == pytest.approx(float(np.ravel(aero["Cm"])[0]), rel=1e-9)
    # bilinear in between: the midpoint of a cell is the mean of its corners
    a = np.radians(dyn.alpha_deg[i : i + 2].mean())
    d = np.radians(dyn.elevator_deg[j : j + 2].mean())
    assert float(dyn.coefficients(a, d)[2]) == pytest.approx(dyn.Cm[i : i + 2, j : j + 2].mean())
    # the same function evaluates a batch (states of shape (n, batch))
    x = np.tile(np.array([20.0, 0.02, 0.1, 0.03])[:, None], (1, 3))
    p = {k: np.full(3, v) for k, v in model.parameters.items()}
    batch = model.dynamics(0.0, x, np.zeros((1, 3)), p)
    single = model.dynamics(0.0, x[:, 0], np.zeros(1), dict(model.parameters))
    np.testing.assert_allclose(batch, np.tile(single[:, None], (1, 3)), rtol=1e-14)


def test_injected_coefficient_scales_are_recovered(model):
    t, u, x0 = _manoeuvre(model)
    truth = {"CL_scale": 1.08, "CD_scale": 0.9, "Cm_scale": 0.95}
    data = model.simulate(t, u, x0, truth, method="rk4", substeps=8).to_flight_data()
    result = aeroid.identify(model, data, list(truth))
    for name, value in truth.items():
        assert result.parameters[name] == pytest.approx(value, rel=2e-2), name


def test_jax_paths_reject_the_table_model_clearly(model):
    pytest.importorskip("jax")
    t, u, x0 = _manoeuvre(model, duration=0.2)
    with pytest.raises(aeroid.AdapterError, match=r"jax\.numpy"):
        aeroid.simulate_rk4(model, t, u, x0)


def test_bad_arguments(airplane):
    with pytest.raises(aeroid.AdapterError, match=r"no control surface 'flap'.*elevator"):
        aerosandbox_model(airplane, **KW, elevator="flap")
    with pytest.raises(aeroid.AdapterError, match="mass"):
        aerosandbox_model(airplane, **{**KW, "mass": -1.0})
    with pytest.raises(aeroid.AdapterError, match=r"aerosandbox.Airplane"):
        aerosandbox_model("cessna", **KW)
    with pytest.raises(aeroid.AdapterError, match="alpha_range"):
        aerosandbox_model(airplane, **KW, alpha_range=(5.0, -5.0))
    with pytest.raises(aeroid.AdapterError, match="n_elevator"):
        aerosandbox_model(airplane, **KW, n_elevator=1)


def test_no_trim_inside_the_tables_is_reported(airplane):
    with pytest.raises(aeroid.AdapterError, match="no level-flight trim"):
        aerosandbox_model(
            airplane, **{**KW, "mass": 40.0}, alpha_range=(-2.0, 4.0), n_alpha=2, n_elevator=2
        )


def test_missing_aerosandbox_names_the_extra(monkeypatch, airplane):
    monkeypatch.setitem(sys.modules, "aerosandbox", None)
    with pytest.raises(aeroid.AdapterError, match=r'pip install "aeroid\[aerosandbox\]"'):
        aerosandbox_model(airplane, **KW)
