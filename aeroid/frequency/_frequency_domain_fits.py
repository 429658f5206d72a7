"""The two frequency-domain methods of `aeroid.frequency.frequency_domain`: output error and
equation error (Fourier transform regression) on the record's transforms, with
their white and frequency-sandwich covariances (see that module's notes).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._colour import frequency_sandwich
from .._linalg import information_inverse
from .._threads import CALLER_STACKLEVEL
from ..errors import IdentificationError
from ..estimation.identifiability import unidentifiable
from ..estimation.least_squares import Linearisation, minimise
from ..models.state_space import StateSpace

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
# the information's pseudo-inverse cut, on its unit-diagonal form (`information_inverse`)
_RCOND = 1e-13

# -- shared statistics ---------------------------------------------------------------------


def _covariances(
    jac: FloatArray,
    res: FloatArray,
    labels: list[str],
    white_scale: float,
    omega: FloatArray,
    duration: float,
    estimated_weights: tuple[str, ComplexArray] | None = None,
) -> tuple[FloatArray, FloatArray, list[tuple[str, ...]], Any, FloatArray]:
    """White and frequency-sandwich covariances of a weighted real least squares, and
    the sandwich's degrees of freedom per unknown.

    `jac` (M, r, n) and `res` (M, r): per frequency, the real-stacked weighted
    sensitivities and residuals. The white covariance is `white_scale` times
    the inverse information (the variance of one weighted real row); the
    sandwich takes the scale from the residuals themselves, with the
    ``N/(N − n)`` factor of the unknowns they absorbed, and the scatter of a
    weighting estimated from them (`estimated_weights`: its form and the
    inverse of the whitening).
    """
    m, r, n = jac.shape
    J = jac.reshape(m * r, n)
    info = J.T @ J
    combos, null = unidentifiable(info, labels)
    inv = information_inverse(info, rcond=_RCOND)
    white = white_scale * inv
    # the one coloured-residual correction, in its per-frequency form: the few
    # frequencies near a mode carry most of the information, and the fit pulls
    # their residuals towards zero (their leverage)
    colored, nu = frequency_sandwich(
        jac,
        res,
        np.asarray(inv, dtype=np.float64),
        omega,
        duration,
        estimated_weights=estimated_weights,
        rcond=_RCOND,
    )
    for cov in (white, colored):
        for j in np.flatnonzero(null):
            cov[j, :] = np.nan
            cov[:, j] = np.nan
            cov[j, j] = np.inf
    return (
        np.asarray(white, dtype=np.float64),
        np.asarray(colored, dtype=np.float64),
        combos,
        null,
        np.asarray(nu, dtype=np.float64),
    )


def _concentrated(gn: FloatArray, v: ComplexArray, dY: ComplexArray, real: bool) -> FloatArray:
    """The Gauss-Newton matrix of ``M/2 log det S`` with ``S = (1/M) sum v v^H``
    estimated from the residuals themselves.

    `gn` is the matrix at S held fixed; the noise covariance moving with the
    parameters takes ``M/2 tr(S^-1 dS_i S^-1 dS_j)`` off it. Without that term
    each step falls short of the optimum by the share of the residual the noise
    estimate absorbs, and the iteration converges only linearly. Where the
    difference is not positive definite (far from the optimum) `gn` is kept.
    """
    m = v.shape[0]
    a = np.einsum("kai,kb->iab", -dY, v.conj()) / m  # the residual's slope is -dY
    dS = a + np.conj(np.transpose(a, (0, 2, 1)))
    S = v.T @ v.conj() / m
    if real:
        S, dS = S.real, dS.real
    try:
        P = np.linalg.solve(S[None], dS)
    except np.linalg.LinAlgError:
        return gn
    out = gn - 0.5 * m * np.einsum("iab,jba->ij", P, P).real
    out = 0.5 * (out + out.T)
    d = np.sqrt(np.clip(np.diag(gn), 1e-300, None))
    try:
        np.linalg.cholesky(out / np.outer(d, d) + 1e-10 * np.eye(d.size))
    except np.linalg.LinAlgError:
        return gn
    return np.asarray(out, dtype=np.float64)


def _stack(z: ComplexArray) -> FloatArray:
    """(M, r, ...) complex -> (M, 2r, ...) real: real parts, then imaginary parts."""
    return np.concatenate([z.real, z.imag], axis=1)


# -- the two methods -----------------------------------------------------------------------


@dataclass
class _Spectra:
    omega: FloatArray
    U: ComplexArray  # (M, n_u + 1): controls and the constant's transform F1
    end: ComplexArray  # (M,) e^{-jωT}
    Z: ComplexArray  # (M, n_z): measured outputs (output error) or states (equation error)
    span: float  # Δt T: noise power of a unit-variance white sequence's transform
    duration: float  # T, s: frequencies closer than 2π/T share their noise


@dataclass
class _Fit:
    theta: FloatArray
    labels: list[str]
    white: FloatArray
    colored: FloatArray
    combos: list[tuple[str, ...]]
    cost: float
    noise: FloatArray
    residuals: ComplexArray
    iterations: int
    success: bool
    message: str
    dof: FloatArray  # per unknown, of the frequency sandwich's variances
    white_dof: float  # of the white variances: real rows less unknowns (inf: noise known)


def _boundary(sp: _Spectra, states: list[str]) -> tuple[ComplexArray, list[str]]:
    """Forcing of the state equations per unit end state, (M, k, n_x), and its labels.

    ``x(0) − x(T) e^{−jωT}``: on the ``k/T`` grid ``e^{−jωT} = 1`` and only the
    jump ``x(0) − x(T)`` shows, one unknown per state; elsewhere both ends.
    """
    n_x = len(states)
    eye = np.broadcast_to(np.eye(n_x), (sp.omega.size, n_x, n_x)).astype(np.complex128)
    if np.max(np.abs(1.0 - sp.end)) < 1e-9:
        return eye, [f"jump[0].{s}" for s in states]
    last = -sp.end[:, None, None] * np.eye(n_x)
    labels = [f"x0[0].{s}" for s in states] + [f"xT[0].{s}" for s in states]
    return np.concatenate([eye, last], axis=1), labels


def _equation_error(
    ss: StateSpace, sp: _Spectra, p0: FloatArray, boundary: bool, states: list[str]
) -> _Fit:
    n_x, n_p = ss.n_x, p0.size
    if not ss.affine(p0):
        raise IdentificationError(
            "method='equation_error' needs state equations whose matrices A, B (and constant "
            f"c) are affine in the estimated parameters; not linear in parameters "
            f"{ss.not_affine_in(p0)}; use method='output_error'"
        )
    F0, _, dF, _ = ss.with_slopes(p0)
    Xa = np.concatenate([sp.Z, sp.U], axis=1)  # (M, n_x + n_u + 1)
    lhs = 1j * sp.omega[:, None] * sp.Z - Xa @ F0.T  # (M, n_x)
    cols = np.einsum("lia,ma->mil", dF, Xa)  # (M, n_x, n_p)
    labels = list(ss.names)
    if boundary:
        bcols, blabels = _boundary(sp, states)
        cols = np.concatenate([cols, bcols.transpose(0, 2, 1)], axis=2)
        labels += blabels
    present = np.any(np.abs(cols) > 0, axis=0)  # (n_x, n_unknown)
    absent = np.flatnonzero(~present[:, :n_p].any(axis=0))
    if absent.size:
        raise IdentificationError(
            f"parameters {[ss.names[j] for j in absent]} do not enter the state equations "
            "at these frequencies; equation error cannot estimate them (use "
            "method='output_error' for parameters of the outputs)"
        )
    m = sp.omega.size
    k_i = present.sum(axis=1)
    if np.any(2 * m <= k_i):
        raise IdentificationError(
            f"too few frequencies: {m} frequencies (2 real equations each) cannot estimate "
            f"{int(k_i.max())} unknowns of one state equation"
        )
    weight = np.ones(n_x)
    theta = np.zeros(cols.shape[2])
    for _ in range(3):  # equal weights, then each equation's residual variance (twice)
        A = _stack(cols * weight[None, :, None])
        b = _stack(lhs * weight[None, :])
        theta = np.linalg.lstsq(A.reshape(-1, A.shape[2]), b.reshape(-1), rcond=None)[0]
        v = lhs - cols @ theta
        var = np.sum(np.abs(v) ** 2, axis=0) / (2 * m - k_i)  # per real component
        # an exact fit (noise-free data) must not give infinite weights
        floor = 1e-24 * np.mean(np.abs(lhs) ** 2, axis=0) + 1e-300
        weight = 1.0 / np.sqrt(np.maximum(var, floor))
    jac = _stack(cols * weight[None, :, None])
    res = _stack(v * weight[None, :])
    # each weighted real row has unit variance (its variance already counts the unknowns)
    white, colored, combos, _, nu = _covariances(jac, res, labels, 1.0, sp.omega, sp.duration)
    theta[:n_p] += p0
    return _Fit(
        theta,
        labels,
        white,
        colored,
        combos,
        0.25 * float(np.sum(np.abs(v * weight[None, :]) ** 2)),  # ½ Σ v* S⁻¹ v, S = 2 var
        np.diag(2.0 * var / sp.span),
        v,
        1,
        True,
        "closed-form least squares",
        nu,
        float(max(res.size - theta.size, 1)),
    )


def _output_error(
    ss: StateSpace,
    sp: _Spectra,
    p0: FloatArray,
    boundary: bool,
    states: list[str],
    noise: FloatArray | None,
    max_iterations: int,
    tolerance: float,
    cross: str = "hermitian",
    delayed: Sequence[int] = (),
    tau0: FloatArray | None = None,
) -> _Fit:
    n_x, n_p = ss.n_x, p0.size
    n_d = len(delayed)
    labels = list(ss.names) + [f"delay[{j}]" for j in delayed]
    bcols: ComplexArray | None = None
    if boundary:
        bcols, blabels = _boundary(sp, states)
        labels += blabels
    n_b = len(labels) - n_p - n_d
    n_pd = n_p + n_d
    dcols = list(delayed)
    jwU = -1j * sp.omega[:, None]
    jw = 1j * sp.omega[:, None, None] * np.eye(n_x)
    bT = None if bcols is None else np.ascontiguousarray(bcols.transpose(0, 2, 1))

    def evaluate_model(theta: FloatArray, slopes: bool) -> tuple[ComplexArray, ComplexArray | None]:
        p = theta[:n_p]
        U = sp.U
        if n_d:
            # a pure input delay τ: U(ω) e^{−jωτ}
            U = U.copy()
            U[:, dcols] = U[:, dcols] * np.exp(jwU * theta[n_p:n_pd][None, :])
        if slopes:
            F, H, dF, dH = ss.with_slopes(p)
        else:
            F, H = ss.at(p)
            dF, dH = None, None
        assert H is not None
        A = F[:, :n_x]
        forcing = U @ F[:, n_x:].T  # (M, n_x)
        if bT is not None:
            forcing = forcing + bT @ theta[n_pd:]
        with np.errstate(all="ignore"):
            G = np.linalg.inv(jw - A)
        X = (G @ forcing[:, :, None])[:, :, 0]
        Xa = np.concatenate([X, U], axis=1)
        v = sp.Z - Xa @ H.T
        if not slopes:
            return v, None
        assert dF is not None and dH is not None
        n_a, n_y = Xa.shape[1], H.shape[0]
        CG = H[:, :n_x] @ G  # (M, n_y, n_x)
        # ∂Y/∂p_l = C G (∂F_l Xa) + ∂H_l Xa, as plain matrix products
        dFXa = (Xa @ dF.reshape(n_p * n_x, n_a).T).reshape(len(Xa), n_p, n_x).transpose(0, 2, 1)
        dHXa = (Xa @ dH.reshape(n_p * n_y, n_a).T).reshape(len(Xa), n_p, n_y).transpose(0, 2, 1)
        dY = CG @ dFXa + dHXa
        if n_d:
            # ∂U_j/∂τ_j = −jω U_j: through the state equations and the feedthrough
            dU = jwU * U[:, dcols]  # (M, n_d)
            bd = F[:, n_x:][:, dcols]  # (n_x, n_d)
            dd = H[:, n_x:][:, dcols]  # (n_y, n_d)
            dYd = CG @ (bd[None, :, :] * dU[:, None, :]) + dd[None, :, :] * dU[:, None, :]
            dY = np.concatenate([dY, dYd], axis=2)
        if bT is not None:
            dY = np.concatenate([dY, CG @ bT], axis=2)
        return v, np.asarray(dY, dtype=np.complex128)

    def weighting(v: ComplexArray) -> ComplexArray:
        # the full Hermitian covariance: outputs whose noise is correlated with a phase
        # shift (one sensor lagging another) have a complex cross term that the real
        # part alone throws away
        if noise is not None:
            S = (noise * sp.span).astype(np.complex128)
        else:
            S = v.T @ v.conj() / v.shape[0]
            if cross == "real":
                S = S.real.astype(np.complex128)
            elif cross == "sidpac":
                S = S.conj()  # fdoe's E[v̄ vᵀ]: the transpose of the covariance
        # C^-1/2 D^-1 with S = D C D (C the correlations), not a triangular factor: the
        # whitened outputs then follow the outputs' order and ignore their units, and so
        # do the weighting spread's draws
        d = np.sqrt(np.clip(np.diag(S).real, 0.0, None))
        lam, vec = np.linalg.eigh(0.5 * (S + S.conj().T) / np.outer(np.where(d > 0, d, 1.0), d))
        if not (np.all(d > 0) and lam[0] > 1e-15 * max(float(lam[-1]), 0.0)):
            raise IdentificationError(
                "output error: the residual covariance is singular (an output the model fits "
                "exactly, or two identical outputs); drop that output or give noise="
            )
        return np.asarray((vec / np.sqrt(lam)) @ vec.conj().T / d[None, :], dtype=np.complex128)

    def cost_of(v: ComplexArray, Li: ComplexArray) -> float:
        e = v @ Li.T
        return 0.5 * float(np.sum(e.real**2 + e.imag**2))

    ss.affine(p0)  # then the iterations evaluate no model function
    tau = np.zeros(n_d) if tau0 is None else np.asarray(tau0, dtype=np.float64)
    theta = np.concatenate([p0, tau, np.zeros(n_b)])
    v, dY = evaluate_model(theta, True)
    if not np.all(np.isfinite(v)):
        raise IdentificationError(
            "output error: the model outputs are not finite at the initial parameters (a pole "
            "on a chosen frequency?)"
        )
    Li = weighting(v)
    if boundary and noise is None:
        # the ends enter linearly: solve for them first, so the first noise estimate
        # is not swamped by the transients they leave
        assert dY is not None
        Jb = _stack(Li @ dY[:, :, n_pd:])
        rb = _stack(v @ Li.T)
        theta[n_pd:] = np.linalg.lstsq(Jb.reshape(-1, n_b), rb.reshape(-1), rcond=None)[0]
        v, dY = evaluate_model(theta, True)
        Li = weighting(v)

    held = noise is not None or cross == "sidpac"

    def linearise(v: ComplexArray, dY: ComplexArray, base: Linearisation | None) -> Linearisation:
        Li = weighting(v)
        J = _stack(Li @ dY).reshape(-1, theta.size)
        r = _stack(v @ Li.T).reshape(-1)
        if held:
            # a fixed noise, or fdoe's weighting, which is no likelihood's: each step is
            # judged with the weighting of the point it starts from, as fdoe does
            cost = cost_of(v, Li)
            judged = None if base is None else cost_of(v, base.payload[2])
        else:
            # the negative log-likelihood less constants: with the noise covariance
            # estimated it is concentrated out, leaving M/2 log det S, whose gradient and
            # Gauss-Newton matrix are those of the weighted squares at this S
            S = v.T @ v.conj() / v.shape[0]
            sign, logdet = np.linalg.slogdet(S.real if cross == "real" else S)
            cost = 0.5 * v.shape[0] * float(logdet) if sign.real > 0 else np.inf
            judged = None
        curvature = J.T @ J
        if not held and np.isfinite(cost):
            curvature = _concentrated(curvature, v, dY, cross == "real")
        # (J is the model's slope, the residual's with its sign turned)
        return Linearisation(cost, -(J.T @ r), curvature, (v, dY, Li), judged)

    def evaluate(trial: FloatArray, base: Linearisation | None) -> Linearisation | None:
        v_t, dY_t = evaluate_model(trial, True)
        if dY_t is None or not (np.all(np.isfinite(v_t)) and np.all(np.isfinite(dY_t))):
            return None
        try:
            return linearise(v_t, dY_t, base)
        except IdentificationError:  # a singular residual covariance: a rejected trial
            return None

    assert dY is not None
    first = linearise(v, dY, None)
    # an unknown near zero (an end state, a small derivative) is measured against its
    # standard error at the start (a weighted real row has variance 1/2), from the
    # weighted squares' own Gauss-Newton matrix
    J0 = _stack(first.payload[2] @ dY).reshape(-1, theta.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        typical = np.sqrt(0.5 * np.abs(np.diag(information_inverse(J0.T @ J0, rcond=1e-15))))
    typical[~(typical > 0)] = 1.0
    fit = minimise(
        evaluate,
        theta,
        first,
        tolerance=tolerance,
        max_iterations=max_iterations,
        typical=typical,
    )
    theta, it, success, message = fit.theta, fit.iterations, fit.success, fit.message
    v, dY, _ = fit.point.payload
    if not success:
        warnings.warn(
            f"identify_frequency_domain: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=CALLER_STACKLEVEL + 1,
        )
    assert dY is not None
    Li = weighting(v)
    jac = _stack(Li @ dY)
    res = _stack(v @ Li.T)
    # a weighted real row has variance ½ (circular complex noise), and an estimated S
    # is short by the unknowns the fit absorbed
    n_rows = res.size
    scale = 0.5 if noise is not None else 0.5 * n_rows / max(n_rows - theta.size, 1)
    estimated = None if noise is not None else (cross, np.asarray(np.linalg.inv(Li), complex))
    white, colored, combos, _, nu = _covariances(
        jac, res, labels, scale, sp.omega, sp.duration, estimated
    )
    S = np.linalg.inv(Li.conj().T @ Li)
    return _Fit(
        theta,
        labels,
        white,
        colored,
        combos,
        cost_of(v, Li),
        np.asarray((S / sp.span).real, dtype=np.float64),
        v,
        it,
        success,
        message,
        nu,
        # a known noise level spends no rows; an estimated one spends the unknowns'
        np.inf if noise is not None else float(max(n_rows - theta.size, 1)),
    )
