"""Running a campaign: plan, prune what is stored, run the rest, write the report.

`run` is the whole of it: `planning.plan` computes every task's key from the
config alone; the tasks already in the store are pruned; the rest run on an
executor (`executors`: worker processes under Dask's local scheduler by
default, a `dask.distributed` scheduler, or this process); the campaign
report is written (`campaign_report`). A failing task is reported with its
error and never committed; its dependants fail with a pointer to it; other
flights carry on.
"""

from __future__ import annotations

import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
from .planning import Plan, Task, campaign_inputs, plan, resolve_model, store_argument
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
    """

    plan: Plan
    statuses: dict[str, TaskStatus]
    report_path: Path | None
    columns: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    report_error: str | None = None
    # the aerodynamic database's files (stage ``database``), beside the report
    database_dir: Path | None = None

    def count(self, status: str) -> int:
        return sum(1 for t in self.plan.tasks if self.statuses[t.key].status == status)

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
                    "status": s.status,
                    "error": s.error,
                }
            )
        return out

    def warnings(self) -> list[tuple[Task, str]]:
        """Warnings raised by the tasks computed in this run, task by task."""
        return [(t, w) for t in self.plan.tasks for w in self.statuses[t.key].warnings]

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
    the_plan = plan(config, pipeline=pipeline, allow_imports=allow_imports)
    t_plan = time.perf_counter()
    result_store = ResultStore(config.store_location)
    if the_plan.report_task is not None:
        check_report_path(config, campaign_inputs(the_plan))
    # the plan's keys, for `aeroid status` on the unchanged campaign (`plan_cache`)
    plan_cache.save(result_store, the_plan.inputs, plan_cache.rows(the_plan.tasks))
    statuses: dict[str, TaskStatus] = {}
    todo: list[Task] = []
    # one look at the store for every task (`verified.look_up`)
    look = verified.look_up(result_store, ((t.stage, t.key) for t in the_plan.tasks))
    for t in the_plan.tasks:
        if t.key in statuses:
            continue
        found = look.found.get((t.stage, t.key))
        if found is None:
            todo.append(t)
        elif isinstance(found, str):  # its bytes fail their checksum
            statuses[t.key] = TaskStatus(t.key, t.step, t.flight, "failed", error=found)
        else:
            statuses[t.key] = TaskStatus(t.key, t.step, t.flight, "cached", warnings=found)
    t_check = time.perf_counter()
    for status in _compute(todo, config, result_store, progress):
        statuses[status.key] = status
    t_run = time.perf_counter()
    # what this run committed (written from memory) joins the index of entries checked whole
    committed = {
        (t.stage, t.key): statuses[t.key].warnings
        for t in todo
        if statuses[t.key].status == "computed" and statuses[t.key].cached
    }
    look.record_run(result_store, committed)
    # the database's files first: the campaign report shows their section and plots
    database_dir, database_error = write_database_files(the_plan, result_store, statuses)
    report_path, columns, rows, report_error = write_report(
        the_plan, result_store, statuses, database_dir=database_dir
    )
    report_error = report_error or database_error
    return RunSummary(
        plan=the_plan,
        statuses=statuses,
        report_path=report_path,
        columns=columns,
        rows=rows,
        report_error=report_error,
        database_dir=database_dir,
        seconds={
            "plan": t_plan - t0,
            "cache_check": t_check - t_plan,
            "run": t_run - t_check,
            "total": time.perf_counter() - t0,
            "compute": sum(s.compute_seconds for s in statuses.values()),
        },
    )


def _compute(
    todo: list[Task],
    config: CampaignConfig,
    result_store: ResultStore,
    progress: bool,
) -> list[TaskStatus]:
    """Run the tasks not yet stored on the executor the config asks for."""
    if not todo:
        return []
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="aeroid", unit="task", file=sys.stderr)
    on_done: Callable[[TaskStatus], None] = (
        (lambda s: None) if bar is None else (lambda s: bar.update(1))
    )
    try:
        executor = executor_for(config.scheduler, config.workers)
        return executor.run(todo, str(result_store.root), scope=uuid.uuid4().hex, on_done=on_done)
    finally:
        if bar is not None:
            bar.close()
