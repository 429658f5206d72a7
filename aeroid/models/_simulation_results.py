"""Simulation records: `SimulationResult` (one run) and `BatchSimulation` (many), re-exported by
`aeroid.models.model` and `aeroid`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import as_float, plain, time_label
from .._records import FrozenState, fmt, markdown_table
from .._value_checks import check_seed
from ..errors import AeroidError, ChannelError, SimulationError
from ..io.data import FlightData, readonly

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class SimulationResult(FrozenState):
    """A simulated trajectory on the requested time grid.

    Attributes
    ----------
    time : ndarray, shape (n_t,)
    states : ndarray, shape (n_t, n_states)
        Empty second axis for black-box simulators that expose no states.
    outputs : ndarray, shape (n_t, n_outputs)
    controls : ndarray, shape (n_t, n_controls)
        The control history that drove the simulation.
    """

    time: FloatArray
    states: FloatArray
    outputs: FloatArray
    controls: FloatArray
    state_names: tuple[str, ...]
    output_names: tuple[str, ...]
    control_names: tuple[str, ...]

    def __post_init__(self) -> None:
        for name in ("time", "states", "outputs", "controls"):
            object.__setattr__(self, name, readonly(getattr(self, name)))
        if self.time.ndim != 1:
            raise SimulationError(
                f"SimulationResult: time must be 1-D, got shape {self.time.shape}"
            )
        # a simulator's rows or columns that do not match its grid and names would
        # surface later as a bare broadcasting error far from the simulator
        for name, names in (
            ("states", self.state_names),
            ("outputs", self.output_names),
            ("controls", self.control_names),
        ):
            shape = getattr(self, name).shape
            want = (self.time.size, len(names))
            if shape != want:
                raise SimulationError(
                    f"SimulationResult: {name} has shape {shape}; {self.time.size} times "
                    f"and {len(names)} {name[:-1]} names {list(names)} need {want}"
                )

    def state(self, name: str) -> FloatArray:
        """History of one state."""
        if name not in self.state_names:
            raise ChannelError(f"state {name!r} not simulated; states: {list(self.state_names)}")
        return self.states[:, self.state_names.index(name)]

    def output(self, name: str) -> FloatArray:
        """History of one output."""
        if name not in self.output_names:
            raise ChannelError(f"output {name!r} not simulated; outputs: {list(self.output_names)}")
        return self.outputs[:, self.output_names.index(name)]

    def summary(self) -> str:
        """A Markdown table of every simulated channel: its range and final value."""
        t = self.time
        head = f"{t.size} samples over {t[-1] - t[0]:.6g} s (t = {t[0]:.6g} to {t[-1]:.6g} s)"
        rows = []
        for kind, names, values in (
            ("state", self.state_names, self.states),
            ("output", self.output_names, self.outputs),
            ("control", self.control_names, self.controls),
        ):
            for j, name in enumerate(names):
                if kind == "output" and name in self.state_names:
                    continue  # an output that is a state is listed once, as the state
                v = values[:, j]
                rows.append((name, kind, fmt(v.min()), fmt(v.max()), fmt(v[-1])))
        table = markdown_table(("channel", "kind", "min", "max", "final"), rows)
        return f"{head}\n\n{table}"

    def to_flight_data(
        self,
        *,
        noise: Mapping[str, float] | None = None,
        seed: int | None = None,
        include_states: bool = False,
        units: Mapping[str, str] | None = None,
    ) -> FlightData:
        """Package the trajectory as `FlightData` (controls plus outputs).

        Parameters
        ----------
        noise : mapping of str to float, optional
            Standard deviation of white Gaussian noise added to named outputs.
        seed : int, optional
            Seed of the noise generator (required when `noise` is given).
        include_states : bool
            Also include states that are not outputs.
        units : mapping of str to str, optional
        """
        channels: dict[str, FloatArray] = {}
        for j, n in enumerate(self.control_names):
            channels[n] = self.controls[:, j]
        if include_states:
            for j, n in enumerate(self.state_names):
                channels[n] = self.states[:, j]
        for j, n in enumerate(self.output_names):
            channels[n] = self.outputs[:, j]
        if noise is not None and not isinstance(noise, Mapping):
            raise SimulationError(
                f"to_flight_data: noise: expected a dict of output -> standard deviation, got "
                f"{type(noise).__name__}"
            )
        if noise:
            unknown = sorted(set(noise) - set(self.output_names))
            if unknown:
                raise ChannelError(f"noise given for unknown outputs {unknown}")
            sigma = {}
            for n, v in noise.items():
                x = as_float(v)
                if x is None or not (np.isfinite(x) and x >= 0.0):
                    raise SimulationError(
                        f"to_flight_data: noise[{n!r}]: expected a standard deviation >= 0, "
                        f"got {plain(v)}"
                    )
                sigma[n] = x
            if check_seed(seed, SimulationError, "to_flight_data: seed") is None:
                raise SimulationError("to_flight_data: noise needs a seed for reproducibility")
            rng = np.random.default_rng(seed)
            for n in self.output_names:  # fixed order keeps the stream reproducible
                if n in sigma:
                    channels[n] = channels[n] + sigma[n] * rng.standard_normal(self.time.size)
        return FlightData(self.time, channels, dict(units or {}))


@dataclass(frozen=True, eq=False)
class BatchSimulation(FrozenState):
    """Trajectories of a batch of parameter vectors.

    ``states`` (batch, n_t, n_states), ``outputs`` (batch, n_t, n_outputs),
    ``ok`` marks members that integrated to the end with finite values,
    ``fail_time`` gives the first non-finite time of the others (NaN if ok)
    and ``failure`` says, per member, which state or output failed and when
    (empty if ok).
    """

    time: FloatArray
    states: FloatArray
    outputs: FloatArray
    ok: NDArray[np.bool_]
    fail_time: FloatArray
    failure: tuple[str, ...] = ()


def _model_name(model: Any) -> str:
    return str(getattr(model, "name", type(model).__name__))


def simulator_problem(model: Any, result: Any, n_times: int, *, finite: bool = True) -> str | None:
    """What is wrong with what a simulator's ``simulate`` returned for `n_times` times,
    in words (None if nothing): not a result, outputs of the wrong shape, or (with
    `finite`) the first output and time that are not finite."""
    outputs = getattr(result, "outputs", None)
    if outputs is None:
        return f"its simulate returned {type(result).__name__}, not a SimulationResult"
    names = list(getattr(model, "outputs", ()))
    try:
        y = np.asarray(outputs, dtype=np.float64)
    except (TypeError, ValueError):
        return "its simulate returned outputs that are not numbers"
    if y.shape != (n_times, len(names)):
        return (
            f"its simulate returned outputs of shape {y.shape}; {n_times} times and the "
            f"{len(names)} outputs {names} need ({n_times}, {len(names)})"
        )
    bad = ~np.isfinite(y)
    if finite and bad.any():
        row = int(np.argmax(bad.any(axis=1)))
        col = int(np.argmax(bad[row]))
        time = getattr(result, "time", None)
        when = (
            f"t = {time_label(np.asarray(time)[row])} s"
            if time is not None and np.size(time) == n_times
            else f"sample {row}"
        )
        return f"output {names[col]!r} is not finite from {when} (value {y[row, col]})"
    return None


def simulator_outputs(
    model: Any, run: Callable[[], Any], n_times: int, *, finite: bool = True
) -> FloatArray:
    """The outputs (`n_times`, n_outputs) of ``run()``, a call of `model`'s simulate; a
    `SimulationError` naming the model and what went wrong if it raised something other
    than an AeroID error, or returned something `simulator_problem` refuses."""
    try:
        result = run()
    except AeroidError:
        raise
    except Exception as exc:  # a simulator's own failure, named at the boundary
        raise SimulationError(
            f"model {_model_name(model)!r}: its simulate raised {type(exc).__name__}: {exc}"
        ) from exc
    problem = simulator_problem(model, result, n_times, finite=finite)
    if problem is not None:
        raise SimulationError(f"model {_model_name(model)!r}: {problem}")
    return np.asarray(result.outputs, dtype=np.float64)
