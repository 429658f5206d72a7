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
        # renewal (the renewer's thread) and release (the holder's) one at a time: a
        # renewal that read the claim just before its release must not write it back
        self._guard = threading.Lock()
        self._released = False

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
        (taken over after its lease ran out, or removed, or released)."""
        with self._guard:
            if self._released or not self._mine():
                return False
            self.store._backend.overwrite(
                self.stage, self.key + _CLAIM, _claim_doc(self._token, self.lease)
            )
            return True

    def release(self) -> None:
        """Give the claim up (after committing, or when the task failed)."""
        _RENEWER.discard(self)
        with self._guard:
            self._released = True
            if self._mine():
                self.store._backend.delete(self.stage, self.key + _CLAIM)

    def __enter__(self) -> Claim:
        _RENEWER.add(self)
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class _Renewer:
    """One thread per process renews every claim held as a context manager, each every
    ``lease / 3`` seconds: a thread started and joined per task cost more than a
    small task itself."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._held: dict[int, tuple[Claim, float]] = {}  # id -> (claim, next renewal)
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    def add(self, claim: Claim) -> None:
        with self._lock:
            self._held[id(claim)] = (claim, time.monotonic() + claim.lease / 3)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, daemon=True)
                self._thread.start()
        self._wake.set()

    def discard(self, claim: Claim) -> None:
        with self._lock:
            self._held.pop(id(claim), None)

    def forget(self) -> None:
        """In a forked child: the parent's claims are the parent's to renew."""
        self._lock = threading.Lock()
        self._held, self._thread, self._wake = {}, None, threading.Event()

    def _loop(self) -> None:
        while True:
            self._wake.clear()  # before looking: a claim added from here on wakes the wait
            with self._lock:
                now = time.monotonic()
                due = [c for c, t in self._held.values() if t <= now]
                later = [t for _, t in self._held.values() if t > now]
            for claim in due:
                try:
                    kept = claim.renew()
                except Exception:  # a renewal that fails leaves the lease to run out
                    kept = False
                with self._lock:
                    if id(claim) in self._held:
                        if kept:
                            self._held[id(claim)] = (claim, now + claim.lease / 3)
                        else:
                            del self._held[id(claim)]
            if not due:
                self._wake.wait(min(later, default=now + 1.0) - now)


_RENEWER = _Renewer()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_RENEWER.forget)
