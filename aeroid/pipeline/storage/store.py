"""The result store: one immutable Zarr v3 group per task result.

Layout under the store root::

    aeroid-store.json                marker with the layout version
    <stage>/<key>.zarr.zip           one result: a zipped Zarr v3 group (arrays + JSON attributes)
    <stage>/<key>.claim              a run computing `key` now (see `ResultStore.claim`)
    .tmp/<key>.<host>.<pid>.<nonce>  results being written (removed by `gc` after a crash)
    .index/<time>-<nonce>.json       entries checked whole, trusted by later runs (`verified`)

Each entry is a Zarr v3 hierarchy in one uncompressed zip file, the form
zarr-python opens with ``zarr.storage.ZipStore``: its root group holds the
JSON attributes and one array per set of numbers. One file per result rather
than a folder per result and two files per array: a campaign's cold run
creates a tenth of the files, and on a disk whose file creation is slow that
was most of what the store cost.

A result is written completely under ``.tmp`` and then moved into place by
a rename that refuses an existing name, so a reader sees either nothing or a
whole entry. If the name exists another run committed the same key first and
the copy is discarded (an entry is never overwritten). Every array's SHA-256
and a digest of the JSON content are stored in the group's attributes and
checked on every read; an altered entry raises `StoreError` and is never
returned. The digests catch accidents (a failing disk, a file cut short, a
careless edit), not deliberate ones: whoever can write an entry can write its
digests too. ``aeroid rerun`` recomputes a result and compares it bit for bit.

The store stays inside its own folder: it follows no symbolic link below its
root (folders are opened with ``O_NOFOLLOW`` and files through them), so a
link planted as ``.tmp``, a stage folder or an entry is refused with a
`StoreError` naming it, and `gc` or ``verify --remove`` never delete outside
the store. An entry's members are checked before they are read: they must be
stored uncompressed, as the store writes them, and each array's chunk must be
exactly the size its metadata implies, so a crafted entry cannot make a read
allocate more than the file's own size.

A store may also live at a URL that fsspec understands (``s3://``,
``gs://``, ``az://``, ...; the backend's package must be installed). There an
entry is one object written in one PUT, which object stores make visible whole
or not at all (see `_ObjectBackend`). Options for the backend come from
fsspec's own configuration, e.g. the environment variable
``FSSPEC_S3_ENDPOINT_URL=http://host:9000`` for an S3-compatible server.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import time
import uuid
import zipfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import StoreError
from ..keys import array_digest, sha256_hex
from . import codec, verified

__all__ = [
    "Claim",
    "Entry",
    "ResultStore",
    "StoreLocation",
    "is_store",
    "is_url",
    "open_store",
    "parse",
    "record_cache",
]

from ._backend import (
    _CLAIM,
    _MARKER,
    StoreLocation,
    _Backend,
    is_url,
    parse,
)
from ._cache import _CACHE, record_cache
from ._objectstore import (
    _ObjectBackend,
)
from ._store_paths import (
    _LocalBackend,
)
from ._zipentry import (
    Entry,
    _check_name,
    _checked_members,
    _content_digest,
    _entry_document,
    _entry_zip,
    _group_bytes,
    _member_reader,
    _Read,
    _read_array,
    _read_back_json,
)
from .claims import (
    Claim,
    _claim_doc,
    _claim_stale,
)

# what `_check_name` admits, checked over many names joined at once
_PLAIN = re.compile(r"[A-Za-z0-9_.\-]*")


def run_store(root: str) -> ResultStore:
    """The store at `root`, opened once per run scope in this process (each task of a run
    would otherwise look for its marker again)."""
    with _CACHE.lock:
        store = _CACHE.stores.get(root) if _CACHE.scope is not None else None
    if store is None:
        store = ResultStore(root)
        with _CACHE.lock:
            if _CACHE.scope is not None:
                _CACHE.stores[root] = store
    return store


class ResultStore:
    """A directory of immutable, content-keyed results.

    Parameters
    ----------
    root : str, Path or StoreLocation
        The store directory, or the URL of a store in an object store
        (``s3://bucket/campaign``; anything fsspec understands), created when
        `create` is true. On a cluster every worker must reach it: a shared
        filesystem or an object store.
    create : bool
        Create the store if it does not exist; otherwise raise `StoreError`.
    repair : bool
        Give a store that lost its marker (emptied while a run still wrote) the
        marker back when it holds nothing but store content, without `create`:
        what ``aeroid verify --remove`` does. A location holding anything else is
        still refused.
    """

    root: Path | str
    """The store's folder, or its URL in an object store."""
    location: StoreLocation
    """Where the store lives, parsed."""

    def __init__(
        self,
        root: str | os.PathLike[str] | StoreLocation,
        *,
        create: bool = True,
        repair: bool = False,
    ) -> None:
        self.location = parse(root)
        backend: _Backend
        if self.location.kind == "fsspec":
            backend = _ObjectBackend(self.location, create=create, repair=repair)
        else:
            given = root.root if isinstance(root, StoreLocation) else os.fspath(root)
            backend = _LocalBackend(self.location, given, create=create, repair=repair)
        self._backend = backend
        self.root = backend.root
        self._root_id = backend.ident

    def __repr__(self) -> str:
        return f"ResultStore({str(self.root)!r})"

    # -- locations -------------------------------------------------------------
    def path_for(self, stage: str, key: str) -> Path | str:
        """Where the result of `key` in `stage` lives (whether or not it exists)."""
        return self._backend.path_for(_check_name(stage, "stage"), _check_name(key, "key"))

    def exists(self, stage: str, key: str) -> bool:
        """True when `key` is committed (commits are atomic, so existence means complete)."""
        return self._backend.exists(_check_name(stage, "stage"), _check_name(key, "key"))

    def stored(self, tasks: Iterable[tuple[str, str]]) -> set[tuple[str, str]]:
        """The (stage, key) pairs among `tasks` that are committed."""
        wanted = set(tasks)
        # every name checked, in one pass over all of them where all are plain (a
        # campaign's 100,000 keys), else one by one to name the bad one
        names = [*{s for s, _ in wanted}, *(k for _, k in wanted)]
        if not (_PLAIN.fullmatch("".join(names)) and all(n and n[0] != "." for n in names)):
            for s, k in wanted:
                _check_name(s, "stage"), _check_name(k, "key")
        return self._backend.stored(wanted)

    def entries(self, stage: str | None = None) -> Iterator[Entry]:
        """Every committed entry, optionally of one stage."""
        yield from self._backend.listing(stage and _check_name(stage, "stage"), "")

    def find(self, key: str) -> Entry:
        """The entry whose key is `key` or starts with it (at least 6 hex digits)."""
        key = key.strip().lower()
        if len(key) < 6 or any(c not in "0123456789abcdef" for c in key):
            raise StoreError(f"key {key!r}: expected at least 6 hexadecimal digits")
        hits = self._backend.listing(None, key)
        if not hits:
            raise StoreError(f"key {key}: no such entry in store {self.root}")
        if len(hits) > 1:
            raise StoreError(f"key {key}: ambiguous, matches {[h.key[:12] for h in hits]}")
        return hits[0]

    # -- writing ---------------------------------------------------------------
    def commit(
        self,
        stage: str,
        key: str,
        record: Any,
        *,
        task: Mapping[str, Any],
        provenance: Mapping[str, Any] | None = None,
    ) -> bool:
        """Write `record` as the result of `key`; False when it was already committed."""
        _check_name(stage, "stage"), _check_name(key, "key")
        if self._backend.look_first and self._backend.exists(stage, key):
            return False
        meta, arrays, digested = _entry_document(stage, key, record, task, provenance)
        group = _group_bytes(meta, digested, stage)
        if not self._backend.publish(stage, key, _entry_zip(arrays, group)):
            return False
        if _CACHE.scope is not None:
            # what a verified read of the new entry returns (the tree went through JSON)
            nbytes = sum(a.nbytes for a in arrays.values())
            _CACHE.put(self._ident(stage, key), codec.decode(meta["record"], arrays), nbytes)
        return True

    def remove(self, stage: str, key: str) -> bool:
        """Take an entry out of the store; False when there is none.

        For corrupt entries (`verify`): once removed, the next run recomputes
        them. The entry is one file, so it disappears at once and whole. A
        store that cannot be written (read-only) raises `StoreError`.
        """
        return self._backend.remove(_check_name(stage, "stage"), _check_name(key, "key"))

    # -- claims: runs sharing one store compute each key once ----------------------
    @property
    def claims_per_task(self) -> bool:
        """Whether a run claims each task before computing it: True in a folder; False
        in an object store, where a claim would cost more requests than the result's
        own PUT (a put-if-absent commit still stores each key once)."""
        return self._backend.claims_per_task

    def claim(self, stage: str, key: str, *, lease: float = 60.0) -> Claim | None:
        """Claim the computing of `key`, or None when another live run holds it.

        A claim is the file ``<stage>/<key>.claim`` (process, host, expiry),
        created only where none exists (``O_CREAT | O_EXCL`` in a folder; the
        backend's put-if-absent in an object store, best effort). A claim
        whose lease has run out, or whose process is gone on this host, is
        taken over, so a crashed run blocks others for at most `lease`
        seconds. Hold the claim while computing and committing (as a context
        manager it renews its lease every ``lease / 3`` seconds), then release it.

        Parameters
        ----------
        stage, key : str
            The task.
        lease : float
            Seconds the claim holds without a renewal.

        Returns
        -------
        Claim or None
            None: wait for the entry with `wait_for`.
        """
        _check_name(stage, "stage"), _check_name(key, "key")
        if not lease > 0:
            raise StoreError(f"claim lease must be positive, got {lease!r}")
        name = key + _CLAIM
        for _ in range(3):  # another run may release or take over between the steps
            token = uuid.uuid4().hex
            doc = _claim_doc(token, lease)
            if self._backend.create(stage, name, doc):
                return Claim(self, stage, key, token, lease)
            found = self._backend.read_small(stage, name)
            if found is None:
                continue  # released since: try again
            if not _claim_stale(*found):
                return None
            if self._backend.take_over(stage, name, found[0], doc):
                return Claim(self, stage, key, token, lease)
        return None

    def wait_for(self, stage: str, key: str, *, timeout: float, poll: float = 0.05) -> bool:
        """Wait until `key` is committed by the run that claimed it.

        Returns True once the entry exists; False after `timeout` seconds, or
        as soon as the claim is released or goes stale without an entry (the
        other run failed or died: claim the task and compute it here).
        """
        _check_name(stage, "stage"), _check_name(key, "key")
        deadline = time.monotonic() + timeout
        delay = poll
        while True:
            if self._backend.exists(stage, key):
                return True
            found = self._backend.read_small(stage, key + _CLAIM)
            if found is None or _claim_stale(*found):
                return self._backend.exists(stage, key)
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(delay, left))
            delay = min(delay * 1.5, 1.0)

    # -- reading ---------------------------------------------------------------
    def _entry(self, key: str, stage: str | None) -> Entry:
        if stage is not None:
            if not self.exists(stage, key):
                raise StoreError(f"{stage} result {key[:12]} is not in store {self.root}")
            return Entry(key, stage, self.path_for(stage, key))
        return self.find(key)

    @contextlib.contextmanager
    def _members(self, entry: Entry) -> Iterator[_Read]:
        """The entry's zip, opened and its members checked: yields a function reading
        a member's bytes."""
        where = f"entry {entry.key[:12]} ({entry.stage}) in {self.root}"
        try:
            with self._backend.open_entry(entry.stage, entry.key) as archive:
                read = _member_reader(archive.zip, archive.size)
                yield read
        except FileNotFoundError:
            raise StoreError(
                f"{entry.stage} result {entry.key[:12]} is not in store {self.root}"
            ) from None
        except StoreError as exc:
            if " is corrupt: " in str(exc):
                raise
            raise StoreError(f"{where} is corrupt: {exc}") from None
        except (OSError, ValueError, EOFError, MemoryError, zipfile.BadZipFile) as exc:
            raise StoreError(f"{where} is corrupt: unreadable ({exc!r})") from None

    def metadata(self, key: str, stage: str | None = None) -> dict[str, Any]:
        """The entry's JSON attributes (record tree, task document, provenance, digests)."""
        entry = self._entry(key, stage)
        with self._members(entry) as read:
            return self._metadata(entry, read)

    @staticmethod
    def _metadata(entry: Entry, read: _Read) -> dict[str, Any]:
        try:
            doc = json.loads(read("zarr.json", None).decode("utf-8"))
            meta = doc["attributes"]["aeroid"]
        except (
            OSError,
            ValueError,
            KeyError,
            TypeError,
            MemoryError,
            StoreError,
            zipfile.BadZipFile,
        ) as exc:
            raise StoreError(
                f"entry {entry.key[:12]} ({entry.stage}) is corrupt: unreadable metadata ({exc})"
            ) from None
        if not isinstance(meta, dict):
            raise StoreError(f"entry {entry.key[:12]} ({entry.stage}) is corrupt: bad metadata")
        return meta

    def _read_verified(self, entry: Entry) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        with self._members(entry) as read:
            return self._verified(entry, read)

    def _verified(self, entry: Entry, read: _Read) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        meta = self._metadata(entry, read)
        where = f"entry {entry.key[:12]} ({entry.stage}) in {self.root}"
        try:
            if _content_digest(meta) != meta.get("content_digest"):
                raise StoreError(f"{where} is corrupt: its attributes were altered")
            if sha256_hex(_read_back_json(meta["task"])) != entry.key:
                raise StoreError(f"{where} is corrupt: its task document does not hash to its key")
            arrays: dict[str, np.ndarray] = {}
            for name, digest in meta["digests"].items():
                if "/" in name or name.startswith("."):
                    raise StoreError(f"{where} is corrupt: bad array name {name!r}")
                arr = _read_array(name, read)
                if array_digest(arr) != digest:
                    raise StoreError(
                        f"{where} is corrupt: array {name!r} does not match its digest"
                    )
                arrays[name] = arr
        except StoreError as exc:
            if " is corrupt: " in str(exc):
                raise
            raise StoreError(f"{where} is corrupt: {exc}") from None
        except Exception as exc:  # zip/json/codec errors on damaged bytes, MemoryError
            raise StoreError(f"{where} is corrupt: {type(exc).__name__}: {exc}") from None
        return meta, arrays

    def check_entry(self, stage: str, key: str) -> bool:
        """True when the entry exists and every member's bytes match their CRC-32.

        A cheap check for a cache hit before it counts as cached: the bytes
        are read in blocks and checksummed by zipfile, nothing is decoded and
        no digest computed (`verify` does that). False for a missing,
        damaged, linked or crafted entry (compressed or oversized members).
        Like the digests it catches accidents, not deliberate edits.
        """
        return self._checked_attributes(stage, key) is not None

    def cached_warnings(self, stage: str, key: str) -> tuple[str, ...] | None:
        """The warnings stored with a sound entry (as `check_entry`, in the same read),
        or None where `check_entry` is False: a cached rerun shows them again."""
        raw = self._checked_attributes(stage, key)
        if raw is None:
            return None
        try:
            found = json.loads(raw)["attributes"]["aeroid"]["provenance"].get("warnings", ())
        except (ValueError, KeyError, TypeError, AttributeError):
            return ()
        return tuple(str(w) for w in found) if isinstance(found, list) else ()

    def _checked_attributes(self, stage: str, key: str) -> bytes | None:
        """The root ``zarr.json`` of an entry whose members all pass their CRC-32, else None."""
        root = b""
        try:
            with self._backend.open_entry(
                _check_name(stage, "stage"), _check_name(key, "key")
            ) as a:
                for name, info in _checked_members(a.zip, a.size).items():
                    with a.zip.open(info) as member:
                        if name == "zarr.json":
                            root = member.read()
                        while member.read(1 << 20):
                            pass  # zipfile compares the CRC-32 at the end of the member
        except (StoreError, OSError, ValueError, EOFError, MemoryError, zipfile.BadZipFile):
            return None
        return root

    def _ident(self, stage: str, key: str) -> tuple[str, str, str]:
        return (self._root_id, stage, key)

    def load(self, key: str, stage: str | None = None) -> Any:
        """The stored result as its record type, after checking every digest."""
        if stage is not None:
            hit = _CACHE.get(self._ident(stage, key))
            if hit is not None:
                return hit
        entry = self._entry(key, stage)
        meta, arrays = self._read_verified(entry)
        record = codec.decode(meta["record"], arrays)
        if _CACHE.scope is not None:
            nbytes = sum(a.nbytes for a in arrays.values())
            _CACHE.put(self._ident(entry.stage, entry.key), record, nbytes)
        return record

    def load_arrays(self, key: str, stage: str | None = None) -> dict[str, np.ndarray]:
        """The entry's arrays by name (digests checked)."""
        return self._read_verified(self._entry(key, stage))[1]

    def verify(self, key: str, stage: str | None = None) -> str | None:
        """None when the entry is intact, else what is wrong with it."""
        return self._verify(key, stage)[0]

    def _verify(self, key: str, stage: str | None) -> tuple[str | None, tuple[str, ...]]:
        """What is wrong with the entry (None: intact), and the warnings stored with it."""
        try:
            entry = self._entry(key, stage)
            meta, arrays = self._read_verified(entry)
        except StoreError as exc:
            return str(exc), ()
        try:
            codec.decode(meta["record"], arrays)
        except codec.UnknownRecordType:
            pass  # intact bytes of a type defined by a pipeline not imported here
        except StoreError as exc:
            return str(exc), ()
        except MemoryError as exc:
            return f"entry {key[:12]} ({entry.stage}) in {self.root} is corrupt: {exc!r}", ()
        found = (meta.get("provenance") or {}).get("warnings") or ()
        return None, tuple(str(w) for w in found) if isinstance(found, list) else ()

    def verify_all(self) -> dict[str, str]:
        """Problems by key for every entry that fails its checks.

        The entries found intact become the store's index of entries checked
        whole (`verified`), which later runs trust instead of reading them.
        A link planted as a stage folder raises `StoreError` naming it: the
        store neither reads nor removes anything through it.
        """
        old = [name for name, _ in self._backend.index_files()]
        bad: dict[str, str] = {}
        sound: dict[tuple[str, str], tuple[str, ...]] = {}
        for entry in self.entries():
            problem, found = self._verify(entry.key, entry.stage)
            if problem is not None:
                bad[entry.key] = f"{entry.stage}: {problem}"
            else:
                sound[(entry.stage, entry.key)] = found
        listed = self.signatures({stage for stage, _ in sound})
        index = {i: (listed[i], w) for i, w in sound.items() if i in listed}
        with contextlib.suppress(OSError, StoreError):  # a read-only store: no index
            verified.replace(self, index, old)
        return bad

    def signatures(self, stages: Iterable[str]) -> dict[tuple[str, str], tuple[int, str]]:
        """(stage, key) -> signature (size, time or ETag) of every entry of `stages`, as
        the store's listing shows it: one listing per stage, no entry opened."""
        return self._backend.signatures({_check_name(s, "stage") for s in stages})

    # -- housekeeping ----------------------------------------------------------
    def temporaries(self) -> list[Path | str]:
        """Partial writes left under ``.tmp`` (none in an object store: an entry is one PUT)."""
        return self._backend.temporaries()

    def gc(self, *, max_age: float = 3600.0) -> list[Path | str]:
        """Remove temporaries of crashed runs; return what was removed.

        A temporary of a process still running on this host is kept; one from
        another host is removed once older than `max_age` seconds. A link in
        place of ``.tmp`` raises `StoreError` and nothing is removed.
        """
        return self._backend.gc(max_age)


def is_store(root: str | os.PathLike[str] | StoreLocation) -> bool:
    """True when `root` (a folder or URL) holds an aeroid store."""
    location = parse(root)
    if location.kind == "local":
        return os.path.isfile(os.path.join(location.root, _MARKER))
    try:
        from ._objectstore import url_to_fs

        fs, base = url_to_fs(location.root)
        return bool(fs.exists(f"{base.rstrip('/')}/{_MARKER}"))
    except (ImportError, ValueError) as exc:
        raise StoreError(f"store {location.root!r}: {exc}") from None


def open_store(
    root: str | os.PathLike[str] | StoreLocation, *, create: bool = False
) -> ResultStore:
    """Open a result store (by default an existing one)."""
    return ResultStore(root, create=create)
