"""Runs sharing one store compute each key once: claims, their leases, and waiting."""

from __future__ import annotations

import json
import multiprocessing
import os
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from test_pipeline_store import Nested

from aeroid.errors import StoreError
from aeroid.pipeline import ResultStore
from aeroid.pipeline.keys import canonical_json, sha256_hex

N_KEYS = 12


def _key(i: int) -> str:
    return sha256_hex(canonical_json({"i": i}))


def _run(root: str, order: list[int], queue: multiprocessing.Queue, start: object) -> None:
    """What a run does with each task: claim it and compute it, or wait for the one
    computing it."""
    store = ResultStore(root)
    start.wait()  # type: ignore[attr-defined]
    outcome = {}
    for i in order:
        key = _key(i)
        while True:
            if store.exists("x", key):
                outcome[i] = "cached"
                break
            claim = store.claim("x", key, lease=5.0)
            if claim is not None:
                with claim:
                    time.sleep(0.02)  # the computing
                    committed = store.commit(
                        "x", key, Nested(str(i), np.arange(3.0)), task={"i": i}
                    )
                outcome[i] = "computed" if committed else "refused"
                break
            if store.wait_for("x", key, timeout=30.0):
                outcome[i] = "by another run"
                break
    queue.put((os.getpid(), outcome))


def test_two_processes_claiming_the_same_keys_compute_each_once(tmp_path):
    root = str(tmp_path / "s")
    ResultStore(root)
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    start = ctx.Barrier(2)
    # the same order: both runs reach every key together
    procs = [ctx.Process(target=_run, args=(root, list(range(N_KEYS)), queue, start)) for _ in "ab"]
    for p in procs:
        p.start()
    results = [queue.get(timeout=60) for _ in procs]
    for p in procs:
        p.join(timeout=30)
        assert p.exitcode == 0
    outcomes = [r[1] for r in results]
    for i in range(N_KEYS):
        seen = sorted(o[i] for o in outcomes)
        # computed exactly once; the other run counts it as another's (or as cached,
        # when it came to the key after the commit)
        assert seen.count("computed") == 1, (i, seen)
        assert set(seen) <= {"computed", "by another run", "cached"}, (i, seen)
    assert sum(list(o.values()).count("by another run") for o in outcomes) >= 1
    store = ResultStore(root)
    assert sorted(e.key for e in store.entries("x")) == sorted(_key(i) for i in range(N_KEYS))
    assert store.verify_all() == {}
    assert not list((tmp_path / "s" / "x").glob("*.claim*"))  # every claim released


def _plant(store: ResultStore, key: str, **doc: object) -> Path:
    path = Path(store.root) / "x" / f"{key}.claim"
    path.parent.mkdir(exist_ok=True)
    base = {"pid": os.getpid(), "host": socket.gethostname(), "expires": time.time() + 60}
    path.write_text(json.dumps({**base, "token": "theirs", "lease": 60.0, **doc}))
    return path


def test_a_live_claim_holds_and_a_stale_one_is_taken_over(tmp_path):
    store = ResultStore(tmp_path / "s")
    key = _key(0)
    other_host = "elsewhere.example"
    _plant(store, key, host=other_host, pid=1)  # alive, as far as this host can tell
    assert store.claim("x", key) is None
    _plant(store, key, host=other_host, expires=time.time() - 1)  # its lease ran out
    taken = store.claim("x", key)
    assert taken is not None and store.claim("x", key) is None
    taken.release()
    # a process that died on this host: taken over at once, whatever its lease
    _plant(store, key, pid=2**22 + 12345, expires=time.time() + 3600)
    again = store.claim("x", key)
    assert again is not None
    doc = json.loads((Path(store.root) / "x" / f"{key}.claim").read_text())
    assert doc["pid"] == os.getpid() and doc["host"] == socket.gethostname()
    again.release()
    assert not (Path(store.root) / "x" / f"{key}.claim").exists()


def test_an_empty_or_garbled_claim_is_taken_over_at_once(tmp_path):
    # claims are written whole and moved into place: an empty one was left by a kill
    store = ResultStore(tmp_path / "s")
    key = _key(0)
    path = _plant(store, key)
    for left in (b"", b'{"pid": 1, "ho'):
        path.write_bytes(left)
        taken = store.claim("x", key)
        assert taken is not None and json.loads(path.read_text())["pid"] == os.getpid()
        taken.release()
        assert not path.exists()
        path.write_bytes(b"")
    assert store.temporaries() == []


def test_renewing_extends_the_lease_and_a_lost_claim_says_so(tmp_path):
    store = ResultStore(tmp_path / "s")
    key = _key(0)
    claim = store.claim("x", key, lease=0.5)
    assert claim is not None
    path = Path(store.root) / "x" / f"{key}.claim"
    first = json.loads(path.read_text())["expires"]
    time.sleep(0.05)
    assert claim.renew() is True
    assert json.loads(path.read_text())["expires"] > first
    # renewed in the background while held as a context manager: never goes stale
    with claim:
        time.sleep(1.0)
        assert store.claim("x", key) is None
    assert not path.exists()
    lost = store.claim("x", key, lease=0.1)
    assert lost is not None
    time.sleep(0.15)
    mine = store.claim("x", key)  # the lease ran out: taken over
    assert mine is not None
    assert lost.renew() is False
    lost.release()  # releases nothing of the new holder's
    assert path.exists()
    mine.release()
    with pytest.raises(StoreError, match="lease must be positive"):
        store.claim("x", key, lease=0)


def test_waiting_ends_with_the_entry_or_with_the_claim_given_up(tmp_path):
    store = ResultStore(tmp_path / "s")
    key = _key(0)
    claim = store.claim("x", key)
    assert claim is not None
    t0 = time.monotonic()
    assert store.wait_for("x", key, timeout=0.2) is False  # still held, no entry
    assert 0.2 <= time.monotonic() - t0 < 2.0
    claim.release()  # the other run failed: nothing to wait for
    assert store.wait_for("x", key, timeout=10.0) is False
    claim = store.claim("x", key)
    assert claim is not None
    store.commit("x", key, Nested("0", np.zeros(1)), task={"i": 0})
    assert store.wait_for("x", key, timeout=10.0) is True
    claim.release()


def test_claims_never_appear_as_entries_or_temporaries(tmp_path):
    store = ResultStore(tmp_path / "s")
    claim = store.claim("x", _key(0))
    assert claim is not None
    assert list(store.entries()) == [] and store.temporaries() == [] and store.verify_all() == {}
    claim.release()
