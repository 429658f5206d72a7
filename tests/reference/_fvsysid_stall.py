"""FVSysID's output-error method in plain numpy (reference code, not the library).

Written after the algorithm of Jategaonkar's ``ml_oem2.m`` (chapter 4 of FVSysID):
maximum-likelihood output error by relaxation. Each iteration estimates the noise
covariance as the diagonal of the residual covariance (``costfun_oem.m``), takes the
determinant as the cost, and, while the cost falls, a Gauss-Newton step from the
information matrix and gradient of one-sided finite-difference response gradients
(relative perturbation 1e-6, ``gradFG.m``/``gradrespH.m``); a rise in the cost halves
the last step (at most ten times). It stops when the relative change in the cost is
below the tolerance (1e-4). The state equations are integrated by FVSysID's
fourth-order Runge-Kutta (``ruku4.m``: the input averaged at the half step), per
segment; a model without states (``state_eq=None``) is a regression whose outputs
come from the inputs alone. Where bounds are given the step is the bounded-variable
Gauss-Newton step (``improv.m``, ``chk_lub_opt.m``, ``chk_update.m``): a parameter
whose step crosses a bound is set on it and held there while the gradient pushes it
outwards (FVSysID's quadratic line search after a bound is hit is left out). The
Cramer-Rao covariance is the inverse of the information matrix of the last
Gauss-Newton step, as ``ml_oem2.m`` reports it, its rows of parameters on a bound zeroed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

StateEq = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
ObsEq = Callable[[Any, np.ndarray, np.ndarray], np.ndarray]


@dataclass
class OemResult:
    """What ``ml_oem`` returns: estimates, outputs per segment, noise covariance and CRB."""

    p: np.ndarray
    y: list[np.ndarray]
    R: np.ndarray
    crb: np.ndarray
    cost: list[float] = field(default_factory=list)
    iterations: int = 0
    active: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def se(self) -> np.ndarray:
        """Cramer-Rao standard deviations (zero where fixed or on a bound)."""
        return np.sqrt(np.clip(np.diag(self.crb), 0.0, None))


def rk4_step(
    f: StateEq, x: np.ndarray, u1: np.ndarray, u2: np.ndarray, p: np.ndarray, dt: float
) -> np.ndarray:
    """One step of ruku4: half-step stages with the input averaged over the interval."""
    um = 0.5 * (u1 + u2)
    k1 = f(x, u1, p)
    k2 = f(x + 0.5 * dt * k1, um, p)
    k3 = f(x + 0.5 * dt * k2, um, p)
    k4 = f(x + dt * k3, u2, p)
    return x + dt * (k1 + 2.0 * (k2 + k3) + k4) / 6.0


def simulate(
    state_eq: StateEq | None,
    obs_eq: ObsEq,
    x0: Sequence[Any],
    us: Sequence[np.ndarray],
    dt: float,
    p: np.ndarray,
) -> list[np.ndarray]:
    """Outputs of every segment (list of (n_k, ny)); a stateless model evaluates
    ``obs_eq(x, u, p)`` with ``x`` None on all samples at once (u of shape (n, nu))."""
    out = []
    for k, u in enumerate(us):
        if state_eq is None:
            out.append(np.asarray(obs_eq(None, u, p), dtype=float))
            continue
        x = np.asarray(x0[k], dtype=float).copy()
        ys = []
        for i in range(u.shape[0]):
            ys.append(obs_eq(x, u[i], p))
            if i + 1 < u.shape[0]:
                x = rk4_step(state_eq, x, u[i], u[i + 1], p, dt)
        out.append(np.asarray(ys, dtype=float))
    return out


def ml_oem(
    state_eq: StateEq | None,
    obs_eq: ObsEq,
    x0: Sequence[Any] | None,
    u: np.ndarray | Sequence[np.ndarray],
    z: np.ndarray | Sequence[np.ndarray],
    dt: float,
    p0: Any,
    *,
    free: Sequence[bool] | None = None,
    bounds: tuple[Any, Any] | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-4,
    par_step: float = 1e-6,
) -> OemResult:
    """Output error as FVSysID's ml_oem2 (Gauss-Newton, ``iOptim = 1``).

    `u` and `z` are one segment's arrays (n, nu), (n, ny) or lists of them (segments
    fitted together, each from its own ``x0[k]``); ``free`` flags the estimated
    parameters (default all), ``bounds = (p_min, p_max)`` arrays with +-inf where
    unbounded.
    """
    us = [np.asarray(u, dtype=float)] if isinstance(u, np.ndarray) else [np.asarray(a) for a in u]
    zs = [np.asarray(z, dtype=float)] if isinstance(z, np.ndarray) else [np.asarray(a) for a in z]
    x0s = list(x0) if x0 is not None else [None] * len(us)
    p = np.asarray(p0, dtype=float).ravel().copy()
    flags = np.ones(p.size, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    idx = np.flatnonzero(flags)
    lo, hi = (
        (np.full(p.size, -np.inf), np.full(p.size, np.inf))
        if bounds is None
        else (np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float))
    )
    bounded = bool(np.any(np.isfinite(lo[idx]) | np.isfinite(hi[idx])))
    state = np.zeros(p.size, dtype=int)  # -1 lower, +1 upper bound active
    zall = np.vstack(zs)
    ndata = zall.shape[0]

    def cost_of(pp: np.ndarray) -> tuple[float, np.ndarray, list[np.ndarray]]:
        ys = simulate(state_eq, obs_eq, x0s, us, dt, pp)
        v = zall - np.vstack(ys)
        rr = np.diag(np.sum(v * v, axis=0) / ndata)
        return float(np.linalg.det(rr)), rr, ys

    info = np.eye(idx.size)
    costs: list[float] = []
    prev = 0.0
    it = 0
    halvings = 0
    p_old = p.copy()
    crb = np.zeros((p.size, p.size))
    while it <= max_iterations:
        cost, rr, ys = cost_of(p)
        rel = abs((cost - prev) / cost)
        costs.append(cost)
        if it > 0 and rel < tolerance:
            break
        if it > 0 and cost > prev:
            if halvings == 10:
                break
            p = 0.5 * (p + p_old)
            halvings += 1
            if it == max_iterations:
                break
            continue
        if it == max_iterations:
            break
        # response gradients by forward differences, relative steps
        ri = 1.0 / np.diag(rr)
        yall = np.vstack(ys)
        v = zall - yall
        h = np.empty((ndata, zall.shape[1], idx.size))
        for j, ip in enumerate(idx):
            d = par_step * p[ip] if p[ip] != 0 else par_step
            pp = p.copy()
            pp[ip] += d
            h[:, :, j] = (np.vstack(simulate(state_eq, obs_eq, x0s, us, dt, pp)) - yall) / d
        info = np.einsum("iap,a,iaq->pq", h, ri, h)
        grad = -np.einsum("iap,a,ia->p", h, ri, v)
        step = np.zeros(idx.size)
        if bounded:
            # release a bound the gradient now pulls away from (chk_lub_opt)
            for j, ip in enumerate(idx):
                if (state[ip] == -1 and grad[j] < 0) or (state[ip] == 1 and grad[j] > 0):
                    state[ip] = 0
            keep = state[idx] == 0
            step[keep] = -np.linalg.solve(info[np.ix_(keep, keep)], grad[keep])
        else:
            step = -np.linalg.solve(info, grad)
        p_old = p.copy()
        p[idx] = p[idx] + step
        if bounded:
            for ip in idx:
                if p[ip] < lo[ip]:
                    p[ip], state[ip] = lo[ip], -1
                elif p[ip] > hi[ip]:
                    p[ip], state[ip] = hi[ip], 1
        prev = cost
        it += 1
        halvings = 0
    # ml_oem2 inverts the whole information matrix and zeroes the bounded ones' deviations
    cov = np.linalg.inv(info)
    on = state[idx] != 0
    cov[on, :] = 0.0
    cov[:, on] = 0.0
    crb[np.ix_(idx, idx)] = cov
    cost, rr, ys = cost_of(p)
    return OemResult(p=p, y=ys, R=rr, crb=crb, cost=costs, iterations=it, active=state.copy())
