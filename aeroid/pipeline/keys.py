"""Content keys: canonical JSON, SHA-256, model fingerprints and array digests.

A task's key is the SHA-256 of a canonical JSON document describing
everything that determines its result (stage, stage version, options,
upstream keys, model fingerprint, seed specification, the user's code it runs).
Canonical means:
keys sorted, no whitespace, tuples as lists, non-finite floats spelled out,
so the same inputs give the same bytes on every machine and Python version.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PipelineError
from ..support import legacy_name

__all__ = [
    "array_digest",
    "canonical_json",
    "file_digest",
    "keyed_text",
    "model_fingerprint",
    "scalar_document",
    "sha256_hex",
    "stable_int",
    "task_key",
    "to_jsonable",
]


def to_jsonable(value: Any, *, where: str = "value") -> Any:
    """Normalise a value to plain JSON types (deterministically; never a silent fallback)."""
    try:
        return _jsonable(value)
    except _NotJsonable as exc:
        raise PipelineError(f"{where}{exc.path}: {exc.message}") from None


class _NotJsonable(Exception):
    # the path inside the value is built as the error unwinds: none is formatted
    # for the thousands of values a plan normalises without one
    def __init__(self, message: str) -> None:
        self.message, self.path = message, ""


def _jsonable(value: Any) -> Any:
    kind = type(value)
    # the plain types first, by exact type: a plan normalises thousands of them
    if kind is str or kind is bool or value is None:
        return value
    if kind is int:
        return value
    if kind is float and math.isfinite(value):
        return value
    if kind is dict or isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise _NotJsonable(f"mapping keys must be strings, got {k!r}")
            try:
                out[k] = _jsonable(v)
            except _NotJsonable as exc:
                exc.path = f".{k}{exc.path}"
                raise
        return out
    if kind is list or kind is tuple or isinstance(value, (list, tuple)):
        items = []
        for i, v in enumerate(value):
            try:
                items.append(_jsonable(v))
            except _NotJsonable as exc:
                exc.path = f"[{i}]{exc.path}"
                raise
        return items
    if isinstance(value, str):
        return value
    if (scalar := scalar_document(value)) is not NOT_SCALAR:
        return scalar
    if isinstance(value, np.ndarray):
        return {"__array_digest__": array_digest(value)}
    raise _NotJsonable(f"cannot hash a value of type {type(value).__name__} deterministically")


# what `scalar_document` gives for a value that is no number
NOT_SCALAR: Any = object()


def scalar_document(value: Any) -> Any:
    """A bool, int or float, Python's or NumPy's, as JSON holds it (a float that is not
    finite as ``{"__float__": "nan" | "inf" | "-inf"}``); `NOT_SCALAR` for anything else."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if math.isfinite(v):
            return v
        return {"__float__": "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")}
    return NOT_SCALAR


def canonical_json(document: Any) -> bytes:
    """Canonical UTF-8 JSON bytes of `document` (sorted keys, compact separators)."""
    return _canonical_plain(to_jsonable(document))


def _canonical_plain(plain: Any) -> bytes:
    # `canonical_json` of a document already made of plain JSON types
    return json.dumps(
        plain, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode("utf-8")


_json_string = json.encoder.encode_basestring  # json.dumps's own, with ensure_ascii=False


def sha256_hex(data: bytes) -> str:
    """Hex SHA-256 of some bytes."""
    return hashlib.sha256(data).hexdigest()


def array_digest(array: Any) -> str:
    """SHA-256 of an array's dtype, shape and C-contiguous bytes."""
    arr = np.ascontiguousarray(np.asarray(array))
    h = hashlib.sha256()
    h.update(arr.dtype.str.encode())
    h.update(repr(tuple(int(s) for s in arr.shape)).encode())
    h.update(arr.tobytes())
    return h.hexdigest()


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes (its name and modification time do not enter)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def stable_int(key: str, bits: int = 63) -> int:
    """A stable non-negative integer from a hex key (used in `SeedSequence` spawn keys)."""
    return int(key[:16], 16) & ((1 << bits) - 1)


def model_fingerprint(model: Any) -> dict[str, Any]:
    """What identifies a model's behaviour: structure, nominal values, source and version.

    Works for `aeroid.Model` and for stepped simulators (`SimulatorModel`),
    whose fingerprint uses the adapter's class and any configuration it exposes.
    """
    fp: dict[str, Any] = {
        "name": str(getattr(model, "name", type(model).__name__)),
        "controls": list(getattr(model, "controls", ())),
        "outputs": list(getattr(model, "output_names", getattr(model, "outputs", ())) or ()),
        "parameters": {k: float(v) for k, v in dict(model.parameters).items()},
        "version": getattr(model, "version", None),
    }
    if hasattr(model, "states") and hasattr(model, "dynamics_source"):
        fp["states"] = list(model.states)
        fp["source"] = model.dynamics_source
        # a declared integration path changes the numbers; undeclared keeps old keys
        linear = getattr(model, "linear", None)
        if linear is not None:
            fp["linear"] = bool(linear)
    else:
        cls = type(model)
        fp["states"] = []
        fp["source"] = f"{legacy_name(cls.__module__)}:{cls.__qualname__}"
        config = getattr(model, "fingerprint_config", None)
        if config is not None:
            fp["config"] = to_jsonable(config() if callable(config) else config)
    return fp


def task_key(**fields: Any) -> tuple[str, dict[str, Any]]:
    """The key of a task and the document it hashes, in plain JSON types.

    Takes the keyword arguments of `keyed_text` and parses its text back.
    """
    key, text = keyed_text(**fields)
    document: dict[str, Any] = json.loads(text)
    return key, document


def keyed_text(
    *,
    record_type: str,
    stage: str,
    stage_version: str,
    options: Mapping[str, Any] | Canonical,
    upstream: Mapping[str, str],
    model: Mapping[str, Any] | None,
    seed: Any,
    memo: dict[int, tuple[Any, bytes]] | None = None,
    code: Mapping[str, Any] | None = None,
) -> tuple[str, bytes]:
    """The key of a task and the canonical text of the document it hashes.

    With `memo` (a dict the caller keeps for a whole plan), the options and the
    model fingerprint are normalised and serialised once per object, not once per
    task: a plan passes the same objects for every flight. The memo holds each
    object, so its id cannot be reused while the memo lives. The text is the
    same either way: the canonical document is assembled from its fields'
    canonical texts in sorted order, as `canonical_json` writes it whole. A plan
    keeps the text, not a parsed document: parsed documents, one per task, made
    the forked workers of a large campaign grow markedly (see
    ``tests/benchmarks/bench_campaign_1000.py``), and only a task that runs
    needs its document.

    `code`: the user's code the task runs besides its model's (a metric's module, a
    stage defined in the config's folder), as ``{what: {module: digest}}``; left out
    of the document when None or empty, so a task running none keeps its key.
    """
    fields: dict[str, Any] = {"code": code} if code else {}
    fields |= {
        "model": model,
        "options": options,
        "record_type": record_type,
        "seed": seed,
        "stage": stage,
        "stage_version": stage_version,
        "upstream": upstream,
    }
    pieces = []
    for name, value in fields.items():  # already in sorted order ("code" first)
        # what every flight of a step shares (a flight's own options come made)
        shared = (
            memo is not None
            and name in ("code", "model", "options")
            and value is not None
            and type(value) is not Canonical
        )
        hit = memo.get(id(value)) if shared and memo is not None else None
        if hit is not None:
            text = hit[1]
        elif value is None:
            text = b"null"
        elif type(value) is str:
            text = _string_text(value)
        else:
            flat = _flat_text(value)
            if flat is None:
                try:
                    plain = _jsonable(value)
                except _NotJsonable as exc:
                    raise PipelineError(f"{stage} task.{name}{exc.path}: {exc.message}") from None
                flat = b"null" if plain is None else _canonical_plain(plain)
            text = flat
            if shared and memo is not None:
                memo[id(value)] = (value, text)
        pieces.append(b'"' + name.encode() + b'":' + text)
    canonical = b"{" + b",".join(pieces) + b"}"
    return sha256_hex(canonical), canonical


@functools.lru_cache(maxsize=256)
def _string_text(value: str) -> bytes:
    # a step's record type, stage name and version: the same strings for every flight
    return _json_string(value).encode("utf-8")


class Canonical(bytes):
    """A value's canonical JSON text, made already: `keyed_text` takes it as it is (a
    plan writes each flight's load options from pieces it serialised once)."""


def _flat_text(value: Any) -> bytes | None:
    """Canonical text of a string, or of a mapping of strings to strings (a task's
    upstream keys), written as `json.dumps` writes them; None for anything else."""
    if type(value) is Canonical:
        return bytes(value)
    if type(value) is str:
        return _json_string(value).encode("utf-8")
    if type(value) is not dict or not all(
        type(k) is str and type(v) is str for k, v in value.items()
    ):
        return None
    items = ",".join(f"{_json_string(k)}:{_json_string(v)}" for k, v in sorted(value.items()))
    return ("{" + items + "}").encode("utf-8")
