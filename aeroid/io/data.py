"""Flight-test time series: the immutable `FlightData` record and its file loader."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float as as_float  # re-exported: the other modules import it here
from .._checks import plain, time_label
from .._checks import positive_number as positive_number
from .._records import FrozenState, frozen_array
from .._value_checks import _first_bad, real_array
from .._value_checks import check_flag as check_flag
from .._value_checks import check_symmetric as check_symmetric
from .._value_checks import delay_starts as delay_starts
from .._value_checks import whole_number as whole_number
from ..errors import ChannelError, DataFormatError
from ._channel_pairs import orient_pairs
from ._flight_csv import _NAME_LIKE as _NAME_LIKE
from ._flight_csv import _NUMBER as _NUMBER
from ._flight_csv import _NUMBER_LIKE as _NUMBER_LIKE
from ._flight_csv import (
    _TIME_CANDIDATES,
    _adopt,
    _columns_text,
    _csv_units,
    _Owned,
    _pick_time_column,
    _read_csv,
    _seconds,
)
from ._flight_csv import _csv_cell_error as _csv_cell_error
from ._flight_csv import _csv_header as _csv_header
from ._flight_csv import _locate_csv_error as _locate_csv_error
from ._flight_csv import _reader_error as _reader_error
from ._table_files import _read_mat, _read_parquet

# FlightData.to_csv's comment line that carries the units, read back by load_flight_test
_UNITS_COMMENT = "# units:"

__all__ = ["FlightData", "load_flight_test"]

FloatArray = NDArray[np.float64]


# One read-only copier for the package; the name stays for existing importers.
readonly = frozen_array


def _listed(names: Any, role: str) -> list[Any]:
    """`names` as a list (one name, not its letters), or a `ChannelError`."""
    if isinstance(names, str):
        return [names]
    try:
        return list(names)
    except TypeError:
        raise ChannelError(f"{role} names: expected a list of names, got {plain(names)}") from None


def numeric(values: Any, what: str, failure: str) -> FloatArray:
    """`values` as a read-only float64 copy, or a `DataFormatError` naming `what`.

    Complex samples are refused: casting them would silently drop the
    imaginary part. Datetimes and durations become seconds (see `_seconds`).
    """
    if type(values) is _Owned:
        return _adopt(values)
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"{what}: {failure} ({exc})") from None
    if arr.dtype.kind in "mM":
        arr = _seconds(arr)
    elif arr.dtype.kind == "c":
        real_array(arr, what)  # raises, with the remedy
    try:
        return readonly(arr)
    except (TypeError, ValueError, OverflowError) as exc:  # an int beyond float64 too
        raise DataFormatError(f"{what}: {failure} ({exc})") from None


# Stamps within this fraction of the sample interval of a uniform grid are taken as
# uniform sampling: stamps rounded to a few digits (SIDPAC's Example 7.2 holds 1e-4
# relative jitter) leave a Fourier transform a phase error of at most 2π × 1 % of one
# sample's phase step (1.8° at Nyquist, less below); larger jitter is refused by the
# tools that need a uniform grid.
_JITTER_FRACTION = 0.01
# Below this the grid is uniform to rounding and no note is made.
_EXACT_GRID = 1e-6


def _grid_jitter(time: FloatArray) -> float:
    """Largest distance of a stamp from the uniform grid through the end stamps, in steps."""
    n = time.size
    if n < 3:
        return 0.0
    step = (float(time[-1]) - float(time[0])) / (n - 1)
    if not step > 0.0:
        return float("inf")
    grid = time[0] + step * np.arange(n)
    return float(np.max(np.abs(time - grid))) / step


def uniform_step(time: FloatArray) -> float | None:
    """The sample interval of stamps on a uniform grid (within `FlightData.is_uniform`'s
    1 % of a step, so a clock at 1.7e9 s, whose last digit is 2.4e-7 s, still is one),
    else None."""
    if time.size < 2 or _grid_jitter(time) > _JITTER_FRACTION:
        return None
    return (float(time[-1]) - float(time[0])) / (time.size - 1)


def _refuse_coarse_stamps(given: Any, time: NDArray[np.float64]) -> None:
    """Refuse time stamps stored in a float too short for their clock: float32 near an
    epoch of 1.7e9 s holds one value per 128 s, and near 1e5 s rounds a 50 Hz grid to
    steps of 1/128 s (a jitter of 20 % nobody asked for)."""
    dtype = getattr(given, "dtype", None)
    if dtype is None or dtype.kind != "f" or dtype.itemsize >= 8 or time.size < 2:
        return
    spacing = float(np.spacing(np.asarray(np.max(np.abs(time)), dtype=dtype)))
    step = float(np.median(np.diff(time)))
    if not step > 10.0 * spacing:  # rounding a tenth of a step or more
        raise DataFormatError(
            f"time: {dtype} stamps near t = {time_label(float(np.max(np.abs(time))))} s are "
            f"only {spacing:.3g} s apart, against a sample interval of {step:.3g} s; give "
            "the times in float64 (or relative to the record's start)"
        )


def _dropout(values: NDArray[np.float64], time: NDArray[np.float64]) -> str:
    """Where a channel's first non-finite samples are: index, time and run length."""
    bad = ~np.isfinite(values)
    i = _first_bad(values)
    run = int(np.argmin(bad[i:])) if not bad[i:].all() else int(bad[i:].size)
    total = int(bad.sum())
    where = f"non-finite value at index {i} (t = {time_label(time[i])} s"
    where += f", a run of {run} samples" if run > 1 else ""
    return where + (f"; {total} in all)" if total > run else ")")


@dataclass(frozen=True, eq=False)
class FlightData(FrozenState):
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
        time = numeric(self.time, "time", "cannot convert to float array")
        if time.ndim != 1 or time.size < 2:
            raise DataFormatError(
                f"time: expected a 1-D array of at least 2 samples, got shape {time.shape}"
            )
        if not np.all(np.isfinite(time)):
            raise DataFormatError(f"time: non-finite value at index {_first_bad(time)}")
        _refuse_coarse_stamps(self.time, time)
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
            arr = numeric(values, f"channel {name!r}", "not numeric")
            if arr.shape != time.shape:
                raise DataFormatError(
                    f"channel {name!r}: length {arr.shape} does not match time {time.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise DataFormatError(f"channel {name!r}: {_dropout(arr, time)}")
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
        meta = dict(self.metadata or {})
        jitter = _grid_jitter(time)
        if _EXACT_GRID < jitter <= _JITTER_FRACTION and "time_jitter" not in meta:
            meta["time_jitter"] = (
                f"time stamps deviate from a uniform grid by up to {100 * jitter:.3g} % of "
                "the sample interval; taken as uniform sampling"
            )
        object.__setattr__(self, "metadata", MappingProxyType(meta))

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
        """True when every stamp lies within 1 % of the sample interval of a uniform grid.

        Such jitter (stamps rounded to a few digits) is taken as uniform sampling at
        `sample_rate`; the record's ``metadata["time_jitter"]`` then says so.
        """
        return _grid_jitter(self.time) <= _JITTER_FRACTION

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
        for name in _listed(names, role):
            if not isinstance(name, str):
                raise ChannelError(f"{role} name {plain(name)}: expected a string")
            if name not in self.channels:
                raise ChannelError(
                    f"{role} {name!r} not found in flight data; "
                    f"channels present: {sorted(self.channels)}"
                )

    def array(self, names: str | Sequence[str]) -> FloatArray:
        """Stack channels into an array of shape (n_samples, len(names))."""
        names = _listed(names, "channel")
        self.require(names)
        if not names:
            return np.zeros((self.n_samples, 0))
        out = np.column_stack([self.channels[n] for n in names])
        out.setflags(write=False)
        return out

    def window(self, t0: float, t1: float) -> FlightData:
        """Return the samples with ``t0 <= time <= t1`` as new flight data."""
        for label, value in (("t0", t0), ("t1", t1)):
            bound = as_float(value)
            if bound is None or np.isnan(bound):
                raise DataFormatError(f"window: {label} must be a number, got {plain(value)}")
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

    def to_csv(self, path: str | Path) -> Path:
        """Write the record as a CSV file that `load_flight_test` reads back exactly,
        units included (a ``# units: {...}`` comment line before the header).

        Parameters
        ----------
        path : str or Path
            The file to write (replaced if it exists). Its columns are ``time``
            and the channels in order, each value written with enough digits to
            round-trip.

        Returns
        -------
        Path
            The file written.

        Raises
        ------
        DataFormatError
            If a channel is named ``time`` or holds a comma, quote or line break
            in its name, or begins or ends with a space (the loader strips those
            from a header), or the file cannot be written.
        """
        target = Path(path)
        for name in self.channels:
            # the loader strips the spaces round a header cell ("time, alpha, q")
            if name == "time" or any(c in name for c in ',"\n\r') or name != name.strip():
                raise DataFormatError(
                    f"to_csv: channel name {name!r} cannot be a CSV column of its own"
                )
        columns = [self.time, *self.channels.values()]
        units = {k: v for k, v in self.units.items() if k in self.channels and v}
        # the units on a comment line before the header, which the loader reads back
        lines = [f"{_UNITS_COMMENT} {json.dumps(units)}"] if units else []
        lines += [",".join(["time", *self.channels])]
        lines += [",".join(repr(float(c[i])) for c in columns) for i in range(self.n_samples)]
        tmp = target.with_name(target.name + ".part")
        try:
            tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
            tmp.replace(target)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise DataFormatError(f"to_csv: cannot write {target} ({exc.strerror})") from None
        return target

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
    can start where the fit did (see `aeroid.models.model.fitted_start`).
    """
    h = hashlib.sha256(np.ascontiguousarray(data.time, dtype="<f8").tobytes())
    for name in sorted(data.channels):
        h.update(name.encode("utf-8") + b"\0")
        h.update(np.ascontiguousarray(data.channels[name], dtype="<f8").tobytes())
    return h.hexdigest()


# -- loading ----------------------------------------------------------------------


def _in_seconds(time: NDArray[Any], unit: str | None, path: Path, column: str) -> NDArray[Any]:
    """The time column in seconds: a unit the file declares for it (ms, us) is applied,
    one that is no time is refused (it was dropped in silence)."""
    if unit is None or unit == "s":
        return time
    factor = {"ms": 1e-3, "us": 1e-6}.get(unit)
    if factor is None:
        raise DataFormatError(
            f"{path}: the time column {column!r} is declared in {unit!r}, not a unit of time "
            "(s, ms, us)"
        )
    return np.asarray(time, dtype=np.float64) * factor


def load_flight_test(
    path: str | Path,
    *,
    time_column: str | None = None,
    channels: Sequence[str] | Mapping[str, str] | None = None,
    units: Mapping[str, str] | None = None,
    sample_rate: float | None = None,
    max_gap: float | None = None,
    t0: float | None = None,
    t1: float | None = None,
) -> FlightData:
    """Load a flight-test record from a table (CSV, Parquet, MATLAB) or a flight log.

    Column headers are kept verbatim as channel names, so they match the
    model's state, control and output names.

    Parameters
    ----------
    path : str or Path
        File to read. Tables: ``.csv``/``.txt``, ``.parquet``/``.pq``,
        ``.mat`` (v5). Flight logs (see `aeroid.read_log`): PX4 ``.ulg``,
        ArduPilot ``.bin``/``.log``, HDF5 ``.h5``, MATLAB v7.3 ``.mat``; a
        log is recognised by its first bytes as well as its suffix.
    time_column : str, optional
        Column holding time in seconds. Default: the first of ``time``, ``t``,
        ``Time`` ... that is present. For HDF5 and MATLAB v7.3, the name of
        the time dataset.
    channels : sequence of str or mapping of str to str, optional
        Columns (log channels) to keep. A mapping renames them, written
        ``{column: channel_name}`` or ``{channel_name: column}`` (a log's
        channels likewise): the side whose names are all the file's columns is
        the column side. One naming the file's columns on both sides (a swap, a
        cycle, a column renamed onto another column's name) reads both ways and
        is an error, and so are two columns renamed to one channel name. Default:
        every column but time (every channel of the log).
    units : mapping of str to str, optional
        Unit label per (renamed) channel; for a log, over the units it states.
    sample_rate : float, optional
        Logs only: resample the channels, each on its own stamps, onto one
        uniform grid at this rate (Hz) with `aeroid.io.resampling.resample`.
        Without it, the channels must share their time stamps. Without
        `channels`, the whole log: the channels that can be resampled go on
        the grid over the span the bulk of the log covers, and the others are
        left out with one warning (see Notes).
    max_gap : float, optional
        Logs only, with `sample_rate`: longest gap in a channel's stamps (s)
        to interpolate across; passed to the resampler.
    t0, t1 : float, optional
        Logs only, with `sample_rate`: the span (s, in the log's own time) to
        put on the grid, so that a gap outside it (a logging pause before
        take-off) does not stop the load; passed to the resampler.

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
    sample; a duration or time-of-day column becomes seconds. A CSV file is
    parsed by pyarrow; comment (``#``) and blank lines before the header are
    skipped, a column whose first cell is an ISO 8601 date and time
    (``2024-05-01T10:00:00.25``, or with a zone, ``...Z`` or ``...+02:00``,
    read in UTC) becomes seconds since its first sample, and a bad cell
    (one of such a column too) is reported by row (the file's line number,
    as an editor shows it) and column. A ``# units:`` comment naming a column the file lacks warns.

    A whole log (`sample_rate` without `channels`) is a first look at
    everything, not a fit: a PX4 log holds fields never set (NaN), topics
    logged once, and topics that start late, stop early or only exist around
    an event, so the span every channel covers is short (about 1 s of the
    shipped PX4 sample's 6.5 s). The grid spans instead the [a, b] that makes
    the most topic-seconds: with a the start of a topic and b the end of one, it maximises
    (topics covering it) x (b - a), a topic covering it when its longest
    stretch without a gap the resampler refuses (`max_gap`) does. Topics
    count, not channels, since a topic's fields share its stamps. So a topic
    is given up only where the length it costs outweighs its share of the
    topics, and a short or late topic cannot shrink the grid. `t0`/`t1`
    fix either end. Left out, with one warning counting them by reason and
    ``metadata["resampling"]["left_out"]`` naming each: channels with a NaN
    or inf, with one sample, with a gap inside the span, and outside it.
    With `channels`, a channel that cannot be resampled is an error naming it.
    """
    from .logs import _existing, sniff_format

    p = _existing(path, kind="data")
    log_format = sniff_format(p)
    if log_format is not None:
        return _load_log(
            p,
            log_format,
            time_column=time_column,
            channels=channels,
            units=units,
            sample_rate=sample_rate,
            max_gap=max_gap,
            t0=t0,
            t1=t1,
        )
    if sample_rate is not None or max_gap is not None or t0 is not None or t1 is not None:
        raise DataFormatError(
            f"{p}: sample_rate, max_gap, t0 and t1 apply to flight logs; this is a table "
            "already on one time axis (FlightData.window cuts a span out of it)"
        )
    suffix = p.suffix.lower()
    columns: Mapping[str, NDArray[Any]]
    wanted = _wanted_columns(channels, time_column)
    declared: dict[str, str] = {}
    if suffix in (".csv", ".txt", ".dat"):
        header, columns = _read_csv(p, wanted)
        declared = _csv_units(p, _UNITS_COMMENT, header)
    elif suffix in (".parquet", ".pq"):
        header, columns = _read_parquet(p, wanted)
    elif suffix == ".mat":
        header, columns = _read_mat(p, wanted)
    else:
        raise DataFormatError(
            f"{p}: unknown file type {suffix!r} (expected .csv, .parquet or .mat)"
        )
    tname = _pick_time_column(header, time_column, p)
    # {channel name: column}; a mapping reads either way round, the file deciding
    pick: dict[str, str]
    if channels is None:
        pick = {h: h for h in header if h != tname}
    elif isinstance(channels, Mapping):
        pick, _ = orient_pairs(channels, header, str(p), "columns")
    else:
        names = [channels] if isinstance(channels, str) else channels
        pick = {str(c): str(c) for c in names}
    for col in pick.values():
        if col not in columns:
            raise ChannelError(f"{p}: column {col!r} not found; {_columns_text(header)}")
    if tname not in columns:  # a header name no reader turned into a column
        raise ChannelError(f"{p}: time column {tname!r} is not a numeric vector")
    for col in (tname, *pick.values()):
        if columns[col].dtype.kind == "c":
            raise DataFormatError(
                f"{p}: column {col!r} holds complex values, which are not supported; "
                "store the real part or the magnitude"
            )
    time = _in_seconds(columns[tname], declared.get(tname), p, tname)
    chans: dict[str, Any] = {}
    for name, col in pick.items():
        if columns[col].shape != time.shape:
            raise DataFormatError(
                f"{p}: column {col!r} has {columns[col].size} samples, time has {time.size}"
            )
        chans[name] = columns[col]
    if units is not None and not isinstance(units, Mapping):
        raise DataFormatError(
            f"units: expected a mapping of channel name to unit, got {type(units).__name__}"
        )
    # units the file declares (to_csv's comment line), by column, under the channels' names
    merged = {name: declared[col] for name, col in pick.items() if col in declared}
    merged.update(units or {})
    try:
        return FlightData(time, chans, merged, {"source": p.name, "format": suffix.lstrip(".")})
    except DataFormatError as exc:
        raise DataFormatError(f"{p}: {exc}") from None


def stated_units(path: str | Path) -> dict[str, str]:
    """The units a table file states for its columns, as `load_flight_test` reads them.

    Parameters
    ----------
    path : str or Path
        A CSV file (its ``# units:`` comment line); other tables state none.

    Returns
    -------
    dict of str to str
        Unit per column; empty when the file states none (or the line is unreadable).
    """
    import warnings

    p = Path(path)
    if p.suffix.lower() not in (".csv", ".txt", ".dat"):
        return {}
    with warnings.catch_warnings():  # the load warns about the units line itself
        warnings.simplefilter("ignore")
        return _csv_units(p, _UNITS_COMMENT, _csv_header(p)[0])


def _wanted_columns(
    channels: Sequence[str] | Mapping[str, str] | None, time_column: str | None
) -> frozenset[str] | None:
    """The names a loader needs to read: the channels asked for (both sides of a
    mapping) and the time column or its candidates; None for every column."""
    if channels is None:
        return None
    if isinstance(channels, str):
        names = [channels]
    elif isinstance(channels, Mapping):
        names = [*channels.keys(), *channels.values()]
    else:
        names = list(channels)
    times = (time_column,) if time_column is not None else _TIME_CANDIDATES
    return frozenset(str(n) for n in (*names, *times))


def _log_mapping(
    log: Any, channels: Sequence[str] | Mapping[str, str] | None, path: Path
) -> dict[str, str]:
    """``{channel_name: log_channel}`` from what the caller passed."""
    from .logs import find_channels

    if channels is None:
        return {c: c for c in log.channels}
    if isinstance(channels, str):
        channels = [channels]
    if not isinstance(channels, Mapping):
        names = [str(c) for c in channels]
        find_channels(log, names, path)
        return {c: c for c in names}
    pairs, missing = orient_pairs(channels, log.channels, str(path), "log channels")
    find_channels(log, missing, path)  # names each, with close names
    return pairs


def _refuse_contradicting_units(
    p: Path, log: Any, mapping: Mapping[str, str], units: Mapping[str, str] | None
) -> None:
    """A unit label the caller gives that contradicts the one the log states is a mistake
    (deg/s over a rad/s gyro): the values would be read in the wrong unit silently."""
    from .._units import UNIT_CONVERSIONS

    for name, given in dict(units or {}).items():
        source = mapping.get(name)
        if source is None or source not in log.channels:
            continue
        stated = log.channels[source].unit
        if not stated or given == stated:
            continue
        theirs, ours = UNIT_CONVERSIONS.get(stated), UNIT_CONVERSIONS.get(str(given))
        if theirs is not None and ours is not None and theirs != ours:
            raise DataFormatError(
                f"{p}: units[{name!r}] = {given!r} contradicts the unit {stated!r} the log "
                f"states for {source!r}; drop it, or convert the channel with "
                "aeroid.apply_channel_map"
            )


def _load_log(
    p: Path,
    log_format: str,
    *,
    time_column: str | None,
    channels: Sequence[str] | Mapping[str, str] | None,
    units: Mapping[str, str] | None,
    sample_rate: float | None,
    max_gap: float | None,
    t0: float | None = None,
    t1: float | None = None,
) -> FlightData:
    """`load_flight_test` for a flight log: read it, pick channels, put them on one grid."""
    from .logs import read_selected

    # a log's datasets nobody asked for are not read (an HDF5 file can hold gigabytes)
    wanted = None if channels is None else _wanted_columns(channels, None)
    log = read_selected(p, log_format, time_column, False, wanted)
    mapping = _log_mapping(log, channels, p)
    if not mapping:
        raise DataFormatError(f"{p}: channels: none selected")
    _refuse_contradicting_units(p, log, mapping, units)
    metadata = {"source": p.name, "format": str(log.metadata.get("format", log_format))}
    if sample_rate is None:
        for name, value in (("max_gap", max_gap), ("t0", t0), ("t1", t1)):
            if value is not None:
                raise DataFormatError(f"{p}: {name} applies only with sample_rate")
        first = next(iter(mapping.values()))
        time = log.channels[first].time
        for source in mapping.values():
            other = log.channels[source].time
            if other.shape != time.shape or not np.array_equal(other, time):
                raise DataFormatError(
                    f"{p}: log channels {first!r} ({log.channels[first].rate:.4g} Hz) and "
                    f"{source!r} ({log.channels[source].rate:.4g} Hz) are on different time "
                    "stamps; pass sample_rate=... to resample them onto one grid"
                )
        log_units = {n: log.channels[c].unit for n, c in mapping.items() if log.channels[c].unit}
        try:
            return FlightData(
                time,
                {n: log.channels[c].values for n, c in mapping.items()},
                {**log_units, **dict(units or {})},
                metadata,
            )
        except DataFormatError as exc:
            raise DataFormatError(f"{p}: {exc}") from None
    from ._regrid import flightlog_parts, regrid

    left: dict[str, str] = {}
    try:
        if channels is None:  # the whole log: what can go on the grid, over its bulk
            mapping, t0, t1, left = _whole_log_grid(p, log, sample_rate, max_gap, t0, t1)
        parts = flightlog_parts(log)
        data = regrid(*parts, mapping, rate=sample_rate, max_gap=max_gap, t0=t0, t1=t1)
    except DataFormatError as exc:
        raise DataFormatError(f"{p}: {exc}") from None
    if left:
        resampling = {**data.metadata["resampling"], "left_out": left}
        data = data._replace(metadata={**data.metadata, "resampling": resampling})
    extra = dict(units or {})
    unknown = sorted(set(extra) - set(data.channels))
    if unknown:
        raise DataFormatError(f"{p}: units given for unknown channels {unknown}")
    log_units = {n: log.channels[c].unit for n, c in mapping.items() if log.channels[c].unit}
    merged = {**log_units, **dict(data.units), **extra}
    merged = {n: u for n, u in merged.items() if n in data.channels}
    return FlightData(data.time, dict(data.channels), merged, {**dict(data.metadata), **metadata})


def _whole_log_grid(
    p: Path,
    log: Any,
    rate: Any,
    max_gap: float | None,
    t0: float | None,
    t1: float | None,
) -> tuple[dict[str, str], float, float, dict[str, str]]:
    """The channels of a whole log to resample, the span, and those left out (one warning
    says how many and why; see `aeroid.io._autopilot_logs._whole_log_plan`)."""
    import warnings

    from .._checks import positive_number
    from ._autopilot_logs import _whole_log_plan
    from ._regrid import _seconds

    rate = positive_number(rate, "sample_rate", " in Hz")
    gap = max_gap
    if gap is not None and gap != float("inf"):
        gap = positive_number(gap, "max_gap", " of seconds")
    start = None if t0 is None else _seconds(t0, "t0")
    end = None if t1 is None else _seconds(t1, "t1")
    mapping, a, b, left = _whole_log_plan(log, rate, gap, start, end)
    if left:
        counts: dict[str, int] = {}
        for why in left.values():
            counts[why] = counts.get(why, 0) + 1
        why_text = ", ".join(f"{why} ({k})" for why, k in counts.items())
        warnings.warn(
            f"{p}: {len(left)} of {len(log.channels)} channels left out: {why_text}; the "
            f"{rate:g} Hz grid spans [{a:.6g}, {b:.6g}] s, the span most of the log covers "
            "(metadata['resampling']['left_out'] names each; channels=... loads chosen "
            "ones strictly)",
            UserWarning,
            stacklevel=4,
        )
    return mapping, a, b, left
