"""Executing tasks on a worker: inputs read (digests checked), the stage run, the result
committed, and a `TaskStatus` returned; never an exception.

`execute_task` runs one task, `execute_part` one part of a split task,
`execute_chain` a flight's consecutive tasks in one process. These are the
functions every executor (`executors`) runs, wherever it runs them.
"""

from __future__ import annotations

import copy
import dataclasses
import platform
import sys
import time
import traceback
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np

from ...errors import AeroidError, PipelineError
from ...models.compiled import fixed_path
from ...support import record_warnings
from ..definition import load_pipeline
from ..plans.planning import Task, resolve_model
from ..stages import STAGES, StageContext
from ..stages.work import Work, context_of, options_of, perform, stage_of
from ..storage.commits import BY_ANOTHER_RUN, Made, put
from ..storage.store import ResultStore, record_cache, run_store
from . import _process

__all__ = [
    "BY_ANOTHER_RUN",
    "PartResult",
    "TaskStatus",
    "execute_chain",
    "execute_part",
    "execute_task",
    "n_parts",
]


@dataclass(frozen=True)
class TaskStatus:
    """What happened to one task in a run.

    `status` is ``"computed"``, ``"cached"`` (stored before the run),
    ``"by_another_run"`` (computed meanwhile by another run sharing the
    store, which this one waited for) or ``"failed"`` (with `error`; `repeatable`
    where the stage refused its keyed inputs, so that the same inputs fail
    again). `cached` says whether a computed result was committed to the store
    (a report over failed flights is only where every failure is repeatable;
    `failures` names them). The campaign report's task also carries its text and table
    (`markdown`, `columns`, `rows`) and figures, so the run writes the report
    files without reading the entry back; a task whose stage makes files beside
    the report (`Stage.files`) carries them in `files`. `briefs` are what campaign tasks
    take of this task's result (`Stage.brief`).

    Read as a mapping too (``status["error"]``, ``status.get("error")``), as
    the plain dict it replaces was.
    """

    key: str
    step: str
    flight: str | None
    status: str
    cached: bool = False
    error: str | None = None
    traceback: str | None = None
    warnings: tuple[str, ...] = ()
    failures: Mapping[str, str] = field(default_factory=dict)
    repeatable: bool = False
    briefs: Mapping[str, Any] = field(default_factory=dict)
    compute_seconds: float = 0.0
    seconds: float = 0.0
    markdown: str | None = None
    columns: tuple[str, ...] = ()
    rows: tuple[tuple[str, ...], ...] = ()
    figures: Mapping[str, bytes] | None = None
    files: Mapping[str, bytes] | None = None

    def replace(self, **changes: Any) -> TaskStatus:
        return dataclasses.replace(self, **changes)

    def __getitem__(self, name: str) -> Any:
        if name not in _FIELDS:
            raise KeyError(name)
        return getattr(self, name)

    def get(self, name: str, default: Any = None) -> Any:
        """The field `name`, or `default` where it is unset (None or empty)."""
        value = getattr(self, name, None) if name in _FIELDS else None
        return default if value is None or value == () else value


_FIELDS = frozenset(f.name for f in dataclasses.fields(TaskStatus))


@dataclass(frozen=True)
class PartResult:
    """One part of a split task: its value (not stored; the task combines the parts)."""

    key: str
    part: int
    status: str
    value: Any = None
    error: str | None = None
    warnings: tuple[str, ...] = ()
    compute_seconds: float = 0.0
    # the worker process's CPU (every thread: JAX compiles on threads of its own)
    compute_cpu_seconds: float = 0.0


def _versions() -> dict[str, str]:
    """Versions of the packages that computed and stored a result: those loaded.

    Read from the modules: asking `importlib.metadata` parses every package's
    metadata, which would cost a fresh worker process more than a small flight.
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
    upstream_status: tuple[TaskStatus, ...],
    read_root: str | None,
) -> tuple[Any, StageContext]:
    """A split task's stage and the context a part of it runs in."""
    gathered = _gather(task, store_root, upstream_status, read_root, None)
    stage = stage_of(task)
    return stage, context_of(task, stage, gathered)


def _gather(
    task: Task,
    store_root: str,
    upstream_status: tuple[TaskStatus, ...],
    read_root: str | None,
    store: ResultStore | None,
) -> dict[str, Any]:
    """What a task reads: its inputs (digests checked), model and seed, the failures of
    its flights, and the briefs its upstream tasks handed over."""
    failed = {s.key: s for s in upstream_status if s.status == "failed"}
    if task.pipeline_ref is not None:
        load_pipeline(task.pipeline_ref)  # registers any stages the pipeline defines
    if store is None:
        store = run_store(store_root)
    reader = store if read_root is None else ResultStore(read_root, create=False)
    inputs: dict[str, Any] = {}
    failures: dict[str, str] = {}
    briefs: dict[str, dict[int, Any]] = {}
    given = {s.key: s.briefs for s in upstream_status if s.briefs}
    for role, ref in task.upstream.items():
        up_stage = task.upstream_stages[role]
        if isinstance(ref, list):
            keys: list[str | None] = []
            name = f"{task.stage}/{role}"
            for i, (flight, k) in enumerate(zip(task.flights, ref, strict=True)):
                if k is None:  # the step did not run on this flight (its `flights`)
                    keys.append(None)
                elif k in failed:
                    keys.append(None)
                    failures.setdefault(flight, _failure_text(failed[k]))
                else:
                    keys.append(k)
                    if k in given and name in given[k]:
                        briefs.setdefault(role, {})[i] = given[k][name]
            inputs[role] = _LazyRecords(reader, up_stage, keys)
        else:
            if ref in failed:
                raise _UpstreamFailed(_upstream_failure(failed[ref]), failed[ref].repeatable)
            inputs[role] = reader.load(ref, up_stage)
    model = None
    if task.model_ref is not None:
        # a copy of its own: what earlier tasks of this process did with the model (its
        # compiled programs, its last rollout) never changes this task's path or bits
        model = copy.copy(resolve_model(task.model_ref["spec"], task.model_ref.get("base_dir")))
    seed = None
    if task.seed is not None:
        seed = np.random.SeedSequence(task.seed["seed"], spawn_key=tuple(task.seed["spawn_key"]))
    return {"inputs": inputs, "model": model, "seed": seed, "failures": failures, "briefs": briefs}


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


def _flatten(statuses: tuple[Any, ...]) -> tuple[TaskStatus | PartResult, ...]:
    """Statuses passed in by upstream futures: single statuses or lists (chains)."""
    out: list[TaskStatus | PartResult] = []
    for s in statuses:
        if isinstance(s, (TaskStatus, PartResult)):
            out.append(s)
        else:
            out.extend(s)
    return tuple(out)


def n_parts(task: Task) -> int:
    """How many parallel parts a task splits into (1: it runs whole)."""
    stage = STAGES.get(task.stage)
    if stage is None or stage.parts is None or stage.run_part is None or stage.combine is None:
        return 1
    try:
        return max(1, int(stage.parts(options_of(task), frozenset(task.upstream))))
    except Exception:
        return 1  # the task itself will report the problem


def execute_part(
    task: Task,
    store_root: str,
    index: int,
    *upstream_status: Any,
    read_root: str | None = None,
    scope: str | None = None,
) -> PartResult:
    """Compute part `index` of a split task (not stored; its task combines the parts)."""
    record_cache(scope)
    try:
        stage, ctx = _context(task, store_root, _statuses(upstream_status), read_root)
        t1, c1 = time.perf_counter(), time.process_time()
        with record_warnings() as caught, fixed_path():
            value = stage.run_part(ctx, index)
        seconds, cpu = time.perf_counter() - t1, time.process_time() - c1
        _process.settle_imports()
        return PartResult(
            task.key,
            index,
            "ok",
            value=value,
            warnings=_warning_texts(caught),
            compute_seconds=seconds,
            compute_cpu_seconds=cpu,
        )
    except Exception as exc:
        return PartResult(task.key, index, "failed", error=error_text(exc))


def _statuses(upstream: tuple[Any, ...]) -> tuple[TaskStatus, ...]:
    return tuple(s for s in _flatten(upstream) if isinstance(s, TaskStatus))


def execute_task(
    task: Task,
    store_root: str,
    *upstream_status: Any,
    read_root: str | None = None,
    scope: str | None = None,
) -> TaskStatus:
    """Run one task and commit its result; never raises (a failure is returned).

    `upstream_status` holds the statuses of upstream tasks run in this
    session (single statuses or lists of them) and, for a split task, the
    results of its parts. Records are cached in this process for the run
    `scope` (see `record_cache`).
    """
    t0 = time.perf_counter()
    flat = _flatten(upstream_status)
    parts = sorted((s for s in flat if isinstance(s, PartResult)), key=lambda s: s.part)
    upstream = tuple(s for s in flat if isinstance(s, TaskStatus))
    out: dict[str, Any] = {}
    try:
        _compute(task, store_root, upstream, parts, read_root, out, scope)
    except Exception as exc:
        # refused by the stage itself (bad data, bad options), or by the upstream
        # step it needs, which was: the keyed inputs fail again, not a crash or the store
        in_stage = out.pop("in_stage", False) and isinstance(exc, AeroidError)
        repeatable = bool(getattr(exc, "repeatable", in_stage))
        out.update(status="failed", error=error_text(exc), repeatable=repeatable)
        if not isinstance(exc, AeroidError):
            out["traceback"] = traceback.format_exc(limit=6)
    out["seconds"] = time.perf_counter() - t0
    _process.settle_imports()
    return TaskStatus(task.key, task.step, task.flight, **out)


def _compute(
    task: Task,
    store_root: str,
    upstream: tuple[TaskStatus, ...],
    parts: list[PartResult],
    read_root: str | None,
    out: dict[str, Any],
    scope: str | None,
) -> None:
    """Compute `task` (or combine its `parts`) and put it in the store; what happened
    into `out`. Each seam is entered once: the store (`commits.put`) claims the key and
    has `make` gather the inputs and run the stage (`work.perform`, which also makes
    the result's briefs) while the claim holds, then writes the entry and releases."""
    failures: dict[str, str] = {}
    work: list[Work] = []

    def make(store: ResultStore) -> Made:
        gathered = _gather(task, store_root, upstream, read_root, store)
        failures.update(gathered["failures"])
        bad = [p for p in parts if p.status != "ok"]
        if bad:
            raise PipelineError(f"part {bad[0].part} failed: {bad[0].error}")
        t1, c1 = time.perf_counter(), time.process_time()
        out["in_stage"] = True
        with record_warnings() as caught, fixed_path():
            # the library's warnings (an unconverged chain, poor coherence) belong to the
            # task: kept with its status and provenance instead of on a worker's stderr
            work.append(perform(task, gathered, [p.value for p in parts] if parts else None))
        del out["in_stage"]
        t2, c2 = time.perf_counter(), time.process_time()
        part_seconds = sum(p.compute_seconds for p in parts)
        part_cpu = sum(p.compute_cpu_seconds for p in parts)
        found = [*(w for p in parts for w in p.warnings), *_warning_texts(caught)]
        out["warnings"] = tuple(dict.fromkeys(found))
        out["compute_seconds"] = t2 - t1 + part_seconds
        provenance: dict[str, Any] = {
            "task": task.to_json(),
            "versions": _versions(),
            "seconds": {
                "compute": t2 - t1 + part_seconds,
                "cpu": c2 - c1 + part_cpu,
                "parts": len(parts),
            },
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "host": platform.node(),
            "warnings": list(out["warnings"]),
        }
        # a report over failed flights is stored only where each failure is the keyed
        # inputs' own (an unchanged rerun fails them again): a crash is retried
        taken = [s for s in upstream if s.status == "failed" and s.key in task.upstream_keys]
        if failures:  # what `aeroid rerun` gives the report again in their place
            provenance["failed"] = [[s.key, s.step, s.flight, s.error] for s in taken]
        repeatable = all(s.repeatable for s in taken)
        return Made(work[0].record, provenance, keep=not failures or repeatable)

    done = put(store_root, task.stage, task.key, make, task=task.document, scope=scope)
    out.update(status=done.status, cached=done.stored)
    if failures:
        out["failures"] = failures
    if done.committed and work[0].briefs:
        out["briefs"] = dict(work[0].briefs)
    record = work[0].record if work else None
    if record is not None and task.flight is None and hasattr(record, "markdown"):
        out["markdown"] = record.markdown
        out["rows"] = tuple(tuple(r) for r in getattr(record, "rows", ()))
        out["columns"] = tuple(getattr(record, "columns", ()))
        if hasattr(record, "figure_bytes"):  # spares reading them back for the HTML
            out["figures"] = record.figure_bytes()
    if work and work[0].files:
        out["files"] = dict(work[0].files)


def execute_chain(
    tasks: list[Task],
    store_root: str,
    parts: list[PartResult],
    *upstream_status: Any,
    scope: str | None = None,
    read_root: str | None = None,
) -> list[TaskStatus]:
    """Run consecutive tasks of one flight in this process, in order; their statuses.

    One Dask task per chain keeps the scheduler's per-task cost off the
    flight's steps; every step is still keyed, committed and reported on its
    own. `parts` are the results of the first task's parts, if it is split.
    """
    known = {s.key: s for s in _statuses(upstream_status)}
    out: list[TaskStatus] = []
    for i, t in enumerate(tasks):
        ups = [known[k] for k in dict.fromkeys(t.upstream_keys) if k in known]
        extra = parts if i == 0 else ()
        status = execute_task(t, store_root, *ups, *extra, scope=scope, read_root=read_root)
        known[t.key] = status
        out.append(status)
    return out


def _warning_texts(caught: list[warnings.WarningMessage]) -> tuple[str, ...]:
    texts = (f"{w.category.__name__}: {w.message}" for w in caught)
    return tuple(dict.fromkeys(texts))


def error_text(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text if isinstance(exc, AeroidError) else f"{type(exc).__name__}: {text}"


class _UpstreamFailed(PipelineError):
    """A task's upstream step failed: repeatable where that failure was."""

    def __init__(self, message: str, repeatable: bool) -> None:
        super().__init__(message)
        self.repeatable = repeatable


def _failure_text(status: TaskStatus) -> str:
    return f"{status.step}: {status.error or 'failed'}"


def _upstream_failure(status: TaskStatus) -> str:
    """Why a task cannot run: the failed step it needs and that step's own reason (the
    first failure's, carried down a chain of steps that could not run after it)."""
    error = status.error or "failed"
    if error.startswith("upstream "):
        return error
    return f"upstream {status.step} failed: {error}"
