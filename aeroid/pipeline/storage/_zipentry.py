"""A store entry's bytes: the zip of a Zarr v3 group it is written as, and the checks
its members pass before they are read."""

from __future__ import annotations

import functools
import io
import json
import math
import struct
import zipfile
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import StoreError
from ..keys import _canonical_plain, array_digest, canonical_json, sha256_hex, to_jsonable
from . import codec

FORMAT = 2  # 1: a folder per entry under <stage>/<key[:2]>/


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
