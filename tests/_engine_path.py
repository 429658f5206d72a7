"""Following one task through the campaign engine with `sys.setprofile`.

`follow` runs a campaign in this process (``workers=0``) and records one task's
way, from ``run(config)`` until ``run`` returns: every call and return that
changes the innermost engine module (consecutive frames in one module are one
stop). Work done for the run's other tasks (their own ``execute_task`` or
``execute_part``) is left out; what the run does for all its tasks at once
(planning, the look for stored entries, the report at the end) is on every
task's way, before and after the task's own execution (its ``execute_task``).

The accessors of `MESSAGES` (the task the plan hands to the run: plain data that
travels to workers) are read as data, not as a visit to the module defining them.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

ENGINE = "aeroid.pipeline"
MESSAGES = ("Task.",)
_TASK_FRAMES = {"execute_task", "execute_part"}


def _module(frame: FrameType) -> str:
    return str(frame.f_globals.get("__name__", ""))


def _engine(frame: FrameType) -> bool:
    name = _module(frame)
    if not (name == ENGINE or name.startswith(ENGINE + ".")):
        return False
    return not frame.f_code.co_qualname.startswith(MESSAGES)


@dataclass(frozen=True)
class Stop:
    module: str
    kind: str  # "call" or "return"
    in_task: bool  # inside the task's own execute_task
    seam: str | None
    entry: bool = False  # a call that moved into another seam
    on_stack: frozenset[str] = frozenset()  # seams below it when it was entered
    function: str = ""
    caller: str = ""  # the engine module a call came from


@dataclass
class Way:
    """The stops of one task's way, in order."""

    stops: list[Stop] = field(default_factory=list)

    def part(self, in_task: bool | None = None) -> list[Stop]:
        return [s for s in self.stops if in_task is None or s.in_task == in_task]

    def counts(self, in_task: bool | None = None) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.part(in_task):
            leaf = s.module.rsplit(".", 1)[-1]
            out[leaf] = out.get(leaf, 0) + 1
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))

    def entries(self, in_task: bool | None = None) -> list[str]:
        return [s.seam for s in self.part(in_task) if s.entry and s.seam is not None]

    def reentered(self, in_task: bool | None = None) -> list[str]:
        """Seams entered again after every frame of theirs had returned (a seam
        called back while one of its frames waits below was never left)."""
        seen: set[str] = set()
        again = []
        for s in self.part(in_task):
            if not s.entry or s.seam is None or s.seam in s.on_stack:
                continue
            if s.seam in seen:
                again.append(s.seam)
            seen.add(s.seam)
        return again

    def calls_from(self, callers: Collection[str]) -> list[tuple[str, str]]:
        """(seam, function) of each call that the modules `callers` make into another
        seam, outside the task's own execution. What a seam's call does inside (the
        report reading the store) is that seam's own."""
        return [
            (s.seam, s.function)
            for s in self.part(False)
            if s.entry and s.seam is not None and s.caller in callers
        ]

    def summary(self, in_task: bool | None = None) -> str:
        part = self.part(in_task)
        returns = sum(1 for s in part if s.kind == "return")
        modules = {s.module for s in part}
        return f"{len(part)} stops in {len(modules)} modules, {returns} of them returns"


def _innermost(frame: FrameType | None) -> FrameType | None:
    while frame is not None and not _engine(frame):
        frame = frame.f_back
    return frame


def _task_of(frame: FrameType | None) -> str | None:
    """The key of the task whose ``execute_task``/``execute_part`` runs `frame`, if any."""
    while frame is not None:
        if frame.f_code.co_name in _TASK_FRAMES and _engine(frame):
            return str(getattr(frame.f_locals.get("task"), "key", ""))
        frame = frame.f_back
    return None


def follow(
    config: Path,
    step: str,
    seam_of: Callable[[str], str | None],
    *,
    flight_index: int | None = 0,
) -> tuple[Way, Any]:
    """The way of the task of `step` on the campaign's `flight_index`-th flight (None: the
    campaign-level task of `step`).

    `seam_of` maps an engine module to its seam (None: shared by all, no seam).
    Returns the way and the run's summary.
    """
    from aeroid.pipeline import plan, run

    planned = plan(config)
    flights = list(dict.fromkeys(t.flight for t in planned.tasks if t.flight is not None))
    flight = None if flight_index is None else flights[flight_index]
    key = next(t.key for t in planned.tasks if t.step == step and t.flight == flight)
    way = Way()
    state: dict[str, Any] = {"current": None}

    def seams_below(frame: FrameType | None) -> frozenset[str]:
        found = set()
        while frame is not None:
            if _engine(frame) and (seam := seam_of(_module(frame))) is not None:
                found.add(seam)
            frame = frame.f_back
        return frozenset(found)

    def note(frame: FrameType, kind: str, owner: str | None) -> None:
        module, before = _module(frame), state["current"]
        if module == before:
            return
        state["current"] = module
        seam = seam_of(module)
        entry = kind == "call" and seam is not None and (before is None or seam_of(before) != seam)
        below = seams_below(frame.f_back) if entry else frozenset()
        function = frame.f_code.co_qualname
        caller = _innermost(frame.f_back) if kind == "call" else None
        came_from = "" if caller is None else _module(caller)
        way.stops.append(Stop(module, kind, owner == key, seam, entry, below, function, came_from))

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        if event not in ("call", "return") or not _engine(frame):
            return  # the library, the standard library: the innermost engine frame stays
        owner = _task_of(frame)
        if owner is not None and owner != key:
            return  # another task's work
        if event == "call":
            note(frame, "call", owner)
            return
        caller = _innermost(frame.f_back)
        if caller is not None:
            note(caller, "return", _task_of(caller))

    sys.setprofile(profile)
    try:
        summary = run(config, workers=0)
    finally:
        sys.setprofile(None)
    return way, summary
