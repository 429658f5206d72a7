"""The filtering problem: model check, noise matrices, initial state and covariance.

Split out of `aeroid.estimation.filtering` (which re-exports every name); shared with the
filter-error method.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState
from .._value_checks import check_distinct
from ..errors import AeroidError, FilterError, IdentificationError
from ..io.data import FlightData, check_symmetric, measured_start, plain, real_array, whole_number
from ..models.integration import Interpolation, check_control_interpolation
from ..models.model import MAX_SUBSTEPS, Model, SimulatorModel, real_number, require_states

FloatArray = NDArray[np.float64]

METHODS = ("ekf", "ukf")

FILTER_OPTIONS = (
    *("method", "ukf_alpha", "ukf_beta", "ukf_kappa", "P0", "substeps", "gain"),
    "control_interpolation",
)


@dataclass(frozen=True)
class _Problem(FrozenState):
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
    # how the controls run between samples (`aeroid.models.integration.control_slopes`)
    interpolation: Interpolation = "linear"
    # the RK4 substeps the record's states ask for, found once per problem
    # (`path_substeps`; a memo, not part of the problem)
    memo: dict[str, int] = field(default_factory=dict, compare=False, repr=False)

    def path_substeps(self, params: Mapping[str, FloatArray]) -> int:
        """The RK4 substeps a prediction takes: what the modes at the start ask for at
        `params`, and at least what they asked for, at the first parameters seen, along
        the record, its measured states there and `x0` for the others (a filter follows
        the measurements; a nonlinear model can stiffen far from its start)."""
        from ..models import integration as _integrate

        f = self.model._dynamics_batch
        first = {k: np.asarray(v)[:1] for k, v in params.items()}
        if "path" not in self.memo:
            states = np.repeat(self.x0[None, :], self.time.size, axis=0)
            for j, name in enumerate(self.output_names):
                if name in self.model.states:
                    states[:, self.model.states.index(name)] = self.Y[:, j]
            self.memo["path"] = _integrate.trajectory_substeps(f, self.time, states, self.U, first)
        start = _integrate.auto_substeps(f, self.time, self.x0[:, None], self.U[None], first)
        return max(self.memo["path"], start)


def _require_model(model: Any, error: type[AeroidError], what: str) -> Model:
    if isinstance(model, Model):
        require_states(
            model,
            error,
            what,
            "a Kalman filter has nothing to estimate; fit it by output error "
            "(identify(method='output_error')), compare it with validate",
        )
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
            i = int(np.argmin(np.diag(mat)))
            got = f"{names[i]!r} is {plain(mat[i, i])} (order {list(names)})"
        else:
            got = f"its smallest eigenvalue is {float(eig.min()):.6g} (order {list(names)})"
        raise error(f"{what}: must be non-negative (positive semi-definite); {got}")
    if positive and n and eig.min() <= 0:
        diag = np.diag(mat)
        where = (
            f"{names[int(np.argmin(diag))]!r} is {plain(diag.min())}"
            if np.any(diag <= 0)
            else f"the matrix is singular, its smallest eigenvalue {float(eig.min()):.6g}"
        )
        raise error(
            f"{what}: every variance must be positive (a measurement needs some noise); "
            f"{where} (order {list(names)})"
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
    # A state measured under its own name starts with the uncertainty of one measurement
    # (its start is read from that channel), whether or not the model has a measurement
    # function: a unit variance there (a radian of angle of attack) makes the first
    # innovations' covariance, and the likelihood's curvature in every parameter that
    # moves it, the prior's rather than the record's. The others start with unit variance
    # (override with P0 when units make that poor).
    diag = np.ones(model.n_states)
    for i, s in enumerate(model.states):
        if s in out_names:
            j = list(out_names).index(s)
            diag[i] = R[j, j]
    return np.diag(diag)


def unbiased_start(
    prob: _Problem, x0: FloatArray, params: Mapping[str, FloatArray], known: NDArray[np.bool_]
) -> FloatArray:
    """Per member, the start of each state read from its own channel (not `known`) moved
    so that the measurement at the start reads that channel's first value: ``x0 - (h(x0)
    - x0)`` on those states, exact for an output bias (a bias on alpha moves the start
    the filter holds, not the parameters). `x0` is (members, n_x), `params` per member."""
    model = prob.model
    own = [
        (j, model.states.index(name))
        for j, name in enumerate(prob.output_names)
        if name in model.states and not known[model.states.index(name)]
    ]
    if not own or model._measurement_batch is None:
        return x0
    y = model._outputs(prob.time[:1], x0[:, None, :], prob.U[:1], params)[:, 0, :]
    out = x0.copy()
    for j, i in own:
        out[:, i] = x0[:, i] - (y[:, prob.out_idx[j]] - x0[:, i])
    return out


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
    control_interpolation: str | Mapping[str, str] = "linear",
) -> tuple[_Problem, FloatArray]:
    """Validate the common arguments; returns the problem and the measurement-noise matrix."""
    what = "filter_states" if error is FilterError else "filter-error identification"
    m = _require_model(model, error, what)
    if not isinstance(data, FlightData):
        raise error(f"data: expected a FlightData record, got {type(data).__name__}")
    if method not in METHODS:
        raise error(f"method {method!r} is unknown; choose one of {list(METHODS)}")
    interpolation = check_control_interpolation(
        control_interpolation, error, controls=_require_model(model, error, "filtering").controls
    )
    if outputs is None:
        out_names = m.output_names
    else:
        out_names = tuple([outputs] if isinstance(outputs, str) else outputs)
        bad = [o for o in out_names if o not in m.output_names]
        if not out_names:
            raise error(f"outputs: name at least one of the model's outputs {list(m.output_names)}")
        if bad:
            raise error(f"outputs: {bad} not among the model's outputs {list(m.output_names)}")
        check_distinct(out_names, "outputs", error)
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
        interpolation,
    )
    return prob, R


def noise_start(prob: _Problem, R: FloatArray | None) -> FloatArray:
    """Measurement variances to start from when none are given: half the variance of
    first differences (white noise dominates sample-to-sample changes)."""
    dy = np.diff(prob.Y, axis=0)
    v = 0.5 * np.var(dy, axis=0)
    scale = np.maximum(np.var(prob.Y, axis=0), 1e-300)
    return np.maximum(v, 1e-12 * scale) if R is None else np.diag(R)


def start_failure_cause(model: Any, datas: Sequence[FlightData], start: Mapping[str, float]) -> str:
    """Why a filter may fail at `start`, for its message: the model's simulation of a
    record from its measured start where that diverges, else the noise levels."""
    values = {k: v for k, v in start.items() if k in getattr(model, "parameters", {})}
    for d in datas:
        try:
            model.simulate_data(d, parameters=values)
        except AeroidError as exc:
            return f": {exc}"
        except Exception:  # a simulator of the user's own: no further diagnosis
            break
    return " (the model simulates; the noise levels may leave no positive covariance)"


def filter_options_of(filter_options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The filter-error method's `filter_options` over its defaults, checked."""
    opts: dict[str, Any] = {"method": "ekf", "ukf_alpha": 1e-3, "ukf_beta": 2.0, "ukf_kappa": 0.0}
    opts.update({"P0": None, "substeps": None, "gain": None, "control_interpolation": "linear"})
    if filter_options is None:
        return opts
    if not isinstance(filter_options, Mapping):
        raise IdentificationError(
            f"filter_options: expected a dict with keys among {list(FILTER_OPTIONS)}, "
            f"got {type(filter_options).__name__}"
        )
    unknown = sorted(set(filter_options) - set(FILTER_OPTIONS))
    if unknown:
        raise IdentificationError(
            f"filter_options: unknown options {unknown}; valid options are {list(FILTER_OPTIONS)}"
        )
    opts.update(filter_options)
    return opts


def simulated_states(
    m: Model,
    data: FlightData,
    x0: Any,
    start: Mapping[str, float],
    opts: Mapping[str, Any],
    compiled: FloatArray | None,
) -> FloatArray:
    """The model's states over the first record at the start: the compiled rollout's
    where it ran, else simulated in numpy."""
    if compiled is not None:
        return compiled
    sim = m.simulate_data(
        data,
        x0=x0,
        parameters=start,
        method="auto",
        control_interpolation=opts["control_interpolation"],
    )
    return np.asarray(sim.states, dtype=np.float64)


def given_states(model: Model, x0: Any) -> NDArray[np.bool_]:
    """Which states' start the caller gave (a mapping's names, or all of a vector)."""
    if x0 is None:
        return np.zeros(model.n_states, dtype=bool)
    if isinstance(x0, Mapping):
        return np.array([s in x0 for s in model.states])
    return np.ones(model.n_states, dtype=bool)
