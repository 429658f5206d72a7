"""Autopilot flight logs: PX4 ULog and ArduPilot DataFlash (binary, text) read into a `FlightLog`.

The optional readers (pyulog, pymavlink) are imported on first use; a missing one
is reported by `_missing` with the install command.
"""

from __future__ import annotations

import contextlib
import io
import math
import re
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError
from ._logtypes import FlightLog, LogChannel, LogEvent

FloatArray = NDArray[np.float64]


def _missing(library: str, path: Path) -> DataFormatError:
    return DataFormatError(
        f"{path}: reading this log needs {library}, which is not installed: "
        'pip install "aeroid[logs]"'
    )


# -- PX4 ULog -----------------------------------------------------------------------

# Units of PX4 fields, stated only where PX4's message definitions fix them.
_PX4_UNITS: tuple[tuple[str, str], ...] = (
    (r"sensor_combined\.gyro_rad\[\d\]", "rad/s"),  # before the generic "_rad"
    (r"vehicle_imu\.delta_angle\[\d\]", "rad"),
    (r"vehicle_imu\.delta_velocity\[\d\]", "m/s"),
    (r"vehicle_angular_velocity\.xyz\[\d\]", "rad/s"),
    (r"vehicle_angular_acceleration\.xyz\[\d\]", "rad/s^2"),
    (r"sensor_gyro\.[xyz]", "rad/s"),
    (r"sensor_accel\.[xyz]", "m/s^2"),
    (r"vehicle_rates_setpoint\.(roll|pitch|yaw)", "rad/s"),
    (r"vehicle_attitude_setpoint\.(roll|pitch|yaw)_body", "rad"),
    (r"vehicle_local_position\.[xyz]", "m"),
    (r"vehicle_local_position\.v[xyz]", "m/s"),
    (r"vehicle_local_position\.a[xyz]", "m/s^2"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_rad_s(\[\d+\])?", "rad/s"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_rad(\[\d+\])?", "rad"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_m_s2(\[\d+\])?", "m/s^2"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_m_s(\[\d+\])?", "m/s"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_pa(\[\d+\])?", "Pa"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_(celsius|celcius)(\[\d+\])?", "degC"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_ga(\[\d+\])?", "gauss"),
    (r"[a-z0-9_]+\.voltage[a-z0-9_]*_v(\[\d+\])?", "V"),
    (r"[a-z0-9_]+\.current[a-z0-9_]*_a(\[\d+\])?", "A"),
    (r"[a-z0-9_]+\.[a-z0-9_]*_(meter|m)(\[\d+\])?", "m"),
    # PX4's message definitions: every timestamp field counts microseconds
    (r"[a-z0-9_]+\.timestamp(_[a-z0-9_]+)?", "us"),
)


_PX4_UNIT_RULES = tuple((re.compile(p), u) for p, u in _PX4_UNITS)


# vehicle_status.nav_state values (PX4 msg/vehicle_status.msg).
_PX4_NAV_STATES = {
    0: "MANUAL",
    1: "ALTCTL",
    2: "POSCTL",
    3: "AUTO_MISSION",
    4: "AUTO_LOITER",
    5: "AUTO_RTL",
    8: "AUTO_LANDENGFAIL",
    10: "ACRO",
    12: "DESCEND",
    13: "TERMINATION",
    14: "OFFBOARD",
    15: "STAB",
    17: "AUTO_TAKEOFF",
    18: "AUTO_LAND",
    19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND",
    21: "ORBIT",
    22: "AUTO_VTOL_TAKEOFF",
}


def _px4_unit(topic: str, field: str) -> str:
    key = f"{topic}.{field}"
    for rule, unit in _PX4_UNIT_RULES:
        if rule.fullmatch(key):
            return unit
    return ""


def _transitions(time: FloatArray, values: NDArray[Any]) -> list[tuple[float, Any]]:
    """(time, value) at the first sample and wherever the value changes."""
    if values.size == 0:
        return []
    change = np.flatnonzero(values[1:] != values[:-1]) + 1
    idx = np.concatenate([[0], change])
    return [(float(time[i]), values[i].item()) for i in idx]


def _read_ulog(path: Path) -> FlightLog:
    try:
        from pyulog import ULog
    except ImportError:
        raise _missing("pyulog", path) from None
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):
            ulog = ULog(str(path))
    except Exception as exc:  # pyulog raises many types for a corrupt file
        raise DataFormatError(f"{path}: not a readable ULog file ({exc})") from None
    if not ulog.data_list:
        first = said.getvalue().strip().split("\n", 1)[0]
        raise DataFormatError(
            f"{path}: the ULog holds no data messages (truncated or corrupt?)"
            + (f"; pyulog says: {first}" if first else "")
        )
    topics = {d.name for d in ulog.data_list}
    channels: dict[str, LogChannel] = {}
    events: list[LogEvent] = []
    stamps_used: dict[str, str] = {}
    for d in ulog.data_list:
        topic = d.name
        if d.multi_id:
            topic = f"{d.name}_{d.multi_id}"
            if topic in topics:  # a real topic already has that name
                topic = f"{d.name}#{d.multi_id}"
        if "timestamp" not in d.data:
            raise DataFormatError(
                f"{path}: ULog topic {topic!r} has no 'timestamp' field (fields "
                f"{sorted(d.data)[:8]}); a damaged format definition?"
            )
        stamp = _ulog_stamp(d.data)
        stamps_used[topic] = stamp
        time = np.asarray(d.data[stamp]).astype(np.float64) / 1e6
        for field, raw in d.data.items():
            if field == "timestamp" or np.asarray(raw).dtype.kind not in "fiub":
                continue
            name = f"{topic}.{field}"
            channels[name] = LogChannel(name, time, raw, _px4_unit(d.name, field))
        if d.name == "vehicle_status" and "nav_state" in d.data:
            for t, state in _transitions(time, np.asarray(d.data["nav_state"])):
                label = _PX4_NAV_STATES.get(int(state), "UNKNOWN")
                events.append(LogEvent(t, "mode", f"{label} (nav_state {int(state)})"))
        if d.name == "vehicle_control_mode":
            for field, raw in d.data.items():
                if "sysid" in field:
                    for t, on in _transitions(time, np.asarray(raw)):
                        events.append(LogEvent(t, "sysid", f"{field}={int(on)}"))
    for m in ulog.logged_messages:
        events.append(LogEvent(m.timestamp / 1e6, "message", f"[{m.log_level_str()}] {m.message}"))
    for drop in ulog.dropouts:
        events.append(LogEvent(drop.timestamp / 1e6, "dropout", f"{drop.duration} ms lost"))
    info = {k: v for k, v in ulog.msg_info_dict.items() if isinstance(v, (str, int, float))}
    metadata: dict[str, Any] = {
        "source": path.name,
        "format": "ulog",
        "info": info,
        "stamps": stamps_used,
    }
    if ulog.file_corruption:
        # pyulog skipped damaged bytes: samples are missing that no dropout message names
        warnings.warn(
            f"{path}: pyulog found the file corrupt and skipped damaged data; samples are "
            "missing (aeroid.check_data_quality shows where)",
            UserWarning,
            stacklevel=5,  # here, a lambda, read_selected, read_log, its caller
        )
        start = float(ulog.start_timestamp) / 1e6
        events.insert(0, LogEvent(start, "corruption", "file corrupt: damaged data skipped"))
        metadata["file_corruption"] = True
    return _finished_log(channels, events, metadata, said.getvalue())


def _ulog_stamp(data: Mapping[str, Any]) -> str:
    """The field a topic's samples are stamped with: PX4's ``timestamp_sample`` (when the
    sensor sampled, the time its estimator and controllers use) where the topic has it,
    set on every message and rising; else ``timestamp`` (when the message was published,
    up to a whole sensor period later: 20 ms for the barometer). A topic published twice
    per sample (PX4's actuator_controls_1) keeps its publication stamps."""
    sample = data.get("timestamp_sample")
    if sample is not None:
        sample = np.asarray(sample)
        if (
            sample.size
            and sample.dtype.kind in "iu"
            and bool(np.all(sample > 0))
            and bool(np.all(np.diff(sample.astype(np.int64)) > 0))
        ):
            return "timestamp_sample"
    return "timestamp"


# -- ArduPilot DataFlash --------------------------------------------------------------

# struct codes of pymavlink's DFFormat.msg_struct as numpy dtypes (little-endian)
_STRUCT_DTYPE = {
    "b": "i1",
    "B": "u1",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "q": "<i8",
    "Q": "<u8",
    "f": "<f4",
    "d": "<f8",
    "e": "<f2",
}


_NOT_CHANNELS = {"FMT", "FMTU", "UNIT", "MULT"}


def _finished_log(
    channels: dict[str, LogChannel],
    events: list[LogEvent],
    metadata: dict[str, Any],
    said: str,
) -> FlightLog:
    """The log a reader built, with what its parser printed (`said`) in the metadata."""
    if said.strip():
        metadata["warnings"] = said.strip()
    if "corruption detected while reading file definitions" in said:
        # topics whose format could not be parsed are missing, not absent from the flight
        metadata["corrupt"] = "its message definitions are corrupt (pyulog could not parse them)"
    return FlightLog(channels, tuple(events), metadata)


def _df_dtype(fmt: Any) -> np.dtype[Any]:
    """A numpy record dtype for one DataFlash message body (strings kept as bytes)."""
    fields = []
    codes = re.findall(r"(\d*)([a-zA-Z?])", fmt.msg_struct.lstrip("<"))
    for column, (count, code) in zip(fmt.columns, codes, strict=False):
        if code == "s":
            fields.append((column, f"S{int(count)}"))
        else:
            fields.append((column, _STRUCT_DTYPE[code]))
    return np.dtype(fields)


def _df_time(fmt: Any, values: Mapping[str, NDArray[Any]]) -> FloatArray | None:
    if "TimeUS" in values:
        return np.asarray(values["TimeUS"], dtype=np.float64) / 1e6
    if "TimeMS" in values:
        return np.asarray(values["TimeMS"], dtype=np.float64) / 1e3
    return None


def _df_unit(fmt: Any, column: str) -> str:
    try:
        return str(fmt.get_unit(column) or "")
    except (AttributeError, IndexError, TypeError):
        return ""


def _df_channels(
    fmt: Any, values: Mapping[str, NDArray[Any]], channels: dict[str, LogChannel]
) -> bool:
    """Add the numeric columns of one message type; False when it has no time stamp."""
    time = _df_time(fmt, values)
    if time is None:
        return False
    numeric = [
        c for c in fmt.columns if c not in ("TimeUS", "TimeMS") and values[c].dtype.kind in "fiub"
    ]
    inst = fmt.instance_field
    groups: list[tuple[str, NDArray[np.bool_] | None]] = [(fmt.name, None)]
    if inst is not None and inst in values and values[inst].dtype.kind in "fiub":
        ids = np.asarray(values[inst])
        groups = [
            (fmt.name if int(i) == 0 else f"{fmt.name}[{int(i)}]", ids == i) for i in np.unique(ids)
        ]
    for prefix, mask in groups:
        t = time if mask is None else time[mask]
        for c in numeric:
            v = values[c] if mask is None else values[c][mask]
            name = f"{prefix}.{c}"
            channels[name] = LogChannel(name, t, v, _df_unit(fmt, c))
    return True


def _df_events(reader: Any) -> list[LogEvent]:
    """MODE changes, text messages (MSG) and event codes (EV) of a DataFlash log."""
    events: list[LogEvent] = []
    reader.rewind()
    while True:
        m = reader.recv_match(type=["MODE", "MSG", "EV", "ERR"])
        if m is None:
            break
        kind = m.get_type()
        stamp = getattr(m, "TimeUS", None)
        t = stamp / 1e6 if stamp is not None else float(getattr(m, "TimeMS", 0)) * 1e-3
        if kind == "MODE":
            number = getattr(m, "ModeNum", getattr(m, "Mode", ""))
            events.append(LogEvent(t, "mode", f"{reader.flightmode} (mode {number})"))
        elif kind == "MSG":
            events.append(LogEvent(t, "message", str(getattr(m, "Message", ""))))
        elif kind == "EV":
            events.append(LogEvent(t, "event", f"EV {getattr(m, 'Id', '')}"))
        else:
            events.append(
                LogEvent(
                    t,
                    "error",
                    f"ERR subsystem {getattr(m, 'Subsys', '')} code {getattr(m, 'ECode', '')}",
                )
            )
    return events


def _read_dataflash(path: Path, *, text: bool) -> FlightLog:
    try:
        from pymavlink import DFReader
    except ImportError:
        raise _missing("pymavlink", path) from None
    base = DFReader.DFReader_text if text else DFReader.DFReader_binary

    class Reader(base):  # type: ignore[misc, valid-type]
        def init_clock(self) -> None:
            # Times come from each message's TimeUS; pymavlink's search for a GPS
            # clock would parse every message in Python when the log has no GPS.
            self._rewind(keep_messages=True)
            self.clock = DFReader.DFReaderClock_usec()

    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        try:
            reader = Reader(str(path), zero_time_base=True)
        except Exception as exc:  # pymavlink raises many types for a corrupt file
            raise DataFormatError(f"{path}: not a readable DataFlash log ({exc})") from None
        try:
            channels: dict[str, LogChannel] = {}
            untimed: list[str] = []
            try:
                collected = _df_collect_text(reader) if text else _df_collect_binary(reader)
            except DataFormatError as exc:
                raise DataFormatError(f"{path}: {exc}") from None
            # Units are final only once every FMTU message has been read.
            for fmt, values in collected:
                if not _df_channels(fmt, values, channels):
                    untimed.append(fmt.name)
            events = _df_events(reader)
            params = {str(k): float(v) for k, v in reader.params.items()}
        finally:
            with contextlib.suppress(Exception):
                reader.close()
    if not channels:
        raise DataFormatError(
            f"{path}: the DataFlash log holds no time-stamped messages (truncated or corrupt?)"
        )
    metadata: dict[str, Any] = {
        "source": path.name,
        "format": "dataflash-text" if text else "dataflash",
        "parameters": params,
    }
    if untimed:
        metadata["untimed_messages"] = sorted(set(untimed))
    return _finished_log(channels, events, metadata, said.getvalue())


def _df_collect_binary(reader: Any) -> list[tuple[Any, dict[str, NDArray[Any]]]]:
    """Decode each message type in bulk from the byte offsets pymavlink indexed."""
    out = []
    data = np.frombuffer(reader.data_map, dtype=np.uint8)
    try:
        for mtype, offsets in enumerate(reader.offsets):
            fmt = reader.formats.get(mtype)
            if fmt is None or not offsets or fmt.name in _NOT_CHANNELS:
                continue
            dtype = _df_dtype(fmt)
            body = dtype.itemsize
            declared = int(getattr(fmt, "len", body + 3))
            if declared != body + 3:
                # pymavlink steps through the log by the declared length: a wrong one
                # drops or garbles messages without a word
                raise DataFormatError(
                    f"message {fmt.name}: its FMT record declares {declared} bytes, but its "
                    f"format {fmt.format!r} packs {body + 3}; the log is corrupt"
                )
            offs = np.asarray(offsets, dtype=np.int64) + 3
            offs = offs[offs + body <= data.size]  # a message cut off at the end of the file
            rows = np.empty((offs.size, body), dtype=np.uint8)
            span = np.arange(body)
            step = max(1, (1 << 22) // max(body, 1))  # about 4 MB of bytes per gather
            for start in range(0, offs.size, step):
                chunk = offs[start : start + step]
                rows[start : start + chunk.size] = data[chunk[:, None] + span]
            records = rows.view(dtype).ravel()
            values: dict[str, NDArray[Any]] = {}
            for i, column in enumerate(fmt.columns):
                col = records[column]
                mult = fmt.msg_mults[i]
                if col.dtype.kind in "fiu":
                    col = col.astype(np.float64)
                    if mult is not None:
                        # as pymavlink does: divide by 1/mult for accuracy (1e-7 is inexact)
                        col = col / (1.0 / mult) if 0.0 < mult < 1.0 else col * mult
                values[column] = col
            out.append((fmt, values))
    finally:
        del data
    return out


def _df_collect_text(reader: Any) -> list[tuple[Any, dict[str, NDArray[Any]]]]:
    """Read every line of a text DataFlash log through pymavlink, per message type."""
    rows: dict[str, list[list[Any]]] = {}
    formats: dict[str, Any] = {}
    reader.rewind()
    while True:
        m = reader.recv_msg()
        if m is None:
            break
        name = m.get_type()
        if name in _NOT_CHANNELS:
            continue
        formats[name] = m.fmt
        rows.setdefault(name, []).append([getattr(m, c) for c in m.fmt.columns])
    out = []
    for name, table in rows.items():
        fmt = reader.formats.get(name, formats[name])
        values: dict[str, NDArray[Any]] = {}
        for i, column in enumerate(fmt.columns):
            cells = [r[i] if i < len(r) else None for r in table]
            if all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in cells):
                values[column] = np.asarray(cells, dtype=np.float64)
            else:
                values[column] = np.asarray([str(c) for c in cells])
        out.append((fmt, values))
    return out


# -- a whole log on one grid -----------------------------------------------------------


def _usable_run(src: Any, rate: float, max_gap: float | None) -> tuple[float, float, bool]:
    """The longest stretch of a cleaned channel the resampler takes at `rate` without a
    refused gap, as (start, end, cut): cut is True when a gap shortened it.

    A side that a gap bounds is pulled in by the anti-aliasing filter's half length
    (and half a step), since the resampler checks for gaps that far outside its grid.
    """
    from ._regrid import _SAME_RATE, GAP_STEPS, design_anti_alias

    time = src.time
    limit = GAP_STEPS * src.step if max_gap is None else max_gap
    cuts = np.flatnonzero(np.diff(time) > limit)
    if not cuts.size:
        return float(time[0]), float(time[-1]), False
    first = np.concatenate([[0], cuts + 1])
    last = np.concatenate([cuts, [time.size - 1]])
    best = int(np.argmax(time[last] - time[first]))
    start, end = float(time[first[best]]), float(time[last[best]])
    source_rate = 1.0 / src.step
    edge = 0.5 * src.step
    if source_rate > _SAME_RATE * rate:
        edge += float(design_anti_alias(source_rate, rate)[1]["edge_s"])
    if best > 0:
        start += edge
    if best < cuts.size:
        end -= edge
    return start, end, True


def _best_span(
    runs: Mapping[Any, tuple[float, float]], rate: float, t0: float | None, t1: float | None
) -> tuple[float, float]:
    """The span [a, b] that makes the most topic-seconds: topics covering it times its
    length (see `_whole_log_plan`); `t0`/`t1`, where given, fix its ends."""
    starts = np.array([r[0] for r in runs.values()])
    ends = np.array([r[1] for r in runs.values()])
    if t0 is not None:
        starts = np.maximum(starts, t0)
    if t1 is not None:
        ends = np.minimum(ends, t1)
    a_all = np.unique(starts) if t0 is None else np.array([t0])
    b_all = np.unique(ends) if t1 is None else np.array([t1])
    best, span = 0.0, (math.nan, math.nan)
    for a in a_all:  # topics x candidates per start: no cube of booleans for a big log
        kept = np.sort(ends[starts <= a])
        covering = kept.size - np.searchsorted(kept, b_all, side="left")
        length = b_all - a
        score = np.where(length * rate >= 1.0, covering * length, 0.0)
        j = int(np.argmax(score))
        if score[j] > best:
            best, span = float(score[j]), (float(a), float(b_all[j]))
    if not best > 0:
        raise DataFormatError(
            f"no span of two samples at {rate:g} Hz is covered by any channel without a gap"
        )
    return span


def _whole_log_plan(
    log: FlightLog, rate: float, max_gap: float | None, t0: float | None, t1: float | None
) -> tuple[dict[str, str], float, float, dict[str, str]]:
    """The channels of a whole log that go on one grid at `rate`, the span, and the reason
    each other channel is left out.

    The span is the one that the most topics cover for the longest: the [a, b], with a
    a topic's start and b a topic's end, that maximises (topics covering it) x (b - a).
    Topics count, not channels: a topic's fields share its stamps, and a topic of a
    hundred fields logged once would otherwise choose the span. The intersection of
    every channel would be set by the shortest (a topic logged only around an event),
    the union would leave most channels short of it; the product keeps the longest
    span that most of the log covers, and gives up a topic only where its loss buys
    more length than it costs. A channel covers the span when its longest stretch
    without a gap the resampler refuses (`max_gap`, default 5 median steps) does.
    """
    from ._regrid import clean_source

    left: dict[str, str] = {}
    chan_run: dict[str, tuple[float, float, bool]] = {}
    topic_run: dict[tuple[str, int, float, float], tuple[float, float, bool]] = {}
    for name, channel in log.channels.items():
        time = channel.time
        if np.unique(time).size < 2:
            left[name] = "one sample"
            continue
        if not np.all(np.isfinite(channel.values)):
            left[name] = "NaN or inf"
            continue
        # a topic's fields share its stamps: its run is found once
        key = (name.partition(".")[0], int(time.size), float(time[0]), float(time[-1]))
        if key not in topic_run:
            try:
                start, end, cut = _usable_run(clean_source(name, channel), rate, max_gap)
            except DataFormatError:
                start, end, cut = math.nan, math.nan, True  # a clock that steps back
            topic_run[key] = (start, end, cut)
        chan_run[name] = topic_run[key]
    usable = {k: v[:2] for k, v in topic_run.items() if v[1] > v[0]}
    if not usable:
        raise DataFormatError("no channel of the log can be resampled")
    a, b = _best_span(usable, rate, t0, t1)
    mapping: dict[str, str] = {}
    for name, (start, end, cut) in chan_run.items():
        time = log.channels[name].time
        if math.isnan(start):
            left[name] = "stamps step back"
        elif start <= a and end >= b:
            mapping[name] = name
        elif cut and time[0] <= a and time[-1] >= b:
            left[name] = "a gap in the span"
        else:
            left[name] = "outside the span"
    return mapping, a, b, left
