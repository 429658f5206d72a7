"""RocketPy flights as AeroID models (``pip install "aeroid[rocketpy]"``).

`RocketpyModel` wraps a user callback that builds a ``rocketpy.Flight`` from
a parameter dict, and samples chosen flight quantities on the data's time
grid; it is a stepped black box (`aeroid.SimulatorModel`) with no controls.
`rocketpy_flight_data` samples an existing flight as `FlightData`.

Builders should pass tight ``Flight`` tolerances (``rtol=1e-9, atol=1e-9``):
finite-difference identification differentiates the sampled outputs with
respect to the parameters, and loose adaptive steps make them jagged.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import AdapterError, SimulationError
from ..io.data import FlightData
from ..models.model import SimulationResult, resolve_parameters
from ..support import ReadOnlyDict
from . import INTEGRATOR_OPTIONS, check_options, control_matrix, require, time_grid

__all__ = ["RocketpyModel", "rocketpy_flight_data"]

FloatArray = NDArray[np.float64]
OutputSpec = str | Callable[[Any, FloatArray], ArrayLike]

# Units of common Flight quantities (RocketPy works in SI).
UNITS = {
    "altitude": "m",
    "z": "m",
    "x": "m",
    "y": "m",
    "vx": "m/s",
    "vy": "m/s",
    "vz": "m/s",
    "speed": "m/s",
    "free_stream_speed": "m/s",
    "ax": "m/s^2",
    "ay": "m/s^2",
    "az": "m/s^2",
    "acceleration": "m/s^2",
    "mach_number": "1",
    "dynamic_pressure": "Pa",
    "pressure": "Pa",
    "density": "kg/m^3",
    "w1": "rad/s",
    "w2": "rad/s",
    "w3": "rad/s",
    "angle_of_attack": "deg",
    "path_angle": "deg",
    "attitude_angle": "deg",
    "aerodynamic_drag": "N",
    "net_thrust": "N",
}


def _sample(flight: Any, spec: OutputSpec, name: str, t: FloatArray) -> FloatArray:
    """Values of one flight quantity at the times `t` (attribute name or callable)."""
    if callable(spec):
        try:
            values = np.asarray(spec(flight, t), dtype=np.float64)
        except Exception as exc:
            raise SimulationError(
                f"output {name!r}: the callable raised {type(exc).__name__}: {exc}"
            ) from None
    else:
        fun = getattr(flight, spec, None)
        if fun is None or not callable(fun):
            raise AdapterError(
                f"output {name!r}: a rocketpy Flight has no time function {spec!r} "
                f"(e.g. {sorted(UNITS)})"
            )
        try:
            values = np.asarray(fun(t), dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            values = np.empty(0)
        if values.shape != t.shape:  # not vectorised: one call per sample
            values = np.array([float(np.asarray(fun(float(ti))).reshape(-1)[0]) for ti in t])
    if values.shape != t.shape:
        raise SimulationError(
            f"output {name!r}: expected {t.size} values, got shape {values.shape}"
        )
    return values


def _check_span(flight: Any, t: FloatArray, who: str) -> None:
    t0 = float(getattr(flight, "t_initial", 0.0))
    t1 = float(getattr(flight, "t_final", math.inf))
    if t[0] < t0 - 1e-9 or t[-1] > t1 + 1e-9:
        raise SimulationError(
            f"{who}: the time grid [{t[0]:.6g}, {t[-1]:.6g}] s leaves the flight's span "
            f"[{t0:.6g}, {t1:.6g}] s; shorten the grid or let the flight run longer"
        )


class RocketpyModel:
    """Rocket flights built from parameters by a user callback, sampled on a time grid.

    Parameters
    ----------
    builder : callable
        ``builder(params, **flight_options) -> rocketpy.Flight``, with
        ``params`` a dict of every parameter's value.
    parameters : mapping of str to float
        Parameter names with their nominal values.
    outputs : mapping of str to str or callable
        ``{name: quantity}`` with quantity the name of a ``Flight`` time
        function (``"altitude"``, ``"vz"``, ``"speed"``, ``"az"``, ...) or a
        callable ``f(flight, t) -> values`` for anything else.
    flight_options : mapping, optional
        Extra keyword arguments for `builder` (for example a maximum time).
    name : str
        Label used in messages and reports.

    Notes
    -----
    The model has no controls and no states. `simulate` accepts the
    integrator options of `Model.simulate` (``method``, ``substeps``,
    ``rtol``, ``atol``) so generic callers can pass them; RocketPy's own
    tolerances are the builder's business, and these are ignored.
    """

    def __init__(
        self,
        builder: Callable[..., Any],
        parameters: Mapping[str, float],
        outputs: Mapping[str, OutputSpec],
        *,
        flight_options: Mapping[str, Any] | None = None,
        name: str = "rocketpy",
    ) -> None:
        require("rocketpy", "rocketpy")
        if not callable(builder):
            raise AdapterError("builder: expected a callable builder(params) -> rocketpy.Flight")
        params: dict[str, float] = {}
        for key, value in dict(parameters or {}).items():
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise AdapterError(
                    f"parameter {key!r}: nominal value {value!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise AdapterError(f"parameter {key!r}: nominal value {value!r} is not finite")
            params[str(key)] = v
        if not outputs:
            raise AdapterError("outputs: give at least one {name: quantity} to sample")
        for key, spec in outputs.items():
            if not (callable(spec) or (isinstance(spec, str) and spec)):
                raise AdapterError(
                    f"output {key!r}: expected a Flight attribute name or a callable, got {spec!r}"
                )
        if not isinstance(name, str) or not name:
            raise AdapterError(f"name: expected a non-empty string, got {name!r}")
        self.builder = builder
        self.parameters: Mapping[str, float] = ReadOnlyDict(params)
        self.output_specs: Mapping[str, OutputSpec] = MappingProxyType(dict(outputs))
        self.flight_options: Mapping[str, Any] = MappingProxyType(dict(flight_options or {}))
        self.name = name
        self.controls: tuple[str, ...] = ()
        self.outputs: tuple[str, ...] = tuple(str(k) for k in outputs)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(self.parameters)

    @property
    def output_names(self) -> tuple[str, ...]:
        return self.outputs

    @property
    def n_outputs(self) -> int:
        return len(self.outputs)

    @property
    def n_controls(self) -> int:
        return 0

    def __repr__(self) -> str:
        return f"RocketpyModel({self.name!r}, parameters={dict(self.parameters)}, outputs={list(self.outputs)})"

    def flight(self, parameters: Any = None) -> Any:
        """Build the ``rocketpy.Flight`` for a parameter dict (merged onto the nominal values)."""
        p = resolve_parameters(self, parameters, error=SimulationError)
        try:
            flight = self.builder(dict(p), **self.flight_options)
        except Exception as exc:
            raise SimulationError(
                f"the builder of {self.name!r} failed for parameters {p}: {type(exc).__name__}: {exc}"
            ) from exc
        if not hasattr(flight, "t_final"):
            raise AdapterError(
                f"the builder of {self.name!r} returned {type(flight).__name__}, not a rocketpy.Flight"
            )
        return flight

    def simulate(
        self,
        time: ArrayLike,
        controls: Any = None,
        x0: Any = None,
        parameters: Any = None,
        **options: Any,
    ) -> SimulationResult:
        """Build the flight for `parameters` and sample the outputs on `time`.

        Raises
        ------
        SimulationError
            The builder fails, an output is not finite, or the grid extends
            beyond the flight.
        """
        check_options(options, INTEGRATOR_OPTIONS, f"{self.name}.simulate")
        t = time_grid(time)
        control_matrix(t, controls, ())  # validates the shape of anything given
        if x0 is not None and not (isinstance(x0, Mapping) and not x0):
            raise SimulationError(
                f"x0: model {self.name!r} has no states; the builder sets the initial conditions"
            )
        flight = self.flight(parameters)
        _check_span(flight, t, self.name)
        y = np.column_stack([_sample(flight, self.output_specs[o], o, t) for o in self.outputs])
        bad = ~np.all(np.isfinite(y), axis=1)
        if bad.any():
            raise SimulationError(
                f"flight of {self.name!r} gave non-finite outputs at t = {t[int(np.argmax(bad))]:.6g} s"
            )
        return SimulationResult(
            t, np.zeros((t.size, 0)), y, np.zeros((t.size, 0)), (), self.outputs, ()
        )

    def simulate_data(
        self, data: FlightData, *, x0: Any = None, parameters: Any = None, **options: Any
    ) -> SimulationResult:
        """Simulate on a flight record's time grid."""
        return self.simulate(data.time, None, x0, parameters, **options)


def rocketpy_flight_data(
    flight: Any,
    *,
    time: ArrayLike | None = None,
    sample_rate: float = 10.0,
    channels: Sequence[str] | Mapping[str, OutputSpec] = ("altitude", "vz", "speed", "az"),
    units: Mapping[str, str] | None = None,
) -> FlightData:
    """Sample a ``rocketpy.Flight`` as `FlightData`.

    Parameters
    ----------
    flight : rocketpy.Flight
    time : array_like, optional
        Sample times; default: from the flight's start to its end at `sample_rate`.
    sample_rate : float
        Samples per second when `time` is not given.
    channels : sequence of str or mapping of str to str or callable
        Flight time functions to sample, by attribute name; a mapping renames
        them (``{"h_m": "altitude"}``) or gives callables ``f(flight, t)``.
    units : mapping of str to str, optional
        Unit labels overriding the SI defaults of known quantities.

    Returns
    -------
    FlightData
        With metadata ``source="rocketpy"``, the flight's end time and apogee.
    """
    if not hasattr(flight, "t_final"):
        raise AdapterError(f"flight: expected a rocketpy.Flight, got {type(flight).__name__}")
    if time is None:
        if not (
            isinstance(sample_rate, int | float) and math.isfinite(sample_rate) and sample_rate > 0
        ):
            raise AdapterError(
                f"sample_rate: expected a positive number of Hz, got {sample_rate!r}"
            )
        t0, t1 = float(flight.t_initial), float(flight.t_final)
        n = math.floor((t1 - t0) * sample_rate + 1e-9) + 1
        t = t0 + np.arange(n) / float(sample_rate)
    else:
        t = time_grid(time)
    _check_span(flight, t, "rocketpy_flight_data")
    mapping: dict[str, OutputSpec] = (
        {str(k): v for k, v in channels.items()}
        if isinstance(channels, Mapping)
        else {str(c): str(c) for c in channels}
    )
    if not mapping:
        raise AdapterError("channels: name at least one flight quantity")
    data = {name: _sample(flight, spec, name, t) for name, spec in mapping.items()}
    unit = {
        name: UNITS[spec]
        for name, spec in mapping.items()
        if isinstance(spec, str) and spec in UNITS
    }
    unit.update({k: v for k, v in dict(units or {}).items() if k in data})
    meta = {"source": "rocketpy", "t_final": float(flight.t_final)}
    apogee = getattr(flight, "apogee", None)
    if isinstance(apogee, int | float) and math.isfinite(apogee):
        meta["apogee"] = float(apogee)
    return FlightData(t, data, unit, meta)
