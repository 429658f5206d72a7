"""Autopilot flight logs: PX4 ULog and ArduPilot DataFlash (binary, text) read into a `FlightLog`.

The optional readers (pyulog, pymavlink) are imported on first use; a missing one
is reported by `_missing` with the install command.
"""

from __future__ import annotations

import contextlib
import io
import re
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
    for d in ulog.data_list:
        topic = d.name
        if d.multi_id:
            topic = f"{d.name}_{d.multi_id}"
            if topic in topics:  # a real topic already has that name
                topic = f"{d.name}#{d.multi_id}"
        stamps = np.asarray(d.data["timestamp"])
        time = stamps.astype(np.float64) / 1e6
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
    metadata: dict[str, Any] = {"source": path.name, "format": "ulog", "info": info}
    if said.getvalue().strip():
        metadata["warnings"] = said.getvalue().strip()
    if "corruption detected while reading file definitions" in said.getvalue():
        # topics whose format could not be parsed are missing, not absent from the flight
        metadata["corrupt"] = "its message definitions are corrupt (pyulog could not parse them)"
    return FlightLog(channels, tuple(events), metadata)


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
    if said.getvalue().strip():
        metadata["warnings"] = said.getvalue().strip()
    if "corruption detected while reading file definitions" in said.getvalue():
        # topics whose format could not be parsed are missing, not absent from the flight
        metadata["corrupt"] = "its message definitions are corrupt (pyulog could not parse them)"
    return FlightLog(channels, tuple(events), metadata)


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
