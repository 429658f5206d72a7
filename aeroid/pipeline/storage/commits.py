"""A task's result into the store in one call: claimed, made, encoded, written, released.

`put` is what the run calls for each task it computes: it opens the store (once
per run and process), claims the task's key so that runs sharing the store compute
it once, has the run make the record while the claim holds (`make`, given the store
to read the task's inputs from), encodes and writes the entry, keeps the record in
the run's cache (`record_cache`), and releases the claim. What came of it is one `Put`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ...errors import AeroidError
from .claims import Claim
from .store import ResultStore, record_cache, run_store

__all__ = ["BY_ANOTHER_RUN", "Made", "Put", "put"]

# the status of a task another run sharing the store computed while this one waited
BY_ANOTHER_RUN = "by_another_run"
# how long one wait for another run's entry lasts before its claim is looked at afresh
_WAIT_SECONDS = 60.0


@dataclass(frozen=True)
class Made:
    """What the run made of a task under its claim: the record, the provenance stored with
    it, and whether it is kept (a report over failed flights is written out, never stored)."""

    record: Any
    provenance: Mapping[str, Any]
    keep: bool = True


@dataclass(frozen=True)
class Put:
    """What `put` did with a task.

    `status` is ``"computed"``, ``"cached"`` (stored by a run that finished while
    this one claimed) or ``"by_another_run"`` (computed by another run sharing the
    store, which this one waited for, or which committed first). `stored` says
    whether the task's entry is in the store, `committed` whether this call wrote
    it. `made` is what `make` returned (None where nothing was made here).
    """

    status: str
    stored: bool
    made: Made | None = None
    committed: bool = False


def put(
    store_root: str,
    stage: str,
    key: str,
    make: Callable[[ResultStore], Made],
    *,
    task: Mapping[str, Any],
    scope: str | None = None,
) -> Put:
    """Claim `key`, make its record (`make`), write its entry and release the claim.

    Parameters
    ----------
    store_root : str
        The store's folder or URL (opened once per run `scope` in this process).
    stage, key : str
        The task's stage and content key.
    make : callable
        ``make(store) -> Made``: computes the record while the claim holds; reads the
        task's inputs from `store`. An exception it raises releases the claim and
        propagates.
    task : mapping
        The task document stored with the entry (it hashes to `key`).
    scope : str, optional
        The run: records are cached in this process for it (`record_cache`), and its
        entries' provenance names it, so that a task this run committed before its
        worker died and ran again counts as computed.
    """
    record_cache(scope)
    store = run_store(store_root)
    claim = _claimed(store, stage, key, scope)
    if isinstance(claim, str):
        # cached, computed by another run meanwhile, or by this one's earlier attempt
        return Put(claim, stored=claim == "computed")
    with claim:
        made = make(store)
        if not made.keep:
            return Put("computed", stored=False, made=made)
        provenance = dict(made.provenance)
        if scope is not None:
            provenance["run"] = scope  # tells this run's entries from others' (`_claimed`)
        committed = store.commit(stage, key, made.record, task=task, provenance=provenance)
    if committed:
        return Put("computed", stored=True, made=made, committed=True)
    if scope is not None and _run_of(store, stage, key) == scope:
        # committed by this run before its worker died and the executor ran it again
        return Put("computed", stored=True, made=made)
    # committed by another run between our claim and commit (its claim went stale)
    return Put(BY_ANOTHER_RUN, stored=True, made=made)


def _claimed(
    store: ResultStore, stage: str, key: str, scope: str | None
) -> Claim | contextlib.nullcontext[None] | str:
    """Claim the task for this run, or say why there is nothing to compute.

    Runs sharing a store compute each key once: where another live run holds
    the claim, this one waits for its entry (``"by_another_run"``); where the
    other run failed or died, the claim is taken here. An entry found right
    after claiming was committed by a run that finished meanwhile (``"cached"``),
    or by this run (`scope`) before an executor ran the task again after its
    worker died (``"computed"``).
    """
    if not store.claims_per_task:
        # the runner pruned what was stored: no look before computing
        return contextlib.nullcontext()
    while True:
        claim = store.claim(stage, key)
        if claim is None:
            if store.wait_for(stage, key, timeout=_WAIT_SECONDS):
                return BY_ANOTHER_RUN
            continue  # the other run gave up, or is slow: claim again (or wait again)
        if store.exists(stage, key):
            claim.release()
            if scope is not None and _run_of(store, stage, key) == scope:
                return "computed"
            return "cached"
        return claim


def _run_of(store: ResultStore, stage: str, key: str) -> str | None:
    """The run (its `scope`) that committed the entry, where the entry says."""
    try:
        run = store.metadata(key, stage).get("provenance", {}).get("run")
    except AeroidError:
        return None
    return run if isinstance(run, str) else None
