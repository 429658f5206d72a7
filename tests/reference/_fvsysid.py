"""FVSysID's flight files and its output-error method in plain numpy (not part of the library).

Jategaonkar's FVSysID (the software of "Flight Vehicle System Identification -
A Time Domain Methodology", 2nd ed.) ships its flight data as ``.asc`` tables
and ``.mat`` files holding one matrix named after the file; `read_flight`
reads either.

`ml_oem` is our own numpy version of the book's output-error method (chapter
4, ``ml_oem2.m`` and the routines it calls), written from the algorithm, not
translated line by line:

- the outputs are simulated sample by sample: ``y_k = g(x_k, u_k)``, then one
  fourth-order Runge-Kutta step per sample interval with the input at the
  interval's start, the mean of its two ends at the half step and the end
  value at the full step;
- the noise covariance ``R`` is the diagonal of the residuals' covariance
  (divided by N), re-estimated at every evaluation; the cost is ``det R``;
- response gradients are forward differences, each free parameter moved by
  ``1e-6 |p|`` (``1e-6`` where it is zero);
- Gauss-Newton: ``F = sum H' R^-1 H``, ``G = -sum H' R^-1 (z - y)``, step
  ``-F^-1 G``; a cost above the previous one halves the last step (at most
  ten times); it stops when the cost's relative change is below
  `tolerance` (FVSysID's ``tolR = 1e-4``);
- the Cramer-Rao covariance is ``F^-1`` from the last gradient evaluated (at
  the iterate before the final one, as FVSysID reports it).

Model functions take ``(x, u, p)`` with ``x`` (nx, K) and ``p`` (np, K)
columns, one per perturbed copy, and ``u`` (nu,), so one call integrates the
nominal model and all its perturbations together.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

Fn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
D2R = np.pi / 180.0


def read_flight(path: pathlib.Path) -> np.ndarray:
    """A flight file as a float matrix: an ``.asc`` table or the one matrix of a ``.mat``."""
    if path.suffix.lower() == ".mat":
        import scipy.io

        d = scipy.io.loadmat(str(path))
        keys = [k for k in d if not k.startswith("__")]
        return np.asarray(d[path.stem if path.stem in d else keys[0]], dtype=float)
    return np.loadtxt(str(path), dtype=float)


@dataclasses.dataclass(frozen=True)
class OemResult:
    """An output-error fit: estimates `p` (all parameters), outputs `y` (n, ny)
    over the concatenated segments, noise covariance `R` (diagonal), Cramer-Rao
    covariance `crb` of the free parameters, the cost ``det R`` of every
    evaluation, the Gauss-Newton iterations, and the free mask."""

    p: np.ndarray
    y: np.ndarray
    R: np.ndarray
    crb: np.ndarray
    cost: tuple[float, ...]
    iterations: int
    free: np.ndarray

    @property
    def se(self) -> np.ndarray:
        """Cramer-Rao standard deviations of every parameter (zero where fixed)."""
        out = np.zeros(self.p.size)
        out[self.free] = np.sqrt(np.diag(self.crb))
        return out


def rk4_step(
    f: Fn, x: np.ndarray, u1: np.ndarray, u2: np.ndarray, p: np.ndarray, dt: float
) -> np.ndarray:
    """One Runge-Kutta step over a sample interval, inputs at its start, mean and end."""
    um = 0.5 * (u1 + u2)
    k1 = f(x, u1, p)
    k2 = f(x + 0.5 * dt * k1, um, p)
    k3 = f(x + 0.5 * dt * k2, um, p)
    k4 = f(x + dt * k3, u2, p)
    return x + dt * (k1 + 2.0 * (k2 + k3) + k4) / 6.0


def simulate(
    state_eq: Fn, obs_eq: Fn, x0: np.ndarray, u: np.ndarray, dt: float, p: np.ndarray
) -> np.ndarray:
    """Outputs (n, ny, K) of one segment for K parameter columns `p` (np, K)."""
    k = p.shape[1]
    x = np.repeat(np.asarray(x0, dtype=float).reshape(-1, 1), k, axis=1)
    out = []
    n = u.shape[0]
    for i in range(n):
        out.append(np.asarray(obs_eq(x, u[i], p), dtype=float).reshape(-1, k))
        if i < n - 1 and x.shape[0]:
            x = rk4_step(state_eq, x, u[i], u[i + 1], p, dt)
    return np.stack(out)


def _as_segments(a: Any) -> list[np.ndarray]:
    if isinstance(a, np.ndarray):
        return [a]
    return [np.asarray(s, dtype=float) for s in a]


def ml_oem(
    state_eq: Fn,
    obs_eq: Fn,
    x0: Any,
    u: Any,
    z: Any,
    dt: float,
    p0: Any,
    *,
    free: Sequence[bool] | np.ndarray | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-4,
    step: float = 1e-6,
) -> OemResult:
    """FVSysID's output-error method (``ml_oem2``, Gauss-Newton) on one record or a
    list of segments (`x0`, `u`, `z` then lists of the same length, fitted together
    with one ``R``). `free` masks the estimated parameters (all by default)."""
    us, zs = _as_segments(u), _as_segments(z)
    x0s = _as_segments(x0) if len(us) > 1 else [np.asarray(x0, dtype=float)]
    us = [s.reshape(s.shape[0], -1) for s in us]
    zall = np.concatenate(zs)
    p = np.asarray(p0, dtype=float).ravel().copy()
    mask = np.ones(p.size, bool) if free is None else np.asarray(free, bool).ravel()
    idx = np.flatnonzero(mask)

    def outputs(cols: np.ndarray) -> np.ndarray:
        return np.concatenate(
            [simulate(state_eq, obs_eq, xs, uu, dt, cols) for xs, uu in zip(x0s, us, strict=True)]
        )

    def evaluate(pp: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        y = outputs(pp[:, None])[:, :, 0]
        r = np.diag(np.mean((zall - y) ** 2, axis=0))
        return float(np.linalg.det(r)), r, y

    costs: list[float] = []
    prev = 0.0
    p_old = p.copy()
    info = np.eye(idx.size)
    crb = np.full((idx.size, idx.size), np.nan)
    it = 0
    halvings = 0
    while it <= max_iterations:
        cost, r, y = evaluate(p)
        costs.append(cost)
        rel = abs((cost - prev) / cost)
        if it > 0 and (cost < prev or rel < tolerance):
            crb = np.linalg.inv(info)
        if it > 0 and rel < tolerance:
            break
        if it > 0 and cost > prev:
            if halvings == 10:
                break
            p = 0.5 * (p + p_old)
            halvings += 1
            continue
        if it == max_iterations:
            break
        # forward-difference response gradients of the free parameters
        h = step * p[idx]
        h[h == 0] = step
        cols = np.repeat(p[:, None], idx.size, axis=1)
        cols[idx, np.arange(idx.size)] += h
        sens = (outputs(cols) - y[:, :, None]) / h  # (n, ny, nfree)
        w = 1.0 / np.diag(r)
        info = np.einsum("iap,a,iaq->pq", sens, w, sens)
        grad = -np.einsum("iap,a,ia->p", sens, w, zall - y)
        c = np.linalg.cholesky(info)
        delta = -np.linalg.solve(c.T, np.linalg.solve(c, grad))
        p_old = p.copy()
        p = p.copy()
        p[idx] += delta
        prev = cost
        it += 1
        halvings = 0
    _, r, y = evaluate(p)
    return OemResult(p=p, y=y, R=r, crb=crb, cost=tuple(costs), iterations=it, free=mask)
