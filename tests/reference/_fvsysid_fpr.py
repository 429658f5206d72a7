"""FVSysID's output-error method (``chapter04/ml_oem2.m``) in plain numpy, several segments.

Our own numpy version of the book's Gauss-Newton output error (Jategaonkar,
ch. 4) for the reference cases, written to the algorithm of ``ml_oem2.m``,
``costfun_oem.m``, ``gradFG.m``, ``gradrespH.m``, ``improv.m`` and ``ruku4.m``:

* the record is ``Nzi`` time segments, each integrated from its own initial
  state (``x0`` per segment, ``free_x0`` its flags: ``parFlagX0``) with its
  own bias parameters (``bx``, ``free_bx``: ``bXpar``, ``parFlagBX``); the
  system parameters ``p`` (flags ``free``: ``parFlag``) are shared;
* one fourth-order Runge-Kutta step per sample interval with the input
  averaged over the interval at the half step (``ruku4``);
* the noise covariance ``R`` is the diagonal of the residuals' mean square,
  re-estimated at every iteration; the cost is ``det(R)``;
* response gradients by forward differences, step ``1e-6`` of the value (of
  ``1e-6`` where the value is zero), the perturbed trajectories integrated
  whole from the perturbed initial states (what ``gradrespH``'s stored states
  amount to);
* Gauss-Newton steps (Cholesky), halved up to ten times while the cost
  rises; converged when the cost changes by less than ``tolerance``
  relatively; the Cramer-Rao covariance is ``F^-1`` of the last information
  matrix computed (at the iterate before the last step, as ``ml_oem2``).

``post(y, p)``, when given, acts on each segment's outputs after the
simulation (FVSysID's output time delays, ``timeDelay.m``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

Array = np.ndarray
# state_eq(x, u, p, bx) and obs_eq(x, u, p, bx): x (K, Nx), u (Nu,), p (K, Np), bx (K, Nbx)
Equation = Callable[[Array, Array, Array, Array], Array]


@dataclass
class OemResult:
    """The converged estimates of `ml_oem`.

    ``p`` all system parameters, ``x0`` (Nzi, Nx), ``bx`` (Nzi, Nbx), ``y``
    the outputs per segment, ``R`` the diagonal noise covariance, ``crb`` the
    Cramer-Rao standard deviations in the order of ``names`` (free system
    parameters, then free initial states and free biases segment by
    segment, as ``par_accuracy``), ``cov`` their covariance, ``cost`` the
    history of ``det(R)``.
    """

    p: Array
    x0: Array
    bx: Array
    y: list[Array]
    R: Array
    crb: Array
    cov: Array
    names: list[str]
    cost: list[float] = field(default_factory=list)
    iterations: int = 0
    converged: bool = False


def ruku4(f: Equation, x: Array, u1: Array, u2: Array, p: Array, bx: Array, dt: float) -> Array:
    """One Runge-Kutta step of ``ruku4.m``: the input averaged at the half step."""
    um = 0.5 * (u1 + u2)
    k1 = f(x, u1, p, bx)
    k2 = f(x + 0.5 * dt * k1, um, p, bx)
    k3 = f(x + 0.5 * dt * k2, um, p, bx)
    k4 = f(x + dt * k3, u2, p, bx)
    return x + dt * (k1 + 2.0 * (k2 + k3) + k4) / 6.0


def simulate(
    state_eq: Equation,
    obs_eq: Equation,
    x0: Array,
    u: Array,
    p: Array,
    bx: Array,
    dt: float,
    post: Callable[[Array, Array], Array] | None = None,
) -> Array:
    """Outputs (K, n, Ny) of one segment for K parameter sets (rows of x0, p, bx)."""
    x = np.array(x0, dtype=float)
    ys = []
    n = u.shape[0]
    for k in range(n):
        ys.append(obs_eq(x, u[k], p, bx))
        if k < n - 1:
            x = ruku4(state_eq, x, u[k], u[k + 1], p, bx, dt)
    y = np.stack(ys, axis=1)
    return post(y, p) if post is not None else y


def ml_oem(
    state_eq: Equation,
    obs_eq: Equation,
    x0: Any,
    u: Sequence[Array],
    z: Sequence[Array],
    dt: float,
    p0: Any,
    *,
    free: Any = None,
    free_x0: Any = None,
    bx: Any = None,
    free_bx: Any = None,
    post: Callable[[Array, Array], Array] | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-4,
    par_step: float = 1e-6,
    names: Sequence[str] | None = None,
) -> OemResult:
    """Gauss-Newton output error over the segments ``u[i]``, ``z[i]`` (see the module)."""
    nz = len(u)
    p = np.asarray(p0, dtype=float).ravel().copy()
    x0 = np.atleast_2d(np.asarray(x0, dtype=float)).copy()
    bx = np.zeros((nz, 0)) if bx is None else np.atleast_2d(np.asarray(bx, dtype=float)).copy()
    fp = np.ones(p.size, bool) if free is None else np.asarray(free, bool).ravel()
    fx = np.zeros(x0.shape, bool) if free_x0 is None else np.asarray(free_x0, bool)
    fb = np.zeros(bx.shape, bool) if free_bx is None else np.asarray(free_bx, bool)
    pnames = list(names) if names is not None else [f"p{i + 1}" for i in range(p.size)]
    labels = [pnames[i] for i in np.flatnonzero(fp)]
    labels += [f"x0[{k}].{j}" for k in range(nz) for j in np.flatnonzero(fx[k])]
    labels += [f"bx[{k}].{j}" for k in range(nz) for j in np.flatnonzero(fb[k])]
    zz = [np.asarray(a, dtype=float) for a in z]
    uu = [np.asarray(a, dtype=float) for a in u]
    ndata = sum(a.shape[0] for a in zz)

    def pack() -> Array:
        return np.concatenate(
            [p[fp], *(x0[k][fx[k]] for k in range(nz)), *(bx[k][fb[k]] for k in range(nz))]
        )

    def unpack(theta: Array) -> None:
        i = int(fp.sum())
        p[fp] = theta[:i]
        for k in range(nz):
            m = int(fx[k].sum())
            x0[k][fx[k]] = theta[i : i + m]
            i += m
        for k in range(nz):
            m = int(fb[k].sum())
            bx[k][fb[k]] = theta[i : i + m]
            i += m

    def outputs() -> list[Array]:
        return [
            simulate(state_eq, obs_eq, x0[k][None], uu[k], p[None], bx[k][None], dt, post)[0]
            for k in range(nz)
        ]

    def cost_of(ys: list[Array]) -> tuple[float, Array]:
        ss = sum(((zk - yk) ** 2).sum(axis=0) for zk, yk in zip(zz, ys, strict=True))
        r = np.diag(ss / ndata)
        return float(np.linalg.det(r)), r

    def info(ys: list[Array], r: Array) -> tuple[Array, Array]:
        n_free = len(labels)
        ri = np.diag(1.0 / np.diag(r))
        F = np.zeros((n_free, n_free))
        G = np.zeros(n_free)
        ip = np.flatnonzero(fp)
        for k in range(nz):
            # one perturbed copy per free quantity; perturbations as gradFG's par_del*
            P = np.repeat(p[None], n_free, axis=0)
            X = np.repeat(x0[k][None], n_free, axis=0)
            B = np.repeat(bx[k][None], n_free, axis=0)
            steps = np.zeros(n_free)
            col = 0
            for j in ip:
                steps[col] = par_step * p[j] if p[j] != 0 else par_step
                P[col, j] += steps[col]
                col += 1
            for kk in range(nz):
                for j in np.flatnonzero(fx[kk]):
                    steps[col] = par_step * x0[kk, j] if x0[kk, j] != 0 else par_step
                    if kk == k:
                        X[col, j] += steps[col]
                    col += 1
            for kk in range(nz):
                for j in np.flatnonzero(fb[kk]):
                    steps[col] = par_step * bx[kk, j] if bx[kk, j] != 0 else par_step
                    if kk == k:
                        B[col, j] += steps[col]
                    col += 1
            yp = simulate(state_eq, obs_eq, X, uu[k], P, B, dt, post)
            H = (yp - ys[k][None]) / steps[:, None, None]  # (n_free, n, Ny)
            v = zz[k] - ys[k]
            F += np.einsum("pia,ab,qib->pq", H, ri, H)
            G -= np.einsum("pia,ab,ib->p", H, ri, v)
        return F, G

    history: list[float] = []
    it, khalf, prev = 0, 0, 0.0
    F = np.eye(len(labels))
    cov = np.full((len(labels), len(labels)), np.nan)
    theta_old = pack()
    converged = False
    while it <= max_iterations:
        ys = outputs()
        cost, r = cost_of(ys)
        history.append(cost)
        rel = abs((cost - prev) / cost)
        if cost < prev or (rel < tolerance and it > 0):
            cov = np.linalg.inv(F)
        if rel < tolerance and it > 0:
            converged = True
            break
        if it == max_iterations:
            break
        if cost > prev and it > 0:
            if khalf == 10:
                break
            theta = 0.5 * (pack() + theta_old)
            unpack(theta)
            khalf += 1
            continue
        F, G = info(ys, r)
        cf = np.linalg.cholesky(F)
        step = -np.linalg.solve(cf.T, np.linalg.solve(cf, G))
        theta_old = pack()
        unpack(theta_old + step)
        prev = cost
        it += 1
        khalf = 0
    return OemResult(
        p=p.copy(),
        x0=x0.copy(),
        bx=bx.copy(),
        y=ys,
        R=r,
        crb=np.sqrt(np.diag(cov)),
        cov=cov,
        names=labels,
        cost=history,
        iterations=it,
        converged=converged,
    )
