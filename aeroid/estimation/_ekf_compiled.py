"""The extended Kalman filter pass compiled whole (one `jax.lax.scan`), internal.

The same algorithm as the numpy pass in `aeroid.estimation.filtering._general` step for
step: the state moved over each interval by the RK4 of `_compiled._interval`
(same substeps, one-sided ends, controls straight or cubic between samples), the
covariance by the Van Loan discretisation of the central-difference Jacobian
of the dynamics at the filtered state (same step rule), the measurement
linearised by central differences at the prediction, and the Joseph-form
update through the Cholesky factor of the innovation covariance. So the two
agree to rounding; what the compiled pass cannot do (diagonal jitter of an
indefinite innovation covariance, naming a failing state) it leaves to the
numpy pass: any non-finite value makes it return None.

The matrix exponential is `aeroid._linalg.expm`'s (the degree-13 Padé approximant, scaled
from the norms of the matrix's powers only when its 1-norm asks for it), not
`jax.scipy.linalg.expm`: that one picks among five approximants and squares up to 16
times behind conditions, which a batched program turns into computing every branch at
every sample, and which the compiler compiles every time. A single filter (the filter
stage's) compiles without the batch axis: its conditions then stay conditions.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._linalg import _B13, _THETA13
from .._threads import quiet_warnings
from ..models import compiled as _compiled
from ..models.integration import Interpolation, control_excess
from ..models.model import Model

FloatArray = NDArray[np.float64]

Arrays = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]


def _expm(jax: Any, jnp: Any) -> Any:
    """`aeroid._linalg.expm` of one matrix as a JAX function, the same steps."""
    b = _B13

    def norm1(X: Any) -> Any:
        return jnp.max(jnp.sum(jnp.abs(X), axis=0))

    def squarings(X: Any) -> Any:
        # only for a matrix whose 1-norm exceeds the approximant's range: the powers'
        # norms bound the error more tightly for a non-normal (stiff) matrix
        A2 = X @ X
        A4 = A2 @ A2
        A6 = A4 @ A2
        n1 = norm1(X)
        d6 = norm1(A6) ** (1.0 / 6.0)
        d8 = norm1(A4 @ A4) ** (1.0 / 8.0)
        d10 = norm1(A4 @ A6) ** (1.0 / 10.0)
        eta = jnp.fmin(jnp.fmin(jnp.fmax(d6, d8), jnp.fmax(d8, d10)), n1)
        eta = jnp.maximum(eta, n1 * 2.0**-53)
        s = jnp.where(eta > _THETA13, jnp.ceil(jnp.log2(jnp.maximum(eta, 1e-300) / _THETA13)), 0.0)
        return jnp.clip(s, 0.0, 1074.0)

    def expm(X: Any) -> Any:
        s = jax.lax.cond(norm1(X) <= _THETA13, lambda X: jnp.zeros((), X.dtype), squarings, X)
        si = s.astype(jnp.int32)
        X = X * jnp.ldexp(jnp.ones((), X.dtype), -si)
        eye = jnp.eye(X.shape[0], dtype=X.dtype)
        A2 = X @ X
        A4 = A2 @ A2
        A6 = A4 @ A2
        U = X @ (
            A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2)
            + b[7] * A6
            + b[5] * A4
            + b[3] * A2
            + b[1] * eye
        )
        V = (
            A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2)
            + b[6] * A6
            + b[4] * A4
            + b[2] * A2
            + b[0] * eye
        )
        E = jnp.linalg.solve(V - U, V + U)
        return jax.lax.fori_loop(0, si, lambda _, E: E @ E, E)

    return expm


def _build(model: Model, out_idx: tuple[int, ...], jax: Any, jnp: Any, batched: bool) -> Any:
    entry = _compiled._entry(model)
    f = _compiled._traced_once(entry[("fn", "dynamics")], jax)
    h = entry.get(("fn", "measurement")) if model.measurement is not None else None
    h = None if h is None else _compiled._traced_once(h, jax)
    n = model.n_states
    oi = np.array(out_idx, dtype=np.int64)
    Hsel = np.zeros((len(out_idx), n))
    sel = np.zeros(len(out_idx), dtype=np.int64)
    if h is None:  # the outputs are states
        sel = np.array([model.states.index(model.output_names[i]) for i in out_idx])
        Hsel[np.arange(len(out_idx)), sel] = 1.0
    step = _compiled._interval(f, jax)
    expm = _expm(jax, jnp)
    tri = jax.scipy.linalg.solve_triangular
    eye = np.eye(n)

    def sym(P: Any) -> Any:
        return 0.5 * (P + P.T)

    def fd_step(x: Any, P: Any) -> Any:  # as filtering._fd_step
        sd = jnp.sqrt(jnp.clip(jnp.diagonal(P), 0.0, None))
        return jnp.maximum(1e-3 * sd, 1e-7 * jnp.maximum(jnp.abs(x), 1e-2))

    def meas_lin(t: Any, x: Any, P: Any, u: Any, pvec: Any) -> tuple[Any, Any]:
        if h is None:
            return x[sel], jnp.asarray(Hsel)
        st = fd_step(x, P)
        E = eye * st[:, None]
        pts = jnp.concatenate([x[None], x[None] + E, x[None] - E], axis=0)
        vals = jax.vmap(h, in_axes=(None, 0, None, None))(t, pts, u, pvec)[:, oi]
        Hm = ((vals[1 : n + 1] - vals[n + 1 :]) / (2.0 * st[:, None])).T
        return vals[0], Hm

    def dyn_lin(t: Any, x: Any, P: Any, u: Any, pvec: Any, Qc: Any, dt: Any) -> tuple[Any, Any]:
        st = fd_step(x, P)
        E = eye * st[:, None]
        pts = jnp.concatenate([x[None] + E, x[None] - E], axis=0)
        vals = jax.vmap(f, in_axes=(None, 0, None, None))(t, pts, u, pvec)
        A = ((vals[:n] - vals[n:]) / (2.0 * st[:, None])).T
        M = jnp.zeros((2 * n, 2 * n))
        M = M.at[:n, :n].set(-A).at[:n, n:].set(Qc).at[n:, n:].set(A.T)
        Ev = expm(M * dt)
        Phi = Ev[n:, n:].T
        return Phi, sym(Phi @ Ev[:n, n:])

    def one(
        time: Any, U: Any, E: Any, Y: Any, x0: Any, P0: Any, pvec: Any, Qc: Any, R: Any, m: Any
    ) -> Any:
        yh0, H0 = meas_lin(time[0], x0, P0, U[0], pvec)
        nu0 = Y[0] - yh0
        S0 = H0 @ P0 @ H0.T + R

        def body(carry: Any, inp: Any) -> Any:
            x, P = carry
            t0, t1, u0, u1, e, y = inp
            xpk = step(x, t0, t1, u0, u1, e, pvec, m)
            Phi, Qd = dyn_lin(t0, x, P, u0, pvec, Qc, t1 - t0)
            Ppk = sym(Phi @ P @ Phi.T + Qd)
            Ck = P @ Phi.T
            yh, H = meas_lin(t1, xpk, Ppk, u1, pvec)
            PHt = Ppk @ H.T
            Sk = sym(H @ PHt + R)
            L = jnp.linalg.cholesky(Sk)
            K = tri(L.T, tri(L, PHt.T, lower=True), lower=False).T
            v = y - yh
            xn = xpk + K @ v
            IKH = eye - K @ H
            Pn = sym(IKH @ Ppk @ IKH.T + K @ R @ K.T)
            return (xn, Pn), (xn, Pn, xpk, Ppk, Ck, v, Sk)

        inputs = (time[:-1], time[1:], U[:-1], U[1:], E, Y[1:])
        _, outs = jax.lax.scan(body, (x0, P0), inputs)
        xf, Pf, xp, Pp, C, nu, S = outs

        def cat(first: Any, rest: Any) -> Any:
            return jnp.concatenate([first[None], rest], axis=0)

        return (
            cat(x0, xf),
            cat(P0, Pf),
            cat(x0, xp),
            cat(P0, Pp),
            cat(jnp.zeros_like(P0), C),
            cat(nu0, nu),
            cat(S0, S),
        )

    if batched:
        return jax.jit(jax.vmap(one, in_axes=(None, None, None, None, 0, 0, 0, 0, 0, None)))

    def single(
        time: Any, U: Any, E: Any, Y: Any, x0: Any, P0: Any, pvec: Any, Qc: Any, R: Any, m: Any
    ) -> Any:
        outs = one(time, U, E, Y, x0[0], P0[0], pvec[0], Qc[0], R[0], m)
        return tuple(a[None] for a in outs)

    return jax.jit(single)


def ekf_pass(
    model: Model,
    time: FloatArray,
    U: FloatArray,
    Y: FloatArray,
    out_idx: tuple[int, ...],
    params: Mapping[str, FloatArray],
    Qc: FloatArray,
    R: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    substeps: int,
    interpolation: Interpolation = "linear",
) -> Arrays | None:
    """(xf, Pf, xp, Pp, C, nu, S) for a batch of B filters, or None (use numpy); the
    controls between samples as `interpolation` says.

    None when the model's functions do not compile, or when any value is not
    finite (the numpy pass then jitters, or names the failure).
    """
    if not _compiled.ENABLED or not isinstance(model, Model):
        return None
    B = x0.shape[0]
    pmat = _compiled._pmatrix(model, params, B)
    pvec = pmat[0]
    if not _compiled.available(model, time, x0[0], U, pvec, measurement=True):
        return None
    mods = _compiled._import_jax()
    if mods is None:
        return None
    jax, jnp = mods
    cache = _compiled._shared(model)
    # a batch of filters (a fit's) or one (the filter stage's): a compilation each,
    # as any new batch size is
    batched = B > 1
    key = ("ekf_pass", tuple(out_idx), batched)
    fn = cache.get(key)
    if fn is None:
        fn = _build(model, tuple(out_idx), jax, jnp, batched)
        cache[key] = fn
    with quiet_warnings():
        try:
            E = control_excess(time, U, interpolation)
            outs = fn(time, U, E, Y, x0, P0, pmat, Qc, R, np.int32(substeps))
        except Exception:  # a model JAX traced pointwise but not in this pass: numpy
            return None
        arrays = tuple(np.asarray(a, dtype=np.float64) for a in outs)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        return None
    return arrays  # type: ignore[return-value]
