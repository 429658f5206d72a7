"""Batched integration of a model's ODE on a measurement time grid.

Three integrators share one contract: states land exactly on the grid, the
controls are piecewise-linear between samples (or, on request, a local cubic:
`CONTROL_INTERPOLATIONS`, `control_slopes`), and a batch of parameter
vectors (and, optionally, of control histories) is integrated in one pass.

* ``"exact"``: for dynamics affine in state and control and independent of
  time, the zero-order-hold-free exact discretisation for piecewise-linear
  inputs (a matrix exponential per grid step size). ``"auto"`` takes it only
  when `lti_form` shows that form at every sample time of the record, or
  when the model declares itself linear (``Model(..., linear=True)``).
* ``"rk4"``: classical Runge-Kutta with ``substeps`` steps per grid interval;
  no step ever straddles a control breakpoint.
* ``"euler"``: one forward-Euler step per grid interval with the controls held
  at the interval's first sample. Crude (first order), but what some legacy
  tools integrate with.
* ``"rk4_hold"``: classical Runge-Kutta, one step per grid interval (or
  ``substeps``), with the controls held at the interval's first sample at
  every stage (a zero-order hold). SIDPAC's saved data-compatibility outputs
  (``dca_lon_demo``, ``dca_lat_demo``) were integrated so, not by the
  Adams-Bashforth code it ships: fourth order in the states, but a held
  input lags the sampled one by half an interval.
* a `scipy.integrate.solve_ivp` method name, integrating the stacked batch.
  The explicit Runge-Kutta pairs (``"RK45"``, ``"RK23"``, ``"DOP853"``) run
  one sample interval at a time, each ending exactly on the next sample and
  seeing the one-sided limits at the interval's ends, as RK4 does: the
  piecewise-linear controls kink, and a time-varying forcing may switch, at
  the samples, and an adaptive step across such a point carries an error its
  error estimate misses (at rtol 1e-9 a burnout at a sample time left 2e-6
  in the velocity, and the control kinks 1e-7 in a linear model's states).
  The implicit methods (``"Radau"``, ``"BDF"``, ``"LSODA"``), whose restarts
  are costly, integrate the record in one call with ``max_step`` no larger
  than the grid spacing so that a late input can never be stepped over.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState
from ..errors import AeroidError, SimulationError
from ._batch_function import BatchFunction
from ._batch_function import UserFunction as UserFunction
from ._batch_function import _same as _same
from ._controls import CONTROL_INTERPOLATIONS as CONTROL_INTERPOLATIONS
from ._controls import Interpolation as Interpolation
from ._controls import _cubic_excess as _cubic_excess
from ._controls import check_control_interpolation as check_control_interpolation
from ._controls import control_excess as control_excess
from ._controls import control_nodes as control_nodes
from ._controls import control_slopes as control_slopes
from ._controls import controls_at as controls_at
from ._controls import hermite as hermite
from ._controls import shifted_controls as shifted_controls
from ._substeps import _MAX_AUTO_SUBSTEPS as _MAX_AUTO_SUBSTEPS
from ._substeps import SUBSTEP_ERROR as SUBSTEP_ERROR
from ._substeps import auto_substeps as auto_substeps
from ._substeps import jacobian_eigenvalues as jacobian_eigenvalues
from ._substeps import substep_demand as substep_demand
from ._substeps import substeps_for as substeps_for
from ._substeps import trajectory_substeps as trajectory_substeps

if TYPE_CHECKING:
    from .model import Model

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
# The distinct sample intervals the exact path discretises (a matrix exponential each).
_EXACT_STEP_SIZES = 64
_BY_INTERVAL = ("RK45", "RK23", "DOP853")  # restarted at every sample (module notes)
METHODS = ("auto", "exact", "rk4", "rk4_hold", "euler", *SOLVE_IVP_METHODS)
# The automatic substeps' path is rerun at most this many times with the count its
# samples ask for (`trajectory_substeps`).
_PREVIEW_PASSES = 2
# RK4 evaluates the stages at a sample interval's ends this fraction of the interval
# inside it: one-sided limits, so a forcing that switches at a sample time (a burnout
# at t = 2 s, even with 2 s stored a few ulp off) acts on the correct side of it.
# For a smooth dependence on time it moves the states by about 1e-10 h T |df/dt|.
_INSIDE = 1e-9


def import_solvers() -> None:
    """Load SciPy's integrators and `expm` now (they are otherwise imported on first use)."""
    import scipy.integrate
    import scipy.linalg  # noqa: F401


@dataclass(frozen=True)
class RawTrajectory(FrozenState):
    """Integrator output: states (batch, n_t, n_x), success mask, failure times."""

    states: FloatArray
    ok: NDArray[np.bool_]
    fail_time: FloatArray


# -- integrators ----------------------------------------------------------------------


def _first_failure(states: FloatArray, time: FloatArray) -> tuple[NDArray[np.bool_], FloatArray]:
    finite = np.all(np.isfinite(states), axis=2)  # (B, n_t)
    ok = finite.all(axis=1)
    fail_time = np.full(states.shape[0], np.nan)
    for b in np.flatnonzero(~ok):
        fail_time[b] = time[int(np.argmin(finite[b]))]
    return ok, fail_time


def _along_path(
    run: Callable[[int], RawTrajectory],
    m: int,
    f: BatchFunction,
    time: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
) -> tuple[RawTrajectory, int]:
    """`run(m)`, rerun with the substeps the first member's path asks for where the
    rule at its start gave fewer (a nonlinear model stiffens where its states have
    grown; a step too coarse blows the path up): the last trajectory and its count."""
    traj = run(m)
    member = {k: np.asarray(v)[:1] for k, v in p.items()}
    for _ in range(_PREVIEW_PASSES):
        need = trajectory_substeps(f, time, traj.states[0], u[0], member)
        if need <= m:
            break
        m = need
        traj = run(m)
    return traj, m


def path_substeps(
    f: BatchFunction, time: FloatArray, x0: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
) -> int | None:
    """The substeps the first member's path (x0 (n_x, B), u (B, n_t, n_u)) asks for where
    that is more than the rule at its start gives, else None: for a caller that fixes
    the count before it runs programs that read the rule at the start only (`infer`)."""
    member = {k: np.asarray(v)[:1] for k, v in p.items()}
    first = auto_substeps(f, time, x0[:, :1], u[:1], member)
    _, m = _along_path(
        lambda k: rk4(f, time, x0[:, :1], u[:1], member, k), first, f, time, u, member
    )
    return m if m > first else None


def euler(
    f: BatchFunction,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
) -> RawTrajectory:
    """Forward Euler on the grid, controls held at each interval's start; x0 (n_x, B)."""
    n_t = time.size
    out = np.empty((n_t, x0.shape[0], x0.shape[1]))
    x = np.array(x0, dtype=np.float64)
    out[0] = x
    with np.errstate(all="ignore"):
        for k in range(n_t - 1):
            h = float(time[k + 1] - time[k])
            x = x + h * f(float(time[k]), x, np.ascontiguousarray(u[:, k, :].T), p)
            out[k + 1] = x
    states = np.transpose(out, (2, 0, 1))
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


def rk4(
    f: BatchFunction,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
    interpolation: Interpolation = "linear",
    *,
    hold: bool = False,
) -> RawTrajectory:
    """Fixed-step RK4; x0 (n_x, B), u (B, n_t, n_u); controls held with `hold`."""
    n_t = time.size
    batch = x0.shape[1]
    m = int(substeps)
    nodes = control_nodes(u, m, time, interpolation, hold=hold)
    out = np.empty((n_t, x0.shape[0], batch))
    x = np.array(x0, dtype=np.float64)
    out[0] = x
    with np.errstate(all="ignore"):
        for k in range(n_t - 1):
            t0 = float(time[k])
            t1 = float(time[k + 1])
            h = (t1 - t0) / m
            hh = 0.5 * h
            inside = _INSIDE * (t1 - t0)
            nk = nodes[k]
            for j in range(m):
                ta = t0 + j * h
                um = nk[2 * j + 1]
                k1 = f(t0 + inside if j == 0 else ta, x, nk[2 * j], p)
                k2 = f(ta + hh, x + hh * k1, um, p)
                k3 = f(ta + hh, x + hh * k2, um, p)
                k4 = f(t1 - inside if j == m - 1 else ta + h, x + h * k3, nk[2 * j + 2], p)
                x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
            out[k + 1] = x
            if k % 64 == 63 and not np.any(np.isfinite(x)):
                out[k + 2 :] = np.nan
                break
    states = np.transpose(out, (2, 0, 1))
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


def solve_ivp_batch(
    f: BatchFunction,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    method: str,
    rtol: float,
    atol: float,
    interpolation: Interpolation = "linear",
) -> RawTrajectory:
    """The whole batch as one stacked ODE through `scipy.integrate.solve_ivp`."""
    import scipy.integrate  # on first use: half a second that a rerun or `aeroid status` skips

    excess = None if interpolation == "linear" else _cubic_excess(time, u, interpolation)
    if method in _BY_INTERVAL:
        return _runge_kutta_by_interval(
            getattr(scipy.integrate, method), f, time, x0, u, p, rtol, atol, excess
        )
    n_x, batch = x0.shape
    n_u = u.shape[2]
    max_step = float(np.min(np.diff(time)))
    # the furthest time the solver evaluated finite states at: where an implicit method
    # that raises on a non-finite Jacobian stopped (it returns no partial solution)
    reached = [float(time[0])]

    def rhs(t: float, z: FloatArray) -> FloatArray:
        if t > reached[0] and np.all(np.isfinite(z)):
            reached[0] = t
        k = int(np.clip(np.searchsorted(time, t, side="right") - 1, 0, time.size - 2))
        w = (t - time[k]) / (time[k + 1] - time[k])
        if excess is None:
            uu = (u[:, k, :] * (1.0 - w) + u[:, k + 1, :] * w).T.reshape(n_u, batch)
        else:
            w = min(max(w, 0.0), 1.0)
            uk = hermite(u[:, k, :], u[:, k + 1, :], excess[0][:, k, :], excess[1][:, k, :], w)
            uu = np.ascontiguousarray(uk.T)
        return _finite_rates(f(t, z.reshape(n_x, batch), uu, p).reshape(-1))

    with np.errstate(all="ignore"):
        try:
            sol = scipy.integrate.solve_ivp(
                rhs,
                (float(time[0]), float(time[-1])),
                x0.reshape(-1),
                method=method,
                t_eval=time,
                rtol=rtol,
                atol=atol,
                max_step=max_step,
            )
        except AeroidError:  # the user's function raised or misbehaved: say so
            raise
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            sol = None
    states = np.full((batch, time.size, n_x), np.nan)
    returned = 0
    if sol is not None and sol.y.size:
        got = sol.y.reshape(n_x, batch, -1)
        returned = got.shape[2]
        states[:, :returned, :] = np.transpose(got, (1, 2, 0))
    ok, fail_time = _first_failure(states, time)
    if sol is None or not sol.success:
        ok[:] = False
        # past the samples returned (an implicit method that raised returns none) the
        # failure is where the solver last saw finite states
        last = time[min(int(np.searchsorted(time, reached[0])), time.size - 1)]
        end = time[returned] if returned < time.size else np.inf
        fail_time[np.isnan(fail_time) | (fail_time >= end)] = max(last, time[max(returned - 1, 0)])
    return RawTrajectory(states, ok, fail_time)


def _interval_rhs(
    f: BatchFunction,
    t0: float,
    t1: float,
    u0: FloatArray,
    u1: FloatArray,
    p: Mapping[str, FloatArray],
    n_x: int,
    excess: tuple[FloatArray, FloatArray] | None = None,
) -> Callable[[float, FloatArray], FloatArray]:
    """The stacked right-hand side on [t0, t1]: controls interpolated between the two
    samples (straight, or the cubic whose `hermite` excess is given, (n_u, B) each),
    times held `_INSIDE` of the interval within it (one-sided limits)."""
    lo, hi = t0 + _INSIDE * (t1 - t0), t1 - _INSIDE * (t1 - t0)
    du = u1 - u0

    def rhs(t: float, y: FloatArray) -> FloatArray:
        tc = min(max(t, lo), hi)
        if excess is None:
            uu = u0 + du * ((tc - t0) / (t1 - t0))
        else:
            uu = hermite(u0, u1, excess[0], excess[1], (tc - t0) / (t1 - t0))
        return _finite_rates(np.asarray(f(tc, y.reshape(n_x, -1), uu, p)).reshape(-1))

    return rhs


class _NotFinite(ArithmeticError):
    """A right-hand side that is not finite: an adaptive solver would shrink its step
    after it forever (SciPy's error norm is NaN, and NaN never meets its limit)."""


def _finite_rates(rates: FloatArray) -> FloatArray:
    if not np.all(np.isfinite(rates)):
        raise _NotFinite
    return rates


def _runge_kutta_by_interval(
    solver: Any,
    f: BatchFunction,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    rtol: float,
    atol: float,
    excess: tuple[FloatArray, FloatArray] | None = None,
) -> RawTrajectory:
    """An adaptive explicit Runge-Kutta pair restarted at every sample (module notes);
    `excess`: the cubic controls' `hermite` a and b, (B, n_t - 1, n_u) each."""
    n_x, batch = x0.shape
    states = np.full((batch, time.size, n_x), np.nan)
    states[:, 0, :] = x0.T
    z = np.array(x0, dtype=np.float64).reshape(-1)
    first: float | None = None
    with np.errstate(all="ignore"):
        for k in range(time.size - 1):
            t0, t1 = float(time[k]), float(time[k + 1])
            ex = None if excess is None else (excess[0][:, k, :].T, excess[1][:, k, :].T)
            rhs = _interval_rhs(f, t0, t1, u[:, k, :].T, u[:, k + 1, :].T, p, n_x, ex)
            try:
                step = solver(
                    rhs, t0, z, t1, rtol=rtol, atol=atol, first_step=first and min(first, t1 - t0)
                )
                while step.status == "running":
                    step.step()
            except AeroidError:  # the user's function raised or misbehaved: say so
                raise
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):
                break
            if step.status != "finished" or not np.all(np.isfinite(step.y)):
                break
            z = step.y
            states[:, k + 1, :] = z.reshape(n_x, batch).T
            # the next interval starts from the step size this one would have taken next
            first = float(getattr(step, "h_abs", 0.0)) or None
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


# -- exact discretisation for linear time-invariant dynamics ----------------------------


@dataclass(frozen=True)
class _Layout(FrozenState):
    """The points `lti_form` evaluates, for one time grid, batch size and check kind.

    Columns: the unit perturbations at ``time[0]`` (probe-major, member-minor),
    then the checks: every member at every sample time (member-major,
    time-minor), or one member per sample time in turn and each member once
    more at the last sample.
    """

    t: FloatArray  # (N,) time of each point
    member: NDArray[np.intp]  # (N,) batch member of each point
    z: FloatArray  # (n_x + n_u + 1, N): x, u and a row of ones
    z_max: float  # largest |x| or |u| among the checks
    n_head: int  # columns of unit perturbations


_LAYOUTS: dict[tuple[Any, ...], _Layout] = {}


def _layout(
    time: FloatArray, grid: tuple[int, int], n_x: int, n_u: int, batch: int, kind: str
) -> _Layout:
    key = (grid, n_x, n_u, batch, kind)
    if key in _LAYOUTS:
        return _LAYOUTS[key]
    if len(_LAYOUTS) >= 16:
        _LAYOUTS.pop(next(iter(_LAYOUTS)))
    n_t = time.size
    n_in = n_x + n_u
    n_probe = 1 + n_in
    n_head = n_probe * batch
    head_member = np.tile(np.arange(batch), n_probe)
    if kind == "probe":
        tail_t, tail_member = np.empty(0), np.empty(0, dtype=np.intp)
    elif kind == "all":
        tail_t, tail_member = np.tile(time, batch), np.repeat(np.arange(batch), n_t)
    else:  # "turns"
        tail_t = np.concatenate([time, np.full(batch, time[-1])])
        tail_member = np.concatenate([np.arange(n_t) % batch, np.arange(batch)])
    n_check = tail_t.size
    z = np.ones((n_in + 1, n_head + n_check))
    z[:n_in, :batch] = 0.0
    z[:n_in, batch:n_head] = np.repeat(np.eye(n_in), batch, axis=1)
    rng = np.random.default_rng(0)
    scale = np.where(np.arange(n_check) % 2 == 0, 1.0, 10.0)
    z[:n_in, n_head:] = rng.standard_normal((n_in, n_check)) * scale
    t = np.concatenate([np.full(n_head, float(time[0])), tail_t])
    member = np.concatenate([head_member, tail_member]).astype(np.intp)
    for arr in (t, member, z):
        arr.flags.writeable = False
    z_max = float(np.max(np.abs(z[:n_in, n_head:]), initial=1.0))
    out = _LAYOUTS[key] = _Layout(t, member, z, z_max, n_head)
    return out


def lti_form(
    f: BatchFunction,
    time: FloatArray,
    n_x: int,
    n_u: int,
    p: Mapping[str, FloatArray],
    *,
    trusted: bool = False,
) -> tuple[tuple[FloatArray, FloatArray, FloatArray] | None, bool]:
    """``((A, B, c), False)`` when ``f(t, x, u) = A x + B u + c`` on all of `time`, per member.

    Works for any batched function of (t, x, u, p): the dynamics (A is n_x by
    n_x) or a measurement (A is n_y by n_x). A, B and c come from unit
    perturbations at ``time[0]``, one batch member per parameter vector of
    `p`. Unless the form is `trusted` (declared by the model and verified when
    it was built), it is checked, in the same batched call, at a pseudo-random
    state and control at every sample time for every member: a forcing that
    switches off, a scheduled gain or a nonlinear term shows up as a mismatch.
    A parameter vector can make a nonlinear term vanish, so every member is
    checked, not only the first. Once the function has passed that on a time
    grid, later calls on the same grid (an identification's iterations) check
    one point per sample time, the members taking turns, and each member once
    more at the last sample: every sample time and every member still, at a
    fraction of the cost. A function that does not broadcast is evaluated
    point by point, so it always gets that lighter check.

    Returns ``(None, True)`` when the function is shown not to have that form
    (callers may remember it; a non-finite value at a finite point with finite
    parameters shows it too), and ``(None, False)`` when it could not be
    evaluated (an exception, or non-finite parameters): the integrator then
    meets the failure where it happens and reports it.
    """
    batch = next(iter(p.values())).shape[0] if p else 1
    n_out = f.n_out
    n_in = n_x + n_u
    grid = (time.size, hash(time.tobytes()))
    if trusted:
        kind = "probe"
    else:
        if f.broadcasts is None:  # decide first: it sets how many points to check
            probe = _layout(time, grid, n_x, n_u, batch, "probe")
            try:
                with np.errstate(all="ignore"):
                    f.detect(
                        float(time[0]),
                        probe.z[:n_x],
                        probe.z[n_x:n_in],
                        {k: v[probe.member] for k, v in p.items()},
                    )
            except Exception:  # the integrator reports it, at the time it happens
                return None, False
        kind = "all" if f.broadcasts and grid not in f.lti_grids else "turns"
    lay = _layout(time, grid, n_x, n_u, batch, kind)
    z = lay.z
    P = {k: v[lay.member] for k, v in p.items()}
    try:
        with np.errstate(all="ignore"):
            if trusted:
                got = f(float(time[0]), z[:n_x], z[n_x:n_in], P)
            else:
                got = f.at_times(lay.t, z[:n_x], z[n_x:n_in], P)
    except Exception:  # the integrator reports it, at the time it happens
        return None, False
    vals = got[:, : lay.n_head].reshape(n_out, 1 + n_in, batch)
    if not np.all(np.isfinite(vals)):
        # an affine function with finite coefficients is finite at every finite point:
        # with finite parameters, this one is not affine (a division by the airspeed)
        return None, _finite(p)
    c = vals[:, 0, :]  # (n_out, B)
    M = np.empty((batch, n_out, n_in + 1))  # [A, B, c] per member
    M[:, :, :n_in] = np.transpose(vals[:, 1:, :] - c[:, None, :], (2, 0, 1))
    M[:, :, n_in] = c.T
    mats = (
        np.ascontiguousarray(M[:, :, :n_x]),
        np.ascontiguousarray(M[:, :, n_x:n_in]),
        np.ascontiguousarray(c.T),
    )
    if trusted:
        return mats, False
    # |f - (A x + B u + c)| against the size of the terms, bounded by max|z| sum_k |M_ik|
    tol = 1e-9 * lay.z_max * np.sum(np.abs(M), axis=2)  # (B, n_out)
    zc = z[:, lay.n_head :]
    fc = got[:, lay.n_head :]
    if kind == "all":
        n_t = time.size
        zb = np.transpose(zc.reshape(n_in + 1, batch, n_t), (1, 0, 2))  # (B, n_in + 1, n_t)
        miss = M @ zb  # in place from here: these arrays are large
        np.subtract(np.transpose(fc.reshape(n_out, batch, n_t), (1, 0, 2)), miss, out=miss)
        ok = bool(np.all(np.abs(miss, out=miss) <= tol[:, :, None]))
    else:
        member = lay.member[lay.n_head :]
        # every member's prediction at every point (one small matmul), then each point's own
        pred = (M @ zc)[member, :, np.arange(member.size)]  # (N, n_out)
        ok = bool(np.all(np.abs(fc.T - pred) <= tol[member]))
    if ok:
        if kind == "all":
            if len(f.lti_grids) >= 16:
                f.lti_grids.pop(next(iter(f.lti_grids)))
            f.lti_grids[grid] = None
        return mats, False
    return None, bool(np.all(np.isfinite(fc))) or _finite(p)


def _finite(p: Mapping[str, FloatArray]) -> bool:
    return all(bool(np.all(np.isfinite(v))) for v in p.values())


def _linear_recursion(phi: FloatArray, x0: FloatArray, forcing: FloatArray) -> FloatArray:
    """States x_1..x_T of x_{k+1} = phi x_k + forcing_k, batched: phi (B, n, n), x0 (B, n),
    forcing (B, T, n).

    A step-by-step loop costs a few microseconds of Python per sample, more
    than the arithmetic. In blocks of L ~ sqrt(T) samples the loop runs about
    2 sqrt(T) times: once over the position in a block (every block at once,
    each from a zero state), once over the blocks (their start states, with
    phi^L), and the two combine as x_{kL+i} = phi^i x_{kL} + (block response).
    The sums are the same, in a different order: the states agree with the
    step-by-step loop to rounding (a few ulp).
    """
    batch, n_t, n_x = forcing.shape
    phi_t = np.ascontiguousarray(np.transpose(phi, (0, 2, 1)))
    size = int(np.ceil(np.sqrt(n_t)))
    powers_t: FloatArray | None = None
    if n_t >= 64:  # shorter records gain nothing
        powers_t = np.empty((batch, size, n_x, n_x))  # (phi^(i+1))^T
        powers_t[:, 0] = phi_t
        for i in range(1, size):
            powers_t[:, i] = np.matmul(powers_t[:, i - 1], phi_t)
    if powers_t is None or not np.all(np.isfinite(powers_t[:, -1])):
        # the plain loop; also when phi^L overflows, where inf * 0 in the blocks would
        # fail states the loop computes
        out = np.empty((batch, n_t, n_x))
        x = x0
        for k in range(n_t):
            x = np.matmul(x[:, None, :], phi_t)[:, 0, :] + forcing[:, k]
            out[:, k] = x
        return out
    n_blk = -(-n_t // size)
    f = np.zeros((batch, n_blk * size, n_x))
    f[:, :n_t] = forcing
    f = f.reshape(batch, n_blk, size, n_x)
    # response[:, k, i]: block k's state after i + 1 steps from a zero start
    response = np.empty((batch, n_blk, size, n_x))
    g = f[:, :, 0]
    response[:, :, 0] = g
    for i in range(1, size):
        g = np.matmul(g, phi_t) + f[:, :, i]
        response[:, :, i] = g
    starts = np.empty((batch, n_blk, n_x))
    x = x0
    for k in range(n_blk):
        starts[:, k] = x
        x = np.matmul(x[:, None, :], powers_t[:, -1])[:, 0, :] + response[:, k, -1]
    free = np.matmul(starts[:, None, :, :], powers_t)  # (B, size, n_blk, n_x)
    states = np.transpose(free, (0, 2, 1, 3)) + response
    return states.reshape(batch, n_blk * size, n_x)[:, :n_t]


def hold_augmented(A: FloatArray, Bm: FloatArray, c: FloatArray) -> FloatArray:
    """The augmented matrix whose exponential discretises ``x' = A x + B u + c`` for
    controls piecewise-linear between samples: for a step h, ``expm(M h)`` holds Phi
    in ``[:n, :n]``, the gains of the step's first control value and (divided by h)
    of its change in the next two column blocks, and the constant's in the last
    column. A, Bm and c are batched: (B, n, n), (B, n, n_u), (B, n)."""
    batch, n_x, _ = A.shape
    n_u = Bm.shape[2]
    n_aug = n_x + 2 * n_u + 1
    M = np.zeros((batch, n_aug, n_aug))
    M[:, :n_x, :n_x] = A
    M[:, :n_x, n_x : n_x + n_u] = Bm
    M[:, n_x : n_x + n_u, n_x + n_u : n_x + 2 * n_u] = np.eye(n_u)
    M[:, :n_x, -1] = c
    return M


def exact_lti(
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    A: FloatArray,
    Bm: FloatArray,
    c: FloatArray,
) -> RawTrajectory | None:
    """Exact solution for piecewise-linear inputs; None when the grid has too many step sizes."""
    from .._linalg import expm  # plain numpy: importing scipy.linalg costs more than the solve

    batch, n_x, _ = A.shape
    n_u = Bm.shape[2]
    dts = np.diff(time)
    uniq, inverse = np.unique(np.round(dts / dts[0], 9), return_inverse=True)
    if uniq.size > _EXACT_STEP_SIZES:
        return None
    M = hold_augmented(A, Bm, c)
    phis = []
    gam = []
    for r in uniq:
        h = float(r * dts[0])
        E = expm(M * h)  # (B, n_aug, n_aug)
        phis.append(E[:, :n_x, :n_x])
        gam.append(
            (E[:, :n_x, n_x : n_x + n_u], E[:, :n_x, n_x + n_u : n_x + 2 * n_u] / h, E[:, :n_x, -1])
        )
    states = np.empty((batch, time.size, n_x))
    x = x0.T.copy()  # (B, n_x)
    states[:, 0] = x
    du = u[:, 1:, :] - u[:, :-1, :]  # (B, n_t-1, n_u)
    if uniq.size == 1:
        Gw, Gv, gc = gam[0]
        forcing = (
            np.einsum("bij,bkj->bki", Gw, u[:, :-1, :])
            + np.einsum("bij,bkj->bki", Gv, du)
            + gc[:, None, :]
        )
        with np.errstate(all="ignore"):
            states[:, 1:] = _linear_recursion(phis[0], x, forcing)
    else:
        with np.errstate(all="ignore"):
            for k in range(time.size - 1):
                i = inverse[k]
                Gw, Gv, gc = gam[i]
                x = (
                    np.einsum("bij,bj->bi", phis[i], x)
                    + np.einsum("bij,bj->bi", Gw, u[:, k])
                    + np.einsum("bij,bj->bi", Gv, du[:, k])
                    + gc
                )
                states[:, k + 1] = x
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


# -- front door ---------------------------------------------------------------------------


def linear_path(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    method: str,
    interpolation: Interpolation = "linear",
) -> RawTrajectory | None:
    """`integrate`'s exact solution where `method` takes it and the dynamics are linear
    time-invariant on the record; else None (a model shown not to be is remembered, so
    later calls skip the check). x0 (B, n_x), u (B, n_t, n_u), p name -> (B,)."""
    f = model._dynamics_batch
    if f.broadcasts is None and x0.shape[0] >= 2:
        f.detect(float(time[0]), np.ascontiguousarray(x0.T), np.ascontiguousarray(u[:, 0, :].T), p)
    if interpolation != "linear":
        if method == "exact":
            raise SimulationError(
                f"method='exact' discretises controls linear between samples; "
                f"control_interpolation={interpolation!r} needs 'rk4', 'auto' or a solve_ivp "
                f"method (model {model.name!r})"
            )
        return None  # "auto": RK4 sees the cubic
    if method in ("auto", "exact") and model._maybe_lti:
        mats, not_lti = lti_form(
            f, time, model.n_states, model.n_controls, p, trusted=model.linear is True
        )
        if mats is not None:
            traj = exact_lti(time, x0.T, u, *mats)
            if traj is not None:
                return traj
            if method == "exact":  # the model is linear: the grid is what it cannot take
                steps = np.unique(np.round(np.diff(time) / (time[1] - time[0]), 9)).size
                raise SimulationError(
                    f"method='exact' takes at most {_EXACT_STEP_SIZES} distinct sample "
                    f"intervals; this time grid has {steps} (jittered stamps?): resample it, "
                    f"or use method='auto' (model {model.name!r})"
                )
        elif not_lti and method == "auto":
            # Shown not to be LTI: remember, so later calls skip the check.
            object.__setattr__(model, "_maybe_lti", False)
        if method == "exact":
            raise SimulationError(
                f"method='exact' needs dynamics affine in state and control and independent "
                f"of time over the record; model {model.name!r} is not"
            )
    elif method == "exact":
        raise SimulationError(
            f"method='exact' is not available for model {model.name!r} (not linear)"
        )
    return None


def integrate(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    *,
    method: str = "auto",
    substeps: int | None = None,
    rtol: float = 1e-9,
    atol: float = 1e-12,
    compiled_rk4: Callable[..., RawTrajectory | None] | None = None,
    control_interpolation: Interpolation = "linear",
) -> RawTrajectory:
    """Integrate a batch: x0 (B, n_x), u (B, n_t, n_u), p name -> (B,).

    `compiled_rk4` (``_compiled.rk4_hook``, passed by the model, which sits above
    both) runs the same RK4 compiled where that pays, returning None where not, the
    controls straight or cubic (its program takes `control_excess` beside them).
    """
    if method not in METHODS:
        raise SimulationError(f"method {method!r} is unknown; choose one of {list(METHODS)}")
    if substeps is not None and (int(substeps) != substeps or substeps < 1):
        raise SimulationError(f"substeps must be a positive integer, got {substeps!r}")
    how = check_control_interpolation(control_interpolation)
    cubic = how != "linear"
    if cubic and method in ("euler", "rk4_hold"):
        raise SimulationError(
            f"method={method!r} holds the controls at each interval's first sample; "
            f"control_interpolation={control_interpolation!r} needs 'rk4', 'auto' or a "
            f"solve_ivp method (model {model.name!r})"
        )
    if model.n_states == 0:
        # outputs algebraic in the controls: nothing to integrate, nothing can diverge
        batch = x0.shape[0]
        empty = np.zeros((batch, time.size, 0))
        return RawTrajectory(empty, np.ones(batch, dtype=bool), np.full(batch, np.nan))
    f = model._dynamics_batch
    X0 = np.ascontiguousarray(x0.T)
    traj = linear_path(model, time, x0, u, p, method, control_interpolation)
    if traj is not None:
        return traj
    if method in ("auto", "rk4"):
        m = substeps if substeps is not None else auto_substeps(f, time, X0, u, p)

        def run(m: int) -> RawTrajectory:
            if compiled_rk4 is not None:
                compiled = compiled_rk4(model, time, X0, u, p, int(m), how)
                if compiled is not None:
                    return compiled
            return rk4(f, time, X0, u, p, int(m), control_interpolation)

        if substeps is not None:
            return run(m)
        return _along_path(run, m, f, time, u, p)[0]
    if method == "rk4_hold":
        return rk4(f, time, X0, u, p, int(substeps or 1), hold=True)
    if method == "euler":
        return euler(f, time, X0, u, p)
    how_ivp = (method, rtol, atol, control_interpolation)
    traj = solve_ivp_batch(f, time, X0, u, p, *how_ivp)
    if traj.ok.all() or traj.ok.size == 1:
        return traj
    # one member's divergence stops the stacked solve for all: each member again alone
    for b in range(traj.ok.size):
        one = solve_ivp_batch(f, time, X0[:, b : b + 1], u[b : b + 1], _member(p, b), *how_ivp)
        traj.states[b], traj.ok[b], traj.fail_time[b] = one.states[0], one.ok[0], one.fail_time[0]
    return traj


def _member(p: Mapping[str, FloatArray], b: int) -> dict[str, FloatArray]:
    """Member `b`'s parameters of a batch's (one value for all stays one)."""
    return {k: v[b : b + 1] if np.ndim(v) and np.shape(v)[0] > 1 else v for k, v in p.items()}
