"""Kalman filtering and RTS smoothing, pinned to closed forms and seeded truths."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import pytest
import scipy.linalg

import aeroid
from aeroid import FilterError, FlightData, Model
from aeroid.estimation.filtering import (
    FilterResult,
    _chol,
    _Failure,
    build_problem,
    filter_states,
    run_filter,
)
from aeroid.models import catalog

NOISE = {"alpha": 0.005**2, "q": 0.01**2}


def _scalar_model(a: float) -> Model:
    return Model(
        states=["x"], controls=[], parameters={"a": a}, dynamics=lambda t, x, u, p: p["a"] * x
    )


def _scalar_riccati(a: float, q: float, r: float, dt: float) -> tuple[float, float]:
    """Steady-state prior and posterior variance of x' = a x + w (PSD q), y_k = x_k + v_k (var r).

    Exact discretisation: phi = e^{a dt}, Qd = q (e^{2 a dt} - 1) / (2 a). The prior
    variance solves M = phi^2 M r / (M + r) + Qd, i.e.
    M^2 + M (r (1 - phi^2) - Qd) - Qd r = 0 (positive root); posterior = M r / (M + r).
    """
    phi = math.exp(a * dt)
    qd = q * (math.exp(2 * a * dt) - 1) / (2 * a)
    b = r * (1 - phi**2) - qd
    prior = 0.5 * (-b + math.sqrt(b * b + 4 * qd * r))
    return prior, prior * r / (prior + r)


def _turbulent_flight(
    seed: int, s_q: float, duration: float = 10.0
) -> tuple[FlightData, np.ndarray]:
    """Truth-case flight with white process noise (PSD s_q) on q, sampled exactly.

    The system is linear, so the response is the noise-free simulation plus the
    exactly discretised stochastic part (x_k = Phi x_{k-1} + w_k, w_k ~ N(0, Qd)).
    """
    truth = catalog.SHORT_PERIOD_TRUTH
    clean = catalog.short_period_flight(noise={}, duration=duration)
    t = clean.time
    A = np.array([[truth["Z_alpha"], 1.0], [truth["M_alpha"], truth["M_q"]]])
    M = np.zeros((4, 4))
    M[:2, :2] = -A
    M[:2, 2:] = np.diag([0.0, s_q])
    M[2:, 2:] = A.T
    E = scipy.linalg.expm(M * (t[1] - t[0]))
    phi = E[2:, 2:].T
    qd = phi @ E[:2, 2:]
    lq = np.linalg.cholesky(0.5 * (qd + qd.T))
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((t.size, 2)) @ lq.T
    xs = np.zeros((t.size, 2))
    for k in range(1, t.size):
        xs[k] = phi @ xs[k - 1] + w[k]
    x = np.column_stack([clean["alpha"], clean["q"]]) + xs
    y = x + rng.standard_normal((t.size, 2)) * np.array([0.005, 0.01])
    data = FlightData(t, {"elevator": clean["elevator"], "alpha": y[:, 0], "q": y[:, 1]})
    return data, x


# -- closed forms -----------------------------------------------------------------------


@pytest.mark.parametrize("linear", [None, False])
def test_ekf_steady_state_equals_scalar_riccati(linear):
    a, q, r, dt = -1.5, 0.04, 0.01, 0.02
    model = _scalar_model(a)
    t = np.arange(401) * dt
    y = np.random.default_rng(1).standard_normal(t.size) * 0.1  # covariances ignore the data
    data = FlightData(t, {"x": y})
    prior, post = _scalar_riccati(a, q, r, dt)
    if linear is None:  # public path (exact discretisation, constant matrices)
        res = filter_states(
            model, data, process_noise={"x": q}, measurement_noise={"x": r}, smooth=False
        )
        P, S = res.filtered_covariance[-1, 0, 0], res.innovation_covariance[-1, 0, 0]
    else:  # general path: RK4 state propagation, Van Loan on the local Jacobian
        prob, R = build_problem(
            model,
            data,
            outputs=None,
            measurement_noise={"x": r},
            x0=None,
            P0=None,
            substeps=None,
            method="ekf",
            ukf=(1e-3, 2.0, 0.0),
            error=FilterError,
        )
        run = run_filter(
            prob,
            {"a": np.array([a])},
            np.array([[[q]]]),
            R[None],
            prob.x0[None],
            prob.P0[None],
            linear=False,
        )
        P, S = run.Pf[0, -1, 0, 0], run.S[0, -1, 0, 0]
    assert P == pytest.approx(post, rel=1e-3)
    assert S == pytest.approx(prior + r, rel=1e-3)


def test_without_process_noise_the_filter_is_recursive_least_squares():
    # x' = 0: the state is a constant observed n times; its variance after n
    # measurements (prior P0) is 1 / (1/P0 + n/r).
    model = _scalar_model(0.0)
    t = np.arange(51) * 0.1
    data = FlightData(t, {"x": np.ones(t.size)})
    res = filter_states(
        model, data, process_noise=None, measurement_noise=[0.04], P0=[1.0], smooth=True
    )
    n = np.arange(t.size)
    assert res.filtered_covariance[:, 0, 0] == pytest.approx(1 / (1 / 1.0 + n / 0.04), rel=1e-9)
    # smoothing a constant: every sample gets the information of the whole record
    assert res.state_std("x") ** 2 == pytest.approx(np.full(t.size, 1 / (1 + 50 / 0.04)), rel=1e-9)


def test_ukf_equals_ekf_on_a_linear_system(sp_noisy, sp_truth):
    kw = dict(process_noise={"alpha": 1e-4, "q": 1e-3}, measurement_noise=NOISE)
    ekf = filter_states(catalog.short_period(), sp_noisy, sp_truth, method="ekf", **kw)
    ukf = filter_states(catalog.short_period(), sp_noisy, sp_truth, method="ukf", **kw)
    for name in (
        "filtered_states",
        "filtered_covariance",
        "smoothed_states",
        "smoothed_covariance",
        "innovations",
        "innovation_covariance",
    ):
        a, b = getattr(ekf, name), getattr(ukf, name)
        assert np.max(np.abs(a - b)) <= 1e-6 * np.max(np.abs(a)), name
    assert ukf.log_likelihood == pytest.approx(ekf.log_likelihood, rel=1e-6)


def test_general_path_matches_exact_linear_path(sp_noisy, sp_truth):
    """RK4 + local linearisation (used for nonlinear models) agrees with the exact LTI filter."""
    prob, R = build_problem(
        catalog.short_period(),
        sp_noisy,
        outputs=None,
        measurement_noise=NOISE,
        x0=None,
        P0=None,
        substeps=None,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=FilterError,
    )
    p = {k: np.array([v]) for k, v in sp_truth.items()}
    Qc = np.diag([1e-4, 1e-3])[None]
    ref = run_filter(prob, p, Qc, R[None], prob.x0[None], prob.P0[None])
    for method in ("ekf", "ukf"):
        run = run_filter(
            prob, p, Qc, R[None], prob.x0[None], prob.P0[None], method=method, linear=False
        )
        assert np.max(np.abs(run.xf - ref.xf)) <= 1e-6 * np.max(np.abs(ref.xf))
        assert np.max(np.abs(run.Pf - ref.Pf)) <= 1e-6 * np.max(np.abs(ref.Pf))


# -- statistics of a correctly specified filter --------------------------------------------------


def test_innovations_are_white_with_unit_variance(sp_truth):
    s_q = 3e-3
    data, x = _turbulent_flight(seed=3, s_q=s_q, duration=40.0)
    res = filter_states(
        catalog.short_period(), data, sp_truth, process_noise={"q": s_q}, measurement_noise=NOISE
    )
    n = data.time.size - 1
    for name in ("alpha", "q"):
        z = res.normalized_innovation(name)[1:]
        # mean of z^2 has standard deviation sqrt(2/n) for white unit-variance z
        assert abs(np.mean(z**2) - 1) < 4 * math.sqrt(2 / n)
        # sample autocorrelations of white noise have standard deviation 1/sqrt(n)
        zc = z - z.mean()
        r = np.array([zc[:-k] @ zc[k:] for k in range(1, 21)]) / (zc @ zc)
        assert np.max(np.abs(r)) < 4 / math.sqrt(n)
    assert abs(res.normalized_innovation_variance - 1) < 4 * math.sqrt(1 / n)
    # the smoother beats the filter, and its 2-sigma band covers about 95 %
    for j, name in enumerate(("alpha", "q")):
        err_f = res.state(name) - x[:, j]
        err_s = res.smoothed_state(name) - x[:, j]
        assert np.sqrt(np.mean(err_s**2)) < np.sqrt(np.mean(err_f**2))
        assert np.all(res.state_std(name) <= np.sqrt(res.filtered_covariance[:, j, j]) * (1 + 1e-9))
        cover = np.mean(np.abs(err_s) < 2 * res.state_std(name))
        assert 0.85 < cover < 1.0  # errors are strongly correlated in time: loose band


def test_log_likelihood_prefers_the_true_noise_level(sp_truth):
    data, _ = _turbulent_flight(seed=4, s_q=3e-3, duration=20.0)
    ll = {
        s: filter_states(
            catalog.short_period(),
            data,
            sp_truth,
            process_noise={"q": s},
            measurement_noise=NOISE,
            smooth=False,
        ).log_likelihood
        for s in (3e-4, 3e-3, 3e-2)
    }
    assert ll[3e-3] > ll[3e-4] and ll[3e-3] > ll[3e-2]


# -- nonlinear models ---------------------------------------------------------------------


def _pendulum(broadcast: bool = True) -> Model:
    def f(t, x, u, p):
        return np.array([x[1], -p["w2"] * np.sin(x[0]) - p["c"] * x[1] + u[0]])

    def f_loop(t, x, u, p):  # written for one point only: exercises the loop fallback
        return [float(x[1]), -p["w2"] * math.sin(float(x[0])) - p["c"] * float(x[1]) + float(u[0])]

    def h(t, x, u, p):
        return np.array([np.sin(x[0])])

    return Model(
        states=["th", "om"],
        controls=["tau"],
        parameters={"w2": 4.0, "c": 0.3},
        dynamics=f if broadcast else f_loop,
        outputs=["s"],
        measurement=h,
        name="pendulum",
    )


def _pendulum_data(seed: int = 0) -> tuple[FlightData, np.ndarray]:
    model = _pendulum()
    t = np.arange(301) * 0.02
    u = np.zeros(t.size)
    sim = model.simulate(t, u, x0=[0.8, 0.0])
    rng = np.random.default_rng(seed)
    y = sim.output("s") + 0.02 * rng.standard_normal(t.size)
    return FlightData(t, {"tau": u, "s": y}), sim.states


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_nonlinear_model_with_measurement_function(method):
    data, x = _pendulum_data()
    res = filter_states(
        _pendulum(),
        data,
        process_noise={"om": 1e-4},
        measurement_noise={"s": 0.02**2},
        method=method,
        x0={"th": 0.7, "om": 0.0},
        P0=[0.05, 0.05],
    )
    err = res.smoothed_state("th") - x[:, 0]
    assert np.sqrt(np.mean(err[50:] ** 2)) < 0.01  # well below the 0.02 sensor noise
    z = res.normalized_innovation("s")[1:]
    assert abs(np.mean(z**2) - 1) < 4 * math.sqrt(2 / z.size) + 0.1  # linearisation error allowance


def test_non_broadcasting_dynamics_give_the_same_estimates():
    data, _ = _pendulum_data()
    kw = dict(
        process_noise={"om": 1e-4},
        measurement_noise={"s": 0.02**2},
        x0=[0.7, 0.0],
        P0=[0.05, 0.05],
        smooth=False,
        substeps=2,
    )
    a = filter_states(_pendulum(True), data, **kw)
    b = filter_states(_pendulum(False), data, **kw)
    np.testing.assert_allclose(a.filtered_states, b.filtered_states, rtol=1e-10, atol=1e-12)


# -- the record -----------------------------------------------------------------------------


def test_result_record(sp_noisy, sp_truth):
    res = filter_states(
        catalog.short_period(),
        sp_noisy,
        sp_truth,
        process_noise=[1e-8, 1e-8],
        measurement_noise=np.diag([0.005**2, 0.01**2]),
    )
    assert isinstance(res, FilterResult)
    assert aeroid.filter_states is filter_states and aeroid.FilterResult is FilterResult
    assert res.state("alpha").shape == res.time.shape
    assert np.all(np.isfinite(res.normalized_innovation("q")))
    for arr in (
        res.filtered_states,
        res.smoothed_states,
        res.innovations,
        res.state("q"),
        res.state_std("q"),
    ):
        with pytest.raises(ValueError):
            arr[0] = 1.0
    with pytest.raises(TypeError):
        res.parameters["M_q"] = 0.0  # type: ignore[index]
    # storable: only plain values, strings, mappings and arrays
    for name, value in vars(res).items():
        assert isinstance(value, (str, int, float, tuple, np.ndarray, type(None))) or hasattr(
            value, "items"
        ), name
    text = res.summary()
    assert "| output" in text and "log-likelihood" in text and "Ljung" in text
    assert res.parameters["M_q"] == sp_truth["M_q"]
    # smoothing off: state_std is the filtered one and smoothed_state refuses
    res2 = filter_states(
        catalog.short_period(),
        sp_noisy,
        sp_truth,
        process_noise=[1e-8, 1e-8],
        measurement_noise=NOISE,
        smooth=False,
    )
    np.testing.assert_allclose(res2.state_std("alpha") ** 2, res2.filtered_covariance[:, 0, 0])
    with pytest.raises(FilterError, match="smooth=False"):
        res2.smoothed_state("alpha")
    with pytest.raises(aeroid.ChannelError, match="not a model state"):
        res2.state("beta")


def test_parameters_from_a_result_object(sp_noisy, sp_truth):
    class Fit:
        parameters: ClassVar[dict[str, float]] = dict(sp_truth)

    a = filter_states(
        catalog.short_period(), sp_noisy, Fit(), process_noise=None, measurement_noise=NOISE
    )
    b = filter_states(
        catalog.short_period(), sp_noisy, sp_truth, process_noise=None, measurement_noise=NOISE
    )
    assert a.log_likelihood == b.log_likelihood


def test_outputs_subset(sp_noisy, sp_truth):
    res = filter_states(
        catalog.short_period(),
        sp_noisy,
        sp_truth,
        process_noise=None,
        measurement_noise={"q": 0.01**2},
        outputs=["q"],
    )
    assert res.output_names == ("q",)
    assert res.innovations.shape == (sp_noisy.time.size, 1)


# -- errors ----------------------------------------------------------------------------------


class _Stepped:
    """A SimulatorModel look-alike (no dynamics callable)."""

    name = "box"
    controls = ("elevator",)
    outputs = ("q",)
    parameters: ClassVar[dict[str, float]] = {"k": 1.0}

    def simulate(self, time, controls=None, x0=None, parameters=None, **options):
        raise NotImplementedError

    def simulate_data(self, data, *, x0=None, parameters=None, **options):
        raise NotImplementedError


def test_errors(sp_noisy):
    model = catalog.short_period()
    kw = dict(process_noise=None, measurement_noise=NOISE)
    with pytest.raises(FilterError, match="continuous dynamics"):
        filter_states(_Stepped(), sp_noisy, **kw)
    with pytest.raises(FilterError, match="method"):
        filter_states(model, sp_noisy, method="pf", **kw)
    with pytest.raises(FilterError, match=r"measurement_noise.*q"):
        filter_states(model, sp_noisy, process_noise=None, measurement_noise={"alpha": 1e-4})
    with pytest.raises(FilterError, match=r"positive .*'q' is 0\.0"):
        filter_states(
            model, sp_noisy, process_noise=None, measurement_noise={"alpha": 1e-4, "q": 0.0}
        )
    with pytest.raises(FilterError, match=r"process_noise.*unknown"):
        filter_states(model, sp_noisy, process_noise={"beta": 1.0}, measurement_noise=NOISE)
    with pytest.raises(FilterError, match=r"non-negative .*'q' is -1\.0"):
        filter_states(model, sp_noisy, process_noise={"q": -1.0}, measurement_noise=NOISE)
    with pytest.raises(FilterError, match="2 values"):
        filter_states(model, sp_noisy, process_noise=[1.0, 2.0, 3.0], measurement_noise=NOISE)
    with pytest.raises(FilterError, match="x0"):
        filter_states(model, sp_noisy, x0=[0.0], **kw)
    with pytest.raises(FilterError, match="parameter"):
        filter_states(model, sp_noisy, {"nope": 1.0}, **kw)
    with pytest.raises(FilterError, match="outputs"):
        filter_states(model, sp_noisy, outputs=["beta"], **kw)
    with pytest.raises(FilterError, match="ukf_alpha"):
        filter_states(model, sp_noisy, method="ukf", ukf_alpha=0.0, **kw)
    with pytest.raises(aeroid.ChannelError, match="elevator"):
        filter_states(
            model, FlightData(sp_noisy.time, {"alpha": sp_noisy["alpha"], "q": sp_noisy["q"]}), **kw
        )


def test_divergence_names_the_sample():
    blow = Model(
        states=["x"],
        controls=[],
        parameters={},
        dynamics=lambda t, x, u, p: x * (1.0 if np.all(np.asarray(t) < 0.5) else np.inf),
    )
    t = np.arange(51) * 0.02
    data = FlightData(t, {"x": np.ones(t.size)})
    with pytest.raises(FilterError, match=r"sample 25 \(t = 0.5 s\)"):
        filter_states(blow, data, process_noise=[1.0], measurement_noise=[1.0], substeps=1)


def test_cholesky_jitter_then_failure():
    stats = [0]
    nearly = np.array([[[1.0, 1.0], [1.0, 1.0 - 1e-15]]])  # indefinite by rounding
    L = _chol(nearly, 7, "test", stats)
    assert stats[0] == 1 and np.allclose(L @ L.transpose(0, 2, 1), nearly, atol=1e-9)
    with pytest.raises(_Failure) as info:
        _chol(np.array([[[1.0, 0.0], [0.0, -1.0]]]), 7, "test", stats)
    assert info.value.k == 7


def test_noise_matrices_must_be_symmetric_positive_semidefinite(sp_noisy):
    model = catalog.short_period()
    with pytest.raises(
        FilterError, match=r"process_noise: the matrix must be symmetric, but \[0, 1\] = 2"
    ):
        filter_states(model, sp_noisy, process_noise=[[1, 2], [0, 1]], measurement_noise=NOISE)
    with pytest.raises(
        FilterError, match=r"process_noise: must be non-negative .* smallest eigenvalue is -1"
    ):
        filter_states(model, sp_noisy, process_noise=[[1, 2], [2, 1]], measurement_noise=NOISE)
    with pytest.raises(FilterError, match=r"measurement_noise: the matrix must be symmetric"):
        filter_states(
            model, sp_noisy, process_noise=None, measurement_noise=[[1e-4, 1e-5], [0.0, 1e-4]]
        )
    # asymmetry at rounding level, relative to the matrix's scale, is no error
    q = np.array([[1e-8, 3e-9], [3e-9 * (1 + 1e-14), 2e-8]])
    res = filter_states(model, sp_noisy, process_noise=q, measurement_noise=NOISE, smooth=False)
    np.testing.assert_array_equal(res.process_noise, 0.5 * (q + q.T))


@pytest.mark.parametrize("model", [None, "short_period"])
def test_a_model_is_required(sp_noisy, model):
    with pytest.raises(FilterError, match=r"model: .*continuous dynamics.* got (NoneType|str)"):
        filter_states(model, sp_noisy, process_noise=None, measurement_noise=NOISE)


# -- fast linear filter and compiled propagation (issue 28) ---------------------------------


def _fast_and_stepped(monkeypatch, *args, **kwargs):
    """filter_states through the block Riccati solution and through the step loop."""
    import aeroid.estimation.filtering as filtering

    used = []
    fast = filtering._riccati_fast

    def spy(*a):
        out = fast(*a)
        used.append(out is not None)
        return out

    monkeypatch.setattr(filtering, "_riccati_fast", spy)
    a = filter_states(*args, **kwargs)
    monkeypatch.setattr(filtering, "_riccati_fast", lambda *a: None)
    b = filter_states(*args, **kwargs)
    return a, b, used


@pytest.mark.parametrize(
    "q, r",
    [(1e-8, 1.0), (1e-8, 1e-4), (3e-3, 1.0), (1.0, 1e-2), (1e-12, 1e-8), (30.0, 1.0)],
)
def test_block_riccati_filter_equals_the_step_loop(monkeypatch, sp_noisy, sp_truth, q, r):
    # slowly converging (tiny process noise: hundreds of samples of transient) and fast
    # converging gains both take the block path and give the step loop's results
    a, b, used = _fast_and_stepped(
        monkeypatch,
        catalog.short_period(),
        sp_noisy,
        sp_truth,
        process_noise={"alpha": q, "q": q},
        measurement_noise={"alpha": r * 0.005**2, "q": r * 0.01**2},
    )
    assert used == [True]
    for name in (
        "filtered_states",
        "filtered_covariance",
        "smoothed_states",
        "smoothed_covariance",
        "innovations",
        "innovation_covariance",
    ):
        x, y = getattr(a, name), getattr(b, name)
        scale = np.max(np.abs(y), axis=0)
        assert np.all(np.abs(x - y) <= 1e-10 * scale), name
    assert a.log_likelihood == pytest.approx(b.log_likelihood, rel=1e-12)


def test_block_riccati_reaches_the_scalar_steady_state(monkeypatch):
    a_, q, r, dt = -0.7, 0.3, 0.05, 0.01
    t = np.arange(2001) * dt
    data = FlightData(t, {"x": np.random.default_rng(2).standard_normal(t.size) * math.sqrt(r)})
    a, b, used = _fast_and_stepped(
        monkeypatch,
        _scalar_model(a_),
        data,
        process_noise={"x": q},
        measurement_noise={"x": r},
        x0=[0.0],
        P0=[1.0],
    )
    assert used == [True]
    prior, post = _scalar_riccati(a_, q, r, dt)
    assert a.filtered_covariance[-1, 0, 0] == pytest.approx(post, rel=1e-12)
    assert a.innovation_covariance[-1, 0, 0] == pytest.approx(prior + r, rel=1e-12)
    np.testing.assert_allclose(a.filtered_states, b.filtered_states, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.smoothed_covariance, b.smoothed_covariance, rtol=1e-10)


@pytest.mark.parametrize("K", [1, 2, 5, 16, 17, 101])
@pytest.mark.parametrize("quadratic", [False, True])
def test_affine_scan_equals_the_loop(K, quadratic):
    from aeroid.estimation.filtering import _affine_scan

    rng = np.random.default_rng(K)
    B, n = 2, 3
    M = rng.standard_normal((B, K, n, n)) / 2.0
    c = rng.standard_normal((B, K, n, n) if quadratic else (B, K, n))
    x0 = rng.standard_normal((B, n, n) if quadratic else (B, n))
    got = _affine_scan(M, c, x0, quadratic=quadratic)
    x = x0
    for k in range(K):
        if quadratic:
            x = M[:, k] @ x @ np.swapaxes(M[:, k], 1, 2) + c[:, k]
        else:
            x = np.einsum("bij,bj->bi", M[:, k], x) + c[:, k]
        np.testing.assert_allclose(got[:, k], x, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_compiled_propagation_equals_numpy(monkeypatch, method):
    from aeroid.models import compiled as _compiled

    if not _compiled.available(
        _pendulum(),
        np.arange(3) * 0.02,
        np.array([0.7, 0.0]),
        np.zeros((3, 1)),
        np.array([4.0, 0.3]),
    ):
        pytest.skip("JAX is not available")
    data, _ = _pendulum_data()
    kw = dict(
        process_noise={"om": 1e-4},
        measurement_noise={"s": 0.02**2},
        method=method,
        x0=[0.7, 0.0],
        P0=[0.05, 0.05],
    )
    from aeroid.estimation import _ekf_compiled

    used = []
    whole = _ekf_compiled.ekf_pass

    def spy(*args):
        out = whole(*args)
        used.append(out is not None)
        return out

    monkeypatch.setattr(_ekf_compiled, "ekf_pass", spy)
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)  # compile at the first pass
    a = filter_states(_pendulum(), data, **kw)
    # the EKF runs as one compiled scan; the UKF moves its sigma points compiled
    assert used == ([True] if method == "ekf" else [])
    monkeypatch.setattr(_compiled, "ENABLED", False)
    b = filter_states(_pendulum(), data, **kw)
    for name in ("filtered_states", "filtered_covariance", "smoothed_states", "innovations"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.all(np.abs(x - y) <= 1e-8 * np.max(np.abs(y), axis=0)), name
    assert a.log_likelihood == pytest.approx(b.log_likelihood, rel=1e-10)


def test_compiled_ekf_of_one_filter_equals_a_batch_member():
    # one filter (the filter stage's) compiles without the batch axis: the same steps as
    # each member of a batch, and the numpy pass to rounding
    from aeroid.estimation._ekf_compiled import ekf_pass
    from aeroid.models import compiled as _compiled

    model = _pendulum()
    data, _ = _pendulum_data()
    t = data.time
    U = data["tau"][:, None]
    Y = data["s"][:, None]
    if not _compiled.available(model, t, np.array([0.7, 0.0]), U, np.array([4.0, 0.3])):
        pytest.skip("JAX is not available")
    params = {"w2": np.array([4.0, 3.0]), "c": np.array([0.3, 0.3])}
    Qc = np.zeros((2, 2, 2))
    Qc[:, 1, 1] = 1e-4
    R = np.full((2, 1, 1), 0.02**2)
    x0 = np.array([[0.7, 0.0], [0.75, 0.1]])
    P0 = np.repeat(np.diag([0.05, 0.05])[None], 2, axis=0)
    both = ekf_pass(model, t, U, Y, (0,), params, Qc, R, x0, P0, 1)
    assert both is not None
    for b in range(2):
        sl = slice(b, b + 1)
        one = ekf_pass(
            model,
            t,
            U,
            Y,
            (0,),
            {k: v[sl] for k, v in params.items()},
            Qc[sl],
            R[sl],
            x0[sl],
            P0[sl],
            1,
        )
        assert one is not None
        for a, c in zip(one, both, strict=True):
            assert a.shape == c[sl].shape
            assert np.all(np.abs(a - c[sl]) <= 1e-12 * (np.max(np.abs(c[sl])) + 1e-300))
    # the two members differ (a test of something)
    assert np.max(np.abs(both[0][0] - both[0][1])) > 1e-3


def test_a_one_off_nonlinear_pass_does_not_wait_for_a_compiler(monkeypatch):
    # Compilation pays only once a model has spent about a compilation's worth of
    # numpy passes; a single filter pass stays on numpy.
    pytest.importorskip("jax")
    data, _ = _pendulum_data()
    kw = dict(process_noise={"om": 1e-4}, measurement_noise={"s": 0.02**2}, x0=[0.7, 0.0])
    from aeroid.estimation import _ekf_compiled
    from aeroid.models import compiled as _compiled

    used = []
    whole = _ekf_compiled.ekf_pass

    def spy(*args):
        used.append(True)
        return whole(*args)

    monkeypatch.setattr(_ekf_compiled, "ekf_pass", spy)
    model = _pendulum()
    filter_states(model, data, **kw)
    assert used == []
    monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    filter_states(model, data, **kw)
    assert used == [True]


# -- input audit ------------------------------------------------------------------------------

_NOISE = {
    "process_noise": {"alpha": 1e-4, "q": 1e-4},
    "measurement_noise": {"alpha": 0.005**2, "q": 0.01**2},
}


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"smooth": "no"}, "smooth"),
        ({"smooth": 0}, "smooth"),
        ({"x0": "a"}, "x0"),
        ({"x0": [1j, 0.0]}, "x0"),
        ({"x0": {"alpha": "a"}}, r"x0\['alpha'\]"),
        ({"method": "ukf", "ukf_alpha": "1"}, "ukf_alpha"),
        ({"method": "ukf", "ukf_beta": True}, "ukf_beta"),
        ({"substeps": True}, "substeps"),
        ({"substeps": float("nan")}, "substeps"),
        ({"substeps": 10**9}, "substeps"),
        ({"process_noise": {"alpha": True}}, r"process_noise\['alpha'\]"),
        ({"measurement_noise": {"alpha": "1", "q": 1.0}}, r"measurement_noise\['alpha'\]"),
        ({"process_noise": np.array([1j, 1.0])}, "process_noise: complex"),
        ({"outputs": []}, r"outputs: name at least one of the model's outputs"),
        ({"outputs": ["beta"]}, r"outputs: \['beta'\] not among"),
    ],
)
def test_filter_states_refuses_bad_arguments(kwargs, culprit):
    kwargs = {**_NOISE, **kwargs}
    with pytest.raises(FilterError, match=culprit):
        filter_states(catalog.short_period(), catalog.short_period_flight(seed=0), **kwargs)


def test_filter_states_refuses_non_flight_data():
    with pytest.raises(FilterError, match="data: expected a FlightData"):
        filter_states(catalog.short_period(), {"alpha": [0.0]}, **_NOISE)
