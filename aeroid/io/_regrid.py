"""The engine of `aeroid.io.resampling`: channels of a multi-rate log on one uniform grid.

It works on plain arrays and returns them (`Regridded`), so that the file loaders in
`aeroid.io.data` can use it below `FlightData`; `aeroid.io.resampling.resample` wraps it.

Why a centred convolution with a symmetric FIR rather than ``filtfilt``: an
odd-length symmetric FIR has exactly linear phase with an integer delay of
``(taps - 1) / 2`` samples, so centring the convolution removes the delay
exactly and the filter is zero-phase as designed. ``filtfilt`` would apply it
twice: the magnitude response squares (the ripple the Kaiser design promises
no longer holds) for twice the work, and it buys nothing that a linear-phase
filter lacks. The ends are padded by odd reflection (as ``filtfilt`` pads),
which a constant or a straight line passes unchanged.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .._checks import plain, positive_number, time_label
from .._records import FrozenState
from .._threads import small_blas
from ..errors import ChannelError, DataFormatError
from ._logtypes import FlightLog, LogChannel

__all__ = ["Regridded", "flightlog_parts", "regrid"]

FloatArray = NDArray[np.float64]

_METHODS = ("auto", "linear", "cubic", "hold")
# Anti-aliasing design: flat to 80 % of the new Nyquist frequency, 80 dB down at
# the new Nyquist frequency, so nothing above it folds back by more than 1e-4.
ATTENUATION_DB = 80.0
PASSBAND_FRACTION = 0.8
# A source from 1 % slower than the new rate up is filtered and evaluated band-limited:
# logged rates are nominal (a "50 Hz" topic arrives at 49.8 to 50.3 Hz).
_SAME_RATE = 1.01
# Default largest step between stamps, in the channel's median steps.
GAP_STEPS = 5.0
# Stamps closer to uniform than this (relative to the step) are taken as uniform.
_UNIFORM_RTOL = 1e-6
# Most grid samples one call may make (0.8 GB per channel): a rate beyond that is a slip.
MAX_SAMPLES = 100_000_000
# Extra raw samples kept around the needed range for a cubic: a spline's end
# conditions fade by about 0.27 per sample.
_SPLINE_PAD = 24
# The band-limited evaluation after the filter: flat to 1e-6, images 120 dB down.
_EVAL_DB = 120.0


# Out-of-order stamps are sorted unless the clock steps back by more than this many sample
# intervals with more than this many samples after the step lying before it.
_BACKWARD_STEPS = 3.0


def close_names(name: str, available: Sequence[str]) -> list[str]:
    """Up to three of `available` that look like `name` (for 'did you mean' messages)."""
    return difflib.get_close_matches(name, list(available), n=3, cutoff=0.5)


def missing_channel(name: str, available: Sequence[str], *, role: str = "channel") -> ChannelError:
    """A `ChannelError` naming `name` and the closest of `available`."""
    near = close_names(name, available)
    hint = f"; did you mean {near}?" if near else ""
    shown = sorted(available)
    listing = shown if len(shown) <= 12 else [*shown[:12], f"... {len(shown) - 12} more"]
    return ChannelError(f"{role} {name!r} not found in the log{hint} (channels: {listing})")


@dataclass(frozen=True)
class Source(FrozenState):
    """One raw channel after cleaning: strictly increasing stamps, finite values."""

    name: str
    time: FloatArray
    values: FloatArray
    unit: str
    duplicates: int  # stamps that repeated an earlier one (their values averaged)
    reordered: int  # steps that went backwards before sorting

    @property
    def step(self) -> float:
        """Median step between stamps in seconds."""
        return float(np.median(np.diff(self.time)))


def flightlog_parts(
    log: Any,
) -> tuple[dict[str, Any], tuple[tuple[float, str, str], ...], dict[str, Any]]:
    """The raw channels (name -> LogChannel or (time, values[, unit])), events, metadata
    of a `FlightLog` or a mapping (`aeroid.io.resampling.log_parts` adds `FlightData`)."""
    if isinstance(log, FlightLog):
        events = tuple((float(e.time), str(e.kind), str(e.value)) for e in log.events)
        return dict(log.channels), events, dict(log.metadata)
    if isinstance(log, Mapping):
        return dict(log), (), {}
    raise DataFormatError(
        "log: expected a FlightLog, FlightData or a mapping of channel name to "
        f"(time, values), got {type(log).__name__}"
    )


def clean_source(name: str, raw: Any) -> Source:
    """Check, sort and de-duplicate one raw channel, naming it in every error."""
    unit = ""
    if isinstance(raw, LogChannel):
        time_in, values_in, unit = raw.time, raw.values, raw.unit
    elif isinstance(raw, (tuple, list)) and len(raw) in (2, 3):
        time_in, values_in = raw[0], raw[1]
        unit = str(raw[2]) if len(raw) == 3 else ""
    else:
        raise DataFormatError(
            f"channel {name!r}: expected a LogChannel or a (time, values[, unit]) pair, "
            f"got {type(raw).__name__}"
        )
    if np.iscomplexobj(time_in) or np.iscomplexobj(values_in):
        # casting would silently drop the imaginary part
        raise DataFormatError(
            f"channel {name!r}: complex values are not supported; pass the real part or "
            "the magnitude explicitly (np.real, np.abs)"
        )
    try:
        time = np.array(time_in, dtype=np.float64)
        values = np.array(values_in, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(f"channel {name!r}: not numeric ({exc})") from None
    if time.ndim != 1 or values.shape != time.shape:
        raise DataFormatError(
            f"channel {name!r}: time and values must be 1-D of one length "
            f"(got {time.shape} and {values.shape})"
        )
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise DataFormatError(f"channel {name!r}: non-finite time stamp at index {int(bad[0])}")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raise DataFormatError(
            f"channel {name!r}: {plain(values[i])} value at t = {time_label(time[i])} s "
            f"(sample {i})"
        )
    steps = np.diff(time)
    reordered = int(np.count_nonzero(steps < 0))
    if reordered:
        # Stamps a sample or two out of order (packets logged late) sort into place; a
        # clock that jumps back further would interleave two stretches of the record.
        forward = steps[steps > 0]
        typical = float(np.median(forward)) if forward.size else 0.0
        back = int(np.argmin(steps))
        # a stale stamp or two re-sent late sort into place; a run of them is a stretch
        overlap = int(np.count_nonzero(time[back + 1 :] < time[back]))
        if -steps[back] > _BACKWARD_STEPS * typical and overlap > _BACKWARD_STEPS:
            raise DataFormatError(
                f"channel {name!r}: time steps back by {-steps[back]:.6g} s at sample "
                f"{back + 1} (from t = {time[back]:.6g} s to {time[back + 1]:.6g} s), "
                f"more than {_BACKWARD_STEPS:g} sample intervals: the clock jumped or two "
                "records were joined; sorting would interleave them. Load the stretches "
                "on either side separately (t0/t1)"
            )
        order = np.argsort(time, kind="stable")
        time, values = time[order], values[order]
    duplicates = int(np.count_nonzero(np.diff(time) == 0))
    if duplicates:
        time, first, inverse, counts = np.unique(
            time, return_index=True, return_inverse=True, return_counts=True
        )
        # Average the deviations from each group's first value, so that repeated
        # equal values stay exactly equal.
        base = values[first]
        values = base + np.bincount(inverse, weights=values - base[inverse]) / counts
    if time.size < 2:
        raise DataFormatError(
            f"channel {name!r}: needs at least 2 distinct time stamps, got {time.size}"
        )
    time.setflags(write=False)
    values.setflags(write=False)
    return Source(name, time, values, unit, duplicates, reordered)


def _seconds(value: Any, what: str) -> float:
    try:
        out = float(value)
        ok = not isinstance(value, (bool, str, bytes)) and math.isfinite(out)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise DataFormatError(f"{what}: expected a finite time in seconds, got {plain(value)}")
    return out


def _mapping(channels: Any) -> dict[str, str]:
    """`channels` as model name -> log channel name."""
    if isinstance(channels, Mapping):
        mapping = {}
        for key, value in channels.items():
            if not isinstance(key, str) or not key or not isinstance(value, str) or not value:
                raise DataFormatError(
                    f"channels: expected model name -> log channel name strings, got "
                    f"{key!r}: {value!r}"
                )
            mapping[key] = value
    elif isinstance(channels, str):
        mapping = {channels: channels}
    elif isinstance(channels, Sequence):
        mapping = {}
        for name in channels:
            if not isinstance(name, str) or not name:
                raise DataFormatError(f"channels: expected channel names, got {name!r}")
            if name in mapping:
                raise DataFormatError(f"channels: {name!r} is listed twice")
            mapping[name] = name
    else:
        raise DataFormatError(
            "channels: expected a sequence of log channel names or a mapping of model "
            f"name to log channel name, got {type(channels).__name__}"
        )
    if not mapping:
        raise DataFormatError("channels: no channel chosen")
    return mapping


def _per_channel(option: Any, what: str, names: Sequence[str]) -> dict[str, Any]:
    """A scalar option, or a mapping from model name to option, as one value per name."""
    if isinstance(option, Mapping):
        unknown = sorted(set(option) - set(names))
        if unknown:
            raise DataFormatError(
                f"{what}: names {unknown} are not among the channels {list(names)}"
            )
        return {n: option.get(n) for n in names}
    return dict.fromkeys(names, option)


def _kaiser_order(ripple_db: float, width: float) -> tuple[int, float]:
    """Taps and β of a Kaiser-window FIR: `ripple_db` down, transition `width` (× Nyquist).

    Kaiser's formulas (Oppenheim & Schafer, "Discrete-Time Signal Processing",
    sec. 7.5.3), as ``scipy.signal.kaiserord`` states them.
    """
    a = abs(ripple_db)
    if a > 50.0:
        beta = 0.1102 * (a - 8.7)
    elif a > 21.0:
        beta = 0.5842 * (a - 21.0) ** 0.4 + 0.07886 * (a - 21.0)
    else:
        beta = 0.0
    return math.ceil((a - 7.95) / 2.285 / (np.pi * width) + 1.0), beta


def _windowed_sinc(numtaps: int, cutoff: float, beta: float) -> FloatArray:
    """Low-pass taps, `cutoff` as a fraction of Nyquist, Kaiser window, unit DC gain.

    The ideal impulse response ``c sinc(c m)`` times a symmetric Kaiser window,
    scaled to sum to one (``scipy.signal.firwin`` with ``window=("kaiser", β)``).
    """
    m = np.arange(numtaps) - 0.5 * (numtaps - 1)
    h = cutoff * np.sinc(cutoff * m) * np.kaiser(numtaps, beta)
    return np.asarray(h / np.sum(h), dtype=np.float64)


def design_anti_alias(source_rate: float, rate: float) -> tuple[FloatArray, dict[str, Any]]:
    """The zero-phase low-pass that precedes decimation from `source_rate` to `rate` (Hz).

    Kaiser-window FIR (Kaiser's order and β formulas, windowed sinc): flat
    (ripple 1e-4) up to `PASSBAND_FRACTION` of the new Nyquist frequency and
    80 dB down from the new Nyquist frequency on. The tap count is made odd so
    that the delay is a whole number of samples.
    """
    nyquist = rate / 2.0
    f_pass, f_stop = PASSBAND_FRACTION * nyquist, nyquist
    width = (f_stop - f_pass) / (source_rate / 2.0)
    numtaps, beta = _kaiser_order(ATTENUATION_DB, width)
    numtaps = int(numtaps) | 1
    cutoff = 0.5 * (f_pass + f_stop)
    taps = _windowed_sinc(numtaps, cutoff / (source_rate / 2.0), beta)
    half = (numtaps - 1) // 2
    return taps, {
        "design": "linear-phase FIR, Kaiser window (Kaiser's order formula, windowed sinc)",
        "applied": "centred convolution, odd-reflection padding (zero phase, zero delay)",
        "taps": numtaps,
        "beta": float(beta),
        "cutoff_hz": float(cutoff),
        "passband_edge_hz": float(f_pass),
        "stopband_edge_hz": float(f_stop),
        "attenuation_db": ATTENUATION_DB,
        "edge_s": float(half / source_rate),
    }


def _convolve_valid(values: FloatArray, taps: FloatArray) -> FloatArray:
    """``np.convolve(values, taps, "valid")`` by FFT overlap-add for long filters."""
    n, k = values.size, taps.size
    if k < 64 or n < 4 * k:
        return np.asarray(np.convolve(values, taps, mode="valid"), dtype=np.float64)
    size = 1 << (8 * k - 1).bit_length()  # blocks of ~8 filter lengths: little overlap waste
    step = size - k + 1
    blocks = -(-n // step)
    padded = np.zeros(blocks * step)
    padded[:n] = values
    spec = np.fft.rfft(padded.reshape(blocks, step), size, axis=1) * np.fft.rfft(taps, size)
    pieces = np.fft.irfft(spec, size, axis=1)  # (blocks, size): each block's full convolution
    full = np.zeros((blocks + 1, step))
    full[:blocks] = pieces[:, :step]
    full[1:, : k - 1] += pieces[:, step:]
    return np.asarray(full.ravel()[k - 1 : n], dtype=np.float64)


def _fir_zero_phase(values: FloatArray, taps: FloatArray) -> FloatArray:
    """`values` filtered by the symmetric, odd-length `taps` with no delay."""
    half = (taps.size - 1) // 2
    padded = np.pad(values, half, mode="reflect", reflect_type="odd")
    return _convolve_valid(padded, taps)


def _lagrange4(time: FloatArray, values: FloatArray, at: FloatArray) -> FloatArray:
    """Four-point cubic (Lagrange) interpolation on any increasing stamps.

    Local, so its cost grows with the points asked for, not with the series;
    for a sine of frequency f on steps h the error is at most
    (3/128) (2 pi f h)^4 of its amplitude. A point on a stamp gets that
    sample exactly.
    """
    i = np.clip(np.searchsorted(time, at, side="right") - 2, 0, time.size - 4)
    nodes = [time[i + k] for k in range(4)]
    out = np.zeros(at.shape)
    for k in range(4):
        weight = np.ones(at.shape)
        for j in range(4):
            if j != k:
                weight *= (at - nodes[j]) / (nodes[k] - nodes[j])
        out += weight * values[i + k]
    return out


def _band_limited_design(source_rate: float, rate: float) -> tuple[int, float, float]:
    """Half-length (source samples), cut-off (cycles per sample, times two) and β of
    the Kaiser-windowed sinc that evaluates filtered samples between their stamps.

    After the anti-aliasing filter the samples hold nothing above the new Nyquist
    frequency ``rate / 2``, so their first image starts at ``source_rate - rate / 2``;
    a kernel flat (1e-6) to `PASSBAND_FRACTION` of the new Nyquist frequency and
    `_EVAL_DB` down from that image on reconstructs the band between the stamps.
    """
    f_pass = PASSBAND_FRACTION * rate / 2.0
    f_stop = source_rate - rate / 2.0
    numtaps, beta = _kaiser_order(_EVAL_DB, (f_stop - f_pass) / (source_rate / 2.0))
    return max(2, -(-numtaps // 2)), (f_pass + f_stop) / source_rate, beta


# Fractional positions at which the band-limited weights are tabulated: linear
# interpolation between them errs by about (pi / 4096)^2 / 8, under 1e-6.
_EVAL_NODES = 4096


@functools.lru_cache(maxsize=16)
def _band_limited_table(source_rate: float, rate: float) -> tuple[FloatArray, FloatArray]:
    """The `_band_limited_design` weights of the taps ``-half ... half`` around the
    nearest stamp, for fractional positions ``f`` from -1/2 to 1/2 in `_EVAL_NODES`
    steps, and their differences from one position to the next.

    Each row is corrected to sum to one with no first moment (a local linear fit's
    weights), so that a constant and a line are kept exactly, as the filter keeps
    them; for a band-limited signal the correction is of the kernel's ripple. Rows
    interpolated linearly in ``f`` keep both properties.
    """
    half, band, beta = _band_limited_design(source_rate, rate)
    lags = np.arange(-half, half + 1)
    f = np.linspace(-0.5, 0.5, _EVAL_NODES + 1)
    dist = f[:, None] - lags  # t - t_k in samples, within half + 1/2
    ratio = np.clip(dist / (half + 0.5), -1.0, 1.0)
    weight = np.sinc(band * dist) * np.i0(beta * np.sqrt(1.0 - ratio**2))
    s0 = weight.sum(axis=1)
    s1 = (weight * dist).sum(axis=1)
    s2 = (weight * dist**2).sum(axis=1)
    weight *= (s2[:, None] - s1[:, None] * dist) / (s0 * s2 - s1 * s1)[:, None]
    step = np.diff(weight, axis=0)
    weight.setflags(write=False)
    step.setflags(write=False)
    return weight, step


def _band_limited(
    time: FloatArray, values: FloatArray, at: FloatArray, source_rate: float, rate: float
) -> FloatArray:
    """``sum_k x_k h(t - t_k)`` at `at` for samples `values` on the (uniform) stamps
    `time`, ``h`` the `_band_limited_design` kernel (`_band_limited_table`); beyond
    the ends the samples are odd reflections, as the filter pads."""
    weight, step = _band_limited_table(source_rate, rate)
    half = (weight.shape[1] - 1) // 2
    padded = np.pad(values, half + 1, mode="reflect", reflect_type="odd")
    out = np.empty(at.shape)
    block = max(1, (1 << 18) // weight.shape[1])  # bound the (points x taps) temporaries
    for a in range(0, at.size, block):
        t = at[a : a + block]
        # the position between the stamps themselves: no drift from a nominal step
        base = np.clip(np.searchsorted(time, t, side="right") - 1, 0, time.size - 2)
        frac = (t - time[base]) / (time[base + 1] - time[base])
        near = base + (frac >= 0.5)
        node = (frac - (frac >= 0.5) + 0.5) * _EVAL_NODES
        row = np.clip(node.astype(np.int64), 0, _EVAL_NODES - 1)
        w = weight[row] + (node - row)[:, None] * step[row]
        taps = padded[near[:, None] + np.arange(1, 2 * half + 2)]
        out[a : a + block] = np.einsum("ij,ij->i", w, taps)
    return out


def _interpolate(time: FloatArray, values: FloatArray, at: FloatArray, kind: str) -> FloatArray:
    if time.size < 4 or kind == "linear":
        return np.interp(at, time, values)
    if kind == "cubic4":
        return _lagrange4(time, values, at)
    from scipy.interpolate import CubicSpline

    return np.asarray(CubicSpline(time, values)(at), dtype=np.float64)


_DESCRIPTION = {
    "linear": "linear",
    "cubic": "cubic spline (not-a-knot)",
    "band": "band-limited: Kaiser-windowed sinc through the filtered samples",
}


def _gaps(src: Source, lo: float, hi: float, max_gap: float) -> tuple[FloatArray, FloatArray]:
    """Start times and lengths of the steps longer than `max_gap` that touch [lo, hi]."""
    t = src.time
    steps = np.diff(t)
    touching = (t[1:] > lo) & (t[:-1] < hi) & (steps > max_gap)
    idx = np.flatnonzero(touching)
    return t[idx], steps[idx]


def _on_grid(src: Source, grid: FloatArray) -> bool:
    """Whether every grid point is one of the source's stamps (to rounding)."""
    at = np.searchsorted(src.time, grid).clip(0, src.time.size - 1)
    near = np.minimum(np.abs(src.time[at] - grid), np.abs(src.time[at - 1] - grid))
    return bool(np.all(near <= 1e-9 * max(src.step, 1e-300) + 1e-12 * np.abs(grid)))


def _resample_one(
    src: Source, grid: FloatArray, rate: float, method: str, max_gap: float
) -> tuple[FloatArray, dict[str, Any]]:
    """`src` on `grid` with the record of what was done."""
    source_rate = 1.0 / src.step
    # a source at about the grid's rate is filtered and evaluated band-limited too:
    # interpolated straight across, a 19 Hz tone from 50.5 to 50 Hz kept 61 %; a
    # source whose stamps are the grid's points is copied
    decimate = method != "hold" and source_rate > rate / _SAME_RATE
    if decimate and source_rate <= _SAME_RATE * rate:
        decimate = not _on_grid(src, grid)
    kind = "linear" if method in ("auto", "linear") else method
    taps: FloatArray | None = None
    design: dict[str, Any] | None = None
    lo, hi = float(grid[0]), float(grid[-1])
    if decimate:
        taps, design = design_anti_alias(source_rate, rate)
        # After the filter the signal is band-limited below the new Nyquist
        # frequency. A local cubic droops where the source has few samples per
        # cycle (7.6 % at 15 Hz from 60 Hz); a windowed sinc, short where the
        # source is fast, reconstructs the band between the stamps at any ratio.
        if method in ("auto", "cubic"):
            kind = "band"
            # how far the evaluation reaches into filtered samples the ends' padding touched
            reach = _band_limited_design(source_rate, rate)[0] / source_rate
            design["evaluation_reach_s"] = float(reach)
        lo -= design["edge_s"]
        hi += design["edge_s"]
    info: dict[str, Any] = {
        "source_rate_hz": float(source_rate),
        "samples": int(src.time.size),
        "method": "hold" if method == "hold" else ("cubic" if kind == "band" else kind),
        "interpolation": "last value held" if method == "hold" else _DESCRIPTION[kind],
        "anti_alias": design,
        "duplicate_stamps": src.duplicates,
        "reordered_stamps": src.reordered,
        "max_gap_s": "inf" if math.isinf(max_gap) else float(max_gap),
    }
    starts, lengths = _gaps(src, lo, hi, max_gap)
    if starts.size and math.isfinite(max_gap):
        raise DataFormatError(
            f"channel {src.name!r}: gap of {lengths[0]:.6g} s in the stamps starting at "
            f"t = {time_label(starts[0])} s (after sample "
            f"{int(np.searchsorted(src.time, starts[0], side='right')) - 1}; longer than "
            f"max_gap = {max_gap:.6g} s"
            f"{'' if starts.size == 1 else f'; {starts.size} such gaps'}); resample around "
            "it with t0/t1, or pass max_gap=float('inf') to interpolate across it"
        )
    if math.isinf(max_gap):
        slow = _gaps(src, lo, hi, GAP_STEPS * src.step)
        info["bridged_gaps"] = [[float(a), float(b)] for a, b in zip(*slow, strict=True)][:20]
    if method == "hold":
        idx = np.searchsorted(src.time, grid, side="right") - 1
        info["uniformized"] = False
        return src.values[np.clip(idx, 0, None)], info
    # Only the stamps that reach the grid (through the filter, for decimation).
    pad = _SPLINE_PAD if kind == "cubic" else 1
    if kind == "band":  # the filtered samples the sinc reaches, clear of the filter's ends
        pad = max(_SPLINE_PAD, _band_limited_design(source_rate, rate)[0] + 1)
    a = max(int(np.searchsorted(src.time, lo, side="right")) - 1 - pad, 0)
    b = min(int(np.searchsorted(src.time, hi, side="left")) + 1 + pad, src.time.size)
    time, values = src.time[a:b], src.values[a:b]
    # Deviations from one sample, so that a constant channel stays exactly constant.
    # values near the float range are filtered scaled by a power of two (exact): the
    # filter's sums of many of them would overflow
    peak = float(np.max(np.abs(values))) if values.size else 0.0
    scale = math.ldexp(1.0, math.frexp(peak)[1] - 1) if peak > 2.0**600 else 1.0
    values = values / scale
    base = float(values[0])
    values = values - base
    info["uniformized"] = False
    if taps is not None:
        step = 1.0 / source_rate
        steps = np.diff(time)
        if float(np.max(np.abs(steps - step))) > _UNIFORM_RTOL * step:
            n = int(np.floor((time[-1] - time[0]) / step + 1e-9)) + 1
            uniform = time[0] + np.arange(n) * step
            # at the source rate, before the filter: many samples per cycle of the band
            values = _interpolate(time, values, uniform, "cubic4" if kind == "band" else kind)
            time = uniform
            info["uniformized"] = True
        values = _fir_zero_phase(values, taps)
        if kind == "band":
            out = _band_limited(time, values, grid, source_rate, rate)
            return (out + base) * scale, info
    return (_interpolate(time, values, grid, kind) + base) * scale, info


def _given_gap(max_gap: Any) -> Any:
    """`max_gap` as the caller gave it, in plain JSON (infinity as "inf")."""
    if isinstance(max_gap, Mapping):
        return {str(k): _given_gap(v) for k, v in max_gap.items()}
    if max_gap is None:
        return None
    return "inf" if math.isinf(float(max_gap)) else float(max_gap)


def _jsonable(value: Any) -> bool:
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return True


class Regridded(NamedTuple):
    """What `regrid` returns: the fields of a `FlightData`, not yet checked into one."""

    time: FloatArray
    channels: dict[str, FloatArray]
    units: dict[str, str]
    metadata: dict[str, Any]


@small_blas
def regrid(
    raw: Mapping[str, Any],
    events: Sequence[tuple[float, str, str]],
    log_meta: Mapping[str, Any],
    channels: Sequence[str] | Mapping[str, str],
    *,
    rate: float,
    t0: float | None = None,
    t1: float | None = None,
    max_gap: float | Mapping[str, float] | None = None,
    method: str | Mapping[str, str] = "auto",
) -> Regridded:
    """`aeroid.io.resampling.resample` on a log's parts (see there)."""
    mapping = _mapping(channels)
    rate = positive_number(rate, "rate", " in Hz")
    names = list(mapping)
    methods = _per_channel(method, "method", names)
    for name, m in methods.items():
        m = "auto" if m is None else m
        if m not in _METHODS:
            raise DataFormatError(f"method for {name!r}: expected one of {_METHODS}, got {m!r}")
        methods[name] = m
    gaps = _per_channel(max_gap, "max_gap", names)
    for name, g in gaps.items():
        if g is not None:
            gaps[name] = (
                float("inf")
                if g == float("inf")
                else positive_number(g, f"max_gap for {name!r}", " of seconds")
            )

    sources: dict[str, Source] = {}
    for model_name, log_name in mapping.items():
        if log_name not in raw:
            raise missing_channel(log_name, list(raw))
        sources[model_name] = clean_source(log_name, raw[log_name])

    starts = {n: float(s.time[0]) for n, s in sources.items()}
    ends = {n: float(s.time[-1]) for n, s in sources.items() if methods[n] != "hold"}
    first = max(starts, key=lambda n: starts[n])
    lo = starts[first]
    last = min(ends, key=lambda n: ends[n]) if ends else None
    hi = ends[last] if last is not None else max(float(s.time[-1]) for s in sources.values())
    if not hi > lo:
        raise DataFormatError(
            f"channels {mapping[first]!r} (from {lo:.6g} s) and "
            f"{mapping[last] if last else mapping[first]!r} (to {hi:.6g} s) do not overlap in time"
        )
    span_start, span_end = lo, hi
    if t0 is not None:
        t0 = _seconds(t0, "t0")
        if t0 < lo:
            raise DataFormatError(
                f"t0 = {plain(t0)} s is before channel {mapping[first]!r} starts ({lo:.6g} s)"
            )
        span_start = t0
    if t1 is not None:
        t1 = _seconds(t1, "t1")
        if t1 > hi:
            who = mapping[last] if last is not None else "the log"
            raise DataFormatError(f"t1 = {plain(t1)} s is after channel {who!r} ends ({hi:.6g} s)")
        span_end = t1
    if not span_end > span_start:
        raise DataFormatError(f"need t1 > t0, got t0={span_start:.6g} s, t1={span_end:.6g} s")
    count = (span_end - span_start) * rate  # checked before the grid is allocated
    if not count < MAX_SAMPLES:
        fastest = max(1.0 / s.step for s in sources.values())
        raise DataFormatError(
            f"rate: {rate:g} Hz over the {span_end - span_start:.6g} s window makes "
            f"{count:.4g} samples per channel, more than the {MAX_SAMPLES:.0e} allowed "
            f"(the fastest chosen channel is logged at {fastest:.4g} Hz); choose a lower "
            "rate or a shorter window with t0/t1"
        )
    n = int(np.floor(count + 1e-9)) + 1
    if n < 2:
        raise DataFormatError(
            f"the window [{span_start:.6g}, {span_end:.6g}] s holds fewer than 2 samples at "
            f"{rate:g} Hz"
        )
    grid = span_start + np.arange(n) / rate

    out: dict[str, FloatArray] = {}
    units: dict[str, str] = {}
    records: dict[str, Any] = {}
    for name, src in sources.items():
        gap = gaps[name]
        if gap is None:
            gap = float("inf") if methods[name] == "hold" else GAP_STEPS * src.step
        values, info = _resample_one(src, grid, rate, methods[name], gap)
        out[name] = values
        if src.unit:
            units[name] = src.unit
        records[name] = {"source": mapping[name], "unit": src.unit, **info}

    meta: dict[str, Any] = {}
    for key, value in log_meta.items():
        value = value.item() if isinstance(value, np.generic) else value
        if isinstance(key, str) and _jsonable(value):
            meta[key] = value
    meta["resampling"] = {
        "rate_hz": rate,
        "window": [float(grid[0]), float(grid[-1])],
        "span": [lo, hi],
        "mapping": dict(mapping),
        "method": dict(method) if isinstance(method, Mapping) else method,
        "max_gap": _given_gap(max_gap),
        "channels": records,
    }
    meta["events"] = [[t, kind, value] for t, kind, value in events]
    return Regridded(grid, out, units, meta)
