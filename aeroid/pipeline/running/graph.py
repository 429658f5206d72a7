"""The task graph an executor runs: chains of one flight's consecutive steps, and the
parts of split tasks.

A chain runs in one process as one Dask task, which keeps the scheduler's
per-task cost off the flight's steps; a split task's parts run in parallel
before the chain that combines them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from ..plans.planning import Task
from ..stages import STAGES
from . import execution
from .execution import n_parts, options_of

__all__ = ["Node", "chains", "nodes", "part_deps", "segments"]


def part_deps(task: Task, index: int, deps: list[Any], owner: Mapping[str, Any]) -> list[Any]:
    """The futures part `index` of a split task waits for (see `Stage.part_flights`)."""
    stage = STAGES.get(task.stage)
    if stage is None or stage.part_flights is None or task.flight is not None:
        return deps
    try:
        flights = stage.part_flights(options_of(task), frozenset(task.upstream), index)
    except Exception:
        return deps  # the part itself will report the problem
    if flights is None:
        return deps
    lists = [ref for ref in task.upstream.values() if isinstance(ref, list)]
    # `flights` may run far past the campaign's flights (every 16th of up to 65,536)
    n = max(map(len, lists), default=0)
    wanted = [j for j in flights if 0 <= j < n]
    keys = [ref[j] for ref in lists for j in wanted if j < len(ref)]
    return list(dict.fromkeys(owner[k] for k in keys if k in owner))


def segments(tasks: list[Task]) -> list[tuple[list[Task], Task | None]]:
    """Split tasks (plan order) into chains of one flight's consecutive steps.

    A split task (it has parts) starts a new chain, whose parts run first;
    campaign tasks are chains of their own. Returns (chain, split task or None).
    """
    out: list[tuple[list[Task], Task | None]] = []
    current: list[Task] = []
    split: Task | None = None
    flight: object = object()
    for t in tasks:
        n = n_parts(t)
        if current and (t.flight != flight or t.flight is None or n > 1):
            out.append((current, split))
            current, split = [], None
        if n > 1:
            split = t
        current.append(t)
        flight = t.flight
    if current:
        out.append((current, split))
    return out


def chains(
    tasks: list[Task], owner: Mapping[str, Any]
) -> Iterator[tuple[list[Task], Task | None, list[Any]]]:
    """The chains of `segments`, each with what it waits for: the owners of its upstream
    tasks in `owner` (task key -> what runs it), which the caller fills as it goes."""
    for chain, split in segments(tasks):
        # identical steps of a pipeline share a key: run once (plans refuse identical flights)
        chain = [t for t in chain if t.key not in owner]
        if not chain:
            continue
        own = {t.key for t in chain}
        deps = list(
            dict.fromkeys(
                owner[k] for t in chain for k in t.upstream_keys if k in owner and k not in own
            )
        )
        yield chain, split, deps


@dataclass
class Node:
    """One Dask task of a run: a chain of one flight's steps, or one part of a split task."""

    name: str
    call: Callable[..., Any]  # execute_chain or execute_part, with its fixed arguments bound
    deps: list[str]  # the nodes whose results it takes, in order
    chain: list[Task] | None = None  # None for a part
    parts: list[str] = field(default_factory=list)  # a chain's parts, run before it
    part: tuple[Task, int] | None = None


def nodes(
    tasks: list[Task], store_root: str, scope: str, read_root: str | None = None
) -> list[Node]:
    """The graph of a run, one node per chain (`segments`) and per part of a split task,
    in the order a scheduler is given them (`read_root`: see `execute_task`)."""
    owner: dict[str, str] = {}  # task key -> name of the chain that runs it
    out: list[Node] = []
    for chain, split, deps in chains(tasks, owner):
        head = chain[0]
        name = f"{head.flight or 'campaign'}-{head.step}-{head.key}"
        parts: list[str] = []
        if split is not None and head is split:
            for i in range(n_parts(split)):
                part: Callable[..., Any] = functools.partial(
                    execution.execute_part, split, store_root, i, scope=scope, read_root=read_root
                )
                pdeps = part_deps(split, i, deps, owner)
                out.append(Node(f"{name}-part{i}", part, pdeps, part=(split, i)))
                parts.append(out[-1].name)
        run_chain: Callable[..., Any] = functools.partial(
            execution.execute_chain, chain, store_root, scope=scope, read_root=read_root
        )
        out.append(Node(name, run_chain, deps, chain=chain, parts=parts))
        for t in chain:
            owner[t.key] = name
    return out
