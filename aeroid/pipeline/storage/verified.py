"""The index of entries checked whole: what an unchanged rerun trusts instead of
opening every stored result.

An entry is recorded when a run commits it (written from memory, its digests
computed from the record), when ``aeroid verify`` checks its digests, or when
a run finds its bytes pass their CRC-32. Each is recorded with its signature,
as the store's listing shows it (size and modification time in a folder; size
and ETag or time in an object store), and the warnings stored with it. A later
run counts a stored entry whose listing shows the same signature as cached
without opening it, so an unchanged rerun costs a listing per stage, not a
read per result; any other entry is read and CRC-checked as before. Damage
that keeps an entry's size and time (a bit flipped on a failing disk) is found
by ``aeroid verify``, which checks every digest and rewrites the index.

The index is a few small files under ``.index/`` in the store, one per run
that added to it (merged once there are more than `_MAX_FILES`), so runs
sharing a store never write the same file. Losing it costs only speed.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ...errors import StoreError

if TYPE_CHECKING:
    from .store import ResultStore

__all__ = ["Lookup", "Trusted", "look_up", "read_index", "record", "replace"]

FORMAT = 1
_MAX_FILES = 8

Ident = tuple[str, str]  # (stage, key)
Signature = tuple[int, str]  # (size, time or ETag) as the store's listing shows it
Known = tuple[Signature, tuple[str, ...]]  # signature, warnings stored with the entry


@dataclass
class Trusted:
    """The entries the index holds, and the files it was read from."""

    entries: dict[Ident, Known] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)

    def lookup(self, ident: Ident, signature: Signature | None) -> tuple[str, ...] | None:
        """The stored warnings of an entry recorded with this very signature, else None."""
        known = self.entries.get(ident)
        if known is None or signature is None or known[0] != signature:
            return None
        return known[1]


def read_index(store: ResultStore) -> Trusted:
    """The index of `store` (empty where it has none or it cannot be read)."""
    out = Trusted()
    try:
        files = store._backend.index_files()
    except (StoreError, OSError):
        return out
    for name, raw in files:
        out.files.append(name)
        try:
            doc = json.loads(raw)
            if doc.get("format") != FORMAT:
                continue
            for stage, key, size, tag, warnings in doc["entries"]:
                sig = (int(size), str(tag))
                out.entries[(str(stage), str(key))] = (sig, tuple(str(w) for w in warnings))
        except (ValueError, KeyError, TypeError, AttributeError):
            continue  # a damaged index file: its entries are checked the slow way
    return out


def _document(entries: Mapping[Ident, Known]) -> bytes:
    rows = [
        [stage, key, sig[0], sig[1], list(warnings)]
        for (stage, key), (sig, warnings) in sorted(entries.items())
    ]
    return json.dumps({"format": FORMAT, "entries": rows}, separators=(",", ":")).encode()


def _name() -> str:
    return f"{time.time_ns()}-{uuid.uuid4().hex[:12]}.json"


def record(store: ResultStore, entries: Mapping[Ident, Known], trusted: Trusted) -> None:
    """Add `entries` to the index (`trusted`: the index as read before the run).

    One new file per call; once there are more than `_MAX_FILES`, they are merged
    into one and the files read are removed. Never raises: the index is a speed-up.
    """
    if not entries:
        return
    try:
        if len(trusted.files) + 1 <= _MAX_FILES:
            store._backend.write_index(_name(), _document(entries))
            return
        replace(store, {**trusted.entries, **entries}, trusted.files)
    except (StoreError, OSError):
        pass


def replace(store: ResultStore, entries: Mapping[Ident, Known], old: Iterable[str]) -> None:
    """Write `entries` as the whole index, then remove the files `old` (``verify``)."""
    store._backend.write_index(_name(), _document(entries))
    for name in old:
        store._backend.remove_index(name)


@dataclass
class Lookup:
    """What a run finds stored of its tasks, a task at a time (`look_up` opens it), and
    what it keeps to add to the index once it has run the rest (`record_run`).

    It holds one listing per stage and the index, read once; `find` answers for one
    task, so a streamed run never holds more than the listing.
    """

    listed: dict[Ident, Signature]
    trusted: Trusted
    checked: dict[Ident, Known] = field(default_factory=dict)

    def find(self, store: ResultStore, ident: Ident) -> tuple[str, ...] | str | None:
        """None where `ident` is not stored (to be computed); else the warnings stored
        with its entry, trusted unopened where the index holds it with the listing's
        signature and CRC-checked otherwise; or a text saying why the entry cannot count
        as cached (its bytes fail their CRC-32)."""
        signature = self.listed.get(ident)
        if signature is None:
            return None
        known = self.trusted.lookup(ident, signature)
        if known is not None:
            return known
        stage, key = ident
        warnings = store.cached_warnings(stage, key)
        if warnings is None:
            where = store.path_for(stage, key)
            return f"{stage} entry {where} is corrupt: its bytes fail their checksum"
        self.checked[ident] = (signature, warnings)
        return warnings

    def record_run(
        self, store: ResultStore, committed: Iterable[tuple[Ident, tuple[str, ...]]]
    ) -> None:
        """Add to the index what the run CRC-checked and what it `committed` (written from
        memory, with their warnings): the next run trusts them unopened."""
        committed = list(committed)
        if committed:
            try:
                listed = store.signatures({stage for (stage, _), _ in committed})
            except (StoreError, OSError):
                listed = {}
            for ident, warnings in committed:
                if ident in listed:
                    self.checked[ident] = (listed[ident], warnings)
        record(store, self.checked, self.trusted)


def look_up(store: ResultStore, stages: Iterable[str]) -> Lookup:
    """Open a run's look at what is stored of `stages`: a listing per stage and the
    index of entries checked whole, each read once (`Lookup.find` then answers a task
    at a time)."""
    return Lookup(store.signatures(set(stages)), read_index(store))
