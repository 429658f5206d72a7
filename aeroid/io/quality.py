"""Checks on flight data as it arrives: time-stamp jitter, duplicates, dropouts,
saturation and aliasing, per channel, before any identification is run on it.

A whole autopilot log (a `FlightLog` checked without ``channels=``) is judged as a
log: what a logger does by design (flags and ids that never change, fields it never
sets, topics logged once or at their own irregular rates) is reported as information,
grouped, and the defects are ranked (see `check_data_quality`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt
from ..errors import ChannelError, DataFormatError
from ._logtypes import FlightLog
from .data import FlightData, as_float, plain

__all__ = ["ChannelQuality", "DataQualityReport", "check_data_quality"]

FloatArray = NDArray[np.float64]

# What each flag means, for the summary's legend.
FLAGS = {
    "too_few_samples": "fewer than 2 samples (nothing else could be checked)",
    "jitter": "std/median of the regular time steps above jitter_limit",
    "duplicate_stamps": "time stamps repeated",
    "non_increasing_stamps": "time stamps that go backwards",
    "dropouts": "gaps longer than dropout_factor x the median step",
    "saturation": "runs of saturation_run or more samples at the channel's min or max "
    "(and more of them than held runs elsewhere)",
    "constant": "the channel never changes",
    "aliasing": "share of the spectrum in the top alias_band of the band above alias_limit",
    "non_finite": "NaN or infinite values (in a whole log, in a channel that holds finite "
    "ones too)",
    "frozen": "a run of identical values inside a signal that otherwise changes, longer "
    "than its own repeats make likely (whole log)",
}
# A whole log's defects, most serious first: values lost or stuck, then holes, clipping,
# broken stamps, then what only degrades a resampled signal.
RANKING = (
    "non_finite",
    "frozen",
    "dropouts",
    "saturation",
    "non_increasing_stamps",
    "duplicate_stamps",
    "jitter",
    "aliasing",
    "too_few_samples",
    "constant",
)
# What a whole log holds by design: reported, grouped, never counted as a defect.
NOTES = {
    "constant": "the same value throughout the log (a flag, id, setting or unused field)",
    "never_set": "no finite value at all (PX4 logs an unset field as NaN, a limit as inf)",
    "one_sample": "logged once (a topic published on an event, or at start-up)",
}
# The chance of a frozen run under the channel's own rate of repeated values, below
# which the run is flagged (one false alarm in a thousand channels of pure chance).
_FROZEN_CHANCE = 1e-3
# A PX4 topic's period may be its median step over 1 to 4: the estimator publishes on
# every second or third IMU sample, a rate controller every fourth to sixth.
_DIVISORS = 4


@dataclass(frozen=True)
class ChannelQuality(FrozenState):
    """The checks of one channel.

    Attributes
    ----------
    name : str
        Channel name.
    n_samples : int
        Number of samples.
    rate : float
        Median sample rate, Hz (0 when it cannot be told).
    jitter : float
        Standard deviation over median of the time steps, leaving out
        repeated or backward stamps and dropouts (0 for a uniform grid).
    duplicates : int
        Steps of exactly zero.
    non_increasing : int
        Steps below zero.
    dropouts : int
        Steps longer than ``dropout_factor`` times the median step.
    longest_gap : float
        Longest step, s.
    saturation : float
        Fraction of samples in runs of at least ``saturation_run``
        consecutive samples at the channel's minimum or maximum. The
        ``saturation`` flag is raised when these outnumber the samples held
        in such runs at other values: a stepped input (a doublet from trim) or
        a slow sensor repeated on a fast grid sits in runs everywhere, so its
        plateaus at the extremes are its shape rather than clipping.
    alias_fraction : float
        Share of the power spectral density (mean removed) in the top
        ``alias_band`` of the band below the Nyquist frequency (NaN with fewer
        than 16 samples).
    flags : tuple of str
        The checks the channel fails (keys of `aeroid.io.quality.FLAGS`).
    non_finite : int
        NaN or infinite values.
    frozen : float
        Longest run of identical values inside the signal (not touching its
        first or last sample, not at its extremes), s; whole-log checks only.
    off_period : float
        Whole-log checks: standard deviation of each regular step's distance
        from a whole number of the topic's period (its median step over the
        k = 1 .. 4 that fits best), in periods (NaN otherwise); the ``jitter``
        flag of a whole log is judged on it.
    notes : tuple of str
        What the channel is by design rather than by fault (keys of
        `aeroid.io.quality.NOTES`); whole-log checks only.
    """

    name: str
    n_samples: int
    rate: float
    jitter: float
    duplicates: int
    non_increasing: int
    dropouts: int
    longest_gap: float
    saturation: float
    alias_fraction: float
    flags: tuple[str, ...]
    non_finite: int = 0
    frozen: float = 0.0
    off_period: float = float("nan")
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class DataQualityReport(FrozenState):
    """The data-quality checks of every channel of a record or log.

    Attributes
    ----------
    channels : mapping of str to ChannelQuality
        Per channel, in the order checked.
    thresholds : mapping of str to float
        The limits the flags were raised against.
    source : str
        The file the data came from, when its metadata says so.
    whole_log : bool
        True when a whole log was checked (a `FlightLog` without
        ``channels=``): flags follow the whole-log rules and ``summary()``
        ranks them, with what the log holds by design listed apart.
    """

    channels: Mapping[str, ChannelQuality]
    thresholds: Mapping[str, float] = field(default_factory=dict)
    source: str = ""
    whole_log: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", MappingProxyType(dict(self.channels)))
        object.__setattr__(self, "thresholds", MappingProxyType(dict(self.thresholds)))

    @property
    def flags(self) -> Mapping[str, tuple[str, ...]]:
        """Flags of every channel (an empty tuple for a clean one)."""
        return MappingProxyType({n: c.flags for n, c in self.channels.items()})

    @property
    def flagged(self) -> tuple[str, ...]:
        """Names of the channels with at least one flag."""
        return tuple(n for n, c in self.channels.items() if c.flags)

    @property
    def ok(self) -> bool:
        """True when no channel is flagged."""
        return not self.flagged

    @property
    def notes(self) -> Mapping[str, tuple[str, ...]]:
        """Per note (keys of `aeroid.io.quality.NOTES`), the channels it applies to."""
        out: dict[str, list[str]] = {}
        for name, c in self.channels.items():
            for note in c.notes:
                out.setdefault(note, []).append(name)
        return MappingProxyType({k: tuple(out[k]) for k in NOTES if k in out})

    @property
    def ranked(self) -> tuple[tuple[str, tuple[str, ...]], ...]:
        """The flags raised, most serious first, each with the channels raising it."""
        out: dict[str, list[str]] = {}
        for name, c in self.channels.items():
            for flag in c.flags:
                out.setdefault(flag, []).append(name)
        order = [f for f in RANKING if f in out] + sorted(set(out) - set(RANKING))
        return tuple((f, tuple(out[f])) for f in order)

    def __getitem__(self, name: str) -> ChannelQuality:
        try:
            return self.channels[name]
        except KeyError:
            raise ChannelError(
                f"no channel {name!r} in the quality report; channels: {list(self.channels)}"
            ) from None

    def summary(self) -> str:
        """A Markdown table: one row per channel, then a legend of the flags raised.

        A whole log's summary ranks the flags first (most serious first, by
        topic), lists what the log holds by design apart, and tabulates only
        the flagged channels.
        """
        head = f"Data quality{f' of {self.source}' if self.source else ''}: "
        head += (
            "no flags"
            if self.ok
            else f"{len(self.flagged)} of {len(self.channels)} channels flagged"
        )
        lines = [head, ""]
        shown = list(self.channels.values())
        if self.whole_log:
            lines += _whole_log_lines(self)
            shown = [c for c in shown if c.flags]
        if shown:
            lines += [
                "| channel | samples | rate (Hz) | jitter | dup. | back | dropouts "
                "| longest gap (s) | saturated | alias share | flags |",
                "|---------|---------|-----------|--------|------|------|----------"
                "|-----------------|-----------|-------------|-------|",
            ]
        for c in shown:
            lines.append(
                f"| {c.name} | {c.n_samples} | {c.rate:.4g} | {c.jitter:.3g} | {c.duplicates} "
                f"| {c.non_increasing} | {c.dropouts} | {c.longest_gap:.4g} | {c.saturation:.3g} "
                f"| {fmt(c.alias_fraction, 3)} | {', '.join(c.flags)} |"
            )
        raised = sorted({f for c in self.channels.values() for f in c.flags})
        if raised:
            lines += ["", *(f"- {f}: {FLAGS[f]}" for f in raised)]
        return "\n".join(lines)


def _topic(name: str) -> str:
    """The topic (message, group) of a log channel: its name before the first dot."""
    return name.partition(".")[0]


def _by_topic(names: Sequence[str], most: int = 6) -> str:
    """``topic (n), ...`` for the topics of `names`, the largest first, `most` shown."""
    counts: dict[str, int] = {}
    for name in names:
        counts[_topic(name)] = counts.get(_topic(name), 0) + 1
    order = sorted(counts, key=lambda t: (-counts[t], t))
    text = ", ".join(f"{t} ({counts[t]})" for t in order[:most])
    return text + (f", ... {len(order) - most} more" if len(order) > most else "")


def _whole_log_lines(report: DataQualityReport) -> list[str]:
    """The ranked defects and the grouped notes of a whole-log report."""
    topics = {_topic(n) for n in report.channels}
    lines = [f"Whole log: {len(report.channels)} channels in {len(topics)} topics."]
    if report.ranked:
        lines += ["", "Defects, most serious first (channels, by topic):", ""]
        for rank, (flag, names) in enumerate(report.ranked, 1):
            lines.append(f"{rank}. {flag}: {len(names)} — {_by_topic(names)}")
    notes = report.notes
    if notes:
        lines += ["", "By design, not defects:", ""]
        for note, names in notes.items():
            lines.append(
                f"- {note}: {len(names)} channels in {len({_topic(n) for n in names})} "
                f"topics, {NOTES[note]}: {_by_topic(names)}"
            )
    return [*lines, ""]


def _option(
    value: Any,
    what: str,
    *,
    low: float,
    high: float = math.inf,
    above: bool = False,
    below: bool = False,
) -> float:
    """A number in [low, high] (above `low` where `above`, below `high` where `below`);
    text and bools are none."""
    out = as_float(value)
    ok = (
        out is not None
        and (low < out if above else low <= out)
        and (out < high if below or high == math.inf else out <= high)
    )
    if not ok or out is None:
        opening = "(" if above else "["
        closing = ")" if below or high == math.inf else "]"
        raise DataFormatError(
            f"{what}: expected a number in {opening}{low:g}, {high:g}{closing}, got {plain(value)}"
        )
    return out


def _runs_at(mask: NDArray[np.bool_], least: int) -> int:
    """Samples of `mask` that lie in runs of `least` or more consecutive True."""
    if not mask.any():
        return 0
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    lengths = ends - starts
    return int(lengths[lengths >= least].sum())


def _held_runs(values: FloatArray, least: int) -> int:
    """Samples in runs of `least` or more consecutive equal values (any value)."""
    if values.size < 2:
        return 0
    same = values[1:] == values[:-1]
    # a run of k equal samples is k - 1 equal neighbours
    edges = np.diff(np.concatenate([[0], same.astype(np.int8), [0]]))
    lengths = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1) + 1
    return int(lengths[lengths >= least].sum())


def _alias_fraction(values: FloatArray, band: float) -> float:
    """Share of the spectrum (mean removed) in the top `band` of the band below Nyquist.

    Welch's estimate: Hann-windowed segments of up to 256 samples, half
    overlapping, each with its mean removed, periodograms averaged.
    """
    n = values.size
    if n < 16:
        return float("nan")
    size = min(256, n)
    hop = size // 2
    starts = np.arange(0, n - size + 1, hop)
    window = np.hanning(size + 2)[1:-1]  # Hann without its two zero end points
    power = np.zeros(size // 2 + 1)
    for start in starts:
        seg = values[start : start + size]
        power += np.abs(np.fft.rfft((seg - seg.mean()) * window)) ** 2
    # one-sided: the bins between DC and Nyquist stand for two
    power[1 : (size + 1) // 2] *= 2.0
    freq = np.fft.rfftfreq(size)  # fractions of the sample rate; Nyquist is 0.5
    total = float(power[1:].sum())
    if not total > 0:
        return 0.0
    return float(power[freq >= 0.5 * (1.0 - band)].sum()) / total


def _check_channel(
    name: str,
    time: FloatArray,
    values: FloatArray,
    *,
    jitter_limit: float,
    dropout_factor: float,
    saturation_run: int,
    alias_band: float,
    alias_limit: float,
) -> ChannelQuality:
    n = int(time.size)
    # a log's channel may hold NaN (PX4 logs an unset field so), a record's cannot
    non_finite = n - int(np.count_nonzero(np.isfinite(values)))
    if n < 2:
        few = ("non_finite", "too_few_samples") if non_finite else ("too_few_samples",)
        return ChannelQuality(
            name, n, 0.0, 0.0, 0, 0, 0, 0.0, 0.0, float("nan"), few, non_finite=non_finite
        )
    steps = np.diff(time)
    forward = steps[steps > 0]
    median = float(np.median(forward)) if forward.size else 0.0
    duplicates = int(np.count_nonzero(steps == 0))
    backwards = int(np.count_nonzero(steps < 0))
    if median > 0:
        # the margin keeps steps of exactly dropout_factor stamps, rounded up, regular
        long = forward > dropout_factor * median * (1 + 1e-9)
        dropouts = int(np.count_nonzero(long))
        regular = forward[~long]
        jitter = float(np.std(regular) / median) if regular.size > 1 else 0.0
        rate = 1.0 / median
    else:
        dropouts, jitter, rate = 0, 0.0, 0.0
    longest = float(steps.max())
    flags: list[str] = []
    if jitter > jitter_limit:
        flags.append("jitter")
    if duplicates:
        flags.append("duplicate_stamps")
    if backwards:
        flags.append("non_increasing_stamps")
    if dropouts:
        flags.append("dropouts")
    finite = values[np.isfinite(values)]
    if non_finite:
        flags.insert(0, "non_finite")
    saturation = 0.0
    alias = float("nan")
    if finite.size and float(np.ptp(finite)) == 0.0:
        flags.append("constant")
    elif finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        held = _runs_at(values == lo, saturation_run) + _runs_at(values == hi, saturation_run)
        saturation = held / n
        # A signal held in runs away from its extremes too (a stepped or doublet input,
        # a slow sensor repeated on a fast grid) has plateaus as its shape: its
        # plateaus at the extremes are not evidence of clipping.
        if held and held > _held_runs(values, saturation_run) - held:
            flags.append("saturation")
        if finite.size == n:
            alias = _alias_fraction(values, alias_band)
            if alias > alias_limit:
                flags.append("aliasing")
    return ChannelQuality(
        name,
        n,
        rate,
        jitter,
        duplicates,
        backwards,
        dropouts,
        longest,
        saturation,
        alias,
        tuple(flags),
        non_finite=non_finite,
    )


def _off_period(time: FloatArray, dropout_factor: float) -> float:
    """Scatter of a log's steps about whole multiples of the topic's period, in periods:
    the period is the median step over the k = 1 .. `_DIVISORS` that fits best (see
    `check_data_quality`); dropouts are left out."""
    steps = np.diff(time)
    forward = steps[steps > 0]
    if forward.size < 2:
        return 0.0
    median = float(np.median(forward))
    best = math.inf
    for k in range(1, _DIVISORS + 1):
        period = median / k
        regular = forward[(forward >= 0.5 * period) & (forward <= dropout_factor * median)]
        if regular.size < 2:
            continue
        ratio = regular / period
        best = min(best, float(np.std(ratio - np.round(ratio))))
    return 0.0 if math.isinf(best) else best


def _longest_frozen(time: FloatArray, values: FloatArray, least: int) -> float:
    """Seconds of the longest run of identical values inside the signal that its own
    rate of repeats makes unlikely (0 when none): a sensor stuck mid-flight.

    A run of k equal samples is k - 1 equal neighbours; with p the share of equal
    neighbours elsewhere in the channel, n p^(k-1) runs that long are expected by
    chance, and the run is frozen when that is below `_FROZEN_CHANCE`. A stepped or
    quantised signal repeats often (p near 1) and is never frozen; a noisy sensor
    (p near 0) is frozen after `least` samples. Runs touching the first or last
    sample (the record starting or ending there) or at the channel's extremes
    (saturation's business) are left out.
    """
    n = values.size
    finite = values[np.isfinite(values)]
    if n < 3 or finite.size < n:
        return 0.0
    same = values[1:] == values[:-1]
    edges = np.diff(np.concatenate([[0], same.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)  # first sample of each run
    ends = np.flatnonzero(edges == -1)  # last sample of each run
    lo, hi = float(finite.min()), float(finite.max())
    inside = (starts > 0) & (ends < n - 1) & (values[starts] != lo) & (values[starts] != hi)
    if not inside.any():
        return 0.0
    lengths = ends - starts + 1
    k = int(lengths[inside].max())
    if k < least:
        return 0.0
    others = n - 1 - (k - 1)
    p = (int(np.count_nonzero(same)) - (k - 1)) / others if others > 0 else 1.0
    if n * p ** (k - 1) >= _FROZEN_CHANCE:
        return 0.0
    j = int(np.flatnonzero(inside & (lengths == k))[0])
    return float(time[ends[j]] - time[starts[j]])


def _as_whole_log(
    c: ChannelQuality,
    time: FloatArray,
    values: FloatArray,
    *,
    jitter_limit: float,
    dropout_factor: float,
    saturation_run: int,
) -> ChannelQuality:
    """The flags of one channel of a whole log, judged as a log (see `check_data_quality`)."""
    judged_here = ("too_few_samples", "constant", "jitter", "non_finite")
    flags = [f for f in c.flags if f not in judged_here]
    notes: list[str] = []
    finite = np.isfinite(values)
    non_finite = c.non_finite
    if c.n_samples == 1:
        notes.append("one_sample")
    elif "too_few_samples" in c.flags:
        flags.append("too_few_samples")  # an empty channel
    if values.size and not finite.any():
        notes.append("never_set")
    elif non_finite:
        flags.insert(0, "non_finite")
    if "constant" in c.flags:
        notes.append("constant")
    off = float("nan")
    if c.n_samples >= 2:
        off = _off_period(time, dropout_factor)
        if off > jitter_limit:
            flags.append("jitter")
        if "dropouts" in flags and c.rate > 0:
            # the first and last steps are the topic's stream starting and stopping
            inner = np.diff(time)[1:-1]
            if not np.any(inner > dropout_factor * (1 + 1e-9) / c.rate):
                flags.remove("dropouts")
    if "saturation" in flags and np.unique(values[finite]).size <= 2:
        flags.remove("saturation")  # a two-state channel's extremes are its states
    frozen = _longest_frozen(time, values, saturation_run) if c.n_samples >= 3 else 0.0
    if frozen > 0:
        flags.insert(0, "frozen")
    ordered = tuple(sorted(flags, key=lambda f: RANKING.index(f) if f in RANKING else 99))
    return replace(
        c, flags=ordered, non_finite=non_finite, frozen=frozen, off_period=off, notes=tuple(notes)
    )


def check_data_quality(
    data: FlightData | FlightLog,
    *,
    channels: Sequence[str] | None = None,
    jitter_limit: float = 0.1,
    dropout_factor: float = 3.0,
    saturation_run: int = 5,
    alias_band: float = 0.1,
    alias_limit: float = 0.2,
) -> DataQualityReport:
    """Check each channel of a record or a log for the faults that spoil identification.

    Parameters
    ----------
    data : FlightData or FlightLog
        A record on one time axis, or a log with each channel on its own stamps.
    channels : sequence of str, optional
        Channels to check. Default: all; for a `FlightLog`, all is a whole-log
        check (see Notes).
    jitter_limit : float, optional
        Flag a channel whose time steps vary by more than this fraction of
        the median step (standard deviation over median, dropouts left out).
    dropout_factor : float, optional
        A step longer than this many median steps is a dropout (> 1).
    saturation_run : int, optional
        Consecutive samples at the channel's extreme value that count as
        saturation (>= 2).
    alias_band : float, optional
        Top share of the band below the Nyquist frequency examined for aliasing.
    alias_limit : float, optional
        Flag a channel with more than this share of its spectrum (mean removed)
        in that top band. A flat (white) spectrum puts `alias_band` there; a
        well-filtered flight signal almost nothing.

    Returns
    -------
    DataQualityReport
        Per channel: jitter, duplicated and backward stamps, dropouts and the
        longest gap, saturation share, alias share, and flags; ``ok`` when no
        channel is flagged, and a Markdown ``summary()``.

    Raises
    ------
    DataFormatError
        `data` is neither a FlightData nor a FlightLog, holds no channel, or
        an option is out of range.
    ChannelError
        A requested channel is missing.

    Notes
    -----
    The spectrum is that of the samples in order, as if evenly spaced at the
    median step; a channel with non-finite values gets no alias share. A
    channel with fewer than 2 samples is flagged ``too_few_samples`` rather
    than refused, so that one empty topic does not hide the rest of a log.

    A whole log (a `FlightLog` without ``channels=``) is judged as a log, because
    much of what the per-channel checks flag is what a logger does by design. The
    numbers are the same; the flags differ:

    * A channel with the same value throughout (a flag, an id, a setting, an unused
      field: most of a PX4 log), one with no finite value at all (PX4 logs an unset
      field as NaN and "no limit" as inf) and one logged once (a topic published on
      an event) get ``notes`` (``constant``, ``never_set``, ``one_sample``), not flags.
    * Stamp jitter is judged against what the logger does. A ULog stamp is the
      sensor's sample time where the topic logs one (`aeroid.read_log` uses
      ``timestamp_sample`` where it can), and PX4's estimator and controllers run
      on the IMU's samples, so a topic's stamps lie on whole multiples of one period. That
      period may be a fraction of the median step (the estimator, at 100 Hz on a
      200 Hz IMU, steps two or three IMU periods), and the logger, which writes a
      topic when its loop finds a new sample, leaves a step of two periods where a
      sample was overwritten first. Neither misplaces a sample: the resampler puts
      each at its own stamp. So the ``jitter`` flag of a whole log looks at how far
      each step (below a dropout) lies from a whole number of periods, the period
      being the median step over the k = 1 .. 4 that fits best (``off_period``, the
      scatter in periods), against `jitter_limit`: a gyro stepping one or two
      periods passes, stamps scattered by a wandering clock do not (a scatter spread
      over the whole period is about 0.29 for every k).
    * ``dropouts`` counts only holes inside a topic's stream: its first and last
      steps are the stream starting and stopping (PX4 writes a topic's first sample
      when it subscribes, the regular stream when logging starts).
    * A channel with at most two values (a switch, a boolean) is not saturated at its
      extremes: they are its states.
    * Two faults are looked for that a record cannot hold: ``non_finite`` (NaN or
      inf in a channel that also holds finite values) and ``frozen`` (a run of
      identical values inside a signal that otherwise changes, longer than its own
      rate of repeats makes likely: a sensor stuck mid-flight).

    ``summary()`` then ranks the flags, most serious first (`RANKING`: lost or stuck
    values, holes, clipping, broken stamps, then jitter and aliasing), by topic, and
    lists the notes apart. A record (`FlightData`) and chosen channels of a log keep
    the per-channel rules above unchanged; a chosen channel's NaN or infinite samples
    are counted (`ChannelQuality.non_finite`) and flagged ``non_finite`` there too, a
    channel without any finite value as well.
    """
    if isinstance(data, FlightData):
        series = {n: (data.time, v) for n, v in data.channels.items()}
    elif isinstance(data, FlightLog):
        series = {n: (c.time, c.values) for n, c in data.channels.items()}
    else:
        raise DataFormatError(
            f"data: expected a FlightData or a FlightLog, got {type(data).__name__}"
        )
    if not series:
        raise DataFormatError("data: no channels to check")
    if channels is not None:
        try:
            names = [channels] if isinstance(channels, str) else list(channels)
        except TypeError:
            raise ChannelError(f"channels: expected channel names, got {plain(channels)}") from None
        for name in names:
            if name not in series:
                raise ChannelError(
                    f"channel {name!r} not found; channels present: {sorted(series)[:50]}"
                )
        series = {n: series[n] for n in names}
    limits = {
        "jitter_limit": _option(jitter_limit, "jitter_limit", low=0.0),
        "dropout_factor": _option(dropout_factor, "dropout_factor", low=1.0, above=True),
        "saturation_run": _option(saturation_run, "saturation_run", low=2.0),
        "alias_band": _option(alias_band, "alias_band", low=0.0, high=1.0, above=True, below=True),
        "alias_limit": _option(alias_limit, "alias_limit", low=0.0, high=1.0),
    }
    if limits["saturation_run"] != int(limits["saturation_run"]):
        raise DataFormatError(f"saturation_run: expected an integer, got {plain(saturation_run)}")
    whole = isinstance(data, FlightLog) and channels is None
    rules = {
        "jitter_limit": limits["jitter_limit"],
        "dropout_factor": limits["dropout_factor"],
        "saturation_run": int(limits["saturation_run"]),
    }
    report = {}
    for name, (time_in, values_in) in series.items():
        time = np.asarray(time_in, dtype=np.float64)
        values = np.asarray(values_in, dtype=np.float64)
        one = _check_channel(
            name,
            time,
            values,
            alias_band=limits["alias_band"],
            alias_limit=limits["alias_limit"],
            **rules,  # type: ignore[arg-type]
        )
        report[name] = _as_whole_log(one, time, values, **rules) if whole else one  # type: ignore[arg-type]
    return DataQualityReport(report, limits, str(data.metadata.get("source", "")), whole)
