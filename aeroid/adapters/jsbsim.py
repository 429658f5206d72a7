"""JSBSim aircraft as AeroID models (``pip install "aeroid[jsbsim]"``).

`JsbsimModel` maps named parameters, controls and outputs onto JSBSim
properties and flies the aircraft on the data's time grid; it is a stepped
black box (`aeroid.SimulatorModel`). `load_jsbsim_output` reads JSBSim's own
CSV (or tab-separated) logs as `FlightData`.

Isolation: every simulation runs in a freshly created ``FGFDMExec``, so
repeated simulations are bit-identical whatever ran before. The aircraft is
loaded from a private temporary copy from which the ``<output>`` elements of
the aircraft file are removed (several stock aircraft, ``c172x`` among them,
declare a CSV log written next to the package and UDP/TCP socket outputs),
data logging is disabled and the output directory points at that temporary
copy, so JSBSim writes nothing into its package directory and opens no
sockets.
"""

from __future__ import annotations

import csv
import math
import os
import shutil
import tempfile
import weakref
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import AdapterError, DataFormatError, SimulationError
from ..io.data import FlightData
from ..models.model import SimulationResult, resolve_parameters
from ..support import ReadOnlyDict
from . import INTEGRATOR_OPTIONS, check_options, control_matrix, require, time_grid

__all__ = ["JsbsimModel", "load_jsbsim_output"]

FloatArray = NDArray[np.float64]

TRIM_MODES = {"longitudinal": 0, "full": 1, "ground": 2, "pullup": 3, "custom": 4, "turn": 5}


def _jsbsim() -> Any:
    return require("jsbsim", "jsbsim")


def _canonical(prop: str) -> str:
    """JSBSim treats ``name[0]`` and ``name`` as the same node."""
    return prop.strip().lstrip("/").replace("[0]", "")


def _quiet(jsb: Any) -> int:
    """Silence JSBSim's console messages; return the previous debug level."""
    base = jsb.FGJSBBase()
    old = int(base.debug_lvl)
    base.debug_lvl = 0
    return old


def _restore(jsb: Any, level: int) -> None:
    jsb.FGJSBBase().debug_lvl = level


class JsbsimModel:
    """A JSBSim aircraft whose properties are mapped to named parameters, controls and outputs.

    Parameters
    ----------
    aircraft : str
        Aircraft name under ``<root>/aircraft`` (for example ``"c172x"``).
    parameters : mapping of str to (str, float)
        ``{name: (property, nominal)}``: writable properties identification may vary.
    controls : mapping of str to str, optional
        ``{name: property}``: writable properties driven by the control channels.
    outputs : mapping of str to str
        ``{name: property}``: readable properties sampled on the time grid.
    initial_conditions : mapping of str to float, optional
        Property values set before initialisation, usually ``ic/...`` ones
        (``ic/h-sl-ft``, ``ic/vc-kts``, ...); other writable properties (such
        as ``propulsion/set-running``) are set again after initialisation.
    dt : float, optional
        JSBSim integration step in seconds. Default: the largest step not
        above JSBSim's own (1/120 s) that divides the sample interval of a
        uniform grid, so outputs are read exactly at the sample times; on a
        non-uniform grid (or with a `dt` that does not divide it) outputs are
        interpolated linearly from the JSBSim steps.
    root : str or Path, optional
        JSBSim data root (default: the package's ``jsbsim.get_default_root_dir()``).
    trim : str or int or bool, optional
        Trim before each manoeuvre: ``"longitudinal"``, ``"full"`` (or
        True), ``"ground"``, ``"pullup"``, ``"custom"``, ``"turn"`` or the
        JSBSim mode number. The trim is computed at the *nominal* parameter
        values, so every parameter vector starts from the same state (as a
        measured flight does); the parameter values are then written and the
        control samples are added to the trimmed control property values (a
        manoeuvre is a perturbation about trim). Default: no trim; controls
        are written as given.
    name : str, optional
        Label used in messages and reports (default ``"jsbsim:<aircraft>"``).

    Notes
    -----
    Controls are linear between samples and written before every JSBSim step.
    Simulation accepts the integrator options of `Model.simulate` (``method``,
    ``substeps``, ``rtol``, ``atol``) so generic callers can pass them; JSBSim
    integrates with its own schemes and ignores them. ``x0`` of `simulate` is
    a mapping of initial-condition properties overriding `initial_conditions`.

    Raises
    ------
    AdapterError
        JSBSim is not installed, the aircraft does not load, or a property is
        not in JSBSim's property catalogue (or lacks the needed read/write access).
    """

    def __init__(
        self,
        aircraft: str,
        parameters: Mapping[str, tuple[str, float]] | None = None,
        controls: Mapping[str, str] | None = None,
        outputs: Mapping[str, str] | None = None,
        initial_conditions: Mapping[str, float] | None = None,
        *,
        dt: float | None = None,
        root: str | os.PathLike[str] | None = None,
        trim: str | int | bool | None = None,
        name: str | None = None,
    ) -> None:
        jsb = _jsbsim()
        if not isinstance(aircraft, str) or not aircraft:
            raise AdapterError(f"aircraft: expected an aircraft name, got {aircraft!r}")
        self.aircraft = aircraft
        self.name = name or f"jsbsim:{aircraft}"
        self.root = Path(root) if root is not None else Path(jsb.get_default_root_dir())
        self.dt = None if dt is None else float(dt)
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise AdapterError(f"dt: expected a positive step in seconds, got {dt!r}")
        self.trim_mode = _trim_mode(trim)

        params: dict[str, float] = {}
        pprops: dict[str, str] = {}
        for key, spec in dict(parameters or {}).items():
            if not isinstance(spec, tuple | list) or len(spec) != 2:
                raise AdapterError(
                    f"parameter {key!r}: expected (property, nominal value), got {spec!r}"
                )
            prop, nominal = spec
            pprops[str(key)] = _prop_name(prop, f"parameter {key!r}")
            params[str(key)] = _number(nominal, f"parameter {key!r}: nominal value")
        if not outputs:
            raise AdapterError("outputs: give at least one {name: property} to sample")
        self.parameters: Mapping[str, float] = ReadOnlyDict(params)
        self.parameter_properties: Mapping[str, str] = MappingProxyType(pprops)
        self.control_properties: Mapping[str, str] = MappingProxyType(
            {str(k): _prop_name(v, f"control {k!r}") for k, v in dict(controls or {}).items()}
        )
        self.output_properties: Mapping[str, str] = MappingProxyType(
            {str(k): _prop_name(v, f"output {k!r}") for k, v in dict(outputs).items()}
        )
        self.initial_conditions: Mapping[str, float] = MappingProxyType(
            {
                _prop_name(k, "initial condition"): _number(v, f"initial condition {k!r}")
                for k, v in dict(initial_conditions or {}).items()
            }
        )
        self.controls: tuple[str, ...] = tuple(self.control_properties)
        self.outputs: tuple[str, ...] = tuple(self.output_properties)
        clash = sorted(set(self.controls) & set(self.outputs))
        if clash:
            raise AdapterError(f"names {clash} are used both as controls and outputs")

        self._workdir = tempfile.mkdtemp(prefix="aeroid-jsbsim-")
        weakref.finalize(self, shutil.rmtree, self._workdir, True)
        self._aircraft_path = self._prepare_aircraft()
        self._check_properties()

    # -- SimulatorModel protocol -------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Parameter names in declaration order."""
        return tuple(self.parameters)

    @property
    def output_names(self) -> tuple[str, ...]:
        return self.outputs

    @property
    def n_outputs(self) -> int:
        return len(self.outputs)

    @property
    def n_controls(self) -> int:
        return len(self.controls)

    def __repr__(self) -> str:
        return (
            f"JsbsimModel({self.aircraft!r}, parameters={dict(self.parameters)}, "
            f"controls={list(self.controls)}, outputs={list(self.outputs)})"
        )

    def simulate(
        self,
        time: ArrayLike,
        controls: Any = None,
        x0: Any = None,
        parameters: Any = None,
        **options: Any,
    ) -> SimulationResult:
        """Fly the aircraft on `time` and sample the outputs there.

        Parameters
        ----------
        time : array_like, shape (n_t,)
            Strictly increasing sample times (JSBSim's clock starts at ``time[0]``).
        controls : array_like, mapping or FlightData, optional
            Control samples (n_t, n_controls); default zero.
        x0 : mapping of str to float, optional
            Initial-condition properties overriding `initial_conditions`.
        parameters : mapping or result, optional
            Parameter values merged onto the nominal ones.
        **options
            ``method``, ``substeps``, ``rtol``, ``atol`` are accepted and ignored.

        Returns
        -------
        SimulationResult
            No states (JSBSim's state is internal); outputs (n_t, n_outputs).
        """
        check_options(options, INTEGRATOR_OPTIONS, f"{self.name}.simulate")
        t = time_grid(time)
        u = control_matrix(t, controls, self.controls)
        p = resolve_parameters(self, parameters, error=SimulationError)
        ic = dict(self.initial_conditions)
        if x0 is not None:
            if not isinstance(x0, Mapping):
                raise SimulationError(
                    f"x0: a JSBSim model takes a mapping of initial-condition properties "
                    f"(e.g. {{'ic/q-rad_sec': 0.0}}), got {type(x0).__name__}"
                )
            extra = {_prop_name(k, "x0"): _number(v, f"x0 {k!r}") for k, v in x0.items()}
            self._check_access(extra, "x0", write=True)
            ic.update(extra)
        y = self._fly(t, u, p, ic)
        bad = ~np.all(np.isfinite(y), axis=1)
        if bad.any():
            raise SimulationError(
                f"JSBSim simulation of {self.name!r} produced non-finite outputs at "
                f"t = {t[int(np.argmax(bad))]:.6g} s"
            )
        return SimulationResult(t, np.zeros((t.size, 0)), y, u, (), self.outputs, self.controls)

    def simulate_data(
        self, data: FlightData, *, x0: Any = None, parameters: Any = None, **options: Any
    ) -> SimulationResult:
        """Simulate on a flight record's time grid with its measured controls."""
        data.require(self.controls, role="control")
        return self.simulate(data.time, data, x0, parameters, **options)

    # -- internals ---------------------------------------------------------------
    def _prepare_aircraft(self) -> Path:
        """Copy the aircraft folder into the work dir without its ``<output>`` elements."""
        src = self.root / "aircraft" / self.aircraft
        main = src / f"{self.aircraft}.xml"
        if not main.is_file():
            available = sorted(
                p.name
                for p in (self.root / "aircraft").glob("*")
                if (p / f"{p.name}.xml").is_file()
            )
            raise AdapterError(
                f"aircraft {self.aircraft!r}: no {main}; aircraft under {self.root / 'aircraft'}: "
                f"{available[:40]}"
            )
        dest_root = Path(self._workdir) / "aircraft"
        dest = dest_root / self.aircraft
        shutil.copytree(src, dest)
        try:
            tree = ET.parse(main)
        except ET.ParseError as exc:
            raise AdapterError(f"aircraft {self.aircraft!r}: cannot parse {main}: {exc}") from None
        top = tree.getroot()
        logs = [el for el in list(top) if el.tag == "output"]
        for el in logs:
            top.remove(el)
        if logs:
            tree.write(dest / f"{self.aircraft}.xml", encoding="utf-8", xml_declaration=True)
        return dest_root

    def executive(self, dt: float | None = None) -> Any:
        """A fresh ``jsbsim.FGFDMExec`` with this aircraft loaded, silent and without outputs.

        For direct work with JSBSim's properties (trimming, static
        evaluations) under the same isolation as the simulations: the
        aircraft comes from the sanitised copy, logging is disabled and the
        output directory is private. No initial conditions are applied.
        JSBSim's console messages stay silenced (its debug level is global
        and is left at 0). With `dt` (s), the executive steps at `dt` from the
        start: the flight controls' components (an actuator's rate limit, a lag
        filter) take their step when the aircraft loads, and keep JSBSim's
        default 1/120 s if the step is set only afterwards.
        """
        jsb = _jsbsim()
        _quiet(jsb)
        return self._exec(jsb, dt)

    def _exec(self, jsb: Any, dt: float | None = None) -> Any:
        fdm = jsb.FGFDMExec(str(self.root), None)
        fdm.set_debug_level(0)
        if dt is not None:
            fdm.set_dt(dt)
        fdm.set_output_path(self._workdir)
        fdm.disable_output()
        ok = fdm.load_model_with_paths(
            self.aircraft,
            str(self._aircraft_path),
            str(self.root / "engine"),
            str(self.root / "systems"),
        )
        if not ok:
            raise AdapterError(f"JSBSim could not load aircraft {self.aircraft!r} from {self.root}")
        fdm.disable_output()
        return fdm

    def _check_properties(self) -> None:
        jsb = _jsbsim()
        old = _quiet(jsb)
        try:
            entries = self._exec(jsb).get_property_catalog()
        finally:
            _restore(jsb, old)
        catalog: dict[str, str] = {}
        for entry in entries:
            prop, _, access = entry.rpartition(" ")
            catalog[_canonical(prop)] = access.strip("()")
        self._catalog = catalog
        self._check_access(self.parameter_properties, "parameter", write=True)
        self._check_access(self.control_properties, "control", write=True)
        self._check_access(self.output_properties, "output", write=False)
        self._check_access({k: k for k in self.initial_conditions}, "initial condition", write=True)

    def _check_access(self, props: Mapping[str, Any], role: str, *, write: bool) -> None:
        for key, prop in props.items():
            name = prop if isinstance(prop, str) else key
            access = self._catalog.get(_canonical(name))
            if access is None:
                near = _similar(_canonical(name), self._catalog)
                raise AdapterError(
                    f"{role} {key!r}: property {name!r} is not in the property catalogue of "
                    f"JSBSim aircraft {self.aircraft!r}"
                    + (f"; similar properties: {near}" if near else "")
                )
            need = "W" if write else "R"
            if need not in access:
                raise AdapterError(
                    f"{role} {key!r}: property {name!r} of aircraft {self.aircraft!r} is "
                    f"{'read-only' if write else 'write-only'} ({access})"
                )

    def _step(self, t: FloatArray) -> tuple[float, int, NDArray[np.int64] | None]:
        """JSBSim step, number of steps, and the step index of every sample.

        The sample indices are None when the grid is not a whole number of
        steps; the outputs are then interpolated linearly between steps.
        """
        rel = t - t[0]
        h = np.diff(t)
        base = self.dt if self.dt is not None else 1.0 / 120.0
        ratio = h / base
        if np.all(np.abs(ratio - np.round(ratio)) <= 1e-9 * np.maximum(ratio, 1.0)):
            idx = np.round(rel / base).astype(np.int64)
            return base, int(idx[-1]), idx
        uniform = np.ptp(h) <= 1e-9 * float(np.mean(h))
        if self.dt is None and uniform:
            spacing = float(rel[-1]) / (t.size - 1)  # robust to rounding of a shifted grid
            per = max(1, math.ceil(spacing / base - 1e-9))
            idx = np.arange(t.size, dtype=np.int64) * per
            return spacing / per, int(idx[-1]), idx
        return base, math.ceil(float(rel[-1]) / base - 1e-9), None

    def _fly(
        self, t: FloatArray, u: FloatArray, p: Mapping[str, float], ic: Mapping[str, float]
    ) -> FloatArray:
        jsb = _jsbsim()
        old = _quiet(jsb)
        try:
            # the step is set as the aircraft loads: its flight controls' rate limits and
            # lags take theirs then, and keep JSBSim's default 1/120 s if set only later
            stepping = self._step(t)
            return self._run(jsb, self._exec(jsb, stepping[0]), t, u, p, ic, stepping)
        finally:
            _restore(jsb, old)

    def _run(
        self,
        jsb: Any,
        fdm: Any,
        t: FloatArray,
        u: FloatArray,
        p: Mapping[str, float],
        ic: Mapping[str, float],
        stepping: tuple[float, int, Any],
    ) -> FloatArray:
        # `fdm` steps at `stepping`'s dt already (set as it loaded)
        dt, n_steps, sample_steps = stepping
        pm = fdm.get_property_manager()

        def node(prop: str) -> Any:
            n = pm.get_node(prop)
            if n is None:
                n = pm.get_node(_canonical(prop))
            if n is None:  # pragma: no cover - the catalogue check makes this unreachable
                raise AdapterError(f"JSBSim property {prop!r} not found")
            return n

        par_nodes = {k: node(v) for k, v in self.parameter_properties.items()}
        ctl_nodes = [node(self.control_properties[c]) for c in self.controls]
        out_nodes = [node(self.output_properties[o]) for o in self.outputs]
        for prop, value in ic.items():
            node(prop).set_double_value(value)
        mode = self.trim_mode
        trimmed = mode is not None
        for k, n in par_nodes.items():
            n.set_double_value(self.parameters[k] if trimmed else p[k])
        if not trimmed:
            for n, v in zip(ctl_nodes, u[0], strict=True):
                n.set_double_value(float(v))
        if not fdm.run_ic():
            raise SimulationError(f"JSBSim could not initialise {self.name!r} (run_ic failed)")
        for prop, value in ic.items():
            if not _canonical(prop).startswith("ic/"):
                node(prop).set_double_value(value)
        base = np.zeros(len(ctl_nodes))
        if mode is not None:
            try:
                fdm.do_trim(mode)
            except jsb.TrimFailureError as exc:
                raise SimulationError(
                    f"JSBSim trim ({_trim_label(mode)}) of {self.name!r} failed "
                    f"at the nominal parameters: {exc}"
                ) from None
            base = np.array([n.get_double_value() for n in ctl_nodes])
            for k, n in par_nodes.items():
                n.set_double_value(p[k])
            for n, b, v in zip(ctl_nodes, base, u[0], strict=True):
                n.set_double_value(float(b + v))

        rel = t - t[0]
        step_t = np.arange(n_steps) * dt
        # Controls at every step start, linear between samples.
        uu = np.zeros((n_steps, u.shape[1]))
        for j in range(u.shape[1]):
            uu[:, j] = np.interp(step_t, rel, u[:, j]) + base[j]
        y_steps: list[list[float]] = [[n.get_double_value() for n in out_nodes]]
        for step in range(n_steps):
            for n, v in zip(ctl_nodes, uu[step], strict=True):
                n.set_double_value(float(v))
            fdm.run()
            y_steps.append([n.get_double_value() for n in out_nodes])
        ys = np.asarray(y_steps, dtype=np.float64).reshape(n_steps + 1, len(out_nodes))
        if sample_steps is not None:
            return np.ascontiguousarray(ys[sample_steps])
        grid = np.arange(n_steps + 1) * dt
        return np.column_stack([np.interp(rel, grid, ys[:, j]) for j in range(ys.shape[1])])

    # Pickling ships the configuration; the work directory is rebuilt on arrival.
    def __getstate__(self) -> dict[str, Any]:
        return {
            "aircraft": self.aircraft,
            "parameters": {
                k: (self.parameter_properties[k], v) for k, v in self.parameters.items()
            },
            "controls": dict(self.control_properties),
            "outputs": dict(self.output_properties),
            "initial_conditions": dict(self.initial_conditions),
            "dt": self.dt,
            "root": str(self.root),
            "trim": self.trim_mode,
            "name": self.name,
        }

    def __setstate__(self, state: dict[str, Any]) -> None:
        aircraft = state.pop("aircraft")
        parameters = state.pop("parameters")
        controls = state.pop("controls")
        outputs = state.pop("outputs")
        ics = state.pop("initial_conditions")
        self.__init__(aircraft, parameters, controls, outputs, ics, **state)  # type: ignore[misc]


def _trim_mode(trim: str | int | bool | None) -> int | None:
    if trim is None or trim is False:
        return None
    if trim is True:
        return TRIM_MODES["full"]
    if isinstance(trim, str) and trim.lower() in TRIM_MODES:
        return TRIM_MODES[trim.lower()]
    if isinstance(trim, int) and trim in TRIM_MODES.values():
        return int(trim)
    raise AdapterError(
        f"trim: expected None, True or one of {list(TRIM_MODES)} (or its JSBSim number), got {trim!r}"
    )


def _trim_label(mode: int) -> str:
    return next(k for k, v in TRIM_MODES.items() if v == mode)


def _prop_name(prop: Any, what: str) -> str:
    if not isinstance(prop, str) or not prop.strip():
        raise AdapterError(f"{what}: expected a JSBSim property path, got {prop!r}")
    return prop.strip()


def _number(value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise AdapterError(f"{what}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise AdapterError(f"{what}: value {v!r} is not finite")
    return v


def _similar(prop: str, catalog: Mapping[str, str]) -> list[str]:
    import difflib

    return difflib.get_close_matches(prop, list(catalog), n=3, cutoff=0.6)


# -- JSBSim logs ------------------------------------------------------------------


def load_jsbsim_output(path: str | os.PathLike[str]) -> FlightData:
    """Read a JSBSim CSV (or tab-separated) output log as `FlightData`.

    Column headers are kept verbatim as channel names (``"Q (deg/s)"``,
    ``"Alpha (deg)"``, properties by their path) and the unit in a trailing
    parenthesis becomes the channel's unit label. The ``Time`` column is the
    time axis; a row repeating the previous time stamp (JSBSim logs the
    initial condition and may log it again at the first step) replaces it.

    Raises
    ------
    DataFormatError
        Unreadable file, bad cells, or time running backwards (a log holding
        several runs), naming the file and row.
    """
    p = Path(path)
    if not p.is_file():
        raise DataFormatError(f"{p}: no such file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{p}: not a UTF-8 text file ({exc})") from None
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if len(lines) < 3:
        raise DataFormatError(f"{p}: expected a header and at least 2 data rows")
    delimiter = "\t" if "\t" in lines[0] and "," not in lines[0] else ","
    rows = list(csv.reader(lines, delimiter=delimiter))
    header = [h.strip() for h in rows[0]]
    if "Time" not in header:
        raise DataFormatError(f"{p}: no 'Time' column; is this a JSBSim log? header: {header[:6]}")
    dupes = sorted({h for h in header if header.count(h) > 1})
    if dupes:
        raise DataFormatError(f"{p}: duplicate column names {dupes}")
    values = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:]):
        cells = [c.strip() for c in row]
        if cells and cells[-1] == "" and len(cells) == len(header) + 1:
            cells = cells[:-1]  # trailing delimiter
        if len(cells) != len(header):
            raise DataFormatError(
                f"{p}: row {i + 2} has {len(cells)} cells, header has {len(header)}"
            )
        try:
            values[i] = [float(c) for c in cells]
        except ValueError:
            bad = next(j for j, c in enumerate(cells) if not _is_number(c))
            raise DataFormatError(
                f"{p}: row {i + 2}, column {header[bad]!r}: non-numeric cell {cells[bad]!r}"
            ) from None
    ti = header.index("Time")
    time = values[:, ti]
    keep = np.ones(time.size, dtype=bool)
    keep[:-1] = np.diff(time) != 0  # equal stamps: the later row wins
    back = np.flatnonzero(np.diff(time) < 0)
    if back.size:
        raise DataFormatError(
            f"{p}: time runs backwards at row {int(back[0]) + 3} (several runs in one log?)"
        )
    values = values[keep]
    channels = {h: values[:, j] for j, h in enumerate(header) if j != ti}
    units = {}
    for h in channels:
        if h.endswith(")") and "(" in h:
            units[h] = h[h.rindex("(") + 1 : -1].strip()
    try:
        return FlightData(values[:, ti], channels, units, {"source": p.name, "format": "jsbsim"})
    except DataFormatError as exc:
        raise DataFormatError(f"{p}: {exc}") from None


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True
