"""Linear Kalman kernels: discretisation, the block Riccati solution, scans and RTS.

Split out of `aeroid.estimation.filtering` (which re-exports every name): the problem record,
the discretised linear system, the batched forward-pass record, the Cholesky with
jitter, the block and stepped Riccati recursions, the affine scan and the
Rauch-Tung-Striebel smoother.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .. import _linalg
from ..errors import FilterError, SimulationError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_JITTER_TRIES = 8
_MAX_DT_GROUPS = 64


def _dt_groups(time: FloatArray) -> tuple[FloatArray, IntArray] | None:
    dts = np.diff(time)
    ratio = np.round(dts / dts[0], 9)
    uniq, inverse = np.unique(ratio, return_inverse=True)
    if uniq.size > _MAX_DT_GROUPS:
        return None
    return uniq * dts[0], inverse.astype(np.int64)


def _van_loan(A: FloatArray, Qc: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """Phi = expm(A h) and Qd = int_0^h expm(A s) Qc expm(A s)' ds, batched over the first axis."""
    B, n, _ = A.shape
    M = np.zeros((B, 2 * n, 2 * n))
    M[:, :n, :n] = -A
    M[:, :n, n:] = Qc
    M[:, n:, n:] = np.transpose(A, (0, 2, 1))
    E = _linalg.expm(M * h)
    Phi = np.ascontiguousarray(np.transpose(E[:, n:, n:], (0, 2, 1)))
    Qd = Phi @ E[:, :n, n:]
    return Phi, 0.5 * (Qd + np.transpose(Qd, (0, 2, 1)))


@dataclass
class _Linear:
    """Exact discretisation of an LTI model for a batch of parameter vectors."""

    Phi: FloatArray  # (B, g, n, n) per time-step group
    Qd: FloatArray  # (B, g, n, n)
    F: FloatArray  # (B, n_t-1, n) input forcing per interval
    idx: IntArray  # (n_t-1,) group of each interval
    H: FloatArray | None  # (B, n_y, n) when the measurement is affine
    d: FloatArray | None  # (B, n_t, n_y) measurement offset


@dataclass
class _Pass:
    """Forward pass of a batch of filters (internal)."""

    xf: FloatArray  # (B, n_t, n)
    Pf: FloatArray  # (B, n_t, n, n)
    xp: FloatArray  # (B, n_t, n); row 0 = x0
    Pp: FloatArray  # (B, n_t, n, n)
    C: FloatArray  # (B, n_t, n, n): cov(x_{k-1}, x_k | k-1), row 0 unused
    nu: FloatArray  # (B, n_t, n_y)
    S: FloatArray  # (B, n_t, n_y, n_y)
    ok: NDArray[np.bool_]
    fail: IntArray  # first failing sample (-1 if ok)
    n_jitter: int
    message: str = ""
    simulation: bool = False  # the model itself gave a non-finite value (finite inputs)
    settled: int | None = None  # S[:, settled:] all equal S[:, -1] (a fixed gain's pass)


class _ModelFailure(SimulationError, FilterError):
    """The model itself gave non-finite values during filtering.

    A `SimulationError` like every such failure, and a `FilterError` as
    `filter_states` has always raised for a diverging estimate.
    """


class _Failure(Exception):
    def __init__(self, k: int, what: str, simulation: bool = False) -> None:
        super().__init__(k, what)
        self.k = k
        self.what = what
        self.simulation = simulation


def _chol(M: FloatArray, k: int, what: str, stats: list[int]) -> FloatArray:
    """Batched Cholesky factor, retrying failing members with growing diagonal jitter."""
    try:
        return np.asarray(np.linalg.cholesky(M), dtype=np.float64)
    except np.linalg.LinAlgError:
        pass
    out = np.empty_like(M)
    n = M.shape[-1]
    for b in range(M.shape[0]):
        Mb = 0.5 * (M[b] + M[b].T)
        if not np.all(np.isfinite(Mb)):
            raise _Failure(k, what)
        try:
            out[b] = np.linalg.cholesky(Mb)
            continue
        except np.linalg.LinAlgError:
            pass
        scale = max(float(np.trace(Mb)) / max(n, 1), 1e-300)
        for j in range(_JITTER_TRIES):
            try:
                out[b] = np.linalg.cholesky(Mb + np.eye(n) * scale * 1e-12 * 10.0**j)
                stats[0] += 1
                break
            except np.linalg.LinAlgError:
                continue
        else:
            raise _Failure(k, what)
    return out


def _sym(P: FloatArray) -> FloatArray:
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def _affine_scan(
    M: FloatArray, c: FloatArray, x0: FloatArray, *, quadratic: bool = False
) -> FloatArray:
    """All iterates of ``x_k = M_k x_{k-1} + c_k`` (or ``X_k = M_k X_{k-1} M_k' + c_k``).

    M (B, K, n, n), c (B, K, n) or (B, K, n, n), x0 (B, n) or (B, n, n); returns
    the K iterates. A step-by-step loop costs microseconds of Python per sample,
    more than the arithmetic; in blocks of L ~ sqrt(K) samples the loop runs
    about 2 sqrt(K) times: once over the position in a block (every block at
    once, from a zero start, with the products of the M's), once over the
    blocks (their start values), and the two combine. The same sums in another
    order: the iterates agree with the loop to rounding.
    """
    B, K, n, _ = M.shape
    if K == 0:
        return np.asarray(c.copy(), dtype=np.float64)
    L = max(1, math.ceil(math.sqrt(K)))
    nb = -(-K // L)
    pad = nb * L - K
    if pad:
        M = np.concatenate([M, np.broadcast_to(np.eye(n), (B, pad, n, n))], axis=1)
        c = np.concatenate([c, np.zeros((B, pad, *c.shape[2:]))], axis=1)
    Mb = M.reshape(B, nb, L, n, n)
    cb = c.reshape(B, nb, L, *c.shape[2:])
    T = np.empty_like(Mb)  # T[:, b, i] = M_{bL+i} ... M_{bL}: block b's transfer so far
    r = np.empty_like(cb)  # block b's iterate i from a zero start
    T[:, :, 0] = Mb[:, :, 0]
    r[:, :, 0] = cb[:, :, 0]
    for i in range(1, L):
        Mi = Mb[:, :, i]
        T[:, :, i] = Mi @ T[:, :, i - 1]
        if quadratic:
            r[:, :, i] = Mi @ r[:, :, i - 1] @ np.swapaxes(Mi, 2, 3) + cb[:, :, i]
        else:
            r[:, :, i] = (Mi @ r[:, :, i - 1, :, None])[..., 0] + cb[:, :, i]
    starts = np.empty((B, nb, *x0.shape[1:]))
    x = x0
    for b in range(nb):
        starts[:, b] = x
        Tb = T[:, b, -1]
        if quadratic:
            x = Tb @ x @ np.swapaxes(Tb, 1, 2) + r[:, b, -1]
        else:
            x = (Tb @ x[..., None])[..., 0] + r[:, b, -1]
    if quadratic:
        out = T @ starts[:, :, None] @ np.swapaxes(T, 3, 4) + r
    else:
        out = (T @ starts[:, :, None, :, None])[..., 0] + r
    return np.asarray(out.reshape(B, nb * L, *c.shape[2:])[:, :K], dtype=np.float64)


# relative accuracy (per entry, scaled by the standard deviations) the block Riccati
# solution must show in its one-step residual before it replaces the step loop
_RICCATI_TOL = 1e-12


def _riccati_blocks(
    Phi: FloatArray,
    Qd: FloatArray,
    H: FloatArray,
    R: FloatArray,
    P1: FloatArray,
    K: int,
    L: int,
) -> FloatArray:
    """Predicted covariances Pp_1..Pp_K of a time-invariant filter, (B, K, n, n).

    The Riccati map P -> Phi (P - P H' (H P H' + R)^-1 H P) Phi' + Qd is the
    Möbius transformation of the symplectic matrix Psi: with [X; Y] = Psi^j [P; I],
    the j-th iterate is X Y^-1. So instead of K dependent steps the covariance
    at the start of each block of about sqrt(K) samples is found by one
    application of Psi^L, and every sample inside the blocks by one batched
    solve. Raises LinAlgError when Phi, R or a block is singular; the caller
    checks the residual.
    """
    B, n, _ = Phi.shape
    PiT = np.swapaxes(np.linalg.inv(Phi), 1, 2)  # Phi^-T
    G = np.swapaxes(H, 1, 2) @ np.linalg.solve(R, H)  # H' R^-1 H
    psi = np.empty((B, 2 * n, 2 * n))
    psi[:, :n, :n] = Phi + Qd @ PiT @ G
    psi[:, :n, n:] = Qd @ PiT
    psi[:, n:, :n] = PiT @ G
    psi[:, n:, n:] = PiT
    L = max(1, min(K, L))
    pw = np.empty((B, L, 2 * n, 2 * n))  # pw[:, i] = Psi^(i+1)
    pw[:, 0] = psi
    for i in range(1, L):
        pw[:, i] = psi @ pw[:, i - 1]
    nb = -(-K // L)
    anchors = np.empty((B, nb, n, n))
    top = pw[:, L - 1]
    P = P1
    done = nb
    for b in range(nb):
        anchors[:, b] = P
        if b + 1 < nb:
            Z = top[:, :, :n] @ P + top[:, :, n:]
            Pn = np.swapaxes(
                np.linalg.solve(np.swapaxes(Z[:, n:], 1, 2), np.swapaxes(Z[:, :n], 1, 2)), 1, 2
            )
            Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
            sd = np.sqrt(np.abs(np.diagonal(Pn, axis1=1, axis2=2)))
            if np.all(np.abs(Pn - P) <= 1e-14 * sd[:, :, None] * sd[:, None, :]):
                # steady state: the rest of the record is this covariance
                done = b + 1
                break
            P = Pn
    # Z[:, b, i] = Psi^(i+1) [anchor_b; I]: the covariance at sample 1 + b L + i + 1
    Z = pw[:, None, :, :, :n] @ anchors[:, :done, None] + pw[:, None, :, :, n:]
    Pall = np.swapaxes(
        np.linalg.solve(np.swapaxes(Z[..., n:, :], -1, -2), np.swapaxes(Z[..., :n, :], -1, -2)),
        -1,
        -2,
    ).reshape(B, done * L, n, n)
    out = np.empty((B, K, n, n))
    out[:, 0] = P1
    m = min(K - 1, done * L)
    out[:, 1 : m + 1] = Pall[:, :m]
    out[:, m + 1 :] = Pall[:, m - 1 : m] if m else P1[:, None]
    return 0.5 * (out + np.swapaxes(out, 2, 3))


def _kf_update(
    Ppk: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Innovation covariance, gain and Joseph-form update for stacks of predictions.

    Ppk (..., n, n), H and R broadcastable against it; returns (S, K, P).
    """
    Ht = np.swapaxes(H, -1, -2)
    PHt = Ppk @ Ht
    Sk = H @ PHt + R
    K = np.swapaxes(np.linalg.solve(Sk, np.swapaxes(PHt, -1, -2)), -1, -2)
    IKH = np.eye(Ppk.shape[-1]) - K @ H
    P = IKH @ Ppk @ np.swapaxes(IKH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return Sk, K, 0.5 * (P + np.swapaxes(P, -1, -2))


def _riccati_fast(
    lin: _Linear, R: FloatArray, P0: FloatArray, n_t: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """(Pp, Pf, S, Kg) over the record by blocks, or None where that is not exact.

    Verified: the filtered covariances, stepped once, must give the next
    predicted ones to `_RICCATI_TOL`; as the Riccati map of a detectable
    filter contracts, the sequence then equals the step-by-step one to about
    that accuracy.
    """
    if lin.Phi.shape[1] != 1 or n_t < 3:
        return None
    assert lin.H is not None
    Phi, Qd, H = lin.Phi[:, 0], lin.Qd[:, 0], lin.H
    PhiT = np.swapaxes(Phi, 1, 2)
    B, n, _ = Phi.shape
    P1 = Phi @ P0 @ PhiT + Qd
    P1 = 0.5 * (P1 + np.swapaxes(P1, 1, 2))
    K = n_t - 1
    first = min(32, math.ceil(math.sqrt(K)))
    # Psi^L is ill-conditioned when the filter forgets fast: then shorter blocks
    for L in sorted({first, min(first, 8), min(first, 3)}, reverse=True):
        try:
            Pp_rest = _riccati_blocks(Phi, Qd, H, R, P1, K, L)
            if not np.all(np.isfinite(Pp_rest)):
                continue
            Pp = np.empty((B, n_t, n, n))
            Pp[:, 0] = P0
            Pp[:, 1:] = Pp_rest
            S, Kg, Pf = _kf_update(Pp, H[:, None], R[:, None])
        except np.linalg.LinAlgError:
            continue
        Pf[:, 0] = P0
        Kg[:, 0] = 0.0
        step = Phi[:, None] @ Pf[:, 1:-1] @ PhiT[:, None] + Qd[:, None]
        sd = np.sqrt(np.abs(np.diagonal(Pp[:, 2:], axis1=2, axis2=3)))
        scale = sd[..., :, None] * sd[..., None, :]
        if np.all(np.abs(step - Pp[:, 2:]) <= _RICCATI_TOL * scale):
            return Pp, Pf, S, Kg
    return None


def _riccati_start(lin: _Linear, n_t: int) -> tuple[int, int, FloatArray, FloatArray]:
    """What every Riccati recursion over a record starts from: the batch size and state
    count, H, and S over the record (unset)."""
    assert lin.H is not None
    B, _, n, _ = lin.Phi.shape
    H = lin.H
    S = np.empty((B, n_t, H.shape[1], H.shape[1]))
    return B, n, H, S


def _riccati_arrays(lin: _Linear, n_t: int) -> tuple[int, int, FloatArray, FloatArray, FloatArray]:
    """`_riccati_start`, and the gains over the record (no gain at the first sample)."""
    B, n, H, S = _riccati_start(lin, n_t)
    Kg = np.empty((B, n_t, n, H.shape[1]))
    Kg[:, 0] = 0.0
    return B, n, H, S, Kg


def _step_matrices(
    lin: _Linear, PhiT: FloatArray, k: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Phi, its transpose and Qd of the step into sample `k` (steps of several sizes)."""
    g = lin.idx[k - 1]
    return lin.Phi[:, g], PhiT[:, g], lin.Qd[:, g]


def _riccati_steps(
    lin: _Linear, R: FloatArray, P0: FloatArray, n_t: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(Pp, Pf, S, Kg) step by step, stopping once the gain has converged."""
    B, n, H, S, Kg = _riccati_arrays(lin, n_t)
    Ht = np.ascontiguousarray(H.transpose(0, 2, 1))
    PhiT = np.ascontiguousarray(np.swapaxes(lin.Phi, 2, 3))
    eye = np.eye(n)
    Pf = np.empty((B, n_t, n, n))
    Pp = np.empty((B, n_t, n, n))
    P = P0.copy()
    Pf[:, 0], Pp[:, 0] = P, P
    S[:, 0] = H @ P @ Ht + R
    single = lin.Phi.shape[1] == 1
    Phi, PT, Qd = lin.Phi[:, 0], PhiT[:, 0], lin.Qd[:, 0]
    Rt = R
    prev = P
    for k in range(1, n_t):
        if not single:
            Phi, PT, Qd = _step_matrices(lin, PhiT, k)
        Ppk = Phi @ P @ PT + Qd
        PHt = Ppk @ Ht
        Sk = H @ PHt + Rt
        K = np.swapaxes(np.linalg.solve(Sk, PHt.transpose(0, 2, 1)), 1, 2)
        IKH = eye - K @ H
        P = IKH @ Ppk @ IKH.transpose(0, 2, 1) + K @ Rt @ K.transpose(0, 2, 1)
        P = 0.5 * (P + P.transpose(0, 2, 1))
        Pp[:, k], Pf[:, k], S[:, k], Kg[:, k] = Ppk, P, Sk, K
        if single and k % 4 == 0:
            # Converged (to well below rounding of any later use): the gain
            # is constant for the rest of the record.
            if np.max(np.abs(Ppk - prev)) <= 1e-13 * float(np.max(np.abs(Ppk))):
                Pp[:, k + 1 :] = Ppk[:, None]
                Pf[:, k + 1 :] = P[:, None]
                S[:, k + 1 :] = Sk[:, None]
                Kg[:, k + 1 :] = K[:, None]
                break
            prev = Ppk
    return Pp, Pf, S, Kg


def _fd_step(x: FloatArray, P: FloatArray) -> FloatArray:
    sd = np.sqrt(np.clip(np.diagonal(P, axis1=1, axis2=2), 0.0, None))
    return np.maximum(1e-3 * sd, 1e-7 * np.maximum(np.abs(x), 1e-2))


def _sigma(x: FloatArray, P: FloatArray, lam: float, k: int, stats: list[int]) -> FloatArray:
    """Scaled sigma points (B, 2n+1, n)."""
    n = x.shape[1]
    L = _chol((n + lam) * P, k, "the state covariance is not positive definite", stats)
    Lc = np.swapaxes(L, 1, 2)  # rows = columns of L
    return np.concatenate([x[:, None, :], x[:, None, :] + Lc, x[:, None, :] - Lc], axis=1)


def _rts(run: _Pass) -> tuple[FloatArray, FloatArray]:
    """Rauch–Tung–Striebel smoother from a forward pass, vectorised over time.

    With the gains G_k = C_{k+1} Pp_{k+1}^-1 known, both backward recursions
    are affine and are solved by prefix scans.
    """
    xf, Pf, xp, Pp, C = run.xf, run.Pf, run.xp, run.Pp, run.C
    rhs = np.swapaxes(C[:, 1:], 2, 3)  # (B, n_t-1, n, n)
    try:
        G = np.swapaxes(np.linalg.solve(Pp[:, 1:], rhs), 2, 3)
    except np.linalg.LinAlgError:
        G = np.swapaxes(np.linalg.pinv(Pp[:, 1:], hermitian=True) @ rhs, 2, 3)
    # reversed time: xs_k = G_k xs_{k+1} + (xf_k - G_k xp_{k+1})
    Gr = G[:, ::-1]
    cx = xf[:, -2::-1] - (Gr @ xp[:, :0:-1, :, None])[..., 0]
    cP = Pf[:, -2::-1] - Gr @ Pp[:, :0:-1] @ np.swapaxes(Gr, 2, 3)
    xs = _affine_scan(Gr, cx, xf[:, -1])[:, ::-1]
    Ps = _affine_scan(Gr, _sym(cP), Pf[:, -1], quadratic=True)[:, ::-1]
    xs = np.concatenate([xs, xf[:, -1:]], axis=1)
    Ps = np.concatenate([Ps, Pf[:, -1:]], axis=1)
    return xs, _sym(Ps)
