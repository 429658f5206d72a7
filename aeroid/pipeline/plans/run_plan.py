"""A run's start, in one call: the config checked, the plan stream, the report path
checked against the campaign's files, and the store opened with its one look.

`plan_run` is all a run asks of the plan seam: it hands back a `RunPlan`
whose `tasks` the run reads a task at a time (planned a flight at a time, so
memory stays bounded per flight); once read to the end, the stream keeps the
plan's keys in the store (`plan_cache`) for ``aeroid status``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import ConfigError
from ..definition import Pipeline
from ..storage import verified
from ..storage.store import ResultStore
from . import plan_cache
from .config import CampaignConfig, load_config, workers_problem
from .plan_cache import PlannedTask
from .planning import PlanStream, Task, plan_stream, store_argument

__all__ = [
    "HTML_MARKER",
    "MD_MARKER",
    "RunPlan",
    "check_report_path",
    "html_report_path",
    "plan_run",
    "report_is_ours",
]

# the last line of every Markdown report a run writes: a file without it is not one of
# ours, and is never overwritten
MD_MARKER = "<!-- written by aeroid: every run of the campaign rewrites this file -->"
HTML_MARKER = "<!-- aeroid campaign report"


@dataclass(frozen=True)
class RunPlan:
    """What a run starts from (`plan_run`).

    Attributes
    ----------
    config : CampaignConfig
        The config, checked, with the run's overrides (store, scheduler, workers).
    stream : PlanStream
        Its plan; read through `tasks`.
    tasks : iterator of Task
        The stream's tasks in plan order; at its end the plan's keys are stored.
    store : ResultStore
        The store, opened.
    look : verified.Lookup
        The one look at what the store holds of the plan's stages.
    look_seconds : float
        What opening the look took (part of a run's cache check).
    """

    config: CampaignConfig
    stream: PlanStream
    tasks: Iterator[Task]
    store: ResultStore
    look: verified.Lookup
    look_seconds: float


def plan_run(
    config: CampaignConfig | str | Path,
    *,
    store: str | Path | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    pipeline: Pipeline | None = None,
    allow_imports: bool = False,
    planned: Callable[[], Iterable[PlannedTask]],
) -> RunPlan:
    """Check `config` with the run's overrides, plan it as a stream, refuse a report
    path that must not be written, and open the store and its look.

    `planned` gives, once the stream is read to the end, every task as planned (the
    run's ledger): the stream then keeps them in the store (`plan_cache.save`).
    """
    if not isinstance(config, CampaignConfig):
        config = load_config(config)
    updates: dict[str, Any] = {}
    if store is not None:
        updates["store"] = store_argument(store)
    if scheduler is not None:
        updates["scheduler"] = scheduler
    if workers is not None:
        if problem := workers_problem(workers):  # model_copy below skips the validators
            raise ConfigError(f"workers: {problem}")
        updates["workers"] = workers
    if updates:
        config = config.model_copy(update=updates)
    stream = plan_stream(config, pipeline=pipeline, allow_imports=allow_imports)
    if stream.has_campaign_tasks:
        # before the store is opened: a refused config leaves no new folder behind
        check_report_path(config, stream.input_files())
    result_store = ResultStore(config.store_location)
    t = time.perf_counter()
    # a listing per stage and the index of entries checked whole, read once: an entry
    # the index holds with the same signature is trusted unopened (`verified`)
    look = verified.look_up(result_store, stream.stages)
    seconds = time.perf_counter() - t
    tasks = _kept(stream, result_store, planned)
    return RunPlan(config, stream, tasks, result_store, look, seconds)


def _kept(
    stream: PlanStream, store: ResultStore, planned: Callable[[], Iterable[PlannedTask]]
) -> Iterator[Task]:
    """The stream's tasks; at its end, the plan's keys kept for ``aeroid status`` on the
    unchanged campaign (`plan_cache`)."""
    yield from stream
    plan_cache.save(store, stream.inputs, planned())


def html_report_path(markdown_path: Path) -> Path:
    """Where the HTML twin of a campaign report lives."""
    return markdown_path.with_suffix(".html")


def report_is_ours(path: Path, marker: str) -> bool:
    """`path` is absent, or a report an earlier run wrote (it holds `marker`)."""
    if not path.exists():
        return True
    try:
        return marker.encode() in path.read_bytes()
    except OSError:
        return False


def check_report_path(config: CampaignConfig, inputs: list[Path]) -> None:
    """Refuse, before anything runs, a report path that cannot or must not be written.

    `inputs`: the campaign's files (flight data, the config, the pipeline), which a
    report must never replace.
    """
    path = config.report_path
    where = f"{config.source}: report" if config.report else f"store {config.store}"
    if config.name is not None and ("/" in config.name or "\\" in config.name):
        raise ConfigError(
            f"{config.source}: name: {config.name!r} names the report file; "
            "no path separators in it"
        )
    if path.suffix.lower() in (".html", ".htm"):
        raise ConfigError(
            f"{where}: {path.name}: name the Markdown report (.md); its HTML twin is written "
            "beside it"
        )
    if path.is_dir():
        raise ConfigError(f"{where}: {path} is a folder; name a .md file")
    resolved = {p.resolve() for p in inputs}
    for target in (path, html_report_path(path)):
        if target.resolve() in resolved:
            raise ConfigError(f"{where}: {target} is an input of the campaign; name another file")
    html = html_report_path(path)
    # a Markdown report of an earlier version has no marker; its HTML twin has one
    md_ours = report_is_ours(path, MD_MARKER) or (
        html.is_file() and report_is_ours(html, HTML_MARKER)
    )
    for target, ours in ((path, md_ours), (html, report_is_ours(html, HTML_MARKER))):
        if not ours:
            raise ConfigError(
                f"{where}: {target} exists and was not written by aeroid; "
                "move it away or name another report file"
            )
    # the folder is made when the report is written: here only whether it can be (a
    # refused config leaves nothing behind)
    folder = path.parent
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"{where}: cannot make {path.parent} ({folder} is a file)")
    if not os.access(folder, os.W_OK):
        raise ConfigError(f"{where}: {folder} is not writable")
