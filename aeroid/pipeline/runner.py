"""Running a campaign: plan, prune what is stored, run the rest, write the report.

`run` is the whole of it: `planning.plan_stream` computes every task's key
from the config alone, a flight at a time; the tasks already in the store are
pruned; the rest run a window of flights at a time on an executor
(`executors`: worker processes under Dask's local scheduler by default, a
`dask.distributed` scheduler, or this process), and of each task only a line
of a `Ledger` is kept; the campaign report is written (`campaign_report`),
its campaign tasks reading the flights' results from the store. A failing task is reported with its
error and never committed; its dependants fail with a pointer to it; other
flights carry on.
"""

from __future__ import annotations

import functools
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import PipelineError, StoreError
from . import plan_cache, verified
from .campaign_report import check_report_path, html_report_path, write_report
from .config import CampaignConfig, load_config
from .database_stage import write_database_files
from .definition import Pipeline
from .execution import (
    BY_ANOTHER_RUN,
    TaskStatus,
    execute_chain,
    execute_part,
    execute_task,
    n_parts,
)
from .executors import executor_for
from .ledger import Ledger, Statuses
from .plan_cache import PlannedTask
from .planning import Plan, PlanStream, Task, plan, plan_stream, resolve_model, store_argument
from .rerun import rerun
from .store import ResultStore

__all__ = [
    "Plan",
    "RunSummary",
    "Task",
    "TaskStatus",
    "execute_chain",
    "execute_part",
    "execute_task",
    "n_parts",
    "plan",
    "rerun",
    "resolve_model",
    "run",
    "store_argument",
]


@dataclass
class RunSummary:
    """What a run did: per-task status, counts, the report.

    `report_error` says why the report files could not be written (a full
    disk); the table (`columns`, `rows`) is there all the same.

    A run keeps of each task only what its summary shows (a `Ledger`: step,
    flight, key and status code, the whole status where it carries an error
    or warnings), never the plan: a campaign of 100,000 flights would hold
    some 4 kB a flight in its tasks. `plan` is made again on first access from
    the config the run was given (keys are computed from the config alone, so
    it is the plan that ran, unless a flight file was rewritten since: its
    keys then differ from `statuses`); `statuses` reads the ledger as the
    mapping key -> `TaskStatus` it always was.
    """

    ledger: Ledger
    report_path: Path | None
    columns: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    report_error: str | None = None
    # the aerodynamic database's files (stage ``database``), beside the report
    database_dir: Path | None = None
    replan: Callable[[], Plan] | None = field(default=None, repr=False)

    @functools.cached_property
    def plan(self) -> Plan:
        """The campaign's plan, made again from the run's config (see above)."""
        if self.replan is None:
            raise PipelineError("this summary keeps no way to plan its campaign again")
        return self.replan()

    @property
    def statuses(self) -> Statuses:
        """Task key -> `TaskStatus`, in plan order."""
        return self.ledger.statuses

    @property
    def flights(self) -> list[str]:
        """The flights of the run, in plan order."""
        return self.ledger.flights

    def count(self, status: str) -> int:
        return self.ledger.count(status)

    @property
    def failed(self) -> int:
        return self.count("failed")

    def task_rows(self) -> list[dict[str, Any]]:
        out = []
        for i in range(len(self.ledger)):
            s = self.ledger.status(i)
            out.append(
                {
                    "stage": s.step,
                    "flight": s.flight,
                    "key": s.key,
                    "status": s.status,
                    "error": s.error,
                }
            )
        return out

    def warnings(self) -> list[tuple[PlannedTask, str]]:
        """Warnings raised by the tasks computed in this run, task by task."""
        return [(t, w) for t, s in self.ledger.told() for w in s.warnings]

    def to_json(self) -> dict[str, Any]:
        html = None if self.report_path is None else html_report_path(self.report_path)
        doc: dict[str, Any] = {
            "computed": self.count("computed"),
            "cached": self.count("cached"),
            BY_ANOTHER_RUN: self.count(BY_ANOTHER_RUN),
            "failed": self.failed,
            "report": None if self.report_path is None else str(self.report_path),
            "report_html": str(html) if html is not None and html.is_file() else None,
        }
        if self.report_error is not None:  # the report files could not be written
            doc["report_error"] = self.report_error
        doc["tasks"] = self.task_rows()
        return doc


def run(
    config: CampaignConfig | str | Path,
    *,
    store: str | Path | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = False,
    pipeline: Pipeline | None = None,
    allow_imports: bool = False,
) -> RunSummary:
    """Compute every missing result of a campaign and write its report.

    The plan is streamed (`plan_stream`): flights are planned, pruned of what
    is stored and run a window of `_WINDOW_FLIGHTS` at a time, and only a
    ledger of their statuses is kept (`RunSummary`), so the memory of this
    process grows by some bytes a flight, not by its tasks.

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
    pipeline : Pipeline, optional
        Instead of the one the config names.
    allow_imports : bool
        Allow ``module:attribute`` models and metrics, which import and run
        code (as the config's ``allow_imports: true`` does).
    """
    t0 = time.perf_counter()
    return _run(config, t0, store, scheduler, workers, progress, pipeline, allow_imports)


# flights handed to the executor at once: their tasks, graph and statuses are what this
# process holds beyond the ledger (a few MB); a window's tail leaves workers idle for
# at most one flight's chain each
_WINDOW_FLIGHTS = 2_000


def _run(
    config: CampaignConfig | str | Path,
    t0: float,
    store: str | Path | None,
    scheduler: str | None,
    workers: int | None,
    progress: bool,
    pipeline: Pipeline | None,
    allow_imports: bool,
) -> RunSummary:
    if not isinstance(config, CampaignConfig):
        config = load_config(config)
    updates: dict[str, Any] = {}
    if store is not None:
        updates["store"] = store_argument(store)
    if scheduler is not None:
        updates["scheduler"] = scheduler
    if workers is not None:
        from ..errors import ConfigError
        from .config import workers_problem

        if problem := workers_problem(workers):  # model_copy below skips the validators
            raise ConfigError(f"workers: {problem}")
        updates["workers"] = workers
    if updates:
        config = config.model_copy(update=updates)
    stream = plan_stream(config, pipeline=pipeline, allow_imports=allow_imports)
    result_store = ResultStore(config.store_location)
    if stream.has_campaign_tasks:
        check_report_path(config, stream.input_files())
    state = _Streamed(result_store, config, progress)
    try:
        state.consume(stream)
    finally:
        state.close()
    ledger = state.ledger
    _record_checked(result_store, state.committed, state.checked, state.trusted)
    # the report sees the campaign tasks and the statuses that carry warnings or errors
    told = {s.key: s for _, s in ledger.told()}
    report_plan = Plan(
        config=stream.config,
        pipeline=stream.pipeline,
        tasks=[*_warned(ledger), *state.campaign],
        flights=ledger.flights,
        inputs=stream.inputs,
    )
    # the database's files first: the campaign report shows their section and plots
    database_dir, database_error = write_database_files(report_plan, result_store, told)
    report_path, columns, rows, report_error = write_report(
        report_plan, result_store, told, database_dir=database_dir
    )
    for t in state.campaign:  # the report task's status, where its entry could not be read
        if t.key in told:
            ledger.settle(state.campaign_index[t.key], told[t.key])
    report_error = report_error or database_error

    def replan() -> Plan:
        return plan(config, pipeline=pipeline, allow_imports=allow_imports)

    return RunSummary(
        ledger=ledger,
        report_path=report_path,
        columns=columns,
        rows=rows,
        report_error=report_error,
        database_dir=database_dir,
        replan=replan,
        seconds={
            "plan": state.t_plan,
            "cache_check": state.t_check,
            "run": state.t_run,
            "total": time.perf_counter() - t0,
            "compute": ledger.compute_seconds,
        },
    )


def _warned(ledger: Ledger) -> list[Task]:
    """Stand-ins for the flight tasks with warnings, as the report reads them (step,
    stage, flight, key): it shows each flight's warnings in its section."""
    return [
        Task(t.key, t.step, t.stage, t.flight, {}, {}, {}, b"")
        for t, s in ledger.told()
        if s.warnings and t.flight is not None
    ]


class _Streamed:
    """The state of a streamed run: the ledger, what the store holds, the window of
    tasks to run, and what the index of checked entries gets at the end."""

    def __init__(self, result_store: ResultStore, config: CampaignConfig, progress: bool):
        self.store = result_store
        self.config = config
        self.ledger = Ledger()
        self.scope = uuid.uuid4().hex
        self.executor = executor_for(config.scheduler, config.workers)
        self.checked: dict[tuple[str, str], verified.Known] = {}
        self.committed: list[tuple[str, str, tuple[str, ...]]] = []
        self.failed: dict[str, TaskStatus] = {}  # run here and failed: later tasks take them
        self.campaign: list[Task] = []
        self.campaign_index: dict[str, int] = {}
        self.window: list[tuple[int, Task]] = []
        self.twins: list[tuple[int, int]] = []  # (task, earlier task of the same key)
        self.window_flights = 0
        self.t_plan = self.t_check = self.t_run = 0.0
        self.bar: Any = None
        if progress and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(desc="aeroid", unit="task", file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def consume(self, stream: PlanStream) -> None:
        """Plan, prune and run the stream a window of flights at a time."""
        t = time.perf_counter()
        # a listing per stage; an entry the index holds with the same signature is trusted
        # without opening it, any other is CRC-checked (`verified`)
        self.listed = self.store.signatures(stream.stages)
        self.trusted = verified.read_index(self.store)
        self.t_check += time.perf_counter() - t
        flight: str | None = None
        seen: dict[str, int] = {}  # the current flight's keys (a key planned twice runs once)
        tasks = iter(stream)
        while True:
            t = time.perf_counter()
            task = next(tasks, None)
            self.t_plan += time.perf_counter() - t
            if task is None:
                break
            if task.flight != flight or task.flight is None:
                flight, seen = task.flight, {}
                if self.window_flights >= _WINDOW_FLIGHTS and task.flight is not None:
                    self._run_window()
                self.window_flights += 1
            index = self.ledger.add(task)
            if task.flight is None:
                self.campaign.append(task)
                self.campaign_index.setdefault(task.key, index)
            if task.key in seen:  # the same as an earlier step of this flight: its status
                self.twins.append((index, seen[task.key]))
                continue
            seen[task.key] = index
            t = time.perf_counter()
            self._prune(index, task)
            self.t_check += time.perf_counter() - t
        # the plan's keys, for `aeroid status` on the unchanged campaign (`plan_cache`)
        plan_cache.save(self.store, stream.inputs, self.ledger.planned())
        self._run_window()

    def _prune(self, index: int, task: Task) -> None:
        """Settle a stored task (trusted from the index, or CRC-checked), or queue it."""
        ident = (task.stage, task.key)
        if ident not in self.listed:
            self.window.append((index, task))
            return
        found = self.trusted.lookup(ident, self.listed[ident])
        if found is not None:
            status = TaskStatus(task.key, task.step, task.flight, "cached", warnings=found)
        else:
            status = _cache_hit(self.store, task)
            if status.status == "cached":
                self.checked[ident] = (self.listed[ident], status.warnings)
        self.ledger.settle(index, status)
        self._tick()

    def _tick(self, _: object = None) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def _run_window(self) -> None:
        """Run the queued tasks, settle their statuses, and let them go."""
        window, self.window, self.window_flights = self.window, [], 0
        self._settle_window(window)
        for index, first in self.twins:
            # its time is counted once, with the first
            self.ledger.settle(index, self.ledger.status(first).replace(compute_seconds=0.0))
        self.twins = []

    def _settle_window(self, window: list[tuple[int, Task]]) -> None:
        todo = list({t.key: t for _, t in window}.values())
        if not todo:
            return
        taken = dict.fromkeys(k for t in todo for k in t.upstream_keys if k in self.failed)
        given = [self.failed[k] for k in taken]
        t = time.perf_counter()
        results = {
            s.key: s
            for s in self.executor.run(
                todo,
                str(self.store.root),
                scope=self.scope,
                on_done=self._tick,
                given=given,
            )
        }
        self.t_run += time.perf_counter() - t
        for index, task in window:
            status = results.get(task.key)
            if status is None:  # not run by the executor: never expected
                status = TaskStatus(
                    task.key, task.step, task.flight, "failed", error="not run by the executor"
                )
            self.ledger.settle(index, status)
            if status.status == "failed":
                self.failed[task.key] = status
            elif status.status == "computed" and status.cached:
                self.committed.append((task.stage, task.key, status.warnings))


def _record_checked(
    result_store: ResultStore,
    committed: list[tuple[str, str, tuple[str, ...]]],
    checked: dict[tuple[str, str], verified.Known],
    trusted: verified.Trusted,
) -> None:
    """Add what this run committed (written from memory) and what it CRC-checked to the
    store's index of entries checked whole: the next run trusts them unopened."""
    if committed:
        try:
            listed = result_store.signatures({stage for stage, _, _ in committed})
        except (StoreError, OSError):
            listed = {}
        for stage, key, warnings in committed:
            if (stage, key) in listed:
                checked[(stage, key)] = (listed[(stage, key)], warnings)
    verified.record(result_store, checked, trusted)


def _cache_hit(result_store: ResultStore, task: Task) -> TaskStatus:
    """A stored task's status: cached only where its entry's bytes pass their CRC-32;
    with the warnings the computation raised, stored beside its result."""
    found = result_store.cached_warnings(task.stage, task.key)
    if found is not None:
        return TaskStatus(task.key, task.step, task.flight, "cached", warnings=found)
    where = result_store.path_for(task.stage, task.key)
    error = f"{task.stage} entry {where} is corrupt: its bytes fail their checksum"
    return TaskStatus(task.key, task.step, task.flight, "failed", error=error)
