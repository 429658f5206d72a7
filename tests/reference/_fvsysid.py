"""FVSysID's flight files and its output-error method in plain numpy (not part of the library).

Jategaonkar's FVSysID (the software of "Flight Vehicle System Identification -
A Time Domain Methodology", 2nd ed.) ships its flight data as ``.asc`` tables
and ``.mat`` files holding one matrix named after the file; `read_flight`
reads either.

`ml_oem` is our own numpy version of the book's output-error method (chapter
4, ``ml_oem2.m`` and the routines it calls: ``costfun_oem``, ``gradFG``,
``gradrespH``, ``improv``, ``ruku4``, ``parUpdate``), written from the
algorithm, not translated line by line; the one port behind every
``ref_fvsysid_*`` output-error case:

- the record is one segment or several (``Nzi``), each integrated from its own
  initial state (`x0` per segment, `free_x0` its flags: ``parFlagX0``) with
  its own bias parameters (`bx`, `free_bx`: ``bXpar``, ``parFlagBX``); the
  system parameters `p0` (flags `free`: ``parFlag``) are shared;
- the outputs are simulated sample by sample: ``y_k = g(x_k, u_k)``, then one
  fourth-order Runge-Kutta step per sample interval with the input at the
  interval's start, the mean of its two ends at the half step and the end
  value at the full step; `post` then acts on each segment's outputs
  (FVSysID's output time delays, ``timeDelay.m``); a model without states
  (``state_eq=None``) is a regression, its outputs from all the segment's
  inputs at once;
- the noise covariance ``R`` is the diagonal of the residuals' mean square
  over all segments, re-estimated at every evaluation; the cost is ``det R``;
- response gradients are forward differences, each free quantity moved by
  ``step`` times its value (``step`` where it is zero), the perturbed trajectories
  integrated whole from the perturbed initial states (what ``gradrespH``'s
  stored states amount to);
- Gauss-Newton: ``F = sum H' R^-1 H``, ``G = -sum H' R^-1 (z - y)``, step
  ``-F^-1 G`` (Cholesky); a cost above the previous one halves the last step
  (at most ten times); it stops when the cost's relative change is below
  `tolerance` (FVSysID's ``tolR = 1e-4``) or after `max_iterations` steps;
- with `bounds` the step is the bounded-variable Gauss-Newton step
  (``improv.m``, ``chk_lub_opt.m``, ``chk_update.m``): a parameter whose step
  crosses a bound is set on it and held there while the gradient pushes it
  outwards (FVSysID's quadratic line search after a bound is hit is left out);
- the Cramer-Rao covariance is ``F^-1`` of the last information matrix
  computed, taken when a step is accepted (at the iterate before the final
  one, as ``ml_oem2`` reports it), its rows of parameters on a bound zeroed.

The helpers beside it serve the case scripts: FVSysID's smoothing and numerical
derivative of a measured channel (`smooth`, `differentiate`), a table row
(`row`), a case's equations as a user model (`user_model`) and the Monte Carlo
over several segments (`segment_monte_carlo`).

Model functions take ``(x, u, p)`` with ``x`` (nx, K) and ``p`` (np + nbx, K)
columns, one per perturbed copy (the segment's biases `bx` below the system
parameters), and ``u`` (nu,), and return (nx, K) or (ny, K), so one call
integrates the nominal model and all its perturbations together. Without
states ``obs_eq(None, U, p)`` gets the segment's inputs ``U`` (n, nu) and
returns (n, ny, K).
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

Fn = Callable[[Any, np.ndarray, np.ndarray], np.ndarray]
# post(y, p): one segment's outputs y (n, ny, K) for the parameter columns p (np + nbx, K)
Post = Callable[[np.ndarray, np.ndarray], np.ndarray]
D2R = np.pi / 180.0


def read_flight(path: pathlib.Path) -> np.ndarray:
    """A flight file as a float matrix: an ``.asc`` table or the one matrix of a ``.mat``."""
    if path.suffix.lower() == ".mat":
        import scipy.io

        d = scipy.io.loadmat(str(path))
        keys = [k for k in d if not k.startswith("__")]
        return np.asarray(d[path.stem if path.stem in d else keys[0]], dtype=float)
    return np.loadtxt(str(path), dtype=float)


def smooth(x: np.ndarray) -> np.ndarray:
    """``smoothMulTS`` on one segment: 15-point weights inside, 5-point near the
    ends, the three end samples raw."""
    y = x.copy()
    n = x.size
    w15 = np.array([-3, -6, -5, 3, 21, 46, 67, 74, 67, 46, 21, 3, -5, -6, -3]) / 320.0
    w5 = np.array([7, 24, 34, 24, 7]) / 96.0
    for k in range(3, n - 3):
        if k <= 7 or k >= n - 8:
            y[k] = w5 @ x[k - 2 : k + 3]
        else:
            y[k] = w15 @ x[k - 7 : k + 8]
    return y


def differentiate(x: np.ndarray, dt: float) -> np.ndarray:
    """``ndiff_Filter08`` on one segment: 17-point derivative inside, 5-point near
    the ends, the two end samples copied from their neighbour."""
    n = x.size
    c17 = np.array(
        [-0.00000971250971, 0.00017760017759, -0.00155400155390, 0.00870240870185,
         -0.03535353535135, 0.11313131312500, -0.31111111109862, 0.88888888887637]
    )  # fmt: skip
    d = np.zeros(n)
    for k in range(2, n - 2):
        if k <= 8 or k >= n - 9:
            d[k] = (-(x[k + 2] - x[k - 2]) / 12.0 + 2.0 * (x[k + 1] - x[k - 1]) / 3.0) / dt
        else:
            d[k] = sum(c17[7 - j] * (x[k + j + 1] - x[k - j - 1]) for j in range(8)) / dt
    d[:2] = d[2]
    d[-2:] = d[-3]
    return d


def row(
    case: str,
    name: str,
    theirs: float,
    theirs_se: float | None,
    ours: float | None,
    ours_se: float | None,
    **extra: Any,
) -> dict[str, Any]:
    """One table row with FVSysID's figure (the port's or a saved one) in the SIDPAC
    columns; FVSysID gives no corrected bars."""
    import _sidpac as S

    return S.row(
        case,
        name,
        sidpac=theirs,
        sidpac_se_white=theirs_se,
        sidpac_se_corrected=None,
        ours=ours,
        ours_se=ours_se,
        **extra,
    )


def user_model(
    state_eq: Fn,
    obs_eq: Fn,
    names: Sequence[str],
    p0: Sequence[float],
    *,
    states: Sequence[str],
    controls: Sequence[str],
    outputs: Sequence[str],
    name: str,
) -> Any:
    """A case's ``(x, u, p)`` equations as a user ``aeroid.Model``, p in the order
    of `names` (the parameters' names and starting values)."""
    import aeroid

    def vector(p: Any) -> list[Any]:
        return [p[n] for n in names]

    return aeroid.Model(
        states=list(states),
        controls=list(controls),
        parameters=dict(zip(names, p0, strict=True)),
        dynamics=lambda t, x, u, p: state_eq(x, u, vector(p)),
        outputs=list(outputs),
        measurement=lambda t, x, u, p: obs_eq(x, u, vector(p)),
        name=name,
    )


def segment_monte_carlo(
    refit: Callable[[list[np.ndarray]], dict[str, float]],
    fitted: list[np.ndarray],
    resid: list[np.ndarray],
    n: int,
    seed: int,
) -> dict[str, float]:
    """`_sidpac.monte_carlo` over several segments, each segment's surrogate drawn
    from its own residuals; `refit` gets the records as a list of segments."""
    import _sidpac as S

    cuts = np.cumsum([r.shape[0] for r in resid])[:-1]

    def draw(rng: np.random.Generator) -> np.ndarray:
        return np.concatenate([S.phase_surrogate(r, rng) for r in resid])

    return S.monte_carlo(
        lambda z: refit(np.split(z, cuts)), np.concatenate(fitted), None, n, seed=seed, draw=draw
    )


@dataclasses.dataclass(frozen=True)
class OemResult:
    """An output-error fit: estimates `p` (all system parameters), initial states
    `x0` (segments, nx) and biases `bx` (segments, nbx), outputs `y` (n, ny) over
    the concatenated segments, noise covariance `R` (diagonal), Cramer-Rao
    covariance `crb` of the free quantities in the order of `names` (free system
    parameters, then free initial states and free biases segment by segment, as
    ``par_accuracy``), the cost ``det R`` of every evaluation, the Gauss-Newton
    iterations, whether the cost converged, the free mask of `p` and the bound
    each parameter ends on (-1 lower, +1 upper, 0 none)."""

    p: np.ndarray
    x0: np.ndarray
    bx: np.ndarray
    y: np.ndarray
    R: np.ndarray
    crb: np.ndarray
    names: tuple[str, ...]
    cost: tuple[float, ...]
    iterations: int
    converged: bool
    free: np.ndarray
    active: np.ndarray

    @property
    def se(self) -> np.ndarray:
        """Cramer-Rao standard deviations of every system parameter (zero where fixed
        or on a bound)."""
        out = np.zeros(self.p.size)
        n = int(self.free.sum())
        out[self.free] = np.sqrt(np.clip(np.diag(self.crb)[:n], 0.0, None))
        return out

    @property
    def stderr(self) -> dict[str, float]:
        """Cramer-Rao standard deviations of the free quantities by name."""
        sd = np.sqrt(np.clip(np.diag(self.crb), 0.0, None))
        return dict(zip(self.names, (float(s) for s in sd), strict=True))


def rk4_step(f: Fn, x: np.ndarray, u1: np.ndarray, u2: np.ndarray, p: np.ndarray, dt: float) -> Any:
    """One Runge-Kutta step over a sample interval, inputs at its start, mean and end."""
    um = 0.5 * (u1 + u2)
    k1 = f(x, u1, p)
    k2 = f(x + 0.5 * dt * k1, um, p)
    k3 = f(x + 0.5 * dt * k2, um, p)
    k4 = f(x + dt * k3, u2, p)
    return x + dt * (k1 + 2.0 * (k2 + k3) + k4) / 6.0


def simulate(
    state_eq: Fn | None,
    obs_eq: Fn,
    x0: np.ndarray,
    u: np.ndarray,
    dt: float,
    p: np.ndarray,
    post: Post | None = None,
) -> np.ndarray:
    """Outputs (n, ny, K) of one segment for K parameter columns `p` (np, K), from
    the initial states `x0` (nx,) or one column each (nx, K)."""
    k = p.shape[1]
    if state_eq is None:
        y = np.asarray(obs_eq(None, u, p), dtype=float)
    else:
        x = np.asarray(x0, dtype=float)
        x = np.repeat(x.reshape(-1, 1), k, axis=1) if x.ndim == 1 else x
        out = []
        n = u.shape[0]
        for i in range(n):
            out.append(np.asarray(obs_eq(x, u[i], p), dtype=float).reshape(-1, k))
            if i < n - 1 and x.shape[0]:
                x = rk4_step(state_eq, x, u[i], u[i + 1], p, dt)
        y = np.stack(out)
    return post(y, p) if post is not None else y


def _as_segments(a: Any) -> list[np.ndarray]:
    if isinstance(a, np.ndarray):
        return [a]
    return [np.asarray(s, dtype=float) for s in a]


def _per_segment(a: Any, nz: int) -> np.ndarray:
    """`x0` or `bx` as one row per segment (one vector serves every segment)."""
    if a is None:
        return np.zeros((nz, 0))
    if isinstance(a, list | tuple):
        a = [np.ravel(s) for s in a]
    v = np.array(a, dtype=float)
    return np.tile(v, (nz, 1)) if v.ndim == 1 else v.reshape(nz, -1)


def _steps(v: np.ndarray, step: float) -> np.ndarray:
    """Forward-difference perturbations: ``step * v``, `step` where v is zero."""
    h = step * v
    h[h == 0] = step
    return h


def ml_oem(
    state_eq: Fn | None,
    obs_eq: Fn,
    x0: Any,
    u: Any,
    z: Any,
    dt: float,
    p0: Any,
    *,
    free: Any = None,
    free_x0: Any = None,
    bx: Any = None,
    free_bx: Any = None,
    bounds: tuple[Any, Any] | None = None,
    post: Post | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-4,
    step: float = 1e-6,
    names: Sequence[str] | None = None,
) -> OemResult:
    """FVSysID's output-error method (``ml_oem2``, Gauss-Newton) on one record or a
    list of segments (`u`, `z` then lists of the same length, fitted together with
    one ``R``; `x0` a row per segment, None without states). `free` masks the
    estimated system parameters (all by default), `free_x0` and `free_bx` the
    estimated initial states and biases (none by default); ``bounds = (p_min,
    p_max)`` with +-inf where unbounded; see the module for the rest."""
    us = [s.reshape(s.shape[0], -1) for s in _as_segments(u)]
    zs = _as_segments(z)
    nz = len(us)
    zall = np.concatenate(zs)
    p = np.asarray(p0, dtype=float).ravel().copy()
    xs = _per_segment(x0, nz)
    bs = _per_segment(bx, nz)
    fp = np.ones(p.size, bool) if free is None else np.asarray(free, bool).ravel()
    fx = np.zeros(xs.shape, bool) if free_x0 is None else np.asarray(free_x0, bool)
    fb = np.zeros(bs.shape, bool) if free_bx is None else np.asarray(free_bx, bool)
    idx = np.flatnonzero(fp)
    pnames = list(names) if names is not None else [f"p{i + 1}" for i in range(p.size)]
    labels = [pnames[i] for i in idx]
    xfree = [(k, int(j)) for k in range(nz) for j in np.flatnonzero(fx[k])]
    bfree = [(k, int(j)) for k in range(nz) for j in np.flatnonzero(fb[k])]
    labels += [f"x0[{k}].{j}" for k, j in xfree] + [f"bx[{k}].{j}" for k, j in bfree]
    nfree = len(labels)
    lo, hi = (
        (np.full(p.size, -np.inf), np.full(p.size, np.inf))
        if bounds is None
        else (np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float))
    )
    bounded = bool(np.any(np.isfinite(lo[idx]) | np.isfinite(hi[idx])))
    state = np.zeros(p.size, dtype=int)  # -1 lower, +1 upper bound active

    def pack() -> np.ndarray:
        return np.concatenate([p[fp], xs[fx], bs[fb]])

    def unpack(theta: np.ndarray) -> None:
        n1, n2 = idx.size, idx.size + int(fx.sum())
        p[fp], xs[fx], bs[fb] = theta[:n1], theta[n1:n2], theta[n2:]

    def columns(k: int, pp: np.ndarray) -> np.ndarray:
        """Segment k's parameter columns: the system parameters, its biases below."""
        return np.concatenate([pp, np.repeat(bs[k][:, None], pp.shape[1], axis=1)])

    def evaluate() -> tuple[float, np.ndarray, list[np.ndarray]]:
        ys = [
            simulate(state_eq, obs_eq, xs[k], us[k], dt, columns(k, p[:, None]), post)[:, :, 0]
            for k in range(nz)
        ]
        ss = sum(((zk - yk) ** 2).sum(axis=0) for zk, yk in zip(zs, ys, strict=True))
        r = np.diag(ss / zall.shape[0])
        return float(np.linalg.det(r)), r, ys

    def sensitivities(ys: list[np.ndarray]) -> list[np.ndarray]:
        """Forward-difference response gradients (n, ny, nfree), every segment; a
        segment's initial states and biases move only its own outputs."""
        h = np.concatenate([_steps(p[idx], step), _steps(xs[fx], step), _steps(bs[fb], step)])
        out = []
        for k in range(nz):
            cols = np.repeat(p[:, None], nfree, axis=1)
            cols[idx, np.arange(idx.size)] += h[: idx.size]
            cols = columns(k, cols)
            xk = np.repeat(xs[k][:, None], nfree, axis=1)
            for c, (kk, j) in enumerate(xfree, start=idx.size):
                if kk == k:
                    xk[j, c] += h[c]
            for c, (kk, j) in enumerate(bfree, start=idx.size + len(xfree)):
                if kk == k:
                    cols[p.size + j, c] += h[c]
            y = simulate(state_eq, obs_eq, xk, us[k], dt, cols, post)
            out.append((y - ys[k][:, :, None]) / h)
        return out

    costs: list[float] = []
    prev = 0.0
    theta_old = pack()
    info = np.eye(nfree)
    crb = np.full((nfree, nfree), np.nan)
    it = 0
    halvings = 0
    converged = False
    while it <= max_iterations:
        cost, r, ys = evaluate()
        costs.append(cost)
        rel = abs((cost - prev) / cost)
        if it > 0 and (cost < prev or rel < tolerance):
            crb = np.linalg.inv(info)
            # ml_oem2 zeroes the deviations of the parameters on a bound
            on = np.flatnonzero(state[idx] != 0)
            crb[on, :] = 0.0
            crb[:, on] = 0.0
        if it > 0 and rel < tolerance:
            converged = True
            break
        if it > 0 and cost > prev:
            if halvings == 10:
                break
            unpack(0.5 * (pack() + theta_old))
            halvings += 1
            continue
        if it == max_iterations:
            break
        # summed segment by segment in this order: case 22's fit stops where the
        # rounding of this sum alone moves its biases by up to 0.03 sigma
        ri = np.diag(1.0 / np.diag(r))
        info = np.zeros((nfree, nfree))
        grad = np.zeros(nfree)
        for sk, yk, zk in zip(sensitivities(ys), ys, zs, strict=True):
            hk = np.ascontiguousarray(sk.transpose(2, 0, 1))  # (nfree, n, ny)
            info += np.einsum("pia,ab,qib->pq", hk, ri, hk)
            grad -= np.einsum("pia,ab,ib->p", hk, ri, zk - yk)
        delta = np.zeros(nfree)
        keep = np.ones(nfree, bool)
        if bounded:
            # release a bound the gradient now pulls away from (chk_lub_opt)
            for j, ip in enumerate(idx):
                if (state[ip] == -1 and grad[j] < 0) or (state[ip] == 1 and grad[j] > 0):
                    state[ip] = 0
            keep[: idx.size] = state[idx] == 0
        c = np.linalg.cholesky(info[np.ix_(keep, keep)])
        delta[keep] = -np.linalg.solve(c.T, np.linalg.solve(c, grad[keep]))
        theta_old = pack()
        unpack(theta_old + delta)
        if bounded:
            for ip in idx:
                if p[ip] < lo[ip]:
                    p[ip], state[ip] = lo[ip], -1
                elif p[ip] > hi[ip]:
                    p[ip], state[ip] = hi[ip], 1
        prev = cost
        it += 1
        halvings = 0
    return OemResult(
        p=p,
        x0=xs,
        bx=bs,
        y=np.concatenate(ys),
        R=r,
        crb=crb,
        names=tuple(labels),
        cost=tuple(costs),
        iterations=it,
        converged=converged,
        free=fp,
        active=state,
    )
