"""The fixed-gain (steady-state) filter error for nonlinear models: the linear case
reduces to the linear filter, and the option is checked."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from numpy.typing import NDArray
from test_filter_error import NAMES, NOISE, _turbulent_flight

import aeroid
from aeroid import IdentificationError, Model
from aeroid.estimation._filter_steady import steady_pass
from aeroid.estimation.filtering import build_problem, run_filter
from aeroid.models import catalog
from aeroid.models.catalog import _short_period_dynamics

FloatArray = NDArray[np.float64]

PROCESS = {"q": 1e-3}


def _as_nonlinear(model: Model) -> Model:
    """The same dynamics declared nonlinear: RK4 moves the state, differences linearise."""
    return Model(
        states=list(model.states),
        controls=list(model.controls),
        parameters=dict(model.parameters),
        dynamics=_short_period_dynamics,
        name="short_period_declared_nonlinear",
        linear=False,
    )


@pytest.fixture(scope="module")
def turbulent() -> aeroid.FlightData:
    return _turbulent_flight(5, PROCESS["q"])


def _fit(model: Model, data: aeroid.FlightData, **options: object) -> aeroid.IdentificationResult:
    return aeroid.identify(
        model,
        data,
        NAMES,
        method="filter_error",
        process_noise=PROCESS,
        measurement_noise=NOISE,
        filter_options={"substeps": 8, **options},
        tolerance=1e-9,
    )


def test_on_a_linear_model_it_is_the_linear_filter_error(turbulent):
    linear = catalog.short_period()
    exact = _fit(linear, turbulent, gain="time_varying")
    # declared nonlinear, the model goes through RK4 propagation, a difference
    # Jacobian at the record's start and the fixed-gain Riccati solution
    steady = _fit(_as_nonlinear(linear), turbulent, gain="steady")
    assert exact.success and steady.success
    for n in NAMES:
        assert steady.parameters[n] == pytest.approx(exact.parameters[n], rel=1e-6)
        assert steady.stderr[n] == pytest.approx(exact.stderr[n], rel=1e-4)
    assert steady.cost == pytest.approx(exact.cost, rel=1e-9)
    # the default for an affine model is the same linear filter
    default = _fit(linear, turbulent)
    assert default.parameters == pytest.approx(exact.parameters, rel=1e-12)


def test_innovations_and_their_covariance_match_the_linear_pass(turbulent):
    linear = catalog.short_period()
    B = 3
    params = {k: np.array([v, 0.9 * v, 1.1 * v]) for k, v in linear.parameters.items()}
    Qc = np.repeat(np.diag([0.0, PROCESS["q"]])[None], B, axis=0)
    args = dict(outputs=None, measurement_noise=NOISE, x0=None, P0=None, substeps=16, method="ekf")
    runs = []
    for model in (linear, _as_nonlinear(linear)):
        prob, R = build_problem(
            model, turbulent, ukf=(1e-3, 2.0, 0.0), error=IdentificationError, **args
        )
        x0 = np.repeat(prob.x0[None], B, axis=0)
        P0 = np.repeat(prob.P0[None], B, axis=0)
        Rb = np.repeat(R[None], B, axis=0)
        if model is linear:
            runs.append(run_filter(prob, params, Qc, Rb, x0, P0))
        else:
            runs.append(steady_pass(prob, params, Qc, Rb, x0, P0))
    exact, steady = runs
    assert np.all(steady.ok)
    scale = np.sqrt(np.diagonal(exact.S, axis1=2, axis2=3))
    assert np.max(np.abs(steady.nu - exact.nu) / scale) < 1e-7
    # the gain is taken as converged once it changes by 1e-10 a step
    assert np.max(np.abs(steady.S - exact.S) / (scale[..., :, None] * scale[..., None, :])) < 1e-8
    # after the transient, the steady state: the discrete algebraic Riccati equation's
    dt = float(turbulent.time[1] - turbulent.time[0])
    H = np.eye(2)
    R = np.diag([NOISE["alpha"], NOISE["q"]])
    for b in range(B):
        p = {k: v[b] for k, v in params.items()}
        A = np.array([[p["Z_alpha"], 1.0], [p["M_alpha"], p["M_q"]]])
        M = np.zeros((4, 4))
        M[:2, :2], M[:2, 2:], M[2:, 2:] = -A, Qc[b], A.T
        E = scipy.linalg.expm(M * dt)
        Phi = E[2:, 2:].T
        Qd = Phi @ E[:2, 2:]
        P = scipy.linalg.solve_discrete_are(Phi.T, H.T, 0.5 * (Qd + Qd.T), R)
        np.testing.assert_allclose(steady.S[b, -1], H @ P @ H.T + R, rtol=1e-8)


def test_gain_option_is_checked(turbulent):
    model = catalog.short_period()
    with pytest.raises(IdentificationError, match=r"filter_options\['gain'\].*'fixed'"):
        _fit(model, turbulent, gain="fixed")
    with pytest.raises(IdentificationError, match=r"gain='steady'.*ukf"):
        _fit(model, turbulent, gain="steady", method="ukf")
    with pytest.raises(IdentificationError, match="unknown options"):
        _fit(model, turbulent, filter_gain="steady")


def test_the_compiled_predictor_is_the_numpy_one(monkeypatch):
    from aeroid.models import compiled as _compiled

    model, prob, args = _lateral_problem(8.0, np.array([1e-5, 1e-3, 1e-4, 0.0]))
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    compiled = steady_pass(*args)
    assert ("steady_predictor", prob.out_idx) in _compiled._shared(model)  # it ran
    monkeypatch.setattr(_compiled, "ENABLED", False)
    plain = steady_pass(*args)
    assert np.all(compiled.ok) and np.all(plain.ok)
    np.testing.assert_allclose(compiled.nu, plain.nu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(compiled.xf, plain.xf, rtol=0, atol=1e-12)


def test_the_start_simulation_is_the_compiled_rollout(monkeypatch):
    """`start_states` (the states a filter-error fit picks its starting process noise
    from) is the compiled rollout, the RK4 of `simulate(method="rk4")` to rounding,
    where the fit's passes compile its predictor; None for a small problem or
    linear dynamics."""
    from _aircraft_data import BASE, LAT

    from aeroid.estimation._filter_steady import start_states
    from aeroid.models import compiled as _compiled
    from aeroid.models.aircraft import AircraftConstants, lateral

    model = lateral(AircraftConstants(**BASE, Ixz=80.0, rho=1.225), V0=53.6, parameters=LAT)
    t = np.arange(0.0, 6.0, 0.02)
    controls = {
        "delta_a": catalog.doublet(t, start=1.0, amplitude=0.1),
        "delta_r": catalog.doublet(t, start=3.0, amplitude=0.1),
    }
    clean = model.simulate(t, controls, substeps=2)
    outputs = ["beta", "p", "r", "phi"]
    data = aeroid.FlightData(t, {**controls, **{o: clean.output(o) for o in outputs}})
    prob, _ = build_problem(
        model,
        data,
        outputs=outputs,
        measurement_noise=dict.fromkeys(outputs, 1e-5),
        x0=None,
        P0=None,
        substeps=2,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=IdentificationError,
    )
    values = {k: 1.1 * v for k, v in model.parameters.items()}
    Qc = np.zeros((4, 4))
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 10**12)  # a small problem
    assert start_states(prob, values, Qc) is None
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    states = start_states(prob, values, Qc)
    assert states is not None
    sim = model.simulate(t, controls, x0=prob.x0, parameters=values, substeps=2, method="rk4")
    np.testing.assert_allclose(states, sim.states, rtol=0, atol=1e-12)
    assert np.ptp(states[:, 1]) > 0.01  # the doublets moved it
    # linear dynamics: the simulation is exact, and the fit's filter the linear one
    linear = catalog.short_period()
    lin_data = catalog.short_period_flight(seed=0)
    lin_prob, _ = build_problem(
        linear,
        lin_data,
        outputs=None,
        measurement_noise=NOISE,
        x0=None,
        P0=None,
        substeps=None,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=IdentificationError,
    )
    assert start_states(lin_prob, dict(linear.parameters), np.zeros((2, 2))) is None


def test_a_known_settled_sample_gives_the_same_likelihood():
    """`innovation_loglik(settled=k)` (a fixed-gain pass knows where S stops changing)
    equals the search for it, and the full sum over every sample."""
    from aeroid.estimation.filtering import innovation_loglik

    rng = np.random.default_rng(3)
    B, K, m = 3, 60, 2
    A = rng.standard_normal((B, K, m, m))
    S = A @ np.swapaxes(A, 2, 3) + np.eye(m)
    S[:, 20:] = S[:, 20:21]
    nu = rng.standard_normal((B, K, m))
    quad = np.einsum("bki,bkij,bkj->b", nu, np.linalg.inv(S), nu)
    logdet = np.sum(np.linalg.slogdet(S)[1], axis=1)
    for settled in (None, 20, 40):
        q, ld = innovation_loglik(nu, S, settled=settled)
        np.testing.assert_allclose(q, quad, rtol=1e-12)
        np.testing.assert_allclose(ld, logdet, rtol=1e-12)


def _lateral_problem(duration: float, process: FloatArray) -> tuple:
    """A lateral model (nonlinear: it compiles) on a doublet record, and the arguments of
    a pass of three members."""
    from _aircraft_data import BASE, LAT

    from aeroid.models.aircraft import AircraftConstants, lateral

    model = lateral(AircraftConstants(**BASE, Ixz=80.0, rho=1.225), V0=53.6, parameters=LAT)
    t = np.arange(0.0, duration, 0.02)
    rng = np.random.default_rng(1)
    controls = {
        "delta_a": catalog.doublet(t, start=1.0, amplitude=0.1),
        "delta_r": catalog.doublet(t, start=4.0, amplitude=0.1),
    }
    clean = model.simulate(t, controls)
    outputs = ["beta", "p", "r", "phi"]
    data = aeroid.FlightData(
        t,
        {**controls, **{o: clean.output(o) + 0.003 * rng.standard_normal(t.size) for o in outputs}},
    )
    prob, R = build_problem(
        model,
        data,
        outputs=outputs,
        measurement_noise=dict.fromkeys(outputs, 1e-5),
        x0=None,
        P0=None,
        substeps=None,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=IdentificationError,
    )
    B = 3
    params = {k: v * np.array([1.0, 0.9, 1.1]) for k, v in model.parameters.items()}
    Qc = np.repeat(np.diag(process)[None], B, axis=0)
    args = (
        prob,
        params,
        Qc,
        np.repeat(R[None], B, axis=0),
        np.repeat(prob.x0[None], B, axis=0),
        np.repeat(prob.P0[None], B, axis=0),
    )
    return model, prob, args


def test_a_long_transient_takes_the_next_gain_buffer(monkeypatch):
    """A gain that settles after the first buffer's samples: the compiled predictor takes
    a larger buffer (four times 128 samples of gains here, the steady one from where it
    settled) and is still the numpy predictor; without the states recorded the
    innovations and their covariances are the same."""
    from aeroid.estimation import _filter_steady
    from aeroid.models import compiled as _compiled

    # little process noise: the gain settles after some 400 samples
    model, prob, args = _lateral_problem(12.0, np.array([1e-6, 1e-4, 1e-5, 1e-7]))
    monkeypatch.setattr(_filter_steady, "_GAIN_SAMPLES", 128)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    compiled = steady_pass(*args)
    assert ("steady_predictor", prob.out_idx) in _compiled._shared(model)  # it ran
    assert compiled.settled is not None
    assert _filter_steady._GAIN_SAMPLES < compiled.settled < prob.time.size - 1
    lean = steady_pass(*args, states=False)
    np.testing.assert_array_equal(lean.nu, compiled.nu)
    np.testing.assert_array_equal(lean.S, compiled.S)
    assert np.all(np.isnan(lean.xf))
    monkeypatch.setattr(_compiled, "ENABLED", False)
    plain = steady_pass(*args)
    assert np.all(compiled.ok) and np.all(plain.ok)
    np.testing.assert_allclose(compiled.nu, plain.nu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(compiled.xf, plain.xf, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(compiled.S, plain.S)
    # the gain buffer sizes: a few shapes whatever the flight
    assert [_filter_steady._capacity(k, 1000) for k in (2, 128, 129, 300, 600, 999)] == [
        128,
        128,
        256,
        512,
        1000,
        1000,
    ]
    # a record of at most four buffers takes one shape, whatever its transient
    assert {_filter_steady._capacity(k, 512) for k in (2, 128, 129, 300, 511)} == {512}


def test_a_nonlinear_model_is_checked_for_linearity_once():
    """A pass that finds the dynamics not affine remembers it on the model (as
    `simulate` does), so a fit's later passes skip the check."""
    model, _, args = _lateral_problem(4.0, np.array([1e-5, 1e-3, 1e-4, 0.0]))
    assert model._maybe_lti
    first = steady_pass(*args)
    assert not model._maybe_lti
    again = steady_pass(*args)
    np.testing.assert_array_equal(first.nu, again.nu)


def test_forward_substitution_is_the_triangular_solve():
    """The likelihood's whitening, row by row over a stack of Cholesky factors, equals
    a triangular solve of each (factors with sub-diagonal entries larger than their
    diagonal included, where a pivoting solver would swap rows)."""
    from aeroid.estimation.filtering import _forward_substitution

    rng = np.random.default_rng(7)
    A = rng.standard_normal((3, 40, 5, 5))
    S = A @ np.swapaxes(A, 2, 3) + 0.01 * np.eye(5)
    L = np.linalg.cholesky(S)
    assert np.any(np.abs(L[..., 1:, 0]) > L[..., :1, 0])
    b = rng.standard_normal((3, 40, 5))
    z = _forward_substitution(L, b)
    for i in range(3):
        for k in range(40):
            expect = scipy.linalg.solve_triangular(L[i, k], b[i, k], lower=True)
            np.testing.assert_allclose(z[i, k], expect, rtol=1e-10, atol=1e-12)


def test_newton_schulz_inverses_reach_the_inverse_to_rounding():
    """`_inverse` refined from a nearby inverse (the Riccati recursion's last step) agrees
    with LAPACK's inverse to rounding (the residual's square each step, three steps at most
    from a residual of 1e-2); from a start too far off it is LAPACK's inverse itself."""
    from aeroid.estimation._filter_steady import _inverse

    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 5, 5))
    S = A @ np.swapaxes(A, 1, 2) + 0.5 * np.eye(5)
    exact = np.linalg.inv(S)
    eye = np.eye(5)
    for rel in (1e-3, 1e-6, 1e-10):
        # the last step's S, each entry off by `rel` of S's scale: its inverse starts
        near = S + rel * np.abs(S).max() * rng.uniform(-1.0, 1.0, S.shape)
        near = 0.5 * (near + np.swapaxes(near, 1, 2))
        got = _inverse(S, np.linalg.inv(near), eye)
        scale = np.abs(exact).max(axis=(1, 2), keepdims=True)
        cond = np.linalg.cond(S).max()
        assert np.max(np.abs(got - exact) / scale) < 50 * cond * np.finfo(float).eps
    far = _inverse(S, np.linalg.inv(2.0 * S), eye)  # residual 1/2: inverted afresh
    np.testing.assert_array_equal(far, exact)
    np.testing.assert_array_equal(_inverse(S, None, eye), exact)
