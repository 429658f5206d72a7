"""Batched integration of a model's ODE on a measurement time grid.

Three integrators share one contract: states land exactly on the grid, the
controls are piecewise-linear between samples, and a batch of parameter
vectors (and, optionally, of control histories) is integrated in one pass.

* ``"exact"``: for dynamics affine in state and control and independent of
  time, the zero-order-hold-free exact discretisation for piecewise-linear
  inputs (a matrix exponential per grid step size).
* ``"rk4"``: classical Runge-Kutta with ``substeps`` steps per grid interval;
  no step ever straddles a control breakpoint.
* any `scipy.integrate.solve_ivp` method name, integrating the stacked batch
  with ``max_step`` no larger than the grid spacing so a late input can never
  be stepped over.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .errors import SimulationError

if TYPE_CHECKING:
    from .model import Model

FloatArray = NDArray[np.float64]
UserFunction = Callable[[Any, Any, Any, Mapping[str, Any]], Any]

SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
METHODS = ("auto", "exact", "rk4", *SOLVE_IVP_METHODS)
_MAX_AUTO_SUBSTEPS = 256


def import_solvers() -> None:
    """Load SciPy's integrators and `expm` now (they are otherwise imported on first use)."""
    import scipy.integrate
    import scipy.linalg  # noqa: F401


class BatchFunction:
    """Evaluate a user function ``f(t, x, u, p)`` on a batch of points.

    The user's function is called once with arrays of shape (n, batch) when it
    broadcasts (checked once, against member-by-member calls), and in a loop
    otherwise.
    """

    def __init__(self, fun: UserFunction, n_out: int, parameter_names: tuple[str, ...]) -> None:
        self.fun = fun
        self.n_out = n_out
        self.parameter_names = parameter_names
        self.broadcasts: bool | None = None

    def _single(self, t: float, x: FloatArray, u: FloatArray, p: Mapping[str, float]) -> FloatArray:
        out = np.asarray(self.fun(t, x, u, p), dtype=np.float64)
        return out.reshape(self.n_out) if out.size == self.n_out else out

    def _loop(
        self, t: Any, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        batch = x.shape[1]
        tt = np.broadcast_to(np.asarray(t, dtype=np.float64), (batch,))
        out = np.empty((self.n_out, batch))
        for b in range(batch):
            pb = {k: float(v[b]) for k, v in p.items()}
            out[:, b] = self._single(float(tt[b]), x[:, b], u[:, b], pb)
        return out

    def detect(self, t: float, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]) -> None:
        """Decide once whether the function broadcasts over a batch axis."""
        batch = x.shape[1]
        if batch < 2:
            return
        reference = self._loop(t, x, u, p)
        try:
            with np.errstate(all="ignore"):
                trial = np.asarray(self.fun(t, x, u, p), dtype=np.float64)
            ok = trial.shape == (self.n_out, batch) and np.allclose(
                trial, reference, rtol=1e-10, atol=1e-300, equal_nan=True
            )
        except Exception:  # any failure means "does not broadcast"
            ok = False
        self.broadcasts = bool(ok)

    def __call__(
        self, t: Any, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        if self.broadcasts is None:
            self.detect(float(np.ravel(t)[0]), x, u, p)
        if self.broadcasts:
            return np.asarray(self.fun(t, x, u, p), dtype=np.float64)
        return self._loop(t, x, u, p)


@dataclass(frozen=True)
class RawTrajectory:
    """Integrator output: states (batch, n_t, n_x), success mask, failure times."""

    states: FloatArray
    ok: NDArray[np.bool_]
    fail_time: FloatArray


# -- controls -----------------------------------------------------------------------


def control_nodes(u: FloatArray, substeps: int) -> FloatArray:
    """Controls at every RK4 node: shape (n_t - 1, 2*substeps + 1, n_u, batch)."""
    # u: (batch, n_t, n_u)
    frac = np.arange(2 * substeps + 1) / (2 * substeps)
    lo = u[:, :-1, None, :]
    hi = u[:, 1:, None, :]
    nodes = lo + frac[None, None, :, None] * (hi - lo)  # (B, n_t-1, 2m+1, n_u)
    return np.ascontiguousarray(np.transpose(nodes, (1, 2, 3, 0)))


# -- integrators ----------------------------------------------------------------------


def _first_failure(states: FloatArray, time: FloatArray) -> tuple[NDArray[np.bool_], FloatArray]:
    finite = np.all(np.isfinite(states), axis=2)  # (B, n_t)
    ok = finite.all(axis=1)
    fail_time = np.full(states.shape[0], np.nan)
    for b in np.flatnonzero(~ok):
        fail_time[b] = time[int(np.argmin(finite[b]))]
    return ok, fail_time


def spectral_radius(
    f: BatchFunction, t: float, x0: FloatArray, u0: FloatArray, p: Mapping[str, FloatArray]
) -> float:
    """Largest |eigenvalue| of df/dx over the batch at its initial points, by central differences."""
    n, batch = x0.shape
    if n == 0:
        return 0.0
    scale = np.maximum(np.abs(x0), 1.0) * 1e-6  # (n, B)
    # columns: for each member b, n "+" then n "-" perturbations
    eye = np.eye(n)
    plus = x0.T[:, :, None] + eye[None] * scale.T[:, :, None]  # (B, n, n): [b, state, col]
    minus = x0.T[:, :, None] - eye[None] * scale.T[:, :, None]
    pts = np.concatenate([plus, minus], axis=2).transpose(1, 0, 2).reshape(n, batch * 2 * n)
    pp = {k: np.repeat(v, 2 * n) for k, v in p.items()}
    uu = np.repeat(u0, 2 * n, axis=1)
    with np.errstate(all="ignore"):
        vals = f(t, pts, uu, pp).reshape(n, batch, 2 * n)
    jac = (vals[:, :, :n] - vals[:, :, n:]) / (2 * scale.T[None, :, :])  # (n_out, B, n_in)
    jac = jac.transpose(1, 0, 2)
    finite = np.all(np.isfinite(jac), axis=(1, 2))
    if not np.any(finite):
        return 0.0
    return float(np.max(np.abs(np.linalg.eigvals(jac[finite]))))


def auto_substeps(
    f: BatchFunction, time: FloatArray, x0: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
) -> int:
    rho = spectral_radius(f, float(time[0]), x0, u[:, 0, :].T, p)
    h = float(np.max(np.diff(time)))
    # h*rho <= 0.05 keeps the RK4 error of the fastest mode near 1e-8 per unit time.
    return int(min(max(1, math.ceil(h * rho / 0.05)), _MAX_AUTO_SUBSTEPS))


def rk4(
    f: BatchFunction,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
) -> RawTrajectory:
    """Fixed-step RK4; x0 (n_x, B), u (B, n_t, n_u)."""
    n_t = time.size
    batch = x0.shape[1]
    m = int(substeps)
    nodes = control_nodes(u, m)
    out = np.empty((n_t, x0.shape[0], batch))
    x = np.array(x0, dtype=np.float64)
    out[0] = x
    with np.errstate(all="ignore"):
        for k in range(n_t - 1):
            t0 = float(time[k])
            h = (float(time[k + 1]) - t0) / m
            hh = 0.5 * h
            nk = nodes[k]
            for j in range(m):
                ta = t0 + j * h
                um = nk[2 * j + 1]
                k1 = f(ta, x, nk[2 * j], p)
                k2 = f(ta + hh, x + hh * k1, um, p)
                k3 = f(ta + hh, x + hh * k2, um, p)
                k4 = f(ta + h, x + h * k3, nk[2 * j + 2], p)
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
) -> RawTrajectory:
    """The whole batch as one stacked ODE through `scipy.integrate.solve_ivp`."""
    import scipy.integrate  # on first use: half a second that a rerun or `aeroid status` skips

    n_x, batch = x0.shape
    n_u = u.shape[2]
    max_step = float(np.min(np.diff(time)))

    def rhs(t: float, z: FloatArray) -> FloatArray:
        k = int(np.clip(np.searchsorted(time, t, side="right") - 1, 0, time.size - 2))
        w = (t - time[k]) / (time[k + 1] - time[k])
        uu = (u[:, k, :] * (1.0 - w) + u[:, k + 1, :] * w).T.reshape(n_u, batch)
        return f(t, z.reshape(n_x, batch), uu, p).reshape(-1)

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
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            sol = None
    states = np.full((batch, time.size, n_x), np.nan)
    if sol is not None and sol.y.size:
        got = sol.y.reshape(n_x, batch, -1)
        states[:, : got.shape[2], :] = np.transpose(got, (1, 2, 0))
    ok, fail_time = _first_failure(states, time)
    if sol is not None and not sol.success:
        ok[:] = False
        fail_time[np.isnan(fail_time)] = float(sol.t[-1]) if sol.t.size else float(time[0])
    return RawTrajectory(states, ok, fail_time)


# -- exact discretisation for linear time-invariant dynamics ----------------------------


def affine_matrices(
    f: BatchFunction,
    t: float,
    n_x: int,
    n_u: int,
    p: Mapping[str, FloatArray],
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Return (A, B, c) per batch member if f is affine in x and u and time-invariant.

    Works for any batched function of (t, x, u, p): the dynamics (A is
    n_x by n_x) or a measurement (A is n_y by n_x). The matrices come from
    unit perturbations; the affine form is then checked at random points and
    another time, and ``None`` means "not affine".
    """
    batch = next(iter(p.values())).shape[0] if p else 1
    n_out = f.n_out
    n_probe = 1 + n_x + n_u + 2
    xs = np.zeros((n_probe, n_x))
    us = np.zeros((n_probe, n_u))
    xs[1 : 1 + n_x] = np.eye(n_x)
    us[1 + n_x : 1 + n_x + n_u] = np.eye(n_u)
    xs[-2:] = rng.standard_normal((2, n_x)) * np.array([[1.0], [10.0]])
    us[-2:] = rng.standard_normal((2, n_u)) * np.array([[1.0], [10.0]])
    ts = np.full(n_probe, t)
    ts[-1] = t + 1.2345
    # batch layout: probe-major, member-minor
    X = np.repeat(xs, batch, axis=0).T
    U = np.repeat(us, batch, axis=0).T
    T = np.repeat(ts, batch)
    P = {k: np.tile(v, n_probe) for k, v in p.items()}
    with np.errstate(all="ignore"):
        try:
            vals = np.asarray(f(T, X, U, P), dtype=np.float64)
        except Exception:
            return None
    if vals.shape != (n_out, n_probe * batch):
        return None
    vals = vals.reshape(n_out, n_probe, batch)
    if not np.all(np.isfinite(vals)):
        return None
    c = vals[:, 0, :]  # (n_x, B)
    A = vals[:, 1 : 1 + n_x, :] - c[:, None, :]  # (n_out, n_x, B)
    Bm = vals[:, 1 + n_x : 1 + n_x + n_u, :] - c[:, None, :]
    for j in (n_probe - 2, n_probe - 1):
        pred = c + np.einsum("ijb,j->ib", A, xs[j]) + np.einsum("ijb,j->ib", Bm, us[j])
        scale = (
            np.abs(c)
            + np.einsum("ijb,j->ib", np.abs(A), np.abs(xs[j]))
            + np.einsum("ijb,j->ib", np.abs(Bm), np.abs(us[j]))
        )
        if not np.all(np.abs(vals[:, j, :] - pred) <= 1e-9 * scale + 1e-12):
            return None
    return (
        np.transpose(A, (2, 0, 1)).copy(),
        np.transpose(Bm, (2, 0, 1)).copy(),
        c.T.copy(),
    )


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


def exact_lti(
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    A: FloatArray,
    Bm: FloatArray,
    c: FloatArray,
) -> RawTrajectory | None:
    """Exact solution for piecewise-linear inputs; None when the grid has too many step sizes."""
    import scipy.linalg

    batch, n_x, _ = A.shape
    n_u = Bm.shape[2]
    dts = np.diff(time)
    uniq, inverse = np.unique(np.round(dts / dts[0], 9), return_inverse=True)
    if uniq.size > 64:
        return None
    n_aug = n_x + 2 * n_u + 1
    M = np.zeros((batch, n_aug, n_aug))
    M[:, :n_x, :n_x] = A
    M[:, :n_x, n_x : n_x + n_u] = Bm
    M[:, n_x : n_x + n_u, n_x + n_u : n_x + 2 * n_u] = np.eye(n_u)
    M[:, :n_x, -1] = c
    phis = []
    gam = []
    for r in uniq:
        h = float(r * dts[0])
        E = scipy.linalg.expm(M * h)  # (B, n_aug, n_aug)
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
) -> RawTrajectory:
    """Integrate a batch: x0 (B, n_x), u (B, n_t, n_u), p name -> (B,)."""
    if method not in METHODS:
        raise SimulationError(f"method {method!r} is unknown; choose one of {list(METHODS)}")
    if substeps is not None and (int(substeps) != substeps or substeps < 1):
        raise SimulationError(f"substeps must be a positive integer, got {substeps!r}")
    f = model._dynamics_batch
    X0 = np.ascontiguousarray(x0.T)
    if f.broadcasts is None and X0.shape[1] >= 2:
        f.detect(float(time[0]), X0, np.ascontiguousarray(u[:, 0, :].T), p)
    if method in ("auto", "exact") and model._maybe_lti:
        mats = affine_matrices(
            f, float(time[0]), model.n_states, model.n_controls, p, np.random.default_rng(0)
        )
        if mats is not None:
            traj = exact_lti(time, x0.T, u, *mats)
            if traj is not None:
                return traj
        elif method == "auto":
            # Not affine: remember, so later calls skip the probe.
            object.__setattr__(model, "_maybe_lti", False)
        if method == "exact":
            raise SimulationError(
                f"method='exact' needs dynamics affine in state and control and independent "
                f"of time; model {model.name!r} is not"
            )
    elif method == "exact":
        raise SimulationError(
            f"method='exact' is not available for model {model.name!r} (not linear)"
        )
    if method in ("auto", "rk4"):
        m = substeps if substeps is not None else auto_substeps(f, time, X0, u, p)
        return rk4(f, time, X0, u, p, int(m))
    return solve_ivp_batch(f, time, X0, u, p, method, rtol, atol)
