"""The RK4 substeps of a record flattened into arrays (stage times, control nodes,
step sizes) and one RK4 step of many points at once: the grid Newton's method
over the record (`_shooting`) sweeps again and again, kept for the last record."""

from __future__ import annotations

import weakref
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._batch_function import ClosedForm
from .integration import _INSIDE, BatchFunction, control_nodes

FloatArray = NDArray[np.float64]

# The stage arrays a grid keeps for repeated runs of steps, at most (bytes).
_KEEP_BYTES = 64 * 2**20


def _same_record(last: list[Any], model: Any, time: FloatArray, controls: FloatArray) -> bool:
    if last[0]() is not model:
        return False
    if last[1] is not time and not np.array_equal(last[1], time):
        return False
    return last[2] is controls or bool(np.array_equal(last[2], controls))


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
        # the stage arrays of runs of steps repeated per column (`_steps`), newest last:
        # a fit's sweeps ask for the same few runs again and again
        self.taken: dict[tuple[int, int, int], tuple[FloatArray, ...]] = {}

    def stages(self, ks: Any, reps: int) -> tuple[FloatArray, ...]:
        """t1, t2, t4, h, hh, h6, u1, u2, u4 of the steps ks, each repeated `reps` times."""
        ks = np.asarray(ks)
        run = ks.size > 0 and int(ks[-1]) - int(ks[0]) == ks.size - 1
        key = (int(ks[0]), ks.size, reps) if run else None
        if key is not None and key in self.taken:
            return self.taken[key]

        def take(a: FloatArray) -> FloatArray:
            picked = a[..., ks[0] : ks[0] + ks.size] if run else a[..., ks]
            return np.repeat(picked, reps, axis=-1) if reps > 1 else picked

        got = tuple(
            take(a)
            for a in (
                self.t1,
                self.t2,
                self.t4,
                self.h,
                self.hh,
                self.h6,
                self.u1,
                self.u2,
                self.u4,
            )
        )
        for a in got:  # shared by the sweeps that follow: nobody writes to them
            a.flags.writeable = False
        if key is not None:
            size = sum(a.nbytes for a in got)
            held = sum(a.nbytes for v in self.taken.values() for a in v)
            while self.taken and held + size > _KEEP_BYTES:
                oldest = next(iter(self.taken))
                held -= sum(a.nbytes for a in self.taken.pop(oldest))
            if size <= _KEEP_BYTES:
                self.taken[key] = got
        return got


# The grid of the last record linearised: (model ref, time, controls, substeps, grid).
_LAST_GRID: list[Any] = []


def _grid(model: Any, time: FloatArray, controls: FloatArray, m: int) -> _Grid:
    """The grid of the record, the last one's when it is the same record and substeps."""
    last = _LAST_GRID
    if last and last[3] == m and _same_record(last, model, time, controls):
        grid: _Grid = last[4]
        return grid
    grid = _Grid(time, controls, m)
    _LAST_GRID[:] = [weakref.ref(model), time, controls, m, grid]
    return grid


def _steps(
    f: BatchFunction,
    grid: _Grid,
    ks: Any,
    X: FloatArray,
    P: Mapping[str, FloatArray],
    reps: int,
    du: tuple[FloatArray, FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """RK4 steps ks (K,) of the points X (n_x, K * reps), each step's `reps` columns
    side by side; P name -> (K * reps,); `du` is added to the controls at the three
    stage times."""

    t1, t2, t4, h, hh, h6, u1, u2, u4 = grid.stages(ks, reps)
    if du is not None:
        u1, u2, u4 = u1 + du[0], u2 + du[1], u4 + du[2]
    with np.errstate(all="ignore"):
        k1 = f.at_times(t1, X, u1, P)
        k2 = f.at_times(t2, X + hh * k1, u2, P)
        k3 = f.at_times(t2, X + hh * k2, u2, P)
        k4 = f.at_times(t4, X + h * k3, u4, P)
        return np.asarray(X + h6 * (k1 + 2.0 * (k2 + k3) + k4), dtype=np.float64)


def _tangent_steps(
    jacobian: ClosedForm,
    grid: _Grid,
    ks: Any,
    X: FloatArray,
    p: Mapping[str, float],
    names: tuple[str, ...],
    active: list[int],
) -> tuple[FloatArray, FloatArray] | None:
    """RK4 steps ks (K,) of the points X (n_x, K) with the function's closed-form
    Jacobians carried through the four stages: the steps (n_x, K) and their
    Jacobians (K, n_x, n_x + n_p + 2 n_c) in the states, `names`, then the controls
    `active` at each step's interval's first sample and at its last. None where the
    function's closed form does not cover the point."""
    t1, t2, t4, h, hh, h6, u1, u2, u4 = grid.stages(ks, 1)
    n_x, K = X.shape
    n_p = len(names)
    n_c = len(active)
    cols = n_x + n_p + 2 * n_c
    # a sample's control moves the nodes between it and its neighbour linearly
    j = (np.asarray(ks) % grid.m).astype(np.float64)
    fracs = [((2.0 * j + node) / (2.0 * grid.m))[:, None, None] for node in range(3)]
    base = np.zeros((K, n_x, cols))
    base[:, np.arange(n_x), np.arange(n_x)] = 1.0

    def stage(
        t: FloatArray, x: FloatArray, u: FloatArray, node: int, dx: FloatArray | None
    ) -> tuple[FloatArray, FloatArray] | None:
        got = jacobian(t, x, u, p, names)
        if got is None:
            return None
        k, fx, fp, fu = got
        if dx is None:  # the states' own directions: dx is the identity
            dk = np.zeros((K, n_x, cols))
            dk[:, :, :n_x] = fx
        else:
            dk = np.matmul(fx, dx)
        dk[:, :, n_x : n_x + n_p] += fp
        if n_c:
            fa = fu[:, :, active]
            dk[:, :, n_x + n_p : n_x + n_p + n_c] += fa * (1.0 - fracs[node])
            dk[:, :, n_x + n_p + n_c :] += fa * fracs[node]
        return k, dk

    with np.errstate(all="ignore"):
        s1 = stage(t1, X, u1, 0, None)
        if s1 is None:
            return None
        s2 = stage(t2, X + hh * s1[0], u2, 1, base + hh[:, None, None] * s1[1])
        if s2 is None:
            return None
        s3 = stage(t2, X + hh * s2[0], u2, 1, base + hh[:, None, None] * s2[1])
        if s3 is None:
            return None
        s4 = stage(t4, X + h * s3[0], u4, 2, base + h[:, None, None] * s3[1])
        if s4 is None:
            return None
        nxt = X + h6 * (s1[0] + 2.0 * (s2[0] + s3[0]) + s4[0])
        T = base + h6[:, None, None] * (s1[1] + 2.0 * (s2[1] + s3[1]) + s4[1])
    return np.asarray(nxt, dtype=np.float64), T
