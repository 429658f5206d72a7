"""Planning a campaign: every task and its key, computed from the config alone.

`plan` turns a config into tasks whose keys are computed from keys only
(file digests, options, model fingerprint, seeds), before anything runs;
`plan_stream` computes the same tasks a flight at a time, and `stored_plan`
reads the keys a store keeps for unchanged inputs (`plan_cache`);
`resolve_model` finds the vehicle model a config names.
"""

from __future__ import annotations

import contextlib
import gc
import json
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...errors import AeroidError, ConfigError, PipelineError
from ...support import record_warnings, replay_warnings
from .. import _code
from .._options import stage_flights
from ..definition import Pipeline, Step, resolve_pipeline
from ..keys import Canonical, canonical_json, keyed_text, stable_int
from ..stages import STAGES
from ..storage.store import parse
from ..vehicle import keyed_fingerprint
from ._flights import _flight_model, _flight_sources, _iter_flight_sources  # noqa: F401 (tests)
from .config import CampaignConfig, FileFlights, load_config, validate_options
from .plan_checks import (
    BUILTIN_MODELS,
    _check_flight_models,
    _check_imports,
    _check_model_import,
    _check_selected,
    _check_selected_names,
    _warn_old_names,
    resolve_model,
)
from .task import Task

if TYPE_CHECKING:
    from ..storage.store import ResultStore
    from .plan_cache import PlannedTask

__all__ = [
    "BUILTIN_MODELS",
    "Plan",
    "PlanStream",
    "Task",
    "plan",
    "plan_stream",
    "resolve_model",
    "store_argument",
    "stored_plan",
]


@dataclass
class Plan:
    """Every task of a campaign, in dependency order."""

    config: CampaignConfig
    pipeline: Pipeline
    tasks: list[Task]
    flights: list[str]
    # digest of everything the keys depend on (`PlanStream.inputs`)
    inputs: str | None = None

    @property
    def report_task(self) -> Task | None:
        last = [t for t in self.tasks if t.flight is None]
        return last[-1] if last else None


# -- planning -----------------------------------------------------------------------------


def plan(
    config: CampaignConfig | str | Path,
    *,
    pipeline: Pipeline | None = None,
    allow_imports: bool = False,
) -> Plan:
    """Compute every task and its key from the config alone (nothing runs).

    ``module:attribute`` models and metrics import and run code: refused with a
    `ConfigError` unless `allow_imports` or the config's ``allow_imports: true``.
    """
    with _no_cyclic_gc():  # see `PlanStream._tasks`
        stream = plan_stream(config, pipeline=pipeline, allow_imports=allow_imports)
        tasks = list(stream)
    return Plan(
        config=stream.config,
        pipeline=stream.pipeline,
        tasks=tasks,
        flights=stream.flights,
        inputs=stream.inputs,
    )


@contextlib.contextmanager
def _no_cyclic_gc() -> Iterator[None]:
    paused = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if paused:
            gc.enable()


@dataclass
class _Setup:
    """What every flight's tasks share: the checked config, pipeline, options and model."""

    config: CampaignConfig
    pipeline: Pipeline
    pipe_ref: dict[str, Any] | None
    steps: list[Step]
    enabled: set[str]
    selected: dict[str, list[str]]
    fingerprint: dict[str, Any]
    model_ref: dict[str, Any]
    step_stage: dict[str, str]  # step -> the stage's stored name
    documents: dict[str, tuple[dict[str, Any], dict[str, Any]]]  # (as keyed, as run)
    run_options: dict[str, dict[str, Any]]
    briefs: dict[str, tuple[tuple[str, str], ...]]
    # step -> the user's code its tasks run besides the model's (`_code.step_code`)
    code: dict[str, dict[str, Any]]


def _setup(
    config: CampaignConfig | str | Path,
    *,
    pipeline: Pipeline | None,
    allow_imports: bool,
    check_flights: bool = True,
) -> _Setup:
    """Resolve and check what every flight's tasks share (`check_flights`: run the
    pre-flight checks of every flight too, which may read each flight's file)."""
    if not isinstance(config, CampaignConfig):
        config = load_config(config)
    allowed = allow_imports or config.allow_imports
    pipe_ref: dict[str, Any] | None
    try:  # the file named in front of what the config's model or pipeline got wrong
        if pipeline is None:
            pipeline, pipe_ref = resolve_pipeline(
                config.pipeline, config.base_dir, allow_imports=allowed
            )
        else:
            pipe_ref = None
        _check_model_import(config, allowed)
        model = resolve_model(config.model, config.base_dir)
    except ConfigError as exc:
        if str(exc).startswith(config.source):
            raise
        raise ConfigError(f"{config.source}: {exc}") from None
    if check_flights:
        # every mistake the config shows (names, files, channels), listed in one error
        _check_flight_models(config, model, pipeline, allowed)
    known = {s.name for s in pipeline.steps}
    for name in config.stages:
        if name not in known:
            raise ConfigError(
                f"{config.source}: stages.{name}: unknown stage; pipeline {pipeline.name!r} has "
                f"{', '.join(s.name for s in pipeline.steps)}"
            )
    steps = pipeline.enabled(config.stages)
    enabled = {s.name for s in steps}
    chosen = {
        s.name: stage_flights(config.stages.get(s.name), where=f"{config.source}: stages.{s.name}")
        for s in steps
    }
    selected = {name: only for name, (_, only) in chosen.items() if only is not None}
    _check_selected(config, pipeline, selected)
    options = {
        s.name: validate_options(
            STAGES[s.stage_name].options,
            chosen[s.name][0],
            source=config.source,
            where=f"stages.{s.name}",
        )
        for s in steps
    }
    _warn_old_names(config, steps)
    _check_imports(config, options, allowed)
    # the stage's stored name: where its results live (a renamed stage keeps its old one)
    step_stage = {s.name: STAGES[s.stage_name].key_name for s in steps}
    # the same for every flight: (options as keyed, options as run)
    documents = {
        s.name: (options[s.name].key_document(), options[s.name].task_document()) for s in steps
    }
    return _Setup(
        config=config,
        pipeline=pipeline,
        pipe_ref=pipe_ref,
        steps=steps,
        enabled=enabled,
        selected=selected,
        fingerprint=keyed_fingerprint(model, config.model, config.base_dir),
        model_ref={"spec": config.model, "base_dir": config.base_dir},
        step_stage=step_stage,
        documents=documents,
        # a load task's run options are made per flight: they add its file's loader options
        run_options={
            name: _run_options(opts, how)
            for name, (opts, how) in documents.items()
            if step_stage[name] != "load"
        },
        briefs=_briefs_wanted(pipeline, enabled),
        code={
            s.name: _code.step_code(STAGES[s.stage_name], options[s.name], config.base_dir)
            for s in steps
        },
    )


class PlanStream:
    """A campaign's tasks computed one flight at a time, in plan order.

    What a plan holds for all its flights at once, a stream holds for one:
    iterating it yields each flight's tasks, then the campaign tasks, and keeps
    of a flight only its name and the keys a campaign step takes (and the load
    key, to refuse a flight listed twice). A consumer that writes or counts the
    tasks as they come (``aeroid status``) thus holds a small, fixed amount a
    flight. Iterated once; `flights` fills as it goes.

    Attributes
    ----------
    config : CampaignConfig
    pipeline : Pipeline
    flights : list of str
        The flights planned so far (all of them once iterated).
    inputs : str
        Digest of everything the keys depend on (`plan_cache.inputs_digest`):
        a stored plan made from the same inputs has the same tasks.
    """

    def __init__(self, setup: _Setup, files: list[tuple[int, Path, FileFlights]], inputs: str):
        self._setup = setup
        self._files = files
        self.config = setup.config
        self.pipeline = setup.pipeline
        self.flights: list[str] = []
        self.inputs = inputs
        self._started = False

    def __iter__(self) -> Iterator[Task]:
        if self._started:
            raise PipelineError("a plan stream is iterated once; plan again to iterate again")
        self._started = True
        return self._tasks()

    @property
    def stages(self) -> set[str]:
        """The stored names of the stages the tasks run (where their results live)."""
        return set(self._setup.step_stage.values())

    @property
    def has_campaign_tasks(self) -> bool:
        """Whether campaign steps (a report, a database) follow the flights' tasks."""
        return any(s in self.pipeline.campaign_steps for s in self._setup.steps)

    def input_files(self) -> list[Path]:
        """The files the campaign reads: its config, pipeline file and flight files."""
        out = [Path(self.config.source)] if Path(self.config.source).is_file() else []
        out += [path for _, path, _ in self._files]
        ref = self._setup.pipe_ref
        if ref is not None and ref.get("file"):
            out.append(Path(ref["file"]))
        return list(dict.fromkeys(out))

    def _tasks(self) -> Iterator[Task]:
        # a plan makes a few objects a task and no reference cycles: the cyclic
        # collector, which walks every live object each time it runs, made planning
        # superlinear (6.1 s for 100,000 flights with it, 3.3 s without)
        with _no_cyclic_gc():
            yield from _tasks(self._setup, self._files, self.flights)

    def batches(self, size: int = 1000) -> Iterator[list[Task]]:
        """The tasks in lists of at most `size` (a flight's tasks may straddle two)."""
        batch: list[Task] = []
        for task in self:
            batch.append(task)
            if len(batch) >= size:
                yield batch
                batch = []
        if batch:
            yield batch


def plan_stream(
    config: CampaignConfig | str | Path,
    *,
    pipeline: Pipeline | None = None,
    allow_imports: bool = False,
) -> PlanStream:
    """The tasks of `plan`, computed as they are iterated (see `PlanStream`).

    The config, pipeline, options and every flight's pre-flight checks are
    checked here, before the first task; a flight file's own problems (one
    listed twice, a segment search that finds nothing) come as it is reached.
    """
    from .plan_cache import inputs_digest

    setup = _setup(config, pipeline=pipeline, allow_imports=allow_imports)
    files = setup.config.expand_files()
    # stat the files before their contents are read: a file that changes in between
    # gets a new signature, and a stored plan made now is never found for it
    return PlanStream(setup, files, inputs_digest(setup, files))


def stored_plan(
    store: ResultStore, config: CampaignConfig, *, allow_imports: bool = False
) -> list[PlannedTask] | None:
    """The tasks of `config` as a plan of the same inputs stored them in `store`
    (`plan_cache`), or None: then plan. Runs none of the pre-flight checks of the
    flights (a stored plan's campaign passed them); a config that does not resolve
    gives None, and planning reports the problem. Old option names warn as planning does."""
    from . import plan_cache

    with record_warnings() as seen:
        try:
            setup = _setup(config, pipeline=None, allow_imports=allow_imports, check_flights=False)
            files = setup.config.expand_files()
        except AeroidError:
            return None
    found = plan_cache.load(store, plan_cache.inputs_digest(setup, files))
    if found is not None:
        replay_warnings(seen)
    return found


def _tasks(
    setup: _Setup, files: list[tuple[int, Path, FileFlights]], flights: list[str]
) -> Iterator[Task]:
    """Every task of the campaign, a flight at a time; `flights` receives the names."""
    config, pipeline, selected = setup.config, setup.pipeline, setup.selected
    documents, step_stage, briefs = setup.documents, setup.step_stage, setup.briefs
    fingerprint, model_ref, pipe_ref = setup.fingerprint, setup.model_ref, setup.pipe_ref
    memo: dict[int, Any] = {}  # keyed_text's: every flight shares the options and the model
    flight_steps = [s for s in setup.steps if s in pipeline.flight_steps]
    campaign_steps = [s for s in setup.steps if s in pipeline.campaign_steps]
    # the per-flight steps whose keys campaign steps take: kept, one list a step
    taken = {up for s in campaign_steps for up in s.inputs.values() if up in setup.enabled}
    step_keys: dict[str, list[str | None]] = {name: [] for name in taken}
    names: set[str] = set()
    loaded: dict[str, str] = {}  # load key -> the flight that has it
    own_models: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {}  # JSON -> fingerprint, ref
    source_texts: dict[int, bytes] = {}
    load_pieces: dict[str, tuple[list[tuple[str, bytes]], dict[str, Any]]] = {}
    for flight in _iter_flight_sources(config, source_texts, files):
        name, source, loader_opts = flight.name, flight.source, flight.loader
        flight_fingerprint, flight_model_ref = fingerprint, model_ref
        if flight.model is not None:
            text = canonical_json(flight.model).decode()
            if text not in own_models:
                own = resolve_model(flight.model, config.base_dir)
                own_models[text] = (
                    keyed_fingerprint(own, flight.model, config.base_dir),
                    {"spec": flight.model, "base_dir": config.base_dir},
                )
            flight_fingerprint, flight_model_ref = own_models[text]
        base = name
        k = 2
        while name in names:
            name, k = f"{base}#{k}", k + 1
        names.add(name)
        flights.append(name)
        keys: dict[str, str] = {}
        flight_id: int | None = None
        for step in flight_steps:
            if step.name in selected and name not in selected[step.name]:
                continue  # the step runs on the flights its `flights` names only
            stage = STAGES[step.stage_name]
            opts, how = documents[step.name]  # `how`: with the execution-only options
            upstream: dict[str, Any] = {}
            made: Canonical | None = None  # a simulated flight's load options, as keyed
            if step.stage_name == "load":
                if source["kind"] == "file":
                    opts = {**opts, **{k: v for k, v in loader_opts.items() if v is not None}}
                    upstream = {"file": "sha256:" + source["sha256"]}
                    run_opts = _run_options(opts, how)
                else:
                    upstream = {"simulated": "sha256:" + source["sha256"]}
                    made, run_opts = _simulated_load(
                        load_pieces, step.name, opts, how, source["spec"], source_texts
                    )
            else:
                run_opts = setup.run_options[step.name]
            for role, up in step.inputs.items():
                if up in keys:
                    upstream[role] = keys[up]
            if stage.names_flight:  # its record shows the flight's name and file
                upstream["flight"] = f"{name}:{Path(source.get('path', '')).name}"
            seed = None
            if stage.seeded:
                assert flight_id is not None
                seed = {"seed": config.seed, "spawn_key": [flight_id]}
            key, canonical = keyed_text(
                record_type=stage.record_type,
                stage=stage.key_name,
                stage_version=stage.version,
                options=opts if made is None else made,
                upstream=upstream,
                model=flight_fingerprint if stage.uses_model else None,
                seed=seed,
                # a file's load options are its own: no use memoising them
                memo=None if step.stage_name == "load" and source["kind"] == "file" else memo,
                code=setup.code.get(step.name),
            )
            if step.stage_name == "load":
                flight_id = stable_int(key)
                if key in loaded:
                    # the same data twice would be fitted twice and listed twice
                    what = (
                        f"({source['path']}) has the same contents and loader options as"
                        if source["kind"] == "file"
                        else "is the same simulated flight as"
                    )
                    raise ConfigError(
                        f"{config.source}: flights: {name!r} {what} {loaded[key]!r}; "
                        "list each flight once"
                    )
                loaded[key] = name
            keys[step.name] = key
            yield Task(
                key=key,
                step=step.name,
                stage=stage.key_name,
                flight=name,
                options=run_opts,
                upstream={r: v for r, v in upstream.items() if r in step.inputs},
                upstream_stages={r: step_stage[u] for r, u in step.inputs.items() if u in keys},
                canonical=canonical,
                model_ref=flight_model_ref if stage.uses_model else None,
                seed=seed,
                source=source if step.stage_name == "load" or stage.names_flight else None,
                pipeline_ref=pipe_ref,
                briefs=briefs.get(step.name, ()),
                code_dir=_code_dir(setup, step.name, config),
            )
        for up, kept in step_keys.items():
            kept.append(keys.get(up))
    _check_selected_names(config, selected, flights)
    for step in campaign_steps:
        stage = STAGES[step.stage_name]
        opts = documents[step.name][0]
        upstream = {
            # None where a step ran on some flights only (`flights` in its options)
            role: list(step_keys[up])
            for role, up in step.inputs.items()
            if up in setup.enabled
        }
        key, canonical = keyed_text(
            record_type=stage.record_type,
            stage=stage.key_name,
            stage_version=stage.version,
            options={**opts, "flights": flights},
            upstream=upstream,
            model=fingerprint if stage.uses_model else None,
            seed=None,
            code=setup.code.get(step.name),
        )
        yield Task(
            key=key,
            step=step.name,
            stage=stage.key_name,
            flight=None,
            options=setup.run_options[step.name],
            upstream=upstream,
            upstream_stages={
                r: step_stage[u] for r, u in step.inputs.items() if u in setup.enabled
            },
            canonical=canonical,
            model_ref=model_ref if stage.uses_model else None,
            pipeline_ref=pipe_ref,
            flights=tuple(flights),
            code_dir=_code_dir(setup, step.name, config),
        )


def _code_dir(setup: _Setup, step: str, config: CampaignConfig) -> str | None:
    """The config's folder where `step`'s options name code in it (`_code.step_code`)."""
    named = any(k.startswith("options.") for k in setup.code.get(step, {}))
    return str(config.base_dir) if named and config.base_dir else None


def _simulated_load(
    cache: dict[str, tuple[list[tuple[str, bytes]], dict[str, Any]]],
    step: str,
    opts: Mapping[str, Any],
    how: Mapping[str, Any],
    spec: dict[str, Any],
    texts: dict[int, bytes],
) -> tuple[Canonical, dict[str, Any]]:
    """A simulated flight's load options as keyed (their canonical text, the flight's
    spec spliced into the step's options serialised once) and as run."""
    if step not in cache:
        base = {k: v for k, v in opts.items() if k != "simulated"}
        pieces = [
            (k, json.dumps(k, ensure_ascii=False).encode() + b":" + canonical_json(v))
            for k, v in base.items()
        ]
        cache[step] = (pieces, _run_options(base, how))
    pieces, base_run = cache[step]
    # popped once used: a spec's id may be reused once the stream lets it go
    text = texts.pop(id(spec), None) or canonical_json(spec)
    every = sorted([*pieces, ("simulated", b'"simulated":' + text)])
    keyed = Canonical(b"{" + b",".join(p for _, p in every) + b"}")
    # run with the spec as its text reads back: mappings in sorted order, as keyed
    return keyed, dict(sorted({**base_run, "simulated": json.loads(text)}.items()))


def _run_options(opts: Mapping[str, Any], how: Mapping[str, Any]) -> dict[str, Any]:
    """The options a task runs with, exactly as keyed (mappings in sorted order), so a
    rerun from the stored document sees the same order as the first run."""
    result: dict[str, Any] = json.loads(canonical_json({**how, **opts}))
    return result


def _briefs_wanted(pipeline: Pipeline, enabled: set[str]) -> dict[str, tuple[tuple[str, str], ...]]:
    """Per-flight step -> the (campaign stage, role) briefs campaign steps take of its
    results (`Stage.brief`)."""
    wanted: dict[str, list[tuple[str, str]]] = {}
    for step in pipeline.campaign_steps:
        if step.name not in enabled or STAGES[step.stage_name].brief is None:
            continue
        for role, up in step.inputs.items():
            if up in enabled:
                wanted.setdefault(up, []).append((step.stage_name, role))
    return {up: tuple(dict.fromkeys(pairs)) for up, pairs in wanted.items()}


def store_argument(store: str | Path) -> str:
    """A store given on the command line or to `run`: a URL as is, a folder made absolute."""
    location = parse(store)
    return location.root if location.is_url else str(Path(location.root).resolve())
