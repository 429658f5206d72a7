"""What a run leaves once its tasks are done, in one call: the store's index of what it
checked and committed, the aerodynamic database's files and the campaign report.

`write_run_outputs` is all a run asks of the stages seam after its tasks: the
report reads the campaign tasks and the statuses that carry warnings or errors,
and the database's files come first (the report shows their section and plots).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ..plans.planning import Plan, Task
from .campaign_report import write_report
from .database_stage import write_database_files

if TYPE_CHECKING:
    from ..plans.plan_cache import PlannedTask
    from ..plans.run_plan import RunPlan
    from ..running.execution import TaskStatus

__all__ = ["RunOutputs", "write_run_outputs"]


@dataclass(frozen=True)
class RunOutputs:
    """The files a run wrote after its tasks (`write_run_outputs`).

    Attributes
    ----------
    report_path : Path or None
        The Markdown report, where it was written.
    columns, rows : list
        The report's table (there even when its files could not be written).
    report_error : str or None
        Why the report or the database's files could not be written.
    database_dir : Path or None
        The aerodynamic database's files, where written.
    statuses : dict
        Key -> status of the tasks the report read; a campaign task whose entry
        could not be read is failed here.
    """

    report_path: Path | None
    columns: list[str]
    rows: list[list[str]]
    report_error: str | None
    database_dir: Path | None
    statuses: dict[str, TaskStatus]


def write_run_outputs(
    start: RunPlan,
    told: Iterable[tuple[PlannedTask, TaskStatus]],
    campaign: list[Task],
    flights: list[str],
    committed: Iterable[tuple[tuple[str, str], tuple[str, ...]]],
) -> RunOutputs:
    """Record in the store's index what the run `committed` and checked, then write the
    database's files and the campaign report.

    `told`: the tasks whose status says more than its code (errors, warnings);
    `campaign`: the campaign tasks; `flights`: the run's flights in plan order.
    """
    start.look.record_run(start.store, committed)
    told = list(told)
    statuses = {s.key: s for _, s in told}
    # stand-ins for the flight tasks with warnings, as the report reads them (step, stage,
    # flight, key): it shows each flight's warnings in its section
    warned = [
        Task(t.key, t.step, t.stage, t.flight, {}, {}, {}, b"")
        for t, s in told
        if s.warnings and t.flight is not None
    ]
    stream = start.stream
    report_plan = Plan(
        config=stream.config,
        pipeline=stream.pipeline,
        tasks=[*warned, *campaign],
        flights=flights,
        inputs=stream.inputs,
    )
    database_dir, database_error = write_database_files(report_plan, start.store, statuses)
    report_path, columns, rows, report_error = write_report(
        report_plan, start.store, statuses, database_dir=database_dir
    )
    return RunOutputs(
        report_path, columns, rows, report_error or database_error, database_dir, statuses
    )
