"""The result store: one immutable Zarr v3 group per task result.

Layout under the store root::

    aeroid-store.json                 marker with the layout version
    <stage>/<key[:2]>/<key>/          one Zarr group per result (arrays + JSON attributes)
    .tmp/<key>.<host>.<pid>.<nonce>/  results being written (removed by `gc` after a crash)

A result is written completely under ``.tmp`` and then renamed into place,
so a reader sees either nothing or a whole entry. If the target already
exists another run committed the same key first and the copy is discarded
(an entry is never overwritten). Every array's SHA-256 and a digest of the
JSON content are stored in the group's attributes and checked on every
read; an altered entry raises `StoreError` and is never returned.

A store may also live at a URL that fsspec understands (``s3://``,
``gs://``, ``az://``, ...; the backend's package must be installed). Object
stores cannot rename, so there the group's metadata, written last in one
object, is what commits an entry (see `_ObjectStore`).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import socket
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..errors import StoreError
from . import codec
from .keys import _canonical_plain, array_digest, canonical_json, sha256_hex, to_jsonable

__all__ = ["Entry", "ResultStore", "is_store", "is_url", "open_store", "record_cache"]

FORMAT = 1
_MARKER = "aeroid-store.json"
_TMP = ".tmp"


@dataclass(frozen=True)
class Entry:
    """A committed result: its key, stage and location (a folder, or a URL in an object store)."""

    key: str
    stage: str
    path: Path | str


# -- a minimal Zarr v3 writer/reader for what the store holds ------------------------
# Entries are plain Zarr v3 (any zarr-python reads them): one uncompressed chunk
# per array with the little-endian ``bytes`` codec. Writing and reading those
# files directly costs well under a millisecond per array, against several for
# zarr-python's general machinery; entries written otherwise are read by zarr.

_DTYPES = {
    "b": "bool",
    "i1": "int8",
    "i2": "int16",
    "i4": "int32",
    "i8": "int64",
    "u1": "uint8",
    "u2": "uint16",
    "u4": "uint32",
    "u8": "uint64",
    "f4": "float32",
    "f8": "float64",
    "c8": "complex64",
    "c16": "complex128",
}
_NUMPY = {v: ("?" if k == "b" else "<" + k) for k, v in _DTYPES.items()}


def _zarr_dtype(arr: np.ndarray) -> str:
    code = "b" if arr.dtype.kind == "b" else f"{arr.dtype.kind}{arr.dtype.itemsize}"
    if code not in _DTYPES:
        raise StoreError(f"arrays of dtype {arr.dtype} cannot be stored")
    return _DTYPES[code]


def _write_file(path: str, data: bytes) -> None:
    # os-level calls: a commit writes a few files per array, and pathlib's and
    # io's layers cost more than the system calls themselves
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)


def _array_files(arr: np.ndarray) -> list[tuple[str, bytes]]:
    """The files of an array as Zarr v3 (name within the array's folder, bytes)."""
    dtype = _zarr_dtype(arr)
    meta = _array_meta(dtype, tuple(int(n) for n in arr.shape))
    if arr.size == 0:
        return [("zarr.json", meta)]  # an empty array has no chunk
    data = np.ascontiguousarray(arr, dtype=_NUMPY[dtype])
    return [("zarr.json", meta), (_chunk_name(arr.ndim), data.tobytes())]


@functools.lru_cache(maxsize=256)
def _array_meta(dtype: str, shape: tuple[int, ...]) -> bytes:
    # a campaign stores the same few shapes over and over
    fill: Any = False if dtype == "bool" else (0 if dtype[0] in "iu" else 0.0)
    if dtype.startswith("complex"):
        fill = [0.0, 0.0]
    chunk = [max(1, n) for n in shape]
    return json.dumps(
        {
            "zarr_format": 3,
            "node_type": "array",
            "shape": list(shape),
            "data_type": dtype,
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": chunk}},
            # "v2" keys ("0.0") put the single chunk beside zarr.json: no chunk directories
            "chunk_key_encoding": {"name": "v2", "configuration": {"separator": "."}},
            "fill_value": fill,
            "codecs": [{"name": "bytes", "configuration": {"endian": "little"}}],
            "attributes": {},
            "storage_transformers": [],
        },
        separators=(",", ":"),
    ).encode("utf-8")


def _write_array(path: str, arr: np.ndarray) -> None:
    os.mkdir(path)
    for name, data in _array_files(arr):
        _write_file(os.path.join(path, name), data)


def _chunk_name(ndim: int) -> str:
    return ".".join(["0"] * ndim) or "0"


def _chunk_path(path: str, ndim: int, encoding: Any) -> str | None:
    """Where the single chunk of an array lives, for the key encodings this store writes."""
    if not isinstance(encoding, dict):
        return None
    sep = (encoding.get("configuration") or {}).get("separator")
    if encoding.get("name") == "v2" and sep == ".":
        return f"{path}/{_chunk_name(ndim)}"
    if encoding.get("name") == "default" and sep == "/":  # entries of earlier versions
        return "/".join([path, "c", *(["0"] * ndim)])
    return None


def _read_local(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def _read_array(path: str, read: Callable[[str], bytes] = _read_local) -> np.ndarray | None:
    """Read an array written by `_write_array` (files read by `read`); None when it was
    written otherwise."""
    meta = json.loads(read(f"{path}/zarr.json").decode("utf-8"))
    dtype = _NUMPY.get(meta.get("data_type"))
    shape = tuple(int(n) for n in meta["shape"])
    layout_ok = (
        meta.get("codecs") == [{"name": "bytes", "configuration": {"endian": "little"}}]
        and meta.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape")
        == [max(1, n) for n in shape]
        and dtype is not None
    )
    target = _chunk_path(path, len(shape), meta.get("chunk_key_encoding"))
    if not layout_ok or target is None:
        return None
    if 0 in shape:
        return np.zeros(shape, dtype=dtype)
    raw = read(target)
    arr = np.frombuffer(raw, dtype=dtype)
    if arr.size != int(np.prod(shape)):
        raise StoreError(f"chunk {target} holds {arr.size} values, expected {int(np.prod(shape))}")
    return arr.reshape(shape).astype(np.dtype(dtype).newbyteorder("="))


_DIGESTED = ("key", "stage", "record", "task", "digests")


def _read_back_json(document: Any) -> bytes:
    """`canonical_json` of a document read back from JSON.

    Such a document is plain JSON already, so the normalising pass of
    `canonical_json` (a quarter of the time of a verified read) is skipped,
    unless the bytes hold what this store never writes (a NaN, say): then it is
    normalised as on writing, and the digest will not match.
    """
    try:
        return _canonical_plain(document)
    except (TypeError, ValueError):
        return canonical_json(document)


def _content_digest(meta: Mapping[str, Any]) -> str:
    return sha256_hex(_read_back_json({k: meta[k] for k in _DIGESTED}))


def _entry_document(
    stage: str,
    key: str,
    record: Any,
    task: Mapping[str, Any],
    provenance: Mapping[str, Any] | None,
) -> tuple[dict[str, Any], dict[str, np.ndarray], bytes]:
    """An entry's attributes (digests included), its arrays, and the canonical JSON of
    the attributes its content digest covers."""
    tree, arrays = codec.encode(record)
    meta: dict[str, Any] = {
        "format": FORMAT,
        "key": key,
        "stage": stage,
        "record_type": tree["__record__"],
        "record": tree,
        "task": dict(task),
        "digests": {name: array_digest(a) for name, a in arrays.items()},
        "provenance": dict(provenance or {}),
    }
    try:
        # the encoded record and a planned task's document are plain JSON already
        digested = _canonical_plain({k: meta[k] for k in _DIGESTED})
    except (TypeError, ValueError):
        meta = to_jsonable(meta, where=f"{stage} result")  # plain JSON types only
        digested = _canonical_plain({k: meta[k] for k in _DIGESTED})
    meta["content_digest"] = sha256_hex(digested)
    return meta, arrays, digested


def _group_bytes(meta: dict[str, Any], digested: bytes, stage: str) -> bytes:
    """The group's ``zarr.json`` holding an entry's attributes.

    The digested attributes go in as the canonical bytes already made for the
    digest (serialising them again cost as much); the rest follows them.
    """

    def dump(value: Any) -> bytes:
        text = json.dumps(value, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
        return text.encode("utf-8")

    try:
        provenance = dump(meta["provenance"])
    except (TypeError, ValueError):
        # the provenance (not in the digest) held what JSON cannot (a NumPy scalar, NaN)
        meta["provenance"] = to_jsonable(meta["provenance"], where=f"{stage} result")
        provenance = dump(meta["provenance"])
    rest = {k: meta[k] for k in ("format", "record_type", "content_digest")}
    return b"".join(
        (
            b'{"zarr_format":3,"node_type":"group","attributes":{"aeroid":',
            digested[:-1],  # the digested mapping, open for the rest
            b',"provenance":',
            provenance,
            b",",
            dump(rest)[1:],  # closes the mapping
            b"}}",
        )
    )


@functools.lru_cache(maxsize=1)
def _hostname() -> str:
    return socket.gethostname()


def _mkdir(path: str) -> None:
    """`os.mkdir(path)`, making its parent folders only when they are missing."""
    try:
        os.mkdir(path)
    except FileNotFoundError:  # a new store, or `gc` or a user removed the folder
        os.makedirs(os.path.dirname(path), exist_ok=True)
        os.mkdir(path)


def _rename_into(tmp: str, final: str) -> None:
    """`os.rename(tmp, final)`, making the folder of `final` only when it is missing."""
    try:
        os.rename(tmp, final)
    except FileNotFoundError:  # the first entry under this key prefix
        os.makedirs(os.path.dirname(final), exist_ok=True)
        os.rename(tmp, final)


# -- a run-scoped cache of records -------------------------------------------------
# Within one run, a record committed or read (digests checked) by this process is
# handed to later tasks of the same run without reading it back: entries are
# immutable, so the copy in memory is what a verified read would return. A new
# scope (the next run) starts empty, so every run verifies what it reads at least
# once; outside a scope nothing is cached.

_CACHE_BYTES = 256 * 2**20


class _RecordCache:
    def __init__(self) -> None:
        self.scope: str | None = None
        self.items: OrderedDict[tuple[str, str, str], tuple[Any, int]] = OrderedDict()
        self.nbytes = 0
        self.lock = threading.Lock()
        self.stores: dict[str, ResultStore] = {}  # opened in this scope, by root

    def enter(self, scope: str | None) -> None:
        with self.lock:
            if scope != self.scope:
                self.items.clear()
                self.stores.clear()
                self.nbytes = 0
                self.scope = scope

    def get(self, ident: tuple[str, str, str]) -> Any:
        with self.lock:
            if self.scope is None or ident not in self.items:
                return None
            self.items.move_to_end(ident)
            return self.items[ident][0]

    def put(self, ident: tuple[str, str, str], record: Any, nbytes: int) -> None:
        with self.lock:
            if self.scope is None or nbytes > _CACHE_BYTES or ident in self.items:
                return
            self.items[ident] = (record, nbytes)
            self.nbytes += nbytes
            while self.nbytes > _CACHE_BYTES:
                _, (_, n) = self.items.popitem(last=False)
                self.nbytes -= n


_CACHE = _RecordCache()
_CHECKED: set[str] = set()  # store roots whose marker this process has read


def record_cache(scope: str | None) -> None:
    """Cache records in this process for the run `scope` (None: stop caching, forget all)."""
    _CACHE.enter(scope)


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


_MARKER_DOC = json.dumps({"format": FORMAT, "kind": "aeroid result store"}).encode("utf-8")


def _check_marker(raw: bytes, store: Path | str) -> None:
    """Raise unless `raw` is a store marker of the layout version this aeroid reads."""
    try:
        info = json.loads(raw)
    except ValueError as exc:
        raise StoreError(f"store {store}: unreadable marker {_MARKER} ({exc})") from None
    got = info.get("format") if isinstance(info, dict) else info
    if got != FORMAT:
        raise StoreError(
            f"store {store}: layout version {got!r}, this aeroid reads version {FORMAT}"
        )


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class ResultStore:
    """A directory of immutable, content-keyed results.

    Parameters
    ----------
    root : str or Path
        The store directory, or the URL of a store in an object store
        (``s3://bucket/campaign``; anything fsspec understands), created when
        `create` is true. On a cluster every worker must reach it: a shared
        filesystem or an object store.
    create : bool
        Create the store if it does not exist; otherwise raise `StoreError`.
    """

    root: Path | str
    """The store's folder, or its URL in an object store."""
    _look_first: ClassVar[bool] = False

    def __new__(cls, root: str | Path, *, create: bool = True) -> ResultStore:
        if cls is ResultStore and is_url(str(root)):
            return super().__new__(_ObjectStore)
        return super().__new__(cls)

    def __init__(self, root: str | Path, *, create: bool = True) -> None:
        self._dir = Path(str(root).removeprefix("file://")).expanduser()
        self.root = self._dir
        self._root_id = os.path.abspath(self._dir)
        marker = self._dir / _MARKER
        if self._root_id in _CHECKED and marker.is_file():
            return  # this process has read this store's marker already
        if marker.is_file():
            try:
                raw = marker.read_bytes()
            except OSError as exc:
                raise StoreError(f"store {self.root}: unreadable marker {marker} ({exc})") from None
            _check_marker(raw, self.root)
        elif create:
            if self._dir.exists() and not self._dir.is_dir():
                raise StoreError(f"store {self.root}: is a file, not a folder")
            if self._dir.exists() and any(self._dir.iterdir()):
                raise StoreError(
                    f"store {self.root}: the directory exists, is not empty and is not an "
                    "aeroid store"
                )
            try:
                self._dir.mkdir(parents=True, exist_ok=True)
                tmp = self._dir / f".{_MARKER}.{uuid.uuid4().hex}"
                tmp.write_bytes(_MARKER_DOC)
                os.replace(tmp, marker)
            except OSError as exc:
                raise StoreError(
                    f"store {self.root}: cannot create it ({exc.strerror or exc})"
                ) from None
        else:
            raise StoreError(f"store {self.root}: not an aeroid store (no {_MARKER})")
        _CHECKED.add(self._root_id)

    def __repr__(self) -> str:
        return f"ResultStore({str(self.root)!r})"

    # -- locations -------------------------------------------------------------
    def path_for(self, stage: str, key: str) -> Path | str:
        """Where the result of `key` in `stage` lives (whether or not it exists)."""
        return self._dir / stage / key[:2] / key

    def exists(self, stage: str, key: str) -> bool:
        """True when `key` is committed (commits are atomic, so existence means complete)."""
        return os.path.isdir(os.path.join(self._root_id, stage, key[:2], key))

    def stored(self, tasks: Iterable[tuple[str, str]]) -> set[tuple[str, str]]:
        """The (stage, key) pairs among `tasks` that are committed."""
        # a stage with no folder yet (a new store, a new stage) has none: one look for all
        has_stage: dict[str, bool] = {}
        out = set()
        for stage, key in tasks:
            if stage not in has_stage:
                has_stage[stage] = os.path.isdir(os.path.join(self._root_id, stage))
            if has_stage[stage] and self.exists(stage, key):
                out.add((stage, key))
        return out

    def _read(self, path: str) -> bytes:
        return _read_local(path)

    def entries(self, stage: str | None = None) -> Iterator[Entry]:
        """Every committed entry, optionally of one stage."""
        if not self._dir.is_dir():
            return
        stages = (
            [stage]
            if stage
            else sorted(
                p.name for p in self._dir.iterdir() if p.is_dir() and not p.name.startswith(".")
            )
        )
        for s in stages:
            base = self._dir / s
            if not base.is_dir():
                continue
            for prefix in sorted(base.iterdir()):
                if not prefix.is_dir():
                    continue
                for entry in sorted(prefix.iterdir()):
                    if entry.is_dir():
                        yield Entry(entry.name, s, entry)

    def find(self, key: str) -> Entry:
        """The entry whose key is `key` or starts with it (at least 6 hex digits)."""
        key = key.strip().lower()
        if len(key) < 6 or any(c not in "0123456789abcdef" for c in key):
            raise StoreError(f"key {key!r}: expected at least 6 hexadecimal digits")
        hits = self._starting_with(key)
        if not hits:
            raise StoreError(f"key {key}: no such entry in store {self.root}")
        if len(hits) > 1:
            raise StoreError(f"key {key}: ambiguous, matches {[h.key[:12] for h in hits]}")
        return hits[0]

    def _starting_with(self, key: str) -> list[Entry]:
        hits = []
        for stage_dir in sorted(self._dir.iterdir()) if self._dir.is_dir() else []:
            if not stage_dir.is_dir() or stage_dir.name.startswith("."):
                continue
            prefix = stage_dir / key[:2]
            if prefix.is_dir():
                hits += [Entry(p.name, stage_dir.name, p) for p in prefix.glob(f"{key}*")]
        return hits

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
        # on a file system the final rename refuses an existing entry: no look first
        if self._look_first and self.exists(stage, key):
            return False
        meta, arrays, digested = _entry_document(stage, key, record, task, provenance)
        group = _group_bytes(meta, digested, stage)
        if not self._publish(stage, key, arrays, group):
            return False
        if _CACHE.scope is not None:
            # what a verified read of the new entry returns (the tree went through JSON)
            nbytes = sum(a.nbytes for a in arrays.values())
            _CACHE.put(self._ident(stage, key), codec.decode(meta["record"], arrays), nbytes)
        return True

    def _publish(
        self, stage: str, key: str, arrays: Mapping[str, np.ndarray], group: bytes
    ) -> bool:
        """Write the entry's files under a temporary name, then rename it into place."""
        final = os.path.join(self._root_id, stage, key[:2], key)
        tmp = self._temporary(key)
        try:
            _mkdir(tmp)
            for name, arr in arrays.items():
                _write_array(os.path.join(tmp, name), arr)
            # the group's metadata is written last: a complete group, then the rename
            _write_file(os.path.join(tmp, "zarr.json"), group)
            try:
                _rename_into(tmp, final)
            except OSError:
                if os.path.isdir(final):  # another run committed the same key first
                    shutil.rmtree(tmp, ignore_errors=True)
                    return False
                raise
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return True

    def _temporary(self, key: str) -> str:
        # host and pid in the name let `gc` keep the temporaries of live processes
        name = f"{key}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        return os.path.join(self._root_id, _TMP, name)

    def remove(self, stage: str, key: str) -> bool:
        """Take an entry out of the store; False when there is none.

        For corrupt entries (`verify`): once removed, the next run recomputes
        them. The entry disappears at once, by a rename into the temporaries,
        and its files are deleted after.
        """
        final = os.path.join(self._root_id, stage, key[:2], key)
        tmp = self._temporary(key)
        try:
            _rename_into(final, tmp)
        except FileNotFoundError:
            return False
        shutil.rmtree(tmp, ignore_errors=True)  # what is left, `gc` collects
        return True

    # -- reading ---------------------------------------------------------------
    def _entry(self, key: str, stage: str | None) -> Entry:
        if stage is not None:
            if not self.exists(stage, key):
                raise StoreError(f"{stage} result {key[:12]} is not in store {self.root}")
            return Entry(key, stage, self.path_for(stage, key))
        return self.find(key)

    def metadata(self, key: str, stage: str | None = None) -> dict[str, Any]:
        """The entry's JSON attributes (record tree, task document, provenance, digests)."""
        entry = self._entry(key, stage)
        try:
            doc = json.loads(self._read(f"{entry.path}/zarr.json").decode("utf-8"))
            meta = doc["attributes"]["aeroid"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise StoreError(
                f"entry {entry.key[:12]} ({entry.stage}) is corrupt: unreadable metadata ({exc})"
            ) from None
        if not isinstance(meta, dict):
            raise StoreError(f"entry {entry.key[:12]} ({entry.stage}) is corrupt: bad metadata")
        return meta

    def _read_verified(self, entry: Entry) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        meta = self.metadata(entry.key, entry.stage)
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
                got = _read_array(f"{entry.path}/{name}", self._read)
                if got is None:  # written by another Zarr writer: let zarr-python read it
                    import zarr

                    node: Any = zarr.open_array(store=f"{entry.path}/{name}", mode="r")
                    got = np.asarray(node[...])
                arr = got
                if array_digest(arr) != digest:
                    raise StoreError(
                        f"{where} is corrupt: array {name!r} does not match its digest"
                    )
                arrays[name] = arr
        except StoreError as exc:
            if " is corrupt: " in str(exc):
                raise
            raise StoreError(f"{where} is corrupt: {exc}") from None
        except Exception as exc:  # zarr/json/codec errors on damaged bytes
            raise StoreError(f"{where} is corrupt: {type(exc).__name__}: {exc}") from None
        return meta, arrays

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
        try:
            entry = self._entry(key, stage)
            meta, arrays = self._read_verified(entry)
        except StoreError as exc:
            return str(exc)
        try:
            codec.decode(meta["record"], arrays)
        except codec.UnknownRecordType:
            pass  # intact bytes of a type defined by a pipeline not imported here
        except StoreError as exc:
            return str(exc)
        return None

    def verify_all(self) -> dict[str, str]:
        """Problems by key for every entry that fails its checks."""
        bad = {}
        for entry in self.entries():
            problem = self.verify(entry.key, entry.stage)
            if problem is not None:
                bad[entry.key] = f"{entry.stage}: {problem}"
        return bad

    # -- housekeeping ----------------------------------------------------------
    def temporaries(self) -> list[Path | str]:
        """Partial writes left under ``.tmp``."""
        return list(self._partial_writes())

    def _partial_writes(self) -> list[Path]:
        tmp = self._dir / _TMP
        return sorted(tmp.iterdir()) if tmp.is_dir() else []

    def gc(self, *, max_age: float = 3600.0) -> list[Path | str]:
        """Remove temporaries of crashed runs; return what was removed.

        A temporary of a process still running on this host is kept; one from
        another host is removed once older than `max_age` seconds.
        """
        removed: list[Path | str] = []
        host = _hostname()
        now = time.time()
        for path in self._partial_writes():
            parts = path.name.split(".")
            alive = False
            if len(parts) >= 4:
                t_host, t_pid = ".".join(parts[1:-2]), parts[-2]
                if t_host == host and t_pid.isdigit():
                    alive = _pid_alive(int(t_pid)) and int(t_pid) != os.getpid()
                else:
                    try:
                        alive = now - path.stat().st_mtime < max_age
                    except OSError:
                        alive = False
            if not alive:
                if path.is_dir():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)
                removed.append(path)
        return removed


def is_url(location: str | Path) -> bool:
    """True when a store location is a URL for fsspec (``s3://...``), not a folder."""
    text = str(location)
    return "://" in text and not text.startswith("file://")


class _ObjectStore(ResultStore):
    """A store at a URL that fsspec understands (``s3://``, ``gs://``, ``az://``, ``memory://`` ...).

    Object stores have no atomic rename, so a commit writes the entry's arrays
    straight under its prefix and the group's ``zarr.json`` last, in one PUT:
    an entry exists once that object does. A run killed before it leaves
    arrays that no reader sees, which the next run rewrites and `gc` removes.
    Two runs that commit the same key at once write the same arrays (results
    are deterministic); were they to differ, the digests say so on every read.
    """

    _look_first = True  # a PUT overwrites: never write under a committed key

    def __init__(self, root: str | Path, *, create: bool = True) -> None:
        text = str(root).rstrip("/")
        try:
            import fsspec

            fs, base = fsspec.core.url_to_fs(text)
        except (ImportError, ValueError) as exc:  # unknown protocol, backend not installed
            raise StoreError(f"store {text!r}: {exc}") from None
        self.root = self._url_root = text
        self._root_id = text
        self._fs = fs
        self._base = str(base).rstrip("/")  # every file goes through `_fs`: no `_dir`
        if text in _CHECKED:
            return
        marker = f"{self._base}/{_MARKER}"
        try:
            raw: bytes | None = fs.cat_file(marker)
        except FileNotFoundError:
            raw = None
        except Exception as exc:
            raise StoreError(f"store {text}: cannot read {_MARKER} ({exc})") from None
        if raw is not None:
            _check_marker(raw, text)
        elif create:
            if fs.exists(self._base) and fs.ls(self._base, detail=False):
                raise StoreError(
                    f"store {text}: the location exists, is not empty and is not an aeroid store"
                )
            self._put({marker: _MARKER_DOC})
        else:
            raise StoreError(f"store {text}: not an aeroid store (no {_MARKER})")
        _CHECKED.add(text)

    def _path(self, location: str) -> str:
        """The filesystem path of a URL under this store (entry locations and
        temporaries are built from its root)."""
        return self._base + location[len(self._url_root) :]

    def _url(self, path: str) -> str:
        return self._url_root + path[len(self._base) :]

    def path_for(self, stage: str, key: str) -> Path | str:
        return f"{self._url_root}/{stage}/{key[:2]}/{key}"

    def exists(self, stage: str, key: str) -> bool:
        return bool(self._fs.exists(f"{self._base}/{stage}/{key[:2]}/{key}/zarr.json"))

    def stored(self, tasks: Iterable[tuple[str, str]]) -> set[tuple[str, str]]:
        # one listing per stage instead of a request per key
        wanted = set(tasks)
        found = set()
        for stage in {stage for stage, _ in wanted}:
            found |= {(e.stage, e.key) for e in self._groups(stage, "")}
        return wanted & found

    def _read(self, path: str) -> bytes:
        return bytes(self._fs.cat_file(self._path(path)))

    def _groups(self, stage: str, key: str) -> list[Entry]:
        pattern = f"{self._base}/{stage}/{key[:2] if len(key) >= 2 else '*'}/{key}*/zarr.json"
        out = []
        for found in sorted(self._fs.glob(pattern)):
            folder = str(found).rsplit("/", 1)[0]
            st, _, name = folder[len(self._base) + 1 :].split("/")
            if not st.startswith("."):
                out.append(Entry(name, st, self._url(folder)))
        return out

    def entries(self, stage: str | None = None) -> Iterator[Entry]:
        yield from self._groups(stage or "*", "")

    def _starting_with(self, key: str) -> list[Entry]:
        return self._groups("*", key)

    def _publish(
        self, stage: str, key: str, arrays: Mapping[str, np.ndarray], group: bytes
    ) -> bool:
        final = f"{self._base}/{stage}/{key[:2]}/{key}"
        files = {
            f"{final}/{name}/{file}": data
            for name, arr in arrays.items()
            for file, data in _array_files(arr)
        }
        if files:
            self._put(files)
        self._put({f"{final}/zarr.json": group})  # the commit: one object, written last
        return True

    def remove(self, stage: str, key: str) -> bool:
        # the entry is gone once its group metadata is, as it appeared with it
        final = f"{self._base}/{stage}/{key[:2]}/{key}"
        try:
            self._fs.rm_file(f"{final}/zarr.json")
        except FileNotFoundError:
            return False
        with contextlib.suppress(FileNotFoundError):
            self._fs.rm(final, recursive=True)
        return True

    def _put(self, files: dict[str, bytes]) -> None:
        """Write files (concurrently, where the backend can)."""
        try:
            self._fs.pipe(files)
        except FileNotFoundError:
            # a filesystem with real folders (``local://``, ``sftp://``): make them once
            for folder in sorted({f.rsplit("/", 1)[0] for f in files}):
                self._fs.makedirs(folder, exist_ok=True)
            self._fs.pipe(files)

    def temporaries(self) -> list[Path | str]:
        """Entries begun by a commit that has not ended: arrays without the group's metadata."""
        folders: dict[str, bool] = {}
        for found in self._fs.find(self._base):
            rel = str(found)[len(self._base) + 1 :].split("/")
            if len(rel) < 4 or rel[0].startswith("."):
                continue
            folder = "/".join(rel[:3])
            done = len(rel) == 4 and rel[3] == "zarr.json"
            folders[folder] = folders.get(folder, False) or done
        return [self._url(f"{self._base}/{f}") for f, done in sorted(folders.items()) if not done]

    def gc(self, *, max_age: float = 3600.0) -> list[Path | str]:
        """Remove entries begun more than `max_age` seconds ago and never committed.

        Object stores record no writer process, so age is the only sign that
        a commit has ended; an entry whose files have no age is kept.
        """
        removed: list[Path | str] = []
        now = time.time()
        for url in self.temporaries():
            folder = self._path(str(url))
            try:
                newest = max(self._fs.modified(f).timestamp() for f in self._fs.find(folder))
            except (NotImplementedError, OSError, ValueError):
                continue
            if now - newest >= max_age:
                self._fs.rm(folder, recursive=True)
                removed.append(url)
        return removed


def is_store(root: str | Path) -> bool:
    """True when `root` (a folder or URL) holds an aeroid store."""
    text = str(root)
    if not is_url(text):
        return (Path(text.removeprefix("file://")).expanduser() / _MARKER).is_file()
    try:
        import fsspec

        fs, base = fsspec.core.url_to_fs(text.rstrip("/"))
        return bool(fs.exists(f"{str(base).rstrip('/')}/{_MARKER}"))
    except (ImportError, ValueError) as exc:
        raise StoreError(f"store {text!r}: {exc}") from None


def open_store(root: str | Path, *, create: bool = False) -> ResultStore:
    """Open a result store (by default an existing one)."""
    return ResultStore(root, create=create)
