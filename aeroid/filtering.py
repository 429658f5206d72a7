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

from . import _integrate, _linalg
from ._records import fmt, frozen_array, frozen_mapping, markdown_table
from ._stats import chi2_sf
from ._threads import small_blas
from .data import (
    FlightData,
    check_flag,
    check_symmetric,
    measured_start,
    plain,
    real_array,
    whole_number,
)
from .errors import AeroidError, ChannelError, FilterError, SimulationError
from .model import (
    MAX_SUBSTEPS,
    Model,
    SimulatorModel,
    delayed_controls,
    fitted_start,
    real_number,
    resolve_parameters,
)

__all__ = ["FilterResult", "filter_states"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

METHODS = ("ekf", "ukf")
_JITTER_TRIES = 8
_MAX_DT_GROUPS = 64


# -----------------------------------------------------------------------------------
# result record
# -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FilterResult:
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
        from .plotting import plot_filter

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
# problem set-up (shared with the filter-error method)
# -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Problem:
    """One record's filtering problem, normalised (internal)."""

    model: Model
    time: FloatArray
    U: FloatArray  # (n_t, n_u)
    Y: FloatArray  # (n_t, n_y)
    out_idx: tuple[int, ...]  # used outputs among the model's outputs
    output_names: tuple[str, ...]
    x0: FloatArray  # (n_x,)
    P0: FloatArray  # (n_x, n_x)
    substeps: int | None
    method: str
    ukf: tuple[float, float, float]


def _require_model(model: Any, error: type[AeroidError], what: str) -> Model:
    if isinstance(model, Model):
        return model
    kind = type(model).__name__
    if not isinstance(model, SimulatorModel):
        raise error(
            f"model: {what} needs an aeroid.Model with a continuous dynamics callable "
            f"f(t, x, u, p), got {kind}"
        )
    raise error(
        f"{what} needs a Model with a continuous dynamics callable f(t, x, u, p); got {kind}, "
        "which has none (a stepped simulator such as JSBSim or RocketPy cannot be linearised "
        "between samples). Use output-error identification (identify(method='output_error')) "
        "for such models, or wrap the dynamics in aeroid.Model."
    )


def noise_matrix(
    value: Any,
    names: Sequence[str],
    what: str,
    error: type[AeroidError],
    *,
    require_all: bool,
    positive: bool,
) -> FloatArray:
    """A noise specification (dict by name, 1-D variances or a matrix) as a square matrix."""
    n = len(names)
    if value is None:
        if require_all:
            raise error(f"{what}: required; give a dict of name -> value for {list(names)}")
        return np.zeros((n, n))
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise error(f"{what}: unknown names {unknown}; expected names among {list(names)}")
        missing = [k for k in names if k not in value]
        if require_all and missing:
            raise error(f"{what}: no value for {missing}; give one for each of {list(names)}")
        diag = np.zeros(n)
        for i, k in enumerate(names):
            if k in value:
                diag[i] = real_number(value[k], f"{what}[{k!r}]", error)
        mat = np.diag(diag)
    else:
        if np.iscomplexobj(value):  # a cast would drop the imaginary part
            raise error(f"{what}: complex values are not supported, got {plain(value)}")
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise error(
                f"{what}: expected a dict, a 1-D array or a matrix, got {plain(value)}"
            ) from None
        if arr.ndim == 0 and n == 1:
            arr = arr.reshape(1)
        if arr.shape == (n,):
            mat = np.diag(arr)
        elif arr.shape == (n, n):
            check_symmetric(arr, names, what, error)
            mat = 0.5 * (arr + arr.T)  # removes rounding-level asymmetry only
        else:
            raise error(
                f"{what}: expected {n} values or a {n}x{n} matrix (order {list(names)}), "
                f"got shape {arr.shape}"
            )
    if not np.all(np.isfinite(mat)):
        raise error(f"{what}: contains NaN or infinite values")
    eig = np.linalg.eigvalsh(mat) if n else np.zeros(0)
    scale = float(np.max(np.abs(eig))) if n else 0.0
    if n and eig.min() < -1e-12 * max(scale, 1e-300):
        if np.any(np.diag(mat) < 0):
            got = f"got {np.diag(mat).tolist()}"
        else:
            got = f"its smallest eigenvalue is {float(eig.min()):.6g} (order {list(names)})"
        raise error(f"{what}: must be non-negative (positive semi-definite); {got}")
    if positive and n and eig.min() <= 0:
        raise error(
            f"{what}: every variance must be positive (a measurement needs some noise); "
            f"got {np.diag(mat).tolist()}"
        )
    return mat


def _x0_vector(model: Model, data: FlightData, x0: Any, error: type[AeroidError]) -> FloatArray:
    measured = measured_start(data, model.states)
    if x0 is None:
        return np.array([measured.get(s, 0.0) for s in model.states])
    if isinstance(x0, Mapping):
        unknown = sorted(set(x0) - set(model.states))
        if unknown:
            raise error(f"x0: unknown states {unknown}; states: {list(model.states)}")
        given = {k: real_number(v, f"x0[{k!r}]", error) for k, v in x0.items()}
        vals = {**measured, **given}
        out = np.array([vals.get(s, 0.0) for s in model.states])
    else:
        try:
            out = real_array(x0, "x0").reshape(-1)
        except AeroidError as exc:
            raise error(str(exc)) from None
        if out.shape != (model.n_states,):
            raise error(
                f"x0: expected {model.n_states} values (states {list(model.states)}), got shape "
                f"{np.shape(x0)}"
            )
    if not np.all(np.isfinite(out)):
        raise error("x0: contains NaN or infinite values")
    return out


def _default_P0(model: Model, out_names: Sequence[str], R: FloatArray) -> FloatArray:
    # A directly measured state starts with the uncertainty of one measurement;
    # the others with unit variance (override with P0 when units make that poor).
    diag = np.ones(model.n_states)
    direct = model._measurement_batch is None
    for i, s in enumerate(model.states):
        if direct and s in out_names:
            j = list(out_names).index(s)
            diag[i] = R[j, j]
    return np.diag(diag)


def build_problem(
    model: Any,
    data: Any,
    *,
    outputs: Sequence[str] | None,
    measurement_noise: Any,
    x0: Any,
    P0: Any,
    substeps: int | None,
    method: str,
    ukf: tuple[float, float, float],
    error: type[AeroidError],
    require_R: bool = True,
) -> tuple[_Problem, FloatArray]:
    """Validate the common arguments; returns the problem and the measurement-noise matrix."""
    what = "filter_states" if error is FilterError else "filter-error identification"
    m = _require_model(model, error, what)
    if not isinstance(data, FlightData):
        raise error(f"data: expected a FlightData record, got {type(data).__name__}")
    if method not in METHODS:
        raise error(f"method {method!r} is unknown; choose one of {list(METHODS)}")
    if outputs is None:
        out_names = m.output_names
    else:
        out_names = tuple([outputs] if isinstance(outputs, str) else outputs)
        bad = [o for o in out_names if o not in m.output_names]
        if bad or not out_names:
            raise error(
                f"outputs: {bad or 'none'} not among the model's outputs {list(m.output_names)}"
            )
    data.require(m.controls, role="control")
    data.require(out_names, role="output")
    R = noise_matrix(
        measurement_noise,
        out_names,
        "measurement_noise",
        error,
        require_all=require_R,
        positive=require_R,
    )
    alpha, beta, kappa = (
        real_number(v, k, error, finite=True)
        for k, v in zip(("ukf_alpha", "ukf_beta", "ukf_kappa"), ukf, strict=True)
    )
    if not alpha > 0:
        raise error(f"ukf_alpha must be positive and ukf_beta, ukf_kappa finite; got {ukf}")
    if method == "ukf" and m.n_states + kappa <= 0:
        raise error(f"ukf_kappa: n_states + kappa must be positive, got {m.n_states} + {kappa}")
    if substeps is not None:
        # a bool would be read as 1; a huge count would exhaust memory (as in `simulate`)
        substeps = whole_number(substeps, "substeps", error)
        if substeps > MAX_SUBSTEPS:
            raise error(f"substeps: expected at most {MAX_SUBSTEPS}, got {substeps}")
    xv = _x0_vector(m, data, x0, error)
    if P0 is None:
        P0m = _default_P0(m, out_names, R)
    else:
        P0m = noise_matrix(P0, m.states, "P0", error, require_all=False, positive=False)
    out_idx = tuple(m.output_names.index(o) for o in out_names)
    U = data.array(list(m.controls)) if m.n_controls else np.zeros((data.time.size, 0))
    Y = data.array(list(out_names))
    prob = _Problem(
        m,
        np.asarray(data.time, dtype=np.float64),
        np.ascontiguousarray(U, dtype=np.float64),
        np.ascontiguousarray(Y, dtype=np.float64),
        out_idx,
        out_names,
        xv,
        P0m,
        None if substeps is None else int(substeps),
        method,
        (float(alpha), float(beta), float(kappa)),
    )
    return prob, R


# -----------------------------------------------------------------------------------
# discretisation
# -----------------------------------------------------------------------------------


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


def _linearise_model(
    prob: _Problem, params: Mapping[str, FloatArray], Qc: FloatArray, B: int
) -> _Linear | None:
    m = prob.model
    if not m._maybe_lti:
        return None
    groups = _dt_groups(prob.time)
    if groups is None:
        return None
    n, nu = m.n_states, m.n_controls
    trusted = m.linear is True
    mats, _ = _integrate.lti_form(m._dynamics_batch, prob.time, n, nu, params, trusted=trusted)
    if mats is None:
        return None
    A = np.broadcast_to(mats[0], (B, n, n))
    Bm = np.broadcast_to(mats[1], (B, n, nu))
    c = np.broadcast_to(mats[2], (B, n))
    hs, idx = groups
    n_aug = n + 2 * nu + 1
    Maug = np.zeros((B, n_aug, n_aug))
    Maug[:, :n, :n] = A
    Maug[:, :n, n : n + nu] = Bm
    Maug[:, n : n + nu, n + nu : n + 2 * nu] = np.eye(nu)
    Maug[:, :n, -1] = c
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


# -----------------------------------------------------------------------------------
# the filter passes (batched over parameter vectors)
# -----------------------------------------------------------------------------------


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


def _riccati_steps(
    lin: _Linear, R: FloatArray, P0: FloatArray, n_t: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """(Pp, Pf, S, Kg) step by step, stopping once the gain has converged."""
    assert lin.H is not None
    B, _, n, _ = lin.Phi.shape
    H = lin.H
    n_y = H.shape[1]
    Ht = np.ascontiguousarray(H.transpose(0, 2, 1))
    PhiT = np.ascontiguousarray(np.swapaxes(lin.Phi, 2, 3))
    eye = np.eye(n)
    Pf = np.empty((B, n_t, n, n))
    Pp = np.empty((B, n_t, n, n))
    S = np.empty((B, n_t, n_y, n_y))
    Kg = np.empty((B, n_t, n, n_y))
    P = P0.copy()
    Pf[:, 0], Pp[:, 0] = P, P
    S[:, 0] = H @ P @ Ht + R
    Kg[:, 0] = 0.0
    single = lin.Phi.shape[1] == 1
    Phi, PT, Qd = lin.Phi[:, 0], PhiT[:, 0], lin.Qd[:, 0]
    Rt = R
    prev = P
    for k in range(1, n_t):
        if not single:
            g = lin.idx[k - 1]
            Phi, PT, Qd = lin.Phi[:, g], PhiT[:, g], lin.Qd[:, g]
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
                p0 = {k: v[:1] for k, v in params.items()}
                X0 = prob.x0[:, None]
                self.m = _integrate.auto_substeps(self.f, prob.time, X0, prob.U[None], p0)
            self.nodes = _integrate.control_nodes(prob.U[None], self.m)[
                ..., 0
            ]  # (n_t-1, 2m+1, n_u)
        self._rep: dict[int, dict[str, FloatArray]] = {}
        # the same RK4 over one interval, compiled, when the dynamics translate to JAX
        self._cp = None
        self._pmat: FloatArray | None = None
        if lin is None:
            from . import _compiled

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


def _fd_step(x: FloatArray, P: FloatArray) -> FloatArray:
    sd = np.sqrt(np.clip(np.diagonal(P, axis1=1, axis2=2), 0.0, None))
    return np.maximum(1e-3 * sd, 1e-7 * np.maximum(np.abs(x), 1e-2))


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


def _sigma(x: FloatArray, P: FloatArray, lam: float, k: int, stats: list[int]) -> FloatArray:
    """Scaled sigma points (B, 2n+1, n)."""
    n = x.shape[1]
    L = _chol((n + lam) * P, k, "the state covariance is not positive definite", stats)
    Lc = np.swapaxes(L, 1, 2)  # rows = columns of L
    return np.concatenate([x[:, None, :], x[:, None, :] + Lc, x[:, None, :] - Lc], axis=1)


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
            prob.model, prob.time, prob.U, prob.Y, prob.out_idx, params, Qc, R, x0, P0, prop.m
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


def innovation_loglik(nu: FloatArray, S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Per member: (sum of nu' S^-1 nu, sum of log det S) over the given samples."""
    L = np.linalg.cholesky(S)  # (B, K, m, m)
    z = np.linalg.solve(L, nu[..., None])[..., 0]
    quad = np.sum(z**2, axis=(1, 2))
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=2, axis2=3)), axis=(1, 2))
    return quad, logdet


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
        integer of at most `aeroid.model.MAX_SUBSTEPS`), or a covariance that stays indefinite despite jitter (the
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
