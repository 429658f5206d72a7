"""RK4 rollouts and their sensitivities by Newton's method over the whole record.

`_integrate.rk4` steps a batch through time in Python: four calls of the
model's dynamics per substep, tens of thousands per fit, each costing the
interpreter far more than its arithmetic. Here the same RK4 recursion
``x[k+1] = step_k(x[k])`` (the same substeps, stage times and control nodes)
is solved as one system over all substeps at once, for a model whose
dynamics broadcast over an array of times (`BatchFunction.at_times`):

* every step of a guessed trajectory is evaluated in one call per RK4 stage,
  with central-difference columns for its Jacobian ``A[k] = d step_k / dx``
  (and ``B[k] = d step_k / dtheta`` for chosen parameters) carried as extra
  columns of the same calls;
* Newton's correction ``d[k+1] = A[k] d[k] + (step_k(g[k]) - g[k+1])`` is a
  linear recursion, solved in about 2 sqrt(N) batched matrix products
  (`linear_recursion`); its fixed point is the RK4 trajectory, to rounding;
* the state sensitivities follow from ``S[k+1] = A[k] S[k] + B[k]``, the
  outputs' from central differences of the measurement at every sample.

A trajectory is guessed from the last one and its sensitivities (a fit's
next point), or built window by window from the initial state. Where Newton
does not settle (a diverging member, dynamics that do not take an array of
times) the callers keep the step-by-step path.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._integrate import _INSIDE, BatchFunction, control_nodes

FloatArray = NDArray[np.float64]

# Relative step of the central differences of a step and of the measurement.
_REL = 1e-6
# Newton stops when a correction moves no state by more than this fraction of its range.
_NEWTON_TOL = 1e-11
_MAX_SWEEPS = 8
# Substeps in the first window when a trajectory is built from its start.
_FIRST_WINDOW = 32

# A fit's last trajectory: (model ref, time, controls, substeps, names, x0_free,
# theta, states (N + 1, n_x), state sensitivities (N + 1, n_x, cols)).
_LAST: list[Any] = []


class _Grid:
    """The flattened RK4 substeps of a record: stage times, control nodes, step sizes."""

    def __init__(self, time: FloatArray, controls: FloatArray, m: int) -> None:
        n_t = time.size
        t0 = time[:-1]
        t1 = time[1:]
        h = (t1 - t0) / m
        j = np.arange(m, dtype=np.float64)
        ta = t0[:, None] + j[None, :] * h[:, None]  # (n_t - 1, m)
        hh = 0.5 * h
        inside = _INSIDE * (t1 - t0)
        first = ta.copy()
        first[:, 0] = t0 + inside
        last = ta + h[:, None]
        last[:, m - 1] = t1 - inside
        self.m = m
        self.n = (n_t - 1) * m
        self.t1 = first.ravel()
        self.t2 = (ta + hh[:, None]).ravel()
        self.t4 = last.ravel()
        self.h = np.repeat(h, m)
        self.hh = np.repeat(hh, m)
        self.h6 = self.h / 6.0
        nodes = control_nodes(np.asarray(controls, dtype=np.float64)[None], m)[..., 0]
        # nodes: (n_t - 1, 2m + 1, n_u) -> per substep (n_u, N)
        idx = 2 * np.arange(m)
        self.u1 = np.ascontiguousarray(nodes[:, idx].reshape(self.n, -1).T)
        self.u2 = np.ascontiguousarray(nodes[:, idx + 1].reshape(self.n, -1).T)
        self.u4 = np.ascontiguousarray(nodes[:, idx + 2].reshape(self.n, -1).T)


def _steps(
    f: BatchFunction,
    grid: _Grid,
    ks: Any,
    X: FloatArray,
    P: Mapping[str, FloatArray],
    reps: int,
) -> FloatArray:
    """RK4 steps ks (K,) of the points X (n_x, K * reps), each step's `reps` columns
    side by side; P name -> (K * reps,)."""

    def take(a: FloatArray) -> FloatArray:
        return np.repeat(a[..., ks], reps, axis=-1) if reps > 1 else a[..., ks]

    h, hh, h6 = take(grid.h), take(grid.hh), take(grid.h6)
    t2 = take(grid.t2)
    u2 = take(grid.u2)
    with np.errstate(all="ignore"):
        k1 = f.at_times(take(grid.t1), X, take(grid.u1), P)
        k2 = f.at_times(t2, X + hh * k1, u2, P)
        k3 = f.at_times(t2, X + hh * k2, u2, P)
        k4 = f.at_times(take(grid.t4), X + h * k3, take(grid.u4), P)
        return np.asarray(X + h6 * (k1 + 2.0 * (k2 + k3) + k4), dtype=np.float64)


def _linearised(
    f: BatchFunction,
    grid: _Grid,
    ks: Any,
    G: FloatArray,
    p: Mapping[str, float],
    hx: FloatArray,
    names: Sequence[str],
    hp: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Steps of the points G (K, n_x) and their central-difference Jacobians
    A (K, n_x, n_x) and B (K, n_x, len(names))."""
    K, n_x = G.shape
    n_p = len(names)
    cols = 1 + 2 * n_x + 2 * n_p
    X = np.repeat(G.T[:, :, None], cols, axis=2)  # (n_x, K, cols)
    for i in range(n_x):
        X[i, :, 1 + 2 * i] += hx[i]
        X[i, :, 2 + 2 * i] -= hx[i]
    P = {k: np.full((K, cols), v) for k, v in p.items()}
    for c, name in enumerate(names):
        P[name][:, 1 + 2 * n_x + 2 * c] += hp[c]
        P[name][:, 2 + 2 * n_x + 2 * c] -= hp[c]
    out = _steps(
        f, grid, ks, X.reshape(n_x, K * cols), {k: v.reshape(-1) for k, v in P.items()}, cols
    ).reshape(n_x, K, cols)
    out = np.transpose(out, (1, 0, 2))  # (K, n_x, cols)
    diff = out[:, :, 1::2] - out[:, :, 2::2]
    A = diff[:, :, :n_x] / (2.0 * hx)[None, None, :]
    B = diff[:, :, n_x:] / (2.0 * hp)[None, None, :] if n_p else np.zeros((K, n_x, 0))
    return out[:, :, 0], A, B


def linear_recursion(A: FloatArray, z0: FloatArray, F: FloatArray) -> FloatArray:
    """z_1..z_N of ``z[k+1] = A[k] z[k] + F[k]``: A (N, n, n), z0 (n, c), F (N, n, c).

    In blocks of L ~ sqrt(N) steps the Python loop runs about 2 sqrt(N)
    times: over the position in a block (every block at once, each from a
    zero state, with the products of its A's), then over the blocks' start
    states. The sums are those of the plain loop in another order.
    """
    N, n, c = F.shape
    L = max(1, math.isqrt(N - 1) + 1) if N > 1 else 1
    nb = -(-N // L)
    pad = nb * L - N
    if pad:
        A = np.concatenate([A, np.broadcast_to(np.eye(n), (pad, n, n))])
        F = np.concatenate([F, np.zeros((pad, n, c))])
    A4 = A.reshape(nb, L, n, n)
    F4 = F.reshape(nb, L, n, c)
    G = np.empty((nb, L, n, c))
    Pr = np.empty((nb, L, n, n))
    g = F4[:, 0]
    pr = A4[:, 0]
    G[:, 0] = g
    Pr[:, 0] = pr
    for i in range(1, L):
        g = np.matmul(A4[:, i], g) + F4[:, i]
        pr = np.matmul(A4[:, i], pr)
        G[:, i] = g
        Pr[:, i] = pr
    starts = np.empty((nb, n, c))
    s = z0
    for b in range(nb):
        starts[b] = s
        s = Pr[b, L - 1] @ s + G[b, L - 1]
    Z = np.matmul(Pr, starts[:, None]) + G
    return np.asarray(Z.reshape(nb * L, n, c)[:N], dtype=np.float64)


def _newton(
    f: BatchFunction,
    grid: _Grid,
    lo: int,
    hi: int,
    G: FloatArray,
    p: Mapping[str, float],
    hx: FloatArray,
    scale: FloatArray,
    names: Sequence[str],
    hp: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Settle G[lo + 1 : hi + 1] (G[lo] held) on the RK4 steps lo..hi-1, in place;
    returns the last sweep's A and B, or None when Newton does not settle."""
    ks = np.arange(lo, hi)
    n_x = G.shape[1]
    for _ in range(_MAX_SWEEPS):
        nxt, A, B = _linearised(f, grid, ks, G[lo:hi], p, hx, names, hp)
        defect = nxt - G[lo + 1 : hi + 1]
        if not (np.all(np.isfinite(defect)) and np.all(np.isfinite(A))):
            return None
        d = linear_recursion(A, np.zeros((n_x, 1)), defect[:, :, None])[:, :, 0]
        if not np.all(np.isfinite(d)):
            return None
        G[lo + 1 : hi + 1] += d
        if np.all(np.abs(d) <= _NEWTON_TOL * scale):
            return A, B, nxt
    return None


def _columns(p: Mapping[str, float], n: int) -> dict[str, FloatArray]:
    return {k: np.full(n, v) for k, v in p.items()}


def _scale(G: FloatArray) -> FloatArray:
    return np.maximum(np.max(np.abs(G), axis=0), 1e-3)


def _from_start(
    f: BatchFunction, grid: _Grid, x0: FloatArray, p: Mapping[str, float]
) -> FloatArray | None:
    """The trajectory (N + 1, n_x) built window by window from x0, each window's guess
    the last state held; windows double while Newton settles quickly, halve when not."""
    n_x = x0.size
    G = np.empty((grid.n + 1, n_x))
    G[0] = x0
    lo = 0
    width = _FIRST_WINDOW
    while lo < grid.n:
        hi = min(grid.n, lo + width)
        G[lo + 1 : hi + 1] = G[lo]
        scale = _scale(G[: hi + 1])
        hx = _REL * scale
        got = _newton(f, grid, lo, hi, G, p, hx, scale, (), np.zeros(0))
        if got is None:
            if width <= 2:
                return None
            width //= 2
            continue
        lo = hi
        width *= 2
    return G


def output_sensitivities(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
    steps: FloatArray,
) -> tuple[FloatArray, FloatArray] | None:
    """Outputs (n_t, n_y) and their Jacobian (n_t, n_y, len(names) + len(x0_free)) of
    the RK4 rollout with `substeps`, as `_compiled.output_sensitivities` returns them;
    `steps` are the central-difference steps of those columns. None when Newton does
    not settle or the dynamics do not take an array of times (the caller then steps)."""
    f = model._dynamics_batch
    if f.broadcasts is False or f.time_broadcasts is False or time.size < 2:
        return None
    m = int(substeps)
    controls = np.asarray(controls, dtype=np.float64)
    grid = _Grid(time, controls, m)
    x0 = np.asarray(x0, dtype=np.float64)
    n_x = x0.size
    p = {k: float(v) for k, v in params.items()}
    # a few steps first: dynamics that cannot take an array of times say so cheaply
    few = np.arange(min(grid.n, 4))
    _steps(f, grid, few, np.repeat(x0[:, None], few.size, axis=1), _columns(p, few.size), 1)
    if f.time_broadcasts is False:
        return None
    names = list(names)
    x0_free = list(x0_free)
    n_p = len(names)
    theta = np.concatenate([[p[n] for n in names], x0[x0_free]])
    hp = np.asarray(steps[:n_p], dtype=np.float64)
    G = _guess(model, time, controls, m, names, x0_free, theta, x0)
    if G is None:
        G = _from_start(f, grid, x0, p)
        if G is None:
            return None
    G[0] = x0
    scale = _scale(G)
    got = _newton(f, grid, 0, grid.n, G, p, _REL * scale, scale, names, hp)
    if got is None or f.time_broadcasts is False:
        return None
    A, B, _ = got
    # state sensitivities: S[0] = d x0 / d(x0_free), S[k+1] = A[k] S[k] + B[k]
    cols = n_p + len(x0_free)
    S0 = np.zeros((n_x, cols))
    for c, i in enumerate(x0_free):
        S0[i, n_p + c] = 1.0
    F = np.zeros((grid.n, n_x, cols))
    F[:, :, :n_p] = B
    S = np.concatenate([S0[None], linear_recursion(A, S0, F)])
    _LAST[:] = [weakref.ref(model), time, controls, m, names, x0_free, theta, G, S]
    xs = G[::m]
    Ss = S[::m]
    y, gx, gp = _measurement(model, time, controls, xs, p, _REL * scale, names, hp)
    if y is None:
        return None
    jac = np.matmul(gx, Ss)
    jac[:, :, :n_p] += gp
    return y, jac


def _guess(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    m: int,
    names: list[str],
    x0_free: list[int],
    theta: FloatArray,
    x0: FloatArray,
) -> FloatArray | None:
    """The last trajectory moved to first order to the new point, when it was of the
    same record and columns."""
    last = _LAST
    if not last or last[0]() is not model or last[3] != m:
        return None
    if last[4] != names or last[5] != x0_free:
        return None
    if last[1] is not time and not np.array_equal(last[1], time):
        return None
    if last[2] is not controls and not np.array_equal(last[2], controls):
        return None
    G: FloatArray = last[7] + np.matmul(last[8], theta - last[6])
    G[0] = x0
    return G if np.all(np.isfinite(G)) else None


def _measurement(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    xs: FloatArray,
    p: Mapping[str, float],
    hx: FloatArray,
    names: Sequence[str],
    hp: FloatArray,
) -> tuple[FloatArray | None, FloatArray, FloatArray]:
    """Outputs (n_t, n_y) at the states xs (n_t, n_x) and their central-difference
    Jacobians in the states (n_t, n_y, n_x) and the parameters (n_t, n_y, n_p)."""
    n_t, n_x = xs.shape
    n_p = len(names)
    g = model._measurement_batch
    if g is None:
        idx = [model.states.index(o) for o in model.output_names]
        gx = np.zeros((n_t, len(idx), n_x))
        gx[:, np.arange(len(idx)), idx] = 1.0
        return xs[:, idx].copy(), gx, np.zeros((n_t, len(idx), n_p))
    cols = 1 + 2 * n_x + 2 * n_p
    X = np.repeat(xs.T[:, :, None], cols, axis=2)
    for i in range(n_x):
        X[i, :, 1 + 2 * i] += hx[i]
        X[i, :, 2 + 2 * i] -= hx[i]
    P = {k: np.full((n_t, cols), v) for k, v in p.items()}
    for c, name in enumerate(names):
        P[name][:, 1 + 2 * n_x + 2 * c] += hp[c]
        P[name][:, 2 + 2 * n_x + 2 * c] -= hp[c]
    T = np.repeat(time, cols)
    U = np.repeat(controls.T, cols, axis=1)
    with np.errstate(all="ignore"):
        Y = g.at_times(T, X.reshape(n_x, n_t * cols), U, {k: v.reshape(-1) for k, v in P.items()})
    if g.time_broadcasts is False:
        return None, np.zeros(0), np.zeros(0)
    Y = np.transpose(Y.reshape(-1, n_t, cols), (1, 0, 2))  # (n_t, n_y, cols)
    if not np.all(np.isfinite(Y[:, :, 0])):
        return None, np.zeros(0), np.zeros(0)
    diff = Y[:, :, 1::2] - Y[:, :, 2::2]
    gx = diff[:, :, :n_x] / (2.0 * hx)[None, None, :]
    gp = diff[:, :, n_x:] / (2.0 * hp)[None, None, :] if n_p else np.zeros((n_t, Y.shape[1], 0))
    return np.ascontiguousarray(Y[:, :, 0]), gx, gp
