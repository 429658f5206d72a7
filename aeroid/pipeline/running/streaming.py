"""A run's plan streamed: planned a flight at a time, pruned of what the store holds,
and run a window of flights at a time, each task then kept as a line of a `Ledger`.

`StreamedRun.consume` takes a `PlanStream`; a stored task is settled at once
(trusted from the store's index of checked entries, or CRC-checked); the others
wait in a window, which goes to the executor once it holds `WINDOW_FLIGHTS`
flights, or at the end of the stream with the campaign tasks. A window is run
whole before the next is planned: what this process holds beyond the ledger is
one window's tasks, graph and statuses. A task that failed is kept whole and
handed to the later tasks that take it (a campaign task, in a later window,
reports the failed flight instead of reading its missing result); other
results reach later tasks through the store.
"""

from __future__ import annotations

import gc
import sys
import time
import uuid
from collections.abc import Iterator
from typing import Any

from ..plans.planning import Task
from ..plans.run_plan import RunPlan
from .execution import TaskStatus
from .executors import executor_for
from .ledger import Ledger

__all__ = ["WINDOW_FLIGHTS", "StreamedRun"]

# flights handed to the executor at once: their tasks, graph and statuses are what this
# process holds beyond the ledger (a few MB); a window's tail leaves workers idle for
# at most one flight's chain each
WINDOW_FLIGHTS = 2_000


class StreamedRun:
    """The state of a streamed run: the ledger, the store's look, and the window of
    tasks to run."""

    def __init__(self, start: RunPlan, ledger: Ledger, progress: bool):
        self.store = start.store
        self.look = start.look  # the store's one look, asked a task at a time
        self.ledger = ledger
        self.scope = uuid.uuid4().hex
        self.executor = executor_for(start.config.scheduler, start.config.workers)
        self.failed: dict[str, TaskStatus] = {}  # run here and failed: later tasks take them
        self.campaign: list[Task] = []
        self.campaign_index: dict[str, int] = {}
        self.window: list[tuple[int, Task]] = []
        self.twins: list[tuple[int, int]] = []  # (task, earlier task of the same key)
        self.window_flights = 0
        self.t_plan = self.t_run = 0.0
        self.t_check = start.look_seconds
        self.bar: Any = None
        if progress and sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(desc="aeroid", unit="task", file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

    def consume(self, tasks: Iterator[Task]) -> None:
        """Plan, prune and run the stream a window of flights at a time (`tasks`: the
        plan stream's, which keeps the plan's keys in the store at its end)."""
        flight: str | None = None
        seen: dict[str, int] = {}  # the current flight's keys (a key planned twice runs once)
        while True:
            t = time.perf_counter()
            task = next(tasks, None)
            self.t_plan += time.perf_counter() - t
            if task is None:
                break
            if task.flight != flight or task.flight is None:
                flight, seen = task.flight, {}
                if self.window_flights >= WINDOW_FLIGHTS and task.flight is not None:
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
        self._run_window()

    def _prune(self, index: int, task: Task) -> None:
        """Settle a stored task (trusted from the index, or CRC-checked), or queue it."""
        found = self.look.find(self.store, (task.stage, task.key))
        if found is None:
            self.window.append((index, task))
            return
        if isinstance(found, str):  # its bytes fail their checksum
            status = TaskStatus(task.key, task.step, task.flight, "failed", error=found)
        else:
            status = TaskStatus(task.key, task.step, task.flight, "cached", warnings=found)
        self.ledger.settle(index, status)
        self._tick()

    def _tick(self, _: object = None) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def _run_window(self) -> None:
        """Run the queued tasks, settle their statuses, and let them go."""
        window, self.window, self.window_flights = self.window, [], 0
        # the stream pauses the cyclic collector while it plans (`PlanStream`), also while
        # it waits here: the executor's graphs, futures and tracebacks make cycles
        paused = not gc.isenabled()
        if paused:
            gc.enable()
        try:
            self._settle_window(window)
        finally:
            if paused:
                gc.disable()
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
