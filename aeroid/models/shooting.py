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
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._rk4_grid import _KEEP_BYTES, _Grid, _grid, _same_record, _steps, _tangent_steps
from .integration import BatchFunction

FloatArray = NDArray[np.float64]

# Relative step of the central differences of a step and of the measurement.
_REL = 1e-6
# Newton stops after a sweep with every column whose correction moves no state by more
# than this fraction of its range.
_ACCEPT = 1e-8
_MAX_SWEEPS = 8
# A correction this small (relative) is one Newton sweep from the solution.
_CLOSE = 1e-6
# Chord sweeps (`_newton`): taken from a correction this small on, kept while each
# correction is at most this fraction of the one before (and for at most this many
# sweeps), until a correction this small.
_CHORD_FROM = 1e-2
_CHORD_RATE = 0.25
_MAX_CHORDS = 12
_CHORD_DONE = 1e-2 * _ACCEPT
# Substeps in the first window when a trajectory is built from its start.
_FIRST_WINDOW = 32

# The last trajectories, newest first, one per record (a fit of several manoeuvres
# alternates): (model ref, time, controls, substeps, names, x0_free, theta, states
# (N + 1, n_x), state sensitivities (N + 1, n_x, cols), the steps' state Jacobians
# (N, n_x, n_x), the values of the parameters the dynamics read).
_RECENT: list[list[Any]] = []
_KEEP = 4


def _linearised(
    f: BatchFunction,
    grid: _Grid,
    ks: Any,
    G: FloatArray,
    p: Mapping[str, float],
    hx: FloatArray,
    names: Sequence[str],
    hp: FloatArray,
    hu: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Steps of the points G (K, n_x) and their central-difference Jacobians
    A (K, n_x, n_x) (`hx` the states' steps, zero for a state the dynamics do not
    read), B (K, n_x, len(names)) and, with `hu` (n_u,) the steps of the
    controls (zero: left out), C (K, n_x, 2 n_c) in the n_c controls of nonzero step
    at the step's interval's first, then last sample."""
    K, n_x = G.shape
    n_p = len(names)
    active = [] if hu is None else np.flatnonzero(hu).tolist()
    n_c = len(active)
    if f.jacobian is not None:
        exact = _tangent_steps(
            f.jacobian, grid, ks, np.ascontiguousarray(G.T), p, tuple(names), active
        )
        if exact is not None:
            nxt, T = exact
            return nxt.T, T[:, :, :n_x], T[:, :, n_x : n_x + n_p], T[:, :, n_x + n_p :]
    xs = np.flatnonzero(hx)  # the states the dynamics read
    n_s = xs.size
    cols = 1 + 2 * n_s + 2 * n_p + 4 * n_c
    X = np.repeat(G.T[:, :, None], cols, axis=2)  # (n_x, K, cols)
    for c, i in enumerate(xs.tolist()):
        X[i, :, 1 + 2 * c] += hx[i]
        X[i, :, 2 + 2 * c] -= hx[i]
    P = _perturbed(p, K, cols, names, hp, 1 + 2 * n_s)
    du: tuple[FloatArray, FloatArray, FloatArray] | None = None
    if n_c:
        assert hu is not None
        # a sample's control moves the nodes between it and its neighbour linearly
        j = (np.asarray(ks) % grid.m).astype(np.float64)
        n_u = grid.u1.shape[0]
        nodes = [np.zeros((n_u, K, cols)) for _ in range(3)]
        for node, d in enumerate(nodes):
            frac = (2.0 * j + node) / (2.0 * grid.m)
            for c, ui in enumerate(active):
                base = 1 + 2 * n_s + 2 * n_p + 4 * c
                for end, w in enumerate((1.0 - frac, frac)):
                    d[ui, :, base + 2 * end] = w * hu[ui]
                    d[ui, :, base + 2 * end + 1] = -w * hu[ui]
        du = (
            nodes[0].reshape(n_u, K * cols),
            nodes[1].reshape(n_u, K * cols),
            nodes[2].reshape(n_u, K * cols),
        )
    out = _steps(f, grid, ks, X.reshape(n_x, K * cols), P, cols, du).reshape(n_x, K, cols)
    out = np.transpose(out, (1, 0, 2))  # (K, n_x, cols)
    diff = out[:, :, 1::2] - out[:, :, 2::2]
    # a state the dynamics do not read moves only itself: its column of A is exact
    A = np.zeros((K, n_x, n_x))
    A[:, np.arange(n_x), np.arange(n_x)] = 1.0
    A[:, :, xs] = diff[:, :, :n_s] / (2.0 * hx[xs])[None, None, :]
    B = diff[:, :, n_s : n_s + n_p] / (2.0 * hp)[None, None, :]
    C = np.zeros((K, n_x, 0))
    if n_c:
        assert hu is not None
        steps_c = np.repeat(hu[active], 2)  # (first, last) per control
        C = diff[:, :, n_s + n_p :] / (2.0 * steps_c)[None, None, :]
        # columns: every control at the first sample, then every control at the last
        C = np.concatenate([C[:, :, 0::2], C[:, :, 1::2]], axis=2)
    return out[:, :, 0], A, B, C


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
    names: Sequence[str] = (),
    hp: FloatArray | None = None,
    hu: FloatArray | None = None,
    A_prev: FloatArray | None = None,
    *,
    jacobians: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Settle G[lo + 1 : hi + 1] (G[lo] held) on the RK4 steps lo..hi-1, in place;
    returns the last sweep's Jacobians A, B, C (`_linearised`), or None when Newton
    does not settle. Sweeps far from the solution leave B and C out; `A_prev`, the
    state Jacobians of a nearby trajectory, serves the first sweeps of the steps alone.

    A sweep whose state Jacobians are kept from an earlier one (a chord sweep: one
    column instead of one pair per state) is taken while it contracts the corrections
    by at least `_CHORD_RATE`; the last sweep always linearises afresh at the settled
    trajectory, so what is returned is as exact as with Newton alone. Without
    `jacobians` (only the trajectory wanted) a settled chord sweep ends the search, and
    the Jacobians returned are those it kept."""
    ks = np.arange(lo, hi)
    n_x = G.shape[1]
    extras = bool(names) or hu is not None
    full = not extras
    none = np.zeros(0)
    chord = A_prev if A_prev is not None and A_prev.shape[0] == ks.size else None
    last = np.inf
    sweeps = chords = 0
    while sweeps < _MAX_SWEEPS:
        if chord is not None:
            X = np.ascontiguousarray(G[lo:hi].T)
            nxt = _steps(f, grid, ks, X, _columns(p, ks.size), 1).T
            A, B, C = chord, np.zeros(0), np.zeros(0)
            chords += 1
        elif full:
            nxt, A, B, C = _linearised(
                f, grid, ks, G[lo:hi], p, hx, names, none if hp is None else hp, hu
            )
            sweeps += 1
        else:
            nxt, A, B, C = _linearised(f, grid, ks, G[lo:hi], p, hx, (), none)
            sweeps += 1
        defect = nxt - G[lo + 1 : hi + 1]
        if not (np.all(np.isfinite(defect)) and np.all(np.isfinite(A))):
            return None
        d = linear_recursion(A, np.zeros((n_x, 1)), defect[:, :, None])[:, :, 0]
        if not np.all(np.isfinite(d)):
            return None
        G[lo + 1 : hi + 1] += d
        moved = float(np.max(np.abs(d) / scale)) if d.size else 0.0
        if chord is None and full and B.ndim == 3 and moved <= _ACCEPT:
            # the correction's own error is of its square: the trajectory is the RK4 one
            # to rounding, its Jacobians to about `moved`
            return A, B, C
        if chord is not None:
            if not jacobians and moved <= _ACCEPT:
                return A, B, C
            if moved <= _CHORD_DONE:
                # settled: one sweep linearised here carries the other columns
                chord, full = None, True
            elif moved > _CHORD_RATE * last or chords >= _MAX_CHORDS:
                chord = None  # too slow: Newton's sweeps from here
                if moved > last:
                    G[lo + 1 : hi + 1] -= d  # a correction that grew is undone
                    moved = last
                full = full or moved <= _CLOSE
        elif moved > _CHORD_DONE and moved <= _CHORD_FROM:
            # near enough that these Jacobians serve the next sweeps of the steps alone
            chord = A
        else:
            # Newton converges quadratically: after a correction this small the next
            # sweep lands on the solution, and carries the other columns
            full = full or moved <= _CLOSE
        last = moved
    return None


def _read_by_dynamics(
    f: BatchFunction, grid: _Grid, G: FloatArray, p: Mapping[str, float], names: Sequence[str]
) -> tuple[list[bool], list[bool]]:
    """Which of `names`, and which states, the dynamics read: a change of each moves
    some derivative at the start of some step of the trajectory G, or at points
    scattered about it (states and controls jittered, so that a factor that happens
    to be zero on the record still shows). A parameter read only in a branch the
    trajectory does not visit has no effect on this rollout: its columns are zero."""
    rng = np.random.default_rng(0)
    few = np.linspace(0, grid.n - 1, min(grid.n, 8)).astype(np.int64)
    n_x = G.shape[1]
    x = G[few].T * (1.0 + 0.1 * rng.standard_normal((n_x, few.size)))
    x = x + 0.01 * rng.standard_normal((n_x, few.size))
    u = grid.u1[:, few] * (1.0 + 0.1 * rng.standard_normal(grid.u1[:, few].shape))
    u = u + 0.01 * rng.standard_normal(u.shape)
    moved = _moves(f, grid.t1[few], x, u, p, names, True)
    read_p, read_x = moved[: len(names)], moved[len(names) :]
    # the others again at every step's start on the trajectory itself: a parameter
    # read only in a branch the trajectory visits shows there
    rest = [n for n, r in zip(names, read_p, strict=True) if not r]
    if rest:
        again = dict(zip(rest, _moves(f, grid.t1, G[:-1].T, grid.u1, p, rest, False), strict=True))
        read_p = [r or again[n] for n, r in zip(names, read_p, strict=True)]
    return read_p, read_x


def _moves(
    f: BatchFunction,
    t: FloatArray,
    x: FloatArray,
    u: FloatArray,
    p: Mapping[str, float],
    names: Sequence[str],
    states: bool,
) -> list[bool]:
    """Whether a change of each of `names` (then, with `states`, of each state) moves
    some derivative at the points (t, x, u)."""
    n_x, K = x.shape
    n_p = len(names)
    cols = 1 + n_p + (n_x if states else 0)
    P = _columns(p, K * cols)
    for c, name in enumerate(names):
        v = np.full((K, cols), p[name])
        v[:, 1 + c] += 0.1 * max(abs(p[name]), 1.0)
        P[name] = v.reshape(-1)
    X = np.repeat(x[:, :, None], cols, axis=2)
    if states:
        for i in range(n_x):
            X[i, :, 1 + n_p + i] += 0.1 * np.maximum(np.abs(x[i]), 1.0)
    with np.errstate(all="ignore"):
        out = f.at_times(
            np.repeat(t, cols), X.reshape(n_x, K * cols), np.repeat(u, cols, axis=1), P
        ).reshape(n_x, K, cols)
    same = np.all((out[:, :, 1:] == out[:, :, :1]), axis=(0, 1))
    return [not bool(v) for v in same]


def _columns(p: Mapping[str, float], n: int) -> dict[str, FloatArray]:
    """Every parameter's value on n columns (read-only views: nothing writes to them)."""
    return {k: np.broadcast_to(np.float64(v), (n,)) for k, v in p.items()}


def _perturbed(
    p: Mapping[str, float], K: int, cols: int, names: Sequence[str], hp: FloatArray, at: int
) -> dict[str, FloatArray]:
    """Parameters on K points of `cols` columns each, `names` moved by +-hp in the
    column pairs from `at` on."""
    P = _columns(p, K * cols)
    for c, name in enumerate(names):
        v = np.full((K, cols), p[name])
        v[:, at + 2 * c] += hp[c]
        v[:, at + 1 + 2 * c] -= hp[c]
        P[name] = v.reshape(-1)
    return P


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
        got = _newton(f, grid, lo, hi, G, p, hx, scale, jacobians=False)
        if got is None:
            if width <= 2:
                return None
            width //= 2
            continue
        lo = hi
        width *= 2
    return G


@dataclass
class _Record:
    """A record's RK4 rollout linearised: outputs, their Jacobian, and the pieces the
    input-noise scatter needs (per substep: A, C; per sample: gx, gu)."""

    y: FloatArray
    jac: FloatArray
    grid: _Grid
    A: FloatArray
    C: FloatArray
    gx: FloatArray
    gu: FloatArray


def _linearise(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
    hp: FloatArray,
    hu: FloatArray | None = None,
) -> _Record | None:
    f = model._dynamics_batch
    if f.broadcasts is False or f.time_broadcasts is False or time.size < 2:
        return None
    m = int(substeps)
    controls = np.asarray(controls, dtype=np.float64)
    grid = _grid(model, time, controls, m)
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
    if hu is not None:
        again = _controls_at_last(model, grid, time, controls, x0, p, names, x0_free, theta, hp, hu)
        if again is not None:
            return again
    guessed = _guess(model, time, controls, m, names, x0_free, theta, x0)
    A_last = None
    if guessed is not None:
        G, A_last = guessed
    else:
        start = _from_start(f, grid, x0, p)
        if start is None:
            return None
        G = start
    G[0] = x0
    scale = _scale(G)
    read_p, read_x = _read_by_dynamics(f, grid, G, p, names)
    read = np.flatnonzero(read_p)
    hx = _REL * scale * np.asarray(read_x, dtype=np.float64)
    got = _newton(
        f,
        grid,
        0,
        grid.n,
        G,
        p,
        hx,
        scale,
        [names[j] for j in read],
        hp[read],
        hu,
        A_last,
    )
    if got is None or f.time_broadcasts is False:
        return None
    A, B, C = got
    # state sensitivities: S[0] = d x0 / d(x0_free), S[k+1] = A[k] S[k] + B[k]
    cols = n_p + len(x0_free)
    S0 = np.zeros((n_x, cols))
    for c, i in enumerate(x0_free):
        S0[i, n_p + c] = 1.0
    F = np.zeros((grid.n, n_x, cols))
    F[:, :, read] = B
    S = np.concatenate([S0[None], linear_recursion(A, S0, F)])
    # the parameters the dynamics read: others may differ in `last_states`
    seen = {k: v for k, v in p.items() if k not in names or names.index(k) in read}
    entry = [weakref.ref(model), time, controls, m, names, x0_free, theta, G, S, A, seen]
    _RECENT[:] = [entry] + [e for e in _RECENT if not _same_record(e, model, time, controls)]
    del _RECENT[_KEEP:]
    # older records only while they stay small (the newest serves the fit under way)
    held = G.nbytes + S.nbytes + A.nbytes
    for k in range(1, len(_RECENT)):
        held += sum(_RECENT[k][j].nbytes for j in (7, 8, 9))
        if held > _KEEP_BYTES:
            del _RECENT[k:]
            break
    xs = G[::m]
    got_y = _measurement(model, time, controls, xs, p, _REL * scale, names, hp, hu)
    if got_y is None:
        return None
    y, gx, gp, gu = got_y
    jac = np.matmul(gx, S[::m])
    jac[:, :, :n_p] += gp
    # what a pass at the same point for the control columns alone reuses
    entry += [dict(p), np.array(hp, dtype=np.float64), (y, jac, gx)]
    return _Record(y=y, jac=jac, grid=grid, A=A, C=C, gx=gx, gu=gu)


def _controls_at_last(
    model: Any,
    grid: _Grid,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    p: Mapping[str, float],
    names: list[str],
    x0_free: list[int],
    theta: FloatArray,
    hp: FloatArray,
    hu: FloatArray,
) -> _Record | None:
    """The record linearised at the point of the last one (a fit's error bars after
    its final evaluation) with its control columns added: the trajectory, its state
    Jacobians, outputs and output Jacobian are the last pass's, so only the columns of
    the controls are evaluated (the steps', then the measurement's)."""
    found = [e for e in _RECENT if _same_record(e, model, time, controls)]
    if not found or len(found[0]) < 14:
        return None
    last = found[0]
    if (
        last[3] != grid.m
        or last[4] != names
        or last[5] != x0_free
        or not np.array_equal(last[6], theta)
        or not np.array_equal(last[7][0], x0)
        or last[11] != dict(p)
        or not np.array_equal(last[12], hp)
    ):
        return None
    G, A = last[7], last[9]
    y, jac, gx = last[13]
    n_x = G.shape[1]
    ks = np.arange(grid.n)
    got = _linearised(model._dynamics_batch, grid, ks, G[:-1], p, np.zeros(n_x), (), hp[:0], hu)
    C = got[3]
    if not (np.all(np.isfinite(got[0])) and np.all(np.isfinite(C))):
        return None
    active = np.flatnonzero(hu)
    xs = G[:: grid.m]
    g = model._measurement_batch
    exact = None
    if g is not None and g.jacobian is not None:
        exact = g.jacobian(time, np.ascontiguousarray(xs.T), controls.T, p, ())
    if g is None:
        gu = np.zeros((time.size, y.shape[1], active.size))
    elif exact is not None:
        gu = exact[3][:, :, active]
    else:
        n_t = time.size
        cols = 1 + 2 * active.size
        U = np.repeat(controls.T[:, :, None], cols, axis=2)
        for c, ui in enumerate(active.tolist()):
            U[ui, :, 1 + 2 * c] += hu[ui]
            U[ui, :, 2 + 2 * c] -= hu[ui]
        X = np.repeat(xs.T[:, :, None], cols, axis=2).reshape(n_x, n_t * cols)
        with np.errstate(all="ignore"):
            Y = g.at_times(
                np.repeat(time, cols), X, U.reshape(-1, n_t * cols), _columns(p, n_t * cols)
            )
        if g.time_broadcasts is False:
            return None
        Y = np.transpose(Y.reshape(-1, n_t, cols), (1, 0, 2))
        gu = (Y[:, :, 1::2] - Y[:, :, 2::2]) / (2.0 * hu[active])[None, None, :]
    return _Record(y=y, jac=jac, grid=grid, A=A, C=C, gx=gx, gu=gu)


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
    hp = np.asarray(steps[: len(names)], dtype=np.float64)
    with np.errstate(all="ignore"):  # a diverging point gives None
        rec = _linearise(model, time, controls, x0, params, names, x0_free, substeps, hp)
    return None if rec is None else (rec.y, rec.jac)


def input_noise_scatter(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
    inverse_variances: FloatArray,
    sigma: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """`_compiled.input_noise_scatter` in numpy: outputs, their Jacobian and the
    covariance of the Gauss–Newton gradient that white control noise of standard
    deviations `sigma` causes to first order, by the adjoint of the linearised
    rollout (``lam[k] = hx[k]' c[k] + phi[k]' lam[k+1]``). None where Newton does
    not apply."""
    names = list(names)
    sigma = np.asarray(sigma, dtype=np.float64)
    u = np.asarray(controls, dtype=np.float64)
    hp = _REL * np.maximum(np.abs(np.array([float(params[n]) for n in names])), 1e-3)
    hu = np.where(sigma > 0, _REL * np.maximum(np.max(np.abs(u), axis=0), 1e-3), 0.0)
    with np.errstate(all="ignore"):  # a diverging point gives None
        rec = _linearise(model, time, u, x0, params, names, x0_free, substeps, hp, hu)
    if rec is None:
        return None
    m = rec.grid.m
    n_t = time.size
    n_x = rec.A.shape[1]
    active = np.flatnonzero(hu)
    n_c = active.size
    # each sample interval's transition and control Jacobians, from its substeps
    A = rec.A.reshape(n_t - 1, m, n_x, n_x)
    C = rec.C.reshape(n_t - 1, m, n_x, 2 * n_c)
    phi = A[:, 0]
    D = C[:, 0]
    for j in range(1, m):
        phi = np.matmul(A[:, j], phi)
        D = np.matmul(A[:, j], D) + C[:, j]
    c = rec.jac * np.asarray(inverse_variances, dtype=np.float64)[None, :, None]
    g = np.matmul(np.transpose(rec.gx, (0, 2, 1)), c)  # (n_t, n_x, cols)
    lam = np.empty_like(g)
    lam[-1] = g[-1]
    if n_t > 1:
        back = linear_recursion(
            np.ascontiguousarray(np.transpose(phi[::-1], (0, 2, 1))), g[-1], g[-2::-1]
        )
        lam[:-1] = back[::-1]
    after = lam[1:]  # lam[k + 1] for each interval k
    z = np.zeros((n_t, n_c, c.shape[2]))
    Dt = np.transpose(D, (0, 2, 1))
    z[:-1] += np.matmul(Dt[:, :n_c], after)
    z[1:] += np.matmul(Dt[:, n_c:], after)
    z += np.matmul(np.transpose(rec.gu, (0, 2, 1)), c)
    flat = (z * sigma[active][None, :, None]).reshape(-1, c.shape[2])
    return rec.y, rec.jac, flat.T @ flat


def _guess(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    m: int,
    names: list[str],
    x0_free: list[int],
    theta: FloatArray,
    x0: FloatArray,
) -> tuple[FloatArray, FloatArray] | None:
    """The last trajectory moved to first order to the new point, when it was of the
    same record and columns, and its steps' state Jacobians."""
    found = [e for e in _RECENT if _same_record(e, model, time, controls)]
    if not found:
        return None
    last = found[0]
    if last[3] != m or last[4] != names or last[5] != x0_free:
        return None
    G: FloatArray = last[7] + np.matmul(last[8], theta - last[6])
    G[0] = x0
    return (G, last[9]) if np.all(np.isfinite(G)) else None


def _measurement(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    xs: FloatArray,
    p: Mapping[str, float],
    hx: FloatArray,
    names: Sequence[str],
    hp: FloatArray,
    hu: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """Outputs (n_t, n_y) at the states xs (n_t, n_x) and their central-difference
    Jacobians in the states (n_t, n_y, n_x), the parameters (n_t, n_y, n_p) and the
    controls of nonzero step `hu` (n_t, n_y, n_c); None when not finite."""
    n_t, n_x = xs.shape
    n_p = len(names)
    active = [] if hu is None else np.flatnonzero(hu).tolist()
    n_c = len(active)
    g = model._measurement_batch
    if g is None:
        idx = [model.states.index(o) for o in model.output_names]
        gx = np.zeros((n_t, len(idx), n_x))
        gx[:, np.arange(len(idx)), idx] = 1.0
        zero = np.zeros((n_t, len(idx), n_p + n_c))
        return xs[:, idx].copy(), gx, zero[:, :, :n_p], zero[:, :, n_p:]
    if g.jacobian is not None:
        with np.errstate(all="ignore"):
            exact = g.jacobian(time, np.ascontiguousarray(xs.T), controls.T, p, tuple(names))
        if exact is not None:
            if not np.all(np.isfinite(exact[0])):
                return None
            return np.ascontiguousarray(exact[0].T), exact[1], exact[2], exact[3][:, :, active]
    cols = 1 + 2 * n_x + 2 * n_p + 2 * n_c
    X = np.repeat(xs.T[:, :, None], cols, axis=2)
    for i in range(n_x):
        X[i, :, 1 + 2 * i] += hx[i]
        X[i, :, 2 + 2 * i] -= hx[i]
    P = _perturbed(p, n_t, cols, names, hp, 1 + 2 * n_x)
    U = np.repeat(controls.T[:, :, None], cols, axis=2)
    for c, ui in enumerate(active):
        assert hu is not None
        U[ui, :, 1 + 2 * (n_x + n_p + c)] += hu[ui]
        U[ui, :, 2 + 2 * (n_x + n_p + c)] -= hu[ui]
    T = np.repeat(time, cols)
    with np.errstate(all="ignore"):
        Y = g.at_times(
            T,
            X.reshape(n_x, n_t * cols),
            U.reshape(-1, n_t * cols),
            P,
        )
    if g.time_broadcasts is False:
        return None
    Y = np.transpose(Y.reshape(-1, n_t, cols), (1, 0, 2))  # (n_t, n_y, cols)
    if not np.all(np.isfinite(Y[:, :, 0])):
        return None
    diff = Y[:, :, 1::2] - Y[:, :, 2::2]
    gx = diff[:, :, :n_x] / (2.0 * hx)[None, None, :]
    gp = diff[:, :, n_x : n_x + n_p] / (2.0 * hp)[None, None, :]
    gu = diff[:, :, n_x + n_p :]
    if n_c:
        assert hu is not None
        gu = gu / (2.0 * hu[active])[None, None, :]
    return np.ascontiguousarray(Y[:, :, 0]), gx, gp, gu


def last_states(
    model: Any,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
) -> FloatArray | None:
    """The states (n_t, n_x) of the last linearised rollout when a one-member RK4
    simulation asks for the same one: the same record, substeps, initial state and
    values of the parameters the dynamics read (a fit's result simulated at its
    estimate, its sensors' errors perhaps zeroed). x0 (n_x, 1), u (1, n_t, n_u)."""
    if x0.shape[1] != 1:
        return None
    found = [e for e in _RECENT if _same_record(e, model, time, u[0])]
    if not found or found[0][3] != int(substeps):
        return None
    last = found[0]
    G: FloatArray = last[7]
    m = last[3]
    if not np.array_equal(G[0], x0[:, 0]):
        return None
    known: Mapping[str, float] = last[10]
    if not set(known) <= set(p) or any(float(p[k][0]) != v for k, v in known.items()):
        return None
    return np.ascontiguousarray(G[::m])
