"""Planning and running a campaign: keys first, cache hits pruned, the rest on Dask.

`plan` turns a config into tasks whose keys are computed from keys only
(file digests, options, model fingerprint, seeds), before anything runs.
`run` prunes the tasks already in the store and, only if something is
left, runs the rest on Dask, named by their keys: by default Dask's local
scheduler over a pool of single-threaded worker processes, or the
`dask.distributed` scheduler given.
A failing task is reported with its error and never committed; its
dependants fail with a pointer to it; other flights carry on.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import json
import os
import platform
import socket
import sys
import threading
import time
import traceback
import uuid
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from ..errors import AeroidError, ConfigError, PipelineError
from .config import CampaignConfig, SimulatedSource, load_config, validate_options
from .definition import Pipeline, load_pipeline, resolve_pipeline
from .keys import canonical_json, file_digest, model_fingerprint, sha256_hex, stable_int, task_key
from .stages import STAGES, StageContext, resolve_callable
from .store import ResultStore, is_url, record_cache, run_store

__all__ = [
    "Plan",
    "RunSummary",
    "Task",
    "execute_chain",
    "execute_part",
    "execute_task",
    "plan",
    "rerun",
    "resolve_model",
    "run",
]

_BLAS_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
}

BUILTIN_MODELS = ("short_period", "first_order")


@dataclass(frozen=True)
class Task:
    """One node of the task graph (plain data, so it travels to workers)."""

    key: str
    step: str
    stage: str
    flight: str | None
    options: dict[str, Any]
    upstream: dict[str, Any]  # role -> key (per flight) or list of keys (campaign)
    upstream_stages: dict[str, str]  # role -> stage name of the upstream step
    document: dict[str, Any]
    model_ref: dict[str, Any] | None = None
    seed: dict[str, Any] | None = None
    source: dict[str, Any] | None = None
    pipeline_ref: dict[str, Any] | None = None
    flights: tuple[str, ...] = ()
    # (campaign stage, role) of each brief of this task's result a campaign task takes
    # (`Stage.brief`); not part of the key or of the stored task
    briefs: tuple[tuple[str, str], ...] = ()

    @property
    def upstream_keys(self) -> list[str]:
        out: list[str] = []
        for v in self.upstream.values():
            out += list(v) if isinstance(v, list) else [v]
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "step": self.step,
            "stage": self.stage,
            "flight": self.flight,
            "options": self.options,
            "upstream": self.upstream,
            "upstream_stages": self.upstream_stages,
            "model_ref": self.model_ref,
            "seed": self.seed,
            "source": self.source,
            "pipeline_ref": self.pipeline_ref,
            "flights": list(self.flights),
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], document: Mapping[str, Any]) -> Task:
        return cls(
            key=doc["key"],
            step=doc["step"],
            stage=doc["stage"],
            flight=doc["flight"],
            options=dict(doc["options"]),
            upstream=dict(doc["upstream"]),
            upstream_stages=dict(doc["upstream_stages"]),
            document=dict(document),
            model_ref=doc.get("model_ref"),
            seed=doc.get("seed"),
            source=doc.get("source"),
            pipeline_ref=doc.get("pipeline_ref"),
            flights=tuple(doc.get("flights", ())),
        )


@dataclass
class Plan:
    """Every task of a campaign, in dependency order."""

    config: CampaignConfig
    pipeline: Pipeline
    tasks: list[Task]
    flights: list[str]

    @property
    def report_task(self) -> Task | None:
        last = [t for t in self.tasks if t.flight is None]
        return last[-1] if last else None


# -- models -----------------------------------------------------------------------------

_MODEL_CACHE: dict[tuple[str, str | None], Any] = {}


def resolve_model(spec: str | Mapping[str, Any], base_dir: str | None = None) -> Any:
    """A model from a built-in name, ``package.module:attribute`` (Model or factory),
    or a mapping that defines an `aeroid.aircraft` model (see `model_from_config`)."""
    from ..model import Model, SimulatorModel

    if isinstance(spec, Mapping):
        text = canonical_json(dict(spec)).decode()
        if (text, None) not in _MODEL_CACHE:
            from ..aircraft import model_from_config
            from ..errors import ModelDefinitionError

            try:
                _MODEL_CACHE[(text, None)] = model_from_config(spec)
            except ModelDefinitionError as exc:
                raise ConfigError(f"model: {exc}") from None
        return _MODEL_CACHE[(text, None)]
    cache_key = (spec, base_dir)
    if cache_key in _MODEL_CACHE:
        return _MODEL_CACHE[cache_key]
    if ":" in spec:
        if base_dir and base_dir not in sys.path:
            sys.path.insert(0, base_dir)
        try:
            obj = resolve_callable(spec, what="model")
        except PipelineError as exc:
            raise ConfigError(str(exc)) from None
    elif spec in BUILTIN_MODELS:
        from .. import catalog

        obj = getattr(catalog, spec)
    else:
        raise ConfigError(
            f"model {spec!r}: expected a built-in model ({', '.join(BUILTIN_MODELS)}) "
            "or 'package.module:attribute'"
        )
    if not isinstance(obj, (Model, SimulatorModel)) and callable(obj):
        try:
            obj = obj()
        except AeroidError:
            raise
        except Exception as exc:
            raise ConfigError(
                f"model {spec!r}: calling it failed: {type(exc).__name__}: {exc}"
            ) from None
    if not isinstance(obj, (Model, SimulatorModel)):
        raise ConfigError(
            f"model {spec!r}: expected a Model (or a function returning one), got {type(obj).__name__}"
        )
    _MODEL_CACHE[cache_key] = obj
    return obj


# -- planning -----------------------------------------------------------------------------


def _flight_sources(config: CampaignConfig) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(flight name, source, loader options) for every flight, in config order."""
    from .synthetic import flight_spec

    files = config.expand_files()
    stems = [p.stem for _, p, _ in files]
    out: list[tuple[str, dict[str, Any], dict[str, Any]]] = []
    for i, item in enumerate(config.flights):
        if isinstance(item, SimulatedSource):
            spec = item.simulated.model_dump(mode="json")
            width = len(str(spec["n_flights"] - 1))
            for j in range(spec["n_flights"]):
                fs = flight_spec(spec, j)
                digest = sha256_hex(canonical_json(fs))
                source = {"kind": "simulated", "spec": fs, "sha256": digest}
                out.append((f"sim-{j:0{width}d}", source, {}))
            continue
        for _, path, loader in (f for f in files if f[0] == i):
            opts = loader.model_dump(mode="json", exclude={"path"})
            name = path.stem
            if stems.count(path.stem) > 1:
                base = Path(config.base_dir)
                name = str(path.relative_to(base)) if path.is_relative_to(base) else str(path)
            try:
                digest = file_digest(path)
            except OSError as exc:
                # unreadable now: the load task fails and says why; nothing is cached
                digest = "unreadable:" + sha256_hex(f"{path}:{exc}".encode())
            out.append((name, {"kind": "file", "path": str(path), "sha256": digest}, opts))
    return out


def plan(
    config: CampaignConfig | str | Path,
    *,
    pipeline: Pipeline | None = None,
) -> Plan:
    """Compute every task and its key from the config alone (nothing runs)."""
    if not isinstance(config, CampaignConfig):
        config = load_config(config)
    pipe_ref: dict[str, Any] | None
    if pipeline is None:
        pipeline, pipe_ref = resolve_pipeline(config.pipeline, config.base_dir)
    else:
        pipe_ref = None
    known = {s.name for s in pipeline.steps}
    for name in config.stages:
        if name not in known:
            raise ConfigError(
                f"{config.source}: stages.{name}: unknown stage; pipeline {pipeline.name!r} has "
                f"{', '.join(s.name for s in pipeline.steps)}"
            )
    steps = pipeline.enabled(config.stages)
    enabled = {s.name for s in steps}
    options = {
        s.name: validate_options(
            STAGES[s.stage_name].options,
            config.stages.get(s.name),
            source=config.source,
            where=f"stages.{s.name}",
        )
        for s in steps
    }
    model = resolve_model(config.model, config.base_dir)
    fingerprint = model_fingerprint(model)
    model_ref = {"spec": config.model, "base_dir": config.base_dir}
    step_stage = {s.name: s.stage_name for s in steps}
    # the same for every flight: (options as keyed, options as run)
    documents = {
        s.name: (options[s.name].key_document(), options[s.name].task_document()) for s in steps
    }
    # a load task's run options are made per flight: they add its file's loader options
    run_options = {
        name: _run_options(opts, how)
        for name, (opts, how) in documents.items()
        if step_stage[name] != "load"
    }
    briefs = _briefs_wanted(pipeline, enabled)

    tasks: list[Task] = []
    flights: list[str] = []
    per_flight_keys: dict[str, dict[str, str]] = {}
    loaded: dict[str, str] = {}  # load key -> the flight that has it
    for name, source, loader_opts in _flight_sources(config):
        base = name
        k = 2
        while name in per_flight_keys:
            name, k = f"{base}#{k}", k + 1
        flights.append(name)
        keys: dict[str, str] = {}
        flight_id: int | None = None
        for step in (s for s in steps if s in pipeline.flight_steps):
            stage = STAGES[step.stage_name]
            opts, how = documents[step.name]  # `how`: with the execution-only options
            upstream: dict[str, Any] = {}
            if step.stage_name == "load":
                if source["kind"] == "file":
                    opts = {**opts, **{k: v for k, v in loader_opts.items() if v is not None}}
                    upstream = {"file": "sha256:" + source["sha256"]}
                else:
                    opts = {**opts, "simulated": source["spec"]}
                    upstream = {"simulated": "sha256:" + source["sha256"]}
                run_opts = _run_options(opts, how)
            else:
                run_opts = run_options[step.name]
            for role, up in step.inputs.items():
                if up in enabled:
                    upstream[role] = keys[up]
            seed = None
            if stage.seeded:
                assert flight_id is not None
                seed = {"seed": config.seed, "spawn_key": [flight_id]}
            key, doc = task_key(
                record_type=stage.record_type,
                stage=stage.name,
                stage_version=stage.version,
                options=opts,
                upstream=upstream,
                model=fingerprint if stage.uses_model else None,
                seed=seed,
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
            tasks.append(
                Task(
                    key=key,
                    step=step.name,
                    stage=stage.name,
                    flight=name,
                    options=run_opts,
                    upstream={r: v for r, v in upstream.items() if r in step.inputs},
                    upstream_stages={
                        r: step_stage[u] for r, u in step.inputs.items() if u in enabled
                    },
                    document=doc,
                    model_ref=model_ref if stage.uses_model else None,
                    seed=seed,
                    source=source if step.stage_name == "load" else None,
                    pipeline_ref=pipe_ref,
                    briefs=briefs.get(step.name, ()),
                )
            )
        per_flight_keys[name] = keys
    for step in (s for s in steps if s in pipeline.campaign_steps):
        stage = STAGES[step.stage_name]
        opts = documents[step.name][0]
        upstream = {
            role: [per_flight_keys[f][up] for f in flights]
            for role, up in step.inputs.items()
            if up in enabled
        }
        key, doc = task_key(
            record_type=stage.record_type,
            stage=stage.name,
            stage_version=stage.version,
            options={**opts, "flights": flights},
            upstream=upstream,
            model=fingerprint if stage.uses_model else None,
            seed=None,
        )
        tasks.append(
            Task(
                key=key,
                step=step.name,
                stage=stage.name,
                flight=None,
                options=run_options[step.name],
                upstream=upstream,
                upstream_stages={r: step_stage[u] for r, u in step.inputs.items() if u in enabled},
                document=doc,
                model_ref=model_ref if stage.uses_model else None,
                pipeline_ref=pipe_ref,
                flights=tuple(flights),
            )
        )
    return Plan(config=config, pipeline=pipeline, tasks=tasks, flights=flights)


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


# -- executing one task (on a worker) -------------------------------------------------------


def _versions() -> dict[str, str]:
    """Versions of the packages that computed and stored a result: those loaded.

    Read from the modules (a few microseconds): asking `importlib.metadata`
    parses every package's metadata, which cost a fresh worker process 80 ms,
    more than three small flights.
    """
    out = {"python": platform.python_version()}
    for pkg in ("aeroid", "numpy", "scipy", "zarr", "dask", "distributed", "pydantic"):
        version = getattr(sys.modules.get(pkg), "__version__", None)
        if isinstance(version, str):
            out[pkg] = version
    return out


def _context(
    task: Task,
    store_root: str,
    upstream_status: tuple[Mapping[str, Any], ...],
    read_root: str | None,
) -> tuple[Any, StageContext, ResultStore, dict[str, str]]:
    """Load a task's inputs (digests checked) and build its stage context."""
    failed = {s["key"]: s for s in upstream_status if s.get("status") == "failed"}
    if task.pipeline_ref is not None:
        load_pipeline(task.pipeline_ref)  # registers any stages the pipeline defines
    stage = STAGES.get(task.stage)
    if stage is None:
        raise PipelineError(f"unknown stage {task.stage!r}")
    store = run_store(store_root)
    reader = store if read_root is None else ResultStore(read_root, create=False)
    inputs: dict[str, Any] = {}
    failures: dict[str, str] = {}
    briefs: dict[str, dict[int, Any]] = {}
    given = {s["key"]: s["briefs"] for s in upstream_status if "briefs" in s}
    for role, ref in task.upstream.items():
        up_stage = task.upstream_stages[role]
        if isinstance(ref, list):
            keys: list[str | None] = []
            name = f"{task.stage}/{role}"
            for i, (flight, k) in enumerate(zip(task.flights, ref, strict=True)):
                if k in failed:
                    keys.append(None)
                    failures.setdefault(flight, _failure_text(failed[k]))
                else:
                    keys.append(k)
                    if k in given and name in given[k]:
                        briefs.setdefault(role, {})[i] = given[k][name]
            inputs[role] = _LazyRecords(reader, up_stage, keys)
        else:
            if ref in failed:
                raise PipelineError(f"upstream {failed[ref]['step']} failed")
            inputs[role] = reader.load(ref, up_stage)
    if stage.library is not None:
        import aeroid

        if not hasattr(aeroid, stage.library):
            raise PipelineError(f"aeroid.{stage.library} is not available in this version")
    model = None
    if task.model_ref is not None:
        model = resolve_model(task.model_ref["spec"], task.model_ref.get("base_dir"))
    seed = None
    if task.seed is not None:
        seed = np.random.SeedSequence(task.seed["seed"], spawn_key=tuple(task.seed["spawn_key"]))
    ctx = StageContext(
        options=_options(task),
        inputs=inputs,
        model=model,
        seed=seed,
        flight=task.flight,
        source=task.source,
        failures=failures,
        flights=task.flights,
        briefs=briefs,
        summarize=stage.brief,
    )
    return stage, ctx, store, failures


class _LazyRecords(Sequence[Any]):
    """Campaign-level inputs: one record per flight (None where it failed), read on access.

    A part that draws one flight's figure reads only that flight's results.
    """

    def __init__(self, reader: ResultStore, stage: str, keys: list[str | None]) -> None:
        self._reader, self._stage, self._keys = reader, stage, keys
        self._loaded: dict[int, Any] = {}

    def __len__(self) -> int:
        return len(self._keys)

    @overload
    def __getitem__(self, index: int) -> Any: ...
    @overload
    def __getitem__(self, index: slice) -> list[Any]: ...
    def __getitem__(self, index: int | slice) -> Any:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = range(len(self._keys))[index]  # IndexError past the end ends iteration
        if i not in self._loaded:
            k = self._keys[i]
            self._loaded[i] = None if k is None else self._reader.load(k, self._stage)
        return self._loaded[i]


def _flatten(statuses: tuple[Any, ...]) -> tuple[Mapping[str, Any], ...]:
    """Statuses passed in by upstream futures: single statuses or lists (chains)."""
    out: list[Mapping[str, Any]] = []
    for s in statuses:
        if isinstance(s, Mapping):
            out.append(s)
        else:
            out.extend(s)
    return tuple(out)


def _options(task: Task) -> Any:
    stage = STAGES[task.stage]
    return stage.options.model_validate(
        {k: v for k, v in task.options.items() if k in stage.options.model_fields}
    )


def n_parts(task: Task) -> int:
    """How many parallel parts a task splits into (1: it runs whole)."""
    stage = STAGES.get(task.stage)
    if stage is None or stage.parts is None or stage.run_part is None or stage.combine is None:
        return 1
    try:
        return max(1, int(stage.parts(_options(task), frozenset(task.upstream))))
    except Exception:
        return 1  # the task itself will report the problem


def execute_part(
    task: Task,
    store_root: str,
    index: int,
    *upstream_status: Any,
    read_root: str | None = None,
    scope: str | None = None,
) -> dict[str, Any]:
    """Compute part `index` of a split task (not stored; its task combines the parts)."""
    record_cache(scope)
    out: dict[str, Any] = {"key": task.key, "part": index}
    try:
        stage, ctx, _, _ = _context(task, store_root, _flatten(upstream_status), read_root)
        t1 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            value = stage.run_part(ctx, index)
        out.update(status="ok", value=value, warnings=_warning_texts(caught))
        out["compute_seconds"] = time.perf_counter() - t1
    except Exception as exc:
        out.update(status="failed", error=_error_text(exc))
    return out


def execute_task(
    task: Task,
    store_root: str,
    *upstream_status: Any,
    read_root: str | None = None,
    scope: str | None = None,
) -> dict[str, Any]:
    """Run one task and commit its result; never raises (a failure is returned).

    `upstream_status` holds the statuses of upstream tasks run in this
    session (single statuses or lists of them) and, for a split task, the
    results of its parts. Records are cached in this process for the run
    `scope` (see `record_cache`).
    """
    record_cache(scope)
    t0 = time.perf_counter()
    status: dict[str, Any] = {"key": task.key, "step": task.step, "flight": task.flight}
    flat = _flatten(upstream_status)
    parts = sorted((s for s in flat if "part" in s), key=lambda s: s["part"])
    upstream = tuple(s for s in flat if "part" not in s)
    try:
        stage, ctx, store, failures = _context(task, store_root, upstream, read_root)
        t1 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            # the library's warnings (an unconverged chain, poor coherence) belong to the
            # task: kept with its status and provenance instead of on a worker's stderr
            warnings.simplefilter("always")
            if parts:
                bad = [p for p in parts if p["status"] != "ok"]
                if bad:
                    raise PipelineError(f"part {bad[0]['part']} failed: {bad[0].get('error')}")
                record = stage.combine(ctx, [p["value"] for p in parts])
                part_seconds = sum(float(p.get("compute_seconds", 0.0)) for p in parts)
            else:
                record = stage.run(ctx)
                part_seconds = 0.0
        t2 = time.perf_counter()
        found = [w for p in parts for w in p.get("warnings", ())] + _warning_texts(caught)
        if found:
            status["warnings"] = list(dict.fromkeys(found))
        provenance = {
            "task": task.to_json(),
            "versions": _versions(),
            "seconds": {"compute": t2 - t1 + part_seconds, "parts": len(parts)},
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "host": platform.node(),
            "warnings": status.get("warnings", []),
        }
        if failures:
            # a report over failed flights is written out but never cached
            status.update(status="computed", cached=False, failures=failures)
        else:
            store.commit(task.stage, task.key, record, task=task.document, provenance=provenance)
            status.update(status="computed", cached=True)
            if task.briefs:
                status["briefs"] = _briefs(task, store)
        status["compute_seconds"] = t2 - t1 + part_seconds
        if task.flight is None and hasattr(record, "markdown"):
            status["markdown"] = record.markdown
            status["rows"] = [list(r) for r in getattr(record, "rows", ())]
            status["columns"] = list(getattr(record, "columns", ()))
            if hasattr(record, "figure_bytes"):  # spares reading them back for the HTML
                status["figures"] = record.figure_bytes()
    except Exception as exc:
        status.update(status="failed", error=_error_text(exc))
        if not isinstance(exc, AeroidError):
            status["traceback"] = traceback.format_exc(limit=6)
    status["seconds"] = time.perf_counter() - t0
    return status


def _briefs(task: Task, store: ResultStore) -> dict[str, Any]:
    """The briefs campaign tasks take of `task`'s committed result (`Stage.brief`).

    They are made from the record as a read of the entry returns it (from this
    run's cache: no read), so they equal what the campaign task would make from
    the store. One that cannot be made is left out: the campaign task then makes
    it itself and reports the problem. So is a None brief (a role the stage reads
    whole), which would only travel for nothing.
    """
    out: dict[str, Any] = {}
    with contextlib.suppress(Exception):
        record = store.load(task.key, task.stage)
        for consumer, role in task.briefs:
            make = STAGES[consumer].brief
            value = None if make is None else make(role, record)
            if value is not None:
                out[f"{consumer}/{role}"] = value
    return out


def execute_chain(
    tasks: list[Task],
    store_root: str,
    parts: list[Mapping[str, Any]],
    *upstream_status: Any,
    scope: str | None = None,
    open_fonts: bool = False,
) -> list[dict[str, Any]]:
    """Run consecutive tasks of one flight in this process, in order; their statuses.

    One Dask task per chain keeps the scheduler's per-task cost off the
    flight's steps; every step is still keyed, committed and reported on its
    own. `parts` are the results of the first task's parts, if it is split.
    `open_fonts` readies this process for the campaign's figures after (see
    `_open_fonts`).
    """
    known: dict[str, Mapping[str, Any]] = {s["key"]: s for s in _flatten(upstream_status)}
    out: list[dict[str, Any]] = []
    for i, t in enumerate(tasks):
        ups = [known[k] for k in dict.fromkeys(t.upstream_keys) if k in known]
        status = execute_task(t, store_root, *ups, *(parts if i == 0 else ()), scope=scope)
        known[t.key] = status
        out.append(status)
    if open_fonts:
        _open_fonts()
    return out


def _warning_texts(caught: list[warnings.WarningMessage]) -> list[str]:
    texts = (f"{w.category.__name__}: {w.message}" for w in caught)
    return list(dict.fromkeys(texts))


def _error_text(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text if isinstance(exc, AeroidError) else f"{type(exc).__name__}: {text}"


def _failure_text(status: Mapping[str, Any]) -> str:
    return f"{status['step']}: {status.get('error', 'failed')}"


# -- running a plan ------------------------------------------------------------------------


@dataclass
class RunSummary:
    """What a run did: per-task status, counts, the report."""

    plan: Plan
    statuses: dict[str, dict[str, Any]]
    report_path: Path | None
    columns: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)

    def count(self, status: str) -> int:
        return sum(1 for t in self.plan.tasks if self.statuses[t.key]["status"] == status)

    @property
    def failed(self) -> int:
        return self.count("failed")

    def task_rows(self) -> list[dict[str, Any]]:
        out = []
        for t in self.plan.tasks:
            s = self.statuses[t.key]
            out.append(
                {
                    "stage": t.step,
                    "flight": t.flight,
                    "key": t.key,
                    "status": s["status"],
                    "error": s.get("error"),
                }
            )
        return out

    def warnings(self) -> list[tuple[Task, str]]:
        """Warnings raised by the tasks computed in this run, task by task."""
        out = []
        for t in self.plan.tasks:
            for w in self.statuses[t.key].get("warnings", ()):
                out.append((t, w))
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "computed": self.count("computed"),
            "cached": self.count("cached"),
            "failed": self.failed,
            "report": None if self.report_path is None else str(self.report_path),
            "report_html": (
                None
                if self.report_path is None or not html_report_path(self.report_path).is_file()
                else str(html_report_path(self.report_path))
            ),
            "tasks": self.task_rows(),
        }


_FROZEN_BY_RUN = False


def _freeze_objects(freeze: bool) -> None:
    """Leave the objects that exist before a run out of garbage collection while it runs.

    Imports leave well over 100 000 long-lived objects that a run never frees,
    and every full collection walks them all (about 0.1 s). In forked workers
    the walk is worse: it writes to, and so copies, every page they share with
    this process. Frozen before the workers fork, they stay frozen there; this
    process unfreezes them when the run ends. Objects someone else froze are
    left as they are.
    """
    global _FROZEN_BY_RUN
    if freeze and (_FROZEN_BY_RUN or gc.get_freeze_count() == 0):
        gc.freeze()  # called again after more imports, it adds the new objects
        _FROZEN_BY_RUN = True
    elif not freeze and _FROZEN_BY_RUN:
        gc.unfreeze()
        _FROZEN_BY_RUN = False


def _workers_default() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _start_method() -> str:
    """How the embedded cluster starts its worker processes.

    ``fork`` on Linux: a worker then starts in a few milliseconds with
    everything this process has imported, instead of a second or more to
    import numpy, scipy and aeroid afresh, which would dominate a campaign's
    run. ``spawn`` elsewhere, when JAX is loaded (it must not be forked), or
    as set by ``AEROID_START_METHOD``.
    """
    chosen = os.environ.get("AEROID_START_METHOD")
    if chosen:
        return chosen
    if sys.platform.startswith("linux") and "jax" not in sys.modules:
        return "fork"
    return "spawn"


_PINNED = False


def _pin_blas() -> None:
    """One BLAS/OpenMP thread in this spawned worker process (the env vars reach only
    libraries not yet loaded, and numpy is loaded as the worker unpickles its work).

    Not for forked workers: after a fork OpenBLAS has no threads, and setting its
    thread count starts them, each spinning for about 0.1 s of CPU before it sleeps.
    Two forked workers on two cores lost a third of their first flight to that.
    They inherit the count from `_blas_pinned` instead.
    """
    global _PINNED
    if _PINNED:
        return
    _PINNED = True
    os.environ.update(_BLAS_ENV)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; spawned workers honour the env
        return
    threadpool_limits(limits=1)


@contextlib.contextmanager
def _blas_pinned(fork: bool) -> Iterator[None]:
    """One BLAS/OpenMP thread in this process while it forks workers, which inherit it.

    Its previous limits come back when the run ends; this process does no
    numerical work meanwhile (a thread of the caller's that does runs on one
    BLAS thread until then).
    """
    if not fork:
        yield
        return
    from threadpoolctl import threadpool_limits

    limiter = threadpool_limits(limits=1)
    try:
        yield
    finally:
        limiter.restore_original_limits()


def _preload(tasks: list[Task]) -> None:
    """Import what the tasks' stages use before the workers fork, so they share it.

    `aeroid` imports its modules on first use; imported here once, the forked
    workers start with them (and their objects frozen, see `_freeze_objects`).
    """
    import importlib

    import aeroid

    stages = [STAGES[t.stage] for t in tasks if t.stage in STAGES]
    for name in dict.fromkeys(s.library for s in stages if s.library):
        getattr(aeroid, name, None)
    if any(s.uses_model for s in stages):
        from .._integrate import import_solvers

        import_solvers()
    for module in dict.fromkeys(m for s in stages for m in s.preload):
        importlib.import_module(module)


def _part_deps(task: Task, index: int, deps: list[Any], owner: Mapping[str, Any]) -> list[Any]:
    """The futures part `index` of a split task waits for (see `Stage.part_flights`)."""
    stage = STAGES.get(task.stage)
    if stage is None or stage.part_flights is None or task.flight is not None:
        return deps
    try:
        flights = stage.part_flights(_options(task), frozenset(task.upstream), index)
    except Exception:
        return deps  # the part itself will report the problem
    if flights is None:
        return deps
    keys = [
        ref[j]
        for ref in task.upstream.values()
        if isinstance(ref, list)
        for j in flights
        if 0 <= j < len(ref)
    ]
    return list(dict.fromkeys(owner[k] for k in keys if k in owner))


def _segments(tasks: list[Task]) -> list[tuple[list[Task], Task | None]]:
    """Split tasks (plan order) into chains of one flight's consecutive steps.

    A split task (it has parts) starts a new chain, whose parts run first;
    campaign tasks are chains of their own. Returns (chain, split task or None).
    """
    out: list[tuple[list[Task], Task | None]] = []
    current: list[Task] = []
    split: Task | None = None
    flight: object = object()
    for t in tasks:
        n = n_parts(t)
        if current and (t.flight != flight or t.flight is None or n > 1):
            out.append((current, split))
            current, split = [], None
        if n > 1:
            split = t
        current.append(t)
        flight = t.flight
    if current:
        out.append((current, split))
    return out


def _chains(
    tasks: list[Task], owner: Mapping[str, Any]
) -> Iterator[tuple[list[Task], Task | None, list[Any]]]:
    """The chains of `_segments`, each with what it waits for: the owners of its upstream
    tasks in `owner` (task key -> what runs it), which the caller fills as it goes."""
    for chain, split in _segments(tasks):
        # identical steps of a pipeline share a key: run once (plans refuse identical flights)
        chain = [t for t in chain if t.key not in owner]
        if not chain:
            continue
        own = {t.key for t in chain}
        deps = list(
            dict.fromkeys(
                owner[k] for t in chain for k in t.upstream_keys if k in owner and k not in own
            )
        )
        yield chain, split, deps


@dataclass
class _Node:
    """One Dask task of a run: a chain of one flight's steps, or one part of a split task."""

    name: str
    call: Callable[..., Any]  # execute_chain or execute_part, with its fixed arguments bound
    deps: list[str]  # the nodes whose results it takes, in order
    chain: list[Task] | None = None  # None for a part
    parts: list[str] = field(default_factory=list)  # a chain's parts, run before it
    part: tuple[Task, int] | None = None


def _early_parts(tasks: list[Task]) -> int:
    """How many parts of the campaign's split tasks wait on a few flights only
    (`Stage.part_flights`), and so run while the other flights do."""
    count = 0
    for t in tasks:
        stage = STAGES.get(t.stage)
        if t.flight is not None or stage is None or stage.part_flights is None:
            continue
        with contextlib.suppress(Exception):  # the task itself will report the problem
            options, roles = _options(t), frozenset(t.upstream)
            count += sum(
                stage.part_flights(options, roles, i) is not None for i in range(n_parts(t))
            )
    return count


def _nodes(tasks: list[Task], store_root: str, scope: str, workers: int) -> list[_Node]:
    """The graph the embedded cluster runs, built as `_run_dask` submits to a scheduler:
    one node per chain (`_segments`), one per part of a split task."""
    # stages that draw preload the plotting module; with no more workers than early
    # parts (the report's detailed figures), every worker draws one of those while the
    # flights run, and readying matplotlib beforehand would cost more than it saves
    draws = any("aeroid.plotting" in STAGES[t.stage].preload for t in tasks if t.stage in STAGES)
    prime = draws and workers > _early_parts(tasks)
    owner: dict[str, str] = {}  # task key -> name of the chain that runs it
    nodes: list[_Node] = []
    for chain, split, deps in _chains(tasks, owner):
        head = chain[0]
        name = f"{head.flight or 'campaign'}-{head.step}-{head.key}"
        parts: list[str] = []
        if split is not None and head is split:
            for i in range(n_parts(split)):
                part: Callable[..., Any] = functools.partial(
                    execute_part, split, store_root, i, scope=scope
                )
                pdeps = _part_deps(split, i, deps, owner)
                nodes.append(_Node(f"{name}-part{i}", part, pdeps, part=(split, i)))
                parts.append(nodes[-1].name)
        run_chain: Callable[..., Any] = functools.partial(
            execute_chain,
            chain,
            store_root,
            scope=scope,
            open_fonts=prime and head.flight is not None,
        )
        nodes.append(_Node(name, run_chain, deps, chain=chain, parts=parts))
        for t in chain:
            owner[t.key] = name
    return nodes


_FONTS_OPEN = False


def _open_fonts() -> None:
    """Ready matplotlib in this worker process: its fonts (dropped at fork) and its first
    figure (about 27 ms; it spares that figure about 15 ms).

    A worker does it after its first flight, in parallel with the other
    workers, when the run has more workers than the report has early parts:
    a worker that has drawn nothing when the flights end would otherwise pay
    it in the trend across flights, which runs after the last flight.
    """
    global _FONTS_OPEN
    if _FONTS_OPEN:
        return
    _FONTS_OPEN = True
    import io

    from matplotlib.figure import Figure

    fig = Figure(figsize=(1.0, 1.0))
    fig.add_subplot().set_title("0")
    fig.savefig(io.BytesIO(), format="png", dpi=10)


def _start_worker(parent: int, forked: bool) -> None:
    """What each worker of the embedded cluster does as it starts: BLAS on one thread
    (inherited when `forked`), and an exit as soon as the run that started it is gone.

    A pool's workers would otherwise outlive a run killed with SIGKILL, waiting
    for work forever. (What a worker was writing is left as a temporary, which
    the next run ignores and `gc` removes.)
    """
    if forked:
        os.environ.update(_BLAS_ENV)  # for any process the worker starts
    else:
        _pin_blas()
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        with contextlib.suppress(OSError, AttributeError):
            pr_set_pdeathsig = 1
            ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGKILL))
            if os.getppid() == parent:
                return  # the kernel stops this process with its parent
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="aeroid-parent-watch", daemon=True).start()


def _process_pool(n: int) -> Any:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    method = _start_method()
    return ProcessPoolExecutor(
        n,
        mp_context=multiprocessing.get_context(method),
        initializer=_start_worker,
        initargs=(os.getpid(), method == "fork"),
    )


_CLOSING: list[threading.Thread] = []
_JOINED_AT_EXIT = False  # True once `_closed_pools` is registered to run before Python's exit


def _close_later(pool: Any) -> None:
    """Shut `pool` down in a thread: its workers exit (a forked process takes 5-15 ms
    to tear down) while this process writes the report and returns.

    Not `shutdown(wait=False)`: at interpreter exit Python 3.11 wakes a pool's
    thread that may be closing its pipe (an ignored "Bad file descriptor"
    traceback on stderr). The closing threads are joined before that exit hook
    runs (threading's exit hooks run in reverse order of registration, and
    `concurrent.futures.process` registered its own on import); where that
    hook is not available, `run` joins them itself as it returns or raises.
    """
    global _JOINED_AT_EXIT
    if not _JOINED_AT_EXIT:
        register = getattr(threading, "_register_atexit", None)
        if register is not None:
            register(_closed_pools)
            _JOINED_AT_EXIT = True
    closer = threading.Thread(
        target=pool.shutdown,
        kwargs={"wait": True, "cancel_futures": True},
        name="aeroid-pool-close",
        daemon=True,
    )
    closer.start()
    _CLOSING[:] = [t for t in _CLOSING if t.is_alive()]
    _CLOSING.append(closer)


def _closed_pools() -> None:
    """Wait until the pools this process shut down have stopped their workers."""
    while _CLOSING:
        _CLOSING.pop().join()


def _run_processes(
    tasks: list[Task],
    store_root: str,
    *,
    workers: int | None,
    on_done: Callable[[dict[str, Any]], None],
    scope: str,
    pins: contextlib.ExitStack,
) -> dict[str, dict[str, Any]]:
    """The embedded cluster: Dask's local scheduler over a pool of worker processes.

    A pool costs a few milliseconds to start and to stop where a
    `dask.distributed` cluster costs a few hundred, and it hands tasks out one
    per idle worker, so each task runs the moment it is handed out. When a
    worker process dies (a crash in native code, out of memory), every task
    then running fails with it: each is run again alone in a fresh process,
    so only the one that kills its worker again is reported failed, and the
    rest of the graph goes on in a fresh pool.
    """
    from concurrent.futures.process import BrokenProcessPool

    import cloudpickle
    from dask.core import quote
    from dask.local import get_async
    from dask.multiprocessing import pack_exception

    n = workers or _workers_default()
    n = max(1, min(n, sum(1 for t in tasks if t.flight is not None) or 1))
    nodes = {node.name: node for node in _nodes(tasks, store_root, scope, n)}
    fork = _start_method() == "fork"
    if fork:
        _preload(tasks)
        _freeze_objects(True)
    done: dict[str, Any] = {}  # node name -> its result
    running: set[str] = set()
    results: dict[str, dict[str, Any]] = {}

    def finished(name: str, value: Any) -> None:
        running.discard(name)
        done[name] = value
        if nodes[name].chain is not None:
            for status in value:
                results[status["key"]] = status
                on_done(status)

    def track(key: str, *_: Any) -> None:
        if key not in done:  # not a result of an earlier attempt, given as data
            running.add(key)

    def record(key: str, value: Any, *_: Any) -> None:
        if key not in done:
            finished(key, value)

    rank = {name: i for i, name in enumerate(nodes)}

    def start(dsk: Any, state: dict[str, Any]) -> None:
        # Dask orders nodes that wait on nothing by string hashes, which change with
        # every process: the first flight ran anywhere in the run, and when it ran last
        # the report's detailed figures of it (a third of a small campaign's work) ran
        # alone at the end. Instead, the node more nodes wait on first, then the plan's
        # order (the list is popped from its end).
        ready, dependents = state.get("ready"), state.get("dependents", {})
        if isinstance(ready, list):
            ready.sort(key=lambda k: (len(dependents.get(k, ())), -rank.get(k, 0)))

    def attempt(names: list[str], n_workers: int) -> None:
        dsk: dict[str, Any] = {}
        for name in names:
            node = nodes[name]
            for dep in [*node.deps, *node.parts]:
                if dep in done:
                    dsk[dep] = quote(done[dep])
            if node.chain is not None:
                dsk[name] = (node.call, list(node.parts), *node.deps)
            else:
                dsk[name] = (node.call, *node.deps)
        pool = _process_pool(n_workers)
        try:
            get_async(
                pool.submit,
                # one node more than workers: the next one waits in the pool's queue, so a
                # worker starts it the moment it is free, not after a round trip through
                # this process (about 2 ms a node)
                n_workers + 1,
                dsk,
                names,
                chunksize=1,
                # given here, not registered globally: no other computation sees them
                callbacks=[(None, start, track, record, None)],
                # as Dask's process scheduler does: a pipeline's own functions travel
                # by value, and a worker's error comes back with its traceback
                dumps=cloudpickle.dumps,
                loads=cloudpickle.loads,
                pack_exception=pack_exception,
            )
        finally:
            _close_later(pool)

    broke = False
    pins.enter_context(_blas_pinned(fork))  # until the caller has written the report
    while len(done) < len(nodes):
        before = len(done)
        try:
            attempt([name for name in nodes if name not in done], n)
        except Exception as exc:  # a worker died, or an error escaped a task (unpickled)
            if not running and len(done) == before:  # no task to blame: none would change
                raise PipelineError(
                    f"the local worker processes could not run: {_error_text(exc)}"
                ) from exc
            broke = broke or isinstance(exc, BrokenProcessPool)
            for name in sorted(running):
                running.discard(name)
                try:
                    attempt([name], 1)
                except Exception as again:
                    broke = broke or isinstance(again, BrokenProcessPool)
                    finished(name, _dead_node(nodes[name], store_root, again))
    if broke:
        # the pool stops every worker when one dies: their half-written entries are
        # temporaries of dead processes, which `gc` removes
        ResultStore(store_root).gc()
    return results


def _dead_node(node: _Node, store_root: str, exc: BaseException) -> Any:
    """What a node that failed when run alone returns (`exc`: its worker died, or an error
    escaped its tasks): a failed part, or the chain's statuses."""
    from concurrent.futures.process import BrokenProcessPool

    died = isinstance(exc, BrokenProcessPool)
    why = f"{_DIED}: it killed its worker again when run alone" if died else _error_text(exc)
    if node.chain is not None:
        return _dead_chain(node.chain, store_root, why, died=died)
    assert node.part is not None
    task, index = node.part
    what = "the worker process died" if died else "the worker failed"
    return {"key": task.key, "part": index, "status": "failed", "error": f"{what} ({why})"}


def _probe_scheduler(address: str) -> None:
    """Fail at once when nothing listens at a ``tcp://`` scheduler address.

    Dask's client retries a refused connection until its timeout (30 s here),
    which is right for a scheduler still starting but leaves a mistyped port
    silent for half a minute; a refused or unresolvable address is reported
    now. A scheduler that accepts the connection is left to Dask.
    """
    from urllib.parse import urlsplit

    parts = urlsplit(address)
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:  # a port out of range: Dask names the problem
        return
    if host is None or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=5.0).close()
    except (ConnectionRefusedError, socket.gaierror) as exc:
        raise PipelineError(
            f"cannot reach the dask scheduler {address}: {exc.strerror or exc}"
        ) from None
    except OSError:  # a slow or filtered network: let the client try for its timeout
        return


def _run_dask(
    tasks: list[Task],
    store_root: str,
    scheduler: str,
    *,
    on_done: Callable[[dict[str, Any]], None],
    scope: str,
) -> dict[str, dict[str, Any]]:
    """Run the tasks on the `dask.distributed` scheduler at `scheduler`."""
    from dask.distributed import Client, as_completed

    _probe_scheduler(scheduler)
    try:
        client = Client(scheduler, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise PipelineError(f"cannot reach the dask scheduler {scheduler}: {exc}") from None
    results: dict[str, dict[str, Any]] = {}
    try:
        owner: dict[str, Any] = {}  # task key -> future of the chain that runs it
        # future -> (its chain, the split task or None, the futures it waits for)
        submitted: dict[Any, tuple[list[Task], Task | None, list[Any]]] = {}
        # a future whose worker died -> its tasks' statuses, given to what waited for it
        stand_in: dict[Any, list[dict[str, Any]]] = {}

        def submit(chain: list[Task], split: Task | None, deps: list[Any]) -> Any:
            parts: list[Any] = []
            if split is not None and chain[0] is split:
                parts = [
                    client.submit(
                        execute_part,
                        split,
                        store_root,
                        i,
                        *(stand_in.get(d, d) for d in _part_deps(split, i, deps, owner)),
                        scope=scope,
                        key=f"{split.step}-{split.key}-part{i}-{uuid.uuid4().hex[:8]}",
                        pure=False,
                        retries=0,
                        # a part waiting on a few flights runs as soon as they are done
                        priority=1,
                    )
                    for i in range(n_parts(split))
                ]
            head = chain[0]
            fut = client.submit(
                execute_chain,
                chain,
                store_root,
                parts,
                *(stand_in.get(d, d) for d in deps),
                scope=scope,
                key=f"{head.flight or 'campaign'}-{head.step}-{head.key}-{uuid.uuid4().hex[:8]}",
                pure=False,
                retries=0,
            )
            for t in chain:
                owner[t.key] = fut
            submitted[fut] = (chain, split, deps)
            return fut

        for chain, split, deps in _chains(tasks, owner):
            submit(chain, split, deps)
        done = as_completed(list(submitted))
        replaced: dict[Any, Any] = {}  # erred only because what it waited for died -> rerun

        def settle(fut: Any) -> None:
            """An erred chain: its worker died (its statuses go to `stand_in`), or one it
            waited for did (it never ran: submitted again, given the dead one's statuses)."""
            if fut in stand_in or fut in replaced:
                return
            chain, split, deps = submitted[fut]
            for d in deps:
                if d.status == "error":
                    settle(d)
            if any(d in stand_in or d in replaced for d in deps):
                replaced[fut] = submit(chain, split, [replaced.get(d, d) for d in deps])
                done.add(replaced[fut])
            else:
                why, died = _death(fut.exception())
                stand_in[fut] = _dead_chain(chain, store_root, why, died=died)

        for fut in done:
            try:
                statuses = fut.result()
            except Exception:  # a worker died under the chain, or under one it waited for
                settle(fut)
                if fut in replaced:
                    continue
                statuses = stand_in[fut]
            for status in statuses:
                results[status["key"]] = status
                on_done(status)
    finally:
        client.close()
    return results


_DIED = "a crash in native code, out of memory or an exit call"


def _death(exc: BaseException | None) -> tuple[str, bool]:
    """Why a chain on a `dask.distributed` worker did not finish, and whether its worker died."""
    from dask.distributed import KilledWorker

    if exc is None or isinstance(exc, KilledWorker):
        # Dask cannot tell which of the tasks on a worker killed it
        why = (
            f"{_DIED}, in this task or in one queued beside it; rerun to recompute what is missing"
        )
        return why, True
    return _error_text(exc).splitlines()[0][:300], False


def _dead_chain(
    chain: list[Task], store_root: str, why: str, *, died: bool = True
) -> list[dict[str, Any]]:
    """Statuses of a chain whose worker process died, or failed outside its tasks (`why`):
    computed up to the task that was running (its results are in the store), failed from
    there on."""
    what = "the worker process died" if died else "the worker failed"
    stored = ResultStore(store_root).stored((t.stage, t.key) for t in chain)
    out: list[dict[str, Any]] = []
    dead: Task | None = None
    for t in chain:
        status: dict[str, Any] = {"key": t.key, "step": t.step, "flight": t.flight}
        if dead is None and (t.stage, t.key) in stored:
            status.update(status="computed", cached=True)
        elif dead is None:
            dead = t
            status.update(status="failed", error=f"{what} while running {t.step} ({why})")
        else:
            status.update(
                status="failed",
                error=f"not run: the worker {'died' if died else 'failed'} at {dead.step}",
            )
        out.append(status)
    return out


def _run_local(
    tasks: list[Task], store_root: str, on_done: Callable[[dict[str, Any]], None], scope: str
) -> dict[str, dict[str, Any]]:
    results: dict[str, dict[str, Any]] = {}
    try:
        for t in tasks:
            if t.key in results:
                continue
            ups = [results[k] for k in dict.fromkeys(t.upstream_keys) if k in results]
            n = n_parts(t)
            if n > 1:
                ups = ups + [execute_part(t, store_root, i, *ups, scope=scope) for i in range(n)]
            results[t.key] = execute_task(t, store_root, *ups, scope=scope)
            on_done(results[t.key])
    finally:
        record_cache(None)
    return results


def run(
    config: CampaignConfig | str | Path,
    *,
    store: str | Path | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = False,
    pipeline: Pipeline | None = None,
) -> RunSummary:
    """Compute every missing result of a campaign and write its report.

    Parameters
    ----------
    config : CampaignConfig or path
    store : path, optional
        Overrides the config's store.
    scheduler : str, optional
        ``tcp://host:port`` of a running dask scheduler (the store must be
        reachable by its workers); default: an embedded local cluster.
    workers : int, optional
        Worker processes of the embedded cluster (default: one per core);
        0 runs every task in this process without Dask.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).
    """
    t0 = time.perf_counter()
    # the objects that exist before the run stay out of garbage collection until it
    # ends: a full collection walks them all (about 70 ms) and would otherwise fall
    # anywhere in it, planning and the report included
    _freeze_objects(True)
    try:
        return _run(config, t0, store, scheduler, workers, progress, pipeline)
    finally:
        if not _JOINED_AT_EXIT:  # no exit hook to join the pools' closing: join it here
            _closed_pools()
        _freeze_objects(False)


def _run(
    config: CampaignConfig | str | Path,
    t0: float,
    store: str | Path | None,
    scheduler: str | None,
    workers: int | None,
    progress: bool,
    pipeline: Pipeline | None,
) -> RunSummary:
    if not isinstance(config, CampaignConfig):
        config = load_config(config)
    updates: dict[str, Any] = {}
    if store is not None:
        updates["store"] = store_argument(store)
    if scheduler is not None:
        updates["scheduler"] = scheduler
    if workers is not None:
        updates["workers"] = workers
    if updates:
        config = config.model_copy(update=updates)
    the_plan = plan(config, pipeline=pipeline)
    t_plan = time.perf_counter()
    result_store = ResultStore(config.store_location)
    if the_plan.report_task is not None:
        _check_report_path(config)
    statuses: dict[str, dict[str, Any]] = {}
    todo: list[Task] = []
    stored = result_store.stored((t.stage, t.key) for t in the_plan.tasks)
    for t in the_plan.tasks:
        if t.key in statuses:
            continue
        if (t.stage, t.key) in stored:
            statuses[t.key] = {"key": t.key, "step": t.step, "flight": t.flight, "status": "cached"}
        else:
            todo.append(t)
    t_check = time.perf_counter()
    # limits given back once the report is written (see `_blas_pinned`)
    pins = contextlib.ExitStack()
    with pins:
        statuses.update(_compute(todo, config, result_store, progress, pins))
        t_run = time.perf_counter()
        report_path, columns, rows = _write_report(the_plan, result_store, statuses)
    summary = RunSummary(
        plan=the_plan,
        statuses=statuses,
        report_path=report_path,
        columns=columns,
        rows=rows,
        seconds={
            "plan": t_plan - t0,
            "cache_check": t_check - t_plan,
            "run": t_run - t_check,
            "total": time.perf_counter() - t0,
            "compute": sum(float(s.get("compute_seconds", 0.0)) for s in statuses.values()),
        },
    )
    return summary


def _compute(
    todo: list[Task],
    config: CampaignConfig,
    result_store: ResultStore,
    progress: bool,
    pins: contextlib.ExitStack,
) -> dict[str, dict[str, Any]]:
    """Run the tasks not yet stored, as the config says; their statuses by key.

    With forked workers, this process's BLAS limits stay at one thread until
    `pins` closes: `run` closes it after writing the report, as restoring
    them restarts OpenBLAS's threads, which spin for about 0.1 s and slowed
    the report by 5-10 ms on a two-core machine.
    """
    if not todo:
        return {}
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="aeroid", unit="task", file=sys.stderr)

    def on_done(status: Mapping[str, Any]) -> None:
        if bar is not None:
            bar.update(1)

    try:
        scope = uuid.uuid4().hex
        _freeze_objects(True)  # and those planning made
        if config.scheduler:
            done = _run_dask(
                todo, str(result_store.root), config.scheduler, on_done=on_done, scope=scope
            )
        elif config.workers == 0:
            done = _run_local(todo, str(result_store.root), on_done, scope)
        else:
            done = _run_processes(
                todo,
                str(result_store.root),
                workers=config.workers,
                on_done=on_done,
                scope=scope,
                pins=pins,
            )
    finally:
        if bar is not None:
            bar.close()
    return done


def store_argument(store: str | Path) -> str:
    """A store given on the command line or to `run`: a URL as is, a folder made absolute."""
    text = str(store)
    if is_url(text):
        return text
    return str(Path(text.removeprefix("file://")).expanduser().resolve())


def _check_report_path(config: CampaignConfig) -> None:
    """Refuse, before anything runs, a report path that cannot be written."""
    path = config.report_path
    where = f"{config.source}: report" if config.report else f"store {config.store}"
    if path.is_dir():
        raise ConfigError(f"{where}: {path} is a folder; name a .md file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{where}: cannot make {path.parent} ({exc.strerror or exc})") from None
    if not os.access(path.parent, os.W_OK):
        raise ConfigError(f"{where}: {path.parent} is not writable")


def _write_report(
    the_plan: Plan, store: ResultStore, statuses: dict[str, dict[str, Any]]
) -> tuple[Path | None, list[str], list[list[str]]]:
    task = the_plan.report_task
    if task is None:
        return None, [], []
    status = statuses[task.key]
    if status["status"] == "failed":
        return None, [], []
    record = None
    if "markdown" in status:
        text, columns, rows = status["markdown"], status["columns"], status["rows"]
    else:
        try:
            record = store.load(task.key, task.stage)
        except AeroidError as exc:
            statuses[task.key].update(status="failed", error=str(exc))
            return None, [], []
        text = getattr(record, "markdown", str(record))
        columns = list(getattr(record, "columns", ()))
        rows = [list(r) for r in getattr(record, "rows", ())]
    from .._html import _atomic_write

    path = the_plan.config.report_path
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        _atomic_write(path, text.encode("utf-8"))
    target = html_report_path(path)
    marker = f"<!-- aeroid campaign report {task.key} -->"
    # rebuilt only when the campaign report's key changes (an unchanged rerun stays cheap)
    if not (target.is_file() and marker in target.read_text(encoding="utf-8", errors="replace")):
        if "figures" in status:
            figures = dict(status["figures"])
        else:
            if record is None:
                with contextlib.suppress(AeroidError):
                    record = store.load(task.key, task.stage)
            draw = getattr(record, "figure_bytes", None)
            figures = draw() if draw is not None else {}
        _atomic_write(target, _html_report(text, figures, marker).encode("utf-8"))
    return path, columns, rows


def html_report_path(markdown_path: Path) -> Path:
    """Where the HTML twin of a campaign report lives."""
    return markdown_path.with_suffix(".html")


def _html_report(text: str, figures: Mapping[str, bytes], marker: str) -> str:
    """The self-contained HTML campaign report: the Markdown plus the report's figures."""
    from .._html import markdown_to_html

    body = text.rstrip()
    if figures:
        body += "\n\n## Figures\n\n" + "\n\n".join(
            f"### {name}\n\n![{name}](fig{i})" for i, name in enumerate(figures)
        )
    images = {f"fig{i}": png for i, png in enumerate(figures.values())}
    return markdown_to_html(body, images).replace("<body>", "<body>\n" + marker, 1)


# -- rerun ---------------------------------------------------------------------------------


def rerun(store: ResultStore, key: str) -> tuple[bool, list[str]]:
    """Recompute a stored result from its recorded inputs into a scratch store and compare.

    Returns (bit-identical, lines to show); raises `PipelineError` when the
    result cannot be recomputed. Upstream results are read from `store`
    (digests checked); the scratch store is removed afterwards.
    """
    import shutil
    import tempfile

    entry = store.find(key)
    problem = store.verify(entry.key, entry.stage)
    if problem is not None:
        raise PipelineError(problem)
    meta = store.metadata(entry.key, entry.stage)
    recorded = meta.get("provenance", {}).get("task")
    if not recorded:
        raise PipelineError(f"entry {entry.key[:12]} records no task to recompute")
    task = Task.from_json(recorded, meta["task"])
    lines = [f"recomputing {task.step} {task.flight or '(campaign)'} {entry.key[:12]}"]
    if task.model_ref is not None:
        model = resolve_model(task.model_ref["spec"], task.model_ref.get("base_dir"))
        current = json.loads(canonical_json(model_fingerprint(model)))
        if current != meta["task"].get("model"):
            lines.append("note: the model's fingerprint differs from the recorded one")
    scratch = Path(tempfile.mkdtemp(prefix="aeroid-rerun-"))
    try:
        status = execute_task(task, str(scratch / "store"), read_root=str(store.root))
        what = f"recomputing {task.step} {task.flight or '(campaign)'} {entry.key[:12]}"
        if status["status"] == "failed":
            raise PipelineError(f"{what} failed: {status.get('error')}")
        fresh = ResultStore(scratch / "store", create=False)
        if not fresh.exists(task.stage, task.key):
            raise PipelineError(f"{what} stored nothing (an upstream flight failed)")
        new_meta = fresh.metadata(task.key, task.stage)
        old_arrays = store.load_arrays(entry.key, entry.stage)
        new_arrays = fresh.load_arrays(task.key, task.stage)
        worst: tuple[float, str] = (0.0, "")
        identical = True
        for name in sorted(set(old_arrays) | set(new_arrays)):
            a, b = old_arrays.get(name), new_arrays.get(name)
            if a is None or b is None or a.shape != b.shape or a.dtype != b.dtype:
                identical = False
                lines.append(f"array {name!r}: present or shaped differently")
                continue
            if a.tobytes() != b.tobytes():
                identical = False
                with np.errstate(all="ignore"):
                    diff = float(np.nanmax(np.abs(a.astype(complex) - b.astype(complex))))
                if not worst[1] or diff > worst[0]:
                    worst = (diff, name)
        if meta["record"] != new_meta["record"]:
            identical = False
            lines.append("the record's non-array fields differ")
        if identical:
            lines.append(f"bit-identical ({len(old_arrays)} arrays)")
        elif worst[1]:
            lines.append(f"largest difference: {worst[0]:.6g} in array {worst[1]!r}")
        return identical, lines
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
