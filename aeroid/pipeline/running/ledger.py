"""What a run keeps of each task once it is done: a few bytes, not its status.

A run streams its plan (`planning.plan_stream`) and hands each window of
flights to the executor; once a window's results are committed, the tasks and
their statuses are let go. The `Ledger` keeps, per task, its step, flight,
key and status code in flat arrays (about 40 bytes a task, the flight's name
once a flight), and a task's whole `TaskStatus` only where it says more than
its code: an error, warnings, a campaign task's table. `statuses` reads it as
the mapping key -> `TaskStatus` a run always returned.
"""

from __future__ import annotations

import contextlib
from array import array
from collections.abc import Iterator, MutableMapping
from typing import NamedTuple

from ..plans.plan_cache import PlannedTask
from ..plans.planning import Task
from .execution import BY_ANOTHER_RUN, TaskStatus

__all__ = ["Ledger", "Statuses"]

_CODES = ("pending", "computed", "cached", BY_ANOTHER_RUN, "failed")
_CODE = {name: i for i, name in enumerate(_CODES)}


class _Row(NamedTuple):
    step: str
    stage: str
    flight: str | None
    key: str
    code: int
    cached: bool


class Ledger:
    """Every task of a run in plan order, with its status, compactly (module notes)."""

    def __init__(self) -> None:
        self._steps: list[tuple[str, str]] = []  # (step, stage)
        self._step_of: dict[tuple[str, str], int] = {}
        self.flights: list[str] = []  # the run's flights, in plan order
        self._step = array("H")
        self._flight = array("l")  # index into `flights`; -1: a campaign task
        self._code = array("B")
        self._stored = array("B")  # whether a computed result was committed
        self._keys = bytearray()  # 32 bytes a task
        self._full: dict[int, TaskStatus] = {}  # statuses with more than a code
        self._where: dict[str, int] | None = None  # key -> first index, made on demand
        self.compute_seconds = 0.0

    def __len__(self) -> int:
        return len(self._code)

    def add(self, task: Task) -> int:
        """Enter a task (pending); its index."""
        ident = (task.step, task.stage)
        step = self._step_of.setdefault(ident, len(self._steps))
        if step == len(self._steps):
            self._steps.append(ident)
        if task.flight is None:
            flight = -1
        else:
            # a flight's tasks come together: a new name is a new flight
            if not self.flights or self.flights[-1] != task.flight:
                self.flights.append(task.flight)
            flight = len(self.flights) - 1
        self._step.append(step)
        self._flight.append(flight)
        self._code.append(0)
        self._stored.append(0)
        self._keys += bytes.fromhex(task.key)
        if self._where is not None:
            self._where.setdefault(task.key, len(self._code) - 1)
        return len(self._code) - 1

    def settle(self, index: int, status: TaskStatus) -> None:
        """Record the status of task `index`."""
        if self._code[index] == 0:  # its first status: a report's rewrite adds no time
            self.compute_seconds += status.compute_seconds
        self._code[index] = _CODE[status.status]
        self._stored[index] = int(status.cached)
        if _telling(status):
            self._full[index] = status
        else:
            self._full.pop(index, None)

    def row(self, index: int) -> _Row:
        step, stage = self._steps[self._step[index]]
        f = self._flight[index]
        key = self._keys[32 * index : 32 * index + 32].hex()
        return _Row(step, stage, None if f < 0 else self.flights[f], key, *self._state(index))

    def _state(self, index: int) -> tuple[int, bool]:
        return self._code[index], bool(self._stored[index])

    def status(self, index: int) -> TaskStatus:
        """Task `index`'s status, whole where it was kept, else rebuilt from its code."""
        if index in self._full:
            return self._full[index]
        r = self.row(index)
        return TaskStatus(r.key, r.step, r.flight, _CODES[r.code], cached=r.cached)

    def index(self, key: str) -> int:
        """The index of the (first) task whose key is `key`; KeyError if none."""
        if self._where is None:
            where: dict[str, int] = {}
            for i in range(len(self)):
                where.setdefault(self._keys[32 * i : 32 * i + 32].hex(), i)
            self._where = where
        return self._where[key]

    def n_keys(self) -> int:
        """How many distinct keys the tasks have."""
        with contextlib.suppress(KeyError):
            self.index("")  # makes the key -> index map
        return len(self._where or ())

    def count(self, status: str) -> int:
        """Tasks (as planned: a key planned twice counts twice) with this status."""
        return self._code.count(_CODE[status])

    def planned(self) -> Iterator[PlannedTask]:
        """Every task as a stored plan keeps it (`plan_cache`)."""
        for i in range(len(self)):
            r = self.row(i)
            yield PlannedTask(r.step, r.stage, r.flight, r.key)

    def committed(self) -> Iterator[tuple[str, str, tuple[str, ...]]]:
        """(stage, key, warnings) of every task this run computed and committed."""
        computed = _CODE["computed"]
        for i in range(len(self)):
            if self._code[i] == computed and self._stored[i]:
                r = self.row(i)
                warnings = self._full[i].warnings if i in self._full else ()
                yield r.stage, r.key, warnings

    def told(self) -> Iterator[tuple[PlannedTask, TaskStatus]]:
        """The tasks whose status says more than its code (errors, warnings), in order."""
        for i in sorted(self._full):
            r = self.row(i)
            yield PlannedTask(r.step, r.stage, r.flight, r.key), self._full[i]

    @property
    def statuses(self) -> Statuses:
        return Statuses(self)


def _telling(status: TaskStatus) -> bool:
    """Whether a status says more than its code and flight (kept whole)."""
    return bool(
        status.error
        or status.warnings
        or status.failures
        or status.flight is None
        or status.traceback
        or status.markdown is not None
    )


class Statuses(MutableMapping[str, TaskStatus]):
    """A run's statuses by task key, read from its `Ledger` (in plan order, each key once)."""

    def __init__(self, ledger: Ledger) -> None:
        self._ledger = ledger

    def __getitem__(self, key: str) -> TaskStatus:
        return self._ledger.status(self._ledger.index(key))

    def __setitem__(self, key: str, status: TaskStatus) -> None:
        self._ledger.settle(self._ledger.index(key), status)

    def __delitem__(self, key: str) -> None:
        raise TypeError("a run's statuses are not removed")

    def __iter__(self) -> Iterator[str]:
        seen: set[str] = set()
        for i in range(len(self._ledger)):
            key = self._ledger.row(i).key
            if key not in seen:
                seen.add(key)
                yield key

    def __len__(self) -> int:
        return self._ledger.n_keys()
