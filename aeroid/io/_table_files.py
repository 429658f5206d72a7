"""Parquet and MATLAB v5 flight files read as named columns: only the columns asked
for, with their declared sizes bounded before any byte is decoded."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError
from ._flight_csv import _seconds, arrow_file

FloatArray = NDArray[np.float64]

# A table or MATLAB file may not expand to more than this in memory (a small compressed
# file can declare gigabytes); checked from the declared sizes before reading.
_MAX_DECLARED_BYTES = 1 << 30
_MAT_ITEM_BYTES = {
    "double": 8, "single": 4, "int64": 8, "uint64": 8, "int32": 4, "uint32": 4,
    "int16": 2, "uint16": 2, "int8": 1, "uint8": 1, "logical": 1, "char": 2,
}  # fmt: skip


def _read_parquet(
    path: Path, wanted: Collection[str] | None = None
) -> tuple[list[str], dict[str, FloatArray]]:
    try:
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        raise DataFormatError(
            f"{path}: reading Parquet needs pyarrow (pip install pyarrow)"
        ) from None
    import pyarrow as pa

    with arrow_file(path) as source:
        return _read_parquet_file(path, source, wanted, pq, pa)


def _read_parquet_file(
    path: Path, source: Any, wanted: Collection[str] | None, pq: Any, pa: Any
) -> tuple[list[str], dict[str, FloatArray]]:
    try:
        file = pq.ParquetFile(source)
        meta = file.metadata
        header = [meta.schema.column(j).path for j in range(meta.num_columns)]
        types = {f.name: f.type for f in file.schema_arrow}
        # only the columns asked for are read (an unused huge one beside them is not)
        picked = [j for j, h in enumerate(header) if wanted is None or h in wanted]
        declared = sum(
            max(
                meta.row_group(i).column(j).total_uncompressed_size,
                8 * meta.row_group(i).num_rows,
            )
            for i in range(meta.num_row_groups)
            for j in picked
        )
    except Exception as exc:  # pyarrow raises many types for corrupt files
        raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None
    dupes = sorted(h for h, n in Counter(header).items() if n > 1)
    if dupes:
        raise DataFormatError(f"{path}: duplicate column names {dupes[:10]}")
    # text, binary and nested columns are no channels, and their stored size (dictionary-
    # encoded, compressed) does not bound what they decode to: refused before reading
    for name in (header[j] for j in picked):
        kind = types.get(name)
        if kind is not None and not (
            pa.types.is_integer(kind)
            or pa.types.is_floating(kind)
            or pa.types.is_boolean(kind)
            or pa.types.is_temporal(kind)
            or pa.types.is_decimal(kind)
        ):
            raise DataFormatError(f"{path}: column {name!r} is not numeric ({kind})")
    # what the table would take in memory, checked before a byte of it is decompressed
    if declared > _MAX_DECLARED_BYTES:
        raise DataFormatError(
            f"{path}: declares {declared / 2**30:.1f} GiB of data ({meta.num_rows} rows x "
            f"{len(picked)} columns read), over the {_MAX_DECLARED_BYTES >> 20} MiB a flight "
            "file may expand to; split the record"
        )
    try:
        table = file.read(columns=[header[j] for j in picked] if wanted else None)
    except Exception as exc:  # pyarrow raises many types for corrupt files
        raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None
    columns: dict[str, FloatArray] = {}
    for name in table.column_names:
        col = table.column(name)
        if col.null_count:
            first = int(np.flatnonzero(np.asarray(col.is_null()))[0])
            raise DataFormatError(f"{path}: row {first}, column {name!r}: null value")
        try:
            if pa.types.is_time(col.type):
                # time of day: its integer count in the type's unit, as a duration
                ticks = col.cast(pa.int64() if pa.types.is_time64(col.type) else pa.int32())
                raw = np.asarray(ticks.to_numpy()).astype(f"timedelta64[{col.type.unit}]")
            else:
                raw = np.asarray(col.to_numpy())
            if raw.dtype.kind in "mM":  # timestamps, dates and durations in seconds
                columns[name] = _seconds(raw)
            else:
                columns[name] = np.asarray(raw, dtype=np.float64)
        except (TypeError, ValueError, pa.ArrowException):
            raise DataFormatError(f"{path}: column {name!r} is not numeric ({col.type})") from None
    return header if wanted is not None else list(table.column_names), columns


def _size_text(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.1f} MiB"


def _mat_columns(name: str, shape: Sequence[int]) -> list[str]:
    """The channel names a MATLAB variable of `shape` becomes (see `_read_mat`)."""
    if len(shape) == 2 and min(shape) > 1:
        return [f"{name}_{j}" for j in range(min(shape))]
    return [name]


def _read_mat(
    path: Path, wanted: Collection[str] | None = None
) -> tuple[list[str], dict[str, NDArray[Any]]]:
    import scipy.io

    from ._mat_scan import check_mat_expansion

    try:
        listing = scipy.io.whosmat(path)
    except Exception as exc:  # scipy raises ValueError/TypeError/NotImplementedError
        raise DataFormatError(
            f"{path}: not a readable MATLAB file ({exc}); MATLAB v7.3 (HDF5) files are "
            "read as logs (see aeroid.read_log)"
        ) from None
    # only the variables asked for are read (an unused huge one beside them is not)
    read = [
        name
        for name, shape, _ in listing
        if wanted is None or any(c in wanted for c in _mat_columns(name, shape))
    ]
    # the variables' declared sizes, checked before any of them is decompressed ...
    total = 0
    for name, shape, kind in listing:
        if name not in read:
            continue
        size = int(np.prod(shape, dtype=np.float64)) * _MAT_ITEM_BYTES.get(kind, 8)
        total += size
        if total > _MAX_DECLARED_BYTES:
            raise DataFormatError(
                f"{path}: variable {name!r} declares {_size_text(size)} ({kind} "
                f"{'x'.join(map(str, shape))}), taking the variables read over the "
                f"{_MAX_DECLARED_BYTES >> 20} MiB a flight file may expand to"
            )
    # ... and what they inflate to, which a lying size tag inside one can hide
    # (a few kB a variable for its name, shape and flags)
    check_mat_expansion(path, listing, set(read), _MAX_DECLARED_BYTES + (4 << 10) * len(read))
    every = [c for name, shape, _ in listing for c in _mat_columns(name, shape)]
    if wanted is not None and not read:
        return every, {}  # the caller names the channel it did not find
    try:
        raw = scipy.io.loadmat(path, squeeze_me=True, variable_names=read)
    except Exception as exc:  # scipy raises ValueError/TypeError/NotImplementedError
        raise DataFormatError(
            f"{path}: not a readable MATLAB file ({exc}); MATLAB v7.3 (HDF5) files are "
            "read as logs (see aeroid.read_log)"
        ) from None
    columns: dict[str, NDArray[Any]] = {}
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        arr = np.asarray(value)
        if arr.dtype.kind not in "fiubc":
            continue  # structs, strings and cell arrays are not channels
        # Complex vectors stay complex so that load_flight_test can refuse them by
        # name if they are asked for (casting would drop the imaginary part).
        dtype = np.complex128 if arr.dtype.kind == "c" else np.float64
        if arr.ndim == 1 and arr.size >= 2:
            columns[name] = arr.astype(dtype)
        elif arr.ndim == 2 and min(arr.shape) > 1:
            # A matrix of channels: one column each, named name_0, name_1, ...
            mat = arr if arr.shape[0] >= arr.shape[1] else arr.T
            for j in range(mat.shape[1]):
                columns[f"{name}_{j}"] = mat[:, j].astype(dtype)
    if not columns:
        raise DataFormatError(f"{path}: no numeric vectors found")
    if wanted is not None:  # every variable's names, so a missing one is reported as such
        return every, columns
    return list(columns), columns
