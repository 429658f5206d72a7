"""A task's work in its stage, in one call: its options read, its context built, the
stage run (or its parts combined), the briefs campaign tasks take of the result, and
the files the stage makes beside the report from it (`Stage.files`).

The run seam gathers what a task reads (its inputs from the store, its model, its
seed) and hands it here; `perform` returns the record and its briefs, which the run
gives to the store seam to keep.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ...errors import PipelineError
from ...support import quiet_warnings
from . import STAGES, Stage, StageContext

if TYPE_CHECKING:
    from ..plans.planning import Task

__all__ = ["Work", "options_of", "perform", "stage_of"]


@dataclass(frozen=True)
class Work:
    """A stage's result for one task, the briefs made of it (``"consumer/role"``) and the
    files made of it beside the report (`Stage.files`; none where they failed: the run
    then makes them itself and reports the problem)."""

    record: Any
    briefs: Mapping[str, Any]
    files: Mapping[str, bytes] = field(default_factory=dict)


def stage_of(task: Task) -> Stage:
    """The stage that runs `task` (registered by the built-in stages or its pipeline)."""
    stage = STAGES.get(task.stage)
    if stage is None:
        raise PipelineError(f"unknown stage {task.stage!r}")
    return stage


def options_of(task: Task) -> Any:
    """A task's options model, from the options it runs with (old names accepted)."""
    model = STAGES[task.stage].options
    known = set(model.model_fields) | set(getattr(model, "renamed", {}))
    return model.model_validate({k: v for k, v in task.options.items() if k in known})


def context_of(task: Task, stage: Stage, gathered: Mapping[str, Any]) -> StageContext:
    """The context `stage` runs `task` in: its options and what the run `gathered`
    (inputs, model, seed, failures, the briefs given by upstream tasks)."""
    return StageContext(
        options=options_of(task),
        flight=task.flight,
        source=task.source,
        flights=task.flights,
        summarize=stage.brief,
        code_dir=task.code_dir,
        **gathered,
    )


def perform(task: Task, gathered: Mapping[str, Any], parts: Sequence[Any] | None) -> Work:
    """Run `task`'s stage on what the run `gathered` (or combine its `parts`' values)
    and make the briefs campaign tasks take of the record (`Stage.brief`).

    A brief that cannot be made is left out: the campaign task then makes it itself
    and reports the problem. So is a None brief (a role the stage reads whole),
    which would only travel for nothing.
    """
    stage = stage_of(task)
    ctx = context_of(task, stage, gathered)
    if parts is not None:
        if stage.combine is None:
            raise PipelineError(f"stage {task.stage!r} does not combine parts")
        record = stage.combine(ctx, list(parts))
    else:
        record = stage.run(ctx)
    briefs: dict[str, Any] = {}
    with contextlib.suppress(Exception):
        for consumer, role in task.briefs:
            make = STAGES[consumer].brief
            value = None if make is None else make(role, record)
            if value is not None:
                briefs[f"{consumer}/{role}"] = value
    files: dict[str, bytes] = {}
    if stage.files is not None:
        # warnings shown, if at all, where the run makes them
        with contextlib.suppress(Exception), quiet_warnings():
            files = dict(stage.files(record))
    return Work(record, briefs, files)
