"""One BLAS thread while the library runs its small-matrix loops.

The numerical entry points multiply and factorise matrices of a handful of
rows thousands of times. A multi-threaded BLAS gains nothing there and, on a
machine whose other cores are busy, loses a great deal: every small call
waits for a worker thread to be scheduled. A caller's environment (default
OpenBLAS threads, no ``OPENBLAS_NUM_THREADS``) must not decide the library's
speed, so each public call runs under `small_blas`:

* the first (outermost) public call in the process limits every loaded BLAS
  to one thread and the last one to return gives the caller's settings back;
  nested public calls (``identify`` simulating through ``Model.simulate``)
  and calls from other threads meanwhile change nothing;
* libraries that already run one thread (a pinned pipeline worker, a caller
  who set ``OPENBLAS_NUM_THREADS=1``) are left alone, so nothing is set or
  restored at all there;
* the `threadpoolctl` controller is built once, on the first call, as
  building it scans every loaded shared library; it is built again only when
  modules have been imported since (a BLAS loaded later, such as SciPy's own
  OpenBLAS, is then found).

BLAS limits are per process, not per thread: while a public call runs, a
caller's other threads also see one BLAS thread. (OpenBLAS 0.3.31 ignores a
thread count set from another thread once the main thread has set one, so a
public call made from a worker thread may run with the caller's count.)

Background work (`after_call`): a job the library defers, such as compiling a
model fitted twice so that its next fit finds the program ready, runs in one
thread of the library's, one job at a time, started when the outermost public
call in the calling thread returns (the call itself never waits for it). A
failing job is logged at debug level and otherwise ignored. At interpreter
exit the jobs still queued are dropped and the running one is finished
(`_stop`); `wait_background` waits for the queue to empty. A job never touches
the process-wide warnings filters (`quiet_warnings`): they belong to the
caller's thread, which runs on meanwhile.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import logging
import os
import queue
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from types import TracebackType
from typing import Any, ParamSpec, TypeVar

__all__ = ["CALLER_STACKLEVEL", "after_call", "blas_threads", "small_blas", "wait_background"]

# `small_blas` wraps a public function in one more frame: a warning issued in
# the function's body points at its caller with this stacklevel (one more per
# helper in between).
CALLER_STACKLEVEL = 3

_P = ParamSpec("_P")
_R = TypeVar("_R")


class _State(threading.local):
    depth = 0  # public calls open in this thread

    def __init__(self) -> None:
        self.deferred: list[Callable[[], None]] = []  # jobs for when the call returns


_local = _State()
_lock = threading.Condition()  # guards the counts below; `alone` waits on it
_active = 0  # threads inside a public call, all threads together
_callers = 0  # of those, the threads other than the background one
_held = False  # a background job holds the process alone (`alone`)
_saved: list[tuple[Any, int]] = []  # (library controller, caller's thread count)
_controllers: list[Any] | None = None  # BLAS controllers of the last scan
_scanned_at = -1  # len(sys.modules) at the last scan


def _blas_controllers() -> list[Any]:
    """The loaded BLAS libraries' controllers, rescanned after new imports."""
    global _controllers, _scanned_at
    n_modules = len(sys.modules)
    if _controllers is None or n_modules != _scanned_at:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - a dependency; without it BLAS is the caller's
            _controllers, _scanned_at = [], n_modules
            return _controllers
        found = ThreadpoolController().select(user_api="blas").lib_controllers
        _controllers, _scanned_at = list(found), n_modules
    return _controllers


def _limit() -> None:
    for lib in _blas_controllers():
        n = int(lib.num_threads)
        if n != 1:
            _saved.append((lib, n))
            lib.set_num_threads(1)


def _restore() -> None:
    while _saved:
        lib, n = _saved.pop()
        lib.set_num_threads(n)


def _enter() -> None:
    global _active, _callers
    depth = _local.depth
    _local.depth = depth + 1
    if depth:
        return
    with _lock:
        if threading.current_thread() is not _worker:
            while _held:
                _lock.wait()
            _callers += 1
        if _active == 0:
            try:
                _limit()
            except Exception:  # a library that refuses: run with the caller's settings
                _restore()
        _active += 1


def _exit() -> None:
    global _active, _callers
    depth = _local.depth - 1
    _local.depth = depth
    if depth:
        return
    with _lock:
        _active -= 1
        if _active == 0:
            _restore()
        if threading.current_thread() is not _worker:
            _callers -= 1
            if _callers == 0:
                _lock.notify_all()
    if _local.deferred:
        jobs, _local.deferred = _local.deferred, []
        for job in jobs:
            _submit(job)


# -- background jobs -------------------------------------------------------------------

_log = logging.getLogger("aeroid")
_jobs: queue.Queue[Callable[[], None]] = queue.Queue()
_worker: threading.Thread | None = None
_stopping = False


def after_call(job: Callable[[], None]) -> None:
    """Run `job` in the library's background thread once the outermost public call
    in this thread has returned (at once when none is open)."""
    if _local.depth:
        _local.deferred.append(job)
    else:
        _submit(job)


def _submit(job: Callable[[], None]) -> None:
    global _worker
    if _stopping:
        return
    _jobs.put(job)
    with _lock:
        if _worker is None or not _worker.is_alive():
            _worker = threading.Thread(target=_work, name="aeroid-background", daemon=True)
            _worker.start()


def _work() -> None:
    try:  # below the caller's threads in the scheduler's eyes (Linux: per thread)
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
    except (AttributeError, OSError):
        pass
    while True:
        job = _jobs.get()
        try:
            if job is _END:
                return
            if not _stopping:
                job()
        except Exception:  # a background job only ever saves time: its failure costs none
            _log.debug("aeroid: a background job failed", exc_info=True)
        finally:
            _jobs.task_done()


# -- warnings in threads ------------------------------------------------------------------
#
# The warnings filters and handler are one state for the whole process, which
# ``catch_warnings`` saves on entry and restores on exit. Two threads inside it
# at once undo each other: the one that leaves first restores what the other
# replaced, and the process can end with every later warning appended to a list
# nobody reads. So the library records or silences a thread's warnings through
# one shared handler, installed while any thread needs it (counted, under a
# lock) and routing each warning by the thread that raised it; a thread with no
# block open meanwhile has its warnings shown by the handler that was there.

_route = threading.local()  # .stack: the open blocks, a list (record) or None (silence)
_route_lock = threading.Lock()
_route_users = 0
_route_saved: tuple[list[Any], Any] | None = None


def _routed(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    stack = getattr(_route, "stack", None)
    if stack:
        if stack[-1] is not None:
            stack[-1].append(
                warnings.WarningMessage(message, category, filename, lineno, file, line)
            )
        return
    saved = _route_saved
    handler = saved[1] if saved is not None else warnings._showwarning_orig  # type: ignore[attr-defined]
    handler(message, category, filename, lineno, file, line)


@contextlib.contextmanager
def _routed_block(sink: list[warnings.WarningMessage] | None) -> Iterator[None]:
    global _route_users, _route_saved
    with _route_lock:
        if _route_users == 0:
            _route_saved = (list(warnings.filters), warnings.showwarning)
            warnings.simplefilter("always")
            warnings.showwarning = _routed
        _route_users += 1
    stack = getattr(_route, "stack", None)
    if stack is None:
        stack = _route.stack = []
    stack.append(sink)
    try:
        yield
    finally:
        stack.pop()
        with _route_lock:
            _route_users -= 1
            if _route_users == 0 and _route_saved is not None:
                warnings.filters[:] = _route_saved[0]  # type: ignore[index]
                warnings.showwarning = _route_saved[1]
                warnings._filters_mutated()  # type: ignore[attr-defined]
                _route_saved = None


def in_background() -> bool:
    """Whether this code runs in the library's background thread."""
    return threading.current_thread() is _worker


def user_stacklevel() -> int:
    """The stacklevel, for a warning issued by the caller of this function, of the
    first frame outside the aeroid package: for warnings raised deep inside, on a path
    every public function may reach."""
    root = os.path.dirname(os.path.abspath(__file__)) + os.sep
    frame = sys._getframe(1)
    level = 1
    while frame.f_back is not None and frame.f_code.co_filename.startswith(root):
        frame = frame.f_back
        level += 1
    return level


@contextlib.contextmanager
def quiet_warnings() -> Iterator[None]:
    """Warnings this thread raises in the block are dropped (what ``catch_warnings``
    with ``"ignore"`` does, through the shared handler); in the library's
    background thread the block runs as it is, since a job must not touch the
    caller's warnings state while the caller runs on. Floating-point warnings are
    silenced per thread by ``np.errstate`` wherever they matter."""
    if threading.current_thread() is _worker:
        yield
        return
    with _routed_block(None):
        yield


@contextlib.contextmanager
def record_warnings() -> Iterator[list[warnings.WarningMessage]]:
    """Every warning this thread raises in the block, recorded (what
    ``catch_warnings(record=True)`` with ``"always"`` does, through the shared
    handler), so that tasks running side by side in threads each keep their own
    and leave the process's warnings state as it was."""
    sink: list[warnings.WarningMessage] = []
    with _routed_block(sink):
        yield sink


def replay_warnings(recorded: list[warnings.WarningMessage]) -> None:
    """Issue warnings `record_warnings` held back, each at the place it named, through
    the caller's filters."""
    for w in recorded:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


@contextlib.contextmanager
def alone() -> Iterator[None]:
    """For a background job: wait until no caller is inside a public call, and hold
    new ones off until the block ends (what importing a module other threads' code
    inspects needs: half-imported, it sits in ``sys.modules``)."""
    global _held
    with _lock:
        while _callers:
            _lock.wait()
        _held = True
    try:
        yield
    finally:
        with _lock:
            _held = False
            _lock.notify_all()


def wait_background(timeout: float | None = None) -> bool:
    """Wait until the background jobs queued so far have run; False on `timeout` (s)."""
    jobs = _jobs
    with jobs.all_tasks_done:
        return jobs.all_tasks_done.wait_for(lambda: not jobs.unfinished_tasks, timeout)


def _END() -> None:  # the worker's last job
    return None


def _stop() -> None:
    """At interpreter exit: queued jobs are dropped and the running one is waited for.

    A thread inside a compiler's C++ code must not meet the interpreter's
    finalisation: when it returns to Python then it is unwound through frames
    that do not allow it, and the process aborts. Only jobs a public call has
    queued run here (a model's compilation once it has been fitted twice), so a
    script that fits once never waits.
    """
    global _stopping
    _stopping = True
    worker = _worker
    if worker is not None and worker.is_alive():
        _jobs.put(_END)
        worker.join()


atexit.register(_stop)


def _after_fork_in_child() -> None:
    # The child has only the forking thread: calls open in other threads are
    # gone (their one-thread limits stay, harmless in a child, and are not
    # restored, which would start OpenBLAS's threads), and the forking thread
    # closes its own open calls as usual.
    global _lock, _active, _worker, _jobs, _callers, _held
    _lock = threading.Condition()
    _callers, _held = (1 if _local.depth else 0), False
    # the parent's background thread is not in the child, nor are its jobs
    _worker, _jobs = None, queue.Queue()
    if _local.depth:
        _active = 1
    else:
        _active = 0
        _saved.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


class _SmallBlas:
    """Decorator and context manager: one BLAS thread for the duration of a call.

    ``@small_blas`` on a public function, ``with small_blas:`` around a block.
    Re-entrant; the caller's limits come back when the outermost call returns.
    """

    def __call__(self, func: Callable[_P, _R]) -> Callable[_P, _R]:
        @functools.wraps(func)
        def limited(*args: _P.args, **kwargs: _P.kwargs) -> _R:
            _enter()
            try:
                return func(*args, **kwargs)
            finally:
                _exit()

        return limited

    def __enter__(self) -> None:
        _enter()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        _exit()


small_blas = _SmallBlas()


def blas_threads() -> dict[str, int]:
    """Thread count of each loaded BLAS library, by file path (for tests and checks)."""
    return {str(lib.filepath): int(lib.num_threads) for lib in _blas_controllers()}
