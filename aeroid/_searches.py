"""Small numerical tools in plain numpy for the error-bar path of a first fit (internal).

Importing `scipy.optimize` costs a few tenths of a second (it pulls in
`scipy.sparse`, `scipy.linalg` and more), `scipy.fft` and `scipy.ndimage`
a tenth or two each: more than a whole first fit of a real record. The noise
model behind coloured error bars needs only a bounded scalar minimum, a
two-parameter simplex search, an orthonormal DCT-II and a mirrored smoothing,
all here:

* `bounded_minimum`: Brent's method (golden sections with parabolic steps;
  Forsythe, Malcolm & Moler, *Computer Methods for Mathematical Computations*,
  1977, routine FMIN) on an interval;
* `nelder_mead`: the simplex search of Nelder & Mead (1965) with the standard
  coefficients (reflection 1, expansion 2, contraction 1/2, shrink 1/2; Lagarias
  et al. 1998), stopped when the simplex is `xatol` small and its values
  `fatol` close, or after `maxfev` evaluations;
* `dct2`: the orthonormal DCT-II along the last axis through one complex FFT
  of the even-odd reordered sequence (Makhoul 1980);
* `mirror_smooth`: a symmetric weighted moving sum along axis 0 with the ends
  reflected about the edge samples (``d c b | a b c d | c b a``);
* `welch_density`: Welch's averaged one-sided periodogram (half-overlapping Hann
  segments, each less its least-squares line), the spectrum data compatibility
  reads its input-noise floor from, without `scipy.signal`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ._records import FrozenState

FloatArray = NDArray[np.float64]

_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))
_SQRT_EPS = math.sqrt(2.2e-16)  # as FMIN: about the square root of the rounding unit


@dataclass(frozen=True)
class SearchResult(FrozenState):
    """Where a search stopped: the point, its value and the evaluations spent."""

    x: FloatArray
    fun: float
    nfev: int


def bounded_minimum(
    fn: Callable[..., float], lo: float, hi: float, *, xatol: float = 1e-5, maxfev: int = 500
) -> SearchResult:
    """A local minimum of `fn` on [lo, hi] by Brent's method, to about `xatol`."""
    a, b = float(lo), float(hi)
    # x: best so far; w: second best; v: the one before (FMM's names)
    x = w = v = a + _GOLDEN * (b - a)
    fx = fw = fv = float(fn(x))
    nfev = 1
    d = e = 0.0
    mid = 0.5 * (a + b)
    tol1 = _SQRT_EPS * abs(x) + xatol / 3.0
    tol2 = 2.0 * tol1
    while abs(x - mid) > tol2 - 0.5 * (b - a):
        golden = True
        if abs(e) > tol1:
            # a parabola through x, w, v
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            e_before = e
            e = d
            if abs(p) < abs(0.5 * q * e_before) and q * (a - x) < p < q * (b - x):
                d = p / q
                u = x + d
                golden = False
                if (u - a) < tol2 or (b - u) < tol2:
                    # too close to an end: a minimal step towards the middle
                    d = tol1 if mid >= x else -tol1
        if golden:
            e = (a - x) if x >= mid else (b - x)
            d = _GOLDEN * e
        step = max(abs(d), tol1)
        u = x + (step if d >= 0.0 else -step)
        fu = float(fn(u))
        nfev += 1
        if fu <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv = w, fw
            w, fw = x, fx
            x, fx = u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv = w, fw
                w, fw = u, fu
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
        mid = 0.5 * (a + b)
        tol1 = _SQRT_EPS * abs(x) + xatol / 3.0
        tol2 = 2.0 * tol1
        if nfev >= maxfev:
            break
    return SearchResult(np.array([x]), fx, nfev)


def nelder_mead(
    fn: Callable[..., float],
    simplex: FloatArray,
    *,
    xatol: float = 1e-4,
    fatol: float = 1e-4,
    maxfev: int = 200,
) -> SearchResult:
    """A local minimum of `fn` by the Nelder–Mead simplex search from `simplex`
    (n + 1, n): stops when every vertex lies within `xatol` (each coordinate) of
    the best and every value within `fatol` of its, or after `maxfev` evaluations."""
    sim = np.array(simplex, dtype=np.float64)
    n = sim.shape[1]
    nfev = 0

    def value(point: FloatArray) -> float:
        nonlocal nfev
        if nfev >= maxfev:
            raise _Exhausted
        nfev += 1
        return float(fn(point))

    fsim = np.array([value(s) for s in sim])
    try:
        while True:
            order = np.argsort(fsim, kind="stable")
            sim, fsim = sim[order], fsim[order]
            if nfev >= maxfev or (
                np.max(np.abs(sim[1:] - sim[0])) <= xatol
                and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol
            ):
                break
            centre = np.add.reduce(sim[:-1], axis=0) / n
            worst = sim[-1]
            xr = 2.0 * centre - worst
            fr = value(xr)
            if fr < fsim[0]:
                xe = 3.0 * centre - 2.0 * worst
                fe = value(xe)
                sim[-1], fsim[-1] = (xe, fe) if fe < fr else (xr, fr)
                continue
            if fr < fsim[-2]:
                sim[-1], fsim[-1] = xr, fr
                continue
            if fr < fsim[-1]:
                # outside contraction, halfway from the centre to the reflection
                xc = 1.5 * centre - 0.5 * worst
                fc = value(xc)
                if fc <= fr:
                    sim[-1], fsim[-1] = xc, fc
                    continue
            else:
                # inside contraction, halfway from the centre to the worst vertex
                xcc = 0.5 * centre + 0.5 * worst
                fcc = value(xcc)
                if fcc < fsim[-1]:
                    sim[-1], fsim[-1] = xcc, fcc
                    continue
            for j in range(1, n + 1):  # shrink towards the best vertex
                sim[j] = sim[0] + 0.5 * (sim[j] - sim[0])
                fsim[j] = value(sim[j])
    except _Exhausted:
        # out of evaluations: the simplex as it stands, best vertex first
        order = np.argsort(fsim, kind="stable")
        sim, fsim = sim[order], fsim[order]
    return SearchResult(sim[0].copy(), float(fsim[0]), nfev)


class _Exhausted(Exception):
    """`nelder_mead` ran out of evaluations."""


def dct2(x: FloatArray) -> FloatArray:
    """The orthonormal DCT-II of `x` along its last axis."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-1]
    if n == 0:
        return x.copy()
    # even samples forwards, then odd samples backwards: the DCT-II of x is the real
    # part of this sequence's DFT turned by a quarter sample
    v = np.concatenate([x[..., 0::2], x[..., 1::2][..., ::-1]], axis=-1)
    k = np.arange(n)
    turn = np.exp(-0.5j * np.pi * k / n)
    out = np.asarray((np.fft.fft(v, axis=-1) * turn).real, dtype=np.float64)
    out *= math.sqrt(2.0 / n)
    out[..., 0] *= math.sqrt(0.5)
    return out


# Above this half-width `mirror_smooth` convolves by FFT (equal to rounding).
_DIRECT_HALF = 256


def mirror_smooth(x: NDArray[np.generic], weights: FloatArray) -> NDArray[np.generic]:
    """``sum_d w[d] x[i + d]`` along axis 0 for symmetric `weights` (2 h + 1,) with
    h < len(x), the samples beyond either end reflected about the edge sample."""
    half = (weights.size - 1) // 2
    n = x.shape[0]
    if half >= n:
        raise ValueError("mirror_smooth: the window is wider than the series")
    pad = [(half, half)] + [(0, 0)] * (x.ndim - 1)
    xp = np.pad(x, pad, mode="reflect")
    if half > _DIRECT_HALF:
        # a wide window (a long record's spectrum): one FFT convolution, not a pass per
        # offset, whose cost grows with the record times the window
        size = xp.shape[0] + weights.size - 1
        shape = (-1,) + (1,) * (x.ndim - 1)
        full: NDArray[np.generic]
        if np.iscomplexobj(xp):
            spec = np.fft.fft(xp, size, axis=0) * np.fft.fft(weights, size).reshape(shape)
            full = np.fft.ifft(spec, size, axis=0)
        else:
            half_spec = np.fft.rfft(xp, size, axis=0) * np.fft.rfft(weights, size).reshape(shape)
            full = np.fft.irfft(half_spec, size, axis=0)
        # the symmetric window's convolution is the moving sum; keep the valid part
        return np.asarray(full[2 * half : 2 * half + n])
    out = weights[half] * x
    for d in range(1, half + 1):
        # the weights are symmetric: the samples d either side share one product
        out = out + weights[half + d] * (xp[half + d : half + d + n] + xp[half - d : half - d + n])
    return np.asarray(out)


def welch_density(x: FloatArray, segment: int) -> FloatArray:
    """Welch's one-sided power spectral density of `x` per unit sample rate.

    Segments of `segment` points overlapping by half (a trailing partial one
    dropped), each less its least-squares line and tapered by the periodic Hann
    window; their periodograms, scaled to a density (``1 / sum w^2``) and folded
    to one side (every bin but zero and Nyquist doubled), averaged. Bins
    ``0 .. segment // 2``.
    """
    x = np.asarray(x, dtype=np.float64)
    step = segment - segment // 2  # an overlap of segment // 2, as scipy's default
    count = 1 + (x.size - segment) // step
    starts = step * np.arange(count)
    segs = x[starts[:, None] + np.arange(segment)[None, :]]
    # each segment less its least-squares line
    u = np.arange(segment, dtype=np.float64) - 0.5 * (segment - 1)
    segs = segs - segs.mean(axis=1, keepdims=True)
    segs = segs - np.outer(segs @ u / float(u @ u), u)
    window = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(segment) / segment)
    power = np.abs(np.fft.rfft(segs * window, axis=1)) ** 2 / float(window @ window)
    if segment % 2 == 0:
        power[:, 1:-1] *= 2.0
    else:
        power[:, 1:] *= 2.0
    return np.asarray(power.mean(axis=0), dtype=np.float64)
