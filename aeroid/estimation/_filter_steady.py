"""The fixed-gain predictor of the filter-error method for nonlinear models.

Jategaonkar (Flight Vehicle System Identification, ch. 5, the filter-error
method for nonlinear systems) keeps the nonlinear model for the state
prediction and takes the Kalman gain from the system linearised about the
reference point, the record's start (its trim):

    x_k|k-1 = x_k-1|k-1 moved over the interval by the nonlinear model (RK4),
    nu_k    = y_k - h(x_k|k-1),
    x_k|k   = x_k|k-1 + K_k nu_k,

with ``A = df/dx`` and ``C = dh/dx`` at the reference (central differences),
``Phi``, ``Qd`` their exact discretisation (Van Loan) and ``K_k``, ``S_k`` the
Kalman gains and innovation covariances of that linear time-invariant system:
the Riccati recursion on constant matrices, run once per parameter vector
until the gain stops changing (the first tens to hundreds of samples), so the
gain is the steady-state gain after the transient from ``P0``. Keeping that
transient makes the predictor on a linear model the linear filter of
`run_filter` itself, innovation for innovation; the book's filter starts at
the steady-state gain, which differs only in those first samples.

Why it is the default (with ``method="ekf"``): the book argues the
steady-state gain for the time-invariant models of system identification
about a trim, where the extended filter's gain converges to it within a few
samples anyway; the nonlinear model still carries the state through large
motions, and the cost per parameter vector is one Riccati solution instead of
a Jacobian, a matrix exponential and a factorisation at every sample (about a
sixth of the time-varying filter's on the demo's flights). The time-varying
filter (``gain="time_varying"``) remains for flights whose linearisation
changes much over the record (large manoeuvres far from the trim).

Each member of a batch (the filter-error method's finite differences of the
whole predictor) linearises and solves its own Riccati equation, so the
sensitivities include the gain's dependence on the parameters and the noise
intensities, as the book's relaxation does through its F/K update steps.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._threads import quiet_warnings
from ..errors import IdentificationError
from ..models import compiled as _compiled
from ..models import integration as _integrate
from ._filter_problem import _Problem
from ._kalman_linear import (
    _dt_groups,
    _Failure,
    _fd_step,
    _Linear,
    _Pass,
    _riccati_start,
    _step_matrices,
    _van_loan,
)
from ._kalman_nonlinear import _linearise_model, _Measurer, _Propagator
from .filtering import run_filter

__all__ = ["GAINS", "gain_choice", "start_states", "steady_pass"]

FloatArray = NDArray[np.float64]

GAINS = ("steady", "time_varying")


def gain_choice(gain: object, method: str, given: Mapping[str, object] | None) -> str:
    """The filter-error gain: ``filter_options["gain"]``, or its default.

    The default is the book's, the steady-state gain (Jategaonkar ch. 5): for
    the time-invariant models of system identification about a trim it is
    what the time-varying filter converges to after a few samples, the
    nonlinear model still moves the state, and the cost is one Riccati
    solution per parameter vector instead of a linearisation, a matrix
    exponential and a factorisation per sample. With ``method="ukf"`` the
    filter is the unscented one, time-varying by construction.
    """
    if gain is None:
        return "time_varying" if method == "ukf" else "steady"
    if gain not in GAINS:
        raise IdentificationError(
            f"filter_options['gain']: {gain!r} is unknown; choose one of {list(GAINS)}"
        )
    if gain == "steady" and method == "ukf" and given is not None and "method" in given:
        raise IdentificationError(
            "filter_options: gain='steady' takes its gain from the linearised model, "
            "which method='ukf' does not use; give gain='time_varying' with 'ukf'"
        )
    return str(gain)


def _reference_system(
    prob: _Problem,
    params: Mapping[str, FloatArray],
    Qc: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    prop: _Propagator,
    meas: _Measurer,
) -> _Linear:
    """The model linearised at (x0, u_0) and discretised per time-step group."""
    m = prob.model
    B, n = x0.shape
    groups = _dt_groups(prob.time)
    if groups is None:
        raise _Failure(0, "the sample times vary too much for a fixed-gain filter")
    hs, idx = groups
    step = _fd_step(x0, P0)  # (B, n)
    e = np.eye(n)[None] * step[:, :, None]
    pts = np.concatenate([x0[:, None, :] + e, x0[:, None, :] - e], axis=1)  # (B, 2n, n)
    cols = np.ascontiguousarray(pts.reshape(B * 2 * n, n).T)
    u = np.broadcast_to(prob.U[0][:, None], (prob.U.shape[1], B * 2 * n))
    with np.errstate(all="ignore"):
        vals = prop.f(float(prob.time[0]), cols, u, prop._p(2 * n))
    vals = np.asarray(vals, dtype=np.float64).T.reshape(B, 2 * n, n)
    A = np.swapaxes((vals[:, :n] - vals[:, n:]) / (2 * step[:, :, None]), 1, 2)
    if not np.all(np.isfinite(A)):
        raise _Failure(
            0, f"the dynamics Jacobian of model {m.name!r} at the record's start is not finite"
        )
    pairs = [_van_loan(np.ascontiguousarray(A), Qc, float(h)) for h in hs]
    Phi = np.stack([p[0] for p in pairs], axis=1)
    Qd = np.stack([p[1] for p in pairs], axis=1)
    _, H = meas.linear(0, x0, P0)
    F = np.zeros((B, 0, n))  # the forcing is the nonlinear model's: unused here
    return _Linear(Phi, Qd, F, idx, np.ascontiguousarray(H), None)


# relative change of the gain below which the Riccati recursion counts as converged:
# far below what moves an estimate, far above rounding
_GAIN_TOL = 1e-10

# samples of gains the compiled predictor takes: this, or the next power-of-two multiple
# of it that holds the transient (a few shapes, a few compilations, whatever the flight;
# the demo's transients take 30 to 540 samples, or the whole record where a process
# noise went to zero)
_GAIN_SAMPLES = 512


# records of up to this many buffers' samples take the whole record's gains, one shape:
# a fit's passes need short and whole-record transients alike (a process noise going to
# zero), and copying the longer buffer costs milliseconds a pass where a second shape
# costs a compilation
_ONE_SHAPE = 4


def _capacity(needed: int, most: int) -> int:
    """Rows of a gain buffer holding `needed` of at most `most`: 512, 1024, ... or `most`,
    and `most` itself where it is at most four buffers."""
    if most <= _ONE_SHAPE * _GAIN_SAMPLES:
        return most
    cap = _GAIN_SAMPLES
    while cap < needed:
        cap *= 2
    return min(cap, most)


# The residual of an inverse (infinity norm) below which Newton-Schulz steps refine it
# (three at most), and the residual they take it to: rounding's
_NEWTON_FROM = 1e-2
_NEWTON_TO = 1e-16


def _inverse(S: FloatArray, X: FloatArray | None, eye: FloatArray) -> FloatArray:
    """The inverses of the batch `S` (B, m, m), refined from `X`, the last step's.

    A Newton-Schulz step ``X + X (I - S X)`` squares the residual ``I - S X``
    exactly (to rounding), so from a start whose residual is below 1e-2 in the
    infinity norm three steps at most reach rounding. The Riccati recursion's S
    changes little from one step to the next past its first samples, and a step costs
    two small matrix products, a fraction of what LAPACK's factorisation costs per
    small matrix. A start further off (the first samples, a batch member that failed)
    is inverted afresh.
    """
    if X is not None:
        E = eye - S @ X
        # the array's own reductions: the same sums without numpy's wrapper per call
        err = float(np.abs(E).sum(axis=2).max())
        if err <= _NEWTON_FROM:
            while True:
                X = X + X @ E
                err *= err
                if err <= _NEWTON_TO:
                    return X
                E = eye - S @ X
    return np.asarray(np.linalg.inv(S), dtype=np.float64)


def _gains(
    ref: _Linear, R: FloatArray, P0: FloatArray, n_t: int, rows: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int]:
    """(S, G, Pp, Pf, k) of the reference system's Kalman filter over the record.

    ``G`` holds the gains time-major, ``G[j, b]`` the gain of sample ``j`` for
    member ``b``, for ``j = 0..k`` only (``G[0]`` zero), the last of them the gain
    from then on; its `rows` (at least B) repeat the last member after the B given,
    as the compiled predictor's padded batch takes them; its samples past ``k`` are
    left unset (untouched memory: the recursion stops after a few hundred samples).

    The Riccati recursion runs until the gain has converged (the first tens to
    hundreds of samples); from there S and the gain are the steady-state ones.
    ``Pp`` and ``Pf`` are the steady-state covariances, broadcast over the
    record (the objective uses the innovations and S only); from sample ``k``
    on the gain is constant.
    """
    B, n, H, S = _riccati_start(ref, n_t)
    n_y = H.shape[1]
    # time-major: a step writes one contiguous block, and the predictor takes a leading
    # slice of it without a copy
    G = np.empty((n_t, rows, n, n_y))
    G[0] = 0.0
    # transposes as arrays of their own: a product by a transposed view on its right takes
    # numpy's slower loop (the same sums, hence the same numbers)
    Ht = np.ascontiguousarray(np.swapaxes(H, 1, 2))
    PhiT = np.swapaxes(ref.Phi, 2, 3)
    P = P0
    S[:, 0] = H @ P0 @ Ht + R
    Ppk = P0
    K_prev = G[0, :B]
    eye = np.eye(n_y)
    X: FloatArray | None = None  # the last step's inverse of S
    single = ref.Phi.shape[1] == 1
    Phi, PhiT_, Qd = ref.Phi[:, 0], np.ascontiguousarray(PhiT[:, 0]), ref.Qd[:, 0]
    done = n_t - 1
    # a step in as few array operations as it takes: at the demo's sizes each costs
    # about what its arithmetic does, and the recursion runs hundreds of steps a pass
    for k in range(1, n_t):
        if not single:
            Phi, PhiT_, Qd = _step_matrices(ref, PhiT, k)
        Ppk = Phi @ P @ PhiT_ + Qd
        HP = H @ Ppk  # (P H')', Ppk being symmetric
        Sk = HP @ Ht + R
        X = _inverse(Sk, X, eye)
        K = np.swapaxes(X @ HP, 1, 2)
        P = Ppk - K @ HP  # the optimal gain's update, (I - K H) Pp
        P += np.swapaxes(P, 1, 2)
        P *= 0.5
        S[:, k] = Sk
        G[k, :B] = K
        # converged: checked every fourth step (a later stop only converges further), the
        # whole batch only once the first member has
        if (
            single
            and k > 1
            and k % 4 == 0
            and np.max(np.abs(K[0] - K_prev[0])) <= _GAIN_TOL * np.max(np.abs(K[0]))
        ):
            scale = np.max(np.abs(K), axis=(1, 2))
            if np.all(np.max(np.abs(K - K_prev), axis=(1, 2)) <= _GAIN_TOL * scale):
                S[:, k + 1 :] = Sk[:, None]
                done = k
                break
        K_prev = K
    G[: done + 1, B:] = G[: done + 1, B - 1 : B]
    Pp = np.broadcast_to(Ppk[:, None], (B, n_t, n, n))
    Pf = np.broadcast_to(P[:, None], (B, n_t, n, n))
    return S, G, np.asarray(Pp), np.asarray(Pf), done


def _padded(B: int) -> int:
    """The compiled predictor's batch for B members: each size would otherwise compile
    anew, so a power of two up to 16, then a multiple of 8."""
    return 1 << (B - 1).bit_length() if B <= 16 else -(-B // 8) * 8


def _build(model: Any, out_idx: tuple[int, ...], jax: Any, jnp: Any) -> Any:
    """The whole predictor as one `jax.lax.scan` over the record, the batch of members
    vmapped inside each step."""
    entry = _compiled._entry(model)
    f = _compiled._traced_once(entry[("fn", "dynamics")], jax)
    h = entry.get(("fn", "measurement")) if model.measurement is not None else None
    h = None if h is None else _compiled._traced_once(h, jax)
    oi = np.array(out_idx, dtype=np.int64)
    sel = None
    if h is None:  # the outputs are states
        sel = np.array([model.states.index(model.output_names[i]) for i in out_idx])
    step = _compiled._interval(f, jax)

    def meas(t: Any, x: Any, u: Any, pvec: Any) -> Any:
        return x[sel] if h is None else h(t, x, u, pvec)[oi]

    def one(
        x: Any, t0: Any, t1: Any, u0: Any, u1: Any, e: Any, y: Any, pvec: Any, K: Any, m: Any
    ) -> Any:
        xpk = step(x, t0, t1, u0, u1, e, pvec, m)
        v = y - meas(t1, xpk, u1, pvec)
        return xpk, xpk + K @ v, v

    every = jax.vmap(one, in_axes=(0, None, None, None, None, None, None, 0, 0, None))

    def run(time: Any, U: Any, E: Any, Y: Any, X0: Any, P: Any, G: Any, last: Any, m: Any) -> Any:
        # G: time-major gains of samples 1.., the one at `last` the steady one; E: the
        # controls' excess over straight lines per interval (zero for them)
        def body(X: Any, inp: Any) -> Any:
            t0, t1, u0, u1, e, y, j = inp
            xpk, xn, v = every(X, t0, t1, u0, u1, e, y, P, G[jnp.minimum(j, last)], m)
            return xn, (xpk, xn, v)

        steps = jnp.arange(time.shape[0] - 1)
        inputs = (time[:-1], time[1:], U[:-1], U[1:], E, Y[1:], steps)
        _, outs = jax.lax.scan(body, X0, inputs)
        return outs

    return jax.jit(run)


def _compiled_predictor(
    prob: _Problem,
    params: Mapping[str, FloatArray],
    x0: FloatArray,
    G: FloatArray,
    steady_from: int,
    substeps: int,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """(xp, xf, nu) from sample 1 on, time-major, of the compiled predictor with the
    `_gains` buffer `G` (its rows the padded batch), or None (the numpy loop then
    runs: the model does not compile)."""
    model = prob.model
    if not _compiled.ENABLED or prob.time.size < 2:
        return None
    B = x0.shape[0]
    pmat = _compiled._pmatrix(model, params, B)
    if not _compiled.available(model, prob.time, x0[0], prob.U, pmat[0], measurement=True):
        return None
    mods = _compiled._import_jax()
    if mods is None:
        return None
    jax, jnp = mods
    cache = _compiled._shared(model)
    key = ("steady_predictor", tuple(prob.out_idx))
    fn = cache.get(key)
    if fn is None:
        fn = cache[key] = _build(model, tuple(prob.out_idx), jax, jnp)
    padded = G.shape[1]
    rows = np.minimum(np.arange(padded), B - 1)
    with quiet_warnings():
        try:
            outs = fn(
                prob.time,
                prob.U,
                _integrate.control_excess(prob.time, prob.U, prob.interpolation),
                prob.Y,
                np.ascontiguousarray(x0[rows]),
                pmat[rows],
                G[1 : _capacity(steady_from + 1, G.shape[0])],  # a leading slice: no copy
                np.int32(steady_from - 1),
                np.int32(substeps),
            )
        except Exception:  # a model JAX traced pointwise but not in this scan: numpy
            return None
    xp, xf, nu = (np.asarray(a, dtype=np.float64)[:, :B] for a in outs)
    return xp, xf, nu


def _compiles(prob: _Problem, substeps: int) -> bool:
    """Whether a fit's passes pay a compiled predictor: by the problem's size alone, so
    a rerun in another process takes the same path and gives the same bits."""
    work = 4 * substeps * (prob.time.size - 1) * _compiled._FIT_EVALUATIONS
    return work >= _compiled.COMPILE_AFTER_CALLS


def start_states(prob: _Problem, values: Mapping[str, float], Qc: FloatArray) -> FloatArray | None:
    """The model's states over `prob`'s record from its x0 at `values`, (n_t, n_x), by
    the compiled RK4 rollout where the fit's passes compile its predictor (decided by
    the problem's size alone, so a rerun in another process gives the same bits), else
    None (the caller then simulates in numpy). The model's later simulations (its
    validation) take the same compiled rollout.
    """
    params = {k: np.full(1, float(v)) for k, v in values.items()}
    if _linearise_model(prob, params, Qc, 1) is not None:
        return None  # linear dynamics: the fit's filter and the simulation are exact
    m = prob.substeps
    if m is None:
        m = prob.path_substeps(params)
    if not _compiles(prob, m):
        return None
    traj = _compiled.compiled_rollout(
        prob.model, prob.time, prob.x0[:, None], prob.U[None], params, int(m), prob.interpolation
    )
    return None if traj is None else np.asarray(traj.states[0], dtype=np.float64)


def steady_pass(
    prob: _Problem,
    params: Mapping[str, FloatArray],
    Qc: FloatArray,
    R: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    *,
    states: bool = True,
) -> _Pass:
    """Forward pass of the fixed-gain predictor for a batch of B members.

    Arguments as `filtering.run_filter`; returns its record (``Pf``, ``Pp``
    those of the reference system, ``C`` zero). ``states=False`` leaves ``xp`` and
    ``xf`` unrecorded (read-only NaN): the likelihood takes the innovations only.
    """
    B, n = x0.shape
    n_t, n_y = prob.Y.shape
    Y = prob.Y
    lin = _linearise_model(prob, params, Qc, B)
    if lin is not None and lin.H is not None:
        # an affine model is its own linearisation: the predictor is the linear
        # Kalman filter, whose vectorised pass `run_filter` has
        return run_filter(prob, params, Qc, R, x0, P0, method="ekf")
    lin = None  # (a nonlinear measurement of linear dynamics: linearised below)
    prop = _Propagator(prob, params, Qc, B, lin)
    meas = _Measurer(prob, params, B, lin)
    if states:
        xf = np.full((B, n_t, n), np.nan)
        xp = np.full((B, n_t, n), np.nan)
    else:  # two record-long arrays a pass less to fill
        xf = xp = np.broadcast_to(np.nan, (B, n_t, n))
    nu = np.full((B, n_t, n_y), np.nan)
    # read-only views until the Riccati solution replaces them: no record-long copies
    S = np.broadcast_to(np.nan, (B, n_t, n_y, n_y))
    Pp = Pf = np.broadcast_to(np.nan, (B, n_t, n, n))
    C = np.broadcast_to(0.0, (B, n_t, n, n))
    ok = np.ones(B, dtype=bool)
    fail = np.full(B, -1, dtype=np.int64)
    try:
        # the first sample's outputs first: a model's first measurement call decides, point
        # by point, whether it broadcasts, at a 17th of the Jacobian's points
        nu[:, 0] = Y[0] - meas.points(0, x0[:, None, :])[:, 0]
        ref = _reference_system(prob, params, Qc, x0, P0, prop, meas)
        with np.errstate(all="ignore"):
            S, G, Pp, Pf, steady_from = _gains(ref, R, P0, n_t, _padded(B))
        x = x0.copy()
        if states:
            xf[:, 0], xp[:, 0] = x, x
        fast = None
        # compiled when a fit's passes would spend what a compilation costs
        if prop._cp is not None or _compiles(prob, prop.m):
            fast = _compiled_predictor(prob, params, x0, G, steady_from, prop.m)
        if fast is not None:
            nu[:, 1:] = np.swapaxes(fast[2], 0, 1)
            if states:
                xp[:, 1:], xf[:, 1:] = np.swapaxes(fast[0], 0, 1), np.swapaxes(fast[1], 0, 1)
        with np.errstate(all="ignore"):
            for k in range(1, n_t if fast is None else 1):
                xpk = prop.points(k - 1, x[:, None, :])
                v = Y[k] - meas.points(k, xpk)[:, 0]
                x = xpk[:, 0] + np.einsum("bij,bj->bi", G[min(k, steady_from), :B], v)
                nu[:, k] = v
                if states:
                    xp[:, k], xf[:, k] = xpk[:, 0], x
    except _Failure as exc:
        ok[:] = False
        fail[:] = exc.k
        return _Pass(xf, Pf, xp, Pp, C, nu, S, ok, fail, 0, exc.what, exc.simulation)
    except np.linalg.LinAlgError:
        ok[:] = False
        fail[:] = 0
        return _Pass(xf, Pf, xp, Pp, C, nu, S, ok, fail, 0, "the Riccati equation has no solution")
    bad = ~np.all(np.isfinite(nu), axis=(1, 2)) | ~np.all(np.isfinite(S), axis=(1, 2, 3))
    ok &= ~bad
    for b in np.flatnonzero(bad):
        fin = np.all(np.isfinite(nu[b]), axis=1)
        fail[b] = int(np.argmin(fin))
    return _Pass(xf, Pf, xp, Pp, C, nu, S, ok, fail, 0, settled=steady_from)
