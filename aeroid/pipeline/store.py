"""The result store: one immutable Zarr v3 group per task result.

Layout under the store root::

    aeroid-store.json                marker with the layout version
    <stage>/<key>.zarr.zip           one result: a zipped Zarr v3 group (arrays + JSON attributes)
    <stage>/<key>.claim              a run computing `key` now (see `ResultStore.claim`)
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
import ctypes
import errno
import functools
import io
import json
import math
import os
import shutil
import socket
import stat
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
from typing import Any, Literal, Protocol

import numpy as np

from ..errors import StoreError
from . import codec
from .keys import _canonical_plain, array_digest, canonical_json, sha256_hex, to_jsonable

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

FORMAT = 2  # 1: a folder per entry under <stage>/<key[:2]>/
_MARKER = "aeroid-store.json"
_TMP = ".tmp"
_SUFFIX = ".zarr.zip"
_CLAIM = ".claim"


@dataclass(frozen=True)
class StoreLocation:
    """Where a store lives, parsed once from the text a user gave.

    Attributes
    ----------
    kind : {"local", "fsspec"}
        A folder on a (possibly shared) file system, or a URL for fsspec.
    root : str
        The absolute folder (``~`` expanded, ``file://`` removed), or the URL
        without a trailing slash.
    protocol : str
        ``"file"`` for a folder, else the URL's protocol (``"s3"``, ``"memory"``).
    """

    kind: Literal["local", "fsspec"]
    root: str
    protocol: str

    @property
    def is_url(self) -> bool:
        """True for a store reached through fsspec."""
        return self.kind == "fsspec"

    def __str__(self) -> str:
        return self.root


def parse(location: str | os.PathLike[str] | StoreLocation) -> StoreLocation:
    """Parse a store location: a folder (``file://`` allowed) or a URL fsspec understands.

    Parameters
    ----------
    location : str, path or StoreLocation
        ``"results/store"``, ``"~/store"``, ``"file:///data/store"``,
        ``"s3://bucket/campaign"``...

    Returns
    -------
    StoreLocation
        Touches no disk and no network.
    """
    if isinstance(location, StoreLocation):
        return location
    text = os.fspath(location)
    if not text.strip():
        raise StoreError("store location is empty")
    if "://" in text and not text.startswith("file://"):
        protocol = text.split("://", 1)[0]
        return StoreLocation("fsspec", text.rstrip("/"), protocol)
    folder = os.path.abspath(os.path.expanduser(text.removeprefix("file://")))
    return StoreLocation("local", folder, "file")


def is_url(location: str | os.PathLike[str] | StoreLocation) -> bool:
    """True when a store location is a URL for fsspec (``s3://...``), not a folder."""
    return parse(location).kind == "fsspec"


@dataclass(frozen=True)
class Entry:
    """A committed result: its key, stage and location (a zip file, or a URL in an object store)."""

    key: str
    stage: str
    path: Path | str


_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-")


def _check_name(name: str, what: str) -> str:
    """A stage or key as one path component of the store: no separators, no dot files."""
    if not name or name[0] == "." or not _NAME_CHARS.issuperset(name):
        raise StoreError(f"{what} {name!r} is not a valid name in a store")
    return name


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


_Read = Callable[[str, int | None], bytes]


class _WrongSize(StoreError):
    """A member whose size differs from the one its metadata implies (never read)."""

    def __init__(self, name: str, held: int, expected: int) -> None:
        super().__init__(f"member {name!r} holds {held} bytes, expected {expected}")
        self.held = held


def _checked_members(archive: zipfile.ZipFile, size: int) -> dict[str, zipfile.ZipInfo]:
    """The archive's members by name, after refusing any a read could not trust.

    The store writes every member uncompressed: a compressed member (a few
    kilobytes that inflate to gigabytes) or one whose declared size differs
    from what it occupies, or reaches past the end of the file, is refused
    before a byte of it is read, so reading costs no more memory than the file's size.
    """
    members: dict[str, zipfile.ZipInfo] = {}
    for info in archive.infolist():
        if info.compress_type != zipfile.ZIP_STORED:
            raise StoreError(f"member {info.filename!r} is compressed (the store writes none)")
        if info.file_size != info.compress_size or info.header_offset + info.file_size > size:
            raise StoreError(
                f"member {info.filename!r} declares {info.file_size} bytes, more than it holds"
            )
        members[info.filename] = info
    return members


def _member_reader(archive: zipfile.ZipFile, size: int) -> _Read:
    """``read(name, expected)``: a member's bytes (CRC-32 checked by zipfile), refused
    unread when `expected` (a byte count) is given and the member's size differs."""
    members = _checked_members(archive, size)

    def read(name: str, expected: int | None = None) -> bytes:
        info = members.get(name)
        if info is None:
            raise StoreError(f"member {name!r} is missing")
        if expected is not None and info.file_size != expected:
            raise _WrongSize(name, info.file_size, expected)
        return archive.read(info)

    return read


def _read_array(name: str, read: _Read) -> np.ndarray:
    """Read the array `name` of an entry whose members `read` returns."""
    meta = json.loads(read(f"{name}/zarr.json", None).decode("utf-8"))
    dtype = _NUMPY.get(meta.get("data_type"))
    shape = tuple(int(n) for n in meta["shape"])
    if (
        dtype is None
        or any(n < 0 for n in shape)
        or meta.get("codecs") != _BYTES_CODEC
        or meta.get("chunk_key_encoding") != _CHUNK_KEYS
        or meta.get("chunk_grid", {}).get("configuration", {}).get("chunk_shape")
        != [max(1, n) for n in shape]
    ):
        raise StoreError(f"array {name!r} is not in this store's layout")
    if 0 in shape:
        return np.zeros(shape, dtype=dtype)
    target = f"{name}/{_chunk_name(len(shape))}"
    itemsize = np.dtype(dtype).itemsize
    count = math.prod(shape)
    try:
        # the size is known from the metadata: a chunk of another size is never read
        raw = read(target, count * itemsize)
    except _WrongSize as exc:
        what = f"{exc.held // itemsize} values" if exc.held % itemsize == 0 else f"{exc.held} bytes"
        raise StoreError(f"chunk {target} holds {what}, expected {count} values") from None
    arr = np.frombuffer(raw, dtype=dtype)
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


# Below the root every folder is opened without following a link and every file
# is reached through such a folder's descriptor: no path in the store resolves
# outside it, whatever was planted in it.
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | _NOFOLLOW | _CLOEXEC
_LINK_ERRNOS = {errno.ELOOP, errno.EMLINK}  # what O_NOFOLLOW gives on a link (Linux, BSD)


def _link_refused(path: str) -> StoreError:
    return StoreError(
        f"{path} is a symbolic link; a store follows no link below its root (remove the link)"
    )


def _place(tmp_dir: int, tmp: str, dir_fd: int, final: str) -> bool:
    """Move the written file `tmp` to `final` (names within the two open folders);
    False, and `tmp` left, when `final` exists.

    A plain rename would replace an existing entry: this one refuses (Linux's
    ``RENAME_NOREPLACE``, or elsewhere a hard link and then removing `tmp`).
    """
    moved = _rename_noreplace(tmp_dir, tmp, dir_fd, final)
    if moved is not None:
        return moved
    try:
        os.link(tmp, final, src_dir_fd=tmp_dir, dst_dir_fd=dir_fd, follow_symlinks=False)
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINKS:
            raise
        # a file system without hard links: a rename after a look, which two
        # commits of one key at the same instant could both pass (their
        # results are the same; the digests would tell if they were not)
        try:
            os.stat(final, dir_fd=dir_fd, follow_symlinks=False)
            return False
        except FileNotFoundError:
            os.rename(tmp, final, src_dir_fd=tmp_dir, dst_dir_fd=dir_fd)
    else:
        os.unlink(tmp, dir_fd=tmp_dir)
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


_RENAME_NOREPLACE = 1
_NOREPLACE_UNSUPPORTED: set[int] = set()  # st_dev of file systems that refused the flag


def _rename_noreplace(tmp_dir: int, tmp: str, dir_fd: int, final: str) -> bool | None:
    """Rename `tmp` to `final` unless `final` exists, in one system call: True when
    renamed, False when `final` exists, None where the system cannot (then a hard link
    does the same in two calls)."""
    func = _renameat2()
    if func is None:
        return None
    if _NOREPLACE_UNSUPPORTED and os.fstat(tmp_dir).st_dev in _NOREPLACE_UNSUPPORTED:
        return None
    if func(tmp_dir, os.fsencode(tmp), dir_fd, os.fsencode(final), _RENAME_NOREPLACE) == 0:
        return True
    err = ctypes.get_errno()
    if err == errno.EEXIST:
        return False
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        _NOREPLACE_UNSUPPORTED.add(os.fstat(tmp_dir).st_dev)  # NFS, FUSE, old kernels
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


class _Backend(Protocol):
    """What `ResultStore` needs of the place its entries live in."""

    root: Path | str  # as shown to users
    ident: str  # one name per store in this process (caches, markers read)
    look_first: bool  # a commit must look before writing (a PUT overwrites)

    def path_for(self, stage: str, key: str) -> Path | str: ...
    def exists(self, stage: str, key: str) -> bool: ...
    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]: ...
    def open_entry(self, stage: str, key: str) -> contextlib.AbstractContextManager[_Archive]: ...
    def listing(self, stage: str | None, prefix: str) -> list[Entry]: ...
    def publish(self, stage: str, key: str, data: bytes) -> bool: ...
    def remove(self, stage: str, key: str) -> bool: ...
    def temporaries(self) -> list[Path | str]: ...
    def gc(self, max_age: float) -> list[Path | str]: ...
    def create(self, stage: str, name: str, data: bytes) -> bool: ...
    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None: ...
    def overwrite(self, stage: str, name: str, data: bytes) -> None: ...
    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool: ...
    def delete(self, stage: str, name: str) -> None: ...


@dataclass(frozen=True)
class _Archive:
    """An entry's zip opened for reading, and the size of its file."""

    zip: zipfile.ZipFile
    size: int
    where: str


def _os_error(action: str, path: object, exc: OSError) -> StoreError:
    return StoreError(f"cannot {action} {path} ({exc.strerror or exc})")


class _LocalBackend:
    """A store in a folder of a local or shared file system."""

    look_first = False  # the final rename refuses an existing entry: no look first

    def __init__(self, location: StoreLocation, given: str, *, create: bool) -> None:
        self.root: Path | str = Path(given.removeprefix("file://")).expanduser()
        self._folder = location.root
        self.ident = location.root
        marker = os.path.join(self._folder, _MARKER)
        if not (self.ident in _CHECKED and os.path.isfile(marker)):
            self._open_marker(marker, create=create)
            _CHECKED.add(self.ident)
        # every path below is made from the real root: a link above it was the user's choice
        self._real = os.path.realpath(self._folder)

    def _open_marker(self, marker: str, *, create: bool) -> None:
        folder, shown = Path(self._folder), self.root
        if os.path.isfile(marker):
            try:
                raw = Path(marker).read_bytes()
            except OSError as exc:
                raise StoreError(f"store {shown}: unreadable marker {marker} ({exc})") from None
            _check_marker(raw, shown)
        elif create:
            if folder.exists() and not folder.is_dir():
                raise StoreError(f"store {shown}: is a file, not a folder")
            if folder.exists() and any(folder.iterdir()):
                raise StoreError(
                    f"store {shown}: the directory exists, is not empty and is not an aeroid store"
                )
            try:
                folder.mkdir(parents=True, exist_ok=True)
                tmp = folder / f".{_MARKER}.{uuid.uuid4().hex}"
                tmp.write_bytes(_MARKER_DOC)
                os.replace(tmp, marker)
            except OSError as exc:
                raise StoreError(
                    f"store {shown}: cannot create it ({exc.strerror or exc})"
                ) from None
        else:
            raise StoreError(f"store {shown}: not an aeroid store (no {_MARKER})")

    # -- folders, never through a link ----------------------------------------
    def _shown(self, *parts: str) -> Path:
        return Path(self.root, *parts)

    def _dir(self, name: str, *, make: bool = False) -> int:
        """A descriptor of the folder `name` under the root, opened without following
        a link (FileNotFoundError when it is missing and `make` is false)."""
        path = os.path.join(self._real, name)
        try:
            return os.open(path, _DIR_FLAGS)
        except FileNotFoundError:
            if not make:
                raise
        except OSError as exc:
            raise self._dir_error(name, exc) from None
        try:
            os.makedirs(path, exist_ok=True)
            return os.open(path, _DIR_FLAGS)
        except OSError as exc:
            raise self._dir_error(name, exc) from None

    def _dir_error(self, name: str, exc: OSError) -> StoreError:
        if exc.errno in _LINK_ERRNOS or os.path.islink(os.path.join(self._real, name)):
            return _link_refused(str(self._shown(name)))
        if exc.errno == errno.ENOTDIR:
            return StoreError(f"{self._shown(name)} is not a folder")
        return _os_error("open", self._shown(name), exc)

    @contextlib.contextmanager
    def _folder_fd(self, name: str, *, make: bool = False) -> Iterator[int]:
        fd = self._dir(name, make=make)
        try:
            yield fd
        finally:
            os.close(fd)

    # -- entries ----------------------------------------------------------------
    def path_for(self, stage: str, key: str) -> Path:
        return self._shown(stage, key + _SUFFIX)

    def exists(self, stage: str, key: str) -> bool:
        return self._stage_present(stage) and os.path.lexists(
            os.path.join(self._real, stage, key + _SUFFIX)
        )

    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]:
        # a stage with no folder yet (a new store, a new stage) has none: one look for all
        has_stage: dict[str, bool] = {}
        out = set()
        for stage, key in tasks:
            if stage not in has_stage:
                has_stage[stage] = self._stage_present(stage)
            if has_stage[stage] and os.path.lexists(os.path.join(self._real, stage, key + _SUFFIX)):
                out.add((stage, key))
        return out

    def _stage_present(self, stage: str) -> bool:
        """True when the stage has a folder; a link in its place is refused."""
        try:
            st = os.lstat(os.path.join(self._real, stage))
        except FileNotFoundError:
            return False
        if stat.S_ISLNK(st.st_mode):
            raise _link_refused(str(self._shown(stage)))
        return stat.S_ISDIR(st.st_mode)

    @contextlib.contextmanager
    def open_entry(self, stage: str, key: str) -> Iterator[_Archive]:
        name = key + _SUFFIX
        with self._folder_fd(stage) as folder:
            try:
                fd = os.open(name, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
            except OSError as exc:
                if exc.errno in _LINK_ERRNOS:
                    raise _link_refused(str(self._shown(stage, name))) from None
                raise
        with os.fdopen(fd, "rb") as file:
            info = os.fstat(file.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise StoreError(f"{self._shown(stage, name)} is not a file")
            with zipfile.ZipFile(file) as archive:
                yield _Archive(archive, info.st_size, str(self._shown(stage, name)))

    def listing(self, stage: str | None, prefix: str) -> list[Entry]:
        if stage is None:
            stages = self._stages()
        else:
            stages = [stage]
        out: list[Entry] = []
        for s in stages:
            try:
                fd = self._dir(s)
            except FileNotFoundError:
                continue
            except StoreError as exc:
                if stage is not None and str(exc).endswith("is not a folder"):
                    continue
                raise
            try:
                with os.scandir(fd) as it:
                    names = sorted(e.name for e in it if not e.is_dir(follow_symlinks=False))
            finally:
                os.close(fd)
            for name in names:
                key = name.removesuffix(_SUFFIX)
                if name.endswith(_SUFFIX) and len(key) == 64 and key.startswith(prefix):
                    out.append(Entry(key, s, self._shown(s, name)))
        return out

    def _stages(self) -> list[str]:
        """The stage folders; a link to a folder among them is refused, not followed."""
        try:
            it = os.scandir(self._real)
        except FileNotFoundError:
            return []
        stages = []
        with it:
            for e in it:
                if e.name.startswith("."):
                    continue
                if e.is_symlink():
                    if e.is_dir():
                        raise _link_refused(str(self._shown(e.name)))
                elif e.is_dir(follow_symlinks=False):
                    stages.append(e.name)
        return sorted(stages)

    def publish(self, stage: str, key: str, data: bytes) -> bool:
        """Write the entry's zip under a temporary name, then move it into place."""
        # host and pid in the name let `gc` keep the temporaries of live processes
        tmp = f"{key}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(_TMP, make=True) as tmp_dir:
                fd = os.open(
                    tmp,
                    os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC,
                    0o644,
                    dir_fd=tmp_dir,
                )
                try:
                    try:
                        view = memoryview(data)
                        while view:
                            view = view[os.write(fd, view) :]
                    finally:
                        os.close(fd)
                    with self._folder_fd(stage, make=True) as folder:
                        placed = _place(tmp_dir, tmp, folder, key + _SUFFIX)
                except BaseException:
                    with contextlib.suppress(OSError):
                        os.unlink(tmp, dir_fd=tmp_dir)
                    raise
                if not placed:
                    os.unlink(tmp, dir_fd=tmp_dir)  # another run committed the same key first
                return placed
        except OSError as exc:
            raise _os_error("write", self._shown(stage, key + _SUFFIX), exc) from None

    def remove(self, stage: str, key: str) -> bool:
        name = key + _SUFFIX
        try:
            with self._folder_fd(stage) as folder:
                os.unlink(name, dir_fd=folder)  # a link planted as an entry: the link goes
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("remove", self._shown(stage, name), exc) from None
        return True

    # -- temporaries ------------------------------------------------------------
    def _partial(self) -> tuple[int, list[str]] | None:
        try:
            fd = self._dir(_TMP)
        except FileNotFoundError:
            return None
        try:
            return fd, sorted(os.listdir(fd))
        except OSError as exc:
            os.close(fd)
            raise _os_error("list", self._shown(_TMP), exc) from None

    def temporaries(self) -> list[Path | str]:
        found = self._partial()
        if found is None:
            return []
        os.close(found[0])
        return [self._shown(_TMP, name) for name in found[1]]

    def gc(self, max_age: float) -> list[Path | str]:
        found = self._partial()
        if found is None:
            return []
        fd, names = found
        removed: list[Path | str] = []
        host, now = _hostname(), time.time()
        try:
            for name in names:
                parts = name.split(".")
                alive = False
                if len(parts) >= 4:
                    t_host, t_pid = ".".join(parts[1:-2]), parts[-2]
                    if t_host == host and t_pid.isdigit():
                        alive = _pid_alive(int(t_pid)) and int(t_pid) != os.getpid()
                    else:
                        try:
                            age = now - os.stat(name, dir_fd=fd, follow_symlinks=False).st_mtime
                            alive = age < max_age
                        except OSError:
                            alive = False
                if alive:
                    continue
                try:
                    info = os.stat(name, dir_fd=fd, follow_symlinks=False)
                    if stat.S_ISDIR(info.st_mode):
                        shutil.rmtree(name, dir_fd=fd)  # descriptor-based: follows no link
                    else:
                        os.unlink(name, dir_fd=fd)
                except FileNotFoundError:
                    continue
                except OSError as exc:
                    raise _os_error("remove", self._shown(_TMP, name), exc) from None
                removed.append(self._shown(_TMP, name))
        finally:
            os.close(fd)
        return removed

    # -- claims -------------------------------------------------------------------
    def create(self, stage: str, name: str, data: bytes) -> bool:
        try:
            with self._folder_fd(stage, make=True) as folder:
                try:
                    fd = os.open(
                        name,
                        os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC,
                        0o644,
                        dir_fd=folder,
                    )
                except FileExistsError:
                    return False
                try:
                    os.write(fd, data)
                finally:
                    os.close(fd)
        except OSError as exc:
            raise _os_error("write", self._shown(stage, name), exc) from None
        return True

    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None:
        try:
            with self._folder_fd(stage) as folder:
                fd = os.open(name, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno in _LINK_ERRNOS:
                raise _link_refused(str(self._shown(stage, name))) from None
            raise _os_error("read", self._shown(stage, name), exc) from None
        try:
            age = time.time() - os.fstat(fd).st_mtime
            return os.read(fd, 4096), age
        finally:
            os.close(fd)

    def overwrite(self, stage: str, name: str, data: bytes) -> None:
        try:
            with self._folder_fd(stage) as folder:
                fd = os.open(name, os.O_WRONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
                try:
                    os.write(fd, data)
                    os.ftruncate(fd, len(data))
                finally:
                    os.close(fd)
        except OSError as exc:
            raise _os_error("write", self._shown(stage, name), exc) from None

    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool:
        aside = f"{name}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(stage) as folder:
                try:
                    # of runs taking over one stale claim, one renames it away
                    os.rename(name, aside, src_dir_fd=folder, dst_dir_fd=folder)
                except FileNotFoundError:
                    return False
                fd = os.open(aside, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
                try:
                    moved = os.read(fd, 4096)
                finally:
                    os.close(fd)
                if moved != old:  # a fresh claim made since it was read: put it back
                    with contextlib.suppress(OSError):
                        _place(folder, aside, folder, name)
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(aside, dir_fd=folder)
                    return False
                os.unlink(aside, dir_fd=folder)
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("take over", self._shown(stage, name), exc) from None
        return self.create(stage, name, new)

    def delete(self, stage: str, name: str) -> None:
        try:
            with self._folder_fd(stage) as folder:
                os.unlink(name, dir_fd=folder)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise _os_error("remove", self._shown(stage, name), exc) from None


class _ObjectBackend:
    """A store at a URL that fsspec understands (``s3://``, ``gs://``, ``az://``, ``memory://`` ...).

    Object stores have no rename, and need none: an entry is one object,
    written in one PUT, and an object store shows an object whole or not at
    all. So there are no temporaries. Two runs that commit the same key at once
    write the same result (results are deterministic); were they to differ,
    the digests say so on every read. A backend that is a file system reached
    through fsspec (``local://``, ``sftp://``) may leave a partial file when a
    run is killed mid-write: the next read reports it corrupt, as `verify`
    does, and ``verify --remove`` takes it out. Claims are written with the
    backend's put-if-absent where it has one (S3's ``If-None-Match``) and read
    back, so two runs rarely both win one; were they to, each computes the
    same result and the second commit is refused.
    """

    look_first = True  # a PUT overwrites: never write under a committed key

    def __init__(self, location: StoreLocation, *, create: bool) -> None:
        text = location.root
        try:
            import fsspec

            fs, base = fsspec.core.url_to_fs(text)
        except (ImportError, ValueError) as exc:  # unknown protocol, backend not installed
            raise StoreError(f"store {text!r}: {exc}") from None
        self.root: Path | str = text
        self.ident = text
        self._fs = fs
        self._base = str(base).rstrip("/")
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
            try:
                if fs.exists(self._base) and fs.ls(self._base, detail=False):
                    raise StoreError(
                        f"store {text}: the location exists, is not empty and is not an aeroid "
                        "store"
                    )
                self._put({marker: _MARKER_DOC})
            except StoreError:
                raise
            except Exception as exc:
                raise StoreError(f"store {text}: cannot create it ({exc})") from None
        else:
            raise StoreError(f"store {text}: not an aeroid store (no {_MARKER})")
        _CHECKED.add(text)

    def _object(self, stage: str, name: str) -> str:
        return f"{self._base}/{stage}/{name}"

    def _url(self, path: str) -> str:
        return str(self.root) + path[len(self._base) :]

    def path_for(self, stage: str, key: str) -> str:
        return f"{self.root}/{stage}/{key}{_SUFFIX}"

    def exists(self, stage: str, key: str) -> bool:
        return bool(self._fs.exists(self._object(stage, key + _SUFFIX)))

    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]:
        # one listing per stage instead of a request per key
        found = set()
        for stage in {stage for stage, _ in tasks}:
            found |= {(e.stage, e.key) for e in self.listing(stage, "")}
        return tasks & found

    @contextlib.contextmanager
    def open_entry(self, stage: str, key: str) -> Iterator[_Archive]:
        raw = self._fs.cat_file(self._object(stage, key + _SUFFIX))
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            yield _Archive(archive, len(raw), self.path_for(stage, key))

    def listing(self, stage: str | None, prefix: str) -> list[Entry]:
        out = []
        pattern = f"{self._base}/{stage or '*'}/{prefix}*{_SUFFIX}"
        for found in sorted(self._fs.glob(pattern)):
            st, _, name = str(found)[len(self._base) + 1 :].rpartition("/")
            name = name.removesuffix(_SUFFIX)
            if "/" not in st and not st.startswith(".") and len(name) == 64:
                out.append(Entry(name, st, self._url(str(found))))
        return out

    def publish(self, stage: str, key: str, data: bytes) -> bool:
        self._put({self._object(stage, key + _SUFFIX): data})  # the commit
        return True

    def remove(self, stage: str, key: str) -> bool:
        try:
            self._fs.rm_file(self._object(stage, key + _SUFFIX))
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("remove", self.path_for(stage, key), exc) from None
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
        return []  # an entry is written in one PUT: no commit leaves a part behind

    def gc(self, max_age: float) -> list[Path | str]:
        return []

    def create(self, stage: str, name: str, data: bytes) -> bool:
        path = self._object(stage, name)
        try:
            self._fs.pipe_file(path, data, mode="create")
        except FileExistsError:
            return False
        except FileNotFoundError:
            self._fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
            return self.create(stage, name, data)
        except OSError as exc:
            raise _os_error("write", f"{self.root}/{stage}/{name}", exc) from None
        # where put-if-absent is only a look and a PUT, the last writer won: read back
        return self._fs.cat_file(path) == data

    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None:
        try:
            raw = self._fs.cat_file(self._object(stage, name))
        except FileNotFoundError:
            return None
        return raw, 0.0  # object ages are not compared across clocks: the lease decides

    def overwrite(self, stage: str, name: str, data: bytes) -> None:
        self._fs.pipe_file(self._object(stage, name), data)

    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool:
        path = self._object(stage, name)
        try:
            if self._fs.cat_file(path) != old:
                return False
        except FileNotFoundError:
            return self.create(stage, name, new)
        self._fs.pipe_file(path, new)
        return self._fs.cat_file(path) == new

    def delete(self, stage: str, name: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._fs.rm_file(self._object(stage, name))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_GARBLED_LEASE = 60.0  # a claim file being written, or cut short: held this long after its write


def _claim_doc(token: str, lease: float) -> bytes:
    doc = {
        "pid": os.getpid(),
        "host": _hostname(),
        "expires": time.time() + lease,
        "lease": lease,
        "token": token,
    }
    return json.dumps(doc, separators=(",", ":")).encode("utf-8")


def _claim_stale(raw: bytes, age: float) -> bool:
    """True when the claim in `raw` no longer holds: its lease ran out, or its process
    (on this host) is gone."""
    try:
        doc = json.loads(raw)
        expires, host, pid = float(doc["expires"]), str(doc["host"]), int(doc["pid"])
    except (ValueError, KeyError, TypeError):
        return age > _GARBLED_LEASE
    if time.time() > expires:
        return True
    return host == _hostname() and pid != os.getpid() and not _pid_alive(pid)


class Claim:
    """A run's claim on computing one task: others wait for its entry instead.

    Made by `ResultStore.claim`. Hold it while computing and committing, then
    `release` it (or use it as a context manager, which also renews the lease
    in the background while the block runs). A claim whose lease runs out, or
    whose process died on this host, is taken over by the next run that asks.
    Claims only spare duplicate work: a commit never overwrites an entry, so
    two runs that both compute a key still store one result.
    """

    def __init__(self, store: ResultStore, stage: str, key: str, token: str, lease: float) -> None:
        self.store, self.stage, self.key = store, stage, key
        self.lease = lease
        self._token = token
        self._stop: threading.Event | None = None
        self._thread: threading.Thread | None = None

    def __repr__(self) -> str:
        return f"Claim({self.stage!r}, {self.key[:12]!r})"

    def _mine(self) -> bool:
        found = self.store._backend.read_small(self.stage, self.key + _CLAIM)
        if found is None:
            return False
        try:
            return bool(json.loads(found[0]).get("token") == self._token)
        except (ValueError, AttributeError):
            return False

    def renew(self) -> bool:
        """Extend the lease by `lease` seconds from now; False when the claim was lost
        (taken over after its lease ran out, or removed)."""
        if not self._mine():
            return False
        self.store._backend.overwrite(
            self.stage, self.key + _CLAIM, _claim_doc(self._token, self.lease)
        )
        return True

    def release(self) -> None:
        """Give the claim up (after committing, or when the task failed)."""
        if self._stop is not None:
            self._stop.set()
            if self._thread is not None and self._thread is not threading.current_thread():
                self._thread.join()
            self._stop = self._thread = None
        if self._mine():
            self.store._backend.delete(self.stage, self.key + _CLAIM)

    def _renewing(self, stop: threading.Event) -> None:
        while not stop.wait(self.lease / 3):
            try:
                if not self.renew():
                    return
            except Exception:  # a renewal that fails leaves the lease to run out
                return

    def __enter__(self) -> Claim:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._renewing, args=(self._stop,), daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


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
    """

    root: Path | str
    """The store's folder, or its URL in an object store."""
    location: StoreLocation
    """Where the store lives, parsed."""

    def __init__(
        self, root: str | os.PathLike[str] | StoreLocation, *, create: bool = True
    ) -> None:
        self.location = parse(root)
        backend: _Backend
        if self.location.kind == "fsspec":
            backend = _ObjectBackend(self.location, create=create)
        else:
            given = root.root if isinstance(root, StoreLocation) else os.fspath(root)
            backend = _LocalBackend(self.location, given, create=create)
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
        wanted = {(_check_name(s, "stage"), _check_name(k, "key")) for s, k in tasks}
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
        try:
            with self._backend.open_entry(
                _check_name(stage, "stage"), _check_name(key, "key")
            ) as a:
                for info in _checked_members(a.zip, a.size).values():
                    with a.zip.open(info) as member:
                        while member.read(1 << 20):
                            pass  # zipfile compares the CRC-32 at the end of the member
        except (StoreError, OSError, ValueError, EOFError, MemoryError, zipfile.BadZipFile):
            return False
        return True

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
        except MemoryError as exc:
            return f"entry {key[:12]} ({entry.stage}) in {self.root} is corrupt: {exc!r}"
        return None

    def verify_all(self) -> dict[str, str]:
        """Problems by key for every entry that fails its checks.

        A link planted as a stage folder raises `StoreError` naming it: the
        store neither reads nor removes anything through it.
        """
        bad = {}
        for entry in self.entries():
            problem = self.verify(entry.key, entry.stage)
            if problem is not None:
                bad[entry.key] = f"{entry.stage}: {problem}"
        return bad

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
        import fsspec

        fs, base = fsspec.core.url_to_fs(location.root)
        return bool(fs.exists(f"{str(base).rstrip('/')}/{_MARKER}"))
    except (ImportError, ValueError) as exc:
        raise StoreError(f"store {location.root!r}: {exc}") from None


def open_store(
    root: str | os.PathLike[str] | StoreLocation, *, create: bool = False
) -> ResultStore:
    """Open a result store (by default an existing one)."""
    return ResultStore(root, create=create)
