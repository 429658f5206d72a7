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
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...errors import PipelineError
from ..definition import Pipeline
from ..plans.config import CampaignConfig
from ..plans.plan_cache import PlannedTask
from ..plans.planning import Plan, Task, plan, resolve_model, store_argument
from ..plans.run_plan import html_report_path, plan_run
from ..stages.run_outputs import write_run_outputs
from .execution import (
    BY_ANOTHER_RUN,
    TaskStatus,
    execute_chain,
    execute_part,
    execute_task,
    n_parts,
)
from .ledger import Ledger, Statuses
from .rerun import rerun
from .streaming import StreamedRun

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
    is stored and run a window of `streaming.WINDOW_FLIGHTS` at a time, and only a
    ledger of their statuses is kept (`RunSummary`, `streaming`), so the memory of this
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
    # each seam once: the plan (config, stream, report path, the store and its look),
    # the tasks (the stream read and the look asked a task at a time, the executor), the
    # files the run leaves (the store's index, the database's files, the report)
    ledger = Ledger()
    start = plan_run(
        config,
        store=store,
        scheduler=scheduler,
        workers=workers,
        pipeline=pipeline,
        allow_imports=allow_imports,
        planned=ledger.planned,
    )
    state = StreamedRun(start, ledger, progress)
    try:
        state.consume(start.tasks)
    finally:
        state.close()
    committed = (((stage, key), w) for stage, key, w in ledger.committed())
    out = write_run_outputs(start, ledger.told(), state.campaign, ledger.flights, committed)
    for t in state.campaign:  # the report task's status, where its entry could not be read
        if t.key in out.statuses:
            ledger.settle(state.campaign_index[t.key], out.statuses[t.key])
    checked = start.config

    def replan() -> Plan:
        return plan(checked, pipeline=pipeline, allow_imports=allow_imports)

    return RunSummary(
        ledger=ledger,
        report_path=out.report_path,
        columns=out.columns,
        rows=out.rows,
        report_error=out.report_error,
        database_dir=out.database_dir,
        replan=replan,
        seconds={
            "plan": state.t_plan,
            "cache_check": state.t_check,
            "run": state.t_run,
            "total": time.perf_counter() - t0,
            "compute": ledger.compute_seconds,
        },
    )
