"""Maximum-likelihood output-error estimation (Gauss–Newton with relaxation).

The unknowns are the model parameters, optionally each manoeuvre's initial
states and per-output measurement biases. The measurement-noise covariance is
concentrated out of the likelihood (estimated from the residuals at every
iteration) unless fixed weights are given, so the cost is
``sum_k N/2 ln(mean residual_k^2)``. Each iteration costs one batched
simulation per manoeuvre: the trial point together with its central
finite-difference columns.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._identifiability import unidentifiable as _combinations
from ._identification_record import IdentificationResult
from .data import FlightData
from .errors import (
    IdentifiabilityWarning,
    IdentificationError,
    ResidualDriftWarning,
    SimulationError,
)

FloatArray = NDArray[np.float64]

# Residuals count as coloured when a lag-one correlation is significant (3/sqrt(N)),
# which makes the estimated correlation time exceed 1.
_WHITE_TAU = 1.0
# residual RMS over the record's RMS beyond which an end point is a runaway simulation
_RUNAWAY = 100.0


@dataclass
class _Manoeuvre:
    data: FlightData
    time: FloatArray
    controls: FloatArray  # (n_t, n_u)
    measured: FloatArray  # (n_t, n_y)
    x0: FloatArray  # (n_x,) current initial state
    x0_free: list[int]  # indices of estimated states
    bias: FloatArray  # (n_y,)
    bias_free: list[int]


@dataclass
class _Layout:
    """Where each unknown sits in the stacked vector theta."""

    names: list[str]  # model parameters
    n_p: int
    x0_slices: list[slice]
    bias_slices: list[slice]
    n_total: int
    # Input time delays (s) sit right after the model parameters, at n_p + i: one
    # per delayed control (its column in the controls array).
    delayed: tuple[int, ...] = ()

    @property
    def n_d(self) -> int:
        return len(self.delayed)


def delay_parameter(control: str) -> str:
    """The name under which the time delay of `control` is reported."""
    return f"tau_{control}"


def _typical_scales(
    layout: _Layout, theta: FloatArray, mans: list[_Manoeuvre], state_idx: list[int]
) -> FloatArray:
    typ = np.ones(layout.n_total)
    typ[: layout.n_p] = np.maximum(np.abs(theta[: layout.n_p]), 1e-3)
    for m, sx, sb in zip(mans, layout.x0_slices, layout.bias_slices, strict=True):
        stds = np.std(m.measured, axis=0) + 1e-12
        for j, s in zip(range(sx.start, sx.stop), m.x0_free, strict=True):
            k = state_idx[s]
            typ[j] = stds[k] if k >= 0 else 1.0
        for j, k in zip(range(sb.start, sb.stop), m.bias_free, strict=True):
            typ[j] = stds[k]
    return typ


def shifted_controls(
    time: FloatArray,
    controls: FloatArray,
    columns: Sequence[int],
    delays: Sequence[float] | FloatArray,
) -> FloatArray:
    """The controls with column ``columns[i]`` delayed by ``delays[i]`` seconds:
    ``u(t - tau)`` interpolated piecewise-linearly between the samples (the
    simulation contract) and held at the first and last samples outside them."""
    out = np.array(controls, dtype=np.float64, copy=True)
    for j, tau in zip(columns, np.asarray(delays, dtype=np.float64).tolist(), strict=True):
        if tau != 0.0:
            out[:, j] = np.interp(time - tau, time, controls[:, j])
    return out


def _simulate_members(
    model: Any,
    man: _Manoeuvre,
    params: Mapping[str, FloatArray],
    x0: FloatArray,
    out_idx: list[int],
    options: Mapping[str, Any],
    errors: list[str] | None = None,
    controls: FloatArray | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Outputs (B, n_t, n_y) and ok mask for a batch of parameter/x0 members; what a
    stepped simulator raised is appended to `errors`. `controls` (n_t, n_u) or per
    member (B, n_t, n_u) replaces the manoeuvre's measured controls."""
    u_all = man.controls if controls is None else controls
    if hasattr(model, "simulate_batch"):
        sim = model.simulate_batch(man.time, u_all, x0, params, **options)
        if errors is not None and not sim.ok[0] and sim.failure[0]:
            errors.append(sim.failure[0])
        return sim.outputs[:, :, out_idx], sim.ok
    # A stepped simulator: one run per member.
    batch = x0.shape[0]
    outs = np.full((batch, man.time.size, len(out_idx)), np.nan)
    ok = np.zeros(batch, dtype=bool)
    for b in range(batch):
        u_b = u_all[b] if u_all.ndim == 3 else u_all
        ctrl = {c: u_b[:, j] for j, c in enumerate(model.controls)}
        p = {k: float(v[b]) for k, v in params.items()}
        try:
            res = model.simulate(man.time, ctrl, None, p, **options)
        except Exception as exc:  # a failed member is a rejected point, not a crash
            if errors is not None:
                errors.append(f"{type(exc).__name__}: {exc}")
            continue
        y = np.asarray(res.outputs)[:, out_idx]
        if np.all(np.isfinite(y)):
            outs[b] = y
            ok[b] = True
    return outs, ok


class _StartFailure(SimulationError, IdentificationError):
    """The model gives non-finite values at the initial parameters: a `SimulationError`
    like every such failure, and the `IdentificationError` that identify raises for a bad start."""


class _Problem:
    def __init__(
        self,
        model: Any,
        mans: list[_Manoeuvre],
        layout: _Layout,
        out_idx: list[int],
        fixed: Mapping[str, float],
        options: Mapping[str, Any],
        gradient: str,
    ) -> None:
        self.model = model
        self.mans = mans
        self.layout = layout
        self.out_idx = out_idx
        self.fixed = dict(fixed)
        self.options = dict(options)
        self.gradient = gradient
        self.errors: list[str] = []  # what a stepped simulator raised, for messages

    def unpack(self, theta: FloatArray, i: int) -> tuple[FloatArray, FloatArray]:
        m = self.mans[i]
        x0 = m.x0.copy()
        x0[m.x0_free] = theta[self.layout.x0_slices[i]]
        b = m.bias.copy()
        b[m.bias_free] = theta[self.layout.bias_slices[i]]
        return x0, b

    def evaluate(
        self, theta: FloatArray, steps: FloatArray | None
    ) -> tuple[list[FloatArray], list[FloatArray] | None, bool]:
        """Residuals per manoeuvre at theta and, when steps are given, dv/dtheta.

        Returns (residuals [n_t, n_y], jacobians [n_t, n_y, n_total] of the
        residual, ok).
        """
        lay = self.layout
        residuals: list[FloatArray] = []
        jacobians: list[FloatArray] | None = [] if steps is not None else None
        for i, m in enumerate(self.mans):
            x0, bias = self.unpack(theta, i)
            sx = lay.x0_slices[i]
            delays = theta[lay.n_p : lay.n_p + lay.n_d]
            u_now = shifted_controls(m.time, m.controls, lay.delayed, delays)
            # simulated columns: model parameters and this manoeuvre's initial states
            cols = list(range(lay.n_p)) + list(range(sx.start, sx.stop))
            # gradient="auto": the exact sensitivities of the compiled RK4 when
            # the model compiles and integrates by RK4 (decided at the first call).
            route = getattr(self, "_compiled_route", None)
            sens = None
            p = dict(self.fixed)
            p.update({n: float(theta[j]) for j, n in enumerate(lay.names)})
            if steps is not None and self.gradient == "auto" and route in (None, True):
                from . import _compiled

                sens = _compiled.output_sensitivities(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    m.x0_free,
                    self.options,
                    probe=route is None,
                    numpy_first=route is None,
                )
                if sens is None:
                    # a first fit that compiling would not pay for runs in numpy, with
                    # the sensitivities of Newton's method over the record (`_shooting`)
                    route = "numpy" if _compiled.declined(self.model) else False
                    self._compiled_route = route
            if steps is not None and route == "numpy":
                from . import _compiled, _shooting

                sens = _shooting.output_sensitivities(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    m.x0_free,
                    _compiled.rk4_substeps(self.model, m.time, u_now, x0, p, self.options),
                    steps[cols],
                )
                if sens is None and self.model._dynamics_batch.time_broadcasts is False:
                    # dynamics that do not take an array of times: step by step from now
                    # on (a point where Newton did not settle steps once, below)
                    self._compiled_route = False
            if (
                steps is not None
                and sens is not None
                and np.all(np.isfinite(sens[0]))
                and np.all(np.isfinite(sens[1]))
            ):
                # (a diverging point falls through to the numpy path, which reports it)
                y_all, jac_all = sens
                y = y_all[:, self.out_idx]
                if route is None:
                    self._compiled_route = True
                v = m.measured - y - bias
                picked = jac_all[:, self.out_idx, :]
                if len(cols) == lay.n_total:  # one manoeuvre, no delays or biases
                    jac = np.negative(picked, out=picked)
                else:
                    jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                    jac[:, :, cols] = -picked
                if not self._delay_columns(jac, theta, steps, i, x0):
                    return [], None, False
                residuals.append(v)
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
                continue
            if steps is not None and self.gradient == "jax":
                from . import _jax

                y, jac_p = _jax.outputs_and_jacobian(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    substeps=self.options.get("substeps"),
                )
                y = np.asarray(y)[:, self.out_idx]
                jac_p = np.asarray(jac_p)[:, self.out_idx, :]
                if not np.all(np.isfinite(y)):
                    return [], None, False
                v = m.measured - y - bias
                jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                jac[:, :, : lay.n_p] = -jac_p
                if not self._delay_columns(jac, theta, steps, i, x0):
                    return [], None, False
                residuals.append(v)
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
                continue
            n_cols = len(cols) if steps is not None else 0
            batch = 1 + 2 * n_cols
            P = {n: np.full(batch, theta[j]) for j, n in enumerate(lay.names)}
            X0 = np.repeat(x0[None, :], batch, axis=0)
            if steps is not None:
                for c, j in enumerate(cols):
                    h = steps[j]
                    for sign, b in ((1.0, 1 + 2 * c), (-1.0, 2 + 2 * c)):
                        if j < lay.n_p:
                            P[lay.names[j]][b] += sign * h
                        else:
                            X0[b, m.x0_free[j - sx.start]] += sign * h
            outs, ok = _simulate_members(
                self.model, m, P, X0, self.out_idx, self.options, self.errors, u_now
            )
            if not ok[0]:
                return [], None, False
            v = m.measured - outs[0] - bias
            residuals.append(v)
            if steps is not None:
                if not np.all(ok):
                    return [], None, False
                jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                for c, j in enumerate(cols):
                    jac[:, :, j] = -(outs[1 + 2 * c] - outs[2 + 2 * c]) / (2 * steps[j])
                if not self._delay_columns(jac, theta, steps, i, x0):
                    return [], None, False
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
        return residuals, jacobians, True

    def _delay_columns(
        self, jac: FloatArray, theta: FloatArray, steps: FloatArray, i: int, x0: FloatArray
    ) -> bool:
        """Fill the time-delay columns of manoeuvre i's Jacobian by central differences
        of the delayed controls (``-du/dt dy/du``, exact within a sample interval,
        where the interpolated control is linear in the delay); False when a member
        fails."""
        lay = self.layout
        if not lay.n_d:
            return True
        m = self.mans[i]
        base = theta[lay.n_p : lay.n_p + lay.n_d]
        batch = 2 * lay.n_d
        U = np.empty((batch, *m.controls.shape))
        for c in range(lay.n_d):
            for sign, b in ((1.0, 2 * c), (-1.0, 2 * c + 1)):
                d = base.copy()
                d[c] += sign * steps[lay.n_p + c]
                U[b] = shifted_controls(m.time, m.controls, lay.delayed, d)
        P = {n: np.full(batch, theta[j]) for j, n in enumerate(lay.names)}
        X0 = np.repeat(x0[None, :], batch, axis=0)
        outs, ok = _simulate_members(self.model, m, P, X0, self.out_idx, self.options, None, U)
        if not np.all(ok):
            return False
        for c in range(lay.n_d):
            h = steps[lay.n_p + c]
            jac[:, :, lay.n_p + c] = -(outs[2 * c] - outs[2 * c + 1]) / (2 * h)
        return True

    def _bias_columns(self, jac: FloatArray, i: int) -> None:
        sb = self.layout.bias_slices[i]
        for j, k in zip(range(sb.start, sb.stop), self.mans[i].bias_free, strict=True):
            jac[:, k, j] = -1.0


def _relative_step(step: FloatArray, theta: FloatArray, typ: FloatArray) -> float:
    return float(np.max(np.abs(step) / np.maximum(np.abs(theta), typ)))


def _converged(rel_step: float, decrease: float, cost: float, tolerance: float) -> bool:
    """The convergence test: a relative parameter step or a cost decrease this small."""
    return rel_step < tolerance or decrease < tolerance * max(1.0, abs(cost)) * 1e-3


def _noise_variances(residuals: list[FloatArray], floor: FloatArray) -> FloatArray:
    stacked = np.concatenate(residuals, axis=0)
    return np.maximum(np.mean(stacked**2, axis=0), floor)


def _ml_cost(residuals: list[FloatArray], fixed_r: FloatArray | None, floor: FloatArray) -> float:
    stacked = np.concatenate(residuals, axis=0)
    n = stacked.shape[0]
    if fixed_r is None:
        r = np.maximum(np.mean(stacked**2, axis=0), floor)
        return float(0.5 * n * np.sum(np.log(r)))
    return float(0.5 * np.sum(stacked**2 / fixed_r))


def _information(jacobians: list[FloatArray], r: FloatArray) -> FloatArray:
    m = np.zeros((jacobians[0].shape[2],) * 2)
    for jac in jacobians:
        w = jac / np.sqrt(r)[None, :, None]
        flat = w.reshape(-1, w.shape[2])
        m += flat.T @ flat
    return m


def _gradient(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray
) -> FloatArray:
    g = np.zeros(jacobians[0].shape[2])
    for jac, v in zip(jacobians, residuals, strict=True):
        g += np.einsum("tkp,tk->p", jac, v / r[None, :])
    return g


# The AR(1) coefficient is kept inside the unit circle only by numerical resolution:
# a residual indistinguishable from a random walk gets enormous, not capped, error bars.
_PHI_LIMIT = 1.0 - 1e-6
# Search range of log(white variance / AR innovation variance) in the noise model.
_LOG_RATIO = (-14.0, 10.0)
# Initial Nelder–Mead simplex around a start, in (atanh phi, log ratio).
_SIMPLEX = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, 2.0]])


def _bandwidth(v: FloatArray) -> tuple[int, float]:
    """Lag window and correlation time of residuals `v` (n_t, n_y).

    The correlation time is the largest AR(1) value ``(1 + rho)/(1 - rho)`` over
    the outputs whose lag-one autocorrelation is significant (above 3/sqrt(N));
    1 when none is, which `fit_output_error` reads as white residuals. The
    window is Andrews' (1991) AR(1) plug-in bandwidth for the Bartlett kernel,
    ``1.1447 (alpha N)^(1/3)`` with ``alpha = mean 4 rho^2 / (1 - rho^2)^2`` over
    the standardised outputs.
    """
    n = v.shape[0]
    c0 = np.einsum("tk,tk->k", v, v)
    c1 = np.einsum("tk,tk->k", v[:-1], v[1:])
    live = c0 > 0
    if n < 3 or not np.any(live):
        return 0, 1.0
    rho = np.clip(c1[live] / c0[live], -_PHI_LIMIT, _PHI_LIMIT)
    significant = rho > 3.0 / np.sqrt(n)
    tau = float(np.max((1.0 + rho) / (1.0 - rho), initial=1.0, where=significant))
    alpha = float(np.mean(4.0 * rho**2 / (1.0 - rho**2) ** 2))
    lags = int(np.floor(1.1447 * (alpha * n) ** (1.0 / 3.0)))
    return min(lags, n - 1), tau


def _ar1_criterion(
    b: float,
    s_mom: FloatArray,
    d_mom: FloatArray,
    e_mom: FloatArray,
    dof: int,
    n_man: int,
    rank: int,
) -> float:
    """REML criterion of a pure AR(1) at ``phi = tanh(b)`` from moments (see `_noise_model`)."""
    p = float(np.tanh(b))
    mat = (1.0 - p) ** 2 * s_mom + p * d_mom + p * (1.0 - p) * e_mom
    try:
        chol = np.linalg.cholesky(mat)
    except np.linalg.LinAlgError:
        return float(np.inf)
    diag = np.diag(chol)
    rss = max(float(diag[-1]) ** 2, 1e-300)
    return float(dof * np.log(rss) - n_man * np.log1p(-p * p) + 2.0 * np.sum(np.log(diag[:rank])))


# Chebyshev nodes per spectral bin, and the ratio of a bin's distance from the nearer
# end of the spectrum [0, 4] at its far and near sides (see `_arw_prepare`).
_CHEB = 17
_BIN_RATIO = 2.0
_CHUNK = 1024


@dataclass
class _Spectral:
    """One manoeuvre's REML design ``Z`` in the eigenbasis of the AR(1) precision."""

    n: int
    nodes: FloatArray  # (n_nodes,) eigenvalues of the Neumann Laplacian
    table: FloatArray  # (n_nodes, n_tri + 2 q + 4 + 1) interpolated moments
    z_ends: FloatArray  # (2, q): the first and last rows of Z
    q: int
    upper: tuple[NDArray[np.intp], NDArray[np.intp]]  # np.triu_indices(q)


def _arw_prepare(z: FloatArray) -> _Spectral:
    """Moments of ``z`` (n, q) that give ``Z' (S + ratio I)^-1 Z`` for every AR(1) +
    white noise model in O(q^2) work per model, independent of n.

    The AR(1) precision (unit innovations) is ``L'L = (1 - phi)^2 I + phi D +
    phi (1 - phi) E`` with D the Neumann Laplacian (the negative second
    difference inside, first differences at the ends), which the orthonormal
    DCT-II diagonalises exactly (eigenvalues ``lam_j = 4 sin^2(pi j / 2n)``),
    and E the two end samples (rank 2, handled by Woodbury). Every quantity
    the criterion needs is then a sum over j of a rational function of lam_j
    (or its logarithm) times fixed per-j terms (``zh_j zh_j'``, ``zh_j f_j'``,
    ``f_j f_j'``, 1; zh the transformed Z, f the transformed end vectors). Those
    functions have their only singularity off [0, 4] (at lam < 0 for phi > 0,
    lam > 4 for phi < 0); on bins whose distance from the nearer end of [0, 4]
    grows by at most a factor 2 across the bin, polynomial interpolation at 17
    Chebyshev points converges to rounding (the pole is at least 3 half-widths
    from the bin's centre), so each bin's sum is that of its interpolant,
    ``sum_m w(x_m) [sum_j l_m(lam_j) a_j]`` with the bracket precomputed.
    Bins with no more samples than nodes keep their samples.
    """
    from scipy.fft import dct

    n, q = z.shape
    # transformed along rows of z', so that every per-sample product below is a
    # contiguous run of samples
    zh = dct(z.T, type=2, norm="ortho", axis=1)  # (q, n)
    unit = np.zeros((2, n))
    unit[0, 0] = 1.0
    unit[1, -1] = 1.0
    fh = dct(unit, type=2, norm="ortho", axis=1)
    lam = 4.0 * np.sin(0.5 * np.pi * np.arange(n) / n) ** 2
    iu, ju = np.triu_indices(q)
    n_tri = iu.size
    width = n_tri + 2 * q + 5
    scratch = np.empty((width, min(n, _CHUNK)))

    def rows(first: int, stop: int) -> FloatArray:
        """The per-j terms of samples first..stop-1, as (samples, terms), in `scratch`
        (the whole table would hold q^2/2 numbers per sample, and fresh memory that
        size costs page faults)."""
        m = stop - first
        a, f = zh[:, first:stop], fh[:, first:stop]
        out = scratch[:, :m]
        col = 0
        for i in range(q):  # the triangle in np.triu_indices order, row by row
            np.multiply(a[i], a[i:], out=out[col : col + q - i])
            col += q - i
        for i in range(q):
            np.multiply(a[i], f, out=out[col : col + 2])
            col += 2
        for i in range(2):
            np.multiply(f[i], f, out=out[col : col + 2])
            col += 2
        out[-1] = 1.0
        return out.T

    dist = np.minimum(lam, 4.0 - lam)
    side = lam > 2.0
    with np.errstate(divide="ignore"):
        level = np.where(dist > 0, np.floor(np.log(2.0 / dist) / np.log(_BIN_RATIO)), -1.0)
    key = np.where(dist > 0, 2.0 * level + side, -1.0)
    nodes: list[FloatArray] = []
    table: list[FloatArray] = []
    k = np.arange(_CHEB)
    cheb = np.cos((2 * k + 1) * np.pi / (2 * _CHEB))
    bary = (-1.0) ** k * np.sin((2 * k + 1) * np.pi / (2 * _CHEB))
    # lam increases with j, so every bin is a run of consecutive j
    cuts = np.flatnonzero(np.diff(key)) + 1
    for first, stop in zip([0, *cuts.tolist()], [*cuts.tolist(), n], strict=True):
        if stop - first <= _CHEB:
            nodes.append(lam[first:stop])
            table.append(rows(first, stop).copy())
            continue
        lo, hi = float(lam[first]), float(lam[stop - 1])
        x = 0.5 * (lo + hi) + 0.5 * (hi - lo) * cheb
        acc = np.zeros((_CHEB, width))
        for c0 in range(first, stop, _CHUNK):
            c1 = min(c0 + _CHUNK, stop)
            diff = lam[c0:c1, None] - x[None, :]
            exact = diff == 0.0
            diff[exact] = 1.0
            basis = bary / diff
            hit = np.any(exact, axis=1)
            basis[hit] = exact[hit].astype(np.float64)  # a sample on a node takes its value
            basis /= basis.sum(axis=1, keepdims=True)
            acc += basis.T @ rows(c0, c1)
        nodes.append(x)
        table.append(acc)
    return _Spectral(
        n=n,
        nodes=np.concatenate(nodes),
        table=np.concatenate(table, axis=0),
        z_ends=np.ascontiguousarray(z[[0, -1]]),
        q=q,
        upper=(iu, ju),
    )


def _arw_criterion(x: FloatArray, zs: list[_Spectral], dof: int, rank: int) -> tuple[float, float]:
    """REML criterion of AR(1) + white noise at ``(atanh phi, log ratio)`` and the
    generalised-least-squares residual sum (innovation-variance units); `zs`
    from `_arw_prepare`, one per manoeuvre.

    ``Z'(S + ratio I)^-1 Z = Z'(I + ratio L'L)^-1 L'L Z`` with ``S^-1 = L'L``;
    in the DCT basis of `_arw_prepare`, with ``c = (1 - phi)^2 + phi lam``,
    ``b = 1 + ratio c``, ``g = phi (1 - phi)`` and ``K = I + ratio g F'B^-1 F``
    (2 x 2), Woodbury gives ``Zh'(c/b)Zh + (Zh'F/b) K^-1 (g F'Z - ratio g
    F'(c/b)Zh)`` and ``log det(I + ratio L'L) = sum log b + log det K``.
    """
    b_max = float(np.arctanh(_PHI_LIMIT))
    phi = float(np.tanh(np.clip(x[0], -b_max, b_max)))
    ratio = float(np.exp(np.clip(x[1], *_LOG_RATIO)))
    q = zs[0].q
    iu, ju = zs[0].upper
    n_tri = iu.size
    g = phi * (1.0 - phi)
    mat = np.zeros((q, q))
    logdet = 0.0
    for sp in zs:
        weights = np.empty((3, sp.nodes.size))
        c = np.multiply(sp.nodes, phi, out=weights[0])
        c += (1.0 - phi) ** 2
        bb = np.multiply(c, ratio, out=weights[2])
        bb += 1.0
        if not bb.min() > 0:
            return float(np.inf), 0.0
        np.divide(1.0, bb, out=weights[1])
        c *= weights[1]  # c / b
        np.log(bb, out=bb)
        sums = weights @ sp.table  # (3, columns)
        tri = sums[0, :n_tri]
        s1 = np.empty((q, q))
        s1[iu, ju] = tri
        s1[ju, iu] = tri
        x_cb = sums[0, n_tri : n_tri + 2 * q].reshape(q, 2)
        x_b = sums[1, n_tri : n_tri + 2 * q].reshape(q, 2)
        f00, f01, f10, f11 = (ratio * g * sums[1, n_tri + 2 * q : n_tri + 2 * q + 4]).tolist()
        # K = I + ratio g F'B^-1 F (2 x 2), positive definite with B
        k00, k01, k10, k11 = 1.0 + f00, f01, f10, 1.0 + f11
        det_k = k00 * k11 - k01 * k10
        if not det_k > 0:
            return float(np.inf), 0.0
        rhs = g * sp.z_ends - ratio * g * x_cb.T  # (2, q)
        corr = np.empty_like(rhs)
        corr[0] = (k11 * rhs[0] - k01 * rhs[1]) / det_k
        corr[1] = (k00 * rhs[1] - k10 * rhs[0]) / det_k
        mat += s1 + x_b @ corr
        logdet += float(sums[2, -1]) + float(np.log(det_k)) - float(np.log1p(-phi * phi))
    try:
        chol = np.linalg.cholesky(0.5 * (mat + mat.T))
    except np.linalg.LinAlgError:
        return float(np.inf), 0.0
    diag_c = np.diag(chol)
    rss = max(float(diag_c[-1]) ** 2, 1e-300)
    return float(dof * np.log(rss) + logdet + 2.0 * np.sum(np.log(diag_c[:rank]))), rss


def _noise_model(
    jacobians: list[FloatArray], residuals: list[FloatArray]
) -> tuple[FloatArray, FloatArray, FloatArray, list[tuple[FloatArray, FloatArray, FloatArray]]]:
    """Per-output noise model ``e = s + w``: s an AR(1) (coefficient phi,
    innovation variance qa), w white (variance qw), fitted by restricted ML.

    For output k the residual is ``v_k = e_k - X_k d`` whatever the joint fit
    did, with ``X_k`` the output's sensitivity columns, so the error contrasts
    orthogonal to span(X_k) have a likelihood that depends on the noise alone
    (REML): the part of the noise the fit absorbed is accounted for exactly,
    where the sample autocorrelation of the residuals is biased low by
    O(tau/N) of ``1 - phi`` (Cheang & Reinsel 2000 on REML for AR errors).
    ``-2 log L_R = (N - r) log RSS + log det S + log det X'S^-1 X`` with the
    variance profiled out and RSS the generalised-least-squares residual sum.
    The white part matters: sensor noise under a slow disturbance makes a
    pure AR(1) fit trade the low-frequency shape for the high-frequency floor
    and underestimate the correlation time severalfold. A pure AR(1) fit from
    moments (``Z'L'LZ = (1 - phi)^2 S + phi D + phi (1 - phi) E`` of
    ``Z = [X, v]``, D and E the moments of the differences and of the end
    samples) starts a Nelder–Mead search over (atanh phi, log qw/qa).
    Manoeuvres share the model.

    Also returns, per output, the estimated covariance of (atanh phi, log
    qw/qa) from the curvature of the REML criterion, the two steps used, and
    the noise model (phi, qa, qw) at those steps either side of the estimate:
    what `_colored_covariance` needs to carry the noise model's own
    uncertainty into the error bars.
    """
    from scipy.optimize import minimize, minimize_scalar

    n_y = residuals[0].shape[1]
    n_tot = sum(v.shape[0] for v in residuals)
    n_man = len(residuals)
    b_max = float(np.arctanh(_PHI_LIMIT))
    phi = np.zeros(n_y)
    qa = np.zeros(n_y)
    qw = np.zeros(n_y)
    spread: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    for k in range(n_y):
        spread.append((np.zeros((2, 2)), np.ones(2), np.zeros((4, 3))))
        gram = sum(jac[:, k, :].T @ jac[:, k, :] for jac in jacobians)
        evals, evecs = np.linalg.eigh(gram)
        keep = evals > 1e-10 * max(float(evals[-1]), 0.0)
        # an orthonormal basis of span(X_k): the same REML, well conditioned
        basis = evecs[:, keep] / np.sqrt(evals[keep])
        rank = basis.shape[1]
        vv = sum(float(v[:, k] @ v[:, k]) for v in residuals)
        if vv <= 0.0 or n_tot - rank < 3 or min(v.shape[0] for v in residuals) < 3:
            qa[k] = vv / max(n_tot - rank, 1)
            continue
        size = rank + 1
        zs: list[_Spectral] = []
        s_mom = np.zeros((size, size))
        d_mom = np.zeros((size, size))
        e_mom = np.zeros((size, size))
        for jac, v in zip(jacobians, residuals, strict=True):
            z = np.empty((v.shape[0], size))
            z[:, :rank] = jac[:, k, :] @ basis
            z[:, rank] = v[:, k] / np.sqrt(vv)
            zs.append(_arw_prepare(z))
            dz = np.diff(z, axis=0)
            s_mom += z.T @ z
            d_mom += dz.T @ dz
            e_mom += np.outer(z[0], z[0]) + np.outer(z[-1], z[-1])
        moments = (s_mom, d_mom, e_mom, n_tot - rank, n_man, rank)
        grid = np.linspace(-b_max, b_max, 57)
        vals = np.array([_ar1_criterion(float(g), *moments) for g in grid])
        i = int(np.argmin(vals))
        res = minimize_scalar(
            lambda b, mom=moments: _ar1_criterion(float(b), *mom),
            bounds=(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]),
            method="bounded",
            options={"xatol": 1e-6},
        )
        b0 = float(res.x) if float(res.fun) <= vals[i] else float(grid[i])
        best_x = np.array([b0, _LOG_RATIO[0]])
        best_f = _arw_criterion(best_x, zs, n_tot - rank, rank)[0]
        # The white floor pulls a pure AR(1) fit towards zero; the search also starts
        # from the moment solution ``phi = c2/c1``, ``qw = c0 - c1/phi`` of the lags.
        c = [sum(float(v[: v.shape[0] - j, k] @ v[j:, k]) for v in residuals) for j in range(3)]
        starts = [(b0, -4.0)]
        if c[1] > 0 and 0 < c[2] < c[1]:
            phi_m = c[2] / c[1]
            white = c[0] - c[1] / phi_m
            innov = c[1] / phi_m * (1 - phi_m**2)
            if white > 0 and innov > 0:
                starts.append((float(np.arctanh(phi_m)), float(np.log(white / innov))))
        for start in starts:
            fit = minimize(
                lambda x, z_=zs, r_=rank: _arw_criterion(x, z_, n_tot - r_, r_)[0],
                np.array(start),
                method="Nelder-Mead",
                options={
                    "xatol": 5e-3,
                    "fatol": 1e-3,
                    "maxfev": 100,
                    "initial_simplex": np.add(start, _SIMPLEX),
                },
            )
            if float(fit.fun) < best_f:
                best_x, best_f = np.asarray(fit.x, dtype=np.float64), float(fit.fun)

        def model_at(
            x: FloatArray,
            z_: list[_Spectral] = zs,
            r_: int = rank,
            vv_: float = vv,
        ) -> FloatArray:
            rss = _arw_criterion(x, z_, n_tot - r_, r_)[1]
            q_a = rss * vv_ / (n_tot - r_)
            p = float(np.tanh(np.clip(x[0], -b_max, b_max)))
            return np.array([p, q_a, q_a * float(np.exp(np.clip(x[1], *_LOG_RATIO)))])

        phi[k], qa[k], qw[k] = model_at(best_x)
        # curvature of -2 log L_R by central differences: Cov(x) = 2 H^-1
        steps = np.array([0.05, 0.25])
        hess = np.zeros((2, 2))
        for i in range(2):
            for j in range(2):
                acc = 0.0
                for si, sj, sign in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
                    x = best_x.copy()
                    x[i] += si * steps[i]
                    x[j] += sj * steps[j]
                    acc += sign * _arw_criterion(x, zs, n_tot - rank, rank)[0]
                hess[i, j] = acc / (4.0 * steps[i] * steps[j])
        ev, vec = np.linalg.eigh(0.5 * (hess + hess.T))
        # a flat direction (the white part absent) carries no information and,
        # the error bars being flat along it too, no spread either
        inv = np.where(ev > 1e-8 * max(float(ev[-1]), 1e-300), 1.0 / np.where(ev > 0, ev, 1.0), 0.0)
        points = np.array(
            [
                model_at(best_x + sign * steps[i] * np.eye(2)[i])
                for i in range(2)
                for sign in (1, -1)
            ]
        )
        spread[k] = (2.0 * (vec * inv) @ vec.T, steps, points)
    return phi, qa, qw, spread


def _recolour(w: FloatArray, phi: FloatArray) -> FloatArray:
    """``G = L^-T W`` per output, so that ``W' S W = G' G`` for the AR(1) correlation S.

    Backwards ``g(t) = w(t) + phi g(t + 1)``, then ``g(0) /= sqrt(1 - phi^2)``.
    """
    g = np.empty_like(w)
    for k in range(w.shape[1]):
        g[::-1, k, :] = _ar1_recursion(w[::-1, k, :], float(phi[k]))
        g[0, k, :] /= np.sqrt((1.0 - phi[k]) * (1.0 + phi[k]))
    return g


def _ar1_recursion(r: FloatArray, phi: float) -> FloatArray:
    """``y[t] = r[t] + phi y[t - 1]`` (y[-1] = 0) down the rows of r (N, c).

    In blocks of L ~ sqrt(N) rows: each block from a zero start by one product
    with the matrix of powers ``phi^(i - j)``, then the blocks' carries in a loop
    of N / L steps (what `scipy.signal.lfilter` computes, without importing
    SciPy's signal package: over half a second of a first fit).
    """
    n, c = r.shape
    if n == 0:
        return r.copy()
    size = math.isqrt(n - 1) + 1
    nb = -(-n // size)
    padded = np.zeros((nb * size, c))
    padded[:n] = r
    blocks = padded.reshape(nb, size, c)
    lag = np.arange(size)[:, None] - np.arange(size)[None, :]
    with np.errstate(under="ignore"):
        powers = np.where(lag >= 0, float(phi) ** np.maximum(lag, 0), 0.0)
        local = np.matmul(powers, blocks)  # each block from a zero start
        rise = float(phi) ** np.arange(1, size + 1)  # phi^(i + 1): a carry's weight
    out = np.empty_like(local)
    carry = np.zeros(c)
    for b in range(nb):
        out[b] = local[b] + rise[:, None] * carry[None, :]
        carry = out[b, -1]
    return np.asarray(out.reshape(nb * size, c)[:n], dtype=np.float64)


def _cross_covariances(
    residuals: list[FloatArray], phi: FloatArray, qa: FloatArray, qw: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Cross-output covariances of the AR innovations and of the white parts.

    After whitening each output by its own phi, ``eps = a + w_t - phi w_(t-1)``
    has lag-0 covariance ``Qa + Qw (1 + phi_k phi_l)`` and lag-one covariances
    ``-phi_l Qw`` and ``-phi_k Qw``: this gives the correlations, which are
    projected onto valid (positive semidefinite) ones and scaled to the REML
    variances on the diagonal.
    """
    eps = [_ar1_filter_columns(v, phi) for v in residuals]
    n_tot = sum(e.shape[0] for e in eps)
    g0 = sum(e.T @ e for e in eps) / n_tot
    g1 = sum(e[:-1].T @ e[1:] for e in eps) / n_tot
    s = phi[:, None] + phi[None, :]
    ok_s = np.abs(s) > 1e-3
    w_emp = np.where(ok_s, -(g1 + g1.T) / np.where(ok_s, s, 1.0), 0.0)
    a_emp = g0 - w_emp * (1.0 + np.outer(phi, phi))
    out = []
    for emp, var in ((a_emp, qa), (w_emp, qw)):
        d = np.sqrt(np.clip(np.diag(emp), 0.0, None))
        both = np.outer(d > 0, d > 0)
        dd = np.where(d > 0, d, 1.0)
        corr = np.where(both, np.clip(emp / np.outer(dd, dd), -1.0, 1.0), 0.0)
        np.fill_diagonal(corr, 1.0)
        ev, vec = np.linalg.eigh(corr)
        corr = (vec * np.clip(ev, 0.0, None)) @ vec.T
        dn = np.sqrt(np.clip(np.diag(corr), 1e-300, None))
        sd = np.sqrt(var)
        out.append(corr / np.outer(dn, dn) * np.outer(sd, sd))
    return out[0], out[1]


def _ar1_filter_columns(v: FloatArray, phi: FloatArray) -> FloatArray:
    """Prais–Winsten whitening of each column of `v` by its own coefficient."""
    e = np.empty_like(v)
    e[0] = np.sqrt((1.0 - phi) * (1.0 + phi)) * v[0]
    e[1:] = (1.0 - phi) * v[1:] + phi * np.diff(v, axis=0)
    return e


def _state_biased_outputs(
    mans: list[_Manoeuvre], states: list[str], outputs: list[str]
) -> set[int]:
    """Outputs whose own state equation carries an estimated bias (``estimate_bias=
    {name: 'state'}``): `identify` adds it as a constant state ``bias.<name>`` (with
    leading underscores where that name was taken) whose initial value is estimated."""
    from ._identification_record import STATE_BIAS_PREFIX as _STATE_BIAS_PREFIX

    found: set[int] = set()
    for m in mans:
        for j in m.x0_free:
            name = states[j].lstrip("_")
            if name.startswith(_STATE_BIAS_PREFIX):
                target = name[len(_STATE_BIAS_PREFIX) :]
                if target in outputs:
                    found.add(outputs.index(target))
    return found


def _warn_unabsorbed_drift(
    phi: FloatArray,
    mans: list[_Manoeuvre],
    outputs: list[str],
    cov: FloatArray,
    cov_white: FloatArray,
    names: list[str],
    states: list[str] | None = None,
) -> None:
    """Warn when an output's residual drifts like a random walk over the record: the
    coloured error bars then widen, most on the parameter named. An output bias
    (`estimate_bias`) absorbs a constant offset; a bias on the output's state equation
    (``estimate_bias={name: 'state'}``) absorbs a ramp but not a wandering offset; a
    wandering one (turbulence, unmodelled slow dynamics) is process noise, which
    filter error models. Outputs with an output bias are not named: their drift is
    what that bias is for."""
    n_t = sum(m.time.size for m in mans)
    with np.errstate(divide="ignore"):
        tau = np.where(phi > 0, -1.0 / np.log(np.clip(phi, 1e-300, None)), 0.0)
    biased = {k for m in mans for k in m.bias_free}
    via_state = _state_biased_outputs(mans, states or [], outputs)
    drifting = [outputs[k] for k in range(phi.size) if tau[k] > n_t and k not in biased]
    if not drifting:
        return
    white = np.diag(cov_white)
    ok = np.flatnonzero(white > 0)
    if ok.size == 0:
        return
    ratio = np.diag(cov)[ok] / white[ok]
    worst = int(ok[np.argmax(ratio)])
    widening = float(np.sqrt(np.max(ratio)))
    # the drift itself is what is told (tau beyond the record); the widening it
    # causes is reported, not a gate: a sound correction need not widen much
    bare = [o for o in drifting if outputs.index(o) not in via_state]
    stated = [o for o in drifting if outputs.index(o) in via_state]
    told = []
    if bare:
        told.append(
            f"no bias is estimated on {bare} (estimate_bias={bare} absorbs a constant offset)"
        )
    if stated:
        told.append(
            f"the bias estimated on the state equation of {stated} absorbs a ramp, not this "
            "wandering offset"
        )
    warnings.warn(
        ResidualDriftWarning(
            f"identify: the residuals of {drifting} drift like a random walk over the "
            f"record; {'; '.join(told)}. The coloured error bars widen up to "
            f"{widening:.0f}x the white ones (on {names[worst]}). A wandering offset "
            "(turbulence, unmodelled slow dynamics) is process noise: method='filter_error'",
            tuple(drifting),
            widening,
        ),
        stacklevel=5,  # here, fit_output_error, identify, its BLAS wrapper, the caller
    )


def _colored_covariance(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray, m_inv: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Covariance for coloured residuals: ``M^-1 [J' R^-1 Sigma R^-1 J] M^-1``, each
    output's AR(1) coefficient and each parameter's degrees of freedom.

    Morelli's correction (Klein & Morelli ch. 6; SIDPAC's colores) puts the
    full-record sample autocorrelation of the residuals in ``Sigma``. With
    strongly coloured residuals that fails where it matters: the fit absorbs
    the noise lying in the span of the sensitivities, which for slow noise is
    much of its power at the frequencies the parameters are fitted at, so the
    residual correlation is biased low there (the plain outer-product
    sandwich is identically zero, ``J'R^-1 v = 0``, and the full-record
    correlation acts as a Bartlett window as long as the record, which in
    expectation keeps about a third of a bias's variance: fixed-b theory,
    Kiefer & Vogelsang 2005); lag windows
    (Bartlett/Parzen with Andrews' plug-in bandwidth) trade that absorption
    bias against truncation bias and cannot win both when N/tau is close to
    the number of parameters; and a degrees-of-freedom factor only rescales
    whatever bias is left, blowing up as N/tau approaches that number.

    Here ``Sigma`` is a parametric model of each output's noise, an AR(1)
    disturbance plus white sensor noise, fitted by restricted maximum
    likelihood (`_noise_model`), which accounts exactly for the dimensions
    the fit removed and needs no window; the cross-output correlations come
    from the whitened residuals (`_cross_covariances`). The sandwich is then
    exact for that model: ``J'R^-1 Sigma R^-1 J = G' Qa G + W' Qw W`` with
    ``W = R^-1 J`` and ``G = L^-T W`` (`_recolour`), O(N n_y p^2) with no loop
    over lags. Nothing is capped or floored. Spectra far from that shape (a
    narrow resonance in the residuals) are outside the model.

    The noise model is estimated from N/tau correlation times, so each
    variance is itself uncertain; the delta method through the REML
    curvature gives its variance and Satterthwaite's degrees of freedom
    ``nu = 2 V^2 / Var(V)``, returned with the covariance: the result's
    intervals take Student's t with them.
    """
    phi, qa, qw, spread = _noise_model(jacobians, residuals)
    sandwich = _Sandwich(jacobians, r, m_inv, phi)
    cov = sandwich.covariance(residuals, qa, qw)
    # The noise model is itself estimated (from some N/tau correlation times), so
    # each variance is uncertain; its delta-method variance gives Satterthwaite
    # degrees of freedom nu, with which the result's intervals take the t quantile.
    var = np.diag(cov)
    var_var = np.zeros_like(var)
    for k, (cov_x, steps, points) in enumerate(spread):
        grad = np.zeros((2, var.size))
        for i in range(2):
            diags = []
            for point in points[2 * i : 2 * i + 2]:
                model = [phi.copy(), qa.copy(), qw.copy()]
                for arr, value in zip(model, point, strict=True):
                    arr[k] = value
                diags.append(sandwich.variances(residuals, *model))
            grad[i] = (diags[0] - diags[1]) / (2.0 * steps[i])
        var_var += np.einsum("ij,ik,kj->j", grad, cov_x, grad)
    ok = (var > 0) & (var_var > 0)
    nu = np.where(ok, 2.0 * var**2 / np.where(ok, var_var, 1.0), np.inf)
    # Below one degree of freedom the t quantile grows without bound (a noise model
    # fitted to less than one correlation time, or to an output the fit leaves
    # almost noise-free); one degree of freedom is the widest interval that still
    # has a finite meaning.
    nu = np.maximum(nu, 1.0)
    return np.asarray(cov, dtype=np.float64), phi, np.asarray(nu, dtype=np.float64)


class _Sandwich:
    """``M^-1 [G' Qa G + W' Qw W] M^-1`` for noise models (phi, qa, qw) near one estimate.

    With ``V_k = W_k M^-1``, output k's weighted sensitivities carried through
    ``M^-1``, and ``H_k = L_k^-T V_k`` recoloured by its phi (`_recolour` acts on
    time alone, so it commutes with ``M^-1``), the covariance is ``sum_kl Qa_kl
    H_k'H_l + Qw_kl V_k'V_l``: formed in full once, at the estimate. The
    Satterthwaite differences of `_colored_covariance` need only its diagonal,
    ``sum_kl Qa_kl sum_t H_k * H_l + ...`` from per-pair column sums, where a
    model that moves one output's phi changes that output's row of pairs:
    O(N n_y p) work per model instead of O(N n_y p^2).
    """

    def __init__(
        self, jacobians: list[FloatArray], r: FloatArray, m_inv: FloatArray, phi: FloatArray
    ) -> None:
        self.phi = phi.copy()
        self.vs = [np.matmul(jac / r[None, :, None], m_inv) for jac in jacobians]
        self.hs = [_recolour(v, phi) for v in self.vs]
        self.dv = _pair_sums(self.vs)
        self.dh = _pair_sums(self.hs)

    def covariance(self, residuals: list[FloatArray], qa: FloatArray, qw: FloatArray) -> FloatArray:
        """The full covariance at the estimate's phi."""
        cov_a, cov_w = _cross_covariances(residuals, self.phi, qa, qw)
        n_y, n_par = self.vs[0].shape[1:]
        total = np.zeros((n_par, n_par))
        for arrays, q in ((self.hs, cov_a), (self.vs, cov_w)):
            for a in arrays:
                mixed = np.tensordot(q, a, axes=([1], [1]))  # (n_y, n_t, p): sum_l q_kl A_l
                for k in range(n_y):
                    total += a[:, k, :].T @ mixed[k]
        return np.asarray(0.5 * (total + total.T), dtype=np.float64)

    def variances(
        self, residuals: list[FloatArray], phi: FloatArray, qa: FloatArray, qw: FloatArray
    ) -> FloatArray:
        """The covariance's diagonal for a model near the estimate."""
        cov_a, cov_w = _cross_covariances(residuals, phi, qa, qw)
        moved = np.flatnonzero(phi != self.phi).tolist()
        dh = self.dh
        if moved:
            dh = dh.copy()
            rows = {k: np.zeros(dh.shape[1:]) for k in moved}
            for v, h in zip(self.vs, self.hs, strict=True):
                new = {k: _recolour(v[:, k : k + 1, :], phi[k : k + 1])[:, 0, :] for k in moved}
                for k, hk in new.items():
                    row = np.einsum("ta,tla->la", hk, h)
                    for j, hj in new.items():  # moved partners take their new columns
                        row[j] = np.einsum("ta,ta->a", hk, hj)
                    rows[k] += row
            for k, row in rows.items():
                dh[k] = row
                dh[:, k] = row
        return np.asarray(
            np.einsum("kl,kla->a", cov_a, dh) + np.einsum("kl,kla->a", cov_w, self.dv),
            dtype=np.float64,
        )


def _pair_sums(arrays: list[FloatArray]) -> FloatArray:
    """``D[k, l, :] = sum_t a[t, k, :] * a[t, l, :]`` summed over `arrays` (n_t, n_y, p)."""
    n_y, n_par = arrays[0].shape[1:]
    total = np.zeros((n_par, n_y, n_y))
    for a in arrays:
        at = np.ascontiguousarray(a.transpose(2, 0, 1))  # (p, n_t, n_y): a product per parameter
        total += np.matmul(at.transpose(0, 2, 1), at)
    return np.ascontiguousarray(total.transpose(1, 2, 0))


def held_at_bounds(
    solve: Callable[[NDArray[np.intp]], FloatArray],
    at_lower: NDArray[np.bool_],
    at_upper: NDArray[np.bool_],
) -> FloatArray:
    """A step (the change of each unknown) with the unknowns held that sit at a bound
    and would leave the box: the active set of bounded Gauss–Newton and scoring.

    ``solve(idx)`` returns the change of the free unknowns `idx`; an unknown at a
    bound whose change points outward is held (zero change) and the rest solved
    again, until none points outward.
    """
    n = at_lower.size
    free = np.ones(n, dtype=bool)
    change = np.zeros(n)
    for _ in range(n + 1):
        change = np.zeros(n)
        idx = np.flatnonzero(free)
        if idx.size:
            change[idx] = solve(idx)
        out = free & ((at_lower & (change < 0)) | (at_upper & (change > 0)))
        if not np.any(out):
            break
        free &= ~out
    return change


def _projected_step(
    a: FloatArray,
    b: FloatArray,
    dn: FloatArray,
    lam: float,
    theta: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """One bounded Gauss–Newton step: (the step taken, the trial point) with
    ``trial = theta - step`` inside the box.

    `a` and `b` are the scaled normal equations (scales `dn`); the active set
    is `held_at_bounds`'s, and what remains is projected onto the box.
    """

    def solve(idx: NDArray[np.intp]) -> FloatArray:
        sub = a if idx.size == theta.size else a[np.ix_(idx, idx)]
        try:
            sol = np.linalg.lstsq(sub + lam * np.eye(idx.size), b[idx], rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            return np.zeros(idx.size)
        return -sol / dn[idx]  # theta moves by -step

    step = -held_at_bounds(solve, theta <= lower, theta >= upper)
    trial = np.clip(theta - step, lower, upper)
    clipped = trial != theta - step
    return np.where(clipped, theta - trial, step), trial


def _refuse_runaway(
    model: Any,
    names: Sequence[str],
    theta: FloatArray,
    outputs: Sequence[str],
    residuals: list[FloatArray],
    measured: FloatArray,
) -> None:
    """Refuse an end point whose simulation runs away from the record.

    From an unstable start the output-error cost can stall where the simulated
    outputs diverge: the estimated noise variances swallow residuals of 1e20
    and the iteration "converges". Predicting a constant zero gives residuals
    no larger than the record's own RMS, so residuals a hundred times that are
    no fit of the record at all.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        res = np.concatenate(residuals, axis=0)
        rms_res = np.sqrt(np.mean(res**2, axis=0))
        rms_meas = np.sqrt(np.mean(measured**2, axis=0))
    away = [
        (o, float(a), float(b))
        for o, a, b in zip(outputs, rms_res, rms_meas, strict=True)
        if not np.isfinite(a) or (b > 0.0 and a > _RUNAWAY * b)
    ]
    if away:
        listing = ", ".join(f"{o!r} off by {a:.3g} RMS (the record's {b:.3g})" for o, a, b in away)
        params = {n: float(f"{v:.6g}") for n, v in zip(names, theta.tolist(), strict=True)}
        raise IdentificationError(
            f"the fit stalled where the simulation of {getattr(model, 'name', '')!r} diverges "
            f"from the record: {listing}, at the parameters {params}. An unstable or "
            "wrong-signed start: start nearer the truth (start='equation_error') or fit an "
            "unstable airframe with method='filter_error'"
        )


def fit_output_error(
    model: Any,
    datas: list[FlightData],
    names: list[str],
    initial: Mapping[str, float],
    *,
    outputs: list[str],
    x0: list[dict[str, float]],
    estimate_x0: list[str],
    estimate_bias: list[str],
    weights: FloatArray | None,
    error_bars: str,
    max_iterations: int,
    tolerance: float,
    simulate_options: Mapping[str, Any],
    gradient: str,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    delays: Mapping[str, float] | None = None,
) -> IdentificationResult:
    """Run the estimation; arguments are already validated by `identify`.

    `delays` (control name -> start value in s) adds one pure time delay per
    named control to the unknowns: the control is simulated as ``u(t - tau)``
    (`shifted_controls`), so every simulation path, the LTI and compiled ones
    included, stays valid, and its sensitivity is a central difference in
    tau. The delays are reported as parameters ``tau_<control>``.

    With `bounds` (name -> (lower, upper), ±inf for an open side) the
    Gauss–Newton steps are projected: a parameter at a bound whose step would
    leave the box is held there and dropped from that step's normal equations
    (the active set, as in Jategaonkar's bounded Gauss–Newton), and the rest of
    the step is clipped into the box, so every iterate is feasible. Parameters
    that end at a bound are reported in ``active_bounds``; the covariance is
    computed with them held fixed (their rows and columns zero).
    """
    all_out = list(model.outputs)
    out_idx = [all_out.index(o) for o in outputs]
    states = list(getattr(model, "states", ()))
    state_out = [outputs.index(s) if s in outputs else -1 for s in states]
    n_y = len(outputs)
    mans: list[_Manoeuvre] = []
    for d, x in zip(datas, x0, strict=True):
        x_arr = np.array([float(x.get(s, 0.0)) for s in states])
        mans.append(
            _Manoeuvre(
                data=d,
                time=d.time,
                controls=d.array(list(model.controls)),
                measured=d.array(outputs),
                x0=x_arr,
                x0_free=[states.index(s) for s in estimate_x0],
                bias=np.zeros(n_y),
                bias_free=[outputs.index(o) for o in estimate_bias],
            )
        )
    n_p = len(names)
    delay_controls = list(delays or {})
    n_d = len(delay_controls)
    controls = list(model.controls)
    delayed = tuple(controls.index(c) for c in delay_controls)
    pos = n_p + n_d
    x0_slices, bias_slices = [], []
    for m in mans:
        x0_slices.append(slice(pos, pos + len(m.x0_free)))
        pos += len(m.x0_free)
    for m in mans:
        bias_slices.append(slice(pos, pos + len(m.bias_free)))
        pos += len(m.bias_free)
    layout = _Layout(names, n_p, x0_slices, bias_slices, pos, delayed)
    theta = np.zeros(pos)
    theta[:n_p] = [initial[n] for n in names]
    theta[n_p : n_p + n_d] = [float((delays or {})[c]) for c in delay_controls]
    for i, m in enumerate(mans):
        theta[x0_slices[i]] = m.x0[m.x0_free]
    box = dict(bounds or {})
    lower = np.full(pos, -np.inf)
    upper = np.full(pos, np.inf)
    for jb, n in enumerate(names):
        lower[jb], upper[jb] = box.get(n, (-np.inf, np.inf))
    theta = np.clip(theta, lower, upper)  # identify checked the start; this is a no-op there
    fixed = {k: float(v) for k, v in model.parameters.items() if k not in names}
    problem = _Problem(model, mans, layout, out_idx, fixed, simulate_options, gradient)
    typ = _typical_scales(layout, theta, mans, state_out)
    if n_d:
        # a delay's natural scale is the sample interval
        typ[n_p : n_p + n_d] = min(float(np.min(np.diff(m.time))) for m in mans)
    all_meas = np.concatenate([m.measured for m in mans], axis=0)
    floor = 1e-14 * np.maximum(np.mean(all_meas**2, axis=0), 1e-300)
    delay_names = [delay_parameter(c) for c in delay_controls]
    names_all = list(names) + delay_names
    for i, m in enumerate(mans):
        names_all += [f"x0[{i}].{states[s]}" for s in m.x0_free]
    for i, m in enumerate(mans):
        names_all += [f"bias[{i}].{outputs[k]}" for k in m.bias_free]

    # Stepped simulators integrate to a tolerance of their own (often ~1e-9), so
    # their differences need steps near the square root of it.
    rel = 1e-6 if hasattr(model, "simulate_batch") else 1e-4

    def steps_for(th: FloatArray) -> FloatArray:
        return rel * np.maximum(np.abs(th), typ)

    residuals, first_jac, ok = problem.evaluate(theta, steps_for(theta))
    if not ok or first_jac is None:
        if problem.errors and hasattr(model, "simulate_batch"):
            raise _StartFailure(
                f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
                f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))}: "
                f"{problem.errors[0]}; check the initial guesses and the model"
            )
        raised = f" (its simulate raised {problem.errors[0]})" if problem.errors else ""
        raise IdentificationError(
            f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
            f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))}{raised}; "
            "check the initial guesses and the model"
        )
    jacobians: list[FloatArray] = first_jac
    fixed_r = None if weights is None else np.asarray(weights, dtype=np.float64)
    cost = _ml_cost(residuals, fixed_r, floor)
    if not np.isfinite(cost):
        # Squares of values near 1e155 and beyond overflow float64: no step can be judged.
        with np.errstate(over="ignore", invalid="ignore"):
            mean_sq = np.mean(np.concatenate(residuals, axis=0) ** 2, axis=0)
        overflow = [o for o, v in zip(outputs, mean_sq, strict=True) if not np.isfinite(v)]
        peak = float(np.max(np.abs(all_meas)))
        raise IdentificationError(
            f"the fit cost is not finite at the initial parameters (cost {cost}): the "
            f"squared residuals of outputs {overflow or outputs} overflow (measured values up "
            f"to {peak:.3g}); check the data's units and scale"
        )
    success = False
    message = f"iteration limit ({max_iterations}) reached before convergence"
    lam = 0.0
    bounded = bool(np.any(np.isfinite(lower)) or np.any(np.isfinite(upper)))
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        r = fixed_r if fixed_r is not None else _noise_variances(residuals, floor)
        info = _information(jacobians, r)
        grad = _gradient(jacobians, residuals, r)
        dn = np.sqrt(np.clip(np.diag(info), 1e-300, None))
        a = info / np.outer(dn, dn)
        b = grad / dn
        accepted = False
        stopped_early = False
        for _attempt in range(12):
            if bounded:
                step, trial = _projected_step(a, b, dn, lam, theta, lower, upper)
            else:
                try:
                    step = np.linalg.lstsq(a + lam * np.eye(a.shape[0]), b, rcond=1e-12)[0] / dn
                except np.linalg.LinAlgError:
                    step = np.zeros_like(theta)
                # Gauss–Newton minimises sum v'R^-1 v, so the step *adds* the solution
                # of M step = -J'R^-1 v with J the residual Jacobian (J = -dy/dtheta).
                trial = theta - step
            if (
                _attempt == 0
                and lam == 0.0
                # the decrease the quadratic model predicts: half the gradient along the step
                and _converged(
                    _relative_step(step, theta, typ), 0.5 * float(grad @ step), cost, tolerance
                )
            ):
                # The next step would already pass the convergence test: stop here
                # rather than simulate it.
                stopped_early = True
                break
            t_res, t_jac, t_ok = problem.evaluate(trial, steps_for(trial))
            if t_ok and t_jac is not None:
                t_cost = _ml_cost(t_res, fixed_r, floor)
                if t_cost <= cost + 1e-12 * abs(cost):
                    accepted = True
                    break
            lam = max(lam * 10.0, 1e-4)
        if stopped_early:
            success = True
            iteration -= 1
            message = f"converged after {iteration} iterations"
            break
        if not accepted:
            success = True
            message = "converged (no further decrease possible)"
            break
        rel_step = _relative_step(step, theta, typ)
        dcost = cost - t_cost
        assert t_jac is not None  # accepted trials always carry their Jacobian
        theta, residuals, jacobians, cost = trial, t_res, t_jac, t_cost
        lam = lam / 10.0 if lam > 1e-6 else 0.0
        if _converged(rel_step, dcost, cost, tolerance):
            success = True
            message = f"converged after {iteration} iterations"
            break
    _refuse_runaway(model, names, theta[:n_p], outputs, residuals, all_meas)
    r = fixed_r if fixed_r is not None else _noise_variances(residuals, floor)
    info = _information(jacobians, r)
    held = np.zeros(layout.n_total, dtype=bool)
    held[:n_p] = (theta[:n_p] <= lower[:n_p]) | (theta[:n_p] >= upper[:n_p])
    keep = np.flatnonzero(~held)
    if np.any(held):
        # Error bars conditional on the active bounds: the held parameters leave the
        # information matrix (and the coloured-residual sandwich) as if fixed.
        jacobians = [jac[:, :, keep] for jac in jacobians]
        info = info[np.ix_(keep, keep)]
    combos, null = _combinations(info, [names_all[j] for j in keep])
    identifiable = not combos
    try:
        m_inv: FloatArray = np.asarray(
            np.linalg.pinv(info, rcond=1e-13, hermitian=True), dtype=np.float64
        )
    except np.linalg.LinAlgError:
        m_inv = np.full_like(info, np.nan)
    cov_white: FloatArray = m_inv.copy()
    shown = error_bars
    tau = max(_bandwidth(v)[1] for v in residuals)
    if error_bars == "colored" and tau <= _WHITE_TAU:
        # Residuals indistinguishable from white: the classical bound is the right
        # one, and a lag-window estimate would only add noise to it.
        shown = "white"
    # classical degrees of freedom: observations less estimates
    n_obs = sum(int(v.size) for v in residuals)
    nu: FloatArray = np.full(keep.size, float(max(n_obs - keep.size, 1)))
    if shown == "colored":
        from ._colour import colored_covariance

        _, phi, _ = _colored_covariance(jacobians, residuals, r, m_inv)
        root = np.sqrt(r)
        cov_col, nu_kept = colored_covariance(
            [jac / root[None, :, None] for jac in jacobians],
            [v / root[None, :] for v in residuals],
            m_inv,
        )
        # the spectrum behind the bars is itself estimated: its degrees of freedom
        # travel with the result, whose intervals take the t quantile
        nu = nu_kept
        _warn_unabsorbed_drift(
            phi, mans, outputs, cov_col, cov_white, [names_all[j] for j in keep], states
        )
        cov = cov_col
        dc = np.diag(cov_col)
        bad = ~(dc > 0)
        if np.any(bad):  # degenerate estimate: fall back to the classical one
            cov[bad, :] = cov_white[bad, :]
            cov[:, bad] = cov_white[:, bad]
    else:
        cov = cov_white
    if np.any(held):  # back to every unknown: zero rows and columns for the held ones
        cov_full = np.zeros((layout.n_total, layout.n_total))
        cov_full[np.ix_(keep, keep)] = cov
        white_full = np.zeros_like(cov_full)
        white_full[np.ix_(keep, keep)] = cov_white
        null_full = np.zeros(layout.n_total, dtype=bool)
        null_full[keep] = null
        nu_full = np.full(layout.n_total, np.inf)
        nu_full[keep] = nu
        cov, cov_white, null, nu = cov_full, white_full, null_full, nu_full
    if not identifiable:
        for j in np.flatnonzero(null):
            cov[j, :] = np.nan
            cov[:, j] = np.nan
            cov[j, j] = np.inf
            cov_white[j, :] = np.nan
            cov_white[:, j] = np.nan
            cov_white[j, j] = np.inf
        text = "; ".join(" + ".join(c) for c in combos)
        warnings.warn(
            f"the data cannot separate these parameter combinations: {text}; their "
            "standard errors are reported as infinite",
            IdentifiabilityWarning,
            stacklevel=4,  # fit_output_error, identify, its BLAS wrapper, the caller
        )
    if not success:
        warnings.warn(
            f"identify: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=4,  # fit_output_error, identify, its BLAS wrapper, the caller
        )
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    se[~np.isfinite(np.diag(cov))] = np.inf
    x0_out = []
    bias_out = []
    for i, m in enumerate(mans):
        xi, bi = problem.unpack(theta, i)
        x0_out.append({s: float(xi[j]) for j, s in enumerate(states)})
        bias_out.append({outputs[k]: float(bi[k]) for k in m.bias_free})
    n_e = n_p + n_d  # model parameters, then time delays
    extra = {names_all[j]: float(se[j]) for j in range(n_e, layout.n_total)}
    return IdentificationResult(
        parameters={n: float(theta[j]) for j, n in enumerate(names_all[:n_e])},
        stderr={n: float(se[j]) for j, n in enumerate(names_all[:n_e])},
        covariance=cov[:n_e, :n_e],
        parameter_names=tuple(names_all[:n_e]),
        fixed=fixed,
        covariance_white=cov_white[:n_e, :n_e],
        error_bars=shown,
        identifiable=identifiable,
        unidentifiable=tuple(combos),
        success=success,
        message=message,
        n_iterations=iteration,
        cost=cost,
        method="output_error",
        output_names=tuple(outputs),
        noise_covariance=np.diag(r),
        initial_states=tuple(x0_out),
        biases=tuple(bias_out),
        extra_stderr=extra,
        degrees_of_freedom={n: float(nu[j]) for j, n in enumerate(names_all)},
        residuals=tuple(residuals),
        model_name=str(getattr(model, "name", "")),
        bounds={n: box[n] for n in names if n in box},
        active_bounds={
            n: ("lower" if theta[j] <= lower[j] else "upper")
            for j, n in enumerate(names)
            if held[j]
        },
        time_delays={c: float(theta[n_p + i]) for i, c in enumerate(delay_controls)},
    )
