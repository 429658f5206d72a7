"""State estimation: extended and unscented Kalman filters with RTS smoothing.

The model is continuous (``x' = f(t, x, u, p) + w``, ``w`` white with power
spectral density ``Q``) and the measurements discrete (``y_k = h(t_k, x_k, u_k, p)
+ v_k``, ``v_k`` white with covariance ``R``). Between samples the state is
propagated with the model itself (RK4 substeps, controls piecewise-linear as
in every simulation) and the covariance with the exact discretisation of the
local linearisation: ``Phi = expm(A dt)`` and ``Qd = int Phi Q Phi' ds`` (Van
Loan's matrix exponential), so a linear filter reproduces the discrete
Riccati recursion of the sampled system exactly.

For dynamics and measurements that are affine in state and control and
independent of time, everything is discretised once per parameter vector and
the Kalman recursion runs on constant matrices, batched over parameter
vectors (which is what the filter-error method's finite differences need).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt, frozen_array, frozen_mapping, markdown_table
from .._stats import chi2_sf
from .._threads import small_blas
from .._units import require_model_units
from ..errors import ChannelError, FilterError
from ..io.data import FlightData, check_flag
from ..models.model import delayed_controls, fitted_start, resolve_parameters
from ._filter_problem import METHODS as METHODS
from ._filter_problem import _default_P0 as _default_P0
from ._filter_problem import _Problem as _Problem
from ._filter_problem import _require_model as _require_model
from ._filter_problem import _x0_vector as _x0_vector
from ._filter_problem import build_problem as build_problem
from ._filter_problem import noise_matrix as noise_matrix
from ._kalman_linear import _JITTER_TRIES as _JITTER_TRIES
from ._kalman_linear import _MAX_DT_GROUPS as _MAX_DT_GROUPS
from ._kalman_linear import _RICCATI_TOL as _RICCATI_TOL
from ._kalman_linear import _affine_scan as _affine_scan
from ._kalman_linear import _chol as _chol
from ._kalman_linear import _dt_groups as _dt_groups
from ._kalman_linear import _Failure as _Failure
from ._kalman_linear import _fd_step as _fd_step
from ._kalman_linear import _kf_update as _kf_update
from ._kalman_linear import _Linear as _Linear
from ._kalman_linear import _ModelFailure as _ModelFailure
from ._kalman_linear import _Pass as _Pass
from ._kalman_linear import _riccati_blocks as _riccati_blocks
from ._kalman_linear import _riccati_fast as _riccati_fast
from ._kalman_linear import _riccati_steps as _riccati_steps
from ._kalman_linear import _rts as _rts
from ._kalman_linear import _sigma as _sigma
from ._kalman_linear import _sym as _sym
from ._kalman_linear import _van_loan as _van_loan
from ._kalman_nonlinear import _general as _general
from ._kalman_nonlinear import _linearise_model as _linearise_model
from ._kalman_nonlinear import _Measurer as _Measurer
from ._kalman_nonlinear import _Propagator as _Propagator

__all__ = ["FilterResult", "filter_states"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


# -----------------------------------------------------------------------------------
# result record
# -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FilterResult(FrozenState):
    """Kalman-filter (and smoother) estimates on a flight record's time grid.

    Attributes
    ----------
    time : ndarray, shape (n_t,)
    state_names, output_names : tuple of str
        States of the model; outputs whose measurements the filter used.
    method : str
        ``"ekf"`` or ``"ukf"``.
    filtered_states : ndarray, shape (n_t, n_states)
        Estimates using the measurements up to each sample.
    filtered_covariance : ndarray, shape (n_t, n_states, n_states)
    smoothed_states : ndarray, shape (n_t, n_states) or None
        Rauch–Tung–Striebel estimates using the whole record (None when
        smoothing was switched off).
    smoothed_covariance : ndarray, shape (n_t, n_states, n_states) or None
    innovations : ndarray, shape (n_t, n_outputs)
        Measured minus predicted outputs. The first sample initialises the
        filter (see `filter_states`), so its row is the mismatch of the initial
        state and is left out of `log_likelihood` and the statistics.
    innovation_covariance : ndarray, shape (n_t, n_outputs, n_outputs)
    log_likelihood : float
        Gaussian log-likelihood of the innovations from the second sample on
        (the prediction-error decomposition); compare noise models with it.
    process_noise : ndarray, shape (n_states, n_states)
        Continuous power spectral density used (state² per second).
    measurement_noise : ndarray, shape (n_outputs, n_outputs)
        Measurement-noise covariance used.
    parameters : mapping of str to float
        Model parameters the filter ran with.
    n_jitter : int
        How many covariance factorisations needed diagonal jitter to succeed.
    model_name : str
    """

    time: FloatArray
    state_names: tuple[str, ...]
    output_names: tuple[str, ...]
    method: str
    filtered_states: FloatArray
    filtered_covariance: FloatArray
    smoothed_states: FloatArray | None
    smoothed_covariance: FloatArray | None
    innovations: FloatArray
    innovation_covariance: FloatArray
    log_likelihood: float
    process_noise: FloatArray
    measurement_noise: FloatArray
    parameters: Mapping[str, float]
    n_jitter: int = 0
    model_name: str = ""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in (
            "time",
            "filtered_states",
            "filtered_covariance",
            "innovations",
            "innovation_covariance",
            "process_noise",
            "measurement_noise",
        ):
            set_(self, name, frozen_array(getattr(self, name)))
        for name in ("smoothed_states", "smoothed_covariance"):
            if getattr(self, name) is not None:
                set_(self, name, frozen_array(getattr(self, name)))
        set_(self, "parameters", frozen_mapping(self.parameters))
        set_(self, "state_names", tuple(self.state_names))
        set_(self, "output_names", tuple(self.output_names))
        set_(self, "log_likelihood", float(self.log_likelihood))

    # -- accessors -----------------------------------------------------------------
    def _state_index(self, name: str) -> int:
        if name not in self.state_names:
            raise ChannelError(
                f"state {name!r} is not a model state; states: {list(self.state_names)}"
            )
        return self.state_names.index(name)

    def _output_index(self, name: str) -> int:
        if name not in self.output_names:
            raise ChannelError(
                f"output {name!r} was not filtered; filtered outputs: {list(self.output_names)}"
            )
        return self.output_names.index(name)

    @property
    def smoothed(self) -> bool:
        """True when the RTS smoother ran."""
        return self.smoothed_states is not None

    def state(self, name: str) -> FloatArray:
        """Filtered estimate of one state (measurements up to each sample)."""
        return self.filtered_states[:, self._state_index(name)]

    def smoothed_state(self, name: str) -> FloatArray:
        """RTS-smoothed estimate of one state (the whole record).

        Raises
        ------
        FilterError
            If the filter ran with ``smooth=False``.
        """
        j = self._state_index(name)
        if self.smoothed_states is None:
            raise FilterError(
                "smoothed_state: the filter ran with smooth=False; rerun with smooth=True"
            )
        return self.smoothed_states[:, j]

    def state_std(self, name: str) -> FloatArray:
        """Standard deviation of a state estimate.

        That of the smoothed estimate when smoothing ran (the default),
        otherwise that of the filtered estimate.
        """
        j = self._state_index(name)
        cov = (
            self.smoothed_covariance
            if self.smoothed_covariance is not None
            else self.filtered_covariance
        )
        out = np.sqrt(np.clip(cov[:, j, j], 0.0, None))
        out.setflags(write=False)
        return out

    def innovation(self, name: str) -> FloatArray:
        """Innovation (measured minus predicted) of one output."""
        return self.innovations[:, self._output_index(name)]

    def normalized_innovation(self, name: str) -> FloatArray:
        """Innovation of one output divided by its predicted standard deviation.

        Unit variance and white when the model and the noise specification
        are consistent with the data.
        """
        j = self._output_index(name)
        out = self.innovations[:, j] / np.sqrt(self.innovation_covariance[:, j, j])
        out.setflags(write=False)
        return out

    @property
    def normalized_innovation_variance(self) -> float:
        """Mean of ``nu' S^-1 nu / n_outputs`` over the record (about 1 when consistent)."""
        return _sigma2(self.innovations[None, 1:], self.innovation_covariance[None, 1:])

    def plot(self, **kwargs: Any) -> Any:
        """States with ±1σ bands. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_filter

        return plot_filter(self, **kwargs)

    def summary(self) -> str:
        """Markdown section: likelihood, innovation statistics per output, state uncertainty."""
        lags = int(min(20, max(1, (self.time.size - 1) // 5)))
        rows = []
        for name in self.output_names:
            nu = self.innovation(name)[1:]
            z = self.normalized_innovation(name)[1:]
            q, p = _ljung_box(z, lags)
            rows.append(
                (
                    name,
                    fmt(float(np.mean(nu))),
                    fmt(float(np.sqrt(np.mean(nu**2)))),
                    fmt(float(np.mean(z**2)), 3),
                    fmt(q, 3),
                    fmt(p, 3),
                )
            )
        table = markdown_table(
            (
                "output",
                "innovation mean",
                "innovation RMS",
                "norm. variance",
                f"Ljung–Box Q({lags})",
                "p-value",
            ),
            rows,
        )
        which = "smoothed" if self.smoothed else "filtered"
        cov = (
            self.smoothed_covariance
            if self.smoothed_covariance is not None
            else self.filtered_covariance
        )
        srows = []
        for j, name in enumerate(self.state_names):
            sd = np.sqrt(np.clip(cov[:, j, j], 0.0, None))
            srows.append((name, fmt(float(np.median(sd))), fmt(float(np.max(sd)))))
        stable = markdown_table(("state", f"median {which} std", "max std"), srows)
        head = (
            f"**State estimation** ({self.method.upper()}"
            f"{' + RTS smoother' if self.smoothed else ''}), model `{self.model_name}`, "
            f"{self.time.size} samples; log-likelihood {self.log_likelihood:.6g}; "
            f"normalised innovation variance {self.normalized_innovation_variance:.3g} "
            "(about 1 when the noise specification fits the data)."
        )
        notes = []
        if self.n_jitter:
            notes.append(f"{self.n_jitter} covariance factorisation(s) needed diagonal jitter.")
        return "\n\n".join([head, table, stable, *notes])


def _ljung_box(z: FloatArray, lags: int) -> tuple[float, float]:
    n = z.size
    if n <= lags + 1:
        return float("nan"), float("nan")
    zc = z - z.mean()
    denom = float(np.dot(zc, zc))
    if denom <= 0:
        return float("nan"), float("nan")
    r = np.array([np.dot(zc[: n - k], zc[k:]) / denom for k in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1))))
    return q, chi2_sf(q, lags)


# -----------------------------------------------------------------------------------
# the filter passes (batched over parameter vectors)
# -----------------------------------------------------------------------------------


def _lti_kf(lin: _Linear, Y: FloatArray, R: FloatArray, x0: FloatArray, P0: FloatArray) -> _Pass:
    """Kalman filter on constant matrices, batched; no per-step factorisation.

    The covariance recursion does not depend on the data, so it runs first:
    by blocks of the Riccati map's Möbius form where that is verified exact
    (`_riccati_fast`), otherwise step by step until it has converged (the
    gain is then constant). The state recursion, linear given the gains, is
    then solved for all samples at once. The innovation covariances are
    checked afterwards in one vectorised Cholesky; the caller falls back to
    the careful pass if that fails.
    """
    assert lin.H is not None and lin.d is not None
    B, _, n, _ = lin.Phi.shape
    n_t = Y.shape[0]
    H, d, F = lin.H, lin.d, lin.F
    eye = np.eye(n)
    with np.errstate(all="ignore"):
        fast = _riccati_fast(lin, R, P0, n_t)
        if fast is not None:
            Pp, Pf, S, Kg = fast
        else:
            Pp, Pf, S, Kg = _riccati_steps(lin, R, P0, n_t)
        # state recursion: x_k = (I - K_k H)(Phi_k x_{k-1} + F_k) + K_k z_k
        z = Y[None] - d  # (B, n_t, n_y)
        Phis = lin.Phi[:, lin.idx]  # (B, n_t-1, n, n)
        IKHs = eye - Kg[:, 1:] @ H[:, None]
        M = IKHs @ Phis
        c = (IKHs @ F[..., None])[..., 0] + (Kg[:, 1:] @ z[:, 1:, :, None])[..., 0]
        xs = _affine_scan(M, c, x0)
        xf = np.concatenate([x0[:, None], xs], axis=1)
        xp = np.empty_like(xf)
        xp[:, 0] = x0
        xp[:, 1:] = (Phis @ xf[:, :-1, :, None])[..., 0] + F
        nu = z - (H[:, None] @ xp[..., None])[..., 0]
        C = np.empty_like(Pp)
        C[:, 1:] = Pf[:, :-1] @ np.swapaxes(Phis, 2, 3)
        C[:, 0] = 0.0
    bad = ~np.all(np.isfinite(xf), axis=(1, 2)) | ~np.all(np.isfinite(Pf), axis=(1, 2, 3))
    fail = np.full(B, -1, dtype=np.int64)
    for b in np.flatnonzero(bad):
        fin = np.all(np.isfinite(xf[b]), axis=1) & np.all(np.isfinite(Pf[b]), axis=(1, 2))
        fail[b] = int(np.argmin(fin))
    return _Pass(xf, Pf, xp, Pp, C, nu, S, ~bad, fail, 0)


def run_filter(
    prob: _Problem,
    params: Mapping[str, FloatArray],
    Qc: FloatArray,
    R: FloatArray,
    x0: FloatArray,
    P0: FloatArray,
    *,
    method: str | None = None,
    linear: bool | None = None,
) -> _Pass:
    """Forward filter pass for a batch of B members (internal entry point).

    params: name -> (B,); Qc (B, n, n); R (B, n_y, n_y); x0 (B, n); P0 (B, n, n).
    ``linear=False`` forces the general path (RK4 + local linearisation).
    """
    method = method or prob.method
    B = x0.shape[0]
    lin = None if linear is False else _linearise_model(prob, params, Qc, B)
    if linear is True and lin is None:
        raise FilterError(f"model {prob.model.name!r} is not linear time-invariant")
    if lin is not None and lin.H is not None and method == "ekf":
        run = _lti_kf(lin, prob.Y, R, x0, P0)
        if np.all(run.ok):
            try:
                np.linalg.cholesky(run.S)
                return run
            except np.linalg.LinAlgError:
                pass
        # fall through to the careful pass, which factorises and jitters per step
    return _general(prob, params, Qc, R, x0, P0, lin, method)


def innovation_loglik(
    nu: FloatArray, S: FloatArray, *, settled: int | None = None
) -> tuple[FloatArray, FloatArray]:
    """Per member: (sum of nu' S^-1 nu, sum of log det S) over the given samples.

    `settled`: where known, the sample from which every member's S is its last
    (a fixed-gain pass knows it); else found by comparing them.
    """
    K = S.shape[1]
    # a fixed-gain filter's S stops changing once its gain has converged: the samples
    # from there on share one factorisation
    if settled is None:
        same = np.all(S == S[:, -1:], axis=(0, 2, 3))
        k0 = K - int(np.argmin(same[::-1])) if not np.all(same) else 0
    else:
        k0 = min(max(int(settled), 0), K)
    if K - k0 < 8:
        k0 = K
    L = np.linalg.cholesky(S[:, :k0])  # (B, k0, m, m)
    z = _forward_substitution(L, nu[:, :k0])
    quad = np.sum(z**2, axis=(1, 2))
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=2, axis2=3)), axis=(1, 2))
    if k0 < K:
        L1 = np.linalg.cholesky(S[:, -1])  # (B, m, m)
        z1 = np.linalg.solve(L1, np.swapaxes(nu[:, k0:], 1, 2))  # (B, m, K - k0)
        quad = quad + np.sum(z1**2, axis=(1, 2))
        logdet = logdet + 2.0 * (K - k0) * np.sum(np.log(np.diagonal(L1, axis1=1, axis2=2)), axis=1)
    return quad, logdet


def _forward_substitution(L: NDArray[np.floating[Any]], b: FloatArray) -> FloatArray:
    """``L^-1 b`` for lower-triangular ``L`` (..., m, m) and ``b`` (..., m), a row at a
    time over the whole stack: LAPACK's general solver factorises each small matrix
    again, at about twice the cost over a record of them."""
    z = np.empty_like(b)
    for i in range(b.shape[-1]):
        acc = b[..., i]
        if i:
            acc = acc - np.einsum("...j,...j->...", L[..., i, :i], z[..., :i])
        z[..., i] = acc / L[..., i, i]
    return z


def _sigma2(nu: FloatArray, S: FloatArray) -> float:
    quad, _ = innovation_loglik(nu, S)
    return float(np.sum(quad) / (nu.shape[1] * nu.shape[2] * nu.shape[0]))


# -----------------------------------------------------------------------------------
# public entry point
# -----------------------------------------------------------------------------------


@small_blas
def filter_states(
    model: Any,
    data: FlightData,
    parameters: Any = None,
    *,
    process_noise: Any,
    measurement_noise: Any,
    method: str = "ekf",
    smooth: bool = True,
    x0: Any = None,
    P0: Any = None,
    outputs: Sequence[str] | None = None,
    ukf_alpha: float = 1e-3,
    ukf_beta: float = 2.0,
    ukf_kappa: float = 0.0,
    substeps: int | None = None,
    control_interpolation: str | Mapping[str, str] = "linear",
) -> FilterResult:
    """Estimate the states of a flight record with a Kalman filter and smoother.

    Parameters
    ----------
    model : Model
        A model with a continuous dynamics callable (stepped simulators are
        rejected).
    data : FlightData
        Must carry the model's controls and the filtered outputs.
    parameters : mapping or result, optional
        Parameter values (merged onto the nominal ones) or a result with
        ``.parameters`` such as an `IdentificationResult`.
    process_noise : mapping, array_like or None
        Continuous power spectral density of the process noise on each state
        (state² per second): a dict by state name (missing states get none),
        a 1-D array of intensities, or a symmetric positive semi-definite
        (n_states, n_states) matrix.
    measurement_noise : mapping or array_like
        Measurement-noise variances, one per filtered output: a dict by output
        name, a 1-D array, or a symmetric positive definite covariance matrix.
    method : {"ekf", "ukf"}
        Extended Kalman filter (Joseph-form updates) or unscented Kalman
        filter with scaled sigma points.
    smooth : bool
        Also run the Rauch–Tung–Striebel smoother.
    x0 : mapping or array_like, optional
        State estimate at the first sample. Default: the initial state an
        identification result given as `parameters` used for this record,
        else the first measured value of each state the data carries, zero
        for the others (a dict fills in only the states it names). A result's
        estimated time delays delay its controls, as in `validate`.
    P0 : mapping or array_like, optional
        Covariance of `x0` (a dict or 1-D array of variances, or a matrix).
        Default: the measurement variance for a directly measured state, 1 for
        the others.
    outputs : sequence of str, optional
        Outputs whose measurements the filter uses (default: all model outputs).
    ukf_alpha, ukf_beta, ukf_kappa : float
        Spread, prior-knowledge and secondary scaling of the sigma points.
    substeps : int, optional
        RK4 steps per sample interval for nonlinear dynamics (default from the
        dynamics' stiffness).
    control_interpolation : {"linear", "cubic"}
        How the controls run between samples while the state is propagated
        (as in `aeroid.Model.simulate`): with ``"cubic"`` even a linear model
        is propagated by RK4 (the exact discretisation holds straight lines),
        compiled where straight lines would be; a mapping of control names to
        either names the cubic ones.

    Returns
    -------
    FilterResult

    Notes
    -----
    The filter starts from ``(x0, P0)`` as the estimate at the first sample and
    processes the measurements from the second sample on, so the default
    ``x0`` (taken from the first measurement) is not counted twice. The state
    is propagated between samples with the model's own dynamics and the
    covariance with the exact discretisation of the local linearisation (Van
    Loan), so for a linear model the filter equals the discrete-time Kalman
    filter of the sampled system.

    Raises
    ------
    FilterError
        A model without a dynamics callable, `data` not a `FlightData`, bad
        noise specifications or options (such as a `smooth` that is not a
        bool, a non-numeric `ukf_alpha` or `x0`, or `substeps` not a positive
        integer of at most `aeroid.models.model.MAX_SUBSTEPS`), or a covariance that stays indefinite despite jitter (the
        message names the sample).
    ChannelError
        The data lacks a control or output channel.
    SimulationError
        The model's dynamics or measurement gave a non-finite value (the
        message names the state or output and the samples); it is also a
        `FilterError`.
    """
    if not isinstance(data, FlightData):  # before the fit's start and delays read it
        raise FilterError(f"data: expected a FlightData record, got {type(data).__name__}")
    check_flag(smooth, "smooth", FilterError)
    require_model_units(
        model,
        [data],
        [*getattr(model, "controls", ()), *getattr(model, "output_names", ())],
        FilterError,
    )
    if x0 is None:
        x0 = fitted_start(parameters, data)[0]
    data = delayed_controls(parameters, data)  # a fit's estimated time delays
    prob, R = build_problem(
        model,
        data,
        outputs=outputs,
        measurement_noise=measurement_noise,
        x0=x0,
        P0=P0,
        substeps=substeps,
        method=method,
        ukf=(ukf_alpha, ukf_beta, ukf_kappa),
        error=FilterError,
        control_interpolation=control_interpolation,
    )
    m = prob.model
    Qc = noise_matrix(
        process_noise, m.states, "process_noise", FilterError, require_all=False, positive=False
    )
    p = resolve_parameters(m, parameters, error=FilterError)
    params = {k: np.array([v]) for k, v in p.items()}
    run = run_filter(prob, params, Qc[None], R[None], prob.x0[None], prob.P0[None])
    if not run.ok[0]:
        k = int(run.fail[0])
        if run.simulation:
            raise _ModelFailure(f"filter_states: {run.message}")
        why = run.message or "the estimate became non-finite"
        raise FilterError(
            f"filter_states: {why} at sample {k} (t = {prob.time[k]:.6g} s) even with diagonal "
            "jitter; check the noise levels, the initial state and the parameters"
        )
    xs = Ps = None
    if smooth:
        xs_b, Ps_b = _rts(run)
        xs, Ps = xs_b[0], Ps_b[0]
        if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(Ps))):
            bad = int(np.argmin(np.all(np.isfinite(xs), axis=1)))
            raise FilterError(f"filter_states: the RTS smoother diverged near sample {bad}")
    nu, S = run.nu[0], run.S[0]
    quad, logdet = innovation_loglik(nu[None, 1:], S[None, 1:])
    loglik = -0.5 * float(
        quad[0] + logdet[0] + (nu.shape[0] - 1) * nu.shape[1] * math.log(2 * math.pi)
    )
    return FilterResult(
        time=prob.time,
        state_names=tuple(m.states),
        output_names=prob.output_names,
        method=method,
        filtered_states=run.xf[0],
        filtered_covariance=run.Pf[0],
        smoothed_states=xs,
        smoothed_covariance=Ps,
        innovations=nu,
        innovation_covariance=S,
        log_likelihood=loglik,
        process_noise=Qc,
        measurement_noise=R,
        parameters=p,
        n_jitter=run.n_jitter,
        model_name=m.name,
    )
