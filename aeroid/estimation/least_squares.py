"""Least squares: the linear core of equation error (QR or normal equations,
collinearity) and the one bounded Levenberg-Marquardt iteration (`minimise`)
behind every iterative estimator.

The linear part is re-exported by `aeroid.estimation.regression`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState
from ..errors import DataFormatError, IdentificationError

FloatArray = NDArray[np.float64]

# A regressor whose part independent of the earlier ones is below this fraction of its
# own norm is a linear combination of them to working precision.
_COLLINEAR = 1e-9
# Below this 1 - R^2 of a regressor on the others (condition number of the scaled
# Gram matrix above ~1e10) the normal equations lose digits; QR is used instead.
_WELL_POSED = 1e-8


def _collinear(names: Sequence[str], j: int) -> IdentificationError:
    return IdentificationError(
        f"regressor {names[j]!r} is zero or a linear combination of "
        f"{list(names[:j]) or 'nothing'}; drop it or the regressors it repeats"
    )


def _qr_solve(x: FloatArray, z: FloatArray, names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
    """Least-squares parameters and (X'X)^-1 by Householder QR; refuses collinear columns."""
    q, r = np.linalg.qr(x)
    norms = np.linalg.norm(x, axis=0)
    diag = np.abs(np.diag(r))
    for j in range(x.shape[1]):
        if not diag[j] > _COLLINEAR * norms[j] or norms[j] == 0:
            raise _collinear(names, j)
    # R is only p x p: a plain inverse is cheaper here than LAPACK's triangular solver
    r_inv = np.linalg.inv(r)
    theta = r_inv @ (q.T @ z)
    return theta, r_inv @ r_inv.T


def _ls_solve(
    x: FloatArray, z: FloatArray, names: Sequence[str]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Least-squares parameters, (X'X)^-1 and X'X.

    Normal equations on the column-scaled Gram matrix with one step of iterative
    refinement: forming X'X costs a fraction of a QR factorisation of the tall
    matrix, and the refinement step brings the estimate to QR accuracy while the
    scaled matrix is well conditioned. Near-collinear columns go to QR.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # reported below, by name
        gram = x.T @ x
    d = np.sqrt(np.diag(gram))
    for j in np.flatnonzero(~np.isfinite(d)).tolist():
        raise DataFormatError(
            f"regressor {names[j]!r}: its sum of squares overflows; rescale it (units?)"
        )
    for j in np.flatnonzero(~(d > 0)).tolist():
        raise _collinear(names, j)
    scaled = gram / np.outer(d, d)
    try:
        chol = np.linalg.cholesky(scaled)
    except np.linalg.LinAlgError:
        return (*_qr_solve(x, z, names), gram)
    # the squared pivot is 1 - R^2 of a column on the ones before it
    if float(np.min(np.diag(chol))) ** 2 < _WELL_POSED:
        return (*_qr_solve(x, z, names), gram)
    l_inv = np.linalg.inv(chol)
    xtx_inv = (l_inv.T @ l_inv) / np.outer(d, d)
    theta = xtx_inv @ (x.T @ z)
    theta = theta + xtx_inv @ (x.T @ (z - x @ theta))
    return theta, xtx_inv, gram


def _reml_covariance(
    x: FloatArray, v: FloatArray, xtx_inv: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Output error's coloured-residual covariance for this one-output regression: the
    residual as AR(1) plus white noise by REML, with Satterthwaite's degrees of freedom
    (`_output_error`)."""
    from ._noise_model import _colored_covariance as output_error_covariance

    cov, _, nu = output_error_covariance([x[:, None, :]], [v[:, None]], np.ones(1), xtx_inv)
    return cov, nu


def _gram_stats(
    gram: FloatArray, szz: float, model: list[int]
) -> tuple[float, FloatArray | None, FloatArray | None]:
    """SSE of a model from the cross-products, its parameters and (X'X)^-1 block."""
    if not model:
        return szz, None, None
    g = gram[np.ix_(model, model)]
    b = gram[model, -1]
    try:
        ginv = np.linalg.inv(g)
    except np.linalg.LinAlgError:
        return szz, None, None
    theta = np.asarray(ginv @ b, dtype=np.float64)
    return max(szz - float(b @ theta), 0.0), theta, np.asarray(ginv, dtype=np.float64)


# -- the one nonlinear least-squares iteration ----------------------------------------------
#
# Every iterative estimator (output error, filter error, frequency-domain output error)
# minimises its cost through `minimise`: Levenberg-Marquardt damping of the Gauss-Newton
# step, Gauss-Newton itself being the undamped limit, on the estimator's own linearisation
# (its cost, gradient and Gauss-Newton matrix at a point), with parameter bounds held by an
# active set. The transfer-function fits, plain sums of squares, come in through
# `fit_residuals`, which runs SciPy's MINPACK under the same stopping rule.

# A step is given up once its damping passes this (the step has shrunk to a sliver of the
# gradient's direction): no damping of it decreases the cost.
_MAX_DAMPING = 1e8
# The damping a rejected Gauss-Newton step starts from, and the one below which an
# accepted step's damping is dropped (Gauss-Newton again).
_MIN_DAMPING = 1e-4
_UNDAMPED = 1e-6
# Two successive Gauss-Newton steps whose cosine (in the curvature's metric) exceeds
# this in magnitude run along one direction: the iteration creeps or zig-zags there.
_PARALLEL = 0.9
# The stopping rule's cost test is this fraction of the step test's tolerance.
_COST_SHARE = 1e-3
# Rounding of a cost: a trial within this fraction of the current cost is no worse.
_COST_ROUNDING = 1e-12
# An unknown whose curvature is below this share of the largest one is unseen by the data:
# its sensitivity is rounding (eps squared of the others' scale) or exactly zero.
_UNSEEN = float(np.finfo(np.float64).eps) ** 2
# SciPy's Levenberg-Marquardt refuses a gradient tolerance below machine precision.
_NO_GRADIENT_TEST = 4.0 * float(np.finfo(np.float64).eps)


@dataclass(frozen=True)
class Linearisation(FrozenState):
    """An estimator's cost near one point: what its callback hands the solver.

    ``cost`` is the objective; ``gradient`` its derivative; ``curvature`` the
    Gauss-Newton matrix (``J^T W J``, or the Fisher information), positive
    semi-definite. ``judged`` is, for an objective whose weighting moves with
    the iterate and is held over one step (a noise covariance re-estimated per
    iteration), the trial's cost under the weighting of the point the step was
    taken from; None when ``cost`` itself compares. ``payload`` carries what the
    estimator needs back (residuals, Jacobians) untouched.
    """

    cost: float
    gradient: FloatArray
    curvature: FloatArray
    payload: Any = None
    judged: float | None = None


def linearised(residual: FloatArray, jacobian: FloatArray, payload: Any = None) -> Linearisation:
    """The linearisation of ``½ r^T r``: gradient ``J^T r``, Gauss-Newton matrix ``J^T J``."""
    return Linearisation(
        0.5 * float(residual @ residual), jacobian.T @ residual, jacobian.T @ jacobian, payload
    )


@dataclass(frozen=True)
class LeastSquaresFit(FrozenState):
    """The one result of `minimise`.

    ``theta`` the estimate, ``point`` the linearisation there, ``iterations``
    the accepted steps, ``evaluations`` the callback's calls, ``success`` and
    ``message`` how it stopped, ``damping`` the Levenberg-Marquardt parameter
    it stopped with.
    """

    theta: FloatArray
    point: Linearisation
    iterations: int
    evaluations: int
    success: bool
    message: str
    damping: float


def held_at_bounds(
    solve: Callable[[NDArray[np.intp]], FloatArray],
    at_lower: NDArray[np.bool_],
    at_upper: NDArray[np.bool_],
) -> FloatArray:
    """A step (the change of each unknown) with the unknowns held that sit at a bound
    and would leave the box: the active set of bounded Gauss–Newton and scoring.

    ``solve(idx)`` returns the change of the free unknowns `idx`; an unknown at a
    bound whose change points outward is held (zero change) and the rest solved
    again, until none points outward.
    """
    n = at_lower.size
    free = np.ones(n, dtype=bool)
    change = np.zeros(n)
    for _ in range(n + 1):
        change = np.zeros(n)
        idx = np.flatnonzero(free)
        if idx.size:
            change[idx] = solve(idx)
        out = free & ((at_lower & (change < 0)) | (at_upper & (change > 0)))
        if not np.any(out):
            break
        free &= ~out
    return change


def damped_step(
    point: Linearisation,
    damping: float,
    theta: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    max_step: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The Levenberg-Marquardt step from `theta`, inside the box: (the change, the
    trial point), the trial exactly on a bound it reaches.

    The normal equations are scaled to a unit diagonal (Marquardt's scaling, so
    the damping is relative to each unknown's own curvature) and solved by least
    squares, which gives a rank-deficient matrix its minimum-norm step. Unknowns
    at a bound whose step points out are held (`held_at_bounds`) and the rest of
    the step is clipped into the box. With `max_step`, an unknown whose change
    would exceed it takes that much, and the others' step is solved again given it.
    """
    dn = np.sqrt(np.clip(np.diag(point.curvature), 1e-300, None))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        # a record that moves no output leaves no curvature at all: `plain` below meets
        # what is not finite
        a = point.curvature / np.outer(dn, dn)
        b = point.gradient / dn

    def plain(sub: FloatArray, rhs: FloatArray) -> FloatArray:
        if not (np.all(np.isfinite(sub)) and np.all(np.isfinite(rhs))):
            # (values near the float range's ends: LAPACK refuses them, and may hang)
            return np.zeros(rhs.size)
        try:
            sol = np.linalg.lstsq(sub + damping * np.eye(rhs.size), rhs, rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            return np.zeros(rhs.size)
        return np.asarray(sol, dtype=np.float64)

    # an unknown the data do not see (no curvature, so no gradient either) takes no step:
    # the minimum-norm solution's rounding there, over its zero scale, would send it to
    # 1e135 and the simulations with it to overflow
    diag = np.diag(point.curvature)
    with np.errstate(invalid="ignore"):
        seen = diag > _UNSEEN * np.max(np.where(np.isfinite(diag), diag, 0.0), initial=0.0)

    def solve(idx: NDArray[np.intp]) -> FloatArray:
        sel = seen[idx]
        if np.all(sel):
            return solve_seen(idx)
        out = np.zeros(idx.size)
        if np.any(sel):
            out[sel] = solve_seen(idx[sel])
        return out

    def solve_seen(idx: NDArray[np.intp]) -> FloatArray:
        sub = a if idx.size == theta.size else a[np.ix_(idx, idx)]
        scaled = plain(sub, -b[idx])
        if max_step is not None:
            cap = max_step[idx] * dn[idx]  # in the scaled unknowns
            fixed = np.zeros(idx.size, dtype=bool)
            for _ in range(idx.size):
                over = ~fixed & (np.abs(scaled) > cap)
                if not np.any(over):
                    break
                fixed |= over
                scaled[over] = np.sign(scaled[over]) * cap[over]
                free = np.flatnonzero(~fixed)
                if free.size:
                    rhs = -b[idx][free] - sub[np.ix_(free, np.flatnonzero(fixed))] @ scaled[fixed]
                    scaled[free] = plain(sub[np.ix_(free, free)], rhs)
        return np.asarray(scaled / dn[idx], dtype=np.float64)

    if np.any(np.isfinite(lower)) or np.any(np.isfinite(upper)):
        delta = held_at_bounds(solve, theta <= lower, theta >= upper)
    else:
        delta = solve(np.arange(theta.size))
    trial = np.asarray(np.clip(theta + delta, lower, upper), dtype=np.float64)
    return trial - theta, trial


def relative_step(delta: FloatArray, theta: FloatArray, typical: FloatArray) -> float:
    """The largest change of an unknown relative to its size (at least `typical`)."""
    if not delta.size:
        return 0.0
    return float(np.max(np.abs(delta) / np.maximum(np.abs(theta), typical)))


def converged(rel_step: float, decrease: float, cost: float, tolerance: float) -> bool:
    """The stopping rule: a relative step below `tolerance`, or a cost decrease below
    ``1e-3 tolerance max(|cost|, 1)``."""
    return rel_step < tolerance or decrease < _COST_SHARE * tolerance * max(1.0, abs(cost))


def minimise(
    evaluate: Callable[[FloatArray, Linearisation | None], Linearisation | None],
    theta: FloatArray,
    start: Linearisation,
    *,
    tolerance: float,
    max_iterations: int,
    typical: FloatArray | None = None,
    lower: FloatArray | None = None,
    upper: FloatArray | None = None,
    damping: float = 0.0,
    max_step: FloatArray | None = None,
    accelerate: bool = False,
) -> LeastSquaresFit:
    """Bounded Levenberg-Marquardt on an estimator's linearisation: the one
    nonlinear least-squares iteration of aeroid.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(theta, base)``: the `Linearisation` at `theta` (a trial step
        from the accepted point `base`), or None where the model fails there.
    theta : (n,) array
        The start, inside the bounds.
    start : Linearisation
        The linearisation at `theta` (the estimator checks its start itself).
    tolerance : float
        The stopping rule (`converged`): a step whose largest change relative to
        its unknown's size (at least `typical`) is below `tolerance`, or whose
        cost decrease is below ``1e-3 tolerance max(|cost|, 1)``. A Gauss-Newton
        step that would already pass the test is not taken. Where the points
        carry ``judged`` (a weighting that moves with the iterate), the step over
        the last two iterations counts too: such a weighting can settle into a
        two-step cycle about its fixed point.
    max_iterations : int
        The most accepted steps; reaching it returns ``success=False`` unless a
        run with a higher limit would stop there too (undamped, its Gauss-Newton
        step passes the stopping rule): converged on the last allowed step.
    typical : (n,) array, optional
        Each unknown's typical size, the floor of the relative step (default 1).
    lower, upper : (n,) arrays, optional
        Bounds (±inf for an open side); every iterate stays inside.
    damping : float
        The Levenberg-Marquardt parameter of the first step (0: Gauss-Newton).
        A rejected step's damping grows tenfold (from 1e-4); an accepted step's
        falls tenfold, to Gauss-Newton below 1e-6. A step no damping up to 1e8
        makes decrease the cost ends the iteration: converged when the
        Gauss-Newton step from there passes the stopping rule, else flagged
        ``success=False``.
    max_step : (n,) array, optional
        For unknowns on which the quadratic model is trusted only so far (inf:
        no limit): a rejected step that changes one by more is tried again at
        the same damping with that change held to its limit and the others
        solved given it (`damped_step`), before the damping grows.
    accelerate : bool
        Where the undamped Gauss-Newton step runs along the last one (or against
        it), try first the point the two steps extrapolate to (`_anderson`): a
        curvature model off by a factor along one direction (the Fisher
        information of a weakly determined noise level) makes the plain
        iteration creep or zig-zag there, one step at a time.

    Returns
    -------
    LeastSquaresFit
    """
    theta = np.asarray(theta, dtype=np.float64)
    n = theta.size
    typ = np.ones(n) if typical is None else np.asarray(typical, dtype=np.float64)
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    point = start
    lam = float(damping)
    evaluations = 0
    iteration = 0
    back: FloatArray | None = None  # the iterate before this one
    memory: tuple[FloatArray, FloatArray] | None = None

    def end(success: bool, message: str) -> LeastSquaresFit:
        return LeastSquaresFit(theta, point, iteration, evaluations, success, message, lam)

    while iteration < max_iterations:
        trial: Linearisation | None = None
        delta = trial_theta = theta
        limit = None  # the first try at each damping takes the whole step
        if accelerate and lam == 0.0 and memory is not None:
            extrapolated = _anderson(point, theta, memory, lo, hi, typ, tolerance)
            if extrapolated is not None:
                memory = (theta, extrapolated[1])
                evaluations += 1
                found = evaluate(extrapolated[0], point)
                if found is not None and np.isfinite(found.cost):
                    judged = found.cost if found.judged is None else found.judged
                    if judged < point.cost:
                        iteration += 1
                        decrease = point.cost - judged
                        rel = relative_step(extrapolated[0] - theta, theta, typ)
                        back = theta
                        theta, point = extrapolated[0], found
                        if converged(rel, decrease, point.cost, tolerance):
                            return end(True, f"converged after {iteration} iterations")
                        continue
        while lam <= _MAX_DAMPING:
            delta, trial_theta = damped_step(point, lam, theta, lo, hi, limit)
            if lam == 0.0 and _negligible(point, delta, theta, typ, tolerance):
                # the step would already pass the test: stop rather than evaluate it
                return end(True, f"converged after {iteration} iterations")
            evaluations += 1
            found = evaluate(trial_theta, point)
            if found is not None and np.isfinite(found.cost):
                judged = found.cost if found.judged is None else found.judged
                if judged <= point.cost + _COST_ROUNDING * abs(point.cost):
                    trial = found
                    break
            if limit is None and max_step is not None and np.any(np.abs(delta) > max_step):
                limit = max_step
                continue
            lam = max(lam * 10.0, _MIN_DAMPING)
        if trial is None:
            # at the minimum to rounding when the Gauss-Newton step from here would
            # pass the stopping rule; stuck otherwise
            if _negligible(point, damped_step(point, 0.0, theta, lo, hi)[0], theta, typ, tolerance):
                return end(True, "converged (no step decreases the cost further)")
            return end(
                False,
                "stopped: no step decreases the cost, though the Gauss-Newton step is not "
                "negligible",
            )
        iteration += 1
        judged = trial.cost if trial.judged is None else trial.judged
        decrease = point.cost - judged
        rel = relative_step(delta, theta, typ)
        if trial.judged is not None and back is not None:
            # a weighting that moves with the iterate can settle into a two-step
            # cycle about its fixed point: the step over two iterations counts too
            rel = min(rel, relative_step(trial_theta - back, theta, typ))
        # the last undamped, whole Gauss-Newton step and where it was taken from
        memory = (theta, delta) if lam == 0.0 and limit is None else None
        back = theta
        theta, point = trial_theta, trial
        lam = lam / 10.0 if lam > _UNDAMPED else 0.0
        if converged(rel, decrease, point.cost, tolerance):
            return end(True, f"converged after {iteration} iterations")
    # the last allowed step may have reached the minimum: the test a run with a higher
    # limit makes before its next step (undamped there), so the verdicts agree
    step = damped_step(point, 0.0, theta, lo, hi)[0]
    if lam == 0.0 and _negligible(point, step, theta, typ, tolerance):
        return end(True, f"converged after {iteration} iterations")
    return end(False, f"iteration limit ({max_iterations}) reached before convergence")


def _anderson(
    point: Linearisation,
    theta: FloatArray,
    memory: tuple[FloatArray, FloatArray],
    lower: FloatArray,
    upper: FloatArray,
    typ: FloatArray,
    tolerance: float,
) -> tuple[FloatArray, FloatArray] | None:
    """Anderson's extrapolation of depth one (Walker & Ni 2011) of the Gauss-Newton
    iteration: (the trial point, the Gauss-Newton step here), or None where the step
    here is negligible or does not run along the last one.

    Where the iteration converges linearly along one direction, each step the last
    times a ratio r (0 < r < 1 creeping, -1 < r < 0 zig-zagging), the steps f and the
    iterates x of the last two points give the limit exactly:
    ``x + f - gamma (dx + df)`` with ``gamma = <df, f> / <df, df>``, in the metric of
    the curvature (each unknown in its own standard errors).
    """
    step = damped_step(point, 0.0, theta, lower, upper)[0]
    if _negligible(point, step, theta, typ, tolerance):
        return None
    x_last, f_last = memory
    W = point.curvature
    df = step - f_last
    norms = float(step @ W @ step) * float(f_last @ W @ f_last)
    along = float(step @ W @ f_last)
    dff = float(df @ W @ df)
    if not (norms > 0 and dff > 0) or abs(along) < _PARALLEL * np.sqrt(norms):
        return None
    gamma = float(df @ W @ step) / dff
    trial = theta + step - gamma * ((theta - x_last) + df)
    return np.asarray(np.clip(trial, lower, upper), dtype=np.float64), step


def _negligible(
    point: Linearisation, delta: FloatArray, theta: FloatArray, typ: FloatArray, tolerance: float
) -> bool:
    """A step from `point` that would pass the stopping rule, its cost decrease the one
    the quadratic model predicts."""
    predicted = -0.5 * float(point.gradient @ delta)
    return converged(relative_step(delta, theta, typ), predicted, point.cost, tolerance)


def fit_residuals(
    residual: Callable[[FloatArray], FloatArray],
    jacobian: Callable[[FloatArray], FloatArray],
    theta: FloatArray,
    *,
    tolerance: float,
    max_iterations: int = 200,
    solver: str = "aeroid",
) -> LeastSquaresFit:
    """Minimise ``½ |residual(theta)|²`` given its Jacobian: `minimise` on the plain
    sum of squares, or SciPy's Levenberg-Marquardt under the same stopping rule.

    ``solver="scipy"`` calls `scipy.optimize.least_squares` (``method="lm"``,
    MINPACK, column scaling by the Jacobian) with its step test at `tolerance`
    and its cost test at ``1e-3 tolerance``, the two halves of `converged`
    (its gradient test held at machine precision);
    ``max_iterations`` bounds its Jacobian evaluations. A residual that is not
    finite counts as a failed point.
    """

    def evaluate(th: FloatArray, _base: Linearisation | None) -> Linearisation | None:
        r = residual(th)
        if not np.all(np.isfinite(r)):
            return None
        return linearised(r, jacobian(th))

    theta = np.asarray(theta, dtype=np.float64)
    if solver == "aeroid":
        first = evaluate(theta, None)
        if first is None:
            return LeastSquaresFit(
                theta,
                linearised(residual(theta), jacobian(theta)),
                0,
                1,
                False,
                "the residual is not finite at the start",
                0.0,
            )
        return minimise(evaluate, theta, first, tolerance=tolerance, max_iterations=max_iterations)
    if solver != "scipy":
        raise IdentificationError(f"solver: expected 'aeroid' or 'scipy', got {solver!r}")
    import scipy.optimize

    with np.errstate(all="ignore"):
        sol = scipy.optimize.least_squares(
            residual,
            theta,
            jac=jacobian,
            method="lm",
            x_scale="jac",
            xtol=tolerance,
            ftol=_COST_SHARE * tolerance,
            # MINPACK's third test (residual orthogonal to the Jacobian) is no part of
            # the rule: held at the smallest value it accepts
            gtol=_NO_GRADIENT_TEST,
            max_nfev=100 * max_iterations,
        )
        x = np.asarray(sol.x, dtype=np.float64)
        point = linearised(np.asarray(sol.fun, dtype=np.float64), np.asarray(sol.jac))
    return LeastSquaresFit(
        x, point, int(sol.njev or 0), int(sol.nfev), bool(sol.status > 0), str(sol.message), 0.0
    )
