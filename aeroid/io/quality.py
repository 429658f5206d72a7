"""Checks on flight data as it arrives: time-stamp jitter, duplicates, dropouts,
saturation and aliasing, per channel, before any identification is run on it."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ChannelError, DataFormatError
from ._logtypes import FlightLog
from .data import FlightData, plain

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
}


@dataclass(frozen=True)
class ChannelQuality:
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


@dataclass(frozen=True)
class DataQualityReport:
    """The data-quality checks of every channel of a record or log.

    Attributes
    ----------
    channels : mapping of str to ChannelQuality
        Per channel, in the order checked.
    thresholds : mapping of str to float
        The limits the flags were raised against.
    source : str
        The file the data came from, when its metadata says so.
    """

    channels: Mapping[str, ChannelQuality]
    thresholds: Mapping[str, float] = field(default_factory=dict)
    source: str = ""

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

    def __getitem__(self, name: str) -> ChannelQuality:
        try:
            return self.channels[name]
        except KeyError:
            raise ChannelError(
                f"no channel {name!r} in the quality report; channels: {list(self.channels)}"
            ) from None

    def summary(self) -> str:
        """A Markdown table: one row per channel, then a legend of the flags raised."""
        head = f"Data quality{f' of {self.source}' if self.source else ''}: "
        head += (
            "no flags"
            if self.ok
            else f"{len(self.flagged)} of {len(self.channels)} channels flagged"
        )
        lines = [
            head,
            "",
            "| channel | samples | rate (Hz) | jitter | dup. | back | dropouts | longest gap (s) "
            "| saturated | alias share | flags |",
            "|---------|---------|-----------|--------|------|------|----------|-----------------"
            "|-----------|-------------|-------|",
        ]
        for c in self.channels.values():
            lines.append(
                f"| {c.name} | {c.n_samples} | {c.rate:.4g} | {c.jitter:.3g} | {c.duplicates} "
                f"| {c.non_increasing} | {c.dropouts} | {c.longest_gap:.4g} | {c.saturation:.3g} "
                f"| {c.alias_fraction:.3g} | {', '.join(c.flags)} |"
            )
        raised = sorted({f for c in self.channels.values() for f in c.flags})
        if raised:
            lines += ["", *(f"- {f}: {FLAGS[f]}" for f in raised)]
        return "\n".join(lines)


def _option(value: Any, what: str, *, low: float, high: float = math.inf) -> float:
    try:
        out = float(value)
        ok = not isinstance(value, bool) and low <= out <= high and not math.isnan(out)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DataFormatError(f"{what}: expected a number in [{low}, {high}], got {plain(value)}")
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
    if n < 2:
        return ChannelQuality(
            name, n, 0.0, 0.0, 0, 0, 0, 0.0, 0.0, float("nan"), ("too_few_samples",)
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
        Channels to check. Default: all.
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
        names = [channels] if isinstance(channels, str) else list(channels)
        for name in names:
            if name not in series:
                raise ChannelError(
                    f"channel {name!r} not found; channels present: {sorted(series)[:50]}"
                )
        series = {n: series[n] for n in names}
    limits = {
        "jitter_limit": _option(jitter_limit, "jitter_limit", low=0.0),
        "dropout_factor": _option(dropout_factor, "dropout_factor", low=1.0),
        "saturation_run": _option(saturation_run, "saturation_run", low=2.0),
        "alias_band": _option(alias_band, "alias_band", low=0.0, high=1.0),
        "alias_limit": _option(alias_limit, "alias_limit", low=0.0, high=1.0),
    }
    if limits["saturation_run"] != int(limits["saturation_run"]):
        raise DataFormatError(f"saturation_run: expected an integer, got {plain(saturation_run)}")
    if not 0.0 < limits["alias_band"] < 1.0:
        raise DataFormatError(f"alias_band: expected a fraction in (0, 1), got {plain(alias_band)}")
    report = {
        name: _check_channel(
            name,
            np.asarray(time, dtype=np.float64),
            np.asarray(values, dtype=np.float64),
            jitter_limit=limits["jitter_limit"],
            dropout_factor=limits["dropout_factor"],
            saturation_run=int(limits["saturation_run"]),
            alias_band=limits["alias_band"],
            alias_limit=limits["alias_limit"],
        )
        for name, (time, values) in series.items()
    }
    return DataQualityReport(report, limits, str(data.metadata.get("source", "")))
