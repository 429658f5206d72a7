"""FVSysID's filter error method in plain numpy (reference code, not the library).

Our own numpy version of the algorithm of Jategaonkar's FVSysID, chapter 5
(``ml_fem2.m`` with ``costfun_fem``, ``gainmat``, ``gainmatPert``, ``gradFG``,
``kcle1``, ``fcompn`` and ``par_accuracy``): the filter error method for
nonlinear systems with a steady-state Kalman gain, written from the book's
equations:

* the model predicts with the nonlinear state equations (``ruku4``: one
  Runge-Kutta step per sample, the input at the interval's ends and their
  mean at its middle) and corrects each prediction by a constant gain,
  ``x^ = x~ + K (z - h(x~))``;
* ``K = P C' R^-1`` with ``P`` the stabilising solution of the continuous
  Riccati equation ``A P + P A' - P C' R^-1 C P / dt + F F' = 0`` (Potter's
  eigenvector method on the Hamiltonian), ``A``, ``C`` central differences at
  the initial state and first input, ``F`` diagonal with the last ``nx``
  parameters on its diagonal (a standard deviation per state: ``F_ii^2`` is
  the continuous process-noise spectral density);
* ``R`` is the diagonal of the innovations' mean square (the innovation
  covariance itself, not the measurement noise), the cost ``det R``;
* a relaxation: Gauss-Newton in the parameters (forward differences of the
  whole predictor, each perturbed member with its own gain) with ``R``
  held; from the third iteration on, after every step, ``R`` is re-estimated
  and ``F`` rescaled by the heuristic of Eq. (5.41) (``fcompn``); step
  halving on a rising cost; the linearised constraint ``diag(K C) <= 1``
  (``kcle1``);
* the Cramer-Rao covariance is the inverse of the last information matrix
  (``F = sum Q' R^-1 Q`` with ``R`` held), as ``par_accuracy`` prints.

Also the flight-data reader for the book's ``.asc`` files (``load -ascii``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from _fvsysid import ml_oem, rk4_step  # one RK4 and one output error for every port

# f(x (B, nx), u (B, nu), p (B, np)) -> (B, nx); h likewise -> (B, ny)
BatchFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _jacobian(fn: BatchFn, x: np.ndarray, u: np.ndarray, p: np.ndarray, step: float = 1e-4):
    """Central-difference Jacobian of one member's fn in x (fn's rows by x's columns)."""
    n = x.size
    e = np.eye(n) * step
    hi = fn(x[None] + e, np.repeat(u[None], n, 0), np.repeat(p[None], n, 0))
    lo = fn(x[None] - e, np.repeat(u[None], n, 0), np.repeat(p[None], n, 0))
    return ((hi - lo) / (2 * step)).T


def riccati_potter(A: np.ndarray, FF: np.ndarray, CRC: np.ndarray) -> np.ndarray:
    """The stabilising P of ``A P + P A' - P CRC P + FF = 0`` from the Hamiltonian's
    eigenvectors: those of its eigenvalues with positive real part, ``P = -E1 E2^-1``."""
    n = A.shape[0]
    ham = np.block([[A, -FF], [-CRC, -A.T]])
    lam, vec = np.linalg.eig(ham)
    pick = np.argsort(lam.real)[n:]
    e1, e2 = vec[:n, pick], vec[n:, pick]
    return np.real(-e1 @ np.linalg.inv(e2))


@dataclass
class FemCase:
    """One test case: the batched model, its data and its set-up (an mDefCase)."""

    f: BatchFn
    h: BatchFn
    nx: int
    z: np.ndarray  # (N, ny) measured outputs
    u: np.ndarray  # (N, nu) inputs
    dt: float
    x0: np.ndarray
    p0: np.ndarray  # all parameters, the last nx the diagonal of F
    free: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        if self.free.size == 0:
            self.free = np.ones(self.p0.size, dtype=bool)


@dataclass
class FemResult:
    """What ml_fem2 ends with."""

    p: np.ndarray  # all parameters
    cov: np.ndarray  # Cramer-Rao covariance of the free ones
    se: np.ndarray  # its standard deviations, free parameters in order
    R: np.ndarray  # innovation covariance (diagonal)
    y: np.ndarray  # predicted outputs
    K: np.ndarray
    cost: float
    iterations: int
    history: list[str]


class _Fem:
    def __init__(self, case: FemCase) -> None:
        self.c = case
        self.nF = case.nx

    def gains(self, P: np.ndarray, RI: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Steady-state gains (B, nx, ny) and linearised C (B, ny, nx) of each member."""
        c = self.c
        Ks, Cs = [], []
        for p in P:
            A = _jacobian(c.f, c.x0, c.u[0], p)
            C = _jacobian(c.h, c.x0, c.u[0], p)
            fd = p[-self.nF :]
            pcov = riccati_potter(A, np.diag(fd**2), C.T @ RI @ C / c.dt)
            Ks.append(pcov @ C.T @ RI)
            Cs.append(C)
        return np.array(Ks), np.array(Cs)

    def predict(self, P: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Predicted outputs (B, N, ny) of the constant-gain filter of each member."""
        c = self.c
        B = P.shape[0]
        n = c.z.shape[0]
        x = np.repeat(c.x0[None], B, 0).astype(float)
        y = np.empty((B, n, c.z.shape[1]))
        for k in range(n):
            uk = np.repeat(c.u[k][None], B, 0)
            y[:, k] = c.h(x, uk, P)
            if k + 1 < n:
                xc = x + np.einsum("bij,bj->bi", K, c.z[k] - y[:, k])
                x = rk4_step(c.f, xc, uk, np.repeat(c.u[k + 1][None], B, 0), P, c.dt)
        return y

    def cost(self, p: np.ndarray, RI: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, tuple]:
        """(det R, R, predicted outputs, (K, C)) at p with the gain from RI."""
        K, C = self.gains(p[None], RI)
        y = self.predict(p[None], K)[0]
        R = np.diag(np.mean((self.c.z - y) ** 2, axis=0))
        return float(np.linalg.det(R)), R, y, (K[0], C[0])

    def information(
        self, p: np.ndarray, RI: np.ndarray, y: np.ndarray, KC: np.ndarray, step: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Information matrix, gradient, parameter steps and d diag(KC)/dp (free ones)."""
        idx = np.flatnonzero(self.c.free)
        dp = step * p[idx]
        dp[dp == 0] = step
        P = np.repeat(p[None], idx.size, 0)
        P[np.arange(idx.size), idx] += dp
        Kp, Cp = self.gains(P, RI)
        gradKC = (np.einsum("bij,bji->bi", Kp, Cp) - np.diag(KC)).T
        gradKC = gradKC / dp[None]
        yp = self.predict(P, Kp)
        Q = (yp - y[None]) / dp[:, None, None]  # (np, N, ny)
        w = np.diag(RI)
        F = np.einsum("pka,a,qka->pq", Q, w, Q)
        G = -np.einsum("pka,a,ka->p", Q, w, self.c.z - y)
        return F, G, dp, gradKC


def _constrain(F: np.ndarray, step: np.ndarray, KC: np.ndarray, gradKC: np.ndarray):
    """kcle1: keep the linearised diag(KC) <= 1, projecting the step where it is not."""
    g2j = np.linalg.inv(F)
    excess = np.diag(KC) + gradKC @ step - 1.0
    hit = excess > 0
    if not np.any(hit):
        return step
    M = gradKC[hit]
    return step - g2j @ M.T @ np.linalg.solve(M @ g2j @ M.T, excess[hit])


def _f_compensation(p: np.ndarray, nF: int, free: np.ndarray, RInew, RIold, C) -> np.ndarray:
    """fcompn, Eq. (5.41): rescale the free F elements for the change of R."""
    out = p.copy()
    w = np.diag(RIold)
    ratio = np.sqrt(w / np.diag(RInew))
    c2 = C**2
    factor = (c2.T @ (w * ratio)) / (c2.T @ w)
    tail = np.arange(p.size - nF, p.size)
    out[tail] = np.where(free[tail], p[tail] * factor, p[tail])
    return out


def ml_fem(
    case: FemCase,
    *,
    par_step: float = 1e-4,
    tol: float = 1e-4,
    max_iterations: int = 15,
    f_update_from: int = 3,
) -> FemResult:
    """FVSysID's ml_fem2 relaxation on `case` (its defaults: par_step 1e-4, tolR 1e-4,
    15 iterations, F compensated from the third)."""
    fem = _Fem(case)
    nF = case.nx
    free = case.free
    p = case.p0.astype(float).copy()
    log: list[str] = []
    # start: R from the residuals of the plain simulation (K = 0)
    y = fem.predict(p[None], np.zeros((1, case.nx, case.z.shape[1])))[0]
    RI = np.diag(1.0 / np.mean((case.z - y) ** 2, axis=0))
    it = 0
    khalf = 0
    prev = 0.0
    f_updated = False
    pending = True  # the while-iFcmp loop of ml_fem2: evaluate before deciding
    p_old = p.copy()
    f_alt = p[-nF:].copy()
    ri_alt = RI.copy()
    F_info = np.eye(int(free.sum()))
    cost = np.inf
    R = np.linalg.inv(RI)
    KC = np.zeros((nF, nF))
    C = np.zeros((case.z.shape[1], nF))
    while it <= max_iterations:
        while pending:
            cost, R, y, (K, C) = fem.cost(p, RI)
            KC = K @ C
            if not f_updated:
                log.append(f"iteration {it}: det R = {cost:.6g}")
                pending = False
            else:
                log.append(f"F corrected: det R = {cost:.6g}")
                if cost > prev:
                    khalf += 1
                    if khalf < 3:
                        p[-nF:] = 0.5 * (p[-nF:] + f_alt)
                    elif khalf == 3:
                        p[-nF:] = f_alt
                        RI = ri_alt
                    else:
                        pending = False
                else:
                    pending = False
        if it == max_iterations:
            log.append("maximum number of iterations")
            break
        if cost > prev and it > 0:
            if khalf == 10:
                log.append("no improvement after 10 halvings")
                break
            p = 0.5 * (p + p_old)
            khalf += 1
            pending = True
            continue
        F_info, G, _, gradKC = fem.information(p, RI, y, KC, par_step)
        step = -np.linalg.solve(F_info, G)
        step = _constrain(F_info, step, KC, gradKC)
        p_old = p.copy()
        p[free] += step
        prev = cost
        it += 1
        pending = True
        khalf = 0
        if it < f_update_from:
            continue
        # after the step: evaluate, halve while the cost rises, stop on convergence
        khalf = 1
        rel = np.inf
        while khalf != 0:
            cost, Rnew, y, (K, C) = fem.cost(p, RI)
            log.append(f"iteration {it}: det R = {cost:.6g}")
            rel = abs((cost - prev) / cost)
            if rel < tol:
                log.append("converged: relative change in det R < tolR")
                break
            if cost > prev:
                if khalf == 10:
                    break
                p = 0.5 * (p + p_old)
                khalf += 1
            else:
                khalf = 0
        if khalf == 10:
            p = p_old
            it -= 1
            break
        if rel < tol:
            R = Rnew
            break
        prev = cost
        f_alt = p[-nF:].copy()
        ri_alt = RI.copy()
        RInew = np.linalg.inv(Rnew)
        p = _f_compensation(p, nF, free, RInew, RI, C)
        RI = RInew
        f_updated = True
        pending = True
    cov = np.linalg.inv(F_info)
    return FemResult(
        p=p,
        cov=cov,
        se=np.sqrt(np.diag(cov)),
        R=R,
        y=y,
        K=K,
        cost=float(cost),
        iterations=it,
        history=log,
    )


def innovation_record(case: FemCase, p: np.ndarray, K: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """Outputs the fitted predictor would have measured with innovations `nu` (N, ny):
    ``z_k = h(x~_k) + nu_k``, ``x~_k+1`` the step from ``x~_k + K nu_k`` (the filter run
    backwards: a record whose innovations under (p, K) are exactly `nu`)."""
    n = nu.shape[0]
    x = case.x0.astype(float)[None]
    P = p[None]
    z = np.empty_like(nu)
    for k in range(n):
        uk = case.u[k][None]
        z[k] = case.h(x, uk, P)[0] + nu[k]
        if k + 1 < n:
            x = rk4_step(case.f, x + (K @ nu[k])[None], uk, case.u[k + 1][None], P, case.dt)
    return z


def output_error(
    case: FemCase, p0: np.ndarray, free: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """The case's output error (K = 0) by the suite's one port of FVSysID's ml_oem2
    (`_fvsysid.ml_oem`), its columns of parameters as this module's batch rows.
    Returns the free parameters' estimates, the outputs, the Cramer-Rao covariance,
    R and the iterations."""

    def rows(fn: BatchFn) -> Any:
        def columns(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
            k = p.shape[1]
            return fn(x.T, np.repeat(np.asarray(u)[None], k, 0), p.T).T

        return columns

    res = ml_oem(rows(case.f), rows(case.h), case.x0, case.u, case.z, case.dt, p0, free=free)
    return res.p[res.free], res.y, res.crb, res.R, res.iterations


# ---------------------------------------------------------------- the cases' common body


def fem_estimates(res: Any, names: Sequence[str], states: Sequence[str]) -> dict[str, float]:
    """A filter-error fit's parameters and F (sqrt of each process-noise intensity)."""
    out = {n: float(res.parameters[n]) for n in names}
    out.update({f"F_{s}": float(np.sqrt(res.process_noise[s])) for s in states})
    return out


def fem_errors(res: Any, names: Sequence[str], states: Sequence[str]) -> dict[str, float]:
    """Its standard errors, F's by the delta method from the intensity's."""
    out = {n: float(res.stderr[n]) for n in names}
    for s in states:
        se_q = float(res.extra_stderr.get(f"process_noise.{s}", np.nan))
        out[f"F_{s}"] = se_q / (2 * np.sqrt(res.process_noise[s]))
    return out


def compare(
    case_name: str,
    case: FemCase,
    names: Sequence[str],
    states: Sequence[str],
    model: Any,
    flight: Callable[[np.ndarray], Any],
    x0: Mapping[str, float],
    *,
    mc: int,
    seed: int,
    note: str = "",
    book: FemResult | None = None,
    truth: Mapping[str, float] | None = None,
) -> list[dict[str, Any]]:
    """The rows of one case: FVSysID's FEM (this port) against ours by filter error
    (default, then ``white:``), ours by output error against the same predictor's
    output error in numpy (``oem:``, ``oem white:``), and FVSysID's output error
    against its filter error (``fvsysid oem-fem:``: both methods by the book).

    Ours: ``identify(method="filter_error", estimate_process_noise=True)`` from
    the case's start, process noise started at F0^2, ``x0`` held. The Monte
    Carlo refits ours on records the port's fitted predictor makes from
    phase-randomised copies of its own innovations (`innovation_record`).
    With `truth`, ``truth <who>:`` rows put each estimate against it, |d|/sig in
    that estimator's own standard error.
    """
    import warnings

    import _sidpac as S

    import aeroid

    npar = len(names)
    book = ml_fem(case) if book is None else book
    start = dict(zip(names, case.p0[:npar], strict=True))
    opts: dict[str, Any] = {
        "method": "filter_error",
        "x0": dict(x0),
        "estimate_process_noise": True,
        "process_noise": {s: float(f * f) for s, f in zip(states, case.p0[npar:], strict=True)},
    }
    data = flight(case.z)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with S.Timer() as tm:
            res = aeroid.identify(model, data, start, **opts)
        white = aeroid.identify(model, data, start, error_bars="white", **opts)
        oem = aeroid.identify(model, data, start, x0=dict(x0))
        oem_w = aeroid.identify(model, data, start, x0=dict(x0), error_bars="white")
    po, _, cov_o, _, it_o = output_error(case, case.p0, np.arange(case.p0.size) < npar)
    se_o = np.sqrt(np.diag(cov_o))
    innov = case.z - book.y
    start_mc = dict(res.parameters)

    def refit(nu: np.ndarray) -> dict[str, float]:
        zz = innovation_record(case, book.p, book.K, nu)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = aeroid.identify(model, flight(zz), start_mc, **opts)
        return fem_estimates(r, names, states)

    mcs = S.monte_carlo(refit, np.zeros_like(innov), innov, mc, seed=seed)
    est, err = fem_estimates(res, names, states), fem_errors(res, names, states)
    west, werr = fem_estimates(white, names, states), fem_errors(white, names, states)
    bp = book.p.copy()
    bp[npar:] = np.abs(bp[npar:])  # F enters as F F': its sign is arbitrary
    text = (
        f"FVSysID ml_fem2 in numpy ({book.iterations} iterations){note}; ours FEM "
        f"{'converged' if res.success else 'NOT converged: ' + res.message} in "
        f"{res.n_iterations} iterations; oem: ours output error "
        f"({'converged' if oem.success else 'NOT converged'} in {oem.n_iterations} "
        f"iterations) against the same predictor's output error in numpy ({it_o} iterations)"
    )
    rows = []
    for i, n in enumerate([*names, *(f"F_{s}" for s in states)]):
        ref = {"sidpac": bp[i], "sidpac_se_white": book.se[i], "sidpac_se_corrected": None}
        rows.append(
            S.row(
                case_name,
                n,
                **ref,
                ours=est[n],
                ours_se=err[n],
                mc_se=mcs.get(n),
                seconds=tm.seconds,
                note=text,
            )
        )
        rows.append(
            S.row(case_name, f"white:{n}", **ref, ours=west[n], ours_se=werr[n], variant=True)
        )
    for i, n in enumerate(names):
        ref = {"sidpac": po[i], "sidpac_se_white": se_o[i], "sidpac_se_corrected": None}
        for label, r in (("oem", oem), ("oem white", oem_w)):
            rows.append(
                S.row(
                    case_name,
                    f"{label}:{n}",
                    **ref,
                    ours=r.parameters[n],
                    ours_se=r.stderr[n],
                    variant=True,
                )
            )
    for i, n in enumerate(names):
        rows.append(
            S.row(
                case_name,
                f"fvsysid oem-fem:{n}",
                sidpac=bp[i],
                sidpac_se_white=book.se[i],
                sidpac_se_corrected=None,
                ours=po[i],
                ours_se=se_o[i],
                variant=True,
            )
        )
    fits = {
        "fvsysid fem": (bp, book.se),
        "ours fem": ([est[n] for n in names], [err[n] for n in names]),
        "fvsysid oem": (po, se_o),
        "ours oem": ([oem.parameters[n] for n in names], [oem.stderr[n] for n in names]),
    }
    for who, (vals, ses) in fits.items() if truth else ():
        for i, n in enumerate(names):
            if n in truth:
                rows.append(
                    S.row(
                        case_name,
                        f"truth {who}:{n}",
                        sidpac=truth[n],
                        sidpac_se_white=None,
                        sidpac_se_corrected=None,
                        ours=vals[i],
                        ours_se=ses[i],
                        # a bar of 0: the fit found the parameter unidentifiable
                        delta_sigma=(vals[i] - truth[n]) / ses[i] if ses[i] > 0 else math.inf,
                        variant=True,
                    )
                )
    return rows
