"""Filter-error identification: maximum likelihood on Kalman-filter innovations.

With process noise (turbulence, model error) the measured outputs are not a
deterministic function of the parameters, and output-error fits are biased.
The filter-error method (Jategaonkar, ch. 5) runs a Kalman filter for each
candidate parameter vector and maximises the likelihood of its innovations,

    -log L = 1/2 sum_k [ nu_k' S_k^-1 nu_k + log det S_k ] + const,

by Levenberg–Marquardt-damped Fisher scoring (the one least-squares
iteration, `aeroid.estimation.least_squares.minimise`). The innovations and their
covariances are differentiated by forward differences, as the book's
filter-error programs do: all perturbed parameter vectors go through one
batched filter pass (half the members central differences would take; the
one-sided error, a relative step of 1e-5, moves the converged estimate by
about half a step, far inside its error bar). The Fisher information
of the innovations,

    I_ij = sum_k [ dnu_i' S^-1 dnu_j + 1/2 tr(S^-1 dS_i S^-1 dS_j) ],

is the Gauss–Newton matrix of the whitened innovations extended by the
covariance term, and its inverse gives the parameter covariance (the
innovations are white by construction, so no colour correction applies).

On request the process-noise intensities (and, when no measurement noise is
given, the measurement-noise variances) are estimated together with the
parameters, log-parameterised so they stay positive. An intensity starts at what the state equations
at the starting parameters leave unexplained in the measured states, less the
measurement noise's share: at the start the filter explains the record, and
the intensities fall as the parameters take up the model's error. A rejected
step that moves a log-intensity by more than a decade is tried again with that
move held to a decade before the damping grows; where a weakly determined noise
level makes the iteration creep or zig-zag, two successive steps are
extrapolated (`aeroid.estimation.least_squares.minimise`, ``accelerate``).

Pure time delays of controls (``time_delays=``) are unknowns of the same
iteration, as in output error (Jategaonkar ch. 4, Klein & Morelli ch. 6): the
filter runs on ``u(t_k - tau)`` at the sample times, interpolated on the
data grid (`aeroid.models.integration.shifted_controls`), so a delay may be a
fraction of a sample, and the innovations' differences in tau give its row of
the information matrix and its error bar. The members of a batch that share
the delays share one pass; a delay's perturbed member runs its own.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._linalg import information_inverse
from ..errors import IdentifiabilityWarning, IdentificationError
from ..io.data import FlightData
from ..models.integration import shifted_controls
from ..models.model import Model, resolve_parameters
from ._filter_problem import (
    FILTER_OPTIONS,
    filter_options_of,
    given_states,
    noise_start,
    simulated_states,
    start_failure_cause,
    unbiased_start,
)
from ._filter_steady import gain_choice, start_states, steady_pass
from ._identification_record import IdentificationResult
from ._identification_start import process_noise_start
from ._output_error import delay_parameter
from .filtering import (
    _default_P0,
    _Problem,
    _require_model,
    build_problem,
    innovation_loglik,
    noise_matrix,
    run_filter,
)
from .identifiability import unidentifiable
from .least_squares import _COST_SHARE, Linearisation, minimise

__all__ = ["FILTER_OPTIONS", "identify_filter_error"]

FloatArray = NDArray[np.float64]

# one batch's filter inputs: parameters, Qc, R, x0 and P0, each per member
_Batch = tuple[Mapping[str, FloatArray], FloatArray, FloatArray, FloatArray, FloatArray]


@dataclass
class _Layout:
    """How the vector z of estimated quantities maps onto the filter inputs."""

    names: tuple[str, ...]  # model parameters
    q_states: tuple[int, ...]  # state indices whose log process noise is estimated
    r_outputs: tuple[int, ...]  # output indices whose log measurement variance is estimated
    # control columns whose time delay (s) is estimated: right after the parameters
    delayed: tuple[int, ...] = ()
    # the shortest sample interval: a delay's natural scale
    dt: float = 1.0

    @property
    def n_e(self) -> int:
        """Parameters and delays: the unknowns before the noise log-intensities."""
        return len(self.names) + len(self.delayed)

    @property
    def size(self) -> int:
        return self.n_e + len(self.q_states) + len(self.r_outputs)

    def labels(self, model: Model, outputs: Sequence[str]) -> list[str]:
        return (
            list(self.names)
            + [delay_parameter(model.controls[i]) for i in self.delayed]
            + [f"process_noise.{model.states[i]}" for i in self.q_states]
            + [f"measurement_noise.{outputs[j]}" for j in self.r_outputs]
        )


class _Objective:
    """Negative log-likelihood of the innovations for batches of z vectors."""

    def __init__(
        self,
        model: Model,
        probs: list[_Problem],
        base: Mapping[str, float],
        layout: _Layout,
        Qc: FloatArray,
        R: FloatArray,
        P0_given: bool,
        method: str,
        known: Sequence[NDArray[np.bool_]] = (),
    ) -> None:
        self.model = model
        self.probs = probs
        self.base = base
        self.layout = layout
        self.Qc = Qc
        self.R = R
        self.P0_given = P0_given
        # per record, the states whose start the caller gave: held, so known exactly
        self.known = list(known) or [np.zeros(model.n_states, dtype=bool) for _ in probs]
        self.method = method
        self.gain = "time_varying"

    def inputs(self, Z: FloatArray) -> tuple[dict[str, FloatArray], FloatArray, FloatArray]:
        B = Z.shape[0]
        lay = self.layout
        params = {k: np.full(B, v) for k, v in self.base.items()}
        for j, name in enumerate(lay.names):
            params[name] = Z[:, j].copy()
        Qc = np.repeat(self.Qc[None], B, axis=0)
        off = lay.n_e
        for j, i in enumerate(lay.q_states):
            Qc[:, i, i] = np.exp(Z[:, off + j])
        R = np.repeat(self.R[None], B, axis=0)
        off += len(lay.q_states)
        for j, i in enumerate(lay.r_outputs):
            R[:, i, i] = np.exp(Z[:, off + j])
        return params, Qc, R

    def _run(
        self, prob: _Problem, batch: _Batch
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], int | None]:
        """(nu, S, ok, settled) of one filter pass over `prob` for a batch (its parameters,
        Qc, R, x0 and P0 per member)."""
        with np.errstate(all="ignore"):
            if self.gain == "steady":
                run = steady_pass(prob, *batch, states=False)
            else:
                run = run_filter(prob, *batch, method=self.method)
        return run.nu, run.S, run.ok, run.settled

    def _delayed_run(
        self, prob: _Problem, batch: _Batch, delays: FloatArray
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], int | None]:
        """`_run` with each member's controls delayed by its row of `delays` (B, n_d): one
        pass per distinct row, the members sharing it batched."""
        rows, which = np.unique(delays, axis=0, return_inverse=True)
        which = np.asarray(which).reshape(-1)
        cols = self.layout.delayed
        if rows.shape[0] == 1:
            moved = shifted_controls(prob.time, prob.U, cols, rows[0], prob.interpolation)
            return self._run(replace(prob, U=moved), batch)
        B = delays.shape[0]
        n_t, n_y = prob.Y.shape
        nu = np.empty((B, n_t, n_y))
        S = np.empty((B, n_t, n_y, n_y))
        ok = np.zeros(B, dtype=bool)
        settled: int | None = 0
        params, *arrays = batch
        for g, row in enumerate(rows):
            sel = np.flatnonzero(which == g)
            shifted = replace(
                prob, U=shifted_controls(prob.time, prob.U, cols, row, prob.interpolation)
            )
            part = {k: v[sel] for k, v in params.items()}
            Qc, R, x0, P0 = (a[sel] for a in arrays)
            nu[sel], S[sel], ok[sel], s = self._run(shifted, (part, Qc, R, x0, P0))
            settled = None if s is None or settled is None else max(settled, s)
        return nu, S, ok, settled

    def __call__(
        self, Z: FloatArray
    ) -> tuple[FloatArray, FloatArray, list[tuple[FloatArray, FloatArray, int | None]]]:
        """Per member: cost (-log L), sum of nu'S^-1 nu; per record: (nu, S) for all members
        and the sample (of nu[:, 1:]) from which every member's S is its last, or None."""
        B = Z.shape[0]
        params, Qc, R = self.inputs(Z)
        lay = self.layout
        cost = np.zeros(B)
        quad_all = np.zeros(B)
        per: list[tuple[FloatArray, FloatArray, int | None]] = []
        for prob, known in zip(self.probs, self.known, strict=True):
            x0 = unbiased_start(prob, np.repeat(prob.x0[None], B, axis=0), params, known)
            if self.P0_given:
                P0 = np.repeat(prob.P0[None], B, axis=0)
            else:
                # the start is held, so the prior is its error: none where the caller gave
                # it, a measurement's where it was read from a channel (`_default_P0`). A
                # prior wider than the start's error (a unit variance on a radian of angle
                # of attack) makes the first innovations' covariance, and the likelihood's
                # curvature in every parameter that moves it, the prior's and not the
                # record's: error bars several times too narrow on parameters the prior
                # turns, too wide on biases only the transient separates, and noise
                # variances driven to their floor.
                P0 = np.stack([_default_P0(self.model, prob.output_names, R[b]) for b in range(B)])
                P0[:, known, :] = 0.0
                P0[:, :, known] = 0.0
            batch = (params, Qc, R, x0, P0)
            if lay.delayed:
                D = Z[:, len(lay.names) : lay.n_e]
                run_nu, run_S, run_ok, run_settled = self._delayed_run(prob, batch, D)
            else:
                run_nu, run_S, run_ok, run_settled = self._run(prob, batch)
            nu, S = run_nu[:, 1:], run_S[:, 1:]
            settled = None if run_settled is None else max(run_settled - 1, 0)
            ok = run_ok.copy()
            quad = np.full(B, np.inf)
            logdet = np.full(B, np.inf)
            good = np.flatnonzero(ok)
            # the whole batch at once (the arrays themselves where every member ran: a
            # record-long copy costs as much as the sums); member by member where one is
            # not positive
            whole = good.size == B
            try:
                quad[good], logdet[good] = innovation_loglik(
                    nu if whole else nu[good], S if whole else S[good], settled=settled
                )
            except np.linalg.LinAlgError:
                for b in good:
                    try:
                        qb, lb = innovation_loglik(nu[b : b + 1], S[b : b + 1], settled=settled)
                    except np.linalg.LinAlgError:
                        ok[b] = False
                        continue
                    quad[b], logdet[b] = qb[0], lb[0]
            n_obs = nu.shape[1] * nu.shape[2]
            with np.errstate(invalid="ignore"):
                cost += 0.5 * (quad + logdet + n_obs * math.log(2 * math.pi))
            quad_all += quad
            per.append((run_nu, run_S, settled))
        cost[~np.isfinite(cost)] = np.inf
        return cost, quad_all, per


def _steps(z: FloatArray, layout: _Layout) -> FloatArray:
    n_p = len(layout.names)
    n_e = layout.n_e
    h = np.full(z.size, 1e-4)  # log-parameters: absolute step
    h[:n_p] = 1e-5 * np.maximum(np.abs(z[:n_p]), 1e-2)
    # a delay moves the interpolated controls linearly within a sample interval
    h[n_p:n_e] = 1e-5 * np.maximum(np.abs(z[n_p:n_e]), layout.dt)
    return h


# samples of the information's trace term summed at a time
_TRACE_BLOCK = 64


def _rows(a: FloatArray, bad: NDArray[np.intp], new: FloatArray) -> FloatArray:
    """`a` with its members ``1 + bad`` replaced by `new`'s rows (a copy)."""
    out = np.array(a)
    out[1 + bad] = new
    return out


def _derivatives(
    obj: _Objective, z: FloatArray, layout: _Layout
) -> tuple[float, FloatArray, FloatArray, FloatArray, list[tuple[FloatArray, FloatArray]]]:
    """Cost, gradient and Fisher information at z from one batched pass (forward
    differences; backward for an unknown whose forward member fails)."""
    n = z.size
    h = _steps(z, layout)
    Z = np.repeat(z[None], 1 + n, axis=0)
    Z[1:] += np.diag(h)
    cost, quad, per = obj(Z)
    bad = np.flatnonzero(~np.isfinite(cost[1:]))
    if bad.size and np.isfinite(cost[0]):
        # a perturbed member failed (a bound of the model's validity): step the other way
        h[bad] = -h[bad]
        back = np.repeat(z[None], bad.size, axis=0)
        back[np.arange(bad.size), bad] += h[bad]
        cost_b, quad_b, per_b = obj(back)
        cost[1 + bad], quad[1 + bad] = cost_b, quad_b
        per = [
            (
                _rows(nu, bad, nu_b),
                _rows(S, bad, S_b),
                None if s is None or s_b is None else max(s, s_b),
            )
            for (nu, S, s), (nu_b, S_b, s_b) in zip(per, per_b, strict=True)
        ]
    # The gradient by the chain rule from the innovations' and their covariances'
    # differences: sum over k of dnu' S^-1 nu + tr(dS M) / 2, M = S^-1 - w w', w = S^-1 nu.
    # The differences' error is O(h) in a derivative, which moves the point where the
    # gradient vanishes by O(h) of a standard error; the cost's own forward differences
    # would move it by h / 2 in the parameter, many standard errors on precise data.
    grad = np.zeros(n)
    fisher = np.zeros((n, n))
    for nu, S, settled in per:
        nu, S = nu[:, 1:], S[:, 1:]
        K = S.shape[1]
        # from `settled` on every member's S is its last (a fixed gain): those samples
        # share one inverse and one dS, and their trace terms are one term times their count
        k0 = K if settled is None or K - settled < 8 else settled
        dnu = (nu[1:] - nu[0]) / h[:, None, None]  # (n, K, m)
        Sinv = np.linalg.inv(S[0, :k0])  # (k0, m, m)
        w = np.einsum("kab,kb->ka", Sinv, nu[0, :k0])  # S_k^-1 nu_k
        M = Sinv - w[:, :, None] * w[:, None, :]
        # sample-major: the products by S^-1 one batched product, the sums over samples
        # and outputs one matrix product
        dT = np.ascontiguousarray(np.swapaxes(dnu[:, :k0], 0, 1))  # (k0, n, m)
        WT = dT @ np.swapaxes(Sinv, 1, 2)  # row i of sample k: S_k^-1 dnu_ik
        fisher += np.tensordot(dT, WT, axes=([0, 2], [0, 2]))
        grad += np.tensordot(dT, w, axes=([0, 2], [0, 1]))
        # the trace term, sum over k, a, b of SdS[i, k, a, b] SdS[j, k, b, a] with
        # SdS = S^-1 dS, a block of samples at a time (the blocks stay in the cache where
        # the record's would not); the differences' steps divide the sum once
        trace = np.zeros((n, n))
        g_trace = np.zeros(n)
        for a in range(0, k0, _TRACE_BLOCK):
            b = min(a + _TRACE_BLOCK, k0)
            dS = np.subtract(S[1:, a:b], S[0, a:b])  # (n, b - a, m, m)
            g_trace += dS.reshape(n, -1) @ M[a:b].reshape(-1)
            SdS = Sinv[None, a:b] @ dS
            SdS_T = np.ascontiguousarray(np.swapaxes(SdS, 2, 3))
            trace += SdS.reshape(n, -1) @ SdS_T.reshape(n, -1).T
        fisher += 0.5 * (trace / np.outer(h, h))
        grad += 0.5 * g_trace / h
        if k0 < K:
            Sinv1 = np.linalg.inv(S[0, -1])
            w1 = nu[0, k0:] @ Sinv1.T  # (K - k0, m)
            W1 = dnu[:, k0:] @ Sinv1.T
            fisher += np.tensordot(dnu[:, k0:], W1, axes=([1, 2], [1, 2]))
            grad += np.tensordot(dnu[:, k0:], w1, axes=([1, 2], [0, 1]))
            dS1 = (S[1:, -1] - S[0, -1]) / h[:, None, None]
            M1 = (K - k0) * Sinv1 - w1.T @ w1
            grad += 0.5 * np.einsum("iab,ab->i", dS1, M1)
            SdS1 = Sinv1[None] @ dS1
            fisher += 0.5 * (K - k0) * np.einsum("iab,jba->ij", SdS1, SdS1)
    with np.errstate(invalid="ignore"):
        # a member whose filter failed both ways: the cost's own difference
        fallback = (cost[1:] - cost[0]) / h
    grad = np.where(np.isfinite(grad), grad, fallback)
    if not np.all(np.isfinite(fisher)):
        fisher = np.nan_to_num(fisher, nan=0.0, posinf=0.0, neginf=0.0)
    fisher = 0.5 * (fisher + fisher.T)
    return float(cost[0]), grad, fisher, quad, [(nu[0], S[0]) for nu, S, _ in per]


def _flat_noises_held(point: Linearisation, n_p: int, tolerance: float) -> Linearisation:
    """`point` with the noise log-intensities the cost no longer feels taken out of the
    step (zero gradient, uncoupled from the other unknowns, unit curvature: a zero step to
    rounding); the payload gains the whole information for the error bars.

    An intensity's information ``F_ii`` is the cost's curvature in its logarithm, so an
    e-fold's change moves the cost by about ``F_ii / 2``. Where that is below the stopping
    rule's cost decrease (``1e-3 tolerance |cost|``), the intensity is spent: one that has
    fallen far below the others (no turbulence in that state) leaves the likelihood flat,
    and its gradient and curvature are the finite differences' rounding, whose ratio sends
    the Gauss-Newton step dozens of e-folds either way and the damping through a string of
    rejected steps before it is small. Held for that step, it stays where the iteration
    left it; a later point where it matters again frees it.
    """
    F = point.curvature
    floor = 2.0 * _COST_SHARE * tolerance * max(1.0, abs(point.cost))
    flat = n_p + np.flatnonzero(np.diag(F)[n_p:] < floor)
    payload = (*point.payload, F)
    if not flat.size:
        return Linearisation(point.cost, point.gradient, F, payload, point.judged)
    g = point.gradient.copy()
    g[flat] = 0.0
    held = F.copy()
    held[flat, :] = 0.0
    held[:, flat] = 0.0
    # a zero curvature would scale the solve's rounding by 1e150 into the step
    held[flat, flat] = 1.0
    return Linearisation(point.cost, g, held, payload, point.judged)


def identify_filter_error(
    model: Any,
    datas: Sequence[FlightData],
    names: Sequence[str],
    initial: Mapping[str, float] | None,
    *,
    outputs: Sequence[str] | None = None,
    process_noise: Any = None,
    measurement_noise: Any = None,
    filter_options: Mapping[str, Any] | None = None,
    estimate_process_noise: bool | Sequence[str] = False,
    x0: Sequence[Mapping[str, float] | None] | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    time_delays: Mapping[str, float] | None = None,
) -> IdentificationResult:
    """Maximum-likelihood parameter estimation on Kalman-filter innovations.

    Called by ``identify(method="filter_error")``; see the module docstring
    for the method.

    Parameters
    ----------
    model : Model
        Needs a continuous dynamics callable; stepped simulators are rejected.
    datas : sequence of FlightData
        One record per manoeuvre; the parameters are shared.
    names : sequence of str
        Parameters to estimate.
    initial : mapping of str to float, optional
        Starting values (merged onto the model's nominal values; the
        parameters not in `names` stay fixed at the merged values).
    outputs : sequence of str, optional
        Outputs the filter uses (default: all model outputs).
    process_noise : mapping or array_like, optional
        Continuous power spectral density per state (state² per second);
        zero where not given. With `estimate_process_noise` it is the
        starting value; an estimated state's intensity not given starts at
        what the state equations at the starting values leave unexplained in
        its measured channel, the measurement noise's share removed
        (`aeroid.estimation._identification_start.process_noise_start`), or,
        for a state not measured, at a hundredth of its simulated variance
        per sample interval.
    measurement_noise : mapping or array_like, optional
        Measurement-noise variances per output. When omitted they are
        estimated from the innovations (maximum likelihood).
    filter_options : mapping, optional
        ``method`` ("ekf" or "ukf"), ``ukf_alpha``, ``ukf_beta``,
        ``ukf_kappa``, ``P0``, ``substeps``, ``control_interpolation`` (as in
        `filter_states`), and ``gain``: "steady" (default with "ekf": the nonlinear model predicts,
        the gain is the Kalman gain of the model linearised at the record's
        start, Jategaonkar's filter error for nonlinear systems; see
        `aeroid.estimation._filter_steady`) or "time_varying" (an EKF or UKF relinearised
        at every sample; the default with "ukf").
    estimate_process_noise : bool or sequence of str
        Estimate the process-noise intensities of all states (True) or of the
        named states, together with the parameters.
    x0 : sequence of mapping or None, optional
        Initial state per manoeuvre (default: the first measured values),
        held. Without ``filter_options["P0"]`` the filter's initial covariance
        is that start's error: none for a state given here, the channel's
        noise for one read from a channel of its name, else unit variance.
    max_iterations : int
    tolerance : float
        The stopping rule of aeroid's one least-squares iteration
        (`aeroid.estimation.least_squares.minimise`): a step below `tolerance` relative
        to each unknown's size (a noise log-intensity's taken as at least 1),
        or a cost decrease below ``1e-3 tolerance max(|cost|, 1)``.
    bounds : mapping of str to (float, float), optional
        Lower and upper bounds (±inf for an open side) on estimated
        parameters. Steps are projected: a quantity at a bound whose step
        would leave the box is held there and the step re-solved without it.
        Parameters that end at a bound are listed in ``active_bounds``, with
        standard error 0 and the others' covariance conditional on the bound.
    time_delays : mapping of str to float, optional
        Control name -> start value (s) of its pure time delay, estimated with
        the parameters: the filter takes ``u(t_k - tau)`` at the sample times,
        joined between them (see `aeroid.identify`). Reported as parameter ``"tau_<control>"`` and in
        ``result.time_delays``.

    Returns
    -------
    IdentificationResult
        ``method="filter_error"``, ``sigma2`` the mean normalised innovation
        variance, ``process_noise`` the intensities used or estimated.
    """
    m = _require_model(model, IdentificationError, "filter-error identification")
    if isinstance(datas, FlightData):
        datas = [datas]
    datas = list(datas)
    if not datas:
        raise IdentificationError("data: at least one flight record is needed")
    names = tuple([names] if isinstance(names, str) else names)
    if not names:
        raise IdentificationError("parameters: name at least one parameter to estimate")
    bad = [n for n in names if n not in m.parameters]
    if bad:
        raise IdentificationError(
            f"parameters {bad} are not parameters of model {m.name!r}; its parameters are "
            f"{list(m.parameters)}"
        )
    if len(set(names)) != len(names):
        raise IdentificationError(f"parameters: duplicate names in {list(names)}")
    opts = filter_options_of(filter_options)
    if x0 is None:
        x0_list: list[Any] = [None] * len(datas)
    else:
        x0_list = list(x0)
        if len(x0_list) != len(datas):
            raise IdentificationError(
                f"x0: expected one initial state per manoeuvre ({len(datas)}), got {len(x0_list)}"
            )
    if int(max_iterations) != max_iterations or max_iterations < 1:
        raise IdentificationError(
            f"max_iterations: expected a positive integer, got {max_iterations!r}"
        )
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise IdentificationError(f"tolerance: expected a positive number, got {tolerance!r}")
    start = resolve_parameters(m, initial, error=IdentificationError)

    estimate_R = measurement_noise is None
    probs: list[_Problem] = []
    R: FloatArray | None = None
    for i, data in enumerate(datas):
        prob, Ri = build_problem(
            m,
            data,
            outputs=outputs,
            measurement_noise=measurement_noise,
            x0=x0_list[i],
            P0=opts["P0"],
            substeps=opts["substeps"],
            method=opts["method"],
            ukf=(float(opts["ukf_alpha"]), float(opts["ukf_beta"]), float(opts["ukf_kappa"])),
            error=IdentificationError,
            require_R=not estimate_R,
            control_interpolation=opts["control_interpolation"],
        )
        probs.append(prob)
        R = Ri
    assert R is not None
    out_names = probs[0].output_names
    n_y = len(out_names)
    Qc = noise_matrix(
        process_noise,
        m.states,
        "process_noise",
        IdentificationError,
        require_all=False,
        positive=False,
    )
    if estimate_process_noise is True:
        q_states = tuple(range(m.n_states))
    elif estimate_process_noise is False or estimate_process_noise is None:
        q_states = ()
    else:
        sel = (
            [estimate_process_noise]
            if isinstance(estimate_process_noise, str)
            else list(estimate_process_noise)
        )
        unknown = [s for s in sel if s not in m.states]
        if unknown:
            raise IdentificationError(
                f"estimate_process_noise: {unknown} are not states; states: {list(m.states)}"
            )
        q_states = tuple(m.states.index(s) for s in sel)
    if q_states:
        off = np.abs(Qc - np.diag(np.diag(Qc)))
        if np.any(off[list(q_states)] > 0) or np.any(off[:, list(q_states)] > 0):
            raise IdentificationError(
                "estimate_process_noise: the estimated states' process noise must be uncorrelated "
                "(diagonal) with the others"
            )
    r_outputs = tuple(range(n_y)) if estimate_R else ()
    delay_starts = dict(time_delays or {})
    unknown_controls = [c for c in delay_starts if c not in m.controls]
    if unknown_controls:
        raise IdentificationError(
            f"time_delays: {unknown_controls} are not controls of model {m.name!r}; its "
            f"controls are {list(m.controls)}"
        )
    dt_min = min(float(np.min(np.diff(p.time))) if p.time.size > 1 else 1.0 for p in probs)
    layout = _Layout(
        names, q_states, r_outputs, tuple(m.controls.index(c) for c in delay_starts), dt_min
    )

    # starting values of the log-parameters
    r_start = np.mean([noise_start(p, None if estimate_R else R) for p in probs], axis=0)
    R0 = np.diag(r_start) if estimate_R else R
    z0 = [start[n] for n in names] + [float(v) for v in delay_starts.values()]
    if q_states:
        # what the state equations at the start leave unexplained in the measured states
        noise = {o: float(R0[j, j]) for j, o in enumerate(out_names)}
        wanted = [i for i in q_states if not Qc[i, i] > 0]
        found = process_noise_start(m, datas, start, noise, wanted) if wanted else {}
        compiled = None
        if gain_choice(opts["gain"], opts["method"], filter_options) == "steady":
            # the compiled rollout, where the fit's passes compile its predictor: the
            # model's later simulations (its validation) take the same program
            compiled = start_states(probs[0], start, Qc)
        svar = None
        if any(i not in found for i in wanted):
            sim = simulated_states(m, datas[0], x0_list[0], start, opts, compiled)
            svar = np.var(sim, axis=0)
        dt = float(np.median(np.diff(probs[0].time)))
        for i in q_states:
            if Qc[i, i] > 0:
                z0.append(math.log(Qc[i, i]))
            elif i in found:
                z0.append(math.log(found[i]))
            else:
                assert svar is not None
                s = m.states[i]
                var = (
                    R0[out_names.index(s), out_names.index(s)]
                    if m._measurement_batch is None and s in out_names
                    else max(float(svar[i]), 1e-12)
                )
                z0.append(math.log(1e-2 * var / dt))
    z0.extend(math.log(r_start[j]) for j in r_outputs)
    z = np.array(z0, dtype=np.float64)
    n_p = len(names)
    n_e = layout.n_e
    known = [given_states(m, x) for x in x0_list]
    obj = _Objective(m, probs, start, layout, Qc, R0, opts["P0"] is not None, opts["method"], known)
    obj.gain = gain_choice(opts["gain"], opts["method"], filter_options)
    # Noise intensities may shrink towards zero (no turbulence in the data):
    # bound them 30 e-folds below and above their starting values.
    lo = np.full(z.size, -np.inf)
    hi = np.full(z.size, np.inf)
    lo[n_e:] = z[n_e:] - 30.0
    hi[n_e:] = z[n_e:] + 30.0
    box = {} if bounds is None else {str(k): (float(a), float(b)) for k, (a, b) in bounds.items()}
    for name, (a, b) in box.items():
        if name not in names:
            raise IdentificationError(
                f"bounds: {name!r} is not among the estimated parameters {list(names)}"
            )
        j = names.index(name)
        if not (a < b and a <= z[j] <= b):
            raise IdentificationError(
                f"bounds[{name!r}]: need lower < upper and the initial value {z[j]:.6g} "
                f"inside, got ({a:.6g}, {b:.6g})"
            )
        lo[j], hi[j] = a, b

    f, g, fisher, quad, per = _derivatives(obj, z, layout)
    if not np.isfinite(f):
        raise IdentificationError(
            "filter-error identification: the filter fails at the initial parameters "
            f"{ {n: start[n] for n in names} }{start_failure_cause(m, datas, start)}; "
            "check the initial values and noise levels"
        )

    def evaluate(zt: FloatArray, _base: Linearisation | None) -> Linearisation | None:
        ft, gt, ft_info, qt, pt = _derivatives(obj, zt, layout)
        if not np.isfinite(ft):
            return None
        return _flat_noises_held(Linearisation(ft, gt, ft_info, (qt, pt)), n_e, tolerance)

    # the noise intensities are logarithms: their steps count in absolute terms
    typical = np.ones_like(z)
    typical[:n_p] = 1e-8
    typical[n_p:n_e] = layout.dt
    # A log-intensity's information goes with the square of its share of the innovations'
    # variance, which a decade can move a hundredfold: a rejected step that moves one
    # by more (a vanishing noise's Gauss-Newton step asks for several) is tried again
    # with it held to a decade before the damping, which shortens every step, grows
    cap = np.full(z.size, np.inf)
    cap[n_e:] = math.log(10.0)
    # a weakly determined noise level's Fisher information can be off by a factor from
    # the likelihood's curvature: the iteration creeps or zig-zags along it and a
    # parameter it correlates with (extrapolated: `minimise`'s ``accelerate``)
    fit = minimise(
        evaluate,
        z,
        _flat_noises_held(Linearisation(f, g, fisher, (quad, per)), n_e, tolerance),
        tolerance=tolerance,
        max_iterations=int(max_iterations),
        typical=typical,
        lower=lo,
        upper=hi,
        damping=1e-3,
        max_step=cap,
        accelerate=True,
    )
    z, f = fit.theta, fit.point.cost
    quad, per, fisher = fit.point.payload
    success, message, it = fit.success, fit.message, fit.iterations
    if not success:
        warnings.warn(
            f"filter-error identification: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=4,  # identify_filter_error, identify, its BLAS wrapper, the caller
        )

    labels = layout.labels(m, out_names)
    # Noise intensities at a bound, or that the data cannot determine, are
    # held fixed for the covariance: they are nuisance parameters.
    free = np.ones(z.size, dtype=bool)
    free[n_e:] = (z[n_e:] > lo[n_e:] + 1e-6) & (z[n_e:] < hi[n_e:] - 1e-6)
    # Parameters at a bound are held there: error bars conditional on the bound.
    held = np.zeros(z.size, dtype=bool)
    held[:n_p] = (z[:n_p] <= lo[:n_p]) | (z[:n_p] >= hi[:n_p])
    free &= ~held
    while True:
        idx = np.flatnonzero(free)
        combos, _ = unidentifiable(fisher[np.ix_(idx, idx)], [labels[i] for i in idx])
        noise_only = [c for c in combos if all(lab not in labels[:n_e] for lab in c)]
        if not noise_only:
            break
        for c in noise_only:
            for lab in c:
                free[labels.index(lab)] = False
    identifiable = not combos
    sub = fisher[np.ix_(idx, idx)]
    if combos:
        warnings.warn(
            "filter-error identification: the data cannot separate "
            + "; ".join(" + ".join(c) for c in combos),
            IdentifiabilityWarning,
            stacklevel=4,  # identify_filter_error, identify, its BLAS wrapper, the caller
        )
    cov_sub = information_inverse(sub, rcond=1e-15) if combos else np.linalg.inv(sub)
    cov_full = np.full((z.size, z.size), np.nan)
    cov_full[np.ix_(idx, idx)] = 0.5 * (cov_sub + cov_sub.T)
    cov_full[held, :] = 0.0
    cov_full[:, held] = 0.0
    cov = cov_full[:n_e, :n_e]
    se = np.sqrt(np.clip(np.diag(cov_full), 0.0, None))
    params_hat = {n: float(z[j]) for j, n in enumerate(labels[:n_e])}
    p_hat, Qc_hat, R_hat = obj.inputs(z[None])
    # the noise levels' errors off the log scale (delta method), their covariance too
    scale = np.concatenate([np.ones(n_e), np.exp(z[n_e:])])
    extra = {lab: float(scale[j] * se[j]) for j, lab in enumerate(labels[n_e:], start=n_e)}
    sigma2 = float(quad[0] / sum((p.time.size - 1) * n_y for p in probs))
    fixed = {k: float(v) for k, v in start.items() if k not in names}
    return IdentificationResult(
        parameters=params_hat,
        stderr={n: float(se[j]) for j, n in enumerate(labels[:n_e])},
        covariance=cov,
        parameter_names=tuple(labels[:n_e]),
        fixed=fixed,
        covariance_white=cov,
        error_bars="white",
        identifiable=identifiable,
        unidentifiable=tuple(combos),
        success=success,
        message=message,
        n_iterations=it,
        cost=float(f),
        method="filter_error",
        output_names=out_names,
        noise_covariance=R_hat[0],
        initial_states=tuple(
            dict(zip(m.states, unbiased_start(p, p.x0[None], p_hat, k)[0].tolist(), strict=True))
            for p, k in zip(probs, obj.known, strict=True)
        ),
        biases=(),
        extra_stderr=extra,
        full_covariance=cov_full * np.outer(scale, scale),
        full_names=tuple(labels),
        residuals=tuple(nu for nu, _ in per),
        sigma2=sigma2,
        process_noise={s: float(Qc_hat[0, i, i]) for i, s in enumerate(m.states)},
        model_name=m.name,
        bounds={n: box[n] for n in names if n in box},
        active_bounds={
            n: ("lower" if z[j] <= lo[j] else "upper") for j, n in enumerate(names) if held[j]
        },
        time_delays={c: float(z[n_p + i]) for i, c in enumerate(delay_starts)},
    )
