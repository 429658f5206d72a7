"""Work a run does in its own process, spread over forked processes: the files it writes
after its tasks (the database's plots, where the database was stored before the run and
no worker drew them), when its workers are gone and the cores idle."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import TypeVar

from . import _process

__all__ = ["forked_map"]

_T = TypeVar("_T")
_R = TypeVar("_R")


def forked_map(fn: Callable[[_T], _R], items: Sequence[_T], n: int | None = None) -> list[_R]:
    """``[fn(x) for x in items]``, computed in up to `n` forked processes (default: one
    per core), for the work a run does in its own process after its tasks (the
    database's plots): its workers are gone by then and the cores idle.

    In this process, one item after the other, where forking is not safe (`start_method`
    is not ``fork``: JAX loaded), for one item or one core, and when a process dies.
    `fn` and the items travel by pickle; the results come back in order.
    """
    from concurrent.futures.process import BrokenProcessPool

    todo = list(items)
    n = min(n or _process.workers_default(), len(todo))
    if n <= 1 or _process.start_method() != "fork":
        return [fn(x) for x in todo]
    import gc
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # as for the workers (`_process.process_pool`): the children's garbage collector
    # leaves this process's objects alone, instead of examining (and copying) them all
    freeze = gc.get_freeze_count() == 0
    if freeze:
        gc.freeze()
    try:
        with (
            _process.blas_pinned(True),
            ProcessPoolExecutor(
                n,
                mp_context=multiprocessing.get_context("fork"),
                initializer=_process._start_worker,
                initargs=(os.getpid(), True),
            ) as pool,
        ):
            # one chunk a process: each pays its first figure's setup once
            return list(pool.map(fn, todo, chunksize=-(-len(todo) // n)))
    except BrokenProcessPool:
        return [fn(x) for x in todo]
    finally:
        if freeze:
            gc.unfreeze()
