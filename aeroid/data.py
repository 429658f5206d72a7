"""Flight-test time series: the immutable `FlightData` record and its file loader."""

from __future__ import annotations

import csv
import hashlib
import math
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ChannelError, DataFormatError

__all__ = ["FlightData", "load_flight_test"]

FloatArray = NDArray[np.float64]


def _readonly(values: ArrayLike) -> FloatArray:
    """Return a read-only float64 copy (the caller's array is never aliased)."""
    out = np.array(values, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def _first_bad(values: FloatArray) -> int:
    return int(np.flatnonzero(~np.isfinite(values))[0])


def plain(value: Any) -> str:
    """`value` for an error message: numpy scalars as plain numbers (0.45, not np.float64(0.45))."""
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def whole_number(value: Any, name: str, error: type[Exception], *, least: int = 1) -> int:
    """`value` as an int >= `least` (1 or 0; integral floats such as 2e3 accepted), else
    `error`."""
    try:
        n = int(value)
        ok = not isinstance(value, bool) and n == value and n >= least
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        what = "a positive" if least == 1 else "a non-negative"
        raise error(f"{name} must be {what} integer, got {plain(value)}")
    return n


def check_symmetric(
    arr: FloatArray, names: Sequence[str], what: str, error: type[Exception]
) -> None:
    """Refuse a square matrix whose asymmetry is beyond rounding (relative to its largest
    entry), naming the entry; NaN and infinity are left to the caller's finiteness check."""
    with np.errstate(invalid="ignore"):
        asym = np.abs(arr - arr.T)
    if not np.all(np.isfinite(asym)):
        return
    scale = float(np.max(np.abs(arr))) if arr.size else 0.0
    if float(np.max(asym, initial=0.0)) > 1e-10 * scale:
        i, j = np.unravel_index(int(np.argmax(asym)), asym.shape)
        raise error(
            f"{what}: the matrix must be symmetric, but [{i}, {j}] = {plain(arr[i, j])} and "
            f"[{j}, {i}] = {plain(arr[j, i])} (order {list(names)})"
        )


def _seconds(values: NDArray[Any]) -> FloatArray:
    """Datetimes as float seconds since the first sample, durations as float seconds.

    Epoch nanoseconds (about 1.7e18) lose sub-microsecond resolution in
    float64, so datetimes count from the first sample; a duration already
    counts from a reference the user chose and is kept. NaT becomes NaN, which
    the finite checks then report by index.
    """
    if values.dtype.kind == "M" and values.size:
        values = values - values[0]
    return np.asarray(values / np.timedelta64(1, "s"), dtype=np.float64)


def _numeric(values: Any, what: str, failure: str) -> FloatArray:
    """`values` as a read-only float64 copy, or a `DataFormatError` naming `what`.

    Complex samples are refused: casting them would silently drop the
    imaginary part. Datetimes and durations become seconds (see `_seconds`).
    """
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"{what}: {failure} ({exc})") from None
    if arr.dtype.kind == "c":
        raise DataFormatError(
            f"{what}: complex values are not supported; pass the real part or the "
            "magnitude explicitly (np.real, np.abs)"
        )
    if arr.dtype.kind in "mM":
        arr = _seconds(arr)
    try:
        return _readonly(arr)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"{what}: {failure} ({exc})") from None


@dataclass(frozen=True, eq=False)
class FlightData:
    """An immutable, name-indexed set of time series sampled on one time axis.

    Parameters
    ----------
    time : array_like
        Sample times in seconds, finite and strictly increasing. Datetimes
        (``datetime64``) become seconds since the first sample, durations
        (``timedelta64``) seconds.
    channels : mapping of str to array_like
        Channel name to real samples, each the same length as `time`.
    units : mapping of str to str, optional
        Unit label per channel (informational; AeroID is unit-agnostic).
    metadata : mapping of str to Any, optional
        Free-form JSON-compatible information (flight condition, source file).

    Raises
    ------
    DataFormatError
        If time is not strictly increasing and finite, a channel has a different
        length, holds NaN, infinite or complex values, or `units` or `metadata`
        is not a mapping.
    """

    time: FloatArray
    channels: Mapping[str, FloatArray]
    units: Mapping[str, str] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        time = _numeric(self.time, "time", "cannot convert to float array")
        if time.ndim != 1 or time.size < 2:
            raise DataFormatError(
                f"time: expected a 1-D array of at least 2 samples, got shape {time.shape}"
            )
        if not np.all(np.isfinite(time)):
            raise DataFormatError(f"time: non-finite value at index {_first_bad(time)}")
        steps = np.diff(time)
        if np.any(steps <= 0):
            bad = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise DataFormatError(
                f"time: not strictly increasing at index {bad} "
                f"(t[{bad - 1}]={plain(time[bad - 1])}, t[{bad}]={plain(time[bad])})"
            )
        if not isinstance(self.channels, Mapping):
            raise DataFormatError("channels: expected a mapping of channel name to samples")
        chans: dict[str, FloatArray] = {}
        for name, values in self.channels.items():
            if not isinstance(name, str) or not name:
                raise DataFormatError(f"channel name {name!r}: expected a non-empty string")
            arr = _numeric(values, f"channel {name!r}", "not numeric")
            if arr.shape != time.shape:
                raise DataFormatError(
                    f"channel {name!r}: length {arr.shape} does not match time {time.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise DataFormatError(
                    f"channel {name!r}: non-finite value at index {_first_bad(arr)}"
                )
            chans[name] = arr
        # None reads as "none given", as for the other optional arguments.
        for label, value in (("units", self.units), ("metadata", self.metadata)):
            if value is not None and not isinstance(value, Mapping):
                raise DataFormatError(
                    f"{label}: expected a mapping (dict), got {type(value).__name__}"
                )
        units = {str(k): str(v) for k, v in dict(self.units or {}).items()}
        unknown = sorted(set(units) - set(chans))
        if unknown:
            raise DataFormatError(f"units given for unknown channels {unknown}")
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "channels", MappingProxyType(chans))
        object.__setattr__(self, "units", MappingProxyType(units))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata or {})))

    # -- access -----------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        """Channel names in insertion order."""
        return tuple(self.channels)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def duration(self) -> float:
        """Record length in seconds."""
        return float(self.time[-1] - self.time[0])

    @property
    def is_uniform(self) -> bool:
        """True when the time grid is uniform to a relative 1e-6."""
        steps = np.diff(self.time)
        return bool(np.ptp(steps) <= 1e-6 * float(np.mean(steps)))

    @property
    def sample_rate(self) -> float:
        """Mean sample rate in Hz."""
        return (self.n_samples - 1) / self.duration

    def __contains__(self, name: object) -> bool:
        return name in self.channels

    def __iter__(self) -> Iterator[str]:
        return iter(self.channels)

    def __len__(self) -> int:
        return self.n_samples

    def __getitem__(self, name: str) -> FloatArray:
        self.require([name])
        return self.channels[name]

    def require(self, names: Iterable[str], *, role: str = "channel") -> None:
        """Raise `ChannelError` naming the first of `names` that is missing."""
        for name in names:
            if name not in self.channels:
                raise ChannelError(
                    f"{role} {name!r} not found in flight data; "
                    f"channels present: {sorted(self.channels)}"
                )

    def array(self, names: str | Sequence[str]) -> FloatArray:
        """Stack channels into an array of shape (n_samples, len(names))."""
        if isinstance(names, str):
            names = [names]
        self.require(names)
        if not names:
            return np.zeros((self.n_samples, 0))
        out = np.column_stack([self.channels[n] for n in names])
        out.setflags(write=False)
        return out

    def window(self, t0: float, t1: float) -> FlightData:
        """Return the samples with ``t0 <= time <= t1`` as new flight data."""
        if not t1 > t0:
            raise DataFormatError(f"window: need t1 > t0, got t0={plain(t0)}, t1={plain(t1)}")
        mask = (self.time >= t0) & (self.time <= t1)
        if int(mask.sum()) < 2:
            raise DataFormatError(
                f"window [{t0}, {t1}] holds fewer than 2 samples of [{self.time[0]}, {self.time[-1]}]"
            )
        return FlightData(
            self.time[mask],
            {k: v[mask] for k, v in self.channels.items()},
            self.units,
            self.metadata,
        )

    def with_channels(
        self, channels: Mapping[str, ArrayLike], units: Mapping[str, str] | None = None
    ) -> FlightData:
        """Return a copy with channels added or replaced."""
        merged: dict[str, Any] = dict(self.channels)
        merged.update(channels)
        new_units = dict(self.units)
        new_units.update(units or {})
        return FlightData(self.time, merged, new_units, self.metadata)

    def summary(self) -> str:
        """A Markdown table of the channels with their ranges."""
        lines = [
            f"{self.n_samples} samples over {self.duration:.6g} s ({self.sample_rate:.6g} Hz)",
            "",
            "| channel | unit | min | max | mean |",
            "|---------|------|-----|-----|------|",
        ]
        for name, v in self.channels.items():
            lines.append(
                f"| {name} | {self.units.get(name, '')} | {v.min():.4g} | {v.max():.4g} | {v.mean():.4g} |"
            )
        return "\n".join(lines)


def measured_start(data: FlightData, states: Iterable[str]) -> dict[str, float]:
    """The first sample of each of `states` that the record measures (the default initial state)."""
    return {s: float(data.channels[s][0]) for s in states if s in data}


def fingerprint(data: FlightData) -> str:
    """SHA-256 of a record's time grid and channels (names and values).

    An identification result keeps the fingerprints of the records it was
    fitted to, so a later function given the result and one of those records
    can start where the fit did (see `aeroid.model.fitted_start`).
    """
    h = hashlib.sha256(np.ascontiguousarray(data.time, dtype="<f8").tobytes())
    for name in sorted(data.channels):
        h.update(name.encode("utf-8") + b"\0")
        h.update(np.ascontiguousarray(data.channels[name], dtype="<f8").tobytes())
    return h.hexdigest()


# -- loading ----------------------------------------------------------------------


def _pick_time_column(columns: Sequence[str], time_column: str | None, path: Path) -> str:
    if time_column is not None:
        if time_column not in columns:
            raise ChannelError(
                f"{path}: time column {time_column!r} not found; columns: {list(columns)}"
            )
        return time_column
    for candidate in ("time", "t", "Time", "TIME", "time_s", "Time (s)", "t_s"):
        if candidate in columns:
            return candidate
    raise ChannelError(
        f"{path}: no time column found (tried 'time', 't', 'Time', ...); "
        f"pass time_column=...; columns: {list(columns)}"
    )


def _read_csv(path: Path) -> tuple[list[str], dict[str, FloatArray]]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{path}: not a UTF-8 text file ({exc})") from None
    rows = list(csv.reader(text.splitlines()))
    # Skip comment lines commonly found at the top of flight-test exports.
    rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise DataFormatError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    if any(not h for h in header):
        raise DataFormatError(f"{path}: empty column name at column {header.index('') + 1}")
    dupes = sorted({h for h in header if header.count(h) > 1})
    if dupes:
        raise DataFormatError(f"{path}: duplicate column names {dupes}")
    body = rows[1:]
    if len(body) < 2:
        raise DataFormatError(f"{path}: fewer than 2 data rows")
    values = np.empty((len(body), len(header)))
    for i, row in enumerate(body):
        line = i + 2  # 1-based, header is line 1 (comments excluded)
        if len(row) != len(header):
            raise DataFormatError(
                f"{path}: row {line} has {len(row)} cells, header has {len(header)}"
            )
        for j, cell in enumerate(row):
            cell = cell.strip()
            try:
                value = float(cell)
            except ValueError:
                what = "blank" if not cell else f"non-numeric ({cell!r})"
                raise DataFormatError(
                    f"{path}: row {line}, column {header[j]!r}: {what} cell"
                ) from None
            if not math.isfinite(value):
                raise DataFormatError(
                    f"{path}: row {line}, column {header[j]!r}: non-finite value {cell!r}"
                )
            values[i, j] = value
    return header, {h: values[:, j] for j, h in enumerate(header)}


def _read_parquet(path: Path) -> tuple[list[str], dict[str, FloatArray]]:
    try:
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover - pyarrow is a dependency
        raise DataFormatError(
            f"{path}: reading Parquet needs pyarrow (pip install pyarrow)"
        ) from None
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises many types for corrupt files
        raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None
    import pyarrow as pa

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
    return list(table.column_names), columns


def _read_mat(path: Path) -> tuple[list[str], dict[str, NDArray[Any]]]:
    import scipy.io

    try:
        raw = scipy.io.loadmat(path, squeeze_me=True)
    except Exception as exc:  # scipy raises ValueError/TypeError/NotImplementedError
        raise DataFormatError(
            f"{path}: not a readable MATLAB file ({exc}); v7.3 (HDF5) files are not supported"
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
    return list(columns), columns


def load_flight_test(
    path: str | Path,
    *,
    time_column: str | None = None,
    channels: Sequence[str] | Mapping[str, str] | None = None,
    units: Mapping[str, str] | None = None,
) -> FlightData:
    """Load a flight-test record from CSV, Parquet or MATLAB ``.mat``.

    Column headers are kept verbatim as channel names, so they match the
    model's state, control and output names.

    Parameters
    ----------
    path : str or Path
        File to read; the format follows the suffix (``.csv``/``.txt``,
        ``.parquet``/``.pq``, ``.mat``).
    time_column : str, optional
        Column holding time in seconds. Default: the first of ``time``, ``t``,
        ``Time`` ... that is present.
    channels : sequence of str or mapping of str to str, optional
        Columns to keep. A mapping renames ``{column: channel_name}``; two
        columns renamed to the same channel name are an error.
        Default: every column but time.
    units : mapping of str to str, optional
        Unit label per (renamed) channel.

    Returns
    -------
    FlightData

    Raises
    ------
    DataFormatError
        A path that is not an existing file, an unreadable or malformed file
        (naming the file and the row or column), a complex-valued column, or
        two columns renamed to one channel name.
    ChannelError
        A requested column (or the time column) is missing.

    Notes
    -----
    A Parquet timestamp or date column becomes seconds since its first
    sample; a duration or time-of-day column becomes seconds.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise DataFormatError(
            f"path: expected a file path (str or Path), got {type(path).__name__}"
        )
    p = Path(path)
    if os.fspath(path) == "":
        raise DataFormatError("path: empty file name")
    if p.is_dir():
        raise DataFormatError(f"{p}: is a directory, not a data file")
    if not p.exists():
        raise DataFormatError(f"{p}: no such file")
    if not p.is_file():
        raise DataFormatError(f"{p}: not a regular file")
    suffix = p.suffix.lower()
    columns: Mapping[str, NDArray[Any]]
    if suffix in (".csv", ".txt", ".dat"):
        header, columns = _read_csv(p)
    elif suffix in (".parquet", ".pq"):
        header, columns = _read_parquet(p)
    elif suffix == ".mat":
        header, columns = _read_mat(p)
    else:
        raise DataFormatError(
            f"{p}: unknown file type {suffix!r} (expected .csv, .parquet or .mat)"
        )
    tname = _pick_time_column(header, time_column, p)
    if channels is None:
        mapping = {h: h for h in header if h != tname}
    elif isinstance(channels, Mapping):
        mapping = {str(k): str(v) for k, v in channels.items()}
        # Keeping one of two columns renamed alike would silently drop the other.
        sources: dict[str, list[str]] = {}
        for col, name in mapping.items():
            sources.setdefault(name, []).append(col)
        clash = {name: cols for name, cols in sources.items() if len(cols) > 1}
        if clash:
            name, cols = next(iter(clash.items()))
            raise DataFormatError(
                f"{p}: channels: columns {cols} are all renamed to {name!r}; "
                "give each column its own channel name"
            )
    else:
        names = [channels] if isinstance(channels, str) else channels
        mapping = {str(c): str(c) for c in names}
    for col in mapping:
        if col not in columns:
            raise ChannelError(f"{p}: column {col!r} not found; columns: {list(header)}")
    for col in (tname, *mapping):
        if columns[col].dtype.kind == "c":
            raise DataFormatError(
                f"{p}: column {col!r} holds complex values, which are not supported; "
                "store the real part or the magnitude"
            )
    time = columns[tname]
    chans: dict[str, Any] = {}
    for col, name in mapping.items():
        if columns[col].shape != time.shape:
            raise DataFormatError(
                f"{p}: column {col!r} has {columns[col].size} samples, time has {time.size}"
            )
        chans[name] = columns[col]
    try:
        return FlightData(
            time, chans, dict(units or {}), {"source": p.name, "format": suffix.lstrip(".")}
        )
    except DataFormatError as exc:
        raise DataFormatError(f"{p}: {exc}") from None
