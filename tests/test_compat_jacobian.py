"""Closed-form Jacobians of the data-compatibility kinematics and sensors (issue 47):
the same values, derivatives that central differences confirm, and fits equal to
those of the central-difference path."""

from __future__ import annotations

import warnings
from collections.abc import Iterator

import numpy as np
import pytest
from _compat_flight import BIASES, simulated_flight

from aeroid.estimation import _compat_model as cm
from aeroid.estimation.compatibility import check_compatibility
from aeroid.models import _rk4_grid, shooting
from aeroid.models import compiled as _compiled

MASKS = {
    "none": (0.0,) * 7,
    "u, theta, h measured": (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0),
}
NAMES = (
    *(f"{e}_{c}" for e in ("b", "k") for c in cm.INPUT_CHANNELS),
    *(f"{e}_{o}" for e in ("b", "k") for o in cm.OUTPUT_CHANNELS),
    "w_n",
    "w_e",
    "w_d",
    "g",
)
POINTS = {
    "no wind": (MASKS["none"], (0.0, 0.0, 0.0)),
    "measured states": (MASKS["u, theta, h measured"], (0.0, 0.0, 0.0)),
    "wind": (MASKS["none"], (6.0, -4.0, 1.5)),
}


def _point(
    masks: tuple[float, ...], wind: tuple[float, ...] = (0.0, 0.0, 0.0), seed: int = 1
) -> tuple[np.ndarray, np.ndarray, dict]:
    """States, controls and parameters at 40 scattered points of a manoeuvring flight."""
    rng = np.random.default_rng(seed)
    K = 40
    x = np.vstack(
        [
            60.0 + 5.0 * rng.standard_normal(K),
            3.0 * rng.standard_normal(K),
            5.0 + 2.0 * rng.standard_normal(K),
            0.4 * rng.standard_normal((3, K)),
            1000.0 + 10.0 * rng.standard_normal(K),
        ]
    )
    u = np.vstack([0.2 * rng.standard_normal((3, K)), rng.standard_normal((3, K))])
    u = np.vstack([u, x + 0.1 * rng.standard_normal(x.shape)])
    p = {n: 0.0 for n in cm.SENSOR_PARAMETERS}
    for n in NAMES[:-4]:
        p[n] = 0.05 * rng.standard_normal()
    p.update(zip(cm._WIND, wind, strict=True))
    p["g"] = 9.80665
    p.update({f"m_{s}": m for s, m in zip(cm.STATES, masks, strict=True)})
    p.update({f"y0_{o}": 0.1 * rng.standard_normal() for o in cm.OUTPUT_CHANNELS})
    return x, u, p


@pytest.mark.parametrize("point", list(POINTS.values()), ids=list(POINTS))
@pytest.mark.parametrize(
    ("fun", "jacobian"),
    [(cm._kinematics, cm._kinematics_jacobian), (cm._sensors, cm._sensors_jacobian)],
    ids=["kinematics", "sensors"],
)
def test_closed_form_matches_central_differences(point, fun, jacobian) -> None:
    x, u, p = _point(*point)
    t = np.zeros(x.shape[1])
    got = jacobian(t, x, u, p, NAMES)
    assert got is not None
    f, fx, fp, fu = got
    # the values are the model's own, to the bit
    assert np.array_equal(f, fun(t, x, u, p))

    def central(kind: str, key, h: float) -> np.ndarray:
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

    # a relative step of 1e-5: truncation ~1e-10 and rounding ~1e-11 of the slopes
    # (values of order 1e3 at most), far below the 1e-7 allowed
    for i in range(x.shape[0]):
        h = 1e-5 * max(1.0, float(np.max(np.abs(x[i]))))
        np.testing.assert_allclose(fx[:, :, i], central("x", i, h), rtol=1e-7, atol=1e-7)
    for i in range(u.shape[0]):
        h = 1e-5 * max(1.0, float(np.max(np.abs(u[i]))))
        np.testing.assert_allclose(fu[:, :, i], central("u", i, h), rtol=1e-7, atol=1e-7)
    for c, name in enumerate(NAMES):
        np.testing.assert_allclose(fp[:, :, c], central("p", name, 1e-5), rtol=1e-7, atol=1e-7)


def test_sensors_leave_time_shifts_to_differences() -> None:
    x, u, p = _point(MASKS["none"])
    t = np.zeros(x.shape[1])
    assert cm._sensors_jacobian(t, x, u, p, ("b_V",)) is not None
    assert cm._sensors_jacobian(t, x, u, {**p, "tau_alpha": 0.01}, ("b_V",)) is None
    assert cm._sensors_jacobian(t, x, u, p, ("tau_alpha",)) is None
    assert cm._kinematics_jacobian(t, x, u, p, ("m_u",)) is None
    # the kinematics read no output error and no wind: zero columns
    got = cm._kinematics_jacobian(t, x, u, p, ("tau_alpha", "w_n", "b_V"))
    assert got is not None and not np.any(got[2])


@pytest.fixture
def numpy_fits() -> Iterator[None]:
    """Every fit in numpy by Newton's method over the record, none compiled."""
    before = _compiled.BACKGROUND
    _compiled.BACKGROUND = False
    yield
    _compiled.BACKGROUND = before


def _nominal(masks: tuple[float, ...]) -> tuple[tuple[str, float], ...]:
    p = {n: 0.0 for n in cm.SENSOR_PARAMETERS}
    p["g"] = 9.80665
    p.update({f"m_{s}": m for s, m in zip(cm.STATES, masks, strict=True)})
    p.update({f"y0_{o}": 0.0 for o in cm.OUTPUT_CHANNELS})
    return tuple(sorted(p.items()))


def _record() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = simulated_flight(12.0, 25.0, errors=dict(BIASES), seed=3)
    names = [*cm.INPUT_CHANNELS]
    u = np.column_stack([data.channels[c] for c in names] + [np.zeros(data.time.size)] * 7)
    V, a, b = (data.channels[c][0] for c in ("V", "alpha", "beta"))
    x0 = np.array(
        [
            V * np.cos(a) * np.cos(b),
            V * np.sin(b),
            V * np.sin(a) * np.cos(b),
            *(data.channels[c][0] for c in ("phi", "theta", "psi", "h")),
        ]
    )
    return data.time, u, x0


def test_rk4_step_jacobians_match_the_differences() -> None:
    t, u, x0 = _record()
    model = cm._model(_nominal(MASKS["none"]))
    p = dict(model.parameters)
    grid = _rk4_grid._grid(model, t, u, 2)
    ks = np.arange(grid.n)
    X = np.repeat(x0[:, None], grid.n, axis=1) + 0.1 * np.sin(np.arange(grid.n))[None, :]
    names = ("b_p", "b_q", "b_r", "b_ax", "b_ay", "b_az", "k_q")
    active = [0, 1, 2, 3, 4, 5]
    got = _rk4_grid._tangent_steps(cm._kinematics_jacobian, grid, ks, X, p, names, active)
    assert got is not None
    nxt, T = got
    # the same RK4 steps as the batched dynamics take
    f = model._dynamics_batch
    assert np.array_equal(nxt, _rk4_grid._steps(f, grid, ks, X, shooting._columns(p, ks.size), 1))
    keep, f.jacobian = f.jacobian, None
    try:
        # steps so large that rounding (1e-16 of states up to 1e3, over the step)
        # stays below 1e-8 of the slopes, the truncation of these near-linear
        # columns below that
        hx = 1e-5 * np.maximum(np.max(np.abs(X), axis=1), 1e-3)
        hp = np.full(len(names), 1e-4)
        hu = np.zeros(u.shape[1])
        hu[active] = 1e-4 * np.maximum(np.max(np.abs(u[:, active]), axis=0), 1e-3)
        _, A, B, C = shooting._linearised(f, grid, ks, X.T, p, hx, names, hp, hu)
    finally:
        f.jacobian = keep
    # within 1e-6 of each column's scale
    n_x = X.shape[0]
    for exact, diff in ((T[:, :, :n_x], A), (T[:, :, n_x : n_x + 7], B), (T[:, :, n_x + 7 :], C)):
        scale = np.max(np.abs(exact), axis=(0, 1))
        assert np.all(np.abs(exact - diff) <= 1e-6 * scale + 1e-12)


def test_sensitivities_equal_the_differences_path(monkeypatch) -> None:
    t, u, x0 = _record()
    nominal = _nominal(MASKS["none"])
    names = ["b_p", "b_q", "b_r", "b_ax", "b_ay", "b_az", "b_V", "k_alpha"]
    free = [0, 1, 2, 3, 4]
    p = dict(nominal)
    steps = 1e-6 * np.ones(len(names) + len(free))
    got = {}
    for way in ("differences", "exact"):
        cm._model.cache_clear()
        shooting._RECENT.clear()
        with monkeypatch.context() as mp:
            if way == "differences":
                mp.setattr(cm, "_kinematics_jacobian", lambda *a: None)
                mp.setattr(cm, "_sensors_jacobian", lambda *a: None)
            model = cm._model(nominal)
            got[way] = shooting.output_sensitivities(model, t, u, x0, p, names, free, 2, steps)
    cm._model.cache_clear()
    exact, diff = got["exact"], got["differences"]
    assert exact is not None and diff is not None
    # the same RK4 rollout (Newton settles each to 1e-8 of the states' range)
    scale_y = np.ptp(exact[0], axis=0) + 1e-3
    assert np.all(np.abs(exact[0] - diff[0]) <= 1e-7 * scale_y)
    scale_j = np.max(np.abs(exact[1]), axis=0)
    assert np.all(np.abs(exact[1] - diff[1]) <= 1e-5 * scale_j + 1e-12)


WIND_ESTIMATE = ["b_p", "b_q", "b_r", "b_V", "b_alpha", "b_beta", "w_n", "w_e", "w_d"]
CASES = {
    # (injected errors, estimated, flight options, analysis options)
    "sensor errors": ({**BIASES, "k_V": 0.02, "k_alpha": 0.08}, None, {}, {}),
    # the sensors' closed form leaves time shifts to differences: the kinematics' stays
    "time shift": ({**BIASES, "tau_alpha": 0.05}, None, {}, {}),
    "measured states": (
        {"b_q": 0.002, "b_ax": 0.15, "b_az": 0.2, "b_V": 1.0, "b_alpha": 0.02, "k_alpha": 0.08},
        None,
        {},
        {"outputs": ["V", "alpha", "theta"], "measured_states": ["v", "phi", "psi"]},
    ),
    "wind": (
        {"b_p": 0.003, "b_V": 1.0, "b_alpha": 0.02},
        WIND_ESTIMATE,
        {"wind": (6.0, -4.0, 0.5), "gps": True},
        {},
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_fit_equals_the_differences_path(case, numpy_fits, monkeypatch) -> None:
    errors, estimate, flight, options = CASES[case]
    estimate = estimate or list(errors)
    data = simulated_flight(20.0, 25.0, errors=errors, seed=5, **flight)
    calls: list[int] = []
    exact_form = cm._kinematics_jacobian
    got = {}
    for way in ("differences", "exact"):
        # a model of its own: each fit is its first, in numpy (Newton over the record)
        cm._model.cache_clear()
        shooting._RECENT.clear()
        with monkeypatch.context() as mp:
            if way == "differences":
                mp.setattr(cm, "_kinematics_jacobian", lambda *a: None)
                mp.setattr(cm, "_sensors_jacobian", lambda *a: None)
            else:
                mp.setattr(cm, "_kinematics_jacobian", lambda *a: calls.append(1) or exact_form(*a))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got[way] = check_compatibility(
                    data, estimate=estimate, error_bars="white", **options
                )
    cm._model.cache_clear()
    assert calls  # the second fit took the closed forms
    exact, diff = got["exact"], got["differences"]
    assert exact.n_passes == diff.n_passes
    # both converge on the same optimum: the Jacobians differ by ~1e-9 relative, the
    # iterations stop at a relative step of 1e-6, far inside the error bars
    for n in estimate:
        assert abs(exact.parameters[n] - diff.parameters[n]) <= 1e-3 * exact.stderr[n]
        assert exact.stderr[n] == pytest.approx(diff.stderr[n], rel=1e-4)
