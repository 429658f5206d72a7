"""Resampling: the channels of a multi-rate log put on one uniform time grid.

Each channel arrives on its own stamps (a 400 Hz gyro, a 10 Hz air-data
probe, a flight mode logged on change). `resample` puts the chosen ones on
one grid, filtering before it decimates so that nothing above the new
Nyquist frequency folds into the band the model sees, and refusing to
interpolate silently across holes in the record.

The work is done on plain arrays in `aeroid.io._regrid` (which `aeroid.io.data`
uses below `FlightData`); the reasons for its filter are given there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import DataFormatError
from ._logtypes import FlightLog
from ._regrid import ATTENUATION_DB as ATTENUATION_DB
from ._regrid import GAP_STEPS as GAP_STEPS
from ._regrid import MAX_SAMPLES as MAX_SAMPLES
from ._regrid import PASSBAND_FRACTION as PASSBAND_FRACTION
from ._regrid import Source as Source
from ._regrid import clean_source as clean_source
from ._regrid import close_names as close_names
from ._regrid import design_anti_alias as design_anti_alias
from ._regrid import flightlog_parts, regrid
from ._regrid import missing_channel as missing_channel
from .data import FlightData

__all__ = ["resample"]


def log_parts(
    log: Any,
) -> tuple[dict[str, Any], tuple[tuple[float, str, str], ...], dict[str, Any]]:
    """The raw channels (name -> LogChannel or (time, values[, unit])), events, metadata."""
    if isinstance(log, FlightData):
        raw: dict[str, Any] = {
            name: (log.time, log.channels[name], log.units.get(name, "")) for name in log.names
        }
        stored = log.metadata.get("events", ())
        try:
            events = tuple((float(e[0]), str(e[1]), str(e[2])) for e in stored)
        except (TypeError, ValueError, IndexError):
            raise DataFormatError(
                "metadata['events']: expected [time, kind, value] entries (as resample writes)"
            ) from None
        meta = {k: v for k, v in log.metadata.items() if k != "events"}
        return raw, events, meta
    return flightlog_parts(log)


def resample(
    log: FlightLog | FlightData | Mapping[str, Any],
    channels: Sequence[str] | Mapping[str, str],
    *,
    rate: float,
    t0: float | None = None,
    t1: float | None = None,
    max_gap: float | Mapping[str, float] | None = None,
    method: str | Mapping[str, str] = "auto",
) -> FlightData:
    """Put channels of a multi-rate log on one uniform time grid.

    A channel logged faster than `rate`, or as fast to 1 % slower, is low-pass
    filtered first (a zero-phase Kaiser-window FIR, flat to 0.8 x the new
    Nyquist frequency and 80 dB down at it), then evaluated on the grid
    band-limited (a Kaiser-windowed sinc through the filtered samples, so the
    band stays flat even from a source rate close to `rate`); one whose stamps
    are the grid's points is copied, and a slower channel is interpolated. Nothing is extrapolated, and a hole in the stamps longer
    than `max_gap` is reported rather than bridged.

    Parameters
    ----------
    log : FlightLog, FlightData or mapping
        What a log reader returned, a record to re-grid, or a mapping of
        channel name to ``(time, values)`` or ``(time, values, unit)``.
    channels : sequence of str or mapping of str to str
        Log channel names to keep (kept as names), or ``{model_name:
        log_channel_name}``.
    rate : float
        The new sample rate in Hz.
    t0, t1 : float, optional
        Start and end of the grid in the log's seconds. Default: the span
        all chosen channels cover (the intersection of their time ranges; a
        ``"hold"`` channel's value holds after its last stamp, so only its
        start counts). Given values must lie inside that span.
    max_gap : float or mapping of str to float, optional
        Longest step between stamps, in seconds, that may be interpolated
        across (per model name in a mapping). Default: 5 x the channel's median
        step (no limit for ``"hold"`` channels). ``float("inf")`` bridges every
        gap and records the long ones in the metadata.
    method : {"auto", "linear", "cubic", "hold"} or mapping of str to str
        How samples are placed on the grid, for every channel or per model
        name (unnamed ones take ``"auto"``). ``"linear"`` and ``"cubic"``
        interpolate (after the anti-aliasing filter when decimating);
        ``"auto"`` is linear, and after the filter ``"auto"`` and ``"cubic"``
        evaluate the filtered samples band-limited (a Kaiser-windowed sinc,
        flat to 1e-6 over the filter's pass band, no delay; recorded as
        ``"cubic"`` with its ``"interpolation"`` described);
        ``"hold"`` keeps the last value without filtering, for flight modes,
        switches and counters.

    Returns
    -------
    FlightData
        The channels under their model names, with the log's units, and
        ``metadata["resampling"]`` recording the rate, window, mapping,
        method and, per channel, the source rate, the filter design, the
        method used and any duplicated or reordered stamps (plain JSON
        values). The log's events are kept in ``metadata["events"]`` as
        ``[time, kind, value]`` and the log's JSON-compatible metadata at the
        top level.

    Raises
    ------
    ChannelError
        A chosen channel is not in the log (the message lists close names).
    DataFormatError
        NaN values (naming the channel and time), a gap longer than
        `max_gap` (naming the channel, the gap's start and length), channels
        whose time ranges do not overlap, a `t0`/`t1` outside them, fewer than
        two grid points, more than `MAX_SAMPLES` (1e8) grid points (naming
        `rate` and the count), a complex-valued channel, or a bad option.

    Notes
    -----
    The filter needs half its length of samples on each side of a grid
    point (``metadata["resampling"]["channels"][name]["anti_alias"]["edge_s"]``);
    where the channel ends sooner, odd reflection stands in for them, so the
    first and last `edge_s` seconds of a channel that bounds the grid (and
    the band-limited evaluation's ``evaluation_reach_s`` beyond them, where it
    is used) are less accurate. Duplicated stamps are averaged and out-of-order stamps sorted.
    """
    parts = log_parts(log)
    grid = regrid(*parts, channels, rate=rate, t0=t0, t1=t1, max_gap=max_gap, method=method)
    return FlightData(grid.time, grid.channels, grid.units, grid.metadata)
