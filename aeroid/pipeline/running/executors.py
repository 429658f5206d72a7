"""Executors: what runs a run's tasks, each behind one small interface.

`InProcess` runs them one after the other in this process; `LocalProcesses`
runs them on a pool of worker processes under Dask's local scheduler (the
default); `DaskCluster` on a `dask.distributed` scheduler. Each returns a
`TaskStatus` per task and never raises for a task's failure; a worker that
dies fails the task it was running, and the rest go on.
"""

from __future__ import annotations

import socket
import uuid
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, SupportsIndex

from ...errors import PipelineError
from ..plans.planning import Task
from ..stages import STAGES
from ..storage.store import ResultStore, record_cache
from . import _process, execution
from .execution import PartResult, TaskStatus, error_text, n_parts
from .graph import Node, chains, nodes, part_deps

__all__ = ["DaskCluster", "Executor", "InProcess", "LocalProcesses", "executor_for"]

OnDone = Callable[[TaskStatus], None]


class Executor(Protocol):
    """Runs tasks (plan order) against the store at `store_root`; a status per task run.

    `read_root`: a store to read the tasks' inputs from instead (a rerun's).
    `given`: statuses of tasks run before (an earlier window of a streamed run)
    that these tasks take as upstream: a failed flight's, which a campaign task
    reports instead of reading its missing result.
    """

    def run(
        self,
        tasks: list[Task],
        store_root: str,
        *,
        scope: str,
        on_done: OnDone,
        read_root: str | None = None,
        given: Sequence[TaskStatus] = (),
    ) -> list[TaskStatus]: ...


def _taken(tasks: Sequence[Task], given: Mapping[str, TaskStatus]) -> list[TaskStatus]:
    """The statuses in `given` that `tasks` take as upstream."""
    if not given:
        return []
    keys = dict.fromkeys(k for t in tasks for k in t.upstream_keys if k in given)
    return [given[k] for k in keys]


def executor_for(scheduler: str | None, workers: int | None) -> Executor:
    """The executor a config or command asks for: a scheduler address, 0 workers (this
    process), or a pool of local worker processes (default: one per core)."""
    if scheduler:
        return DaskCluster(scheduler)
    if workers == 0:
        return InProcess()
    return LocalProcesses(workers)


class InProcess:
    """Every task in this process, one after the other, without Dask."""

    def run(
        self,
        tasks: list[Task],
        store_root: str,
        *,
        scope: str,
        on_done: OnDone,
        read_root: str | None = None,
        given: Sequence[TaskStatus] = (),
    ) -> list[TaskStatus]:
        results: dict[str, TaskStatus] = {}
        before = {s.key: s for s in given}
        try:
            for t in tasks:
                if t.key in results:
                    continue
                ups: list[Any] = [
                    results.get(k) or before[k]
                    for k in dict.fromkeys(t.upstream_keys)
                    if k in results or k in before
                ]
                n = n_parts(t)
                if n > 1:
                    ups += [
                        execution.execute_part(
                            t, store_root, i, *ups, scope=scope, read_root=read_root
                        )
                        for i in range(n)
                    ]
                results[t.key] = execution.execute_task(
                    t, store_root, *ups, scope=scope, read_root=read_root
                )
                on_done(results[t.key])
        finally:
            record_cache(None)
        return list(results.values())


def pool_size(tasks: list[Task], workers: int) -> int:
    """Worker processes for `tasks`: no more than their pieces of work (each task, or
    each part of a split one), so that a report-only rerun still draws its figure
    parts in parallel while a one-flight run starts no idle workers."""
    return max(1, min(workers, sum(n_parts(t) for t in tasks)))


class LocalProcesses:
    """The embedded cluster: Dask's local scheduler over a pool of worker processes.

    A pool starts and stops far faster than a `dask.distributed` cluster, and
    it hands tasks out one per idle worker, so each task runs the moment it is
    handed out. When a
    worker process dies (a crash in native code, out of memory), every task
    then running fails with it: each is run again alone in a fresh process,
    so only the one that kills its worker again is reported failed, and the
    rest of the graph goes on in a fresh pool.
    """

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers

    def run(
        self,
        tasks: list[Task],
        store_root: str,
        *,
        scope: str,
        on_done: OnDone,
        read_root: str | None = None,
        given: Sequence[TaskStatus] = (),
    ) -> list[TaskStatus]:
        from concurrent.futures.process import BrokenProcessPool

        import cloudpickle
        from dask.core import quote
        from dask.local import get_async
        from dask.multiprocessing import pack_exception

        n = pool_size(tasks, self.workers or _process.workers_default())
        graph = {node.name: node for node in nodes(tasks, store_root, scope, read_root)}
        earlier = {s.key: s for s in given}
        # the earlier statuses each node takes, passed as one more argument (a list)
        extra = {name: _taken(_node_tasks(node), earlier) for name, node in graph.items()}
        fork = _process.start_method() == "fork"
        if fork and n > 1:
            stages = {t.stage for t in tasks} & set(STAGES)
            _process.share_imports(
                (
                    name
                    for s in stages
                    for name in (
                        STAGES[s].library or getattr(STAGES[s].options, "library", None),
                        *STAGES[s].imports,
                    )
                ),
                models=any(STAGES[s].uses_model for s in stages),
            )
        done: dict[str, Any] = {}  # node name -> its result
        running: set[str] = set()
        results: dict[str, TaskStatus] = {}

        def finished(name: str, value: Any) -> None:
            running.discard(name)
            done[name] = value
            if graph[name].chain is not None:
                for status in value:
                    results[status.key] = status
                    on_done(status)

        def track(key: str, *_: Any) -> None:
            if key not in done:  # not a result of an earlier attempt, given as data
                running.add(key)

        def record(key: str, value: Any, *_: Any) -> None:
            if key not in done:
                finished(key, value)

        rank = {name: i for i, name in enumerate(graph)}
        # a flight's chain with more steps (an infer or a design on that flight) is the
        # long one: started first, it does not run alone at the end of the run
        steps = {name: len(node.chain or ()) for name, node in graph.items()}
        # a campaign task that runs whole (the database, with its plots) is the longest
        # piece of work left once the last flight is done: started before the report's
        # parts ready then, it runs beside them, not after them
        whole = {
            name
            for name, node in graph.items()
            if node.chain and node.chain[0].flight is None and not node.parts
        }

        def start(dsk: Any, state: dict[str, Any]) -> None:
            # Dask orders nodes that wait on nothing by string hashes, which change with
            # every process: the first flight ran anywhere in the run, and when it ran last
            # the report's detailed figures of it (a third of a small campaign's work) ran
            # alone at the end. Instead, the node more nodes wait on first, then the longer
            # chain, then the plan's order (the list is popped from its end). Nodes made ready
            # later are popped newest first (a report part as soon as its flight is done),
            # a campaign task run whole (`whole`) before any other.
            ready, dependents = state.get("ready"), state.get("dependents", {})
            if isinstance(ready, list):
                ready.sort(
                    key=lambda k: (len(dependents.get(k, ())), steps.get(k, 0), -rank.get(k, 0))
                )
                if whole:
                    state["ready"] = _WholeFirst(ready, whole)

        def attempt(names: list[str], n_workers: int) -> None:
            dsk: dict[str, Any] = {}
            for name in names:
                node = graph[name]
                for dep in [*node.deps, *node.parts]:
                    if dep in done:
                        dsk[dep] = quote(done[dep])
                more = (quote(extra[name]),) if extra.get(name) else ()
                if node.chain is not None:
                    dsk[name] = (node.call, list(node.parts), *node.deps, *more)
                else:
                    dsk[name] = (node.call, *node.deps, *more)
            with _process.process_pool(n_workers) as pool:
                get_async(
                    pool.submit,
                    # one node more than workers: the next one waits in the pool's queue, so a
                    # worker starts it the moment it is free, not after a round trip through
                    # this process
                    n_workers + 1,
                    dsk,
                    names,
                    chunksize=1,
                    # given here, not registered globally: no other computation sees them
                    callbacks=[(None, start, track, record, None)],
                    # as Dask's process scheduler does: a pipeline's own functions travel
                    # by value, and a worker's error comes back with its traceback
                    dumps=cloudpickle.dumps,
                    loads=cloudpickle.loads,
                    pack_exception=pack_exception,
                )

        broke = False
        with _process.blas_pinned(fork):
            while len(done) < len(graph):
                before = len(done)
                try:
                    attempt([name for name in graph if name not in done], n)
                except Exception as exc:  # a worker died, or an error escaped a task (unpickled)
                    if not running and len(done) == before:  # no task to blame: none would change
                        raise PipelineError(
                            f"the local worker processes could not run: {error_text(exc)}"
                        ) from exc
                    broke = broke or isinstance(exc, BrokenProcessPool)
                    for name in sorted(running):
                        running.discard(name)
                        try:
                            attempt([name], 1)
                        except Exception as again:
                            broke = broke or isinstance(again, BrokenProcessPool)
                            finished(name, _dead_node(graph[name], store_root, again))
        if broke:
            # the pool stops every worker when one dies: their half-written entries are
            # temporaries of dead processes, which `gc` removes
            ResultStore(store_root).gc()
        return list(results.values())


class _WholeFirst(list[str]):
    """Dask's list of ready nodes (popped from its end), from which a node in `whole` is
    popped before any other."""

    def __init__(self, ready: list[str], whole: set[str]) -> None:
        super().__init__(ready)
        self._whole = whole
        self._held = sum(name in whole for name in ready)  # how many of them it holds

    def append(self, name: str) -> None:
        self._held += name in self._whole
        super().append(name)

    def pop(self, index: SupportsIndex = -1) -> str:
        if self._held and index == -1:
            at = max((i for i, name in enumerate(self) if name in self._whole), default=None)
            if at is not None:
                self._held -= 1
                return super().pop(at)
            self._held = 0  # (added to by a method other than `append`)
        name = super().pop(index)
        self._held = max(0, self._held - (name in self._whole))
        return name


def _node_tasks(node: Node) -> list[Task]:
    """The tasks a node runs: its chain, or the split task it is a part of."""
    if node.chain is not None:
        return node.chain
    return [] if node.part is None else [node.part[0]]


def _dead_node(node: Node, store_root: str, exc: BaseException) -> Any:
    """What a node that failed when run alone returns (`exc`: its worker died, or an error
    escaped its tasks): a failed part, or the chain's statuses."""
    from concurrent.futures.process import BrokenProcessPool

    died = isinstance(exc, BrokenProcessPool)
    why = f"{_DIED}: it killed its worker again when run alone" if died else error_text(exc)
    if node.chain is not None:
        return _dead_chain(node.chain, store_root, why, died=died)
    assert node.part is not None
    task, index = node.part
    what = "the worker process died" if died else "the worker failed"
    return PartResult(task.key, index, "failed", error=f"{what} ({why})")


def _probe_scheduler(address: str) -> None:
    """Fail at once when nothing listens at a ``tcp://`` scheduler address.

    Dask's client retries a refused connection until its timeout (30 s here),
    which is right for a scheduler still starting but leaves a mistyped port
    silent for half a minute; a refused or unresolvable address is reported
    now. A scheduler that accepts the connection is left to Dask.
    """
    from urllib.parse import urlsplit

    parts = urlsplit(address)
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:  # a port out of range: Dask names the problem
        return
    if host is None or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=5.0).close()
    except (ConnectionRefusedError, socket.gaierror) as exc:
        raise PipelineError(
            f"cannot reach the dask scheduler {address}: {exc.strerror or exc}"
        ) from None
    except OSError:  # a slow or filtered network: let the client try for its timeout
        return


class DaskCluster:
    """The `dask.distributed` scheduler at `address` (its workers must reach the store)."""

    def __init__(self, address: str) -> None:
        self.address = address

    def run(
        self,
        tasks: list[Task],
        store_root: str,
        *,
        scope: str,
        on_done: OnDone,
        read_root: str | None = None,
        given: Sequence[TaskStatus] = (),
    ) -> list[TaskStatus]:
        return _run_dask(
            tasks,
            store_root,
            self.address,
            on_done=on_done,
            scope=scope,
            read_root=read_root,
            given=given,
        )


def _run_dask(
    tasks: list[Task],
    store_root: str,
    scheduler: str,
    *,
    on_done: OnDone,
    scope: str,
    read_root: str | None,
    given: Sequence[TaskStatus] = (),
) -> list[TaskStatus]:
    from dask.distributed import Client, as_completed

    _probe_scheduler(scheduler)
    try:
        client = Client(scheduler, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise PipelineError(f"cannot reach the dask scheduler {scheduler}: {exc}") from None
    results: dict[str, TaskStatus] = {}
    before = {s.key: s for s in given}
    try:
        owner: dict[str, Any] = {}  # task key -> future of the chain that runs it
        # future -> (its chain, the split task or None, the futures it waits for)
        submitted: dict[Any, tuple[list[Task], Task | None, list[Any]]] = {}
        # a future whose worker died -> its tasks' statuses, given to what waited for it
        stand_in: dict[Any, list[TaskStatus]] = {}

        def submit(chain: list[Task], split: Task | None, deps: list[Any]) -> Any:
            parts: list[Any] = []
            if split is not None and chain[0] is split:
                parts = [
                    client.submit(
                        execution.execute_part,
                        split,
                        store_root,
                        i,
                        *(stand_in.get(d, d) for d in part_deps(split, i, deps, owner)),
                        *([taken] if (taken := _taken([split], before)) else []),
                        scope=scope,
                        read_root=read_root,
                        key=f"{split.step}-{split.key}-part{i}-{uuid.uuid4().hex[:8]}",
                        pure=False,
                        retries=0,
                        # a part waiting on a few flights runs as soon as they are done
                        priority=1,
                    )
                    for i in range(n_parts(split))
                ]
            head = chain[0]
            fut = client.submit(
                execution.execute_chain,
                chain,
                store_root,
                parts,
                *(stand_in.get(d, d) for d in deps),
                *([taken] if (taken := _taken(chain, before)) else []),
                scope=scope,
                read_root=read_root,
                key=f"{head.flight or 'campaign'}-{head.step}-{head.key}-{uuid.uuid4().hex[:8]}",
                pure=False,
                retries=0,
            )
            for t in chain:
                owner[t.key] = fut
            submitted[fut] = (chain, split, deps)
            return fut

        for chain, split, deps in chains(tasks, owner):
            submit(chain, split, deps)
        done = as_completed(list(submitted))
        replaced: dict[Any, Any] = {}  # erred only because what it waited for died -> rerun

        def settle(fut: Any) -> None:
            """An erred chain: its worker died (its statuses go to `stand_in`), or one it
            waited for did (it never ran: submitted again, given the dead one's statuses)."""
            if fut in stand_in or fut in replaced:
                return
            chain, split, deps = submitted[fut]
            for d in deps:
                if d.status == "error":
                    settle(d)
            if any(d in stand_in or d in replaced for d in deps):
                replaced[fut] = submit(chain, split, [replaced.get(d, d) for d in deps])
                done.add(replaced[fut])
            else:
                why, died = _death(fut.exception())
                stand_in[fut] = _dead_chain(chain, store_root, why, died=died)

        for fut in done:
            try:
                statuses = fut.result()
            except Exception:  # a worker died under the chain, or under one it waited for
                settle(fut)
                if fut in replaced:
                    continue
                statuses = stand_in[fut]
            for status in statuses:
                results[status.key] = status
                on_done(status)
    finally:
        client.close()
        # workers that are threads of this process (a cluster made with processes=False)
        # cached this run's records here: forgotten, as the other executors forget them
        record_cache(None)
    return list(results.values())


_DIED = "a crash in native code, out of memory or an exit call"


def _death(exc: BaseException | None) -> tuple[str, bool]:
    """Why a chain on a `dask.distributed` worker did not finish, and whether its worker died."""
    from dask.distributed import KilledWorker

    if exc is None or isinstance(exc, KilledWorker):
        # Dask cannot tell which of the tasks on a worker killed it
        why = (
            f"{_DIED}, in this task or in one queued beside it; rerun to recompute what is missing"
        )
        return why, True
    return error_text(exc).splitlines()[0][:300], False


def _dead_chain(
    chain: list[Task], store_root: str, why: str, *, died: bool = True
) -> list[TaskStatus]:
    """Statuses of a chain whose worker process died, or failed outside its tasks (`why`):
    computed up to the task that was running (its results are in the store), failed from
    there on."""
    what = "the worker process died" if died else "the worker failed"
    stored = ResultStore(store_root).stored((t.stage, t.key) for t in chain)
    out: list[TaskStatus] = []
    dead: Task | None = None
    for t in chain:
        if dead is None and (t.stage, t.key) in stored:
            out.append(TaskStatus(t.key, t.step, t.flight, "computed", cached=True))
            continue
        if dead is None:
            dead = t
            error = f"{what} while running {t.step} ({why})"
        else:
            error = f"not run: the worker {'died' if died else 'failed'} at {dead.step}"
        out.append(TaskStatus(t.key, t.step, t.flight, "failed", error=error))
    return out
