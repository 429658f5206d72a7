"""Segmentation: the manoeuvre windows of a long flight record.

One log holds take-off, cruise and several manoeuvres; identification wants
each manoeuvre with a little trim before and after. `segment` finds the
windows three ways: given times, a flight mode or pair of event markers of
the log, or the excitation of chosen input channels measured against their
own noise floor.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, ReadOnlyDict, fmt, frozen_array, markdown_table
from .._threads import small_blas
from ..errors import DataFormatError
from ._logtypes import FlightLog
from .data import FlightData, plain, positive_number
from .resampling import Source, clean_source, close_names, log_parts, missing_channel

__all__ = ["InputTrace", "ManeuverWindow", "SegmentationResult", "segment"]

FloatArray = NDArray[np.float64]

# 1.4826 * MAD estimates the standard deviation of Gaussian noise.
_MAD_SCALE = 1.4826
# Trim is tracked on medians of short blocks: robust, and cheap on long records.
_BLOCK_S = 0.25
_Interval = tuple[float, float, frozenset[str]]


@dataclass(frozen=True)
class ManeuverWindow(FrozenState):
    """One window of a record: ``t0 <= time <= t1`` seconds, and why it was chosen."""

    t0: float
    t1: float
    reason: str = ""

    def __post_init__(self) -> None:
        try:
            t0, t1 = float(self.t0), float(self.t1)
        except (TypeError, ValueError):
            raise DataFormatError(
                f"window: t0 and t1 must be numbers, got {self.t0!r}, {self.t1!r}"
            ) from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise DataFormatError(
                f"window: need finite t1 > t0, got t0={plain(self.t0)}, t1={plain(self.t1)}"
            )
        object.__setattr__(self, "t0", t0)
        object.__setattr__(self, "t1", t1)
        object.__setattr__(self, "reason", str(self.reason))

    @property
    def duration(self) -> float:
        """Length in seconds."""
        return self.t1 - self.t0


@dataclass(frozen=True, eq=False)
class InputTrace(FrozenState):
    """An input channel as segmentation saw it (uniform stamps), for plots and checks.

    `trim`, `energy` and `floor` are set only for automatic segmentation:
    the trim level, the moving RMS of the input less trim, and the noise
    floor (a standard deviation); windows open where ``energy > level``.
    """

    name: str
    time: FloatArray
    values: FloatArray
    unit: str = ""
    trim: FloatArray | None = None
    energy: FloatArray | None = None
    floor: float | None = None
    level: float | None = None

    def __post_init__(self) -> None:
        for name in ("time", "values", "trim", "energy"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, frozen_array(value))


@dataclass(frozen=True, eq=False)
class SegmentationResult(FrozenState):
    """The windows `segment` found, how, and the inputs it looked at.

    Attributes
    ----------
    windows : tuple of ManeuverWindow
        In time order.
    way : {"time", "mode", "events", "excitation"}
        Given windows, a flight mode, event markers, or input excitation.
    traces : tuple of InputTrace
        The inputs (with trim, energy and noise floor for ``"excitation"``).
    extent : tuple of float
        First and last time of the record; windows are clipped to it.
    settings : mapping
        The options that shaped the windows (plain values).
    """

    windows: tuple[ManeuverWindow, ...]
    way: str
    traces: tuple[InputTrace, ...] = ()
    extent: tuple[float, float] = (0.0, 0.0)
    settings: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "windows", tuple(self.windows))
        object.__setattr__(self, "traces", tuple(self.traces))
        object.__setattr__(self, "settings", ReadOnlyDict(self.settings))

    def __len__(self) -> int:
        return len(self.windows)

    def __iter__(self) -> Iterator[ManeuverWindow]:
        return iter(self.windows)

    def flights(self, data: FlightData) -> list[FlightData]:
        """Each window of `data` as its own record.

        Each keeps `data`'s units and metadata, with ``metadata["window"] =
        [t0, t1]`` and ``metadata["reason"]`` added.
        """
        if not isinstance(data, FlightData):
            raise DataFormatError(
                f"flights: expected FlightData (resample the log first), got {type(data).__name__}"
            )
        out = []
        for w in self.windows:
            part = data.window(w.t0, w.t1)
            meta = dict(part.metadata)
            meta["window"] = [w.t0, w.t1]
            meta["reason"] = w.reason
            out.append(FlightData(part.time, part.channels, part.units, meta))
        return out

    def summary(self) -> str:
        """Markdown table of the windows (and the inputs' noise floors, when automatic)."""
        lines = [
            f"{len(self.windows)} window(s) by {self.way} in "
            f"[{fmt(self.extent[0])}, {fmt(self.extent[1])}] s",
            "",
            markdown_table(
                ("#", "t0 [s]", "t1 [s]", "duration [s]", "reason"),
                [
                    (i + 1, fmt(w.t0, 6), fmt(w.t1, 6), fmt(w.duration), w.reason)
                    for i, w in enumerate(self.windows)
                ],
            ),
        ]
        floors = [t for t in self.traces if t.floor is not None]
        if floors:
            lines += [
                "",
                markdown_table(
                    ("input", "noise floor", "threshold level"),
                    [
                        (f"{t.name} [{t.unit}]" if t.unit else t.name, fmt(t.floor), fmt(t.level))  # type: ignore[arg-type]
                        for t in floors
                    ],
                ),
            ]
        return "\n".join(lines)

    def plot(self, **kwargs: Any) -> Any:
        """The inputs over time with the windows shaded. Returns a matplotlib Figure.

        Keyword arguments go to `matplotlib.figure.Figure`.
        """
        from matplotlib.figure import Figure

        rows = max(len(self.traces), 1)
        fig = Figure(figsize=kwargs.pop("figsize", (8.0, 1.0 + 2.0 * rows)), **kwargs)
        axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
        for ax, trace in zip(axes, self.traces, strict=False):
            ax.plot(trace.time, trace.values, lw=0.8, label=trace.name)
            if trace.trim is not None:
                ax.plot(trace.time, trace.trim, "k--", lw=0.8, label="trim")
            ax.set_ylabel(f"{trace.name} [{trace.unit or '-'}]")
        for ax in axes:
            for w in self.windows:
                ax.axvspan(w.t0, w.t1, color="tab:orange", alpha=0.2, lw=0)
        axes[0].set_title(f"{len(self.windows)} window(s) by {self.way}")
        axes[-1].set_xlabel("time [s]")
        if not self.traces:
            axes[0].set_xlim(*self.extent)
            axes[0].set_yticks([])
        return fig


# -- options ---------------------------------------------------------------------


def _nonnegative(value: Any, what: str, unit: str = "of seconds") -> float:
    """`value` as a finite float >= 0; `unit` completes "expected a non-negative number"."""
    try:
        out = float(value)
        ok = not isinstance(value, bool) and math.isfinite(out) and out >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DataFormatError(f"{what}: expected a non-negative number {unit}, got {plain(value)}")
    return out


def _positive(value: Any, what: str, unit: str = "of seconds") -> float:
    """`value` as a finite float > 0; `unit` completes "expected a positive number"."""
    return positive_number(value, what, f" {unit}")


def _margin(margin: Any) -> tuple[float, float]:
    if isinstance(margin, (tuple, list)):
        if len(margin) != 2:
            raise DataFormatError(f"margin: expected (before, after) seconds, got {margin!r}")
        return _nonnegative(margin[0], "margin before"), _nonnegative(margin[1], "margin after")
    value = _nonnegative(margin, "margin")
    return value, value


# -- the three ways --------------------------------------------------------------


def _given_windows(windows: Any, extent: tuple[float, float]) -> tuple[ManeuverWindow, ...]:
    if not isinstance(windows, Sequence) or isinstance(windows, str):
        raise DataFormatError("windows: expected a sequence of (t0, t1) or (t0, t1, reason)")
    out = []
    for item in windows:
        if isinstance(item, ManeuverWindow):
            w = item
        elif isinstance(item, (tuple, list)) and len(item) in (2, 3):
            w = ManeuverWindow(item[0], item[1], item[2] if len(item) == 3 else "given")
        else:
            raise DataFormatError(f"windows: expected (t0, t1) or (t0, t1, reason), got {item!r}")
        if w.t1 <= extent[0] or w.t0 >= extent[1]:
            raise DataFormatError(
                f"window [{w.t0:.6g}, {w.t1:.6g}] s lies outside the record "
                f"[{extent[0]:.6g}, {extent[1]:.6g}] s"
            )
        if w.t0 < extent[0] or w.t1 > extent[1]:  # clipped to the record, as all windows are
            w = ManeuverWindow(max(w.t0, extent[0]), min(w.t1, extent[1]), w.reason)
        out.append(w)
    return tuple(sorted(out, key=lambda w: (w.t0, w.t1)))


def _same(value: Any, target: Any) -> bool:
    """Event or channel value equal to the wanted mode, as text or as a number. A log's
    mode event reads ``"SYSTEMID (mode 25)"`` or ``"MANUAL (nav_state 0)"``: the whole
    text, the name before the brackets or the number in them match."""
    text = str(value)
    forms = [text]
    found = _MODE_EVENT.fullmatch(text)
    if found:
        forms += [found.group(1), found.group(2)]
    for form in forms:
        if form == str(target):
            return True
        try:
            if float(form) == float(target):
                return True
        except (TypeError, ValueError):
            continue
    return False


# the loaders' mode events: "<name> (mode <number>)", "<name> (nav_state <number>)"
_MODE_EVENT = re.compile(r"(.+?) \((?:mode|nav_state) (-?\d+)\)")


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(first, last) indices of each run of True."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    edges = np.diff(padded)
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def _event_windows(
    events: Sequence[tuple[float, str, str]],
    opens: Any,
    closes: Any,
    end: float,
    label: str,
) -> list[_Interval]:
    """From an event matching `opens` to the next matching `closes` (or the record's end)."""
    out: list[_Interval] = []
    start: float | None = None
    for t, kind, value in events:
        if start is None and opens(kind, value):
            start = t
        elif start is not None and closes(kind, value):
            if t > start:
                out.append((start, t, frozenset([label])))
            start = None
    if start is not None and end > start:
        out.append((start, end, frozenset([label + " (open at the end)"])))
    return out


def _mode_windows(
    mode: Any,
    sources: Mapping[str, Any],
    events: Sequence[tuple[float, str, str]],
    extent: tuple[float, float],
) -> tuple[list[_Interval], list[str]]:
    """Windows while the mode equals a value; also the channel shown in the plot."""
    if isinstance(mode, (tuple, list)):
        if len(mode) != 2:
            raise DataFormatError(f"mode: expected a value or (source, value), got {mode!r}")
        where, value = str(mode[0]), mode[1]
    else:
        where, value = None, mode
    kinds = sorted({kind for _, kind, _ in events})
    if where is None:
        if "mode" not in kinds:
            raise DataFormatError(
                f"mode: the log has no 'mode' events (event kinds: {kinds}); name where the "
                "mode is: mode=(channel or event kind, value)"
            )
        where = "mode"
    label = f"{where} == {value!r}"
    if where in sources:
        src = clean_source(where, sources[where])
        try:
            mask = src.values == float(value)
        except (TypeError, ValueError):
            mask = np.zeros(src.values.size, dtype=bool)  # text never equals a number
        return [
            (float(src.time[a]), float(src.time[b]), frozenset([label])) for a, b in _runs(mask)
        ], [where]
    if where in kinds:
        chosen = [e for e in events if e[1] == where]
        return (
            _event_windows(
                chosen,
                lambda k, v: _same(v, value),
                lambda k, v: not _same(v, value),
                extent[1],
                label,
            ),
            [],
        )
    raise missing_channel(where, [*sources, *kinds], role="mode channel or event kind")


def _marker(spec: Any, what: str) -> Any:
    if isinstance(spec, str):
        return lambda kind, value: value == spec
    if isinstance(spec, (tuple, list)) and len(spec) == 2:
        kind_want, value_want = str(spec[0]), str(spec[1])
        return lambda kind, value: kind == kind_want and value == value_want
    raise DataFormatError(
        f"events: the {what} marker must be a value or (kind, value), got {spec!r}"
    )


# -- excitation ------------------------------------------------------------------


def _uniform(src: Source) -> tuple[FloatArray, FloatArray, float]:
    """The channel on uniform stamps at its median step (linear interpolation)."""
    step = src.step
    steps = np.diff(src.time)
    if float(np.max(np.abs(steps - step))) <= 1e-6 * step:
        return src.time, src.values, step
    n = int(np.floor((src.time[-1] - src.time[0]) / step + 1e-9)) + 1
    time = src.time[0] + np.arange(n) * step
    return time, np.interp(time, src.time, src.values), step


def _odd(n: float) -> int:
    return max(round(n) // 2 * 2 + 1, 1)


def _moving_rms(d: FloatArray, width: int) -> FloatArray:
    """Centred moving RMS over `width` samples (fewer at the ends)."""
    half = width // 2
    c = np.concatenate(([0.0], np.cumsum(d * d)))
    idx = np.arange(d.size)
    lo = np.clip(idx - half, 0, d.size)
    hi = np.clip(idx + half + 1, 0, d.size)
    return np.sqrt(np.maximum(c[hi] - c[lo], 0.0) / (hi - lo))


def _running_trim(
    time: FloatArray, values: FloatArray, quiet: NDArray[np.bool_], k: int, width: int
) -> FloatArray | None:
    """Running median over `width` blocks of `k` samples, from the quiet samples only.

    A block with no quiet sample takes the value interpolated between its
    quiet neighbours, so the trim under a manoeuvre is drawn from the trim
    before and after it. None when nothing is quiet.
    """
    from scipy.ndimage import median_filter

    nb = -(-time.size // k)
    pad = nb * k - time.size
    blocks = np.concatenate((values, np.full(pad, np.nan))).reshape(nb, k)
    mask = np.concatenate((quiet, np.zeros(pad, dtype=bool))).reshape(nb, k)
    centres = np.concatenate((time, np.full(pad, np.nan))).reshape(nb, k)
    centre = np.nanmean(centres, axis=1)  # every block holds at least one stamp
    ok = mask.any(axis=1)
    if not ok.any():
        return None
    chosen = np.where(mask[ok], blocks[ok], np.nan)
    level = np.interp(centre, centre[ok], np.nanmedian(chosen, axis=1))
    smooth = median_filter(level, size=width, mode="nearest")
    trim = np.interp(time, centre, smooth)
    if nb > 1:
        # Half a block before the first centre and after the last: continue the
        # end slopes rather than hold, so that a drifting trim stays followed.
        head, tail = time < centre[0], time > centre[-1]
        slope0 = (smooth[1] - smooth[0]) / (centre[1] - centre[0])
        slope1 = (smooth[-1] - smooth[-2]) / (centre[-1] - centre[-2])
        trim[head] = smooth[0] + slope0 * (time[head] - centre[0])
        trim[tail] = smooth[-1] + slope1 * (time[tail] - centre[-1])
    return trim


def _floor(d: FloatArray, quiet: NDArray[np.bool_]) -> float:
    """Noise standard deviation of the quiet samples (MAD, else RMS, else a tiny scale)."""
    q = d[quiet] if quiet.any() else d
    dev = np.abs(q - np.median(q))
    sigma = _MAD_SCALE * float(np.median(dev))
    if sigma == 0:
        # Over half the samples sit exactly at trim: a commanded or simulated input, or a
        # quantised one that flickers by a step. The flicker is among the smaller quarter
        # of the deviations; the manoeuvres, which the quiet set may still hold (nothing
        # was flagged yet), are not unless they fill a quarter of the record.
        small = dev[dev <= np.quantile(dev, 0.75)]
        sigma = float(np.sqrt(np.mean(small**2)))
    if sigma == 0:
        # A noise-free input: any real departure from trim counts.
        sigma = 1e-9 * max(float(np.max(np.abs(d))), 1e-300)
    return sigma


def _excitation(
    src: Source,
    *,
    threshold: float,
    trim_window: float,
    energy_window: float,
    noise_floor: float | None,
) -> tuple[list[_Interval], InputTrace]:
    """Intervals where `src` departs from its trim by more than `threshold` x its noise floor."""
    time, values, step = _uniform(src)
    if time.size < 8:
        raise DataFormatError(
            f"input {src.name!r}: {time.size} samples are too few to tell excitation from noise"
        )
    k = max(round(_BLOCK_S / step), 1)
    nb = -(-time.size // k)
    # A running median (edges held) wider than twice the blocks gives what 2 nb + 1 gives:
    # capping it keeps a long trim_window from allocating a filter the size of the window.
    width_blocks = _odd(min(trim_window / (k * step), 2 * nb + 1))
    # Quiet samples lie an energy window clear of any flag: 2 m + 1 samples must fit.
    reach = energy_window / step
    m = _odd(reach) if reach < time.size else time.size
    if 2 * m + 1 > time.size:
        raise DataFormatError(
            f"energy_window: {energy_window:.6g} s is too long for input {src.name!r} "
            f"({time[-1] - time[0]:.6g} s, {time.size} samples); telling quiet trim from "
            "excitation takes two energy windows, so it must be under half the record"
        )
    kernel = np.ones(2 * m + 1)

    def flags(trim: FloatArray) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]]:
        d = values - trim
        energy = _moving_rms(d, m)
        quiet = np.ones(d.size, dtype=bool)
        sigma = float(noise_floor) if noise_floor is not None else _floor(d, quiet)
        flagged = energy > threshold * sigma
        for _ in range(20):
            # The floor from the quiet parts only: a window's width clear of any flag.
            quiet_new = np.convolve(flagged, kernel, mode="same") == 0
            if np.array_equal(quiet_new, quiet):
                break
            quiet = quiet_new
            if noise_floor is None:
                sigma = _floor(d, quiet)
            flagged = energy > threshold * sigma
        return d, energy, sigma, quiet

    first = _running_trim(time, values, np.ones(time.size, dtype=bool), k, width_blocks)
    trim = first if first is not None else np.full(time.size, float(np.median(values)))
    d, energy, sigma, quiet = flags(trim)
    second = _running_trim(time, values, quiet, k, width_blocks)
    if second is not None:
        trim = second
        d, energy, sigma, quiet = flags(trim)
    level = threshold * sigma
    out: list[_Interval] = []
    for a, b in _runs(energy > level):
        # The moving RMS smears an edge by half its window: place each edge at
        # the first and last sample that departs from trim by the same margin.
        lo, hi = max(a - m // 2 - 1, 0), min(b + m // 2 + 1, time.size - 1)
        strong = np.flatnonzero(np.abs(d[lo : hi + 1]) > level)
        if strong.size:
            a, b = lo + int(strong[0]), lo + int(strong[-1])
        out.append((float(time[a]), float(time[b]), frozenset([src.name])))
    trace = InputTrace(src.name, time, values, src.unit, trim, energy, sigma, level)
    return out, trace


# -- shaping ---------------------------------------------------------------------


def _shape(
    intervals: list[_Interval],
    *,
    merge_gap: float,
    min_duration: float,
    margin: tuple[float, float],
    extent: tuple[float, float],
    reason: Any,
    step: float = 0.0,
) -> tuple[ManeuverWindow, ...]:
    """Merge close intervals, drop short ones, add margins, clip to the record. An
    interval from its first to its last sample of `step` spans one step more."""
    merged: list[list[Any]] = []
    for a, b, labels in sorted(intervals, key=lambda iv: (iv[0], iv[1])):
        if merged and a - merged[-1][1] < merge_gap:
            merged[-1][1] = max(merged[-1][1], b)
            merged[-1][2] = merged[-1][2] | labels
        else:
            merged.append([a, b, labels])
    out = []
    for a, b, labels in merged:
        if b - a + step < min_duration * (1.0 - 1e-9):
            continue
        t0, t1 = max(a - margin[0], extent[0]), min(b + margin[1], extent[1])
        if t1 > t0:
            out.append(ManeuverWindow(t0, t1, reason(labels)))
    return tuple(out)


@small_blas
def segment(
    data_or_log: FlightData | FlightLog | Mapping[str, Any],
    *,
    inputs: Sequence[str] | None = None,
    windows: Sequence[Any] | None = None,
    events: tuple[Any, Any] | None = None,
    mode: Any = None,
    margin: float | tuple[float, float] = (1.0, 1.0),
    threshold: float = 5.0,
    min_duration: float = 1.0,
    merge_gap: float | None = None,
    trim_window: float = 30.0,
    energy_window: float = 1.0,
    noise_floor: float | Mapping[str, float] | None = None,
) -> SegmentationResult:
    """Find the manoeuvre windows of a flight record.

    One of three ways: `windows` (given times), `mode` or `events` (from the
    log), or, when none of those is given, the excitation of `inputs`:

    1. trim: a running median over `trim_window` seconds, then again from
       the quiet samples only, so that under a manoeuvre it is drawn from the
       trim before and after it (a slowly drifting trim is followed);
    2. energy: the RMS of input less trim over `energy_window` seconds;
    3. noise floor: 1.4826 x the median absolute deviation of the quiet
       samples (those an energy window clear of any flag), iterated with the
       flags until they settle;
    4. excited where energy > `threshold` x floor; each edge then moves to the
       first (last) sample that departs from trim by as much, undoing the
       smear of the moving window.

    Excited intervals of all inputs are pooled; then, for every way but
    given `windows`: intervals closer than `merge_gap` merge, those shorter
    than `min_duration` are dropped, and `margin` is added before and after,
    clipped to the record.

    Parameters
    ----------
    data_or_log : FlightData, FlightLog or mapping
        A record on one grid, a log (channels at their own rates, events),
        or a mapping of channel name to ``(time, values)``.
    inputs : sequence of str, optional
        Input channels whose excitation marks manoeuvres; with the other
        ways, the channels to show in the plot.
    windows : sequence of (t0, t1) or (t0, t1, reason), optional
        Given windows in seconds, used as they are (no merging or margins)
        but clipped to the record; one wholly outside it is refused.
    events : (start, end), optional
        Windows from each event matching `start` to the next matching `end`
        (or to the end of the record). A marker is an event value (``"sysid
        start"``) or a ``(kind, value)`` pair. With a FlightData, the events
        are those `resample` kept in its metadata.
    mode : value or (source, value), optional
        Windows while the mode equals `value`. The source is a channel (such
        as a PX4 ``vehicle_status.nav_state`` resampled with
        ``method="hold"``) or an event kind; a bare value means the events of
        kind ``"mode"``. Values compare as text or as numbers.
    margin : float or (float, float)
        Seconds added before and after each derived window.
    threshold : float
        Excitation threshold as a multiple of the noise floor.
    min_duration : float
        Shortest window kept, in seconds, before margins.
    merge_gap : float, optional
        Windows closer than this merge. Default: the two margins together,
        so that windows never overlap once the margins are added.
    trim_window : float
        Length of the running median that tracks trim, in seconds; longer
        than any one manoeuvre.
    energy_window : float
        Length of the moving RMS, in seconds.
    noise_floor : float or mapping of str to float, optional
        Noise standard deviation of each input, in its units, instead of the
        estimate (needed for an input without noise whose trim drifts).

    Returns
    -------
    SegmentationResult
        ``.windows``, ``.summary()``, ``.plot()``, ``.flights(data)``.

    Raises
    ------
    ChannelError
        An input or mode channel is not in the record (naming close names).
    DataFormatError
        More than one way chosen, no way chosen, a bad option, a given window
        outside the record, or input samples that hold NaN.
    """
    sources, log_events, _ = log_parts(data_or_log)
    chosen = [
        w for w, v in (("windows", windows), ("events", events), ("mode", mode)) if v is not None
    ]
    if len(chosen) > 1:
        raise DataFormatError(f"segment: choose one of windows, events and mode, got {chosen}")
    way = (
        {"windows": "time", "events": "events", "mode": "mode"}[chosen[0]]
        if chosen
        else "excitation"
    )
    try:
        names = [] if inputs is None else [inputs] if isinstance(inputs, str) else list(inputs)
    except TypeError:
        raise DataFormatError(f"inputs: expected channel names, got {plain(inputs)}") from None
    if way == "excitation" and not names:
        raise DataFormatError(
            "segment: give inputs=[...] (channels whose excitation marks manoeuvres), "
            "windows=[(t0, t1), ...], events=(start, end) or mode=..."
        )
    for name in names:
        if not isinstance(name, str) or not name:
            raise DataFormatError(
                f"inputs: expected channel names, got {plain(name)} in {inputs!r}"
            )
        if name not in sources:
            raise missing_channel(name, list(sources), role="input")
    cleaned = {name: clean_source(name, sources[name]) for name in names}
    extent = _extent(data_or_log, sources, log_events)
    before_after = _margin(margin)
    threshold = _positive(threshold, "threshold", "(a multiple of the noise floor)")
    min_duration = _nonnegative(min_duration, "min_duration")
    gap = sum(before_after) if merge_gap is None else _nonnegative(merge_gap, "merge_gap")
    trim_window = _positive(trim_window, "trim_window")
    energy_window = _positive(energy_window, "energy_window")
    if isinstance(noise_floor, Mapping):
        unknown = sorted(set(noise_floor) - set(names))
        if unknown:
            raise DataFormatError(f"noise_floor: {unknown} are not among the inputs {names}")
    settings: dict[str, Any] = {
        "margin": list(before_after),
        "threshold": threshold,
        "min_duration": min_duration,
        "merge_gap": gap,
        "trim_window": trim_window,
        "energy_window": energy_window,
    }

    def traces_of(extra: Sequence[str] = ()) -> tuple[InputTrace, ...]:
        shown = [*names, *(e for e in extra if e not in names)]
        out = []
        for name in shown:
            src = cleaned.get(name) or clean_source(name, sources[name])
            out.append(InputTrace(name, src.time, src.values, src.unit))
        return tuple(out)

    def shaped(
        intervals: list[_Interval], reason: Any, step: float = 0.0
    ) -> tuple[ManeuverWindow, ...]:
        return _shape(
            intervals,
            merge_gap=gap,
            min_duration=min_duration,
            margin=before_after,
            extent=extent,
            reason=reason,
            step=step,
        )

    if way == "time":
        found = _given_windows(windows, extent)
        return SegmentationResult(found, way, traces_of(), extent, {})
    if way == "mode":
        intervals, shown = _mode_windows(mode, sources, log_events, extent)
        found = shaped(intervals, lambda labels: " + ".join(sorted(labels)))
        return SegmentationResult(found, way, traces_of(shown), extent, settings)
    if way == "events":
        if not isinstance(events, (tuple, list)) or len(events) != 2:
            raise DataFormatError(f"events: expected (start, end) markers, got {events!r}")
        opens, closes = _marker(events[0], "start"), _marker(events[1], "end")
        label = f"from {events[0]!r} to {events[1]!r}"
        intervals = _event_windows(log_events, opens, closes, extent[1], label)
        if not any(opens(k, v) for _, k, v in log_events):
            values = sorted({v for _, _, v in log_events})
            near = close_names(str(events[0]), values)
            raise DataFormatError(
                f"events: no event matches the start marker {events[0]!r}"
                + (f"; did you mean {near}?" if near else f" (event values: {values[:12]})")
            )
        found = shaped(intervals, lambda labels: " + ".join(sorted(labels)))
        return SegmentationResult(found, way, traces_of(), extent, settings)

    intervals = []
    traces = []
    for name, src in cleaned.items():
        floor = noise_floor.get(name) if isinstance(noise_floor, Mapping) else noise_floor
        if floor is not None:
            floor = _positive(floor, f"noise_floor for {name!r}", "in the input's units")
        found_here, trace = _excitation(
            src,
            threshold=threshold,
            trim_window=trim_window,
            energy_window=energy_window,
            noise_floor=floor,
        )
        intervals.extend(found_here)
        traces.append(trace)
    # an excited run of N samples lasts N steps: a 1 s doublet of 50 samples at 50 Hz
    # is not shorter than a 1 s min_duration
    step = min(float(np.median(np.diff(tr.time))) for tr in traces) if traces else 0.0
    found = shaped(intervals, lambda labels: "excitation in " + ", ".join(sorted(labels)), step)
    return SegmentationResult(found, way, tuple(traces), extent, settings)


def _extent(
    data_or_log: Any, sources: Mapping[str, Any], events: Sequence[tuple[float, str, str]]
) -> tuple[float, float]:
    """First and last time stamp of the record (channels, else events)."""
    if isinstance(data_or_log, FlightData):
        return float(data_or_log.time[0]), float(data_or_log.time[-1])
    lo, hi = math.inf, -math.inf
    for name, raw in sources.items():
        if hasattr(raw, "time"):
            time = raw.time
        elif isinstance(raw, (tuple, list)) and len(raw) in (2, 3):
            time = raw[0]
        else:
            # as clean_source words it, for a channel segmentation does not look at
            raise DataFormatError(
                f"channel {name!r}: expected a LogChannel or a (time, values[, unit]) pair, "
                f"got {type(raw).__name__}"
            )
        try:
            arr = np.asarray(time, dtype=np.float64)
        except (TypeError, ValueError):
            raise DataFormatError(f"channel {name!r}: time stamps are not numeric") from None
        finite = arr[np.isfinite(arr)]
        if finite.size:
            lo, hi = min(lo, float(finite.min())), max(hi, float(finite.max()))
    if not math.isfinite(lo) and events:
        lo, hi = events[0][0], events[-1][0]
    if not hi > lo:
        raise DataFormatError("the record spans no time (no channel with two distinct stamps)")
    return lo, hi
