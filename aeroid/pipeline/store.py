"""The result store: one immutable Zarr v3 group per task result.

Layout under the store root::

    aeroid-store.json                marker with the layout version
    <stage>/<key>.zarr.zip           one result: a zipped Zarr v3 group (arrays + JSON attributes)
    .tmp/<key>.<host>.<pid>.<nonce>  results being written (removed by `gc` after a crash)

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
returned.

A store may also live at a URL that fsspec understands (``s3://``,
``gs://``, ``az://``, ...; the backend's package must be installed). There an
entry is one object written in one PUT, which object stores make visible whole
or not at all (see `_ObjectStore`).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import io
import json
import os
import shutil
import socket
import struct
import threading
import time
import uuid
import zipfile
import zlib
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

FORMAT = 2  # 1: a folder per entry under <stage>/<key[:2]>/
_MARKER = "aeroid-store.json"
_TMP = ".tmp"
_SUFFIX = ".zarr.zip"


@dataclass(frozen=True)
class Entry:
    """A committed result: its key, stage and location (a zip file, or a URL in an object store)."""

    key: str
    stage: str
    path: Path | str


# -- a minimal Zarr v3 writer/reader for what the store holds ------------------------
# Entries are plain Zarr v3 (zarr-python reads them through its ZipStore): one
# uncompressed chunk per array with the little-endian ``bytes`` codec, beside the
# array's ``zarr.json`` in the zip. Writing and reading those members directly
# costs well under a millisecond per array, against several for zarr-python's
# general machinery.

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
_BYTES_CODEC = [{"name": "bytes", "configuration": {"endian": "little"}}]
# "v2" keys ("0.0") put an array's single chunk beside its zarr.json
_CHUNK_KEYS = {"name": "v2", "configuration": {"separator": "."}}
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def _zarr_dtype(arr: np.ndarray) -> str:
    code = "b" if arr.dtype.kind == "b" else f"{arr.dtype.kind}{arr.dtype.itemsize}"
    if code not in _DTYPES:
        raise StoreError(f"arrays of dtype {arr.dtype} cannot be stored")
    return _DTYPES[code]


def _array_files(arr: np.ndarray) -> list[tuple[str, bytes]]:
    """The members of an array as Zarr v3 (name within the array's node, bytes)."""
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
            "chunk_key_encoding": _CHUNK_KEYS,
            "fill_value": fill,
            "codecs": _BYTES_CODEC,
            "attributes": {},
            "storage_transformers": [],
        },
        separators=(",", ":"),
    ).encode("utf-8")


def _chunk_name(ndim: int) -> str:
    return ".".join(["0"] * ndim) or "0"


def _entry_zip(arrays: Mapping[str, np.ndarray], group: bytes) -> bytes:
    """An entry's zip: every array, then the group's metadata."""
    members = [
        (f"{name}/{file}", data) for name, arr in arrays.items() for file, data in _array_files(arr)
    ]
    members.append(("zarr.json", group))
    if len(members) < 0xFFFF and sum(len(data) for _, data in members) < _ZIP32_LIMIT:
        return _stored_zip(members)
    out = io.BytesIO()  # past the limits of the plain zip format: zipfile writes Zip64
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
        for name, data in members:
            info = zipfile.ZipInfo(name, _ZIP_TIME)
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
    return out.getvalue()


# An uncompressed zip (APPNOTE 6.3: local headers and data, central directory, end
# record), written directly: zipfile's writer costs about 10 us a member, a third of
# a commit, for what is a few struct.pack calls. zipfile reads what this writes.
_ZIP32_LIMIT = 2**31
_LOCAL = struct.Struct("<IHHHHHIIIHH")
_CENTRAL = struct.Struct("<IHHHHHHIIIHHHHHII")
_END = struct.Struct("<IHHHHIIH")
_DOS_DATE = (1 << 5) | 1  # 1980-01-01, time 00:00: members carry no clock


def _stored_zip(members: list[tuple[str, bytes]]) -> bytes:
    parts: list[bytes] = []
    central: list[bytes] = []
    offset = 0
    for name, data in members:
        raw = name.encode("utf-8")
        flags = 0 if raw.isascii() else 0x800  # bit 11: the name is UTF-8
        crc, size = zlib.crc32(data), len(data)
        fields = (flags, 0, 0, _DOS_DATE, crc, size, size, len(raw))  # stored, no clock
        head = _LOCAL.pack(0x04034B50, 20, *fields, 0)
        # made by Unix (3) zip 2.0, so the external attributes are its file mode
        central.append(
            _CENTRAL.pack(0x02014B50, 0x0314, 20, *fields, 0, 0, 0, 0, 0o644 << 16, offset)
        )
        central.append(raw)
        parts += (head, raw, data)
        offset += len(head) + len(raw) + size
    directory = b"".join(central)
    n = len(members)
    end = _END.pack(0x06054B50, 0, 0, n, n, len(directory), offset, 0)
    return b"".join((*parts, directory, end))


def _read_array(name: str, read: Callable[[str], bytes]) -> np.ndarray:
    """Read the array `name` of an entry whose members `read` returns."""
    meta = json.loads(read(f"{name}/zarr.json").decode("utf-8"))
    dtype = _NUMPY.get(meta.get("data_type"))
    shape = tuple(int(n) for n in meta["shape"])
    if (
        dtype is None
        or meta.get("codecs") != _BYTES_CODEC
        or meta.get("chunk_key_encoding") != _CHUNK_KEYS
        or meta.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape")
        != [max(1, n) for n in shape]
    ):
        raise StoreError(f"array {name!r} is not in this store's layout")
    if 0 in shape:
        return np.zeros(shape, dtype=dtype)
    target = f"{name}/{_chunk_name(len(shape))}"
    arr = np.frombuffer(read(target), dtype=dtype)
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


def _move_into(tmp: str, final: str) -> bool:
    """Move the written file `tmp` to `final`; False, and `tmp` left, when `final` exists.

    A plain rename would replace an existing entry: this one refuses (Linux's
    ``RENAME_NOREPLACE``, or elsewhere a hard link and then removing `tmp`).
    The folder of `final` is made only when it is missing.
    """
    try:
        return _place(tmp, final)
    except FileNotFoundError:  # the stage's first entry, or a user removed its folder
        os.makedirs(os.path.dirname(final), exist_ok=True)
        return _place(tmp, final)


def _place(tmp: str, final: str) -> bool:
    moved = _rename_noreplace(tmp, final)
    if moved is not None:
        return moved
    try:
        os.link(tmp, final)
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINKS:
            raise
        # a file system without hard links: a rename after a look, which two
        # commits of one key at the same instant could both pass (their
        # results are the same; the digests would tell if they were not)
        if os.path.exists(final):
            return False
        os.rename(tmp, final)
    else:
        os.unlink(tmp)
    return True


@functools.lru_cache(maxsize=1)
def _renameat2() -> Any:
    """Linux's renameat2, or None where the C library has none (macOS, musl before 1.2.5)."""
    try:
        func = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    return func


_AT_FDCWD, _RENAME_NOREPLACE = -100, 1
_NOREPLACE_UNSUPPORTED: set[int] = set()  # st_dev of file systems that refused the flag


def _rename_noreplace(tmp: str, final: str) -> bool | None:
    """Rename `tmp` to `final` unless `final` exists, in one system call: True when
    renamed, False when `final` exists, None where the system cannot (then a hard link
    does the same in two calls)."""
    func = _renameat2()
    if func is None:
        return None
    if _NOREPLACE_UNSUPPORTED and os.stat(tmp).st_dev in _NOREPLACE_UNSUPPORTED:
        return None
    if func(_AT_FDCWD, os.fsencode(tmp), _AT_FDCWD, os.fsencode(final), _RENAME_NOREPLACE) == 0:
        return True
    err = ctypes.get_errno()
    if err == errno.EEXIST:
        return False
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        _NOREPLACE_UNSUPPORTED.add(os.stat(tmp).st_dev)  # NFS, FUSE, old kernels
        return None
    raise OSError(err, os.strerror(err), final)


_NO_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK, errno.EXDEV}


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
    if got == 1:
        raise StoreError(
            f"store {store}: layout version 1 (a folder per entry, as aeroid wrote before "
            f"zipped entries); this aeroid reads version {FORMAT}: run the campaign into a "
            "new store (the keys are the same)"
        )
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
        return self._dir / stage / f"{key}{_SUFFIX}"

    def exists(self, stage: str, key: str) -> bool:
        """True when `key` is committed (commits are atomic, so existence means complete)."""
        return os.path.exists(os.path.join(self._root_id, stage, key + _SUFFIX))

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

    def _open_zip(self, entry: Entry) -> zipfile.ZipFile:
        return zipfile.ZipFile(entry.path)

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
            if base.is_dir():
                yield from self._in_stage(base, "")

    @staticmethod
    def _in_stage(base: Path, key: str) -> Iterator[Entry]:
        """The entries in the stage folder `base` whose keys start with `key`."""
        for path in sorted(base.glob(f"{key}*{_SUFFIX}")):
            name = path.name.removesuffix(_SUFFIX)
            if len(name) == 64 and path.is_file():
                yield Entry(name, base.name, path)

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
        hits: list[Entry] = []
        for stage_dir in sorted(self._dir.iterdir()) if self._dir.is_dir() else []:
            if stage_dir.is_dir() and not stage_dir.name.startswith("."):
                hits += self._in_stage(stage_dir, key)
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
        """Write the entry's zip under a temporary name, then move it into place."""
        tmp = self._temporary(key)
        try:
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileNotFoundError:  # a new store, or `gc` or a user removed the folder
                os.makedirs(os.path.dirname(tmp), exist_ok=True)
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            try:
                view = memoryview(_entry_zip(arrays, group))
                while view:
                    view = view[os.write(fd, view) :]
            finally:
                os.close(fd)
            if _move_into(tmp, os.path.join(self._root_id, stage, key + _SUFFIX)):
                return True
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise
        os.unlink(tmp)  # another run committed the same key first
        return False

    def _temporary(self, key: str) -> str:
        # host and pid in the name let `gc` keep the temporaries of live processes
        name = f"{key}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        return os.path.join(self._root_id, _TMP, name)

    def remove(self, stage: str, key: str) -> bool:
        """Take an entry out of the store; False when there is none.

        For corrupt entries (`verify`): once removed, the next run recomputes
        them. The entry is one file, so it disappears at once and whole.
        """
        try:
            os.unlink(os.path.join(self._root_id, stage, key + _SUFFIX))
        except FileNotFoundError:
            return False
        return True

    # -- reading ---------------------------------------------------------------
    def _entry(self, key: str, stage: str | None) -> Entry:
        if stage is not None:
            if not self.exists(stage, key):
                raise StoreError(f"{stage} result {key[:12]} is not in store {self.root}")
            return Entry(key, stage, self.path_for(stage, key))
        return self.find(key)

    @contextlib.contextmanager
    def _members(self, entry: Entry) -> Iterator[Callable[[str], bytes]]:
        """The entry's zip, opened: yields a function reading a member's bytes."""
        try:
            archive = self._open_zip(entry)
        except FileNotFoundError:
            raise StoreError(
                f"{entry.stage} result {entry.key[:12]} is not in store {self.root}"
            ) from None
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            raise StoreError(
                f"entry {entry.key[:12]} ({entry.stage}) in {self.root} is corrupt: "
                f"unreadable ({exc})"
            ) from None
        with archive:
            yield archive.read

    def metadata(self, key: str, stage: str | None = None) -> dict[str, Any]:
        """The entry's JSON attributes (record tree, task document, provenance, digests)."""
        entry = self._entry(key, stage)
        with self._members(entry) as read:
            return self._metadata(entry, read)

    @staticmethod
    def _metadata(entry: Entry, read: Callable[[str], bytes]) -> dict[str, Any]:
        try:
            doc = json.loads(read("zarr.json").decode("utf-8"))
            meta = doc["attributes"]["aeroid"]
        except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            raise StoreError(
                f"entry {entry.key[:12]} ({entry.stage}) is corrupt: unreadable metadata ({exc})"
            ) from None
        if not isinstance(meta, dict):
            raise StoreError(f"entry {entry.key[:12]} ({entry.stage}) is corrupt: bad metadata")
        return meta

    def _read_verified(self, entry: Entry) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        with self._members(entry) as read:
            return self._verified(entry, read)

    def _verified(
        self, entry: Entry, read: Callable[[str], bytes]
    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
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
        except Exception as exc:  # zip/json/codec errors on damaged bytes
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

    Object stores have no rename, and need none: an entry is one object,
    written in one PUT, and an object store shows an object whole or not at
    all. So there are no temporaries. Two runs that commit the same key at once
    write the same result (results are deterministic); were they to differ,
    the digests say so on every read. A backend that is a file system reached
    through fsspec (``local://``, ``sftp://``) may leave a partial file when a
    run is killed mid-write: the next read reports it corrupt, as `verify`
    does, and ``verify --remove`` takes it out.
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
        return f"{self._url_root}/{stage}/{key}{_SUFFIX}"

    def exists(self, stage: str, key: str) -> bool:
        return bool(self._fs.exists(f"{self._base}/{stage}/{key}{_SUFFIX}"))

    def stored(self, tasks: Iterable[tuple[str, str]]) -> set[tuple[str, str]]:
        # one listing per stage instead of a request per key
        wanted = set(tasks)
        found = set()
        for stage in {stage for stage, _ in wanted}:
            found |= {(e.stage, e.key) for e in self._objects(stage, "")}
        return wanted & found

    def _open_zip(self, entry: Entry) -> zipfile.ZipFile:
        return zipfile.ZipFile(io.BytesIO(self._fs.cat_file(self._path(str(entry.path)))))

    def _objects(self, stage: str, key: str) -> list[Entry]:
        out = []
        for found in sorted(self._fs.glob(f"{self._base}/{stage}/{key}*{_SUFFIX}")):
            st, _, name = str(found)[len(self._base) + 1 :].rpartition("/")
            name = name.removesuffix(_SUFFIX)
            if "/" not in st and not st.startswith(".") and len(name) == 64:
                out.append(Entry(name, st, self._url(str(found))))
        return out

    def entries(self, stage: str | None = None) -> Iterator[Entry]:
        yield from self._objects(stage or "*", "")

    def _starting_with(self, key: str) -> list[Entry]:
        return self._objects("*", key)

    def _publish(
        self, stage: str, key: str, arrays: Mapping[str, np.ndarray], group: bytes
    ) -> bool:
        self._put({f"{self._base}/{stage}/{key}{_SUFFIX}": _entry_zip(arrays, group)})  # the commit
        return True

    def remove(self, stage: str, key: str) -> bool:
        try:
            self._fs.rm_file(f"{self._base}/{stage}/{key}{_SUFFIX}")
        except FileNotFoundError:
            return False
        return True

    def _put(self, files: dict[str, bytes]) -> None:
        """Write objects (concurrently, where the backend can)."""
        try:
            self._fs.pipe(files)
        except FileNotFoundError:
            # a filesystem with real folders (``local://``, ``sftp://``): make them once
            for folder in sorted({f.rsplit("/", 1)[0] for f in files}):
                self._fs.makedirs(folder, exist_ok=True)
            self._fs.pipe(files)

    def temporaries(self) -> list[Path | str]:
        """None: an entry is written in one PUT, so no commit leaves a part behind."""
        return []

    def gc(self, *, max_age: float = 3600.0) -> list[Path | str]:
        """Nothing to remove (see `temporaries`)."""
        return []


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
