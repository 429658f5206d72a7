"""The general (nonlinear) Kalman pass: EKF and UKF steps batched over parameters.

Split out of `aeroid.estimation.filtering` (which re-exports every name): the model
linearisation into constant matrices, the between-sample propagator, the
measurement model and the general forward pass.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from .. import _linalg
from ..models import integration as _integrate
from ._filter_problem import _Problem
from ._kalman_linear import (
    _chol,
    _dt_groups,
    _Failure,
    _fd_step,
    _Linear,
    _Pass,
    _sigma,
    _sym,
    _van_loan,
)

FloatArray = NDArray[np.float64]


def _linearise_model(
    prob: _Problem, params: Mapping[str, FloatArray], Qc: FloatArray, B: int
) -> _Linear | None:
    m = prob.model
    if not m._maybe_lti or prob.interpolation != "linear":
        # the exact discretisation holds straight-line controls only: RK4 sees the cubic
        return None
    groups = _dt_groups(prob.time)
    if groups is None:
        return None
    n, nu = m.n_states, m.n_controls
    trusted = m.linear is True
    mats, not_lti = _integrate.lti_form(
        m._dynamics_batch, prob.time, n, nu, params, trusted=trusted
    )
    if mats is None:
        if not_lti:
            # shown not to be LTI: remembered, as `simulate` does, so that a fit's later
            # passes skip a check that costs about a tenth of a fixed-gain pass
            object.__setattr__(m, "_maybe_lti", False)
        return None
    A = np.broadcast_to(mats[0], (B, n, n))
    Bm = np.broadcast_to(mats[1], (B, n, nu))
    c = np.broadcast_to(mats[2], (B, n))
    hs, idx = groups
    Maug = _integrate.hold_augmented(A, Bm, c)
    Phis, Qds = [], []
    U = prob.U
    dU = U[1:] - U[:-1]
    F = np.empty((B, prob.time.size - 1, n))
    for g, h in enumerate(hs):
        E = _linalg.expm(Maug * h)
        Gw = E[:, :n, n : n + nu]
        Gv = E[:, :n, n + nu : n + 2 * nu] / h
        gc = E[:, :n, -1]
        sel = idx == g
        F[:, sel] = (
            np.einsum("bij,kj->bki", Gw, U[:-1][sel])
            + np.einsum("bij,kj->bki", Gv, dU[sel])
            + gc[:, None, :]
        )
        Phi, Qd = _van_loan(np.ascontiguousarray(A), Qc, float(h))
        Phis.append(Phi)
        Qds.append(Qd)
    H = d = None
    if m._measurement_batch is None:
        sel_idx = [m.states.index(m.output_names[i]) for i in prob.out_idx]
        H = np.zeros((B, len(sel_idx), n))
        H[:, np.arange(len(sel_idx)), sel_idx] = 1.0
        d = np.zeros((B, prob.time.size, len(sel_idx)))
    else:
        aff, _ = _integrate.lti_form(
            m._measurement_batch, prob.time, n, nu, params, trusted=trusted
        )
        if aff is not None:
            oi = list(prob.out_idx)
            H = np.ascontiguousarray(np.broadcast_to(aff[0], (B, m.n_outputs, n))[:, oi])
            D = np.broadcast_to(aff[1], (B, m.n_outputs, nu))[:, oi]
            cc = np.broadcast_to(aff[2], (B, m.n_outputs))[:, oi]
            d = np.einsum("bij,kj->bki", D, U) + cc[:, None, :]
    return _Linear(np.stack(Phis, axis=1), np.stack(Qds, axis=1), F, idx, H, d)


class _Propagator:
    """Moves points (and linearises) between consecutive samples, batched (internal)."""

    def __init__(
        self,
        prob: _Problem,
        params: Mapping[str, FloatArray],
        Qc: FloatArray,
        B: int,
        lin: _Linear | None,
    ) -> None:
        self.prob = prob
        self.params = params
        self.Qc = Qc
        self.B = B
        self.lin = lin
        m = prob.model
        self.f = m._dynamics_batch
        self.n = m.n_states
        self.nu_ = m.n_controls
        if lin is None:
            if prob.substeps is not None:
                self.m = prob.substeps
            else:
                self.m = prob.path_substeps(params)
            self.nodes = _integrate.control_nodes(
                prob.U[None], self.m, prob.time, prob.interpolation
            )[..., 0]  # (n_t-1, 2m+1, n_u)
        self._rep: dict[int, dict[str, FloatArray]] = {}
        # the same RK4 over one interval, compiled, when the dynamics translate to JAX
        self._cp = None
        self._pmat: FloatArray | None = None
        if lin is None:  # compiled: straight or cubic controls
            from ..models import compiled as _compiled

            # a point propagation and a difference Jacobian per interval, each RK4
            work = 8 * self.m * (prob.time.size - 1)
            if _compiled.worth_compiling(m, work):
                self._cp = _compiled.interval_propagator(
                    m,
                    prob.time,
                    prob.U,
                    prob.x0,
                    {k: float(v[0]) for k, v in params.items()},
                    self.m,
                    prob.interpolation,
                )
            if self._cp is not None:
                self._pmat = _compiled._pmatrix(m, params, B)

    def _p(self, r: int) -> dict[str, FloatArray]:
        if r not in self._rep:
            self._rep[r] = {k: np.repeat(v, r) for k, v in self.params.items()}
        return self._rep[r]

    def _u(self, u: FloatArray, cols: int) -> FloatArray:
        return np.broadcast_to(u[:, None], (self.nu_, cols))

    def points(self, k: int, X: FloatArray) -> FloatArray:
        """Propagate points X (B, r, n) from sample k to k+1."""
        B, r, n = X.shape
        if self.lin is not None:
            g = self.lin.idx[k]
            return np.einsum("bij,brj->bri", self.lin.Phi[:, g], X) + self.lin.F[:, k][:, None, :]
        t = self.prob.time
        M = B * r
        t0, t1 = float(t[k]), float(t[k + 1])
        if self._cp is not None:
            assert self._pmat is not None
            pm = self._pmat if r == 1 else np.repeat(self._pmat, r, axis=0)
            x = self._cp(k, np.ascontiguousarray(X.reshape(M, n)), pm).T
        else:
            x = self._rk4(k, X)
        if not np.all(np.isfinite(x)) and np.all(np.isfinite(X)):
            m = self.prob.model
            bad = int(np.argmax(~np.all(np.isfinite(x), axis=1)))
            raise _Failure(
                k + 1,
                f"the dynamics of model {m.name!r} gave a non-finite state {m.states[bad]!r} "
                f"between sample {k} (t = {t0:.6g} s) and sample {k + 1} (t = {t1:.6g} s)",
                simulation=True,
            )
        return np.ascontiguousarray(x.T.reshape(B, r, n))

    def _rk4(self, k: int, X: FloatArray) -> FloatArray:
        """Numpy RK4 of points X (B, r, n) over interval k; columns (n, B r)."""
        B, r, n = X.shape
        t = self.prob.time
        M = B * r
        x = np.ascontiguousarray(X.reshape(M, n).T)
        p = self._p(r)
        t0, t1 = float(t[k]), float(t[k + 1])
        h = (t1 - t0) / self.m
        hh = 0.5 * h
        inside = _integrate._INSIDE * (t1 - t0)  # one-sided ends, as in _integrate.rk4
        nk = self.nodes[k]
        f = self.f
        last = self.m - 1
        with np.errstate(all="ignore"):
            for j in range(self.m):
                ta = t0 + j * h
                um = self._u(nk[2 * j + 1], M)
                k1 = f(t0 + inside if j == 0 else ta, x, self._u(nk[2 * j], M), p)
                k2 = f(ta + hh, x + hh * k1, um, p)
                k3 = f(ta + hh, x + hh * k2, um, p)
                tb = t1 - inside if j == last else ta + h
                k4 = f(tb, x + h * k3, self._u(nk[2 * j + 2], M), p)
                x = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        out: FloatArray = x
        return out

    def linear(self, k: int, x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Transition matrix and discrete process noise over interval k at the point x."""
        if self.lin is not None:
            g = self.lin.idx[k]
            return self.lin.Phi[:, g], self.lin.Qd[:, g]
        n, B = self.n, self.B
        step = _fd_step(x, P)  # (B, n)
        pts = np.concatenate(
            [
                x[:, None, :] + np.eye(n)[None] * step[:, :, None],
                x[:, None, :] - np.eye(n)[None] * step[:, :, None],
            ],
            axis=1,
        )  # (B, 2n, n)
        cols = np.ascontiguousarray(pts.reshape(B * 2 * n, n).T)
        t = float(self.prob.time[k])
        with np.errstate(all="ignore"):
            vals = self.f(t, cols, self._u(self.prob.U[k], B * 2 * n), self._p(2 * n))
        vals = np.asarray(vals, dtype=np.float64).T.reshape(B, 2 * n, n)
        A = np.swapaxes((vals[:, :n] - vals[:, n:]) / (2 * step[:, :, None]), 1, 2)
        h = float(self.prob.time[k + 1] - self.prob.time[k])
        if not np.all(np.isfinite(A)):
            raise _Failure(k, "the dynamics Jacobian is not finite")
        return _van_loan(A, self.Qc, h)


class _Measurer:
    """Predicted measurements and their linearisation, batched (internal)."""

    def __init__(
        self, prob: _Problem, params: Mapping[str, FloatArray], B: int, lin: _Linear | None
    ) -> None:
        self.prob = prob
        m = prob.model
        self.h = m._measurement_batch
        self.B = B
        self.n = m.n_states
        self.params = params
        self.oi = list(prob.out_idx)
        self.H: FloatArray | None = None
        self.d: FloatArray | None = None
        if lin is not None and lin.H is not None:
            self.H, self.d = lin.H, lin.d
        elif self.h is None:
            sel = [m.states.index(m.output_names[i]) for i in prob.out_idx]
            self.H = np.zeros((B, len(sel), self.n))
            self.H[:, np.arange(len(sel)), sel] = 1.0
            self.d = np.zeros((B, prob.time.size, len(sel)))
        self._rep: dict[int, dict[str, FloatArray]] = {}

    def points(self, k: int, X: FloatArray) -> FloatArray:
        """Outputs at points X (B, r, n) at sample k: (B, r, n_y)."""
        if self.H is not None:
            assert self.d is not None
            return np.einsum("bij,brj->bri", self.H, X) + self.d[:, k][:, None, :]
        assert self.h is not None
        B, r, n = X.shape
        if r not in self._rep:
            self._rep[r] = {kk: np.repeat(v, r) for kk, v in self.params.items()}
        cols = np.ascontiguousarray(X.reshape(B * r, n).T)
        u = np.broadcast_to(self.prob.U[k][:, None], (self.prob.U.shape[1], B * r))
        tk = float(self.prob.time[k])
        with np.errstate(all="ignore"):
            vals = np.asarray(self.h(tk, cols, u, self._rep[r]), dtype=np.float64)
        sel = vals[self.oi]
        if not np.all(np.isfinite(sel)) and np.all(np.isfinite(cols)):
            m = self.prob.model
            bad = self.oi[int(np.argmax(~np.all(np.isfinite(sel), axis=1)))]
            raise _Failure(
                k,
                f"the measurement of model {m.name!r} gave a non-finite output "
                f"{m.output_names[bad]!r} at sample {k} (t = {tk:.6g} s)",
                simulation=True,
            )
        return sel.T.reshape(B, r, len(self.oi))

    def linear(self, k: int, x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Predicted outputs (B, n_y) and the Jacobian H (B, n_y, n) at x."""
        if self.H is not None:
            assert self.d is not None
            return np.einsum("bij,bj->bi", self.H, x) + self.d[:, k], self.H
        n = self.n
        step = _fd_step(x, P)
        e = np.eye(n)[None] * step[:, :, None]
        pts = np.concatenate([x[:, None, :], x[:, None, :] + e, x[:, None, :] - e], axis=1)
        vals = self.points(k, pts)  # (B, 2n+1, n_y)
        Hm = np.swapaxes((vals[:, 1 : n + 1] - vals[:, n + 1 :]) / (2 * step[:, :, None]), 1, 2)
        if not np.all(np.isfinite(Hm)):
            raise _Failure(k, "the measurement Jacobian is not finite")
        return vals[:, 0], Hm


def _general(
    prob: _Problem,
    params: Mapping[str, FloatArray],
    Qc: FloatArray,
    R: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    lin: _Linear | None,
    method: str,
) -> _Pass:
    """EKF or UKF with per-step factorisations and jitter (any model), batched."""
    B, n = x0.shape
    n_t, n_y = prob.Y.shape
    Y = prob.Y
    prop = _Propagator(prob, params, Qc, B, lin)
    if method == "ekf" and prop._cp is not None:
        from ._ekf_compiled import ekf_pass

        arrays = ekf_pass(
            prob.model,
            prob.time,
            prob.U,
            prob.Y,
            prob.out_idx,
            params,
            Qc,
            R,
            x0,
            P0,
            prop.m,
            prob.interpolation,
        )
        if arrays is not None:
            ok_all = np.ones(B, dtype=bool)
            return _Pass(*arrays, ok_all, np.full(B, -1, dtype=np.int64), 0)
    meas = _Measurer(prob, params, B, lin)
    stats = [0]
    xf = np.full((B, n_t, n), np.nan)
    Pf = np.full((B, n_t, n, n), np.nan)
    xp = np.full((B, n_t, n), np.nan)
    Pp = np.full((B, n_t, n, n), np.nan)
    C = np.zeros((B, n_t, n, n))
    nu = np.full((B, n_t, n_y), np.nan)
    S = np.full((B, n_t, n_y, n_y), np.nan)
    alpha, beta, kappa = prob.ukf
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha**2 + beta
    eye = np.eye(n)
    x, P = x0.copy(), P0.copy()
    xf[:, 0], Pf[:, 0], xp[:, 0], Pp[:, 0] = x, P, x, P
    ok = np.ones(B, dtype=bool)
    fail = np.full(B, -1, dtype=np.int64)
    k = 0
    try:
        yh, H0 = meas.linear(0, x, P)
        nu[:, 0] = Y[0] - yh
        S[:, 0] = H0 @ P @ np.swapaxes(H0, 1, 2) + R
        H: FloatArray | None
        with np.errstate(all="ignore"):
            for k in range(1, n_t):
                if method == "ekf":
                    xpk = prop.points(k - 1, x[:, None, :])[:, 0]
                    Phi, Qd = prop.linear(k - 1, x, P)
                    Ppk = _sym(Phi @ P @ np.swapaxes(Phi, 1, 2) + Qd)
                    Ck = P @ np.swapaxes(Phi, 1, 2)
                    yh, H = meas.linear(k, xpk, Ppk)
                    PHt = Ppk @ np.swapaxes(H, 1, 2)
                    Sk = _sym(H @ PHt + R)
                else:
                    X = _sigma(x, P, lam, k - 1, stats)
                    Xn = prop.points(k - 1, X)
                    _, Qd = prop.linear(k - 1, x, P)
                    xpk = Xn[:, 0] + np.einsum("r,bri->bi", wm[1:], Xn[:, 1:] - Xn[:, :1])
                    dX = X - x[:, None, :]
                    dY = Xn - xpk[:, None, :]
                    Ppk = _sym(np.einsum("r,bri,brj->bij", wc, dY, dY) + Qd)
                    Ck = np.einsum("r,bri,brj->bij", wc, dX, dY)
                    Z = _sigma(xpk, Ppk, lam, k, stats)
                    Yz = meas.points(k, Z)
                    yh = Yz[:, 0] + np.einsum("r,bri->bi", wm[1:], Yz[:, 1:] - Yz[:, :1])
                    dZ = Z - xpk[:, None, :]
                    dYz = Yz - yh[:, None, :]
                    PHt = np.einsum("r,bri,brj->bij", wc, dZ, dYz)
                    Sk = _sym(np.einsum("r,bri,brj->bij", wc, dYz, dYz) + R)
                    H = None
                if not (np.all(np.isfinite(xpk)) and np.all(np.isfinite(Ppk))):
                    raise _Failure(k, "the predicted state or covariance is not finite")
                L = _chol(Sk, k, "the innovation covariance is not positive definite", stats)
                # S = L L' (L possibly jittered): K' = L'^-1 L^-1 (P H')'
                Lt = np.swapaxes(L, 1, 2)
                Kt = np.linalg.solve(Lt, np.linalg.solve(L, np.swapaxes(PHt, 1, 2)))
                K = np.swapaxes(Kt, 1, 2)
                v = Y[k] - yh
                x = xpk + np.einsum("bij,bj->bi", K, v)
                if H is not None:
                    IKH = eye - K @ H
                    P = IKH @ Ppk @ np.swapaxes(IKH, 1, 2) + K @ R @ np.swapaxes(K, 1, 2)
                else:
                    P = Ppk - K @ Sk @ np.swapaxes(K, 1, 2)
                P = _sym(P)
                if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                    raise _Failure(k, "the updated state or covariance is not finite")
                xp[:, k], Pp[:, k], C[:, k] = xpk, Ppk, Ck
                xf[:, k], Pf[:, k], nu[:, k], S[:, k] = x, P, v, Sk
    except _Failure as exc:
        ok[:] = False
        fail[:] = exc.k
        return _Pass(xf, Pf, xp, Pp, C, nu, S, ok, fail, stats[0], exc.what, exc.simulation)
    return _Pass(xf, Pf, xp, Pp, C, nu, S, ok, fail, stats[0])
