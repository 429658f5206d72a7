"""Result records <-> arrays + JSON, generically over dataclass fields (never pickle).

A frozen result dataclass is encoded field by field into a JSON tree whose
numeric arrays are replaced by references into a flat ``{name: ndarray}``
table. Supported values: ``None``, ``bool``, ``int``, ``float`` (non-finite
too), ``str``, numpy scalars and arrays, tuples/lists, mappings with string
keys, and nested dataclasses. The record type is written under a stable
name, so that moving a class to another module never makes stores unreadable:
aeroid's public record types by their class name (``"IdentificationResult"``,
the name ``aeroid`` or ``aeroid.pipeline`` exports them under), a type given
to `register_record` by the name it was registered with (``module:qualname``
unless one is given). Names are resolved on decode only from the registry,
aeroid's public names, or dataclasses defined inside the ``aeroid`` package
itself (the ``module:qualname`` names of stores written before stable names),
so decoding never imports arbitrary code.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import re
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...errors import StoreError
from ...support import legacy_name
from ..keys import NOT_SCALAR, scalar_document

__all__ = [
    "UnknownRecordType",
    "decode",
    "encode",
    "exported_records",
    "record_type_name",
    "register_record",
]

_REGISTRY: dict[str, type] = {}
_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


class UnknownRecordType(StoreError):
    """A stored record's type is not available here (not registered, or not in this version)."""


def _qualified(cls: type) -> str:
    # aeroid's own modules by their flat-layout names: stored bytes do not move with them
    return f"{legacy_name(cls.__module__)}:{cls.__qualname__}"


def record_type_name(cls: type) -> str:
    """The stable name a record type is stored under.

    Its registered name; else, for aeroid's public record types, the name
    ``aeroid`` or ``aeroid.pipeline`` exports it under; else ``module:qualname``.
    """
    name = _NAMES.get(cls)
    if name is None:
        public = _public_type(cls.__qualname__)
        name = _NAMES[cls] = cls.__qualname__ if public is cls else _qualified(cls)
    return name


_NAMES: dict[type, str] = {}  # stored name by type, worked out once per type


def register_record(cls: type | None = None, *, name: str | None = None) -> Any:
    """Allow a dataclass defined outside `aeroid` to be stored and read back (a decorator).

    Parameters
    ----------
    cls : type
        The dataclass.
    name : str, optional
        The stable name it is stored under (default ``module:qualname``): give
        one so that moving the class to another module keeps stores readable.
        Its ``module:qualname`` is accepted on reading as well.
    """
    if cls is None:
        return lambda c: register_record(c, name=name)
    if not dataclasses.is_dataclass(cls) or not isinstance(cls, type):
        raise StoreError(f"register_record: {cls!r} is not a dataclass type")
    stable = name or _qualified(cls)
    held = _REGISTRY.get(stable)
    if held is not None and _qualified(held) != _qualified(cls):
        raise StoreError(f"register_record: the name {stable!r} is taken by {_qualified(held)}")
    _REGISTRY[stable] = _REGISTRY[_qualified(cls)] = cls
    _NAMES[cls] = stable
    return cls


_EXPORTERS: list[tuple[str, tuple[str, ...]]] = []  # (package, its __all__) after aeroid's


def exported_records(package: str, names: Sequence[str]) -> None:
    """Store the dataclasses `package` exports (as ``names``) under their bare names.

    The packages above the codec (``aeroid.pipeline``) call this once loaded,
    so that the codec need not import them.
    """
    _EXPORTERS.append((package, tuple(names)))
    _PUBLIC.clear()


def _public_type(name: str) -> type | None:
    """The public dataclass aeroid's packages export under `name` (aeroid's own first),
    or None. Only the package attribute of that name is looked up: aeroid imports its
    exports lazily, and importing them all (scipy's optimisers among them) cost a
    fresh process more than reading the record it was asked for."""
    got = _PUBLIC.get(name, _UNSEEN)
    if got is not _UNSEEN:
        return got  # type: ignore[return-value]
    import aeroid

    found: type | None = None
    exporters = [(aeroid, tuple(aeroid.__all__))]
    exporters += [(sys.modules[package], names) for package, names in _EXPORTERS]
    for package, names in exporters:
        if name not in names:
            continue
        obj = getattr(package, name, None)
        if isinstance(obj, type) and dataclasses.is_dataclass(obj) and name == obj.__qualname__:
            found = obj
            break
    _PUBLIC[name] = found
    return found


_PUBLIC: dict[str, type | None] = {}  # _public_type's answers, by name
_UNSEEN = object()


def _resolve(name: str) -> type:
    if name in _REGISTRY:
        return _REGISTRY[name]
    cls = _RESOLVED.get(name)
    if cls is None:
        cls = _RESOLVED[name] = _resolve_own(name)
    return cls


_RESOLVED: dict[str, type] = {}  # aeroid's own record types, by stored name


def _resolve_own(name: str) -> type:
    module, _, qualname = name.partition(":")
    if not qualname:  # a stable name
        public = _public_type(name)
        if public is None:
            raise UnknownRecordType(
                f"record type {name!r} is not registered and aeroid exports no such type; "
                "only aeroid's own result types and types passed to "
                "aeroid.pipeline.register_record can be read"
            )
        return public
    top = module.split(".")[0]
    if top != "aeroid" or not re.fullmatch(r"[A-Za-z0-9_.]+", module + qualname):
        raise UnknownRecordType(
            f"record type {name!r} is not registered; only aeroid's own result types and "
            "types passed to aeroid.pipeline.register_record can be read"
        )
    try:
        obj: Any = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        # written before stable names, by a version where the class lived elsewhere
        moved = _public_type(qualname)
        if moved is None:
            raise UnknownRecordType(
                f"record type {name!r} does not exist in this aeroid version"
            ) from None
        return moved
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise StoreError(f"record type {name!r} is not a dataclass")
    return obj


def _init_fields(cls: type) -> tuple[str, ...]:
    """The names of a record type's constructor fields, looked up once per type."""
    names = _FIELDS.get(cls)
    if names is None:
        names = _FIELDS[cls] = tuple(f.name for f in dataclasses.fields(cls) if f.init)
    return names


_FIELDS: dict[type, tuple[str, ...]] = {}


class _Encoder:
    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def _array_name(self, path: str) -> str:
        base = _SAFE.sub("_", path).strip("._") or "array"
        if base.startswith("__"):
            base = "a" + base
        name, i = base, 1
        while name in self.arrays:
            i += 1
            name = f"{base}.{i}"
        return name

    def value(self, v: Any, path: str) -> Any:
        # the plain types a record holds most, by exact type first (a float subclass
        # such as np.float64 takes the general path below)
        t = type(v)
        if t is float:
            if math.isfinite(v):
                return v
        elif t is str or t is bool or t is int or v is None:
            return v
        return self._value(v, path)

    def _value(self, v: Any, path: str) -> Any:
        if v is None or isinstance(v, str):
            return v
        if (scalar := scalar_document(v)) is not NOT_SCALAR:
            return scalar
        if isinstance(v, np.ndarray):
            if v.dtype.kind in "US":
                return {"__strings__": v.tolist(), "shape": list(v.shape)}
            if v.dtype.kind not in "biufc":
                raise StoreError(f"{path}: cannot store an array of dtype {v.dtype}")
            name = self._array_name(path)
            self.arrays[name] = np.ascontiguousarray(v)
            return {"__array__": name}
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return self.record(v, path)
        if isinstance(v, Mapping):
            items = []
            for k, item in v.items():
                if not isinstance(k, str):
                    raise StoreError(f"{path}: mapping keys must be strings, got {k!r}")
                items.append([k, self.value(item, f"{path}.{k}")])
            return {"__map__": items}
        if isinstance(v, (tuple, list)):
            return [self.value(item, f"{path}.{i}") for i, item in enumerate(v)]
        raise StoreError(
            f"{path}: a value of type {type(v).__name__} cannot be stored (no pickle); "
            "results may hold numbers, strings, arrays, tuples, mappings and nested records"
        )

    def record(self, obj: Any, path: str) -> dict[str, Any]:
        prefix = f"{path}." if path else ""
        fields = {
            name: self.value(getattr(obj, name), prefix + name) for name in _init_fields(type(obj))
        }
        return {"__record__": record_type_name(type(obj)), "fields": fields}


def encode(obj: Any) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Encode a result record into (JSON tree, arrays by name)."""
    if not (dataclasses.is_dataclass(obj) and not isinstance(obj, type)):
        raise StoreError(f"only dataclass records can be stored, got {type(obj).__name__}")
    enc = _Encoder()
    tree = enc.record(obj, "")
    return tree, enc.arrays


def decode(tree: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    """Rebuild a record from `encode`'s output (its constructor re-freezes arrays)."""
    return _decode(tree, arrays)


def _decode(v: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    # a tree is JSON as parsed (or as `encode` made it): exact lists and dicts
    t = type(v)
    if t is list:
        return tuple([_decode(x, arrays) for x in v])
    if t is not dict:
        return v
    if "__array__" in v:
        arr = np.array(arrays[v["__array__"]], copy=True)
        arr.setflags(write=False)
        return arr
    if "__float__" in v:
        return float(v["__float__"])
    if "__strings__" in v:
        return np.array(v["__strings__"], dtype=str).reshape(v["shape"])
    if "__map__" in v:
        return {k: _decode(x, arrays) for k, x in v["__map__"]}
    if "__record__" in v:
        cls = _resolve(v["__record__"])
        kwargs = {k: _decode(x, arrays) for k, x in v["fields"].items()}
        try:
            return cls(**kwargs)
        except Exception as exc:
            raise StoreError(f"cannot rebuild {v['__record__']} from stored fields: {exc}") from exc
    raise StoreError(f"unrecognised stored value {v!r}")
