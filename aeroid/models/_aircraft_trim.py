"""Trim and linearisation of the aircraft models (see `aeroid.models.aircraft`)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import as_float, plain
from .._records import FrozenState, fmt, frozen_array, frozen_mapping, markdown_table
from .._threads import small_blas
from .._value_checks import whole_number
from ..errors import ModelDefinitionError, SimulationError
from ._aircraft_parts import AircraftModel, _finite
from .model import Model, resolve_parameters

FloatArray = NDArray[np.float64]

# -- trim and linearisation ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TrimResult(FrozenState):
    """A trimmed flight condition of an aircraft model.

    Attributes
    ----------
    states, controls : mapping of str to float
        The trim state and control values.
    derivatives : mapping of str to float
        The state derivatives there (zero for the trimmed equations; ``h``
        changes at ``V sin γ``, ``psi`` and position in straight flight).
    outputs : mapping of str to float
        The model outputs at the trim.
    trimmed : tuple of str
        The states whose derivatives the solver zeroed.
    unknowns : mapping of str to float
        What the solver chose (angles, surfaces, thrust, and ``gamma`` for a
        model without thrust, which glides).
    """

    states: Mapping[str, float]
    controls: Mapping[str, float]
    derivatives: Mapping[str, float]
    outputs: Mapping[str, float]
    trimmed: tuple[str, ...]
    unknowns: Mapping[str, float]

    def __post_init__(self) -> None:
        for name in ("states", "controls", "derivatives", "outputs", "unknowns"):
            object.__setattr__(self, name, frozen_mapping(getattr(self, name)))

    @property
    def x0(self) -> FloatArray:
        """The trim state vector, in the model's state order."""
        return np.array(list(self.states.values()), dtype=np.float64)

    @property
    def u0(self) -> FloatArray:
        """The trim control vector, in the model's control order."""
        return np.array(list(self.controls.values()), dtype=np.float64)

    def summary(self) -> str:
        """The trim as a Markdown table of states, controls and derivatives."""
        rows: list[tuple[str, str, str, str]] = []
        for k, v in self.states.items():
            rows.append((k, "state", fmt(v, 8), fmt(self.derivatives[k], 3)))
        for k, v in self.controls.items():
            rows.append((k, "control", fmt(v, 8), ""))
        worst = max((abs(self.derivatives[k]) for k in self.trimmed), default=0.0)
        head = f"trim: largest trimmed derivative {worst:.3g} ({', '.join(self.trimmed)})"
        return head + "\n\n" + markdown_table(("name", "kind", "value", "derivative"), rows)


def _evaluate(
    fun: Callable[..., Any], X: FloatArray, U: FloatArray, p: Mapping[str, float]
) -> FloatArray:
    """A model function over a batch of states and controls, shape (n_out, batch)."""
    batch = X.shape[1]
    P = {k: np.full(batch, v) for k, v in p.items()}
    with np.errstate(all="ignore"):
        return np.asarray(fun(0.0, X, U, P), dtype=np.float64).reshape(-1, batch)


def _central_points(z: FloatArray, h: FloatArray) -> FloatArray:
    """Columns ``z + h_j e_j`` then ``z - h_j e_j``: the batch of a central difference."""
    E = np.diag(h)
    return np.concatenate([z[:, None] + E, z[:, None] - E], axis=1)


def _central_slopes(F: FloatArray, h: FloatArray) -> FloatArray:
    """The Jacobian from a function's values at `_central_points`."""
    return (F[:, : h.size] - F[:, h.size :]) / (2 * h)


@small_blas
def trim(
    model: AircraftModel,
    V: float | None = None,
    *,
    gamma: float = 0.0,
    parameters: Mapping[str, float] | None = None,
    controls: Mapping[str, float] | None = None,
    tolerance: float = 1e-10,
    max_iterations: int = 50,
) -> TrimResult:
    """Trim an aircraft model in straight, wings-level flight.

    ===========================  ==========================================  =====================
    model                        unknowns                                    zeroed derivatives
    ===========================  ==========================================  =====================
    longitudinal                 α, elevator, thrust (or γ without thrust)   V̇, α̇, q̇
    lateral                      β, aileron, rudder                          β̇, ṗ, ṙ
    six_dof                      α, β, elevator, aileron, rudder, thrust     u̇, v̇, ẇ, ṗ, q̇, ṙ
    longitudinal_linear          α, elevator, thrust (or γ)                  V̇, α̇, q̇
    lateral_linear               β, aileron, rudder                          β̇, ṗ, ṙ
    ===========================  ==========================================  =====================

    The elevator, aileron and rudder are the model's first, first/second and
    first three surfaces; other controls stay at `controls` (default zero).
    With ``θ = α + γ`` (six-dof: ``sin γ = cos β sin(θ - α)``), q = 0 and
    φ = 0. The perturbation (linear) models trim their perturbation states.

    Parameters
    ----------
    model : AircraftModel
        A model from this module.
    V : float, optional
        Airspeed, m/s; default the model's reference ``V0`` (the lateral
        models fly at ``V0`` only; the linear ones at zero perturbation).
    gamma : float
        Flight-path angle, rad (ignored, and solved for, without thrust).
    parameters : mapping, optional
        Parameter values merged onto the model's nominal ones.
    controls : mapping, optional
        Fixed values of controls the solver does not set.
    tolerance : float
        Largest acceptable trimmed derivative.
    max_iterations : int

    Returns
    -------
    TrimResult

    Raises
    ------
    ModelDefinitionError
        `model` is not an aircraft model of this module, or has too few controls.
    SimulationError
        The solver cannot reach the tolerance, or reaches it only with an angle
        (α, β, γ) or a surface at 90° or beyond (no trim at this condition).

    Warns
    -----
    UserWarning
        A nonlinear model's trim needs negative thrust.
    """
    if not isinstance(model, AircraftModel):
        raise ModelDefinitionError(
            f"trim: expected a model built by aeroid.models.aircraft, got {type(model).__name__}"
        )
    if model.kind not in _TRIM_SETUP:
        raise ModelDefinitionError(
            f"trim: a {model.kind!r} aircraft model is not trimmed here; trim the models it is "
            f"built from (trim takes {sorted(_TRIM_SETUP)})"
        )
    tol = _finite("tolerance", tolerance)
    if not tol > 0:
        raise ModelDefinitionError(f"tolerance: expected a positive number, got {tolerance!r}")
    max_iterations = whole_number(max_iterations, "max_iterations", ModelDefinitionError)
    p = resolve_parameters(model, parameters)
    fixed = dict.fromkeys(model.controls, 0.0)
    for k, v in (controls or {}).items():
        if k not in fixed:
            raise ModelDefinitionError(
                f"controls: {k!r} is not a control of {model.name!r}; its controls are "
                f"{list(model.controls)}"
            )
        fixed[k] = _finite(f"controls[{k!r}]", v)
    speed = float(model.reference.get("V0", 0.0)) if V is None else _finite("V", V)
    if model.kind == "lateral" and "V" in fixed and "V" not in (controls or {}):
        fixed["V"] = speed  # a lateral model fed the flown airspeed trims at its V0
    if model.kind in ("lateral", "lateral_linear") and V is not None:
        if not math.isclose(speed, model.reference["V0"], rel_tol=1e-12):
            raise ModelDefinitionError(
                f"V: the lateral model is linearised about V0 = {model.reference['V0']:.6g} "
                f"m/s and flies at it only, got {speed!r}"
            )
    if model.kind == "longitudinal_linear" and V is not None:
        raise ModelDefinitionError("V: the linear model trims at zero perturbation; leave V out")
    if model.kind in ("longitudinal", "six_dof") and not speed > 0:
        raise ModelDefinitionError(f"V: must be positive, got {speed!r}")
    gamma = _finite("gamma", gamma)
    unknowns, trimmed, build = _TRIM_SETUP[model.kind](model, speed, gamma, fixed)
    solved = [name for name, _ in unknowns]
    clash = [k for k in (controls or {}) if k in solved]
    if clash:
        raise ModelDefinitionError(
            f"controls: the trim solves for {clash} (its unknowns are {solved}); give only "
            "the controls it does not set"
        )
    idx = [model.states.index(s) for s in trimmed]
    z = np.array([start for _, start in unknowns], dtype=np.float64)

    def residual(Z: FloatArray) -> FloatArray:
        X, U = build(Z)
        return _evaluate(model._dynamics_batch.fun, X, U, p)[idx]

    scale = np.ones(len(idx))
    r = residual(z[:, None])[:, 0]
    for _ in range(max_iterations):
        if np.all(np.isfinite(r)) and np.max(np.abs(r)) <= tol:
            break
        h = 1e-7 * np.maximum(1.0, np.abs(z))
        J = _central_slopes(residual(_central_points(z, h)), h)
        if not np.all(np.isfinite(J)):
            break
        step = np.linalg.lstsq(J * scale[:, None], -r * scale, rcond=None)[0]
        # halve the Newton step until the residual falls (keeps α, β in range)
        for _ in range(30):
            trial = z + step
            r_trial = residual(trial[:, None])[:, 0]
            if np.all(np.isfinite(r_trial)) and np.linalg.norm(r_trial) < np.linalg.norm(r):
                break
            step = 0.5 * step
        else:
            break
        z, r = trial, r_trial
    if not (np.all(np.isfinite(r)) and np.max(np.abs(r)) <= tol):
        worst = trimmed[int(np.nanargmax(np.abs(r)))] if np.any(np.isfinite(r)) else trimmed[0]
        raise SimulationError(
            f"trim of {model.name!r} at V = {speed:.6g} m/s failed: the derivative of "
            f"{worst!r} stays at {np.nanmax(np.abs(r)):.3g} (no trim with these parameters and "
            f"controls {sorted(k for k, _ in unknowns)})"
        )
    _check_envelope(model, speed, dict(zip(solved, z.tolist(), strict=True)))
    X, U = build(z[:, None])
    xdot = _evaluate(model._dynamics_batch.fun, X, U, p)[:, 0]
    y = (
        X[[model.states.index(o) for o in model.output_names], 0]
        if model.measurement is None
        else _evaluate(model.measurement, X, U, p)[:, 0]
    )
    return TrimResult(
        states=dict(zip(model.states, X[:, 0].tolist(), strict=True)),
        controls=dict(zip(model.controls, U[:, 0].tolist(), strict=True)),
        derivatives=dict(zip(model.states, xdot.tolist(), strict=True)),
        outputs=dict(zip(model.output_names, y.tolist(), strict=True)),
        trimmed=tuple(trimmed),
        unknowns={name: float(v) for (name, _), v in zip(unknowns, z, strict=True)},
    )


def _check_envelope(model: AircraftModel, speed: float, solved: Mapping[str, float]) -> None:
    """Refuse a root of the trim equations that is no flight condition: an angle or a
    surface at a right angle or beyond (the equations are periodic in the angles and
    linear in the surfaces, so such roots exist where no trim does); warn of a trim
    that needs the engine to pull backwards."""
    for name, value in solved.items():
        if name != "thrust" and abs(value) >= 0.5 * math.pi:
            raise SimulationError(
                f"trim of {model.name!r} at V = {speed:.6g} m/s: the equations are met with "
                f"{name} = {math.degrees(value):.1f} deg, which is no flight condition (at "
                "or beyond 90 deg); this model has no trim within the envelope there (too "
                "slow for its lift, or parameters without one)"
            )
    thrust = solved.get("thrust")
    if thrust is not None and thrust < 0 and model.kind in ("longitudinal", "six_dof"):
        warnings.warn(
            f"trim of {model.name!r} at V = {speed:.6g} m/s needs thrust {thrust:.4g} (a "
            "drag the engine cannot give): fly a steeper descent (gamma) or another speed",
            UserWarning,
            stacklevel=4,  # the caller of trim (through its thread-limiting wrapper)
        )


_TrimBuild = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
_TrimSetup = tuple[list[tuple[str, float]], list[str], _TrimBuild]


def _need_surfaces(model: AircraftModel, n: int, what: str) -> tuple[str, ...]:
    if len(model.surfaces) < n:
        raise ModelDefinitionError(
            f"trim: {model.name!r} needs {n} control surfaces ({what}) to trim, "
            f"it has {list(model.surfaces)}"
        )
    return model.surfaces[:n]


def _controls_matrix(
    model: AircraftModel, fixed: Mapping[str, float], set_by: Mapping[str, FloatArray], batch: int
) -> FloatArray:
    U = np.empty((model.n_controls, batch))
    for i, name in enumerate(model.controls):
        U[i] = set_by[name] if name in set_by else fixed[name]
    return U


def _trim_longitudinal(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    (elevator,) = _need_surfaces(model, 1, "an elevator")
    thrust = "thrust" in model.controls
    linear = model.kind == "longitudinal_linear"
    third = "thrust" if thrust else "gamma"
    unknowns = [("alpha", 0.0 if linear else 0.05), (elevator, 0.0), (third, 0.0)]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        alpha, de, z3 = Z[0], Z[1], Z[2]
        path = gamma if thrust else z3
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = 0.0 if linear else V
        X[1], X[2] = alpha, alpha + path
        set_by = {elevator: de, "thrust": z3} if thrust else {elevator: de}
        return X, _controls_matrix(model, fixed, set_by, Z.shape[1])

    return unknowns, ["V", "alpha", "q"], build


def _trim_lateral(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    aileron, rudder = _need_surfaces(model, 2, "aileron and rudder")
    unknowns = [("beta", 0.0), (aileron, 0.0), (rudder, 0.0)]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = Z[0]
        return X, _controls_matrix(model, fixed, {aileron: Z[1], rudder: Z[2]}, Z.shape[1])

    return unknowns, ["beta", "p", "r"], build


def _trim_six_dof(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    elevator, aileron, rudder = _need_surfaces(model, 3, "elevator, aileron and rudder")
    thrust = "thrust" in model.controls
    unknowns = [
        ("alpha", 0.05),
        ("beta", 0.0),
        (elevator, 0.0),
        (aileron, 0.0),
        (rudder, 0.0),
        ("thrust" if thrust else "gamma", 0.0),
    ]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        alpha, beta = Z[0], Z[1]
        path = gamma if thrust else Z[5]
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = V * np.cos(alpha) * np.cos(beta)
        X[1] = V * np.sin(beta)
        X[2] = V * np.sin(alpha) * np.cos(beta)
        X[7] = alpha + np.arcsin(np.sin(path) / np.cos(beta))
        set_by = {elevator: Z[2], aileron: Z[3], rudder: Z[4]}
        if thrust:
            set_by["thrust"] = Z[5]
        return X, _controls_matrix(model, fixed, set_by, Z.shape[1])

    return unknowns, ["u", "v", "w", "p", "q", "r"], build


_TRIM_SETUP: dict[str, Callable[..., _TrimSetup]] = {
    "longitudinal": _trim_longitudinal,
    "longitudinal_linear": _trim_longitudinal,
    "lateral": _trim_lateral,
    "lateral_linear": _trim_lateral,
    "six_dof": _trim_six_dof,
}


@dataclass(frozen=True, eq=False)
class Linearization(FrozenState):
    """A model linearised about a point: ``ẋ = A x + B u``, ``y = C x + D u`` (perturbations).

    Attributes
    ----------
    A, B, C, D : ndarray
        Jacobians of the dynamics and measurement (central differences).
    state_names, control_names, output_names : tuple of str
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def __post_init__(self) -> None:
        for name in ("A", "B", "C", "D"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))

    @property
    def eigenvalues(self) -> NDArray[np.complex128]:
        """Eigenvalues of ``A``, sorted by real part then imaginary part."""
        ev = np.linalg.eigvals(self.A).astype(np.complex128)
        return ev[np.lexsort((ev.imag, ev.real))]

    def derivative(self, of: str, by: str) -> float:
        """One entry of ``A`` or ``B``: ``∂(d of/dt)/∂ by``.

        Parameters
        ----------
        of : str
            The state whose derivative is differentiated.
        by : str
            A state (entry of ``A``) or a control (entry of ``B``).

        Returns
        -------
        float

        Raises
        ------
        ModelDefinitionError
            `of` is not a state, or `by` neither a state nor a control.
        """
        if of not in self.state_names:
            raise ModelDefinitionError(f"{of!r} is not a state; states: {list(self.state_names)}")
        i = self.state_names.index(of)
        if by in self.state_names:
            return float(self.A[i, self.state_names.index(by)])
        if by in self.control_names:
            return float(self.B[i, self.control_names.index(by)])
        raise ModelDefinitionError(f"{by!r} is neither a state nor a control of this linearisation")

    def summary(self) -> str:
        """Eigenvalues with their frequency, damping and time constant, and ``A``."""
        rows = []
        for ev in self.eigenvalues:
            wn = abs(ev)
            zeta = -ev.real / wn if wn > 0 else float("nan")
            tau = -1.0 / ev.real if ev.real != 0 and ev.imag == 0 else float("nan")
            rows.append((f"{ev.real:.6g}{ev.imag:+.6g}j", fmt(wn), fmt(zeta), fmt(tau)))
        table = markdown_table(("eigenvalue", "ω (rad/s)", "ζ", "τ (s)"), rows)
        a_rows = [
            (s, *(fmt(v) for v in row)) for s, row in zip(self.state_names, self.A, strict=True)
        ]
        a_table = markdown_table(("ẋ \\ x", *self.state_names), a_rows)
        return f"{table}\n\nA =\n\n{a_table}"


@small_blas
def linearize(
    model: Model,
    x0: Any,
    u0: Any = None,
    *,
    parameters: Mapping[str, float] | None = None,
    step: float = 1e-6,
) -> Linearization:
    """Linearise a model about a state and control by central differences.

    Parameters
    ----------
    model : Model
    x0 : TrimResult, mapping or array_like
        The point: a `TrimResult` (then `u0` comes from it), or a state.
    u0 : mapping or array_like, optional
        Controls (default zero).
    parameters : mapping, optional
    step : float
        Relative difference step.

    Returns
    -------
    Linearization

    Raises
    ------
    ModelDefinitionError
        `model` is not a model, or `x0` or `u0` does not fit it.
    SimulationError
        The model is not finite near the point.
    """
    if not isinstance(model, Model):
        raise ModelDefinitionError(
            f"linearize: expected an aeroid.Model, got {type(model).__name__}"
        )
    if isinstance(x0, TrimResult):
        u0 = x0.controls if u0 is None else u0
        x0 = x0.states
    p = resolve_parameters(model, parameters)
    try:
        x = model.initial_state(x0)[0]
    except SimulationError as exc:  # the point does not fit the model: as documented
        raise ModelDefinitionError(str(exc)) from None
    if u0 is None:
        u = np.zeros(model.n_controls)
    elif isinstance(u0, Mapping):
        unknown = sorted(set(u0) - set(model.controls))
        if unknown:
            raise ModelDefinitionError(f"u0: unknown controls {unknown}")
        u = np.array([_finite(f"u0[{c!r}]", u0.get(c, 0.0)) for c in model.controls])
    else:
        u = np.asarray(u0, dtype=np.float64).reshape(-1)
        if u.size != model.n_controls:
            raise ModelDefinitionError(
                f"u0: expected {model.n_controls} controls {list(model.controls)}, got {u.size}"
            )
    rel = as_float(step)
    if rel is None or not (np.isfinite(rel) and 0.0 < rel < 1.0):
        raise ModelDefinitionError(
            f"step: expected a relative difference step in (0, 1), got {plain(step)}"
        )
    n, m = x.size, u.size
    z = np.concatenate([x, u])
    h = rel * np.maximum(1.0, np.abs(z))
    Z = _central_points(z, h)
    X, U = Z[:n], Z[n:]
    J = _central_slopes(_evaluate(model._dynamics_batch, X, U, p), h)
    if model._measurement_batch is None:
        sel = [model.states.index(o) for o in model.output_names]
        C = np.eye(n)[sel]
        D = np.zeros((len(sel), m))
    else:
        JG = _central_slopes(_evaluate(model._measurement_batch, X, U, p), h)
        C, D = JG[:, :n], JG[:, n:]
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(C)) and np.all(np.isfinite(D))):
        raise SimulationError(f"linearize: {model.name!r} is not finite near the given point")
    return Linearization(
        J[:, :n],
        J[:, n:],
        C,
        D,
        tuple(model.states),
        tuple(model.controls),
        model.output_names,
    )
