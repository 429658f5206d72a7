"""Channel maps: log (or table) channels to model names, with unit conversions and windows.

A flight log names its signals after the autopilot's topics and records them
in the autopilot's units (``vehicle_angular_velocity.xyz[0]`` in rad/s,
ArduPilot's ``ATT.Roll`` in degrees, an RC channel in microseconds); a model
wants ``p`` in rad/s and ``delta_a`` in rad. A `ChannelMap` says, per model
name, which channel to read and how to convert it; `load_mapped` reads a
file, cuts the manoeuvre window and applies the map, recording every choice
in the record's metadata as plain JSON.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._records import FrozenState
from .._units import UNIT_CONVERSIONS
from ..errors import ChannelError, DataFormatError
from ._channel_pairs import orient_pairs, plain_pairs
from ._logtypes import FlightLog
from .data import FlightData, load_flight_test, plain
from .resampling import close_names

__all__ = [
    "UNIT_CONVERSIONS",
    "ChannelMap",
    "ChannelSpec",
    "apply_channel_map",
    "flight_windows",
    "load_mapped",
    "resolve_window",
]

# the keys a window or segments mapping may hold, and the `segment` keywords they feed
_WINDOW_KEYS = frozenset({"mode", "events", "index"})
_SEGMENT_KEYS = frozenset(
    {
        "inputs",
        "mode",
        "events",
        "margin",
        "threshold",
        "min_duration",
        "merge_gap",
        "trim_window",
        "energy_window",
        "noise_floor",
    }
)


def _known_units() -> str:
    return ", ".join(sorted(UNIT_CONVERSIONS))


def unit_conversion(unit: str) -> tuple[float, str]:
    """(factor to SI, SI unit) of a source unit; `DataFormatError` listing the known ones."""
    try:
        return UNIT_CONVERSIONS[unit]
    except (KeyError, TypeError):
        near = close_names(str(unit), list(UNIT_CONVERSIONS))
        hint = f"; did you mean {near}?" if near else ""
        raise DataFormatError(
            f"unit {unit!r}: no known conversion{hint} (known units: {_known_units()})"
        ) from None


def _number(value: Any, what: str) -> float:
    try:
        out = float(value)
        ok = not isinstance(value, bool) and math.isfinite(out)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DataFormatError(f"{what}: expected a finite number, got {plain(value)}")
    return out


@dataclass(frozen=True)
class ChannelSpec(FrozenState):
    """How one model channel is made: ``sign * scale * factor * raw + offset``.

    Attributes
    ----------
    name : str
        Model name (``p``).
    channel : str
        Channel of the log or column of the table (``vehicle_angular_velocity.xyz[0]``).
    unit : str or None
        The channel's unit in the file, converted to SI (see `UNIT_CONVERSIONS`);
        None: no conversion.
    scale : float
        Extra factor (a gearing, a calibration; ``-1`` flips the sign).
    offset : float
        Added last, in the model's units (removes a trim or a sensor bias).
    sign : {1, -1}
        Sign convention flip.
    """

    name: str
    channel: str
    unit: str | None = None
    scale: float = 1.0
    offset: float = 0.0
    sign: int = 1

    def __post_init__(self) -> None:
        for label in ("name", "channel"):
            value = getattr(self, label)
            if not isinstance(value, str) or not value:
                raise DataFormatError(
                    f"channel map: {label}: expected a non-empty string, got {value!r}"
                )
        if self.unit is not None:
            unit_conversion(self.unit)
        object.__setattr__(self, "scale", _number(self.scale, f"channel map {self.name!r}: scale"))
        object.__setattr__(
            self, "offset", _number(self.offset, f"channel map {self.name!r}: offset")
        )
        if isinstance(self.sign, bool) or self.sign not in (1, -1):
            raise DataFormatError(
                f"channel map {self.name!r}: sign: expected 1 or -1, got {self.sign!r}"
            )
        object.__setattr__(self, "sign", int(self.sign))

    @property
    def factor(self) -> float:
        """The whole factor applied to the raw values."""
        unit_factor = 1.0 if self.unit is None else UNIT_CONVERSIONS[self.unit][0]
        return self.sign * self.scale * unit_factor

    def converted_unit(self, stated: str) -> str:
        """The unit of the model channel: SI after a conversion, else the file's when unscaled."""
        if self.unit is not None:
            return UNIT_CONVERSIONS[self.unit][1]
        return stated if abs(self.scale) == 1.0 else ""

    def to_json(self) -> dict[str, Any]:
        """The choices as plain JSON."""
        return {
            "channel": self.channel,
            "unit": self.unit,
            "scale": self.scale,
            "offset": self.offset,
            "sign": self.sign,
        }


def _entry(name: str, value: Any) -> ChannelSpec:
    if isinstance(value, ChannelSpec):
        return (
            value
            if value.name == name
            else ChannelSpec(name, value.channel, value.unit, value.scale, value.offset, value.sign)
        )
    if isinstance(value, str):
        return ChannelSpec(name, value)
    if hasattr(value, "model_dump"):  # a pydantic options model from a campaign config
        value = value.model_dump()
    if not isinstance(value, Mapping):
        raise DataFormatError(
            f"channel map {name!r}: expected a channel name or a mapping with 'channel' "
            f"(and optionally unit, scale, offset, sign), got {type(value).__name__}"
        )
    unknown = sorted(set(value) - {"channel", "unit", "scale", "offset", "sign"})
    if unknown:
        raise DataFormatError(
            f"channel map {name!r}: unknown keys {unknown}; allowed: channel, unit, scale, offset, sign"
        )
    if "channel" not in value:
        raise DataFormatError(f"channel map {name!r}: 'channel' (the log channel) is missing")
    given = {k: v for k, v in value.items() if v is not None}
    return ChannelSpec(name, **given)


@dataclass(frozen=True)
class ChannelMap(FrozenState):
    """Model channels made from a file's channels (see `ChannelSpec`), in order.

    Build one with `ChannelMap.from_config` from what a campaign config
    holds: ``{model_name: channel}`` or ``{model_name: {channel: ..., unit:
    "deg/s", scale: ..., offset: ..., sign: -1}}``, or a list of names kept
    as they are. (`from_config` has no file to look at, so it reads a plain map
    ``{model_name: channel}``; the readers of a file, `load_flight_test`,
    `load_mapped`, `apply_channel_map` and a campaign's flights, also take it
    written ``{channel: model_name}``, the side naming the file's channels being
    the channel side, and refuse a map that reads both ways.)
    """

    entries: tuple[ChannelSpec, ...]

    def __post_init__(self) -> None:
        entries = tuple(self.entries)
        if not entries:
            raise DataFormatError("channel map: no channel chosen")
        names = [e.name for e in entries]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise DataFormatError(f"channel map: model names {twice} are given twice")
        object.__setattr__(self, "entries", entries)

    @classmethod
    def from_config(cls, mapping: Any) -> ChannelMap:
        """A map from a mapping of model name to channel (or entry), or a list of names."""
        if isinstance(mapping, ChannelMap):
            return mapping
        if isinstance(mapping, str):
            mapping = [mapping]
        if isinstance(mapping, Mapping):
            entries = []
            for name, value in mapping.items():
                if not isinstance(name, str) or not name:
                    raise DataFormatError(
                        f"channel map: model name {name!r}: expected a non-empty string"
                    )
                entries.append(_entry(name, value))
            return cls(tuple(entries))
        if isinstance(mapping, Sequence):
            return cls(tuple(_entry(str(n), str(n)) for n in mapping))
        raise DataFormatError(
            "channel map: expected a mapping of model name to channel or a list of channel "
            f"names, got {type(mapping).__name__}"
        )

    @property
    def names(self) -> tuple[str, ...]:
        """Model names, in order."""
        return tuple(e.name for e in self.entries)

    @property
    def sources(self) -> tuple[str, ...]:
        """The file's channels read, each once, in order."""
        return tuple(dict.fromkeys(e.channel for e in self.entries))

    def to_json(self) -> dict[str, Any]:
        """``{model_name: {channel, unit, scale, offset, sign}}``, plain JSON."""
        return {e.name: e.to_json() for e in self.entries}


def orient(mapping: Any, available: Sequence[str], *, where: str = "channels") -> Any:
    """A plain ``{str: str}`` mapping turned ``{model_name: channel}``, read the way
    round `available` (the file's channels) decides (`aeroid.io._channel_pairs`: one
    rule for every reader; a map that reads both ways is refused). Other forms are
    returned as they are, and missing channels are left for the caller to name.
    """
    pairs = plain_pairs(mapping)
    if pairs is None:
        return mapping
    return orient_pairs(pairs, set(available), where)[0]


def _missing(name: str, available: Sequence[str], where: str) -> ChannelError:
    near = close_names(name, available)
    hint = f"; close names: {near}" if near else ""
    return ChannelError(
        f"{where}: channel {name!r} not found ({len(available)} channels; "
        f"aeroid.list_channels lists a log's){hint}"
    )


def apply_channel_map(data: FlightData, mapping: Any) -> FlightData:
    """Make model channels from a record's channels: pick, convert, rename.

    Parameters
    ----------
    data : FlightData
        A record whose channels carry the file's names (as `load_flight_test`
        gives them without a mapping).
    mapping : ChannelMap, mapping or sequence
        See `ChannelMap.from_config`: ``{model_name: channel}``,
        ``{model_name: {channel, unit, scale, offset, sign}}`` or a list. A
        mapping of plain strings may also be written ``{channel: model_name}``:
        the side naming the record's channels is the channel side, and one that
        names them on both sides (a swap, a cycle) is refused.

    Returns
    -------
    FlightData
        The model channels only, with the units after conversion (SI where a
        ``unit`` was converted; the file's unit where neither a conversion nor
        a scale changed it) and ``metadata["channel_map"]`` recording every
        choice (plain JSON).

    Raises
    ------
    ChannelError
        A channel the record lacks (naming close names).
    DataFormatError
        An unknown unit (listing the known ones), a bad scale, offset or sign.
    """
    cmap = ChannelMap.from_config(
        orient(mapping, data.names, where=str(data.metadata.get("source", "flight data")))
    )
    where = str(data.metadata.get("source", "flight data"))
    channels: dict[str, Any] = {}
    units: dict[str, str] = {}
    for e in cmap.entries:
        if e.channel not in data.channels:
            raise _missing(e.channel, list(data.names), where)
        stated = data.units.get(e.channel, "")
        if e.unit is not None and stated in UNIT_CONVERSIONS and stated != e.unit:
            # the log says what its channel holds: a map that disagrees is a mistake
            # that would scale the channel silently (deg/s applied to a rad/s channel)
            raise DataFormatError(
                f"{where}: channel map {e.name!r}: unit {e.unit!r} contradicts the unit "
                f"{stated!r} the file states for {e.channel!r}; drop the unit or fix it"
            )
        channels[e.name] = e.factor * data.channels[e.channel] + e.offset
        unit = e.converted_unit(stated)
        if unit:
            units[e.name] = unit
    meta = {**dict(data.metadata), "channel_map": cmap.to_json()}
    return FlightData(data.time, channels, units, meta)


# -- windows ----------------------------------------------------------------------


def _window_pair(window: Sequence[Any]) -> tuple[float, float]:
    if len(window) != 2:
        raise DataFormatError(f"window: expected [t0, t1] in seconds, got {list(window)!r}")
    t0 = _number(window[0], "window t0")
    t1 = _number(window[1], "window t1")
    if not t1 > t0:
        raise DataFormatError(
            f"window: [{plain(t0)}, {plain(t1)}] s is inverted or empty; need t1 > t0"
        )
    return t0, t1


def _as_dict(value: Any) -> Any:
    return value.model_dump(exclude_none=True) if hasattr(value, "model_dump") else value


def _check_keys(value: Any, option: str, expected: str, keys: frozenset[str]) -> None:
    """Refuse a config option that is not a mapping of `keys` (`expected` words what is)."""
    if not isinstance(value, Mapping):
        raise DataFormatError(f"{option}: expected {expected}, got {value!r}")
    unknown = sorted(set(value) - keys)
    if unknown:
        raise DataFormatError(f"{option}: unknown keys {unknown}; allowed: {sorted(keys)}")


def resolve_window(record: Any, window: Any) -> tuple[float, float, dict[str, Any]]:
    """``(t0, t1, record of how)`` for a window spec on a log or record.

    `window` is ``[t0, t1]`` seconds in the log's time, or ``{mode: value}``
    / ``{events: [start, end]}`` (see `aeroid.segment`), optionally with
    ``index`` choosing among several windows found (required when there are
    several).
    """
    window = _as_dict(window)
    if isinstance(window, (tuple, list)):
        t0, t1 = _window_pair(window)
        return t0, t1, {"t0": t0, "t1": t1, "way": "time"}
    _check_keys(
        window,
        "window",
        "[t0, t1] or {mode: ...} / {events: [start, end]}",
        _WINDOW_KEYS,
    )
    from .segmentation import segment

    kwargs: dict[str, Any] = {}
    if window.get("mode") is not None:
        kwargs["mode"] = window["mode"]
    if window.get("events") is not None:
        kwargs["events"] = tuple(window["events"])
    if not kwargs:
        raise DataFormatError("window: give mode: ... or events: [start, end]")
    found = segment(record, margin=0.0, min_duration=0.0, **kwargs).windows
    index = window.get("index")
    spec = {k: list(v) if isinstance(v, tuple) else v for k, v in kwargs.items()}
    listed = [[round(w.t0, 6), round(w.t1, 6)] for w in found]
    if not found:
        raise DataFormatError(f"window: {spec} matches no part of the log")
    if index is None and len(found) > 1:
        raise DataFormatError(
            f"window: {spec} matches {len(found)} windows {listed}; choose one with index: ..."
        )
    i = 0 if index is None else int(index)
    if not -len(found) <= i < len(found):
        raise DataFormatError(f"window: index {i} is out of range; {spec} matches {listed}")
    w = found[i]
    return (
        w.t0,
        w.t1,
        {
            "t0": w.t0,
            "t1": w.t1,
            "way": "mode" if "mode" in kwargs else "events",
            **spec,
            "index": i,
        },
    )


def _spans(log: Any, names: Sequence[str]) -> tuple[float, float]:
    """The time span every one of the log's `names` covers."""
    lo = max(float(log.channels[n].time[0]) for n in names)
    hi = min(float(log.channels[n].time[-1]) for n in names)
    return lo, hi


def _fit_window(
    t0: float, t1: float, record: dict[str, Any], lo: float, hi: float, where: str
) -> tuple[float, float]:
    """A found window (mode, events) clipped to the channels' span [lo, hi], as
    `flight_windows` clips it; a window in seconds must lie inside it."""
    if record.get("way") == "time":
        _check_inside(t0, t1, lo, hi, where)
        return t0, t1
    a, b = max(t0, lo), min(t1, hi)
    if not b > a:
        raise DataFormatError(
            f"{where}: window [{t0:.6g}, {t1:.6g}] s does not overlap the span "
            f"[{lo:.6g}, {hi:.6g}] s that the mapped channels cover"
        )
    if (a, b) != (t0, t1):
        record.update(t0=a, t1=b, found=[t0, t1])
    return a, b


def _check_inside(t0: float, t1: float, lo: float, hi: float, where: str) -> None:
    if t0 < lo or t1 > hi:
        raise DataFormatError(
            f"{where}: window [{t0:.6g}, {t1:.6g}] s is not inside the span "
            f"[{lo:.6g}, {hi:.6g}] s that the mapped channels cover"
        )


_QUALITY_LIMITS = ("jitter_limit", "dropout_factor", "saturation_run", "alias_band", "alias_limit")


def _quality_limits(quality: bool | Mapping[str, float]) -> dict[str, float] | None:
    """The limits of `check_data_quality` that `quality` asks for (None: no check)."""
    if quality is False or quality is None:
        return None
    if quality is True:
        return {}
    if not isinstance(quality, Mapping):
        raise DataFormatError(
            f"quality: expected true, false or a mapping of limits, got {plain(quality)}"
        )
    unknown = sorted(set(quality) - set(_QUALITY_LIMITS))
    if unknown:
        raise DataFormatError(
            f"quality: unknown limit(s) {unknown}; known: {list(_QUALITY_LIMITS)}"
        )
    return dict(quality)


def _quality(
    data: FlightData | FlightLog,
    sources: Sequence[str] | None,
    bounds: tuple[float | None, float | None] | None,
    limits: Mapping[str, Any],
) -> Any:
    """The data-quality report of `sources` (all: None) as read, inside `bounds`, with
    the limits `_quality_limits` checked."""
    from ._logtypes import LogChannel
    from .quality import check_data_quality

    if isinstance(data, FlightLog) and bounds is not None and bounds[0] is not None:
        t0, t1 = float(bounds[0]), float(bounds[1])  # type: ignore[arg-type]
        cut = {}
        for name in sources or list(data.channels):
            c = data.channels[name]
            keep = (c.time >= t0) & (c.time <= t1)
            cut[name] = LogChannel(name, c.time[keep], c.values[keep], c.unit)
        data = FlightLog(cut, data.events, data.metadata)
    return check_data_quality(data, channels=sources, **limits)


def load_mapped(
    path: str | Path,
    channels: Any = None,
    *,
    sample_rate: float | None = None,
    max_gap: float | None = None,
    window: Any = None,
    time_column: str | None = None,
    units: Mapping[str, str] | None = None,
    quality: bool | Mapping[str, float] = False,
    allow_external_data: bool = False,
) -> FlightData:
    """Load a flight file through a channel map, cut to a manoeuvre window.

    Parameters
    ----------
    path : str or Path
        A flight log or a table, as `aeroid.load_flight_test` reads.
    channels : ChannelMap, mapping, sequence or None
        See `apply_channel_map`. A mapping of plain strings reads
        ``{model_name: channel}`` or ``{channel: model_name}``, the side whose
        names are all the file's channels being the channel side (as
        `load_flight_test` reads it; one naming the file's channels on both
        sides is refused); None keeps every channel.
    sample_rate : float, optional
        Logs: the uniform rate (Hz) the channels are resampled to (a table,
        already on one time axis, refuses it).
    max_gap : float, optional
        Logs: the longest gap in a channel's stamps to interpolate across (s).
    window : [t0, t1] or mapping, optional
        The part of the flight to keep: seconds in the log's time, or
        ``{mode: ...}`` / ``{events: [start, end]}`` resolved with
        `aeroid.segment` (``index`` picks one of several) and clipped to the
        span the mapped channels cover (as `flight_windows` clips them; the
        window found is kept as ``metadata["window"]["found"]``). A log resampled
        with `sample_rate` is resampled inside the window only, so gaps
        outside it do not matter.
    time_column : str, optional
        As for `load_flight_test`.
    units : mapping of str to str, optional
        Unit labels per model name, over those the map gives; they label the
        loaded values, so one that contradicts the unit a channel has after
        the map (``deg`` on a channel the map converted to ``rad``) is refused.
    quality : bool or mapping of str to float, optional
        Check the channels read as they arrive (a log's on their own stamps,
        before resampling; inside the window) with `aeroid.check_data_quality`,
        with its default limits (True) or those given (``{"jitter_limit":
        0.05}``), and keep the report in ``metadata["quality"]``.
    allow_external_data : bool, default False
        HDF5 logs: read datasets stored outside the file (see `aeroid.read_log`).

    Returns
    -------
    FlightData
        The model channels with ``metadata["channel_map"]`` and, with a
        window, ``metadata["window"] = {"t0", "t1", "way", ...}``. With a
        plain mapping (or none), no window and no quality check, exactly what
        `load_flight_test` returns.

    Raises
    ------
    ChannelError
        A mapped channel the file lacks (naming close names).
    DataFormatError
        An unknown unit (listing the known ones), a `units` label that
        contradicts a channel's unit after the map, an inverted window, a
        window in seconds outside the mapped channels' span (a mode or events
        window that misses it), a mode or event that
        matches nothing, or anything `load_flight_test` refuses.
    """
    from .logs import read_log, sniff_format

    p = Path(path)
    limits = _quality_limits(quality)
    # a log's quality is checked on its own stamps, before load_flight_test resamples it
    raw_log = limits is not None and p.is_file() and sniff_format(p) is not None
    if (
        window is None
        and not raw_log
        and not allow_external_data
        and (
            channels is None
            or plain_pairs(channels) is not None
            or (isinstance(channels, Sequence) and all(isinstance(m, str) for m in channels))
        )
    ):
        data = load_flight_test(
            p,
            time_column=time_column,
            channels=channels,
            units=units,
            sample_rate=sample_rate,
            max_gap=max_gap,
        )
        if limits is None:
            return data
        report = _quality(data, None, None, limits)
        return FlightData(
            data.time, dict(data.channels), dict(data.units), {**data.metadata, "quality": report}
        )
    if isinstance(window, (tuple, list)):
        _window_pair(window)  # an inverted window is refused before the file is read
    fmt = sniff_format(p) if p.is_file() else None
    if fmt is None:
        # a table refuses sample_rate and max_gap (it is on one time axis already)
        data = load_flight_test(
            p, time_column=time_column, sample_rate=sample_rate, max_gap=max_gap
        )
        cmap = _map_for(channels, data.names, where=p.name)
        for source in cmap.sources:
            if source not in data.channels:
                raise _missing(source, list(data.names), p.name)
        record: dict[str, Any] | None = None
        if window is not None:
            t0, t1, record = resolve_window(data, window)
            t0, t1 = _fit_window(t0, t1, record, float(data.time[0]), float(data.time[-1]), p.name)
            data = data.window(t0, t1)
        report = None if limits is None else _quality(data, cmap.sources, None, limits)
    else:
        log = read_log(
            p, format=fmt, time_column=time_column, allow_external_data=allow_external_data
        )
        cmap = _map_for(channels, list(log.channels), where=p.name)
        for source in cmap.sources:
            if source not in log.channels:
                raise _missing(source, list(log.channels), p.name)
        bounds: tuple[float | None, float | None] = (None, None)
        record = None
        if window is not None:
            t0, t1, record = resolve_window(log, window)
            t0, t1 = _fit_window(t0, t1, record, *_spans(log, cmap.sources), p.name)
            bounds = (t0, t1)
        report = None if limits is None else _quality(log, cmap.sources, bounds, limits)
        data = _log_record(p, log, cmap.sources, sample_rate, max_gap, bounds)
    out = apply_channel_map(data, cmap)
    meta = dict(out.metadata)
    if record is not None:
        meta["window"] = record
    if report is not None:
        meta["quality"] = report
    _refuse_relabel(p.name, out.units, units, cmap)
    return FlightData(out.time, dict(out.channels), {**dict(out.units), **dict(units or {})}, meta)


def _refuse_relabel(
    where: str, made: Mapping[str, str], units: Mapping[str, str] | None, cmap: ChannelMap
) -> None:
    """A `units` label that contradicts the unit a model channel is in after the map
    (rad after a deg conversion) would mislabel the values: refuse it by name."""
    specs = {e.name: e for e in cmap.entries}
    for name, given in dict(units or {}).items():
        now = made.get(name)
        ours, theirs = UNIT_CONVERSIONS.get(str(given)), UNIT_CONVERSIONS.get(str(now))
        if now is None or ours is None or theirs is None or ours == theirs:
            continue
        spec = specs.get(name)
        how = (
            f"the map converts it from {spec.unit!r} to {now!r}"
            if spec is not None and spec.unit is not None
            else f"the file states {now!r}"
        )
        raise DataFormatError(
            f"{where}: units[{name!r}] = {given!r} contradicts the unit {now!r} of the "
            f"loaded values ({how}); units= labels the output: drop it or give {now!r}"
        )


def _map_for(mapping: Any, available: Sequence[str], *, where: str) -> ChannelMap:
    if mapping is None:
        return ChannelMap.from_config(list(available))
    return ChannelMap.from_config(orient(mapping, available, where=where))


def _log_record(
    p: Path,
    log: Any,
    sources: Sequence[str],
    sample_rate: float | None,
    max_gap: float | None,
    bounds: tuple[float | None, float | None],
) -> FlightData:
    """The log's `sources` on one grid (resampled inside the window), under their own names."""
    from .resampling import resample

    meta: dict[str, Any] = {"source": p.name, "format": str(log.metadata.get("format", ""))}
    stamps = log.metadata.get("stamps")
    if stamps:  # which of a ULog topic's stamps each channel's time is (read_log's notes)
        topics = {n: n.split(".", 1)[0] for n in sources}
        meta["stamps"] = {n: stamps[t] for n, t in topics.items() if t in stamps}
    if sample_rate is None:
        if max_gap is not None:
            raise DataFormatError(f"{p}: max_gap applies only with sample_rate")
        first = log.channels[sources[0]]
        for name in sources:
            other = log.channels[name].time
            if other.shape != first.time.shape or not np.array_equal(other, first.time):
                raise DataFormatError(
                    f"{p}: log channels {sources[0]!r} and {name!r} are on different time "
                    "stamps; give sample_rate to resample them onto one grid"
                )
        data = FlightData(
            first.time,
            {n: log.channels[n].values for n in sources},
            {n: log.channels[n].unit for n in sources if log.channels[n].unit},
            meta,
        )
        return data if bounds[0] is None else data.window(float(bounds[0]), float(bounds[1]))  # type: ignore[arg-type]
    try:
        data = resample(
            log, list(sources), rate=sample_rate, t0=bounds[0], t1=bounds[1], max_gap=max_gap
        )
    except DataFormatError as exc:
        raise DataFormatError(f"{p}: {exc}") from None
    return FlightData(
        data.time, dict(data.channels), dict(data.units), {**dict(data.metadata), **meta}
    )


def flight_windows(
    path: str | Path | FlightLog | FlightData,
    spec: Any,
    *,
    channels: Any = None,
    time_column: str | None = None,
) -> list[tuple[float, float]]:
    """The manoeuvre windows of a flight file, each to become a flight of its own.

    Parameters
    ----------
    path : str, Path, FlightLog or FlightData
        A flight log or table (or one already read).
    spec : mapping
        `aeroid.segment` keywords: ``inputs`` (channels whose excitation marks
        manoeuvres; model names of `channels` are taken too) with ``margin``,
        ``threshold``, ``min_duration``, ``merge_gap``, ``trim_window``,
        ``energy_window``, ``noise_floor``; or ``mode`` / ``events``.
    channels : mapping, optional
        The flight's channel map: its model names may stand for channels in
        ``inputs``, and windows are clipped to the span its channels cover.
    time_column : str, optional
        As for `load_flight_test`.

    Returns
    -------
    list of (float, float)
        ``(t0, t1)`` seconds in the file's time, in order.

    Raises
    ------
    ChannelError
        An input the file lacks.
    DataFormatError
        An unknown key, or what `aeroid.segment` refuses.
    """
    from .logs import read_log, sniff_format
    from .segmentation import segment

    spec = _as_dict(spec)
    _check_keys(spec, "segments", "a mapping of aeroid.segment options", _SEGMENT_KEYS)
    record: Any
    if isinstance(path, (FlightLog, FlightData)):
        record, where = path, str(path.metadata.get("source", "the log"))
    else:
        p = Path(path)
        where = p.name
        fmt = sniff_format(p) if p.is_file() else None
        record = (
            load_flight_test(p, time_column=time_column)
            if fmt is None
            else read_log(p, format=fmt, time_column=time_column)
        )
    table = isinstance(record, FlightData)
    available = list(record.names) if table else list(record.channels)
    cmap = None if channels is None else _map_for(channels, available, where=where)
    by_name = {} if cmap is None else {e.name: e.channel for e in cmap.entries}
    kwargs = {k: v for k, v in spec.items() if v is not None}
    if "inputs" in kwargs:
        inputs = [kwargs["inputs"]] if isinstance(kwargs["inputs"], str) else list(kwargs["inputs"])
        kwargs["inputs"] = [by_name.get(n, n) if n not in available else n for n in inputs]
    for key in ("events", "margin"):
        if isinstance(kwargs.get(key), list):
            kwargs[key] = tuple(kwargs[key])
    found = segment(record, **kwargs).windows
    if cmap is None:
        return [(w.t0, w.t1) for w in found]
    for source in cmap.sources:
        if source not in available:
            raise _missing(source, available, where)
    if table:
        lo, hi = float(record.time[0]), float(record.time[-1])
    else:
        lo, hi = _spans(record, cmap.sources)
    out = []
    for w in found:
        t0, t1 = max(w.t0, lo), min(w.t1, hi)
        if t1 > t0:
            out.append((t0, t1))
    return out
