"""Autopilot flight logs: PX4 ULog, ArduPilot DataFlash, HDF5 and MATLAB v7.3 readers.

Each reader returns a `FlightLog`: every signal on its own time stamps, in
seconds on the log's own clock (time since boot for PX4 and ArduPilot), with
the events the log records. The readers rest on the field's own libraries,
installed with ``pip install "aeroid[logs]"``: pyulog (ULog), pymavlink
(DataFlash) and h5py (HDF5, MATLAB v7.3).

A ULog topic is stamped with PX4's ``timestamp_sample`` (when its sensor
sampled: the time PX4's estimator and controllers use) where it has that field,
set and rising; else with ``timestamp`` (when the message was published, up to a
sensor period later: 20 ms for the barometer's air data). The log's
``metadata["stamps"]`` names the field each topic's stamps come from.

Channel names
-------------
* ULog: ``topic.field`` (``vehicle_angular_velocity.xyz[1]``). A topic logged
  in several instances (``multi_id`` 1, 2, ...) gets the instance after an
  underscore, as PX4's own ``ulog2csv`` names its files:
  ``sensor_accel_1.x``; instance 0 keeps the plain topic name. Should another
  topic already be called ``sensor_accel_1``, the instance is written
  ``sensor_accel#1`` instead.
* DataFlash: ``MSG.Field`` (``IMU.GyrY``). A message with an instance field
  (several IMUs in one message type) keeps the plain name for instance 0 and
  puts the instance in brackets otherwise: ``IMU[1].GyrY``.
* HDF5: the dataset path joined by dots (``flight.q``). A 2-D dataset of
  several channels gives ``name[j]`` (HDF5) or ``name_j`` (MATLAB, as the
  MATLAB v5 loader names matrix columns).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState
from ..errors import DataFormatError
from ._autopilot_logs import _NOT_CHANNELS as _NOT_CHANNELS
from ._autopilot_logs import _PX4_NAV_STATES as _PX4_NAV_STATES
from ._autopilot_logs import _PX4_UNIT_RULES as _PX4_UNIT_RULES
from ._autopilot_logs import _PX4_UNITS as _PX4_UNITS
from ._autopilot_logs import _STRUCT_DTYPE as _STRUCT_DTYPE
from ._autopilot_logs import _df_channels as _df_channels
from ._autopilot_logs import _df_collect_binary as _df_collect_binary
from ._autopilot_logs import _df_collect_text as _df_collect_text
from ._autopilot_logs import _df_dtype as _df_dtype
from ._autopilot_logs import _df_events as _df_events
from ._autopilot_logs import _df_time as _df_time
from ._autopilot_logs import _df_unit as _df_unit
from ._autopilot_logs import _missing, _read_dataflash, _read_ulog
from ._autopilot_logs import _px4_unit as _px4_unit
from ._autopilot_logs import _transitions as _transitions
from ._logtypes import FlightLog, LogChannel

__all__ = ["ChannelListing", "list_channels", "read_log"]

FloatArray = NDArray[np.float64]

ULOG_MAGIC = b"ULog\x01\x12\x35"
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
DATAFLASH_MAGIC = b"\xa3\x95"

FORMATS = ("ulog", "dataflash", "dataflash-text", "hdf5")
_ALIASES = {
    "ulg": "ulog",
    "px4": "ulog",
    "bin": "dataflash",
    "ardupilot": "dataflash",
    "log": "dataflash-text",
    "h5": "hdf5",
    "hdf": "hdf5",
    "mat": "hdf5",
    "matlab": "hdf5",
}
_SUFFIXES = {
    ".ulg": "ulog",
    ".bin": "dataflash",
    ".log": "dataflash-text",
    ".h5": "hdf5",
    ".hdf5": "hdf5",
    ".hdf": "hdf5",
    ".he5": "hdf5",
}
_LIBRARY = {
    "ulog": "pyulog",
    "dataflash": "pymavlink",
    "dataflash-text": "pymavlink",
    "hdf5": "h5py",
}


# -- format detection ---------------------------------------------------------------


def _hdf5_offset(head: bytes) -> int | None:
    """Where the HDF5 signature sits: at 0, or after a user block (512, 1024, ... bytes;
    MATLAB v7.3 files carry a 512-byte text header there)."""
    at = 0
    while at + len(HDF5_MAGIC) <= len(head):
        if head[at : at + len(HDF5_MAGIC)] == HDF5_MAGIC:
            return at
        at = 512 if at == 0 else 2 * at
    return None


def sniff_format(path: Path) -> str | None:
    """The log format of `path` from its first bytes, then its suffix; None for other files.

    Magic bytes win over the suffix, so a ``.bin`` that is really a ULog is read
    as a ULog. A ``.mat`` file is a log only when it is MATLAB v7.3 (HDF5).
    """
    with open(path, "rb") as f:
        head = f.read(4096)
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if _hdf5_offset(head) is not None:
        return "hdf5"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if head.lstrip().startswith(b"FMT,"):
        return "dataflash-text"
    return _SUFFIXES.get(path.suffix.lower())


def _check_magic(path: Path, fmt: str) -> None:
    """Refuse a file whose first bytes contradict the format it was read as."""
    with open(path, "rb") as f:
        head = f.read(4096)
    expected = {
        "ulog": (head.startswith(ULOG_MAGIC), "the ULog magic bytes 'ULog\\x01\\x12\\x35'"),
        "hdf5": (_hdf5_offset(head) is not None, "the HDF5 signature"),
        "dataflash": (head.startswith(DATAFLASH_MAGIC), "the DataFlash header 0xA3 0x95"),
        "dataflash-text": (b"FMT," in head, "an 'FMT,' line"),
    }
    ok, what = expected[fmt]
    if not ok:
        size = path.stat().st_size
        raise DataFormatError(
            f"{path}: not a {fmt} file: it does not start with {what} "
            f"({size} bytes; truncated, or another format?)"
        )


def _resolve_format(path: Path, format: str | None) -> str:
    if format is None:
        fmt = sniff_format(path)
        if fmt is None:
            raise DataFormatError(
                f"{path}: unknown log format (suffix {path.suffix!r}, first bytes "
                f"not those of a ULog, DataFlash or HDF5 file); expected one of {list(FORMATS)}"
            )
    else:
        if not isinstance(format, str):
            raise DataFormatError(f"format: expected a string, got {type(format).__name__}")
        fmt = _ALIASES.get(format.lower(), format.lower())
        if fmt not in FORMATS:
            raise DataFormatError(
                f"format: unknown log format {format!r}; expected {list(FORMATS)}"
            )
    _check_magic(path, fmt)
    return fmt


def _existing(path: str | Path, *, kind: str = "log") -> Path:
    """`path` as a Path to a regular file, or a `DataFormatError` saying why not
    (`kind` names the file in the message: ``"log"``, ``"data"``)."""
    import os

    if not isinstance(path, (str, os.PathLike)):
        raise DataFormatError(
            f"path: expected a file path (str or Path), got {type(path).__name__}"
        )
    p = Path(path)
    if os.fspath(path) == "":
        raise DataFormatError("path: empty file name")
    if p.is_dir():
        raise DataFormatError(f"{p}: is a directory, not a {kind} file")
    if not p.exists():
        raise DataFormatError(f"{p}: no such file")
    if not p.is_file():
        raise DataFormatError(f"{p}: not a regular file")
    return p


# -- HDF5 and MATLAB v7.3 -----------------------------------------------------------

_TIME_NAMES = ("time", "t", "timestamp", "Time", "TIME", "time_s", "timestamp_s")
_TIME_SCALE = {
    "": 1.0,
    "s": 1.0,
    "sec": 1.0,
    "second": 1.0,
    "seconds": 1.0,
    "ms": 1e-3,
    "msec": 1e-3,
    "milliseconds": 1e-3,
    "us": 1e-6,
    "µs": 1e-6,
    "usec": 1e-6,
    "microseconds": 1e-6,
    "ns": 1e-9,
    "nanoseconds": 1e-9,
}
_MATLAB_NON_NUMERIC = {"char", "cell", "function_handle", "string", "datetime", "table"}


def _text_attr(obj: Any, *names: str) -> str:
    for name in names:
        if name in obj.attrs:
            value = obj.attrs[name]
            if isinstance(value, np.ndarray):
                value = value.ravel()[0] if value.size else ""
            if isinstance(value, (bytes, np.bytes_)):
                return bytes(value).decode("utf-8", "replace").strip()
            return str(value).strip()
    return ""


# The most one dataset may declare (bytes, uncompressed): a few MB of compressed
# file can declare gigabytes, and a flight channel is far below this.
_MAX_DATASET_BYTES = 1 << 30
# ... and the most all datasets read from one file may declare together
_MAX_FILE_BYTES = 4 << 30


def _hdf5_refusal(path: Path, ds: Any, allow_external: bool) -> str:
    """Why a dataset is not read ('' to read it): storage outside the file, or too big."""
    if not allow_external:
        if ds.is_virtual:
            return "is a virtual dataset mapping other files"
        if ds.external:
            return "is stored in an external file"
    declared = int(ds.size) * int(ds.dtype.itemsize)
    if declared > _MAX_DATASET_BYTES:
        return f"declares {declared / 2**30:.1f} GiB, over the {_MAX_DATASET_BYTES >> 20} MiB limit"
    return ""


def _hdf5_wanted(wanted: Collection[str]) -> frozenset[str]:
    """The dataset names (dots for slashes) that hold the channels in `wanted`: a
    matrix dataset's columns are ``name[j]`` (``name_j`` in a MATLAB file)."""
    bases = set()
    for name in wanted:
        bases.add(name)
        bases.add(re.sub(r"(\[\d+\]|_\d+)$", "", name))
    return frozenset(bases)


def _read_hdf5(
    path: Path,
    time_column: str | None = None,
    *,
    allow_external: bool = False,
    wanted: Collection[str] | None = None,
) -> FlightLog:
    try:
        import h5py
    except ImportError:
        raise _missing("h5py", path) from None
    try:
        f = h5py.File(path, "r")
    except Exception as exc:  # h5py raises OSError and others for a corrupt file
        raise DataFormatError(f"{path}: not a readable HDF5 file ({exc})") from None
    with f:
        matlab = f.userblock_size > 0 and _is_matlab_header(path)
        datasets: dict[str, Any] = {}
        groups: dict[str, Any] = {"": f}

        def visit(name: str, obj: Any) -> None:
            if any(part.startswith("#") for part in name.split("/")):
                return  # MATLAB's hidden reference groups
            if isinstance(obj, h5py.Dataset):
                datasets[name] = obj
            else:
                groups[name] = obj

        try:
            f.visititems(visit)
        except Exception as exc:
            raise DataFormatError(f"{path}: not a readable HDF5 file ({exc})") from None
        # MATLAB's layout without its text header (a copied or rewritten file)
        matlab = matlab or any("MATLAB_class" in ds.attrs for ds in datasets.values())
        names = (time_column,) if time_column is not None else _TIME_NAMES
        time_of: dict[str, str] = {}  # group -> its time dataset
        for group in groups:
            for candidate in names:
                key = f"{group}/{candidate}" if group else candidate
                if key in datasets:
                    time_of[group] = key
                    break
        if not time_of:
            raise DataFormatError(
                f"{path}: no time dataset found (looked for {list(names)} in every group); "
                "pass time_column=... naming it"
            )
        bases = None if wanted is None else _hdf5_wanted(wanted)
        needed = set(time_of)
        if bases is not None:  # only the time of a group holding a channel asked for
            groups_of = (
                _time_group(key, time_of)
                for key in datasets
                if key.replace("/", ".") in bases and key not in time_of.values()
            )
            needed = {g for g in groups_of if g is not None}
        times: dict[str, tuple[str, FloatArray]] = {}
        for group in sorted(needed):
            key = time_of[group]
            refusal = _hdf5_refusal(path, datasets[key], allow_external)
            if refusal:
                raise DataFormatError(
                    f"{path}: time dataset {key!r} {refusal}; not read"
                    + _EXTERNAL_HINT * ("GiB" not in refusal)
                )
            times[group] = (key, _hdf5_time(path, datasets[key], matlab))
        channels: dict[str, LogChannel] = {}
        skipped: dict[str, str] = {}
        unread: list[str] = []
        time_keys = set(time_of.values())
        budget = _MAX_FILE_BYTES - sum(t.nbytes for _, t in times.values())
        for key, ds in datasets.items():
            if key in time_keys:
                continue
            if bases is not None and key.replace("/", ".") not in bases:
                # not asked for: not read at all, only named from its shape
                home = _time_group(key, time_of)
                if home is not None:
                    n = int(datasets[time_of[home]].size)
                    unread.extend(_hdf5_names(key, ds, n, matlab))
                continue
            reason = _hdf5_refusal(path, ds, allow_external)
            declared = int(ds.size) * int(ds.dtype.itemsize)
            if not reason and declared > budget:
                reason = (
                    f"not read: the datasets before it use the {_MAX_FILE_BYTES >> 30} GiB "
                    "one file may declare in all"
                )
            if not reason:
                budget -= declared
                reason = _hdf5_channels(key, ds, times, matlab, channels)
            if reason:
                skipped[key.replace("/", ".")] = reason
    if not channels and not unread:
        raise DataFormatError(
            f"{path}: no numeric dataset matches a time dataset in length"
            + (f" (skipped: {skipped})" if skipped else "")
        )
    metadata: dict[str, Any] = {"source": path.name, "format": "matlab" if matlab else "hdf5"}
    if unread:
        metadata["unread"] = tuple(unread)
    refused = {k: v for k, v in skipped.items() if "external" in v or "virtual" in v}
    if refused:
        # never silently missing: a channel the caller asks for would read 'not found'
        warnings.warn(
            f"{path}: datasets not read: {refused}{_EXTERNAL_HINT}", UserWarning, stacklevel=4
        )
    if skipped:
        metadata["skipped"] = skipped
    return FlightLog(channels, (), metadata)


def _hdf5_names(key: str, ds: Any, n: int, matlab: bool) -> list[str]:
    """The channel names `_hdf5_channels` would make of a dataset, from its shape and
    attributes alone (nothing is read); [] for one it would skip."""
    cls = _text_attr(ds, "MATLAB_class")
    if cls in _MATLAB_NON_NUMERIC or "MATLAB_empty" in ds.attrs or ds.dtype.kind not in "fiub":
        return []
    shape = tuple(ds.shape)[::-1] if matlab and ds.ndim == 2 else tuple(ds.shape)
    name = key.replace("/", ".")
    if len(shape) == 1 or (len(shape) == 2 and 1 in shape):
        return [name] if int(np.prod(shape)) == n else []
    if len(shape) != 2 or n not in shape:
        return []
    width = shape[1] if shape[0] == n else shape[0]
    return [f"{name}_{j}" if matlab else f"{name}[{j}]" for j in range(width)]


def _time_group(key: str, time_of: Mapping[str, Any]) -> str | None:
    """The nearest group enclosing dataset `key` that has a time dataset."""
    group = key.rpartition("/")[0]
    while group not in time_of:
        if not group:
            return None
        group = group.rpartition("/")[0]
    return group


_EXTERNAL_HINT = " (pass allow_external_data=True to read data stored outside the file you named)"


def _is_matlab_header(path: Path) -> bool:
    with open(path, "rb") as f:
        return f.read(10) == b"MATLAB 7.3"


def _hdf5_array(ds: Any, matlab: bool) -> NDArray[Any]:
    arr = np.asarray(ds[()])
    # MATLAB writes column-major arrays, which HDF5 sees transposed.
    return arr.T if matlab and arr.ndim == 2 else arr


def _hdf5_time(path: Path, ds: Any, matlab: bool) -> FloatArray:
    arr = _hdf5_array(ds, matlab)
    if arr.dtype.kind not in "fiu" or arr.size < 2 or arr.size != max(arr.shape, default=0):
        raise DataFormatError(
            f"{path}: time dataset {ds.name!r} must be a numeric vector, got shape {arr.shape} "
            f"of {arr.dtype}"
        )
    unit = _text_attr(ds, "units", "unit")
    scale = _TIME_SCALE.get(unit.lower() if unit != "µs" else unit)
    if scale is None:
        raise DataFormatError(
            f"{path}: time dataset {ds.name!r} has unit {unit!r}; expected one of "
            f"{sorted(k for k in _TIME_SCALE if k)}"
        )
    time = arr.ravel().astype(np.float64) * scale
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise DataFormatError(
            f"{path}: time dataset {ds.name!r}: stamp {arr.ravel()[bad[0]]} at index "
            f"{bad[0]} is not finite"
        )
    return time


def _hdf5_channels(
    key: str,
    ds: Any,
    times: Mapping[str, tuple[str, FloatArray]],
    matlab: bool,
    channels: dict[str, LogChannel],
) -> str:
    """Add the channels of one dataset; the reason it holds none, or ''."""
    cls = _text_attr(ds, "MATLAB_class")
    if cls in _MATLAB_NON_NUMERIC or "MATLAB_empty" in ds.attrs:
        return f"MATLAB class {cls or 'empty'}"
    if ds.dtype.kind not in "fiub":
        return f"not numeric ({ds.dtype})"
    if ds.ndim > 2:
        return f"{ds.ndim}-D"
    if ds.ndim == 0:
        return "a single value (no time history)"
    group = _time_group(key, times)
    if group is None:
        return "no time dataset in its group or above"
    time = times[group][1]
    arr = _hdf5_array(ds, matlab)
    name = key.replace("/", ".")
    unit = _text_attr(ds, "units", "unit")
    n = time.size
    if arr.ndim == 1 or (arr.ndim == 2 and 1 in arr.shape):
        if arr.size != n:
            return f"{arr.size} samples, its time has {n}"
        channels[name] = LogChannel(name, time, arr.ravel(), unit)
        return ""
    if arr.shape[0] != n:
        if arr.shape[1] != n:
            return f"shape {arr.shape}, its time has {n} samples"
        arr = arr.T
    for j in range(arr.shape[1]):
        label = f"{name}_{j}" if matlab else f"{name}[{j}]"
        channels[label] = LogChannel(label, time, arr[:, j], unit)
    return ""


# -- public API -----------------------------------------------------------------------


def read_log(
    path: str | Path,
    *,
    format: str | None = None,
    time_column: str | None = None,
    allow_external_data: bool = False,
) -> FlightLog:
    """Read an autopilot or HDF5 flight log with every channel at its own rate.

    Parameters
    ----------
    path : str or Path
        PX4 ULog (``.ulg``), ArduPilot DataFlash (``.bin`` binary, ``.log``
        text), HDF5 (``.h5``, ``.hdf5``) or MATLAB v7.3 (``.mat``) file.
    format : str, optional
        One of ``"ulog"``, ``"dataflash"``, ``"dataflash-text"``, ``"hdf5"``.
        Default: from the file's first bytes, then its suffix.
    time_column : str, optional
        HDF5 only: the name of the time dataset in each group. Default: the
        first of ``time``, ``t``, ``timestamp`` ... present; a ``units``
        attribute of ``ms``, ``us`` or ``ns`` is converted to seconds.
    allow_external_data : bool, default False
        HDF5 only: read datasets whose storage lies outside the file
        (external raw files, virtual datasets into other files). Refused by
        default: a file could otherwise make AeroID read any local file.
        Datasets declaring more than 1 GiB, or beyond 4 GiB in all, are never read.

    Returns
    -------
    FlightLog
        Channels (see the module notes for their names) with times in
        seconds, the log's units where it states them (PX4 units where PX4's
        message definitions fix them), and events: flight-mode changes,
        text messages, dropouts, and a ULog pyulog found corrupt (an event
        ``corruption``, ``metadata["file_corruption"]`` and a warning: samples
        are missing that no dropout names).

    Raises
    ------
    DataFormatError
        A missing or unreadable file, an unknown format, first bytes that
        contradict the format, a log without data, or the reading library
        not installed (``pip install "aeroid[logs]"``).
    """
    return read_selected(path, format, time_column, allow_external_data, None)


def read_selected(
    path: str | Path,
    format: str | None,
    time_column: str | None,
    allow_external_data: bool,
    wanted: Collection[str] | None,
) -> FlightLog:
    """`read_log`; an HDF5 file's datasets outside `wanted` (channel names) are not
    read, only listed in ``metadata["unread"]``."""
    p = _existing(path)
    fmt = _resolve_format(p, format)
    if fmt != "hdf5" and time_column is not None:
        raise DataFormatError(
            f"{p}: time_column applies to HDF5 files only; a {fmt} log stamps each message"
        )
    readers: dict[str, Callable[[], FlightLog]] = {
        "ulog": lambda: _read_ulog(p),
        "dataflash": lambda: _read_dataflash(p, text=False),
        "dataflash-text": lambda: _read_dataflash(p, text=True),
        "hdf5": lambda: _read_hdf5(
            p, time_column, allow_external=allow_external_data, wanted=wanted
        ),
    }
    return readers[fmt]()


@dataclass(frozen=True)
class ChannelListing(FrozenState):
    """What a log holds: each channel's name, rate, unit and sample count.

    Attributes
    ----------
    source : str
        File name.
    format : str
        Log format read.
    names : tuple of str
        Channel names, as `read_log` and `load_flight_test` take them.
    rates : ndarray
        Median sample rate of each channel, Hz (0 for a single sample).
    units : tuple of str
        Unit each channel states, ``""`` when none.
    counts : ndarray
        Samples per channel.
    """

    source: str
    format: str
    names: tuple[str, ...]
    rates: FloatArray
    units: tuple[str, ...]
    counts: NDArray[np.int64]

    def __post_init__(self) -> None:
        for label, dtype in (("rates", np.float64), ("counts", np.int64)):
            arr = np.array(getattr(self, label), dtype=dtype)
            arr.setflags(write=False)
            object.__setattr__(self, label, arr)

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def rate(self, name: str) -> float:
        """Median sample rate of channel `name`, Hz."""
        return float(self.rates[self._index(name)])

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise DataFormatError(f"{self.source}: the log has no channel {name!r}") from None

    def summary(self) -> str:
        """A Markdown table of the channels."""
        lines = [
            f"{len(self.names)} channels in {self.source} ({self.format})",
            "",
            "| channel | rate (Hz) | samples | unit |",
            "|---------|-----------|---------|------|",
        ]
        for name, rate, count, unit in zip(
            self.names, self.rates, self.counts, self.units, strict=True
        ):
            lines.append(f"| {name} | {rate:.4g} | {int(count)} | {unit} |")
        return "\n".join(lines)


def listing(log: FlightLog) -> ChannelListing:
    """The `ChannelListing` of a log already read."""
    chans = list(log.channels.values())
    return ChannelListing(
        source=str(log.metadata.get("source", "")),
        format=str(log.metadata.get("format", "")),
        names=tuple(c.name for c in chans),
        rates=np.array([c.rate for c in chans], dtype=np.float64),
        units=tuple(c.unit for c in chans),
        counts=np.array([c.time.size for c in chans], dtype=np.int64),
    )


def list_channels(
    path: str | Path, *, format: str | None = None, time_column: str | None = None
) -> ChannelListing:
    """List the channels of a flight log: names, sample rates, units, sample counts.

    Parameters
    ----------
    path : str or Path
        A log `read_log` reads.
    format, time_column : str, optional
        As for `read_log`.

    Returns
    -------
    ChannelListing
        With a Markdown ``summary()``.

    Raises
    ------
    DataFormatError
        As `read_log`.
    """
    return listing(read_log(path, format=format, time_column=time_column))


def find_channels(log: FlightLog, wanted: Iterable[str], path: Path | str) -> None:
    """Raise `ChannelError` naming the first of `wanted` the log lacks, with near names
    or why the file's dataset was not read; `DataFormatError` when the log's definitions
    are corrupt (the channel may have been lost with them)."""
    import difflib

    from ..errors import ChannelError

    skipped = dict(log.metadata.get("skipped", {}) or {})
    for name in wanted:
        if name not in log.channels and name in skipped:
            raise ChannelError(f"{path}: channel {name!r} {skipped[name]}")
        if name not in log.channels and log.metadata.get("corrupt"):
            raise DataFormatError(
                f"{path}: channel {name!r} cannot be read: {log.metadata['corrupt']}, so "
                f"only {len(log.channels)} channels were recovered; the file is damaged"
            )
        if name not in log.channels:
            known = [*log.channels, *log.metadata.get("unread", ())]  # not read: not asked for
            near = difflib.get_close_matches(name, known, n=5, cutoff=0.6)
            hint = f"; close names: {near}" if near else ""
            raise ChannelError(
                f"{path}: channel {name!r} not found in the log ({len(known)} "
                f"channels; aeroid.list_channels lists them){hint}"
            )
