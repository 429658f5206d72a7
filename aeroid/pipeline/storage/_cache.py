"""The run's cache of records: what a process committed or read (digests checked) in
one run, handed to the run's later tasks without reading the entry back.

Entries are immutable, so the copy in memory is what a verified read would
return. A new scope (the next run) starts empty, so every run verifies what it
reads at least once; outside a scope nothing is cached.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .store import ResultStore

__all__ = ["record_cache"]

_CACHE_BYTES = 256 * 2**20


class _RecordCache:
    def __init__(self) -> None:
        self.scope: str | None = None
        self.items: OrderedDict[tuple[str, str, str], tuple[Any, int]] = OrderedDict()
        self.nbytes = 0
        self.lock = threading.Lock()
        self.stores: dict[str, ResultStore] = {}  # opened in this scope, by root

    def enter(self, scope: str | None) -> None:
        with self.lock:
            if scope != self.scope:
                self.items.clear()
                self.stores.clear()
                self.nbytes = 0
                self.scope = scope

    def get(self, ident: tuple[str, str, str]) -> Any:
        with self.lock:
            if self.scope is None or ident not in self.items:
                return None
            self.items.move_to_end(ident)
            return self.items[ident][0]

    def put(self, ident: tuple[str, str, str], record: Any, nbytes: int) -> None:
        with self.lock:
            if self.scope is None or nbytes > _CACHE_BYTES or ident in self.items:
                return
            self.items[ident] = (record, nbytes)
            self.nbytes += nbytes
            while self.nbytes > _CACHE_BYTES:
                _, (_, n) = self.items.popitem(last=False)
                self.nbytes -= n


_CACHE = _RecordCache()


def record_cache(scope: str | None) -> None:
    """Cache records in this process for the run `scope` (None: stop caching, forget all)."""
    _CACHE.enter(scope)
