"""Checks of a whole campaign before its first task: every mistake the config alone shows.

`check_campaign` looks at the config together with the model and the pipeline
it names: names in stage options that the model lacks (parameters, states,
outputs, controls), metric and generator names, flight files that are missing
or are not regular files (a directory, a device, a FIFO: found by ``stat``,
never opened), and channels the model needs that a flight file's header lacks.
It reads headers only (a CSV file's first line, a Parquet schema, a MATLAB
file's table of contents), so it takes milliseconds where a run would have
found the same mistake minutes in. Every problem found is listed in one
`ConfigError`, a line each: ``file: key.path: fault; did you mean ...?``.
"""

from __future__ import annotations

import csv
import difflib
import glob
import importlib
import inspect
import os
import stat
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import AeroidError, ConfigError
from .config import (
    CampaignConfig,
    ChannelEntry,
    FileFlights,
    SimulatedSource,
    validate_options,
)

__all__ = ["check_campaign", "preflight"]

_MAX_PROBLEMS = 50  # lines in one error; a glob of a thousand bad files says so once
_HEADER_BYTES = 64 * 1024  # a CSV header (with its comment lines) is shorter than this
_CSV_SUFFIXES = (".csv", ".txt", ".dat")
_PARQUET_SUFFIXES = (".parquet", ".pq")
# what `aeroid.load_flight_test` tries when no time column is named
_TIME_CANDIDATES = ("time", "t", "Time", "TIME", "time_s", "Time (s)", "t_s")
_MATLAB_NUMERIC = frozenset(
    {
        "double",
        "single",
        "logical",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
    }
)
# stages whose library function reads the flight's controls and outputs
_READS_DATA = frozenset({"identify", "filter", "validate", "infer", "frequency", "sensitivities"})

# (stage, option) -> which of the model's names the option's entries are
# ("parameter", "state", "output", "control"; "output or state" for either)
_NAMED: dict[tuple[str, str], str] = {
    ("identify", "parameters"): "parameter",
    ("identify", "bounds"): "parameter",
    ("identify", "x0"): "state",
    ("identify", "estimate_x0"): "state",
    ("identify", "estimate_bias"): "output or state",
    ("identify", "outputs"): "output",
    ("identify", "weights"): "output",
    ("identify", "process_noise"): "state",
    ("identify", "measurement_noise"): "output",
    ("identify", "estimate_process_noise"): "state",
    ("filter", "process_noise"): "state",
    ("filter", "measurement_noise"): "output",
    ("validate", "outputs"): "output",
    ("infer", "parameters"): "parameter",
    ("infer", "priors"): "parameter",  # the old name of `parameters`
    ("infer", "noise"): "output",
    ("infer", "outputs"): "output",
    ("design", "parameters"): "parameter",
    ("design", "noise"): "output",
    ("frequency", "inputs"): "control",
    ("frequency", "outputs"): "output",
    ("sensitivities", "parameters"): "parameter",
    ("sensitivities", "noise"): "output",
    ("sensitivities", "outputs"): "output",
}


@dataclass(frozen=True)
class _ModelNames:
    name: str
    parameter: tuple[str, ...]
    state: tuple[str, ...] | None  # None: an external simulator has no named states
    control: tuple[str, ...]
    output: tuple[str, ...]
    nominal: Mapping[str, float]

    @classmethod
    def of(cls, model: Any) -> _ModelNames:
        params = getattr(model, "parameters", None) or {}
        states = getattr(model, "states", None)
        outputs = getattr(model, "output_names", None) or getattr(model, "outputs", None) or ()
        return cls(
            name=str(getattr(model, "name", "model")),
            parameter=tuple(str(p) for p in params),
            state=None if states is None else tuple(str(s) for s in states),
            control=tuple(str(c) for c in getattr(model, "controls", ()) or ()),
            output=tuple(str(o) for o in outputs),
            nominal={str(k): v for k, v in dict(params).items()},
        )

    def names(self, kind: str) -> tuple[str, ...] | None:
        if kind == "output or state":
            return None if self.state is None else (*self.output, *self.state)
        found: tuple[str, ...] | None = getattr(self, kind)
        return found


def _hint(name: str, choices: Iterable[str], what: str = "") -> str:
    """'; did you mean X?' for a close match, else the choices (when few enough)."""
    pool = sorted({str(c) for c in choices})
    close = difflib.get_close_matches(name, pool, n=2, cutoff=0.6)
    if close:
        return "; did you mean " + " or ".join(repr(c) for c in close) + "?"
    if pool and len(pool) <= 12:
        return f"; {what or 'expected one of'}: {', '.join(pool)}"
    return ""


class _Problems:
    """The faults found so far, each a line ``source: key.path: fault``."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.lines: list[str] = []

    def add(self, where: str, fault: str) -> None:
        line = f"{self.source}: {where}: {fault}"
        if line not in self.lines:
            self.lines.append(line)

    def add_lines(self, text: str) -> None:
        for line in text.splitlines():
            if line and line not in self.lines:
                self.lines.append(line)

    def raise_any(self) -> None:
        if not self.lines:
            return
        lines = self.lines[:_MAX_PROBLEMS]
        if len(self.lines) > _MAX_PROBLEMS:
            lines.append(f"{self.source}: ... and {len(self.lines) - _MAX_PROBLEMS} more problems")
        raise ConfigError("\n".join(lines))


# -- the entry points -------------------------------------------------------------------------


def check_campaign(
    config: CampaignConfig,
    model: Any,
    pipeline: Any,
    *,
    base_dir: str | Path | None = None,
    allow_imports: bool = False,
) -> None:
    """Check a campaign config against its model, pipeline and flight files; nothing runs.

    Parameters
    ----------
    config : CampaignConfig
        The validated config (`load_config`).
    model : Model or None
        The model the config names (``resolve_model(config.model, base_dir)``);
        None skips the checks of names against the model.
    pipeline : Pipeline or None
        The pipeline the config names; None checks every stage the config lists.
    base_dir : str or Path, optional
        Folder relative paths are resolved from (default: the config file's).
    allow_imports : bool
        Allow ``module:attribute`` metrics and generators (as the config's
        ``allow_imports: true`` does); they are imported to check they exist.

    Raises
    ------
    ConfigError
        Every problem found, one line each naming the file, the key path and
        the fault, with the closest valid names where there are any.
    """
    problems = _Problems(config.source)
    allowed = allow_imports or bool(config.allow_imports)
    _check(config, model, pipeline, Path(base_dir or config.base_dir), allowed, problems)
    problems.raise_any()


def preflight(
    config: str | Path | CampaignConfig, *, allow_imports: bool = False, pipeline: Any = None
) -> None:
    """Load a config, resolve its model and pipeline as a run does, and `check_campaign` it.

    A model or pipeline that cannot be resolved is reported with everything
    else that can be checked without it.

    Parameters
    ----------
    config : str, Path or CampaignConfig
        The config file (or the config already loaded).
    allow_imports : bool
        Allow ``module:attribute`` models, pipelines, metrics and generators
        (as the config's ``allow_imports: true`` does).
    pipeline : Pipeline, optional
        The pipeline to check against (default: the one the config names).

    Raises
    ------
    ConfigError
        Every problem found (see `check_campaign`).
    """
    from .config import load_config

    cfg = config if isinstance(config, CampaignConfig) else load_config(config)
    allowed = allow_imports or bool(cfg.allow_imports)
    problems = _Problems(cfg.source)
    model = None
    if pipeline is None:
        resolve_pipeline = _planning("resolve_pipeline")
        try:
            if "allow_imports" in inspect.signature(resolve_pipeline).parameters:
                pipeline, _ = resolve_pipeline(cfg.pipeline, cfg.base_dir, allow_imports=allowed)
            else:
                pipeline, _ = resolve_pipeline(cfg.pipeline, cfg.base_dir)
        except ConfigError as exc:
            problems.add("pipeline", str(exc))
    if isinstance(cfg.model, str) and ":" in cfg.model and not allowed:
        problems.add("model", _imports_refused(cfg.model, Path(cfg.base_dir)))
    else:
        try:
            model = _planning("resolve_model")(cfg.model, cfg.base_dir)
        except ConfigError as exc:
            problems.add("model", str(exc).removeprefix("model: "))
    _check(cfg, model, pipeline, Path(cfg.base_dir), allowed, problems)
    problems.raise_any()


def _planning(name: str) -> Callable[..., Any]:
    """A planning function from wherever it lives (the runner is being split up)."""
    for module in (
        "aeroid.pipeline.planning",
        "aeroid.pipeline.runner",
        "aeroid.pipeline.definition",
    ):
        try:
            found = getattr(importlib.import_module(module), name, None)
        except ImportError:
            continue
        if callable(found):
            return found
    raise ImportError(f"aeroid.pipeline has no {name}")


def _stage_attr(name: str) -> Any:
    """A name of the built-in stages' modules (the metrics moved with the stages)."""
    for module in ("aeroid.pipeline.library_stages", "aeroid.pipeline.stages"):
        try:
            found = getattr(importlib.import_module(module), name, None)
        except ImportError:
            continue
        if found is not None:
            return found
    raise ImportError(f"aeroid.pipeline has no {name}")


def _imports_refused(spec: str, base_dir: Path) -> str:
    """The engine's words for a ``module:attribute`` name that was not allowed."""
    module = spec.partition(":")[0]
    where: Any = f"the installed module {module!r}"
    try:
        from ._code import module_file

        where = module_file(module, base_dir) or where
    except ImportError:
        pass
    return (
        f"{spec!r} runs Python code from {where}: allow it with `allow_imports: true` "
        "in the config or `--allow-imports` on the command line"
    )


def _resolve_code(spec: str, base_dir: Path, what: str) -> Any:
    """Import ``module:attribute`` the way the engine will (the config's folder first)."""
    try:
        from . import _code
    except ImportError:
        from .stages import resolve_callable

        return resolve_callable(spec, what=what)
    return _code.resolve(spec, str(base_dir), what=what)


def _check(
    config: CampaignConfig,
    model: Any,
    pipeline: Any,
    base_dir: Path,
    allowed: bool,
    problems: _Problems,
) -> None:
    names = None if model is None else _ModelNames.of(model)
    options = _stage_options(config, pipeline, problems)
    for (step, stage), opts in options.items():
        raw = config.stages.get(step) or {}
        if names is not None:
            _check_names(step, stage, raw, names, problems)
        if stage == "propagate":
            _check_metric(step, opts, base_dir, allowed, names, problems)
        else:
            _check_code_fields(step, opts, base_dir, allowed, problems)
    _check_generators(config, allowed, problems)
    needs = None if names is None else _channel_needs(options, names, pipeline is None)
    _check_simulated_channels(config, needs, problems)
    _check_files(config, base_dir, needs, problems)


# -- stage options ------------------------------------------------------------------------


def _stage_options(
    config: CampaignConfig, pipeline: Any, problems: _Problems
) -> dict[tuple[str, str], Any]:
    """(step, stage) -> validated options of every step that runs; faults noted."""
    from .stages import STAGES

    configured = config.stages
    if pipeline is None:
        steps = [(name, name) for name in configured if name in STAGES]
    else:
        known = [s.name for s in pipeline.steps]
        for name in configured:
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                problems.add(
                    f"stages.{name}",
                    f"unknown stage; pipeline {pipeline.name!r} has {', '.join(known)}"
                    + (f"; did you mean {close[0]!r}?" if close else ""),
                )
        steps = [(s.name, s.stage_name) for s in pipeline.enabled(configured)]
    out: dict[tuple[str, str], Any] = {}
    for step, stage_name in steps:
        stage = STAGES.get(stage_name)
        if stage is None:
            continue
        try:
            out[(step, stage_name)] = validate_options(
                stage.options, configured.get(step), source=config.source, where=f"stages.{step}"
            )
        except ConfigError as exc:
            problems.add_lines(str(exc))
    return out


def _entries(value: Any) -> list[str]:
    """The names an option holds: a mapping's keys, a list's items, a single name."""
    if value is None or isinstance(value, bool):
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, Mapping):
        return [str(k) for k in value]
    if isinstance(value, (list, tuple)):
        return [str(v) for v in value if isinstance(v, str)]
    return []


def _check_names(
    step: str, stage: str, raw: Mapping[str, Any], model: _ModelNames, problems: _Problems
) -> None:
    """Names in a step's options (as written: validated already) that the model lacks."""
    for (stage_name, option), kind in _NAMED.items():
        if stage_name != stage:
            continue
        valid = model.names(kind)
        if valid is None:
            continue
        article = "an" if kind[0] in "aeiou" else "a"
        plural = kind.replace(" or ", "s or ") + "s"
        for name in _entries(raw.get(option)):
            if name not in valid:
                problems.add(
                    f"stages.{step}.{option}",
                    f"{name!r} is not {article} {kind} of model {model.name!r}"
                    + _hint(name, valid, f"its {plural}"),
                )
    maneuver = raw.get("maneuver") if stage == "design" else None
    control = maneuver.get("control") if isinstance(maneuver, Mapping) else None
    if isinstance(control, str) and control not in model.control:
        problems.add(
            f"stages.{step}.maneuver.control",
            f"{control!r} is not a control of model {model.name!r}"
            + _hint(control, model.control, "its controls"),
        )


def _check_code_fields(
    step: str, options: Any, base_dir: Path, allowed: bool, problems: _Problems
) -> None:
    """Options a stage declares as ``module:attribute`` code (its ``code_fields``)."""
    for name in getattr(type(options), "code_fields", ()):
        value = getattr(options, name, None)
        if isinstance(value, str) and ":" in value:
            _check_import(f"stages.{step}.{name}", value, base_dir, allowed, problems)


def _check_import(
    where: str, spec: str, base_dir: Path, allowed: bool, problems: _Problems
) -> None:
    if not allowed:
        problems.add(where, _imports_refused(spec, base_dir))
        return
    try:
        obj = _resolve_code(spec, base_dir, what=where.rsplit(".", 1)[-1])
    except AeroidError as exc:
        problems.add(where, str(exc))
        return
    if not callable(obj):
        problems.add(where, f"{spec!r} is not callable")


def _check_metric(
    step: str,
    options: Any,
    base_dir: Path,
    allowed: bool,
    model: _ModelNames | None,
    problems: _Problems,
) -> None:
    metrics: Mapping[str, Callable[[Mapping[str, float]], float]] = _stage_attr("METRICS")
    metric = str(getattr(options, "metric", ""))
    where = f"stages.{step}.metric"
    if ":" in metric:
        _check_import(where, metric, base_dir, allowed, problems)
        return
    if metric not in metrics:
        close = difflib.get_close_matches(metric, list(metrics), n=1)
        problems.add(
            where,
            f"unknown metric {metric!r}"
            + (
                f"; did you mean {close[0]!r}?"
                if close
                else f"; expected one of {', '.join(sorted(metrics))} or 'package.module:function'"
            ),
        )
        return
    if model is not None:
        # a built-in metric reads named parameters: evaluating it at the model's nominal
        # values finds a name the model lacks (any other failure is the values', not ours)
        try:
            metrics[metric](dict(model.nominal))
        except KeyError as exc:
            problems.add(
                where,
                f"{metric} reads the parameter {exc.args[0]!r}, which model "
                f"{model.name!r} lacks" + _hint(str(exc.args[0]), model.parameter),
            )
        except (ArithmeticError, ValueError, TypeError):
            pass


# -- flights ------------------------------------------------------------------------------


def _generators() -> dict[str, Any]:
    from . import synthetic

    registry = getattr(synthetic, "GENERATORS", None)
    if isinstance(registry, Mapping):
        return dict(registry)
    return {"short_period_campaign": synthetic.fly}


def _check_generators(config: CampaignConfig, allowed: bool, problems: _Problems) -> None:
    known = _generators()
    for i, item in enumerate(config.flights):
        if not isinstance(item, SimulatedSource):
            continue
        name = str(item.simulated.generator)
        where = f"flights[{i}].simulated.generator"
        if ":" in name:
            _check_import(where, name, Path(config.base_dir), allowed, problems)
        elif name not in known:
            problems.add(where, f"unknown generator {name!r}" + _hint(name, known))


@dataclass(frozen=True)
class _Needs:
    """The channels every flight must carry for the stages that run."""

    model: str
    controls: tuple[str, ...]
    outputs: tuple[str, ...]  # each of these
    any_output: tuple[str, ...]  # at least one of these (the fit uses those present)


def _channel_needs(
    options: Mapping[tuple[str, str], Any], model: _ModelNames, unknown_pipeline: bool
) -> _Needs:
    stages = {stage for _, stage in options}
    reads = stages & _READS_DATA
    controls = model.control if (reads or unknown_pipeline) else ()
    outputs: list[str] = []
    for (_, stage), opts in options.items():
        named = getattr(opts, "outputs", None) if stage in _READS_DATA else None
        if named:
            outputs += [o for o in named if o in model.output]
        elif stage in ("filter", "infer"):  # these fit every model output
            outputs += list(model.output)
    return _Needs(
        model=model.name,
        controls=controls,
        outputs=tuple(dict.fromkeys(outputs)),
        any_output=model.output if (reads or unknown_pipeline) else (),
    )


def _missing(needs: _Needs, have: Sequence[str]) -> list[str]:
    """Faults of a flight whose channels are `have`."""
    faults = []
    for role, names in (("control", needs.controls), ("output", needs.outputs)):
        for name in names:
            if name not in have:
                faults.append(
                    f"model {needs.model!r} needs the {role} {name!r}, which the flight lacks"
                    + _hint(name, have, "its channels")
                )
    if needs.any_output and not any(o in have for o in needs.any_output):
        faults.append(
            f"the flight has none of model {needs.model!r}'s outputs "
            f"({', '.join(needs.any_output)}); its channels: {', '.join(have)}"
        )
    return faults


def _check_simulated_channels(
    config: CampaignConfig, needs: _Needs | None, problems: _Problems
) -> None:
    if needs is None:
        return
    known = _generators()
    for i, item in enumerate(config.flights):
        if not isinstance(item, SimulatedSource):
            continue
        spec = item.simulated.model_dump(mode="json")
        if spec["generator"] not in known:
            continue
        have = _simulated_channels(spec)
        for fault in _missing(needs, have or []) if have is not None else ():
            problems.add(f"flights[{i}].simulated", fault)


def _simulated_channels(spec: Mapping[str, Any]) -> list[str] | None:
    """The channels a simulated flight carries: one flown for a tenth of a second."""
    from .synthetic import flight_spec, fly

    short = {**spec, "n_flights": 1, "duration": 10.0 / float(spec["sample_rate"])}
    try:
        return sorted(fly(flight_spec(short, 0)).channels)
    except (AeroidError, ValueError, KeyError):
        return None


def _check_files(
    config: CampaignConfig, base_dir: Path, needs: _Needs | None, problems: _Problems
) -> None:
    seen: set[tuple[Path, str]] = set()
    headers: dict[tuple[Path, str | None], _Header | None] = {}
    for i, item in enumerate(config.flights):
        if isinstance(item, SimulatedSource):
            continue
        spec = FileFlights(path=item) if isinstance(item, str) else item
        where = f"flights[{i}]" if isinstance(item, str) else f"flights[{i}].path"
        for key, unit_fault in _unit_faults(spec):
            problems.add(f"flights[{i}].{key}", unit_fault)
        raw = Path(spec.path).expanduser()
        pattern = str(raw if raw.is_absolute() else (base_dir / raw))
        if glob.has_magic(pattern):
            paths = sorted(Path(p) for p in glob.glob(pattern, recursive=True))
            if not paths:
                problems.add(where, f"the pattern {spec.path!r} matches no file")
                continue
        else:
            paths = [Path(pattern)]
        # a file named again with other loader options (another window) is another flight
        options = repr(sorted(spec.loader_options().items()))
        for path in paths:
            if (path, options) in seen:
                continue
            seen.add((path, options))
            fault = _not_a_flight_file(path)
            if fault is not None:
                problems.add(where, fault)
                continue
            uses_log_options = spec.window is not None or spec.segments is not None
            if (
                needs is None
                and spec.channels is None
                and spec.time_column is None
                and not uses_log_options
            ):
                continue
            try:
                header = headers.get((path, spec.time_column))
                if header is None:
                    header = headers[(path, spec.time_column)] = _header(path, spec.time_column)
            except AeroidError as exc:
                problems.add(where, str(exc))
                continue
            except OSError as exc:
                problems.add(where, f"{path}: cannot read it ({exc.strerror or exc})")
                continue
            if header is None:
                continue  # a format whose channels cannot be listed without loading it
            for fault in _file_channel_faults(path, header, spec, needs):
                problems.add(where, fault)
            for key, window_fault in _window_faults(path, header, spec):
                problems.add(f"flights[{i}].{key}", window_fault)


def _not_a_flight_file(path: Path) -> str | None:
    """Why `path` cannot be a flight file (it is never opened here), or None."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        hint = ""
        try:
            with os.scandir(path.parent) as it:
                # a folder of millions of files is not listed whole for a hint
                siblings = [e.name for _, e in zip(range(2000), it, strict=False)]
            hint = _hint(path.name, siblings, "")
            if not hint.startswith("; did you mean"):
                hint = ""
        except OSError:
            pass
        return f"no such file: {path}{hint}"
    except OSError as exc:
        return f"{path}: cannot read it ({exc.strerror})"
    if stat.S_ISREG(st.st_mode):
        return None
    if stat.S_ISDIR(st.st_mode):
        what = "a directory"
    elif stat.S_ISFIFO(st.st_mode):
        what = "a FIFO (named pipe)"
    elif stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode):
        what = "a device"
    else:
        what = "not a regular file"
    return f"{path} is {what}, not a flight file"


def _file_channel_faults(
    path: Path, header: _Header, spec: FileFlights, needs: _Needs | None
) -> list[str]:
    columns = header.columns
    faults: list[str] = []
    if header.has_time:
        if spec.time_column is not None and spec.time_column not in columns:
            faults.append(
                f"{path.name}: time column {spec.time_column!r} not found"
                + _hint(spec.time_column, columns, "its columns")
            )
        elif spec.time_column is None and not any(c in columns for c in _TIME_CANDIDATES):
            faults.append(
                f"{path.name}: no time column (tried {', '.join(_TIME_CANDIDATES[:3])}, ...); "
                f"set time_column; its columns: {', '.join(columns)}"
            )
    time = spec.time_column or next((c for c in _TIME_CANDIDATES if c in columns), None)
    if spec.channels is None:
        have = [c for c in columns if c != time]
    elif _mapped(spec.channels) is not None:
        pairs = _mapped(spec.channels) or {}
        for col in dict.fromkeys(pairs.values()):
            if col not in columns:
                what = "column" if header.has_time else "log channel"
                faults.append(
                    f"{path.name}: channels: {what} {col!r} not found"
                    + _hint(col, columns, "its channels")
                )
        have = list(pairs)
    elif not header.has_time:
        plain_names: Any = spec.channels  # names only: `_mapped` found no entry
        have = _log_channels(path, columns, plain_names, faults)
    else:
        chosen = spec.channels
        wanted = [str(c) for c in chosen]
        for col in wanted:
            if col not in columns:
                faults.append(
                    f"{path.name}: channels: column {col!r} not found"
                    + _hint(col, columns, "its columns")
                )
        have = [str(v) for v in chosen.values()] if isinstance(chosen, Mapping) else wanted
    if needs is not None:
        faults += [f"{path.name}: {f}" for f in _missing(needs, have)]
    return faults


def _mapped(chosen: Any) -> dict[str, str] | None:
    """``{model_name: channel}`` of a channel map with at least one full entry (its
    direction is then fixed); None for a list or a mapping of plain names."""
    if not isinstance(chosen, Mapping) or not any(
        isinstance(v, ChannelEntry) for v in chosen.values()
    ):
        return None
    return {
        str(k): (v.channel if isinstance(v, ChannelEntry) else str(v)) for k, v in chosen.items()
    }


def _unit_faults(spec: FileFlights) -> list[tuple[str, str]]:
    """(key path, fault) for every unit conversion of the channel map that is not known."""
    from ..channel_map import UNIT_CONVERSIONS

    if not isinstance(spec.channels, Mapping):
        return []
    known = sorted(UNIT_CONVERSIONS)
    out = []
    for name, entry in spec.channels.items():
        if isinstance(entry, ChannelEntry) and entry.unit is not None:
            if entry.unit not in UNIT_CONVERSIONS:
                close = difflib.get_close_matches(entry.unit, known, n=2, cutoff=0.6)
                hint = (
                    "; did you mean " + " or ".join(repr(c) for c in close) + "?" if close else ""
                )
                out.append(
                    (
                        f"channels.{name}.unit",
                        f"no known conversion from {entry.unit!r}{hint} "
                        f"(known units: {', '.join(known)})",
                    )
                )
    return out


def _window_faults(path: Path, header: _Header, spec: FileFlights) -> list[tuple[str, str]]:
    """(key path, fault) for a window outside the log, or a window or segmentation the
    log cannot give (a mode or event it lacks, an input it does not carry)."""
    if header.log is None or (spec.window is None and spec.segments is None):
        return []
    from ..channel_map import flight_windows, orient, resolve_window

    log = header.log
    names = list(log.channels)
    if spec.channels is None:
        sources = names
    else:
        chosen = _mapped(spec.channels) or orient(spec.channels, names, table=False)
        sources = list(chosen.values()) if isinstance(chosen, Mapping) else list(chosen)
    sources = [s for s in sources if s in log.channels]
    out: list[tuple[str, str]] = []
    if spec.window is not None:
        try:
            t0, t1, _ = resolve_window(log, spec.window)
        except AeroidError as exc:
            return [("window", f"{path.name}: {exc}")]
        if sources:
            lo = max(float(log.channels[s].time[0]) for s in sources)
            hi = min(float(log.channels[s].time[-1]) for s in sources)
            if t0 < lo or t1 > hi:
                out.append(
                    (
                        "window",
                        f"{path.name}: [{t0:.6g}, {t1:.6g}] s is not inside the span "
                        f"[{lo:.6g}, {hi:.6g}] s that the mapped channels cover",
                    )
                )
    if spec.segments is not None:
        try:
            found = flight_windows(log, spec.segments, channels=spec.channels)
        except AeroidError as exc:
            return [*out, ("segments", f"{path.name}: {exc}")]
        if not found:
            out.append(("segments", f"{path.name}: no manoeuvre window found"))
    return out


def _log_channels(
    path: Path, names: list[str], chosen: list[str] | dict[str, str], faults: list[str]
) -> list[str]:
    """The channels a log's flight will carry, picked as `load_flight_test` picks them: a
    mapping may name the log's channels on either side (``{name: log_channel}`` first)."""
    if isinstance(chosen, Mapping):
        pairs = {str(k): str(v) for k, v in chosen.items()}
        keys_in = all(k in names for k in pairs)
        values_in = all(v in names for v in pairs.values())
        if keys_in and not values_in:  # {log_channel: name}, as for a table
            return list(pairs.values())
        wanted, have = list(pairs.values()), list(pairs)
    else:
        wanted = have = [str(c) for c in chosen]
    for name in wanted:
        if name not in names:
            faults.append(
                f"{path.name}: channels: log channel {name!r} not found"
                + _hint(name, names, "its channels")
            )
    return have


# -- headers --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Header:
    columns: list[str]
    has_time: bool = True  # the columns include the time column (a table, not a log)
    log: Any = None  # the log read (a FlightLog), for the checks of windows


def _header(path: Path, time_column: str | None = None) -> _Header | None:
    """A flight file's column names, from its header only; None for an unknown format."""
    from ..errors import DataFormatError

    log = _log_listing(path, time_column)
    if log is not None:
        return log
    suffix = path.suffix.lower()
    if suffix in _CSV_SUFFIXES:
        return _Header(_csv_header(path))
    if suffix in _PARQUET_SUFFIXES:
        try:
            import pyarrow.parquet as pq

            return _Header([str(n) for n in pq.read_schema(path).names])
        except ImportError:
            return None
        except Exception as exc:  # pyarrow raises many types for a corrupt file
            raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None
    if suffix == ".mat":
        return _Header(_mat_header(path))
    return None


def _log_listing(path: Path, time_column: str | None) -> _Header | None:
    """A flight log's channels (`aeroid.list_channels`, where this aeroid reads logs);
    None when `path` is not a log (a table) or logs cannot be listed."""
    try:
        from ..logs import listing, read_log, sniff_format
    except ImportError:
        return None
    fmt = sniff_format(path)  # the first bytes, then the suffix, as the loader decides
    if fmt is None:
        return None
    log = read_log(path, format=fmt, time_column=time_column)
    names = listing(log).names
    # a log's time axis is the reader's business, not one of the channels
    return _Header([str(n) for n in names], has_time=False, log=log)


def _csv_header(path: Path) -> list[str]:
    """The first line of a CSV file that is not a comment, read without blocking."""
    from ..errors import DataFormatError

    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read it ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the stat
            raise DataFormatError(f"{path}: not a regular file")
        head = fh.read(_HEADER_BYTES)
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not merely a character cut at the end of the read
            raise DataFormatError(f"{path}: not a UTF-8 text file") from None
        text = head[: exc.start].decode("utf-8-sig")
    lines = text.splitlines()
    if len(head) == _HEADER_BYTES and lines:
        lines = lines[:-1]  # the last line read may be cut short
    for row in csv.reader(lines):
        if row and not row[0].lstrip().startswith("#"):
            return [h.strip() for h in row]
    raise DataFormatError(f"{path}: no header line (empty file, or only comments)")


def _mat_header(path: Path) -> list[str]:
    """The channels `aeroid.load_flight_test` makes of a MATLAB file, from its contents table."""
    import scipy.io

    from ..errors import DataFormatError

    try:
        table = scipy.io.whosmat(path)
    except Exception as exc:  # scipy raises ValueError/TypeError/NotImplementedError
        raise DataFormatError(
            f"{path}: not a readable MATLAB file ({exc}); v7.3 (HDF5) files are not supported"
        ) from None
    columns: list[str] = []
    for name, shape, kind in table:
        if name.startswith("__") or kind not in _MATLAB_NUMERIC:
            continue
        dims = [d for d in shape if d != 1]  # loaded with squeeze_me
        if len(dims) == 1 and dims[0] >= 2:
            columns.append(name)
        elif len(dims) == 2:
            # a matrix: one channel per column of its longer orientation
            columns += [f"{name}_{j}" for j in range(min(dims))]
    return columns
