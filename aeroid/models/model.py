"""ODE vehicle models: `Model`, its simulation results, and the simulator protocol."""

from __future__ import annotations

import inspect
import keyword
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import check_time as check_time  # re-exported (adapters import it here)
from .._checks import named_columns
from .._records import ReadOnlyDict
from .._threads import quiet_warnings, small_blas
from .._units import require_model_units
from ..errors import AeroidError, ChannelError, ModelDefinitionError, SimulationError
from ..io.data import FlightData, measured_start, plain
from . import integration as _integrate
from ._fitted_parameters import _names, control_delays, resolve_parameters
from ._fitted_parameters import delayed_controls as delayed_controls
from ._fitted_parameters import fitted_manoeuvre as fitted_manoeuvre
from ._fitted_parameters import fitted_start as fitted_start
from ._model_base import ContinuousModel
from ._simulation_checks import MAX_SUBSTEPS as MAX_SUBSTEPS
from ._simulation_checks import _real, check_integrator, real_number
from ._simulation_results import BatchSimulation, SimulationResult
from ._simulation_results import simulator_outputs as simulator_outputs
from ._simulation_results import simulator_problem as simulator_problem
from .batch_simulator import BatchSimulator

__all__ = [
    "BatchSimulation",
    "BatchSimulator",
    "Model",
    "SimulationResult",
    "SimulatorModel",
    "check_integrator",
    "check_simulate_options",
    "real_number",
    "resolve_parameters",
]

FloatArray = NDArray[np.float64]
Dynamics = Callable[[Any, Any, Any, Mapping[str, Any]], Any]

SIMULATE_OPTION_KEYS = ("method", "substeps", "rtol", "atol", "control_interpolation")


def check_simulate_options(
    options: Any, model: Any, error: type[AeroidError], *, name: str = "simulate_options"
) -> dict[str, Any]:
    """`options` (a mapping or None) as a dict, its keys and values checked for a `Model`.

    Unknown keys and bad values raise `error` naming them; defaults fill in
    only for the check, so the returned dict holds what the caller gave.
    Options for another simulator are passed on unchecked.
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise error(f"{name}: expected a dict, got {type(options).__name__}")
    if isinstance(model, Model):
        unknown = sorted(str(k) for k in options if k not in SIMULATE_OPTION_KEYS)
        if unknown:
            raise error(
                f"{name}: unknown keys {unknown}; valid keys are {list(SIMULATE_OPTION_KEYS)}"
            )
        check_integrator(
            options.get("method", "auto"),
            options.get("substeps"),
            options.get("rtol", 1e-9),
            options.get("atol", 1e-12),
            error=error,
            prefix=name,
        )
        _integrate.check_control_interpolation(
            options.get("control_interpolation", "linear"),
            error,
            f"{name}['control_interpolation']",
            model.controls,
        )
    return dict(options)


@runtime_checkable
class SimulatorModel(Protocol):
    """What AeroID needs from an external, stepped simulator (JSBSim, RocketPy, ...).

    Such a model has named controls, outputs and nominal parameters, and can
    simulate onto a given time grid; it has no continuous dynamics callable,
    so Kalman filtering and JAX paths do not apply to it.

    ``simulate`` receives `controls` as a mapping of control name to a 1-D
    array on `time`, and `parameters` as a mapping of name to value; it
    returns a `SimulationResult` whose outputs follow `outputs`.
    """

    name: str
    controls: tuple[str, ...]
    outputs: tuple[str, ...]
    parameters: Mapping[str, float]

    def simulate(
        self,
        time: ArrayLike,
        controls: Any = None,
        x0: Any = None,
        parameters: Any = None,
        **options: Any,
    ) -> SimulationResult: ...

    def simulate_data(
        self, data: FlightData, *, x0: Any = None, parameters: Any = None, **options: Any
    ) -> SimulationResult: ...


def _jax_64_bit() -> None:
    """Switch on JAX's 64-bit floats when JAX is loaded (dynamics may use jax.numpy).

    With JAX's default 32-bit floats, dynamics written with jax.numpy would
    compute in float32 in every numpy path until a JAX path switched 64-bit on,
    so results would depend on which ran first. Nothing is imported here.
    """
    jax = sys.modules.get("jax")
    config = getattr(jax, "config", None)
    if config is not None and not config.read("jax_enable_x64"):
        config.update("jax_enable_x64", True)


def _no_dynamics(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> FloatArray:
    """The derivatives of a model without states: none, for each point of a batch."""
    return np.zeros((0, *np.shape(x)[1:]))


@dataclass(frozen=True, eq=False)
class Model(ContinuousModel):
    """A continuous-time vehicle model ``x' = f(t, x, u, p)``, ``y = h(t, x, u, p)``.

    Parameters
    ----------
    states : sequence of str
        State names, in the order of the state vector. Empty for a model
        whose outputs are algebraic functions of the measured controls and
        the parameters (aerodynamic coefficients from measured alpha, rates
        and surfaces): it then needs a `measurement`, no `dynamics`, and
        refuses what only states give meaning to (an initial state ``x0``
        with values, Kalman filtering, state-equation biases).
    controls : sequence of str
        Control (input) names, in the order of the control vector.
    parameters : mapping of str to float
        Named physical parameters with their nominal values.
    dynamics : callable, optional
        ``dynamics(t, x, u, p) -> x_dot`` with ``p`` a dict of parameters.
        Written with numpy broadcasting it is evaluated on whole batches of
        parameter vectors at once (``x`` of shape (n_states, batch)).
        Required when there are states; None for a model without them.
    outputs : sequence of str, optional
        Output names; default: the states.
    measurement : callable, optional
        ``measurement(t, x, u, p) -> y``; default: the states named in `outputs`.
        Without states ``x`` is empty and a simulation is this function
        evaluated at every sample (nothing is integrated).
    name : str
        A label used in messages, reports and fingerprints.
    version : str, optional
        A label the pipeline folds into the model's fingerprint; change it to
        invalidate cached results when behaviour changes without a source change.
    linear : bool, optional
        Whether the model is linear time-invariant: dynamics (and measurement,
        when given) affine in state and control, ``A x + B u + c``, with
        coefficients that depend on the parameters but not on time.
        ``None`` (default): find out. The exact matrix-exponential solution
        is then used only when that form is shown, for every parameter vector
        of a batch, at every sample time of the record; anything else (a
        forcing that switches off, a scheduled gain, a nonlinear term) is
        integrated numerically. ``True``: declare it; the form is verified once
        here, at the nominal parameters and near them, and then trusted, which
        skips the per-record check. ``False``: always integrate numerically.

    Raises
    ------
    ModelDefinitionError
        Bad names, dynamics/measurement that fail or return the wrong shape
        when probed at the nominal parameters, no dynamics for a model with
        states, no measurement for one without, or ``linear=True`` for a
        model that is not linear time-invariant.

    Notes
    -----
    A dynamics or measurement function that raises, or returns the wrong
    number of values, during a simulation is reported as a `SimulationError`
    (`ModelDefinitionError` for the wrong shape) naming the model and the time.
    """

    states: Sequence[str]
    controls: Sequence[str]
    parameters: Mapping[str, float]
    dynamics: Dynamics | None = None
    outputs: Sequence[str] | None = None
    measurement: Dynamics | None = None
    name: str = "model"
    version: str | None = None
    linear: bool | None = None
    _dynamics_batch: _integrate.BatchFunction = field(init=False, repr=False, compare=False)
    _measurement_batch: _integrate.BatchFunction | None = field(
        init=False, repr=False, compare=False
    )
    _maybe_lti: bool = field(init=False, repr=False, compare=False, default=True)

    def __post_init__(self) -> None:
        _jax_64_bit()
        states = _names(self.states, "states")
        controls = _names(self.controls, "controls")
        if not isinstance(self.parameters, Mapping):
            raise ModelDefinitionError("parameters: expected a dict of name -> nominal value")
        params: dict[str, float] = {}
        for k, v in self.parameters.items():
            if not isinstance(k, str) or not k.isidentifier() or keyword.iskeyword(k):
                raise ModelDefinitionError(
                    f"parameter name {k!r} must be a valid identifier (it becomes a dict key "
                    "and a column name)"
                )
            try:
                params[k] = float(v)
            except (TypeError, ValueError):
                raise ModelDefinitionError(
                    f"parameter {k!r}: nominal value {plain(v)} is not a number"
                ) from None
            if not np.isfinite(params[k]):
                raise ModelDefinitionError(
                    f"parameter {k!r}: nominal value {plain(v)} is not finite"
                )
        if self.dynamics is None and states:
            raise ModelDefinitionError(
                f"dynamics: model {self.name!r} has states {list(states)}; give their "
                "derivatives f(t, x, u, p) (dynamics=None only for a model without states)"
            )
        if self.dynamics is not None and not callable(self.dynamics):
            raise ModelDefinitionError("dynamics: expected a callable f(t, x, u, p)")
        if self.measurement is not None and not callable(self.measurement):
            raise ModelDefinitionError("measurement: expected a callable h(t, x, u, p)")
        if not states and self.measurement is None:
            raise ModelDefinitionError(
                f"measurement: model {self.name!r} has no states, so its outputs come from "
                "the controls and parameters alone; give h(t, x, u, p) (x is empty)"
            )
        outputs = states if self.outputs is None else _names(self.outputs, "outputs")
        if not outputs:
            raise ModelDefinitionError("outputs: a model needs at least one output")
        if self.measurement is None:
            missing = [o for o in outputs if o not in states]
            if missing:
                raise ModelDefinitionError(
                    f"outputs {missing} are not states; give a measurement function "
                    "h(t, x, u, p) to compute them"
                )
        clash = sorted(set(controls) & (set(states) | set(outputs)))
        if clash:
            raise ModelDefinitionError(
                f"names {clash} are used both as controls and states/outputs"
            )
        if not isinstance(self.name, str) or not self.name:
            raise ModelDefinitionError(f"name: expected a non-empty string, got {self.name!r}")
        object.__setattr__(self, "states", states)
        object.__setattr__(self, "controls", controls)
        object.__setattr__(self, "outputs", outputs)
        object.__setattr__(self, "parameters", ReadOnlyDict(params))
        names = tuple(params)
        if self.linear is not None and not isinstance(self.linear, (bool, np.bool_)):
            raise ModelDefinitionError(
                f"linear: expected True, False or None, got {plain(self.linear)}"
            )
        object.__setattr__(self, "linear", None if self.linear is None else bool(self.linear))
        object.__setattr__(
            self,
            "_dynamics_batch",
            _integrate.BatchFunction(
                _no_dynamics if self.dynamics is None else self.dynamics,
                len(states),
                names,
                role="dynamics",
                model_name=self.name,
            ),
        )
        object.__setattr__(
            self,
            "_measurement_batch",
            None
            if self.measurement is None
            else _integrate.BatchFunction(
                self.measurement, len(outputs), names, role="measurement", model_name=self.name
            ),
        )
        object.__setattr__(self, "_maybe_lti", self.linear is not False)
        self._probe()
        if self.linear:
            self._verify_linear()

    def _verify_linear(self) -> None:
        """Check a declared-linear model once: affine, time-invariant, near the nominal values.

        A parameter can make a nonlinear term vanish at its nominal value (a
        zero coefficient), so the form is also checked a little away from it.
        """
        nominal = np.array(list(self.parameters.values()), dtype=np.float64)
        rng = np.random.default_rng(0)
        near = nominal * (1.0 + 0.1 * rng.uniform(-1.0, 1.0, (2, nominal.size)))
        near = near + np.where(nominal == 0.0, 0.1, 0.0) * rng.uniform(0.5, 1.0, near.shape)
        # times up to 1000 s: a switch, a schedule or a t-term shows within them
        times = np.array([0.0, 0.3, 1.1, 2.6, 5.3, 12.7, 31.4, 97.0, 310.0, 1000.0])
        for role, fun in (
            ("dynamics", self._dynamics_batch),
            ("measurement", self._measurement_batch),
        ):
            if fun is None:
                continue
            for rows, must_evaluate in ((nominal[None], True), (near, False)):
                p = {k: rows[:, j].copy() for j, k in enumerate(self.parameters)}
                mats, not_lti = _integrate.lti_form(fun, times, self.n_states, self.n_controls, p)
                if not_lti:
                    where = "at" if must_evaluate else "near"
                    raise ModelDefinitionError(
                        f"model {self.name!r} is declared linear=True, but its {role} is not "
                        f"affine in state and control with time-invariant coefficients {where} "
                        "the nominal parameters; leave linear unset to let AeroID find out"
                    )
                if mats is None and must_evaluate:
                    raise ModelDefinitionError(
                        f"model {self.name!r} is declared linear=True, but its {role} could not "
                        "be evaluated (an exception or a non-finite value) at the states, "
                        "controls and times used to verify it"
                    )

    def _probe(self) -> None:
        x = np.zeros(self.n_states)
        u = np.zeros(self.n_controls)
        p = dict(self.parameters)
        for role, fun, n in (
            ("dynamics", self.dynamics, self.n_states),
            ("measurement", self.measurement, self.n_outputs),
        ):
            if fun is None:
                continue
            try:
                with quiet_warnings(), np.errstate(all="ignore"):
                    val = np.asarray(fun(0.0, x, u, p), dtype=np.float64)
            except KeyError as exc:
                raise ModelDefinitionError(
                    f"{role} of model {self.name!r} asked for parameter {exc.args[0]!r}, which "
                    f"is not among its parameters {sorted(p)}"
                ) from None
            except IndexError as exc:
                raise ModelDefinitionError(
                    f"{role} of model {self.name!r} indexed past the state/control vector "
                    f"({self.n_states} states, {self.n_controls} controls): {exc}"
                ) from None
            except Exception as exc:
                raise ModelDefinitionError(
                    f"{role} of model {self.name!r} failed when probed at the nominal parameters "
                    f"with zero state and control: {type(exc).__name__}: {exc}"
                ) from None
            if val.size != n:
                raise ModelDefinitionError(
                    f"{role} of model {self.name!r} returned {val.size} values "
                    f"(shape {val.shape}); expected {n}"
                )

    # -- structure ------------------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Parameter names in declaration order."""
        return tuple(self.parameters)

    @property
    def output_names(self) -> tuple[str, ...]:
        """Output names (the states when no measurement is given)."""
        return tuple(self.outputs or ())

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_controls(self) -> int:
        return len(self.controls)

    @property
    def n_outputs(self) -> int:
        return len(self.output_names)

    @property
    def dynamics_source(self) -> str:
        """Source text of the dynamics and measurement functions (for fingerprints)."""
        parts = []
        for fun in (self.dynamics, self.measurement):
            if fun is None:
                parts.append("")
                continue
            try:
                parts.append(inspect.getsource(fun))
            except (OSError, TypeError):
                parts.append(getattr(fun, "__qualname__", repr(type(fun))))
        return "\n".join(parts)

    # -- argument normalisation ---------------------------------------------------
    def control_array(self, time: FloatArray, controls: Any) -> FloatArray:
        """Normalise controls to shape (batch, n_t, n_controls)."""
        n_t = time.size
        if controls is None:
            if self.n_controls:
                # Zeros in place of a forgotten input would simulate a different flight.
                raise ChannelError(
                    f"model {self.name!r}: controls {list(self.controls)} not given "
                    "(controls=None); pass them as an array, a mapping or FlightData"
                )
            return np.zeros((1, n_t, 0))
        if isinstance(controls, FlightData):
            controls.require(self.controls, role="control")
            if controls.time.shape != time.shape or not np.allclose(
                controls.time, time, rtol=0.0, atol=1e-9 * max(1.0, float(np.max(np.abs(time))))
            ):
                # its samples belong to its own clock: read on another grid they would
                # be another flight's controls
                raise SimulationError(
                    f"controls: a FlightData on its own time grid ({controls.n_samples} "
                    f"samples, {controls.time[0]:.6g} to {controls.time[-1]:.6g} s) is not "
                    f"the simulation's ({n_t}, {time[0]:.6g} to {time[-1]:.6g} s); use "
                    "simulate_data, or resample the record to the grid"
                )
            return controls.array(list(self.controls))[None, :, :].astype(np.float64)
        controls = named_columns(controls) or controls
        if isinstance(controls, Mapping):
            missing = [c for c in self.controls if c not in controls]
            if missing:
                raise ChannelError(
                    f"control {missing[0]!r} not given; controls given: {sorted(controls)}"
                )
            cols = [_real(controls[c], f"control {c!r}") for c in self.controls]
            for c, col in zip(self.controls, cols, strict=True):
                if col.shape != (n_t,):
                    raise SimulationError(
                        f"control {c!r}: expected {n_t} samples, got shape {col.shape}"
                    )
                if not np.all(np.isfinite(col)):
                    raise SimulationError(f"control {c!r}: contains NaN or infinite values")
            arr = np.stack(cols, axis=1) if cols else np.zeros((n_t, 0))
            return arr[None]
        arr = _real(controls, "controls")
        if arr.ndim == 1 and self.n_controls == 1:
            arr = arr[:, None]
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1:] != (n_t, self.n_controls):
            raise SimulationError(
                f"controls: expected shape ({n_t}, {self.n_controls}) or "
                f"(batch, {n_t}, {self.n_controls}), got {np.shape(controls)}"
            )
        if not np.all(np.isfinite(arr)):
            raise SimulationError("controls: contain NaN or infinite values")
        return arr

    def initial_state(self, x0: Any, batch: int = 1) -> FloatArray:
        """Normalise an initial state to shape (batch, n_states)."""
        if given_values(x0):
            require_states(
                self, SimulationError, "x0", "there is no initial state to give; leave x0 unset"
            )
        if x0 is None:
            return np.zeros((batch, self.n_states))
        x0 = named_columns(x0) or x0
        if isinstance(x0, Mapping):
            unknown = sorted(set(x0) - set(self.states))
            if unknown:
                raise SimulationError(f"x0: unknown states {unknown}; states: {list(self.states)}")
            arr = np.array([[real_number(x0.get(s, 0.0), f"x0[{s!r}]") for s in self.states]])
        else:
            arr = np.atleast_2d(_real(x0, "x0"))
        if arr.shape[1] != self.n_states or arr.shape[0] not in (1, batch):
            raise SimulationError(
                f"x0: expected {self.n_states} values (states {list(self.states)}), "
                f"got shape {np.shape(x0)}"
            )
        if not np.all(np.isfinite(arr)):
            raise SimulationError("x0: contains NaN or infinite values")
        return np.broadcast_to(arr, (batch, self.n_states)).copy()

    # -- simulation -------------------------------------------------------------------
    def _outputs(
        self, time: FloatArray, states: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        batch, n_t, _ = states.shape
        if self._measurement_batch is None:
            idx = [self.states.index(o) for o in self.output_names]
            return states[:, :, idx]
        # Evaluate h on every (member, sample) at once: flatten batch x time.
        X = states.reshape(batch * n_t, self.n_states).T
        U = np.broadcast_to(u, (batch, n_t, self.n_controls)).reshape(batch * n_t, -1).T
        T = np.tile(time, batch)
        P = {k: np.repeat(v, n_t) for k, v in p.items()}
        with np.errstate(all="ignore"):
            Y = self._measurement_batch.at_times(
                T, np.ascontiguousarray(X), np.ascontiguousarray(U), P
            )
        return np.ascontiguousarray(Y.T.reshape(batch, n_t, self.n_outputs))

    def _failure(
        self, time: FloatArray, states: FloatArray, outputs: FloatArray, solver_time: float
    ) -> tuple[float, str]:
        """When and where one member's simulation failed: states (n_t, n_x), outputs (n_t, n_y)."""
        bad_x = ~np.isfinite(states)
        bad_y = ~np.isfinite(outputs)
        kx = int(np.argmax(bad_x.any(axis=1))) if bad_x.any() else time.size
        ky = int(np.argmax(bad_y.any(axis=1))) if bad_y.any() else time.size
        first = min(kx, ky)
        if first < time.size and np.isfinite(solver_time) and time[first] < solver_time:
            # a solver that raised (an implicit method's non-finite Jacobian) returns no
            # states at all: it got as far as its own time, not the grid's first NaN
            return solver_time, (
                f"states {list(self.states)} are not finite from t = {solver_time:.6g} s "
                "(the solver stopped there and returned none of them)"
            )
        if kx < time.size and kx <= ky:
            j = int(np.argmax(bad_x[kx]))
            return float(time[kx]), (
                f"state {self.states[j]!r} is not finite at t = {time[kx]:.6g} s"
            )
        if ky < time.size:
            j = int(np.argmax(bad_y[ky]))
            return float(time[ky]), (
                f"output {self.output_names[j]!r} is not finite at t = {time[ky]:.6g} s"
            )
        return solver_time, f"the solver failed at t = {solver_time:.6g} s"

    @small_blas
    def simulate_batch(
        self,
        time: ArrayLike,
        controls: Any,
        x0: Any,
        parameters: Mapping[str, ArrayLike],
        *,
        method: str = "auto",
        substeps: int | None = None,
        rtol: float = 1e-9,
        atol: float = 1e-12,
        control_interpolation: str | Mapping[str, str] = "linear",
    ) -> BatchSimulation:
        """Integrate many parameter vectors in one pass.

        Parameters
        ----------
        time : array_like, shape (n_t,)
        controls : array_like or mapping or None
            Shared (n_t, n_controls) or per member (batch, n_t, n_controls).
        x0 : array_like or mapping or None
            Shared (n_states,) or per member (batch, n_states).
        parameters : mapping of str to array_like
            Each entry a scalar or a (batch,) array; missing parameters take
            their nominal values.
        method : str
            ``"auto"`` (exact for dynamics shown linear time-invariant at
            every sample time of `time`, for every member, or declared so with
            ``linear=True``; else RK4), ``"exact"``, ``"rk4"``, ``"rk4_hold"``
            (RK4 with the controls held at each interval's first sample, one
            step per sample unless `substeps`: SIDPAC's data compatibility),
            ``"euler"`` (one forward-Euler step per sample, controls held:
            first order; both for reproducing legacy tools only), or a
            `scipy.integrate.solve_ivp` method.
        substeps : int, optional
            RK4 steps per sample interval (default: from the dynamics'
            stiffness; one for ``"rk4_hold"``).
        control_interpolation : {"linear", "cubic"}
            How the controls run between samples (see `simulate`).

        Returns
        -------
        BatchSimulation
            Members that diverge are marked in ``ok``; nothing is raised for them.

        Raises
        ------
        SimulationError
            If an argument is malformed (see `simulate`).
        """
        simulator = BatchSimulator(
            self,
            time,
            controls,
            x0,
            method=method,
            substeps=substeps,
            rtol=rtol,
            atol=atol,
            control_interpolation=control_interpolation,
        )
        return simulator(parameters)

    @small_blas
    def simulate(
        self,
        time: ArrayLike,
        controls: Any = None,
        x0: Any = None,
        parameters: Any = None,
        *,
        method: str = "RK45",
        substeps: int | None = None,
        rtol: float = 1e-9,
        atol: float = 1e-12,
        control_interpolation: str | Mapping[str, str] = "linear",
    ) -> SimulationResult:
        """Simulate the model with outputs exactly on `time`.

        Parameters
        ----------
        time : array_like, shape (n_t,)
            Strictly increasing sample times.
        controls : array_like, mapping or FlightData, optional
            Control samples (interpolated piecewise-linearly); required when the
            model has controls: a missing control raises `ChannelError`.
        x0 : array_like or mapping, optional
            Initial state; default zero.
        parameters : mapping or result, optional
            Parameter values (merged onto the nominal ones) or a result with
            ``.parameters``. The pure delays a fit with ``time_delays``
            estimated (its ``tau_<control>`` entries, in a mapping such as a
            `propagate` draw or in the result) delay their controls:
            ``u(t - tau)`` at the sample times, joined between them as
            `control_interpolation` says and held at the first sample, as
            `identify` simulated them (a fractional delay's corners fall on
            the sample times: see `identify`'s ``time_delays``).
        method : str
            A `scipy.integrate.solve_ivp` method (default ``"RK45"``; the
            explicit pairs restart at every sample, where the controls kink,
            the implicit ones take steps no longer than the sample spacing),
            ``"rk4"``, ``"rk4_hold"``, ``"euler"``, ``"exact"`` or ``"auto"``
            (as in `simulate_batch`).
        substeps : int, optional
            RK4 steps per sample interval.
        rtol, atol : float
            Tolerances of the adaptive methods.
        control_interpolation : {"linear", "cubic"}
            How the controls run between samples: ``"linear"`` (straight
            lines, the default) or ``"cubic"``, a C1 local cubic through the
            samples (Catmull-Rom on a uniform grid; see
            `aeroid.models.integration.control_slopes`), for smooth inputs
            recorded at a rate near the motion's bandwidth, where straight
            lines lose about ``(ωT)²/12`` of a swing's amplitude; or a
            mapping of control names to either (the others straight). Steps
            and surfaces at their stops overshoot with it, so it is not the
            default. ``"exact"`` and ``"euler"`` refuse it; RK4 with it runs
            compiled where the straight lines would, in the same programs.

        Returns
        -------
        SimulationResult

        Raises
        ------
        SimulationError
            If the solution diverges or the solver fails (the message names the
            time), or an argument is malformed: time not a finite increasing
            grid, controls or x0 of the wrong shape, not finite, complex or
            text, an unknown method, substeps not a positive integer (at most
            `MAX_SUBSTEPS`), rtol not positive or atol negative.
        """
        p = resolve_parameters(self, parameters, error=SimulationError, delays=True)
        given = controls
        delays = control_delays(self, parameters, error=SimulationError)
        if delays:
            # the vehicle a delayed fit describes: its controls act as u(t - tau)
            grid = check_time(time)
            how = _integrate.check_control_interpolation(
                control_interpolation, controls=self.controls
            )
            controls = _integrate.shifted_controls(
                grid,
                self.control_array(grid, controls)[0],
                [self.controls.index(c) for c in delays],
                list(delays.values()),
                how,
            )
        res = self.simulate_batch(
            time,
            controls,
            x0,
            p,
            method=method,
            substeps=substeps,
            rtol=rtol,
            atol=atol,
            control_interpolation=control_interpolation,
        )
        if not res.ok[0]:
            raise SimulationError(f"simulation of model {self.name!r} failed: {res.failure[0]}")
        u = self.control_array(res.time, given)[0]
        return SimulationResult(
            res.time,
            res.states[0],
            res.outputs[0],
            u,
            tuple(self.states),
            self.output_names,
            tuple(self.controls),
        )

    def simulate_data(
        self,
        data: FlightData,
        *,
        x0: Any = None,
        parameters: Any = None,
        **options: Any,
    ) -> SimulationResult:
        """Simulate on a flight record's time grid with its measured controls.

        The initial state defaults to the measured value of each state that
        the data carries (zero for the others).

        Raises
        ------
        SimulationError
            If `data` is not a `FlightData`, or as `simulate` does.
        ChannelError
            If a control is missing from `data`.
        """
        if not isinstance(data, FlightData):
            raise SimulationError(f"data: expected a FlightData, got {type(data).__name__}")
        data.require(self.controls, role="control")
        # a control stated in deg for a model in rad would be flown 57.3 times too hard
        require_model_units(self, [data], [*self.controls, *self.states], ChannelError)
        if x0 is None:
            x0 = measured_start(data, self.states)
        return self.simulate(data.time, data, x0, parameters, **options)


def require_model(model: Any, error: type[AeroidError]) -> None:
    """Raise `error` unless `model` is a `Model` or has the `SimulatorModel` interface."""
    if not isinstance(model, (Model, SimulatorModel)):
        raise error(
            f"model: expected an aeroid.Model or a SimulatorModel, got {type(model).__name__}"
        )


def require_states(model: Any, error: type[AeroidError], option: str, reason: str) -> None:
    """Raise `error` naming `option` when `model` is a `Model` without states (`reason`
    says what the option would need them for)."""
    if isinstance(model, Model) and not model.states:
        raise error(
            f"{option}: model {model.name!r} has no states (its outputs follow from the "
            f"controls and parameters alone), so {reason}"
        )


def given_values(x0: Any) -> bool:
    """Whether an initial-state option carries any value (None, empty mappings and empty
    arrays, alone or one per record, carry none)."""
    if x0 is None:
        return False
    if isinstance(x0, Mapping):
        return len(x0) > 0
    if isinstance(x0, (list, tuple)):
        return any(given_values(e) for e in x0)
    return bool(np.size(x0) > 0)
