"""Claims: runs sharing one store compute each key once (`ResultStore.claim`)."""

from __future__ import annotations

import json
import os
import threading
import time
from typing import TYPE_CHECKING

from ._backend import (
    _CLAIM,
    _pid_alive,
)
from ._store_paths import (
    _hostname,
)

if TYPE_CHECKING:
    from .store import ResultStore


def _claim_doc(token: str, lease: float) -> bytes:
    doc = {
        "pid": os.getpid(),
        "host": _hostname(),
        "expires": time.time() + lease,
        "lease": lease,
        "token": token,
    }
    return json.dumps(doc, separators=(",", ":")).encode("utf-8")


def _claim_stale(raw: bytes, age: float) -> bool:
    """True when the claim in `raw` no longer holds: its lease ran out, its process (on
    this host) is gone, or it is empty or garbled. A claim is written whole (a file
    moved into place, one PUT), so an unreadable one was left by a crash or a failing
    disk, never by a run still writing it: taken over at once."""
    try:
        doc = json.loads(raw)
        expires, host, pid = float(doc["expires"]), str(doc["host"]), int(doc["pid"])
    except (ValueError, KeyError, TypeError):
        return True
    if time.time() > expires:
        return True
    return host == _hostname() and pid != os.getpid() and not _pid_alive(pid)


class Claim:
    """A run's claim on computing one task: others wait for its entry instead.

    Made by `ResultStore.claim`. Hold it while computing and committing, then
    `release` it (or use it as a context manager, which also renews the lease
    in the background while the block runs). A claim whose lease runs out, or
    whose process died on this host, is taken over by the next run that asks.
    Claims only spare duplicate work: a commit never overwrites an entry, so
    two runs that both compute a key still store one result.
    """

    def __init__(self, store: ResultStore, stage: str, key: str, token: str, lease: float) -> None:
        self.store, self.stage, self.key = store, stage, key
        self.lease = lease
        self._token = token
        self._stop: threading.Event | None = None
        self._thread: threading.Thread | None = None

    def __repr__(self) -> str:
        return f"Claim({self.stage!r}, {self.key[:12]!r})"

    def _mine(self) -> bool:
        found = self.store._backend.read_small(self.stage, self.key + _CLAIM)
        if found is None:
            return False
        try:
            return bool(json.loads(found[0]).get("token") == self._token)
        except (ValueError, AttributeError):
            return False

    def renew(self) -> bool:
        """Extend the lease by `lease` seconds from now; False when the claim was lost
        (taken over after its lease ran out, or removed)."""
        if not self._mine():
            return False
        self.store._backend.overwrite(
            self.stage, self.key + _CLAIM, _claim_doc(self._token, self.lease)
        )
        return True

    def release(self) -> None:
        """Give the claim up (after committing, or when the task failed)."""
        if self._stop is not None:
            self._stop.set()
            if self._thread is not None and self._thread is not threading.current_thread():
                self._thread.join()
            self._stop = self._thread = None
        if self._mine():
            self.store._backend.delete(self.stage, self.key + _CLAIM)

    def _renewing(self, stop: threading.Event) -> None:
        while not stop.wait(self.lease / 3):
            try:
                if not self.renew():
                    return
            except Exception:  # a renewal that fails leaves the lease to run out
                return

    def __enter__(self) -> Claim:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._renewing, args=(self._stop,), daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
