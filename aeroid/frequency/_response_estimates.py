"""Welch estimates behind `aeroid.frequency.response.frequency_response`: the spectra of each
window and of the whole record on the analysis grid, and the window that counts at
each frequency (see that module's notes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._czt import fourier, hann

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# An input whose spectral density is 60 dB below its own peak does not excite the
# system at that frequency: coherence there reflects leakage and transients only.
_EXCITATION_FLOOR = 1e-6
# A frequency counts only if (a) its coherence beats chance: with n_d independent
# averages, noise alone reaches γ² = c with probability about (1 - c)^(n_d - 1). With
# the six averages of a 10 s record at 50 Hz noise passes 0.6 at 1.2 % of frequencies,
# somewhere in half of all 63-frequency channels, and on the standard doublet flight
# such frequencies gave the true model a mismatch of 2.4, 2.5 and 0.9 (seeds 0-2).
# So the threshold is raised until noise passes it anywhere in a channel with at
# most this chance:
_FALSE_COHERENCE_LEVEL = 0.01
# and (b) the input drives it: from a few averages the coherence also reads a weak
# response high (the same flight, seed 0: the doublet's third side lobe at 3.5 Hz,
# 17 dB below the input's peak, beats chance and is off by 1.4), while the measured
# input's spectrum shows where it puts its energy. A twentieth of the peak (13 dB
# down) spans a sweep's or multisine's band and a doublet's main lobe and first side
# lobe (10.6 dB down) and drops its second (15.1 dB down). Each rule misses what the
# other catches: (a) that side lobe, (b) noise where the input is strong.
_EXCITED_FRACTION = 0.05


def _spectral_matrix(signals: FloatArray, fs: float, nperseg: int) -> tuple[FloatArray, Any]:
    """All cross-spectra of the rows of `signals` (n, n_t): S[a, b] = E[conj(Z_a) Z_b].

    Welch's one-sided cross-spectral density as ``scipy.signal.csd`` computes it
    with ``window="hann"`` (periodic), half-overlapping segments, ``detrend="constant"``
    and density scaling; in numpy, with every segment transformed once rather than
    once per pair, and without importing `scipy.signal`.
    """
    n_t = signals.shape[-1]
    step = nperseg - nperseg // 2
    k = (n_t - nperseg) // step + 1
    win = hann(nperseg)
    starts = np.arange(k) * step
    segs = signals[:, starts[:, None] + np.arange(nperseg)[None, :]]  # (n, k, nperseg)
    segs = (segs - segs.mean(axis=-1, keepdims=True)) * win
    z = np.fft.rfft(segs, axis=-1)  # (n, k, n_f)
    s = np.einsum("akf,bkf->fab", np.conj(z), z) / (k * fs * float(np.dot(win, win)))
    # one-sided: double all but the zero frequency (and Nyquist for even lengths)
    s[1 : None if nperseg % 2 else -1] *= 2.0
    freqs = np.asarray(np.fft.rfftfreq(nperseg, 1.0 / fs), dtype=np.float64)
    return freqs, s  # (n_f,), (n_f, n, n)


def _independent_averages(n: int, nperseg: int) -> float:
    """Independent averages equivalent to the overlapping Welch segments of a record.

    K Hann segments overlapping by half average like
    ``K / (1 + 2 Σ_j (1 - j/K) ρ_j²)`` independent ones, ``ρ_j`` the window's
    overlap correlation at a shift of j segments (Welch 1967): 5.7 for the six
    segments of a 10 s record at 50 Hz. One count for every window
    (`_cross_spectra._independent_averages`).
    """
    from ._cross_spectra import _independent_averages as count

    return count(n, nperseg, nperseg - nperseg // 2, hann(nperseg))


def _chance_coherence(n_averages: float, n_inputs: int, n_frequencies: int) -> float:
    """γ² that noise alone exceeds at any of `n_frequencies` with probability 1 %.

    With zero true coherence the estimate from ``n_d`` averages exceeds ``c``
    with probability ``(1 - c)^(n_d - 1)``, and a partial coherence given
    ``n_u - 1`` other inputs with ``(1 - c)^(n_d - n_u)`` (Carter, Knapp &
    Nuttall 1973; Bendat & Piersol, Random Data, ch. 9); a Bonferroni split of
    the level over the frequencies keeps the chance for the whole channel. The
    Welch estimate's tail lies between those for the segment count and for
    `n_averages` (its overlap discount), so the level errs on the safe side.
    Returns 1 when there are too few averages for any coherence to beat chance,
    0 when there is no frequency to guard.
    """
    dof = n_averages - n_inputs
    if n_frequencies < 1:
        return 0.0
    if dof <= 0.0:
        return 1.0
    return float(1.0 - (_FALSE_COHERENCE_LEVEL / n_frequencies) ** (1.0 / dof))


# Why a frequency did not count, by code (0: counted).
_REASONS = (
    "",
    "below two periods of every window",
    "input not excited",
    "not coherent",
    "not resolved by any window",
)
# A window counts at a frequency only where its estimate of the model's own (noise-free)
# response is within this fraction of the model's transfer function: the estimator's bias
# (resolution, leakage from a neighbouring line, transients) measured on this record's
# input rather than bounded by a rule of thumb. A tenth: what the issue-52 users expect of a
# noise-free estimate (10 % in magnitude); the transients of a short record (8 s of Twin
# Otter pitch data) already cost 7-11 % in the whole-record estimate.
_RESOLVED_BIAS = 0.10
# Default windows: these fractions of the record (50 % overlap, so the longest still
# averages three segments; a window as long as the record has coherence 1 by construction).
_WINDOW_DIVISORS = (2, 3, 4, 6, 8, 12, 16)
_MIN_WINDOW = 32


def _default_windows(n: int) -> tuple[int, ...]:
    """Window lengths (samples) tried at every frequency, longest first."""
    out = sorted({n // d for d in _WINDOW_DIVISORS if n // d >= _MIN_WINDOW}, reverse=True)
    if out:
        return tuple(out)
    return (max(8, n // 2),) if n >= 16 else (n,)


# The whole record, transformed once (SIDPAC's and CIFER's single-window estimate), with
# the cross-spectra averaged over this many neighbouring 1/T bins either side: 3, 5 and 7
# about independent averages at the record's own resolution, which resolves responses a
# record too short for several segments holds (an 8 s Twin Otter pitch record).
_RECORD_SMOOTHING = (1, 2, 3)


@dataclass(eq=False)
class _Estimate:
    """One window's estimates on the analysis grid."""

    seg: int
    h: ComplexArray  # (n_f, n_u, n_y)
    coherence: FloatArray  # (n_f, n_u, n_y)
    excitation: FloatArray  # (n_f, n_u), relative to the input's peak
    h_sim: ComplexArray | None  # the model's simulated outputs, same window
    n_averages: float
    lowest: float  # lowest frequency (Hz) with two periods in the window
    cell: float  # spacing (Hz) of independent estimates
    threshold: float = 1.0


def _estimate(
    g: ComplexArray, n_u: int, n_y: int, seg: int, n_avg: float, lowest: float, cell: float
) -> _Estimate:
    """An `_Estimate` from the spectral matrix (n_f, c, c) of [inputs, outputs, simulated]."""
    from ._cross_spectra import _condition

    c = g.shape[1]
    meas = [*range(n_u + n_y)]
    h, coh, _ = _condition(g[:, meas][:, :, meas], n_u)
    puu = np.real(np.diagonal(g[:, :n_u, :n_u], axis1=1, axis2=2))
    peak = np.max(puu, axis=0, initial=0.0)
    with np.errstate(all="ignore"):
        excitation = np.where(peak > 0, puu / peak, 0.0)
    coh = np.where((excitation >= _EXCITATION_FLOOR)[:, :, None], coh, 0.0)
    h_sim = None
    if c > n_u + n_y:
        sim = [*range(n_u), *range(n_u + n_y, c)]
        h_sim = _condition(g[:, sim][:, :, sim], n_u)[0]
    return _Estimate(seg, h, coh, excitation, h_sim, n_avg, lowest, cell)


def _zero_ends(x: FloatArray) -> FloatArray:
    """Each column less the line through its end points (SIDPAC's ``zep``)."""
    ramp = np.linspace(0.0, 1.0, x.shape[0])[:, None]
    return np.asarray(x - (x[:1] + ramp * (x[-1:] - x[:1])), dtype=np.float64)


def _record_estimate(signals: FloatArray, fs: float, m: int, n_u: int, n_y: int) -> _Estimate:
    """Whole-record estimate on the grid k fs / n (k >= 1), spectra averaged over 2m + 1 bins.

    The line through each signal's end points is removed (SIDPAC's ``zep``) so the
    record starts and ends at zero and needs no taper; the bins ``1/T`` apart are then
    about independent, and the average of ``2m + 1`` of them has coherence at most 1
    (one weight for every spectrum) and ``2m + 1`` averages.
    """

    n, c = signals.shape
    x = _zero_ends(signals)
    k_top = n // 2
    z = np.fft.rfft(x, axis=0)[: k_top + m + 1] / fs  # bins 0 .. k_top + m
    if z.shape[0] < k_top + m + 1:
        # bins beyond Nyquist mirror those below it (a real signal's spectrum)
        need = k_top + m + 1 - z.shape[0]
        z = np.concatenate([z, np.conj(z[n - k_top - need : n - k_top][::-1])])
    prod = np.conj(z)[:, :, None] * z[:, None, :]  # (bins, c, c)
    csum = np.concatenate([np.zeros((1, c, c)), np.cumsum(prod, axis=0)])
    k = np.arange(1, k_top + 1)
    lo = np.maximum(k - m, 1)  # never the zero bin (the mean)
    g = (csum[k + m + 1] - csum[lo]) / (k + m + 1 - lo)[:, None, None]
    # the lowest bin averaged holds one period, the frequency itself at least two
    return _estimate(g, n_u, n_y, n, float(2 * m + 1), (m + 2) * fs / n, (2 * m + 1) * fs / n)


def _window_estimate(
    signals: FloatArray, fs: float, seg: int, f: FloatArray, n_u: int, n_y: int
) -> _Estimate:
    """Hann-windowed, half-overlapped (Welch) estimate of one window length at `f` (Hz)."""
    from ._cross_spectra import _window_spectra

    g, _, n_avg = _window_spectra(signals, 1.0 / fs, seg, seg - seg // 2, 2.0 * np.pi * f)
    return _estimate(g, n_u, n_y, seg, n_avg, 2.0 * fs / seg, fs / seg)


def _record_ratio(u: FloatArray, y: FloatArray, fs: float, f: FloatArray) -> ComplexArray:
    """Y(f) / U(f), shape (n_f, 1, n_y), from one transform of the whole record.

    The line through each signal's end points is removed first, so the record
    starts and ends at zero and no window is needed (SIDPAC's ``zep``).
    """
    z = fourier(_zero_ends(np.vstack([u, y]).T), 1.0 / fs, f)
    with np.errstate(all="ignore"):
        return np.asarray(z[:, None, 1:] / z[:, :1, None], dtype=np.complex128)


def _choose_windows(
    est: Sequence[_Estimate],
    h_ref: ComplexArray,
    f: FloatArray,
    thr: float,
    fs: float,
    n_u: int,
    band_hz: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per frequency and pair, the window used and why the frequency does not count.

    A window qualifies at a frequency when it holds two periods of it, the input
    is excited there, the coherence beats the requested threshold and chance, and
    its estimate of the model's response is within `_RESOLVED_BIAS` of the
    transfer function; of those, the one with the most averages (the shortest) is
    used, without combining spectra. Where none qualifies,
    the two-period window with the smallest random error is shown and the
    furthest test passed names the reason.
    """
    from ._cross_spectra import _random_error

    shape = h_ref.shape
    best = np.full(shape, np.inf)
    shown = np.full(shape, -np.inf)
    chosen = np.zeros(shape, dtype=np.int64)
    display = np.full(shape, int(np.argmax([e.seg for e in est])), dtype=np.int64)
    stage = np.zeros(shape, dtype=np.int64)
    for j, e in enumerate(est):
        independent = max(1, round(band_hz / e.cell))
        e.threshold = max(thr, _chance_coherence(e.n_averages, n_u, independent))
        err = _random_error(e.coherence, e.n_averages, n_u)
        # on a bin (the rate's rounding in time stamps must not move it off)
        two_periods = f >= e.lowest * (1.0 - 1e-9)
        two = np.broadcast_to(two_periods[:, None, None] & (e.n_averages > n_u), shape)
        excited = two & (e.excitation >= _EXCITED_FRACTION)[:, :, None]
        coherent = excited & (e.coherence >= e.threshold)
        if e.h_sim is None:
            resolved = coherent
        else:
            with np.errstate(all="ignore"):
                bias = np.abs(e.h_sim - h_ref) / np.abs(h_ref)
            resolved = coherent & (bias <= _RESOLVED_BIAS)
        level = two.astype(np.int64) + excited + coherent + resolved
        stage = np.maximum(stage, level)
        # the most averages wins: a coherence from few averages reads high, so its
        # random error would flatter the long windows
        better = resolved & (1.0 / e.n_averages < best)
        chosen = np.where(better, j, chosen)
        best = np.where(better, 1.0 / e.n_averages, best)
        # shown where nothing counts: the window that passed the most tests, then the
        # smallest random error
        key = level - np.arctan(np.nan_to_num(err, posinf=1e300)) / np.pi
        nearer = key > shown
        display = np.where(nearer, j, display)
        shown = np.where(nearer, key, shown)
    counted = np.isfinite(best)
    chosen = np.where(counted, chosen, display)
    reason = np.where(counted, 0, np.minimum(stage, 3) + 1)
    return chosen, reason
