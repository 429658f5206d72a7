"""Smoothing and numerical differentiation of measured signals.

Equation-error regression needs the angular accelerations and other state
derivatives that flight tests rarely measure, and differentiating a noisy
record amplifies its noise by the frequency. Two smoothers are offered:

``"fourier"`` (default)
    Morelli's global Fourier smoother (Klein & Morelli, *Aircraft System
    Identification*, ch. 11). The straight line through the end points is
    removed, which leaves a record that is zero at both ends and so has a
    sine series (DST-I) without end discontinuities. White measurement noise
    spreads evenly over the orthonormal sine coefficients, so the upper half
    of the spectrum gives the noise floor ``σ²`` (its median over the median
    of χ²₁). A low-pass at sine index ``m_c`` then has the expected squared
    error ``Σ_{m>m_c} w_m s_m² + Σ_{m≤m_c} w_m σ²`` (``s_m`` the signal's
    coefficients, ``w_m = ω_m^{2k}`` for the k-th derivative), estimated
    without bias by replacing ``s_m²`` with ``c_m² − σ²``; the cut-off is the
    index that minimises it, i.e. the one where the weighted signal spectrum
    sinks into the noise floor. The smoothed signal or its derivative is the
    truncated series (differentiated term by term) plus the trend line.

``"local"``
    A local polynomial (Savitzky–Golay) fit of degree `polyorder` over a
    sliding window, differentiated analytically; at the ends the polynomial
    of the first and last windows is used, so polynomials up to `polyorder`
    are reproduced exactly everywhere. By default the window's half-width is
    the one with the least estimated squared error: the Fourier method's
    risk with the filter's own response (the smoother's, or the
    differentiator's for a derivative) in place of the brick wall. With
    `cutoff` given, it is the one whose −3 dB frequency (computed from its
    coefficients' frequency response) is nearest to it.

Both need uniformly sampled data and treat every column independently.

No noise floor. The data-chosen cut-off needs white noise to flatten the top
of the spectrum. Band-limited, already smoothed or coarsely sampled data have
a spectrum that keeps falling to the top of the band, the cut-off lands near
the band edge and the "smoothed" signal is the input, nearly unchanged; a
`NoiseFloorWarning` says so (then give `cutoff` in Hz). The test: the median
power of the third and of the top quarter of the sine coefficients agree for
white noise (each median's log scatters by ``1 / (2 f sqrt(n) med)`` with
``f`` the χ²₁ density at its median ``med``); a fall by more than four of
those standard deviations of the difference, and by at least a factor of
two, means no floor.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import small_blas
from ..errors import DataFormatError
from .data import FlightData, positive_number, real_array, whole_number

__all__ = ["NoiseFloorWarning", "differentiate", "optimal_cutoff", "smooth"]

FloatArray = NDArray[np.float64]

_METHODS = ("fourier", "local")
# Median of the χ² distribution with one degree of freedom: the median of the squared
# orthonormal coefficients of white noise is this fraction of its variance.
_CHI2_1_MEDIAN = 0.454936423119572
# The χ²₁ density at that median: it sets the scatter of a sample median.
_CHI2_1_DENSITY_AT_MEDIAN = 0.4711
_HALF_POWER = 2.0**-0.5  # the -3 dB amplitude


class NoiseFloorWarning(UserWarning):
    """The data-chosen cut-off found no white-noise floor (see the module notes)."""


def _as_columns(x: ArrayLike, what: str) -> tuple[FloatArray, bool]:
    arr = np.array(real_array(x, what))  # a copy: the caller's array is never written
    if arr.ndim not in (1, 2):
        raise DataFormatError(f"{what}: expected a 1-D or 2-D array, got shape {arr.shape}")
    one = arr.ndim == 1
    cols = arr[:, None] if one else arr
    if cols.shape[0] < 5:
        raise DataFormatError(f"{what}: need at least 5 samples, got {cols.shape[0]}")
    if not np.all(np.isfinite(cols)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(cols), axis=1))[0])
        raise DataFormatError(f"{what}: non-finite value at sample {bad}")
    return cols, one


def _step(dt: float | None, data: FlightData | None) -> float:
    if data is not None:
        if not data.is_uniform:
            raise DataFormatError(
                "flight data: smoothing and differentiation need a uniform time grid; "
                "resample the record first"
            )
        step = float(np.mean(np.diff(data.time)))
        if dt is not None and not np.isclose(
            positive_number(dt, "dt", " of seconds"), step, rtol=1e-6
        ):
            raise DataFormatError(f"dt: {dt!r} contradicts the data's sample interval {step:.6g} s")
        return step
    if dt is None:
        raise DataFormatError("dt: the sample interval in seconds is required for array input")
    return positive_number(dt, "dt", " of seconds")


def _check_options(method: str, order: int, polyorder: int) -> None:
    if method not in _METHODS:
        raise DataFormatError(f"method: expected one of {_METHODS}, got {method!r}")
    if order not in (0, 1, 2):
        raise DataFormatError(f"order: expected 0, 1 or 2 (derivative order), got {order!r}")
    if isinstance(polyorder, bool) or not isinstance(polyorder, (int, np.integer)):
        raise DataFormatError(f"polyorder: expected an integer, got {polyorder!r}")
    if polyorder < max(order, 1):
        raise DataFormatError(
            f"polyorder: must be at least {max(order, 1)} for this derivative, got {polyorder}"
        )


def _sine_series(col: FloatArray) -> tuple[FloatArray, float, float]:
    """Orthonormal DST-I coefficients of the end-point-detrended column."""
    import scipy.fft  # imported on first use: it costs a large part of a second

    n = col.shape[0]
    ramp = np.linspace(0.0, 1.0, n)
    start, end = float(col[0]), float(col[-1])
    detrended = col - (start + (end - start) * ramp)
    coef = scipy.fft.dst(detrended[1:-1], type=1, norm="ortho")
    return coef, start, end


def _no_floor(power: FloatArray) -> float | None:
    """How far the top quarter of the spectrum sits below the third: None when flat,
    infinite when the floor is round-off (noise-free data)."""
    m = power.shape[0]
    quarter = m // 4
    if quarter < 8:
        return None
    third = float(np.median(power[m // 2 : m // 2 + quarter]))
    top = float(np.median(power[m - quarter :]))
    if top <= (1e3 * np.finfo(float).eps) ** 2 * float(np.max(power)):
        return math.inf
    if third <= 0.0:
        return None
    if top <= 0.0:
        return math.inf
    spread = 1.0 / (2.0 * _CHI2_1_DENSITY_AT_MEDIAN * math.sqrt(quarter) * _CHI2_1_MEDIAN)
    fall = third / top
    return fall if math.log(fall) > max(4.0 * math.sqrt(2.0) * spread, math.log(2.0)) else None


def _noise_power(coef: FloatArray, label: str = "x") -> float:
    """The white-noise floor σ² of the sine coefficients (the upper half's median over the
    χ²₁ median), with a `NoiseFloorWarning` where the spectrum shows none."""
    power = coef**2
    m = power.shape[0]
    fall = _no_floor(power)
    if fall is not None:
        why = (
            "the data carry no noise above round-off"
            if math.isinf(fall)
            else f"the spectrum still falls by a factor {fall:.3g} over its top quarter "
            "(band-limited, already smoothed or coarsely sampled data)"
        )
        warnings.warn(
            NoiseFloorWarning(
                f"{label}: no noise floor found: {why}, so the data-chosen cut-off "
                "leaves the signal (nearly) unchanged; give cutoff= in Hz to smooth it"
            ),
            stacklevel=3,
        )
    return float(np.median(power[m // 2 :])) / _CHI2_1_MEDIAN


def _cutoff_index(coef: FloatArray, order: int, label: str = "x") -> int:
    """Number of sine terms that minimises the estimated squared error (see module doc)."""
    power = coef**2
    m = power.shape[0]
    noise = _noise_power(coef, label)
    weight = np.arange(1, m + 1, dtype=np.float64) ** (2 * order)
    gain = np.cumsum(weight * (power - 2.0 * noise))
    best = int(np.argmax(gain))
    return best + 1 if gain[best] > 0 else 0


def _fourier(
    col: FloatArray, dt: float, order: int, cutoff: float | None, label: str = "x"
) -> FloatArray:
    import scipy.fft  # imported on first use: it costs a large part of a second

    n = col.shape[0]
    coef, start, end = _sine_series(col)
    m = coef.shape[0]
    span = (n - 1) * dt
    if cutoff is None:
        keep = _cutoff_index(coef, order, label)
    else:
        # sine term m has frequency m / (2 T) Hz
        keep = int(min(m, np.floor(2.0 * span * cutoff)))
    kept = coef.copy()
    kept[keep:] = 0.0
    if order == 0:
        inner = scipy.fft.idst(kept, type=1, norm="ortho")
        ramp = np.linspace(0.0, 1.0, n)
        out = start + (end - start) * ramp
        out[1:-1] += inner
        return out
    # d(t) = sqrt(2/(n-1)) Σ c_m sin(π m t / T): differentiate term by term.
    omega = np.pi * np.arange(1, m + 1) / span
    scale = np.sqrt(2.0 / (n - 1))
    if order == 1:
        a = np.zeros(n)
        a[1:-1] = scale * kept * omega
        # DCT-I: y_k = a_0 + (-1)^k a_{n-1} + 2 Σ a_m cos(π k m / (n-1))
        return 0.5 * scipy.fft.dct(a, type=1) + (end - start) / span
    b = -scale * kept * omega**2
    out = np.zeros(n)
    out[1:-1] = 0.5 * scipy.fft.dst(b, type=1)
    # The odd extension forces the series' second derivative to zero at the ends;
    # extrapolate the end samples quadratically from the interior instead.
    out[0] = 3.0 * out[1] - 3.0 * out[2] + out[3]
    out[-1] = 3.0 * out[-2] - 3.0 * out[-3] + out[-4]
    return out


def _local_window(
    col: FloatArray,
    dt: float,
    order: int,
    polyorder: int,
    label: str = "x",
    cutoff: float | None = None,
) -> int:
    """The odd window of the Savitzky–Golay filter: by default the one that minimises the
    estimated squared error of the Fourier method (module notes), else the one whose -3 dB
    frequency is nearest `cutoff` (Hz)."""
    n = col.shape[0]
    smallest = (polyorder + 2 + (polyorder % 2)) // 2
    largest = (n if n % 2 else n - 1) // 2
    if cutoff is None:
        return 2 * _least_risk_half(col, order, polyorder, smallest, largest, label) + 1
    target = cutoff * dt  # cycles per sample
    # the -3 dB frequency falls as the window grows: bisect for the first
    # half-width at or below the target, then take the nearer of it and the one before
    lo, hi = smallest, largest
    if _savgol_minus3db(hi, polyorder) > target:
        return 2 * hi + 1
    while lo < hi:
        mid = (lo + hi) // 2
        if _savgol_minus3db(mid, polyorder) <= target:
            hi = mid
        else:
            lo = mid + 1
    half = lo
    if half > smallest and abs(_savgol_minus3db(half - 1, polyorder) - target) < abs(
        _savgol_minus3db(half, polyorder) - target
    ):
        half -= 1
    return 2 * half + 1


def _least_risk_half(
    col: FloatArray, order: int, polyorder: int, smallest: int, largest: int, label: str
) -> int:
    """The half-width whose filter has the least estimated squared error on this record.

    The Fourier cut-off's risk with the filter's response in place of the brick wall:
    ``Σ_m [(R_m − T_m)² (c_m² − σ²) + R_m² σ²]`` over the sine coefficients ``c_m`` at
    ``ω_m = π m / (n − 1)`` rad per sample, with ``T_m`` the ideal response (1, ω_m,
    −ω_m² for the k-th derivative) and ``R_m`` the Savitzky–Golay filter's (the
    smoother's or the differentiator's own taps): Wiener's trade of the signal a filter
    loses against the noise it passes. Placing the smoother's -3 dB point at the
    Fourier cut-off instead lost 5-13 % of a derivative at two thirds of it.
    """
    import scipy.fft
    import scipy.signal

    coef, _, _ = _sine_series(col)
    noise = _noise_power(coef, label)
    signal = coef**2 - noise
    m = coef.shape[0]
    omega = np.pi * np.arange(1, m + 1, dtype=np.float64) / (m + 1)
    ideal = (np.ones(m), omega, -(omega**2))[order]
    risks: dict[int, float] = {}

    def risk(half: int) -> float:
        if half not in risks:
            # taps applied as a dot product over the window, earliest sample first
            taps = scipy.signal.savgol_coeffs(2 * half + 1, polyorder, deriv=order, use="dot")
            if order == 1:
                # odd taps: response j 2 Σ_k c_k sin(ω k), the DST-I of c_1 .. c_h
                b = np.zeros(m)
                b[:half] = taps[half + 1 :]
                response = scipy.fft.dst(b, type=1)
            else:
                # even taps: c_0 + 2 Σ_k c_k cos(ω k), the DCT-I of c_0 .. c_h
                a = np.zeros(m + 2)
                a[: half + 1] = taps[half:]
                response = scipy.fft.dct(a, type=1)[1 : m + 1]
            risks[half] = float(np.sum((response - ideal) ** 2 * signal + response**2 * noise))
        return risks[half]

    lo, hi = smallest, largest
    while hi - lo > 24:
        grid = np.unique(np.round(np.geomspace(lo, hi, 24)).astype(int))
        best = int(np.argmin([risk(int(h)) for h in grid]))
        lo, hi = int(grid[max(best - 1, 0)]), int(grid[min(best + 1, grid.size - 1)])
    return min(range(lo, hi + 1), key=risk)


def _savgol_minus3db(half: int, polyorder: int) -> float:
    """The frequency, in cycles per sample, where the Savitzky–Golay smoother of
    half-width `half` first falls to 1/sqrt(2) in amplitude."""
    import scipy.signal

    taps = scipy.signal.savgol_coeffs(2 * half + 1, polyorder)
    lags = np.arange(-half, half + 1, dtype=np.float64)

    def gain(f: FloatArray) -> FloatArray:
        # symmetric taps: the response is real
        return np.abs(np.cos(2.0 * np.pi * np.outer(f, lags)) @ taps)

    # Schafer's approximation (p + 1) / (3.2 h - 4.6) x Nyquist brackets the point
    guess = 0.5 * (polyorder + 1) / max(3.2 * half - 4.6, 1.0)
    top = min(0.5, 3.0 * guess)
    grid = np.linspace(0.0, top, 257)
    below = gain(grid) < _HALF_POWER
    if not below.any():
        grid = np.linspace(0.0, 0.5, 4097)
        below = gain(grid) < _HALF_POWER
        if not below.any():
            return 0.5
    i = int(np.argmax(below))
    a, b = float(grid[i - 1]), float(grid[i])
    for _ in range(40):
        m = 0.5 * (a + b)
        if gain(np.array([m]))[0] < _HALF_POWER:
            b = m
        else:
            a = m
    return 0.5 * (a + b)


def _local(
    col: FloatArray,
    dt: float,
    order: int,
    window: int | None,
    polyorder: int,
    label: str = "x",
    cutoff: float | None = None,
) -> FloatArray:
    n = col.shape[0]
    if polyorder >= n:
        raise DataFormatError(
            f"polyorder: a polynomial of degree {polyorder} needs a window of more than "
            f"{polyorder} samples; the record has {n}"
        )
    if window is None:
        w = _local_window(col, dt, order, polyorder, label, cutoff)
    else:
        w = whole_number(window, "window", DataFormatError)
    if w % 2 == 0 or w <= polyorder or w > n:
        raise DataFormatError(
            f"window: expected an odd number of samples above polyorder={polyorder} "
            f"and at most the record length {n}, got {window!r}"
        )
    import scipy.signal  # only this method needs it, and it is slow to import

    return np.asarray(
        scipy.signal.savgol_filter(col, w, polyorder, deriv=order, delta=dt, mode="interp"),
        dtype=np.float64,
    )


def _apply(
    x: ArrayLike,
    what: str,
    dt: float,
    order: int,
    method: str,
    cutoff: float | None,
    window: int | None,
    polyorder: int,
    names: Sequence[str] | None = None,
) -> FloatArray:
    cols, one = _as_columns(x, what)
    if cutoff is not None:
        cutoff = positive_number(cutoff, "cutoff", " (a frequency in Hz)")
        if method == "local" and window is not None:
            raise DataFormatError(
                "cutoff: the local method's window is set by window= or chosen from "
                "cutoff=; give one of them"
            )
    out = np.empty_like(cols)
    for j in range(cols.shape[1]):
        if names is not None:
            label = f"channel {names[j]!r}"
        else:
            label = what if one else f"{what}[:, {j}]"
        if method == "fourier":
            out[:, j] = _fourier(cols[:, j], dt, order, cutoff, label)
        else:
            out[:, j] = _local(cols[:, j], dt, order, window, polyorder, label, cutoff)
    return out[:, 0] if one else out


def _process(
    x: FlightData | ArrayLike,
    channels: str | Sequence[str] | None,
    dt: float | None,
    order: int,
    method: str,
    cutoff: float | None,
    window: int | None,
    polyorder: int,
    tail: str,
) -> FlightData | FloatArray:
    """Smooth (order 0) or differentiate arrays, or channels of flight data.

    Flight data get the result as channel ``name + tail``: the smoothed
    channels replace the originals (``tail=""``), derivatives are added with
    their units divided by s or s^2.
    """
    if not isinstance(x, FlightData):
        if channels is not None:
            raise DataFormatError("channels: only meaningful with FlightData input")
        return _apply(x, "x", _step(dt, None), order, method, cutoff, window, polyorder)
    step = _step(dt, x)
    names = _channel_list(x, channels)
    if not names:
        return x
    if tail:  # derivatives are added: never over a channel the record has
        for n in names:
            if n + tail in x:
                raise DataFormatError(
                    f"suffix: the derivative of {n!r} would replace the channel {n + tail!r} "
                    "the record already has; choose another suffix"
                )
    out = _apply(x.array(names), "channels", step, order, method, cutoff, window, polyorder, names)
    values = {n + tail: out[:, j] for j, n in enumerate(names)}
    if order == 0:
        return x.with_channels(values)
    per = "/s" if order == 1 else "/s^2"
    return x.with_channels(values, {n + tail: x.units[n] + per for n in names if n in x.units})


def _channel_list(data: FlightData, channels: str | Sequence[str] | None) -> list[str]:
    if channels is None:
        return list(data.names)
    if isinstance(channels, str):
        channels = [channels]
    if not isinstance(channels, Sequence) or not all(isinstance(c, str) for c in channels):
        raise DataFormatError(f"channels: expected channel names, got {channels!r}")
    data.require(channels)
    return list(channels)


@small_blas
def optimal_cutoff(x: ArrayLike, *, dt: float, order: int = 0) -> float:
    """The Fourier smoother's data-chosen cut-off frequency in Hz.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled signal.
    dt : float
        Sample interval, s.
    order : int
        0 for the smoothed signal, 1 or 2 for its derivative (the error is
        weighted by ω^(2·order); each term still pays off exactly when its
        signal power beats the noise, so this only decides between
        crossings of the noise floor).

    Returns
    -------
    float
        The frequency of the last sine term kept, ``m_c / (2 T)`` Hz.
    """
    step = _step(dt, None)
    _check_options("fourier", order, 3)
    cols, one = _as_columns(x, "x")
    if not one:
        raise DataFormatError(f"x: expected a 1-D array, got shape {cols.shape}")
    coef, _, _ = _sine_series(cols[:, 0])
    return _cutoff_index(coef, order) / (2.0 * (cols.shape[0] - 1) * step)


@overload
def smooth(
    x: FlightData,
    channels: str | Sequence[str] | None = ...,
    *,
    dt: float | None = ...,
    method: str = ...,
    cutoff: float | None = ...,
    window: int | None = ...,
    polyorder: int = ...,
) -> FlightData: ...
@overload
def smooth(
    x: ArrayLike,
    channels: None = ...,
    *,
    dt: float | None = ...,
    method: str = ...,
    cutoff: float | None = ...,
    window: int | None = ...,
    polyorder: int = ...,
) -> FloatArray: ...
@small_blas
def smooth(
    x: FlightData | ArrayLike,
    channels: str | Sequence[str] | None = None,
    *,
    dt: float | None = None,
    method: str = "fourier",
    cutoff: float | None = None,
    window: int | None = None,
    polyorder: int = 3,
) -> FlightData | FloatArray:
    """Smooth measured signals (see the module notes for the two methods).

    Parameters
    ----------
    x : FlightData or array_like, shape (n,) or (n, k)
        The record, or uniformly sampled signals (columns smoothed separately).
    channels : str or sequence of str, optional
        For flight data, the channels to smooth (default all).
    dt : float, optional
        Sample interval in s; required for array input.
    method : {"fourier", "local"}
        Global Fourier smoother with the data-chosen cut-off, or local
        polynomial (Savitzky–Golay) fit.
    cutoff : float, optional
        A cut-off in Hz instead of the data-chosen one: the Fourier method's,
        or the local method's window's -3 dB frequency (not with `window`).
    window : int, optional
        Local method: odd window length in samples (default: the one with the
        least estimated squared error; see the module notes).
    polyorder : int
        Local method: degree of the local polynomial.

    Returns
    -------
    FlightData or ndarray
        Flight data with the named channels replaced by their smoothed
        versions, or an array shaped like `x`.

    Raises
    ------
    DataFormatError
        Non-uniform time, a missing `dt`, fewer than 5 samples, non-finite
        values or a bad option.
    ChannelError
        A named channel is not in the data.
    """
    _check_options(method, 0, polyorder)
    return _process(x, channels, dt, 0, method, cutoff, window, polyorder, "")


@overload
def differentiate(
    x: FlightData,
    channels: str | Sequence[str] | None = ...,
    *,
    dt: float | None = ...,
    order: int = ...,
    method: str = ...,
    cutoff: float | None = ...,
    window: int | None = ...,
    polyorder: int = ...,
    suffix: str | None = ...,
) -> FlightData: ...
@overload
def differentiate(
    x: ArrayLike,
    channels: None = ...,
    *,
    dt: float | None = ...,
    order: int = ...,
    method: str = ...,
    cutoff: float | None = ...,
    window: int | None = ...,
    polyorder: int = ...,
    suffix: str | None = ...,
) -> FloatArray: ...
@small_blas
def differentiate(
    x: FlightData | ArrayLike,
    channels: str | Sequence[str] | None = None,
    *,
    dt: float | None = None,
    order: int = 1,
    method: str = "fourier",
    cutoff: float | None = None,
    window: int | None = None,
    polyorder: int = 3,
    suffix: str | None = None,
) -> FlightData | FloatArray:
    """Smoothed time derivative of measured signals.

    Parameters
    ----------
    x : FlightData or array_like, shape (n,) or (n, k)
        The record, or uniformly sampled signals (columns differentiated
        separately).
    channels : str or sequence of str, optional
        For flight data, the channels to differentiate (default all).
    dt : float, optional
        Sample interval in s; required for array input.
    order : {1, 2}
        First or second derivative.
    method : {"fourier", "local"}
        See `smooth`. The Fourier cut-off minimises the estimated error of
        the derivative (the error weighted by ω^(2·order)).
    cutoff, window, polyorder
        As for `smooth`.
    suffix : str, optional
        For flight data, the derivative of channel ``q`` is added as
        ``q + suffix``; default ``"_dot"`` (``"_ddot"`` for order 2).

    Returns
    -------
    FlightData or ndarray
        Flight data with the derivative channels added (unit ``<unit>/s``
        where the unit is known), or an array shaped like `x`.

    Raises
    ------
    DataFormatError
        Non-uniform time, a missing `dt`, fewer than 5 samples, non-finite
        values or a bad option.
    ChannelError
        A named channel is not in the data.
    """
    if order not in (1, 2) or isinstance(order, bool):
        raise DataFormatError(
            f"order: expected 1 or 2 (derivative order), got {order!r}"
            + ("; use smooth()" if order == 0 else "")
        )
    _check_options(method, order, polyorder)
    if suffix is not None and (not isinstance(suffix, str) or not suffix):
        raise DataFormatError(f"suffix: expected a non-empty string, got {suffix!r}")
    tail = suffix if suffix is not None else ("_dot" if order == 1 else "_ddot")
    return _process(x, channels, dt, order, method, cutoff, window, polyorder, tail)
