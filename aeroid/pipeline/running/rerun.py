"""Rerun: recompute stored results from their recorded inputs and compare them bit for bit.

Each result is recomputed into a scratch store from the task its provenance
records, reading its upstream results from the store under test (digests
checked), and compared with the stored one array by array. `rerun_all` runs
every recomputation on the same executors as a campaign run.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import AeroidError, PipelineError
from ..keys import canonical_json
from ..plans.planning import Task, resolve_model
from ..storage.store import Entry, ResultStore
from ..vehicle import keyed_fingerprint
from . import execution
from .executors import Executor, InProcess

__all__ = ["RerunResult", "rerun", "rerun_all"]


@dataclass(frozen=True)
class RerunResult:
    """One entry recomputed: bit-identical or not, and lines that say how (or why not)."""

    entry: Entry
    identical: bool
    lines: tuple[str, ...]
    failed: bool = False  # not recomputed: nothing to compare


def rerun(
    store: ResultStore, key: str, *, current: Mapping[str, Task] | None = None
) -> tuple[bool, list[str]]:
    """Recompute a stored result from its recorded inputs into a scratch store and compare.

    Returns (bit-identical, lines to show); raises `PipelineError` when the
    result cannot be recomputed. Upstream results are read from `store`
    (digests checked); the scratch store is removed afterwards. `current`, the
    tasks of the campaign's config as it is now by key (`current_tasks`), gives
    the files and code where they are now: a campaign folder moved or copied
    since the run recomputes from its own files (keys hash contents, not paths);
    an entry not among them is recomputed from the files its task recorded, and
    says so.
    """
    entry = store.find(key)
    task, lines = _recorded_task(store, entry, current)
    with _Scratch() as scratch:
        failed = _recorded_failures(store, entry)
        status = execution.execute_task(task, scratch.root, *failed, read_root=str(store.root))
        identical, more = _compare(store, entry, task, status, scratch.root)
    return identical, lines + more


def rerun_all(
    store: ResultStore,
    *,
    stage: str | None = None,
    executor: Executor | None = None,
    on_done: Callable[[RerunResult], None] | None = None,
    current: Mapping[str, Task] | None = None,
) -> list[RerunResult]:
    """Recompute every entry of `store` (or of one `stage`) on `executor` and compare.

    The recomputations are independent (each reads its inputs from `store`),
    so they run in parallel on the executor a campaign run uses; split tasks
    (Monte Carlo batches, the report's figures) split as they did. `current`
    as in `rerun`.
    """
    entries = sorted(store.entries(stage), key=lambda e: (e.stage, e.key))
    results: dict[str, RerunResult] = {}
    tasks: dict[str, tuple[Entry, Task, list[str]]] = {}
    for entry in entries:
        try:
            task, lines = _recorded_task(store, entry, current)
        except AeroidError as exc:
            results[entry.key] = RerunResult(entry, False, ("", str(exc)), failed=True)
            if on_done is not None:
                on_done(results[entry.key])
            continue
        tasks[entry.key] = (entry, task, lines)
    if tasks:
        with _Scratch() as scratch:

            def finished(status: execution.TaskStatus) -> None:
                entry, task, lines = tasks[status.key]
                try:
                    identical, more = _compare(store, entry, task, status, scratch.root)
                    result = RerunResult(entry, identical, tuple(lines + more))
                except AeroidError as exc:
                    result = RerunResult(entry, False, (lines[0], str(exc)), failed=True)
                results[entry.key] = result
                if on_done is not None:
                    on_done(result)

            (executor or InProcess()).run(
                _in_order(t for _, t, _ in tasks.values()),
                scratch.root,
                scope=uuid.uuid4().hex,
                on_done=finished,
                read_root=str(store.root),
                given=[s for e, _, _ in tasks.values() for s in _recorded_failures(store, e)],
            )
    return [results[e.key] for e in entries if e.key in results]


class _Scratch:
    """A scratch store folder, removed afterwards."""

    def __enter__(self) -> _Scratch:
        self.folder = Path(tempfile.mkdtemp(prefix="aeroid-rerun-"))
        self.root = str(self.folder / "store")
        return self

    def __exit__(self, *exc: object) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def current_tasks(config: Any) -> dict[str, Task]:
    """The tasks of `config` (a campaign config or its path) as it is now, by key."""
    from ..plans.planning import plan

    return {t.key: t for t in plan(config).tasks}


def _recorded_task(
    store: ResultStore, entry: Entry, current: Mapping[str, Task] | None = None
) -> tuple[Task, list[str]]:
    problem = store.verify(entry.key, entry.stage)
    if problem is not None:
        raise PipelineError(problem)
    meta = store.metadata(entry.key, entry.stage)
    recorded = meta.get("provenance", {}).get("task")
    if not recorded:
        raise PipelineError(f"entry {entry.key[:12]} records no task to recompute")
    task = Task.from_json(recorded, meta["task"])
    lines = [f"recomputing {task.step} {task.flight or '(campaign)'} {entry.key[:12]}"]
    if current is not None:
        if entry.key in current:  # the same inputs, by content: read where they are now
            task = current[entry.key]
        else:
            where = (task.source or {}).get("path")
            lines.append(
                "note: not a task of the config as it is now (its inputs changed since, or it "
                "is another campaign's); recomputed from the inputs it recorded"
                + (f" ({where})" if where else "")
            )
    if task.model_ref is not None:
        model = resolve_model(task.model_ref["spec"], task.model_ref.get("base_dir"))
        current = json.loads(
            canonical_json(
                keyed_fingerprint(model, task.model_ref["spec"], task.model_ref.get("base_dir"))
            )
        )
        if current != meta["task"].get("model"):
            lines.append("note: the model's fingerprint differs from the recorded one")
    return task, lines


def _recorded_failures(store: ResultStore, entry: Entry) -> list[execution.TaskStatus]:
    """The upstream failures a report over failed flights was made with (its provenance
    records them: they are stored nowhere else), given to its recomputation again."""
    recorded = store.metadata(entry.key, entry.stage).get("provenance", {}).get("failed", [])
    return [
        execution.TaskStatus(key, step, flight, "failed", error=error, repeatable=True)
        for key, step, flight, error in recorded
    ]


def _in_order(tasks: Iterable[Task]) -> list[Task]:
    """Tasks in an order an executor runs: each after those it reads, a flight's together."""
    by_key = {t.key: t for t in tasks}
    out: list[Task] = []
    seen: set[str] = set()

    def visit(t: Task) -> None:
        if t.key in seen:
            return
        seen.add(t.key)
        for k in t.upstream_keys:
            if k in by_key:
                visit(by_key[k])
        out.append(t)

    for t in sorted(by_key.values(), key=lambda t: (t.flight is None, t.flight or "")):
        visit(t)
    return out


def _compare(
    store: ResultStore, entry: Entry, task: Task, status: Any, scratch_root: str
) -> tuple[bool, list[str]]:
    what = f"recomputing {task.step} {task.flight or '(campaign)'} {entry.key[:12]}"
    if status.status == "failed":
        raise PipelineError(f"{what} failed: {status.error}")
    fresh = ResultStore(scratch_root, create=False)
    if not fresh.exists(task.stage, task.key):
        raise PipelineError(f"{what} stored nothing (an upstream flight failed)")
    lines: list[str] = []
    old_meta = store.metadata(entry.key, entry.stage)
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
    if old_meta["record"] != new_meta["record"]:
        identical = False
        lines.append("the record's non-array fields differ")
    if identical:
        lines.append(f"bit-identical ({len(old_arrays)} arrays)")
    elif worst[1]:
        lines.append(f"largest difference: {worst[0]:.6g} in array {worst[1]!r}")
    return identical, lines
