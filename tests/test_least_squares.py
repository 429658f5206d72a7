"""The one bounded least-squares iteration (`aeroid.estimation.least_squares.minimise`)."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid.errors import IdentificationError
from aeroid.estimation.least_squares import (
    Linearisation,
    converged,
    damped_step,
    fit_residuals,
    linearised,
    minimise,
)


def _linear(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((40, 3))
    z = x @ np.array([1.5, -2.0, 0.25]) + 0.1 * rng.standard_normal(40)
    return x, z


def _plain(x: np.ndarray, z: np.ndarray):  # type: ignore[no-untyped-def]
    def evaluate(th: np.ndarray, _base: Linearisation | None) -> Linearisation:
        return linearised(x @ th - z, x)

    return evaluate


def test_linear_least_squares_is_one_gauss_newton_step() -> None:
    x, z = _linear()
    exact = np.linalg.lstsq(x, z, rcond=None)[0]
    evaluate = _plain(x, z)
    th0 = np.zeros(3)
    fit = minimise(evaluate, th0, evaluate(th0, None), tolerance=1e-10, max_iterations=20)
    # the undamped step lands on the solution; the next one would pass the stopping
    # rule and is not evaluated
    assert fit.success and fit.iterations == 1 and fit.evaluations == 1
    np.testing.assert_allclose(fit.theta, exact, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(fit.point.gradient, 0.0, atol=1e-10)
    # damping from the start: Gauss-Newton is its limit, the answer is the same
    damped = minimise(
        evaluate, th0, evaluate(th0, None), tolerance=1e-10, max_iterations=50, damping=1.0
    )
    assert damped.success and damped.iterations > 1
    np.testing.assert_allclose(damped.theta, exact, rtol=1e-9)


def _rosenbrock(th: np.ndarray) -> np.ndarray:
    return np.array([10.0 * (th[1] - th[0] ** 2), 1.0 - th[0]])


def _rosenbrock_jacobian(th: np.ndarray) -> np.ndarray:
    return np.array([[-20.0 * th[0], 10.0], [-1.0, 0.0]])


@pytest.mark.parametrize("solver", ["aeroid", "scipy"])
def test_rosenbrock_minimum_is_found(solver: str) -> None:
    fit = fit_residuals(
        _rosenbrock, _rosenbrock_jacobian, np.array([-1.2, 1.0]), tolerance=1e-10, solver=solver
    )
    assert fit.success
    np.testing.assert_allclose(fit.theta, [1.0, 1.0], atol=1e-8)
    assert fit.point.cost < 1e-16


def test_iteration_limit_is_flagged() -> None:
    fit = fit_residuals(
        _rosenbrock, _rosenbrock_jacobian, np.array([-1.2, 1.0]), tolerance=1e-10, max_iterations=2
    )
    assert not fit.success and fit.iterations == 2 and "iteration limit (2)" in fit.message


def test_convergence_on_the_last_allowed_step_is_convergence() -> None:
    # linear least squares: the one Gauss-Newton step lands on the solution, so a
    # limit of one step stops where the free run stops, converged (not flagged)
    x, z = _linear()
    evaluate = _plain(x, z)
    th0 = np.zeros(3)
    fit = minimise(evaluate, th0, evaluate(th0, None), tolerance=1e-10, max_iterations=1)
    assert fit.success and fit.message == "converged after 1 iterations"
    assert fit.iterations == 1 and fit.evaluations == 1
    np.testing.assert_allclose(fit.theta, np.linalg.lstsq(x, z, rcond=None)[0], rtol=1e-12)
    # Rosenbrock: the free run's count as the limit gives its answer and its verdict;
    # one step fewer is flagged
    free = fit_residuals(_rosenbrock, _rosenbrock_jacobian, np.array([-1.2, 1.0]), tolerance=1e-10)
    n = free.iterations
    capped = fit_residuals(
        _rosenbrock, _rosenbrock_jacobian, np.array([-1.2, 1.0]), tolerance=1e-10, max_iterations=n
    )
    assert free.success and capped.success and capped.message == free.message
    np.testing.assert_array_equal(capped.theta, free.theta)
    short = fit_residuals(
        _rosenbrock,
        _rosenbrock_jacobian,
        np.array([-1.2, 1.0]),
        tolerance=1e-10,
        max_iterations=n - 1,
    )
    assert not short.success and f"iteration limit ({n - 1})" in short.message


def test_an_active_bound_holds_and_the_rest_is_the_constrained_solution() -> None:
    x, z = _linear(1)
    evaluate = _plain(x, z)
    th0 = np.zeros(3)
    # the free optimum has theta_1 = -2: bound it at -1
    lower = np.array([-np.inf, -1.0, -np.inf])
    fit = minimise(
        evaluate, th0, evaluate(th0, None), tolerance=1e-12, max_iterations=50, lower=lower
    )
    assert fit.success
    assert fit.theta[1] == -1.0  # exactly on the bound, not a rounding off it
    # the others: least squares with theta_1 held at its bound (closed form)
    rest = np.linalg.lstsq(x[:, [0, 2]], z + 1.0 * x[:, 1], rcond=None)[0]
    np.testing.assert_allclose(fit.theta[[0, 2]], rest, rtol=1e-10)
    # Kuhn-Tucker: the cost falls outward across the bound, and is flat in the rest
    assert fit.point.gradient[1] > 0
    np.testing.assert_allclose(fit.point.gradient[[0, 2]], 0.0, atol=1e-9)
    # every iterate feasible: a step from the bound that points outward is held
    delta, trial = damped_step(fit.point, 0.0, fit.theta, lower, np.full(3, np.inf))
    assert delta[1] == 0.0 and trial[1] == -1.0


def test_rank_deficiency_takes_the_minimum_norm_step() -> None:
    x, z = _linear(2)
    twin = np.column_stack([x[:, 0], x[:, 0], x[:, 1]])  # two identical columns
    evaluate = _plain(twin, z)
    th0 = np.zeros(3)
    fit = minimise(evaluate, th0, evaluate(th0, None), tolerance=1e-10, max_iterations=20)
    single = np.linalg.lstsq(x[:, :2], z, rcond=None)[0]
    # the twins share their coefficient equally (the minimum-norm split), and the fit
    # is the one of the single column
    np.testing.assert_allclose(fit.theta, [single[0] / 2, single[0] / 2, single[1]], rtol=1e-9)
    assert fit.success and np.all(np.isfinite(fit.theta))


def test_failed_points_are_rejected_and_damped() -> None:
    # the model fails (None) beyond 3; the optimum at 5 cannot be reached
    def evaluate(th: np.ndarray, _base: Linearisation | None) -> Linearisation | None:
        if th[0] > 3.0:
            return None
        return linearised(th - 5.0, np.eye(1))

    fit = minimise(
        evaluate, np.zeros(1), evaluate(np.zeros(1), None), tolerance=1e-8, max_iterations=100
    )
    assert 2.9 < fit.theta[0] <= 3.0
    assert fit.damping > 0.0  # the last steps were damped


def test_no_decrease_at_the_minimum_is_convergence() -> None:
    # a cost at its minimum to rounding: every trial comes out worse, and the
    # Gauss-Newton step from there is negligible
    def evaluate(th: np.ndarray, base: Linearisation | None) -> Linearisation:
        return Linearisation(1.0 if base is None else 1.1, np.array([1e-14]), np.eye(1))

    fit = minimise(
        evaluate,
        np.ones(1),
        evaluate(np.ones(1), None),
        tolerance=1e-8,
        max_iterations=10,
        damping=1.0,
    )
    assert fit.success and fit.iterations == 0


def test_stopping_rule_halves() -> None:
    # a relative step below the tolerance, or a cost decrease below 1e-3 of it
    assert converged(0.9e-6, 1.0, 10.0, 1e-6)
    assert not converged(1.1e-6, 1.0, 10.0, 1e-6)
    assert converged(1.0, 0.9e-8, 10.0, 1e-6)  # 1e-3 * 1e-6 * 10
    assert not converged(1.0, 1.1e-8, 10.0, 1e-6)
    assert converged(1.0, 0.9e-9, 1e-5, 1e-6)  # a cost below 1 counts as 1


def test_tolerance_sets_how_close_the_answer_is() -> None:
    # y = a exp(-b t): a loose tolerance stops earlier and further from the optimum
    t = np.linspace(0.0, 4.0, 50)
    y = 2.0 * np.exp(-0.7 * t)

    def res(th: np.ndarray) -> np.ndarray:
        return np.asarray(th[0] * np.exp(-th[1] * t) - y)

    def jac(th: np.ndarray) -> np.ndarray:
        e = np.exp(-th[1] * t)
        return np.column_stack([e, -th[0] * t * e])

    loose = fit_residuals(res, jac, np.array([1.0, 0.1]), tolerance=1e-2)
    tight = fit_residuals(res, jac, np.array([1.0, 0.1]), tolerance=1e-12)
    assert loose.success and tight.success and loose.iterations < tight.iterations
    np.testing.assert_allclose(tight.theta, [2.0, 0.7], rtol=1e-8)
    assert np.max(np.abs(loose.theta - [2.0, 0.7])) > 1e-9


def test_exponential_decay_recovers_truth_within_its_error_bars() -> None:
    # a seeded noisy fit of another model: the estimate lies within 4 standard errors
    t = np.linspace(0.0, 4.0, 200)
    y = 2.0 * np.exp(-0.7 * t) + 0.02 * np.random.default_rng(5).standard_normal(t.size)

    def res(th: np.ndarray) -> np.ndarray:
        return np.asarray(th[0] * np.exp(-th[1] * t) - y)

    def jac(th: np.ndarray) -> np.ndarray:
        e = np.exp(-th[1] * t)
        return np.column_stack([e, -th[0] * t * e])

    for solver in ("aeroid", "scipy"):
        fit = fit_residuals(res, jac, np.array([1.0, 0.1]), tolerance=1e-10, solver=solver)
        s2 = 2.0 * fit.point.cost / (t.size - 2)
        se = np.sqrt(s2 * np.diag(np.linalg.inv(fit.point.curvature)))
        assert np.all(np.abs(fit.theta - [2.0, 0.7]) < 4.0 * se), solver


def test_moving_weighting_judges_the_trial_in_the_base_metric() -> None:
    # a cost whose weighting is held over a step: the trial is compared by `judged`
    seen: list[float | None] = []

    def evaluate(th: np.ndarray, base: Linearisation | None) -> Linearisation:
        w = 1.0 + th[0] ** 2  # the weighting moves with the iterate
        r = np.array([th[0] - 1.0]) / w
        here = linearised(r, np.array([[1.0 / w]]))
        judged = None
        if base is not None:
            wb = base.payload
            judged = 0.5 * float(((th[0] - 1.0) / wb) ** 2)
        seen.append(judged)
        return Linearisation(here.cost, here.gradient, here.curvature, w, judged)

    th0 = np.array([3.0])
    fit = minimise(evaluate, th0, evaluate(th0, None), tolerance=1e-10, max_iterations=50)
    assert fit.success and abs(fit.theta[0] - 1.0) < 1e-9
    assert all(j is not None for j in seen[1:])


def test_unknown_solver_is_refused() -> None:
    with pytest.raises(IdentificationError, match="solver"):
        fit_residuals(_rosenbrock, _rosenbrock_jacobian, np.zeros(2), tolerance=1e-8, solver="x")


def test_no_decrease_short_of_the_minimum_is_flagged() -> None:
    # a gradient that points the wrong way: no step decreases the cost, and the
    # Gauss-Newton step is far from negligible
    def evaluate(th: np.ndarray, _base: Linearisation | None) -> Linearisation:
        return Linearisation(0.5 * float(th @ th), -th, np.eye(1))

    fit = minimise(
        evaluate, np.ones(1), evaluate(np.ones(1), None), tolerance=1e-8, max_iterations=10
    )
    assert not fit.success and "no step decreases" in fit.message
    assert fit.theta[0] == 1.0


def test_a_step_held_to_its_limit_solves_the_rest_given_it() -> None:
    # least squares on x: the Gauss-Newton step moves theta_1 by 2, limited to 0.5; the
    # others are then the least squares with theta_1 fixed at 0.5 (closed form)
    x, z = _linear(3)
    point = linearised(-z, x)
    free = np.full(3, np.inf)
    whole, _ = damped_step(point, 0.0, np.zeros(3), -free, free)
    assert abs(whole[1]) > 1.0
    limit = np.array([np.inf, 0.5, np.inf])
    delta, trial = damped_step(point, 0.0, np.zeros(3), -free, free, limit)
    assert delta[1] == np.sign(whole[1]) * 0.5
    rest = np.linalg.lstsq(x[:, [0, 2]], z - delta[1] * x[:, 1], rcond=None)[0]
    np.testing.assert_allclose(delta[[0, 2]], rest, rtol=1e-10)
    np.testing.assert_array_equal(trial, delta)


def test_a_rejected_long_step_is_tried_again_at_its_limit_before_damping() -> None:
    # cost exp(t) - 2 t + t^2/2 (minimum near 0.44) with a curvature model a quarter of
    # the truth: the Gauss-Newton step from 0 (to 2) overshoots to a higher cost; held
    # to 0.5 it decreases the cost at the same damping, so no damping is added; without
    # the limit the iteration damps the step instead
    def evaluate(th: np.ndarray, _base: Linearisation | None) -> Linearisation:
        t = float(th[0])
        cost = np.exp(t) - 2.0 * t + 0.5 * t * t
        grad = np.array([np.exp(t) - 2.0 + t])
        return Linearisation(float(cost), grad, np.array([[0.25 * (np.exp(t) + 1.0)]]))

    calls: list[float] = []

    def counted(th: np.ndarray, base: Linearisation | None) -> Linearisation:
        calls.append(float(th[0]))
        return evaluate(th, base)

    start = evaluate(np.zeros(1), None)
    limit = np.full(1, 0.5)
    fit = minimise(counted, np.zeros(1), start, tolerance=1e-3, max_iterations=1, max_step=limit)
    assert calls == [pytest.approx(2.0), 0.5]  # the whole step, then held at 0.5
    assert fit.iterations == 1 and fit.theta[0] == 0.5 and fit.damping == 0.0
    calls.clear()
    plain = minimise(counted, np.zeros(1), start, tolerance=1e-3, max_iterations=1)
    assert plain.damping > 0.0 and len(calls) > 2


@pytest.mark.parametrize("factor", [0.55, 3.0])
def test_extrapolation_ends_a_creep_or_a_zig_zag(factor: float) -> None:
    # a quadratic cost whose curvature model is off by `factor` along one direction: the
    # plain iteration's steps there shrink by 1 - 1/factor each (0.55: zig-zags, ratio
    # -0.82; 3: creeps, ratio 0.67), linearly; Anderson's extrapolation of two steps
    # lands on the minimum (closed form) and the fit stops after a few evaluations
    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    H = q @ np.diag([1.0, 2.0, 5.0, 10.0]) @ q.T
    b = rng.standard_normal(4)
    v = q[:, 0]
    model = H + (factor - 1.0) * np.outer(v, v)  # v'Hv = 1, so v'(model)v = factor

    def evaluate(th: np.ndarray, _base: Linearisation | None) -> Linearisation:
        return Linearisation(float(0.5 * th @ H @ th - b @ th), H @ th - b, model)

    th0 = np.zeros(4)
    truth = np.linalg.solve(H, b)
    runs = {}
    for accelerate in (False, True):
        runs[accelerate] = minimise(
            evaluate,
            th0,
            evaluate(th0, None),
            tolerance=1e-10,
            max_iterations=200,
            accelerate=accelerate,
        )
    plain, fast = runs[False], runs[True]
    assert plain.success and fast.success
    np.testing.assert_allclose(fast.theta, truth, rtol=1e-8, atol=1e-10)
    assert fast.evaluations <= 4 < plain.evaluations
