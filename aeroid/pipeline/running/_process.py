"""The worker processes of the embedded cluster, and what a run does to its own process.

Each piece is here for the reason given with it:

- workers are forked on Linux: a spawned worker imports numpy, scipy and
  aeroid afresh before its first task;
- one BLAS thread per worker: two workers each running a multi-threaded BLAS
  on two cores fight over them;
- a worker exits when the process that started it is gone, instead of
  waiting for work forever after its run was killed with SIGKILL;
- the modules the tasks will import are imported once before the workers
  fork, so that their pages are shared rather than copied into every
  worker (a 1,000-flight campaign: the process tree's peak PSS 357 -> 272 MB
  on two workers);
- JAX is imported before the workers fork when the run fits models (every
  worker that fits one compiles it, and each imported JAX on its own, about a
  second of CPU); imported and unused, it has no threads, and the workers start
  it themselves;
- a worker keeps the memory it frees in its heap (glibc's `mallopt`): a
  filter-error pass allocates and frees record-long arrays of tens of MB,
  which glibc would otherwise map afresh from the kernel each time, every
  page faulted in and zeroed again (the demo's identify: a fifth of its CPU
  time was the kernel's, 100,000-150,000 page faults a flight; after: none
  once the first flight has grown the heap);
- a worker's garbage collector runs on a young generation of 10,000 objects
  rather than 700, and after a task that imported modules (JAX, a plotting
  library) it freezes what the task left alive, which later full collections
  then skip (`settle_imports`; the demo's workers: 1-2 s of collections each
  before).
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from typing import Any

__all__: list[str] = []

_BLAS_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
}


def workers_default() -> int:
    """One worker per core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def start_method() -> str:
    """How the embedded cluster starts its worker processes.

    ``fork`` on Linux: a worker then starts with everything this process has
    imported, instead of importing numpy, scipy and aeroid afresh, which
    would dominate a small campaign's run. ``spawn`` elsewhere, when JAX has
    started its runtime here (its threads must not be forked; JAX imported and
    not yet used has none), or as set by ``AEROID_START_METHOD``.
    """
    chosen = os.environ.get("AEROID_START_METHOD")
    if chosen:
        return chosen
    if sys.platform.startswith("linux") and not _jax_started():
        return "fork"
    return "spawn"


def _jax_started() -> bool:
    """Whether JAX has started a backend in this process (its thread pools); a JAX that
    does not say so counts as started."""
    if "jax" not in sys.modules:
        return False
    bridge = sys.modules.get("jax._src.xla_bridge")
    backends = getattr(bridge, "_backends", None)
    return not isinstance(backends, dict) or bool(backends)


@contextlib.contextmanager
def blas_pinned(fork: bool) -> Iterator[None]:
    """One BLAS/OpenMP thread in this process while it forks workers, which inherit it.

    Not set in the forked workers themselves: after a fork OpenBLAS has no
    threads, and setting its thread count starts them, each spinning before
    it sleeps. The previous limits come back when the block ends.
    """
    if not fork:
        yield
        return
    from threadpoolctl import threadpool_limits

    limiter = threadpool_limits(limits=1)
    try:
        yield
    finally:
        limiter.restore_original_limits()


# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4
# free memory at the heap's top kept for reuse rather than given back to the kernel
_KEEP_FREE = 256 << 20


def keep_freed_memory() -> bool:
    """Serve every allocation of this process from its heap and keep up to `_KEEP_FREE`
    bytes of freed memory there (module notes); False where the C library has no
    `mallopt` (not glibc), which changes nothing."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # no mmap for large blocks: a freed block returns to the heap, not to the kernel
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, _KEEP_FREE))


_YOUNG = 10_000

# In a worker process: the number of modules loaded when it last froze its objects
# (`settle_imports`); None in any other process.
_SETTLED: list[int] = []


def settle_imports() -> None:
    """After a task, in a worker process that has imported modules since it last looked:
    collect its garbage, then freeze what is left (the modules and their objects).

    Forked from a frozen parent, a worker's collector examines only what the worker
    made; a task that imports JAX or a plotting library adds some 100,000 objects that
    live as long as the worker, and every full collection after examined them all
    again (the demo's workers: 1-2 s of collections each). Frozen once their task is
    done, they are left alone; what a task leaves behind is collected first, so only
    what lives on is frozen, a few times in a worker's life. Nothing happens outside
    a worker (a run in the user's own process keeps its collector as it was).
    """
    if not _SETTLED or len(sys.modules) <= _SETTLED[0]:
        return
    gc.collect()
    gc.freeze()
    _SETTLED[0] = len(sys.modules)


def _start_worker(parent: int, forked: bool) -> None:
    """What each worker process does as it starts: BLAS on one thread, freed memory
    kept for reuse, a garbage collector that runs less often and freezes the objects
    a task imported (`settle_imports`), and an exit as soon as the run that started
    it is gone."""
    _SETTLED[:] = [len(sys.modules)]
    # a young generation of `_YOUNG` objects, not 700: the collector runs a fourteenth
    # as often in a worker that builds and drops arrays and figures by the thousand (the
    # demo's workers: 1,200 collections each, 0.3 s; a few MB more garbage at most)
    gc.set_threshold(_YOUNG, *gc.get_threshold()[1:])
    os.environ.update(_BLAS_ENV)  # for libraries not loaded yet, and processes it starts
    if sys.platform.startswith("linux"):
        keep_freed_memory()
    if not forked:
        # spawned: numpy is loaded as the worker unpickles its work, after the env
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="aeroid-parent-watch", daemon=True).start()


# What nearly every task imports on first use, beyond its stage's library module. Not
# scipy.stats nor scipy.signal (half a second of this process's CPU before the workers
# could start): the library computes what it needs of them itself, and the rare task
# that imports one (a Savitzky-Golay smoothing) imports it where it runs.
_SHARED_IMPORTS = ("scipy.linalg", "scipy.optimize")


def share_imports(libraries: Iterable[str | None], *, models: bool = False) -> None:
    """Import the stages' library modules (``module:function`` names) and the shared
    scientific modules in this process before it forks its workers; with `models`
    (some task simulates a model), JAX too.

    Every worker that fits a model compiles it with JAX, and each imported JAX on its
    own (a second of CPU each). Imported here, before the fork, JAX is shared; it
    starts no threads until it is first used, which happens in the workers only
    (`start_method` forks as long as JAX has not started here).
    """
    import importlib

    modules = [name.partition(":")[0] for name in libraries if name]
    if models and not _jax_started():
        modules += _JAX_IMPORTS
    for module in dict.fromkeys([*modules, *_SHARED_IMPORTS]):
        with contextlib.suppress(ImportError):
            importlib.import_module(module)


# What a worker that compiles a model imports (`aeroid.models.jax_compiled.require_jax`)
_JAX_IMPORTS = ["jax", "jax.numpy"]


@contextlib.contextmanager
def process_pool(n: int) -> Iterator[Any]:
    """A pool of `n` worker processes (see `start_method`), shut down on leaving."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    method = start_method()
    fork = method == "fork"
    # (a caller that froze objects itself keeps them frozen: nothing here undoes it)
    freeze = fork and gc.get_freeze_count() == 0
    if freeze:
        # Forked workers inherit this process's objects page by page, shared until
        # written; their cyclic garbage collector writes into the header of every
        # inherited container it examines, which would copy the planner's pages into
        # each worker. Frozen objects are never examined (bench_campaign_1000.py).
        gc.freeze()
    pool = ProcessPoolExecutor(
        n,
        mp_context=multiprocessing.get_context(method),
        initializer=_start_worker,
        initargs=(os.getpid(), fork),
    )
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if freeze:
            gc.unfreeze()
