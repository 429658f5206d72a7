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

import difflib
import importlib
import inspect
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ...errors import AeroidError, ConfigError
from .._options import stage_flights
from ._check_common import (
    _NAMED,
    _generators,
    _hint,
    _ModelNames,
    _Problems,
)
from ._file_checks import (
    _channel_needs,
    _check_files,
    _check_simulated_channels,
)
from .config import (
    CampaignConfig,
    SimulatedSource,
    validate_options,
)

__all__ = ["check_campaign", "preflight"]


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
        "aeroid.pipeline.plans.planning",
        "aeroid.pipeline.running.runner",
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
    for module in ("aeroid.pipeline.stages.library_stages", "aeroid.pipeline.stages"):
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
        from .._code import module_file

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
        from .. import _code
    except ImportError:
        from ..stages import resolve_callable

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
        raw = (_without_flights(config.stages.get(step))) or {}
        if names is not None:
            _check_names(step, stage, raw, names, problems)
        if stage == "propagate":
            _check_metric(step, opts, base_dir, allowed, names, problems)
        else:
            _check_code_fields(step, opts, base_dir, allowed, problems)
        if stage == "infer":
            _check_infer_size(step, opts, problems)
        if model is not None:
            _check_simulate_options(step, opts, model, problems)
    _check_generators(config, allowed, problems)
    needs = None if names is None else _channel_needs(options, names, pipeline is None)
    _check_simulated_channels(config, needs, problems)
    _check_files(config, base_dir, needs, problems)


# -- stage options ------------------------------------------------------------------------


def _stage_options(
    config: CampaignConfig, pipeline: Any, problems: _Problems
) -> dict[tuple[str, str], Any]:
    """(step, stage) -> validated options of every step that runs; faults noted."""
    from ..stages import STAGES

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
            # keyed by the stage's current name, whichever name the pipeline used
            raw, _ = stage_flights(configured.get(step), where=f"stages.{step}")
            out[(step, stage.name)] = validate_options(
                stage.options, raw, source=config.source, where=f"stages.{step}"
            )
        except ConfigError as exc:
            problems.add_lines(str(exc))
    return out


# Posterior evaluations (one simulation each) an infer step may ask for per flight: each
# count has its own bound, but their product can still ask for years of simulation.
_MAX_EVALUATIONS = 10**9


def _check_infer_size(step: str, opts: Any, problems: _Problems) -> None:
    # unset counts at their least (the library's defaults are at least these), so only
    # a request that cannot run in any case is refused
    walkers = getattr(opts, "n_walkers", None) or 2
    steps = getattr(opts, "n_steps", None) or 1
    ensembles = getattr(opts, "n_ensembles", None) or 1
    total = walkers * steps * ensembles
    if total > _MAX_EVALUATIONS:
        problems.add(
            f"stages.{step}",
            f"n_walkers x n_steps x n_ensembles = {walkers} x {steps} x {ensembles} = "
            f"{total:.3g} simulations a flight, over the {_MAX_EVALUATIONS:.0e} a run can "
            "finish (days at a millisecond each); use fewer steps or walkers",
        )


def _check_simulate_options(step: str, opts: Any, model: Any, problems: _Problems) -> None:
    """A step's ``simulate_options`` values, by the library's own check: a bad method,
    tolerance, substep count or control interpolation would fail every flight."""
    from ...models.model import check_simulate_options

    given = getattr(opts, "simulate_options", None)
    if given is None:
        return
    try:
        check_simulate_options(given, model, ConfigError, name=f"stages.{step}.simulate_options")
    except ConfigError as exc:
        where, _, fault = str(exc).partition(": ")
        problems.add(where, fault)


def _without_flights(values: Any) -> dict[str, Any] | None:
    try:
        return stage_flights(values)[0]
    except ConfigError:
        return None  # `_stage_options` reports it


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
