"""Stored plans: the keys of a campaign's tasks, kept in its store, so that ``aeroid
status`` on an unchanged campaign reads them instead of planning.

A plan is stored under ``.plans/`` in the store (one compressed JSON file of a
few bytes a task: step, flight, key), named by the digest of everything its
keys depend on (`inputs_digest`):

- the config as planned (less what only says where and how to run: store,
  workers, scheduler, report, the opt-ins) and the folder it was read from;
- the pipeline's steps, each stage's stored name, version and record type,
  each step's options as keyed, the user's code it runs (its text), and the
  model's fingerprint, as resolved now (a user's stage whose version or option
  defaults changed has new keys);
- the source of the installed ``aeroid`` package (its ``.py`` files), which
  writes the keys, flight specs and segment searches;
- each flight file's path, size, modification and change times (ns) and inode,
  taken before its contents are read: a key hashes the file's contents, and a
  file rewritten in place changes its times.

A change to any of these gives another digest, so a stored plan is never
found for it and the campaign is planned afresh. Only the newest `_MAX_PLANS`
plans are kept. Losing them costs only speed; a file that does not parse, or
whose digest or shape is not what its name says, is ignored. A stored plan is
as trustworthy as the store it is in: whoever can write the store can write
its results too.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import time
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from ...errors import StoreError
from ..keys import canonical_json
from ..stages import STAGES
from .config import FileFlights

if TYPE_CHECKING:
    from ..storage.store import ResultStore
    from .planning import Task, _Setup

__all__ = ["PlannedTask", "inputs_digest", "load", "rows", "save"]

FORMAT = 1
_MAX_PLANS = 4
# a stored plan is refused past this many bytes unpacked (a million flights take 200 MB)
_MAX_BYTES = 1 << 30
# what says where and how to run, not what the keys hash
_EXECUTION = {"store", "workers", "scheduler", "report", "allow_imports", "allow_network"}
_NAME = re.compile(r"([0-9]+)-([0-9a-f]{64})\.plan")
_HEX = re.compile(r"[0-9a-f]*")


class PlannedTask(NamedTuple):
    """A task as ``aeroid status`` shows it: its step, stored stage, flight and key."""

    step: str
    stage: str
    flight: str | None  # None for a campaign task
    key: str


def rows(tasks: Iterable[Task]) -> Iterator[PlannedTask]:
    """The `PlannedTask` of each task."""
    for t in tasks:
        yield PlannedTask(t.step, t.stage, t.flight, t.key)


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """SHA-256 of the ``aeroid`` package's Python source (names and contents)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode() + b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def inputs_digest(setup: _Setup, files: list[tuple[int, Path, FileFlights]]) -> str:
    """Digest of everything the keys of a plan depend on (see the module's notes):
    `setup` as resolved, `files` the config's flight files (``expand_files``)."""
    config, pipeline = setup.config, setup.pipeline
    steps = []
    for s in setup.steps:
        stage = STAGES[s.stage_name]
        steps.append(
            {
                "name": s.name,
                "stage": stage.key_name,
                "version": stage.version,
                "record_type": stage.record_type,
                "uses_model": stage.uses_model,
                "seeded": stage.seeded,
                "per_flight": s in pipeline.flight_steps,
                "inputs": dict(s.inputs),
                "options": setup.documents[s.name][0],
                "code": setup.code.get(s.name),
            }
        )
    head = {
        "format": FORMAT,
        "code": _code_digest(),
        "config": config.model_dump(mode="json", exclude=_EXECUTION),
        "base_dir": config.base_dir,
        "pipeline": [pipeline.name, setup.pipe_ref],
        "steps": steps,
        "selected": setup.selected,
        "model": setup.fingerprint,
    }
    h = hashlib.sha256(canonical_json(head))
    for index, path, _ in files:
        try:
            st = os.stat(path)
            sig = f"{st.st_size}:{st.st_mtime_ns}:{st.st_ctime_ns}:{st.st_ino}"
        except OSError as exc:
            sig = f"unreadable:{exc.errno}"
        h.update(f"\0{index}\0{path}\0{sig}".encode("utf-8", "surrogateescape"))
    return h.hexdigest()


def _document(inputs: str, planned: Iterable[PlannedTask]) -> bytes:
    """A stored plan: the steps and flights once, then per task their indices and key."""
    steps: dict[tuple[str, str], int] = {}
    flights: dict[str, int] = {}
    step_col: list[int] = []
    flight_col: list[int] = []
    keys: list[str] = []
    for t in planned:
        step_col.append(steps.setdefault((t.step, t.stage), len(steps)))
        flight_col.append(-1 if t.flight is None else flights.setdefault(t.flight, len(flights)))
        keys.append(t.key)
    doc = {
        "format": FORMAT,
        "inputs": inputs,
        "steps": [list(s) for s in steps],
        "flights": list(flights),
        "step": step_col,
        "flight": flight_col,
        "keys": "".join(keys),
    }
    text = json.dumps(doc, separators=(",", ":"), ensure_ascii=False).encode()
    return zlib.compress(text, 1)


def _parse(raw: bytes, inputs: str) -> list[PlannedTask] | None:
    """The tasks of a stored plan, or None where it is damaged or not the plan of
    `inputs`."""
    unpack = zlib.decompressobj()
    try:
        text = unpack.decompress(raw, _MAX_BYTES)
        if not unpack.eof or unpack.unconsumed_tail:
            return None  # cut short, or larger than any plan
        doc = json.loads(text)
        if doc["format"] != FORMAT or doc["inputs"] != inputs:
            return None
        steps = [(str(a), str(b)) for a, b in doc["steps"]]
        flights = [str(f) for f in doc["flights"]]
        step_col, flight_col, keys = doc["step"], doc["flight"], doc["keys"]
        n = len(step_col)
        if (
            len(flight_col) != n
            or not isinstance(keys, str)
            or len(keys) != 64 * n
            or not _HEX.fullmatch(keys)
        ):
            return None
        if n and not (
            0 <= min(step_col) <= max(step_col) < len(steps)
            and -1 <= min(flight_col) <= max(flight_col) < len(flights)
        ):
            return None
        names = [*flights, None]  # index -1: a campaign task
        return list(
            map(
                PlannedTask._make,
                zip(
                    [steps[s][0] for s in step_col],
                    [steps[s][1] for s in step_col],
                    [names[f] for f in flight_col],
                    [keys[i : i + 64] for i in range(0, 64 * n, 64)],
                    strict=True,
                ),
            )
        )
    except (zlib.error, ValueError, KeyError, TypeError):
        return None


def _names(store: ResultStore, inputs: str | None = None) -> list[str]:
    """The stored plans' file names, newest first (those of `inputs` only, if given)."""
    found = [
        (int(m[1]), name)
        for name in store._backend.plan_names()
        if (m := _NAME.fullmatch(name)) and (inputs is None or m[2] == inputs)
    ]
    return [name for _, name in sorted(found, reverse=True)]


def load(store: ResultStore, inputs: str) -> list[PlannedTask] | None:
    """The tasks of the plan stored for `inputs`, or None. Never raises."""
    try:
        for name in _names(store, inputs):
            raw = store._backend.read_plan(name)
            found = None if raw is None else _parse(raw, inputs)
            if found is not None:
                return found
            if raw is not None:  # damaged: removed, so that `save` writes it again
                store._backend.remove_plan(name)
    except (StoreError, OSError):
        pass
    return None


def save(store: ResultStore, inputs: str | None, planned: Iterable[PlannedTask]) -> bool:
    """Store a plan of `inputs` (unless one is stored already) and remove all but the
    newest `_MAX_PLANS`. Returns whether it wrote one; never raises (a read-only
    store keeps no plan)."""
    if inputs is None:
        return False
    try:
        names = _names(store)  # one listing (a request on an object store)
        if any(name.endswith(f"-{inputs}.plan") for name in names):
            return False
        store._backend.write_plan(f"{time.time_ns()}-{inputs}.plan", _document(inputs, planned))
        for old in names[_MAX_PLANS - 1 :]:
            store._backend.remove_plan(old)
    except (StoreError, OSError):
        return False
    return True
