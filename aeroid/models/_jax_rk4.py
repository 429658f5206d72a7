"""JAX graphs of the fixed-step RK4 rollout: one interval, its state Jacobian, the whole record,
its tangent-linear sensitivities and the first-order effect of control noise.

Each builder takes the traced single-point model function(s) and the `jax` module and
returns a function of arrays that `aeroid.models.compiled` vmaps and jit-compiles; the steps
reproduce `aeroid.models.integration.rk4` substep for substep. Beside the controls each
program takes their excess over the straight line per interval (``e``, ``(n_t - 1, 2,
n_u)``: `aeroid.models.integration.control_excess`), zero for straight lines: one program
for straight and cubic controls, at any substep count.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .integration import _INSIDE

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model


def _node(u0: Any, du: Any, e: Any, s: Any) -> Any:
    """The controls at fraction `s` of an interval: the straight line plus the cubic's
    excess (`_integrate.hermite`, the same operations), which adds zero where `e` is."""
    return u0 + s * du + s * (1.0 - s) * ((1.0 - s) * e[0] - s * e[1])


def _substep(f: Callable[..., Any], jax: Any) -> Callable[..., Any]:
    """Substep `j` of `m` of one grid interval of RK4, as `_integrate.rk4` computes it;
    `e` (2, n_u): the interval's `hermite` excess a and b."""

    def sub(j: Any, x: Any, t0: Any, t1: Any, u0: Any, u1: Any, e: Any, pvec: Any, m: Any) -> Any:
        mf = m.astype(x.dtype)
        h = (t1 - t0) / mf
        hh = 0.5 * h
        du = u1 - u0
        inside = _INSIDE * (t1 - t0)
        jf = j.astype(x.dtype)
        ta = t0 + jf * h
        # one-sided ends of the interval, as `_integrate.rk4` evaluates them
        t_first = jax.numpy.where(j == 0, t0 + inside, ta)
        t_last = jax.numpy.where(j == m - 1, t1 - inside, ta + h)
        # (2j)/(2m) etc.: the same correctly rounded fractions as numpy's node grid
        ua = _node(u0, du, e, (2.0 * jf) / (2.0 * mf))
        um = _node(u0, du, e, (2.0 * jf + 1.0) / (2.0 * mf))
        ub = _node(u0, du, e, (2.0 * jf + 2.0) / (2.0 * mf))
        k1 = f(t_first, x, ua, pvec)
        k2 = f(ta + hh, x + hh * k1, um, pvec)
        k3 = f(ta + hh, x + hh * k2, um, pvec)
        k4 = f(t_last, x + h * k3, ub, pvec)
        return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)

    return sub


def _interval(f: Callable[..., Any], jax: Any) -> Callable[..., Any]:
    """One grid interval of RK4 with `m` substeps, as `_integrate.rk4` computes it.

    `m` is an argument (a traced integer), so one compilation serves every
    substep count that the stiffness rule picks as the parameters move.
    """
    sub = _substep(f, jax)

    def step(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, e: Any, pvec: Any, m: Any) -> Any:
        def body(j: Any, x: Any) -> Any:
            return sub(j, x, t0, t1, u0, u1, e, pvec, m)

        return jax.lax.fori_loop(0, m, body, x)

    return step


def _interval_jacobian(f: Callable[..., Any], jax: Any, jnp: Any) -> Callable[..., Any]:
    """``(x, t0, t1, z, place, m) -> (phi, gz)``: the Jacobians of one grid interval's
    RK4 step by its start state and by `z`, where ``place(z)`` gives the
    ``(pvec, u0, u1, e)`` the step uses.

    Substep by substep, each differentiated on its own and the Jacobians chained
    in the loop: differentiating through the loop would trace the model many
    times over (the fixed points that JAX's forward mode and batching of a
    loop iterate), and tracing dominates the compilation of a large model.
    """
    sub = _substep(f, jax)

    def jacobian(
        x: Any, t0: Any, t1: Any, z: Any, place: Callable[[Any], Any], m: Any
    ) -> tuple[Any, Any]:
        def substep(j: Any, xj: Any) -> tuple[Any, Any, Any]:
            def one(xj: Any, z: Any) -> tuple[Any, Any]:
                pvec, u0, u1, e = place(z)
                xn = sub(j, xj, t0, t1, u0, u1, e, pvec, m)
                return xn, xn

            (jx, jz), xn = jax.jacfwd(one, argnums=(0, 1), has_aux=True)(xj, z)
            return xn, jx, jz

        def body(j: Any, carry: tuple[Any, Any, Any]) -> tuple[Any, Any, Any]:
            xj, phi, gz = carry
            xn, jx, jz = substep(j, xj)
            return xn, jx @ phi, jx @ gz + jz

        # the first substep outside the loop: one substep (the usual case) multiplies
        # no Jacobians
        return jax.lax.fori_loop(1, m, body, substep(jnp.int32(0), x))[1:]

    return jacobian


def _fixed_interval(f: Callable[..., Any], jax: Any, jnp: Any, substeps: int) -> Callable[..., Any]:
    """`_interval` with the substep count written into the program (its `m` argument
    ignored): no inner loop to run, a third faster for one substep. The same steps; the
    compiler may order their rounding differently."""
    sub = _substep(f, jax)
    m = jnp.int32(substeps)

    def step(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, e: Any, pvec: Any, _m: Any) -> Any:
        for j in range(substeps):
            x = sub(jnp.int32(j), x, t0, t1, u0, u1, e, pvec, m)
        return x

    return step


def _rollout(
    f: Callable[..., Any], jax: Any, jnp: Any, substeps: int | None = None, unroll: int = 2
) -> Callable[..., Any]:
    """``(time, u (n_t, n_u), e (n_t - 1, 2, n_u), x0 (n_x,), pvec, m) -> states (n_t,
    n_x)``; with `substeps`, that count written into the program (`_fixed_interval`) in
    place of `m`; `unroll` intervals per loop iteration."""
    step = _interval(f, jax) if substeps is None else _fixed_interval(f, jax, jnp, substeps)

    def roll(time: Any, u: Any, e: Any, x0: Any, pvec: Any, m: Any) -> Any:
        def body(x: Any, inp: Any) -> tuple[Any, Any]:
            t0, t1, u0, u1, ek = inp
            x = step(x, t0, t1, u0, u1, ek, pvec, m)
            return x, x

        # by default two intervals per loop iteration (the sensitivities' rollout); the
        # sampler's and the batch rollout take one: unrolled, they compile longer
        inputs = (time[:-1], time[1:], u[:-1], u[1:], e)
        _, xs = jax.lax.scan(body, x0, inputs, unroll=unroll)
        return jnp.concatenate([x0[None, :], xs], axis=0)

    return roll


def _tangent_linear(
    f: Callable[..., Any], h: Callable[..., Any] | None, model: Model, jax: Any, jnp: Any
) -> Callable[..., Any]:
    """``(theta, pbase, pidx, dpos, xbase, xidx, time, u, e, m) -> (y, J, states, phi, hx)``.

    Outputs and their Jacobian with respect to ``theta`` (the parameters at
    `pidx`, then the initial states at `xidx`; ``dpos`` marks the parameters
    the dynamics read, `_dynamic_parameters`), with the pieces
    `input_noise_scatter` reuses: the states, each interval's state-transition
    Jacobian ``phi`` and the measurement's state Jacobian ``hx`` per sample.

    Forward mode through the rollout would carry every tangent through every
    step of a sequential loop of small operations. Here the one sequential
    part is a matrix recursion: the Jacobians of each sample interval's RK4
    step are computed for all intervals at once along the primal trajectory,
    then ``S[k+1] = phi[k] S[k] + G[k]`` chains them (the same chain rule in
    another order: equal to rounding).
    """
    interval_jacobian = _interval_jacobian(f, jax, jnp)
    roll = _rollout(f, jax, jnp)
    out_idx = np.array([model.states.index(o) for o in model.output_names]) if h is None else None

    def tl(
        theta: Any,
        pbase: Any,
        pidx: Any,
        dpos: Any,
        xbase: Any,
        xidx: Any,
        time: Any,
        u: Any,
        e: Any,
        m: Any,
    ) -> tuple[Any, Any, Any, Any, Any]:
        n_p = pidx.shape[0]
        n_d = dpos.shape[0]  # the parameters (at these positions of theta) the dynamics read
        n_x = xbase.shape[0]
        th = theta[:n_p]
        x0 = xbase.at[xidx].set(theta[n_p:])
        pvec = pbase.at[pidx].set(th)
        xs = roll(time, u, e, x0, pvec, m)
        pd = pidx[dpos]

        def local(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, ek: Any) -> Any:
            def place(thd: Any) -> tuple[Any, Any, Any, Any]:
                return pvec.at[pd].set(thd), u0, u1, ek

            return interval_jacobian(x, t0, t1, th[dpos], place, m)

        phi, gp = jax.vmap(local)(xs[:-1], time[:-1], time[1:], u[:-1], u[1:], e)
        forcing = jnp.concatenate([gp, jnp.zeros((phi.shape[0], n_x, xidx.shape[0]))], axis=2)
        s0 = jnp.concatenate([jnp.zeros((n_x, n_d)), jnp.eye(n_x)[:, xidx]], axis=1)

        def chain(s: Any, k: Any) -> tuple[Any, Any]:
            s = k[0] @ s + k[1]
            return s, s

        _, rest = jax.lax.scan(chain, s0, (phi, forcing))
        sx = jnp.concatenate([s0[None], rest], axis=0)  # (n_t, n_x, n_d + n_x0)

        def columns(chained: Any) -> Any:
            # the chained columns in theta's order: dynamic parameters, then initial states
            J = jnp.zeros((*chained.shape[:2], theta.shape[0]))
            return J.at[:, :, dpos].set(chained[:, :, :n_d]).at[:, :, n_p:].set(chained[:, :, n_d:])

        if h is None:
            pick = jnp.eye(n_x)[out_idx]
            hx = jnp.broadcast_to(pick, (time.shape[0], *pick.shape))
            return xs[:, out_idx], columns(sx[:, out_idx, :]), xs, phi, hx

        def meas(t: Any, x: Any, uk: Any) -> Any:
            def g(x: Any, th: Any) -> Any:
                y = h(t, x, uk, pbase.at[pidx].set(th))
                return y, y

            (hx, hp), y = jax.jacfwd(g, argnums=(0, 1), has_aux=True)(x, th)
            return y, hx, hp

        y, hx, hp = jax.vmap(meas)(time, xs, u)
        J = columns(jnp.einsum("kyx,kxc->kyc", hx, sx)).at[:, :, :n_p].add(hp)
        return y, J, xs, phi, hx

    return tl


def _input_noise_scatter(
    f: Callable[..., Any], h: Callable[..., Any] | None, jax: Any, jnp: Any
) -> Callable[..., Any]:
    """``(states, phi, hx, time, u, e, pvec, m, c, sigma) -> Q``: the covariance of
    ``sum_k c[k]' dy[k]`` when the controls carry white noise of standard
    deviations `sigma` (n_u,) at every sample, dy being the outputs' first-order
    response; ``c`` (n_t, n_y, cols) weights each sample's outputs (a fit's
    ``R^-1 dy/dtheta``), so that Q is the scatter of the Gauss–Newton gradient.

    By the adjoint of the tangent-linear recursion of `_tangent_linear`: one
    backward pass ``lam[k] = hx[k]' c[k] + phi[k]' lam[k+1]`` gives every
    sample's control its effect on the weighted sum, exactly, with no draws. A
    control sample moves its two intervals only: the straight lines' rule (`e` held,
    zero for them; the cubic's excess also moves with the samples beside them).
    """
    interval_jacobian = _interval_jacobian(f, jax, jnp)

    def scatter(
        xs: Any,
        phi: Any,
        hx: Any,
        time: Any,
        u: Any,
        e: Any,
        pvec: Any,
        m: Any,
        c: Any,
        sigma: Any,
    ) -> Any:
        n_u = u.shape[1]

        def local(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, ek: Any) -> Any:
            def place(z: Any) -> tuple[Any, Any, Any, Any]:
                return pvec, z[:n_u], z[n_u:], ek

            return interval_jacobian(x, t0, t1, jnp.concatenate([u0, u1]), place, m)[1]

        b = jax.vmap(local)(xs[:-1], time[:-1], time[1:], u[:-1], u[1:], e)
        # products of small matrices per sample, as broadcast sums (one fused loop each)
        g = jnp.sum(hx[:, :, :, None] * c[:, :, None, :], axis=1)  # (n_t, n_x, cols)

        def back(lam: Any, k: Any) -> tuple[Any, Any]:
            lam = k[1] + k[0].T @ lam
            return lam, lam

        _, lams = jax.lax.scan(back, g[-1], (phi, g[:-1]), reverse=True)
        after = jnp.concatenate([lams[1:], g[-1:]], axis=0)  # lam[k + 1] for each interval k
        # a control sample enters the interval it starts and the one it ends
        z0 = jnp.sum(b[:, :, :n_u, None] * after[:, :, None, :], axis=1)
        z1 = jnp.sum(b[:, :, n_u:, None] * after[:, :, None, :], axis=1)
        zero = jnp.zeros_like(z0[:1])
        z = jnp.concatenate([z0, zero], axis=0) + jnp.concatenate([zero, z1], axis=0)
        if h is not None:

            def meas(t: Any, x: Any, uk: Any) -> Any:
                return jax.jacfwd(lambda uk: h(t, x, uk, pvec))(uk)

            hu = jax.vmap(meas)(time, xs, u)
            z = z + jnp.sum(hu[:, :, :, None] * c[:, :, None, :], axis=1)
        flat = (z * sigma[None, :, None]).reshape(-1, c.shape[2])
        return flat.T @ flat

    return scatter
