"""Closed-form Jacobians of `aircraft.lateral` (issue 47): the model's own values,
derivatives that central differences confirm, and fits equal to those of the
central-difference path."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import aircraft, shooting
from aeroid.models import compiled as _compiled

TERMS = {
    "CY": ["0", "beta", "r", "delta_r", "beta*delta_a", "abs(beta)"],
    "Cl": ["0", "beta", "p", "r", "delta_a", "delta_r", "beta*beta"],
    "Cn": ["0", "beta", "p", "r", "delta_a", "delta_r", "p*q", "abs(beta)*delta_r"],
}


def _model(heading: bool, flown: bool = False) -> aircraft.AircraftModel:
    c = aircraft.AircraftConstants(
        mass=1200.0,
        Ixx=1500.0,
        Iyy=3000.0,
        Izz=3500.0,
        Ixz=120.0,
        S=16.0,
        b=11.0,
        cbar=1.5,
        rho=1.1,
        engine_momentum=30.0,
        accel_position=(0.3, 0.1, -0.2),
        beta_vane_position=(1.5, 0.0, 0.3),
    )
    outputs = ["beta", "p", "r", "phi", "p_dot", "r_dot", "ay"] + (["psi"] if heading else [])
    return aircraft.lateral(
        c,
        V0=50.0,
        alpha0=0.05,
        theta0=0.08,
        terms={**TERMS, "Cn": [*TERMS["Cn"], "r*V", "V"]} if flown else TERMS,
        outputs=outputs,
        surfaces=("delta_a", "delta_r", "q", "V") if flown else ("delta_a", "delta_r", "q"),
        with_heading=heading,
        accel_units="g",
    )


@pytest.mark.parametrize(("heading", "flown"), [(False, False), (True, False), (False, True)])
def test_lateral_closed_form_matches_central_differences(heading: bool, flown: bool) -> None:
    # flown: the model takes the flown airspeed V as an input (q̄, b/2V, β̇, the vane)
    model = _model(heading, flown)
    rng = np.random.default_rng(0)
    p = {k: float(0.3 * rng.standard_normal()) for k in model.parameters}
    n_x, K = len(model.states), 30
    x = 0.2 * rng.standard_normal((n_x, K))
    u = 0.1 * rng.standard_normal((len(model.controls), K))
    if flown:
        u[3] = 50.0 + 5.0 * rng.standard_normal(K)
    t = np.zeros(K)
    names = tuple(model.parameters)
    for batch in (model._dynamics_batch, model._measurement_batch):
        assert batch is not None and batch.jacobian is not None
        got = batch.jacobian(t, x, u, p, names)
        assert got is not None
        f, fx, fp, fu = got
        assert np.array_equal(f, batch.fun(t, x, u, p))  # the model's own values

        def central(kind: str, key, h: float = 1e-5, fun=batch.fun) -> np.ndarray:
            def at(step: float) -> np.ndarray:
                xx, uu, pp = x.copy(), u.copy(), dict(p)
                if kind == "x":
                    xx[key] += step
                elif kind == "u":
                    uu[key] += step
                else:
                    pp[key] += step
                return np.asarray(fun(t, xx, uu, pp))

            return ((at(h) - at(-h)) / (2.0 * h)).T

        # slopes up to ~200: central differences of step 1e-5 carry ~1e-8 of them
        # (truncation of the quadratic terms cancels, rounding ~1e-11 / 1e-5 of the
        # values), well inside 1e-7 relative
        for i in range(n_x):
            np.testing.assert_allclose(fx[:, :, i], central("x", i), rtol=1e-7, atol=1e-7)
        for i in range(u.shape[0]):
            np.testing.assert_allclose(fu[:, :, i], central("u", i), rtol=1e-7, atol=1e-7)
        for c, name in enumerate(names):
            np.testing.assert_allclose(fp[:, :, c], central("p", name), rtol=1e-7, atol=1e-7)
        # a name that is not a coefficient: central differences instead
        assert batch.jacobian(t, x, u, p, ("not_a_coefficient",)) is None


def test_lateral_fit_equals_the_differences_path(monkeypatch) -> None:
    monkeypatch.setattr(_compiled, "BACKGROUND", False)
    truth = _model(False)
    rng = np.random.default_rng(4)
    values = {k: float(0.2 * rng.standard_normal()) for k in truth.parameters}
    values.update(Cl_p=-0.5, Cn_r=-0.15, Cl_beta=-0.08, Cn_beta=0.07, CY_beta=-0.6)
    values.update(Cl_delta_a=0.12, Cn_delta_r=-0.08, Cl_r=0.1, Cn_p=-0.03)
    t = np.arange(601) * 0.02
    da = 0.05 * np.sign(np.sin(2 * np.pi * t / 2.0)) * (t < 5)
    dr = 0.05 * np.sign(np.sin(2 * np.pi * t / 2.7)) * ((t > 4) & (t < 9))
    u = np.column_stack([da, dr, 0.02 * np.sin(1.3 * t)])
    sim = truth.simulate(t, u, np.zeros(4), values, method="rk4", substeps=1)
    noise = np.array([0.002, 0.005, 0.005, 0.003, 0.05, 0.05, 0.003])
    y = sim.outputs + noise * rng.standard_normal(sim.outputs.shape)
    channels = {o: y[:, j] for j, o in enumerate(truth.outputs)}
    channels.update(delta_a=da, delta_r=dr, q=u[:, 2])
    data = aeroid.FlightData(time=t, channels=channels)
    guess = {k: 0.8 * v for k, v in values.items()}
    fits = {}
    calls: list[int] = []
    for way in ("differences", "exact"):
        model = _model(False)  # a model of its own: its first fit, in numpy
        shooting._RECENT.clear()
        exact_form = model._dynamics_batch.jacobian
        if way == "differences":
            model._dynamics_batch.jacobian = None
            assert model._measurement_batch is not None
            model._measurement_batch.jacobian = None
        else:
            model._dynamics_batch.jacobian = lambda *a, f=exact_form: calls.append(1) or f(*a)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fits[way] = aeroid.identify(model, data, guess, x0=dict.fromkeys(model.states, 0.0))
    assert calls  # the second fit took the closed forms
    exact, diff = fits["exact"], fits["differences"]
    # the same optimum: the Jacobians differ by ~1e-9 relative and the iterations stop at
    # a relative step far inside the error bars
    for n in values:
        assert abs(exact.parameters[n] - diff.parameters[n]) <= 1e-3 * exact.standard_errors[n]
        assert exact.standard_errors[n] == pytest.approx(diff.standard_errors[n], rel=1e-4)


@pytest.mark.parametrize("flown", [False, True])
def test_lateral_models_at_two_trims_share_one_compiled_structure(flown: bool) -> None:
    # the trim's numbers (V0, the density's q̄ S, b/2V0) are lifted out of the JAX
    # program: two flight conditions of one structure compile once, flown airspeed or not
    from aeroid.models import _jax_translation

    a = _model(False, flown)
    b = aircraft.lateral(
        dataclasses.replace(a.constants, rho=0.9),
        V0=35.0,
        alpha0=0.09,
        theta0=0.1,
        terms={**TERMS, "Cn": [*TERMS["Cn"], "r*V", "V"]} if flown else TERMS,
        outputs=["beta", "p", "r", "phi", "p_dot", "r_dot", "ay"],
        surfaces=("delta_a", "delta_r", "q", "V") if flown else ("delta_a", "delta_r", "q"),
        accel_units="g",
    )
    ka = _jax_translation._structure(a)["key"]
    kb = _jax_translation._structure(b)["key"]
    assert ka is not None and ka == kb
    consts_a = _jax_translation._structure(a)["consts"]
    consts_b = _jax_translation._structure(b)["consts"]
    assert not np.array_equal(consts_a, consts_b)  # the trims differ in the lifted numbers
