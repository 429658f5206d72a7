"""`forked_map`: the work a run does in its own process after its tasks, spread over
forked processes, with the results of the serial loop, in order."""

from __future__ import annotations

import os
import sys

import pytest

from aeroid.pipeline.running.parallel import forked_map


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def _die_on_three(x: int) -> int:
    if x == 3 and os.getpid() != _PARENT[0]:
        os._exit(3)  # a crash in native code, as the pool sees it
    return -x


_PARENT = [os.getpid()]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is Linux's")
def test_forked_map_runs_in_other_processes_and_keeps_the_order(monkeypatch):
    monkeypatch.delenv("AEROID_START_METHOD", raising=False)
    if "jax" in sys.modules:  # loaded by an earlier test: forking is not safe, serial
        monkeypatch.setenv("AEROID_START_METHOD", "fork")
    out = forked_map(_square_and_pid, list(range(7)), 2)
    assert [v for v, _ in out] == [x * x for x in range(7)]
    # (which of the two processes takes which chunk is the pool's affair)
    assert os.getpid() not in {p for _, p in out}


def test_forked_map_is_the_serial_loop_where_forking_is_not_safe(monkeypatch):
    monkeypatch.setenv("AEROID_START_METHOD", "spawn")
    out = forked_map(_square_and_pid, [1, 2, 3], 2)
    assert out == [(1, os.getpid()), (4, os.getpid()), (9, os.getpid())]
    # one item, or one process: no pool either
    monkeypatch.setenv("AEROID_START_METHOD", "fork")
    assert forked_map(_square_and_pid, [5], 4) == [(25, os.getpid())]
    assert forked_map(_square_and_pid, [1, 2], 1) == [(1, os.getpid()), (4, os.getpid())]
    assert forked_map(_square_and_pid, [], 2) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is Linux's")
def test_a_process_that_dies_leaves_the_serial_loop_to_finish(monkeypatch):
    monkeypatch.setenv("AEROID_START_METHOD", "fork")
    _PARENT[0] = os.getpid()
    assert forked_map(_die_on_three, [1, 2, 3, 4], 2) == [-1, -2, -3, -4]


_WHERE = """
import sys
import numpy as np
from aeroid.pipeline.running import _process
kept = _process.keep_freed_memory() if sys.argv[1] == "keep" else None
a = np.ones(8 << 20)  # 64 MB
address = a.ctypes.data
for line in open("/proc/self/maps"):
    if line.rstrip().endswith("[heap]"):
        lo, hi = (int(v, 16) for v in line.split()[0].split("-"))
        print(kept, lo <= address < hi)
        break
else:
    print(kept, False)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_worker_serves_large_arrays_from_its_heap():
    import subprocess

    def in_heap(mode: str) -> tuple[str, str]:
        done = subprocess.run(
            [sys.executable, "-c", _WHERE, mode], capture_output=True, text=True, check=True
        )
        kept, inside = done.stdout.split()
        return kept, inside

    kept, inside = in_heap("keep")
    if kept != "True":
        pytest.skip("the C library has no mallopt (not glibc)")
    # kept: the block comes from the heap, where a freed one stays for the next
    # allocation; otherwise glibc maps a large block of its own, unmapped when freed
    assert inside == "True"
    assert in_heap("plain")[1] == "False"


def _collector_state(_: int) -> tuple[int, int, int]:
    """In a forked child: how many objects are frozen, and the young generation's size."""
    import gc

    return gc.get_freeze_count(), gc.get_threshold()[0], os.getpid()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork is Linux's")
def test_forked_children_inherit_a_frozen_parent_which_thaws_after(monkeypatch):
    """The children's collector leaves the parent's objects alone (frozen before the
    fork), runs on a larger young generation, and the parent thaws once they are done."""
    import gc

    monkeypatch.setenv("AEROID_START_METHOD", "fork")
    assert gc.get_freeze_count() == 0
    young = gc.get_threshold()[0]
    out = forked_map(_collector_state, [0, 1], 2)
    assert all(frozen > 1000 and threshold == 10_000 for frozen, threshold, _ in out)
    assert gc.get_freeze_count() == 0 and gc.get_threshold()[0] == young


def test_settle_imports_freezes_only_in_a_worker_after_an_import(monkeypatch):
    """`settle_imports` does nothing outside a worker; in one, it freezes what lives
    after a task that imported a module, and only then."""
    import gc

    from aeroid.pipeline.running import _process

    assert _process._SETTLED == []  # this process is no worker
    _process.settle_imports()
    assert gc.get_freeze_count() == 0
    try:
        monkeypatch.setattr(_process, "_SETTLED", [len(sys.modules)])
        _process.settle_imports()  # nothing imported since
        assert gc.get_freeze_count() == 0
        monkeypatch.setattr(_process, "_SETTLED", [len(sys.modules) - 1])
        _process.settle_imports()
        assert gc.get_freeze_count() > 0
        assert _process._SETTLED == [len(sys.modules)]
    finally:
        gc.unfreeze()
