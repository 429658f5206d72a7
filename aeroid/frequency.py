"""Frequency-domain validation: empirical versus model transfer functions.

The empirical frequency response comes from Welch cross- and auto-spectral
densities of the measured inputs and outputs (Welch 1967). With several
inputs the estimate is conditioned on all of them (``H = S_uu^-1 S_uy`` per
frequency) and the coherence is the partial coherence of each input with the
output given the others; with one input these reduce to the familiar
``S_uy / S_uu`` and ordinary coherence.

By default the model's response is estimated with the same Welch estimator
from the model's outputs simulated on the measured inputs, so leakage,
finite resolution and start-up transients bias both sides alike and the
mismatch measures the model, not the estimator. For linear time-invariant
models ``model_response="exact"`` gives ``C (jωI - A)^-1 B + D`` from the
model's own matrices instead; `FrequencyResponseResult.model_response`
records which was used.

Several window lengths are tried at every frequency (by default a half, a
third, ... a sixteenth of the record: half-overlapping Hann segments, so even the
longest averages three and none has coherence 1 by construction), all
transformed at the longest window's frequency grid by chirp-z. A frequency counts
in the comparison ("coherent") with the window of most averages among those that
qualify there: the window holds at least two periods of it, the input's spectral
density is at least a twentieth of its peak, its coherence beats both the
requested threshold and the level noise alone would reach by chance with that
window's averages, and the window resolves the response: its estimate of the
model's own, noise-free response (simulated on the measured inputs) is within
10 % of the model's transfer function (exact or linearised; for a simulator, the
whole-record ratio of the simulated output's and input's Fourier transforms).
So on noise-free data a counted frequency is within 10 % of the true transfer
function. Each channel says how many frequencies did not count and why
(`ChannelFrequencyResponse.dropped`). The mismatch is the coherence-weighted
mean relative error over the counted frequencies.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import _integrate
from ._czt import fourier, hann
from ._records import fmt, markdown_table
from ._threads import small_blas
from ._transfer import state_space_response
from .data import FlightData, as_float, measured_start, whole_number
from .errors import ChannelError, DataFormatError, IdentificationError, SimulationError
from .frequency_id import ResponseChannel
from .model import (
    Model,
    SimulatorModel,
    delayed_controls,
    fitted_start,
    require_model,
    resolve_parameters,
)

__all__ = ["ChannelFrequencyResponse", "FrequencyResponseResult", "frequency_response"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_MODEL_RESPONSES = ("simulated", "exact", "auto")
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


# One response record for every frequency tool: rad/s, complex response, dB and
# degrees as properties (`frequency_id.ResponseChannel`); the spec's name stays.
ChannelFrequencyResponse = ResponseChannel


@dataclass(frozen=True, eq=False)
class FrequencyResponseResult:
    """Frequency responses of every analysed input-output pair.

    Attributes
    ----------
    channels : tuple of ResponseChannel
        One per input-output pair: frequencies in rad/s, the complex measured
        and model responses, coherence, the coherent mask and mismatch.
    input_names, output_names : tuple of str
    sample_rate : float
        Hz.
    nperseg : int
        Welch segment length (samples); resolution ``sample_rate / nperseg``.
    coherence_threshold : float
        The γ² a frequency needed: the requested threshold, raised where
        needed to the level that noise alone exceeds at any of a channel's
        frequencies with 1 % chance given `n_averages`.
    frequency_range : tuple of float
        The analysed band (Hz).
    model_response : str
        ``"simulated"`` (Welch estimate from the model's outputs simulated on
        the measured inputs), ``"exact"`` (analytic, linear time-invariant model)
        or ``"linearised"`` (analytic, the model linearised at the record's first
        sample).
    model_name : str
    n_averages : float
        Independent averages equivalent to the overlapping segments of the
        longest Welch window.
    windows : tuple of int
        Welch window lengths (samples) tried at every frequency.
    window_averages : tuple of float
        Their independent averages.
    record_bins : tuple of int
        Whole-record estimates also tried: the record's transform with the
        spectra averaged over this many neighbouring ``1/T`` bins.
    frequency_step : float
        Spacing of the analysis frequencies (Hz).
    notes : tuple of str
        What the analysis changed or could not count (a band clipped at
        Nyquist, frequencies below two periods of every window).
    """

    channels: tuple[ChannelFrequencyResponse, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    sample_rate: float
    nperseg: int
    coherence_threshold: float
    frequency_range: tuple[float, float]
    model_response: str
    model_name: str = ""
    n_averages: float = float("nan")
    windows: tuple[int, ...] = ()
    window_averages: tuple[float, ...] = ()
    record_bins: tuple[int, ...] = ()
    frequency_step: float = float("nan")
    notes: tuple[str, ...] = ()

    def channel(self, input: str, output: str) -> ChannelFrequencyResponse:
        """The response from control `input` to output `output`."""
        for ch in self.channels:
            if ch.input_name == input and ch.output_name == output:
                return ch
        raise ChannelError(
            f"no frequency response for input {input!r} -> output {output!r}; "
            f"inputs {list(self.input_names)}, outputs {list(self.output_names)}"
        )

    @property
    def mismatch(self) -> float:
        """Largest channel mismatch (NaN if no channel has a coherent frequency)."""
        vals = [c.mismatch for c in self.channels if np.isfinite(c.mismatch)]
        return float(max(vals)) if vals else float("nan")

    def plot(self, **kwargs: Any) -> Any:
        """Empirical vs model Bode plot with coherence. Returns a matplotlib Figure."""
        from .plotting import plot_frequency_response

        return plot_frequency_response(self, **kwargs)

    def summary(self) -> str:
        """Markdown section: per-channel coherent band and coherence-weighted mismatch."""
        rows = []
        for c in self.channels:
            band = (
                f"{fmt(float(c.frequency_hz[c.coherent].min()), 3)}–"
                f"{fmt(float(c.frequency_hz[c.coherent].max()), 3)} Hz"
                if c.n_coherent
                else "—"
            )
            mean_coh = float(np.mean(c.coherence)) if c.coherence.size else float("nan")
            mis = f"{100 * c.mismatch:.3g}%" if np.isfinite(c.mismatch) else "—"
            why = "; ".join(f"{int(v)} {k}" for k, v in c.dropped.items()) or "—"
            rows.append(
                (c.input_name, c.output_name, c.n_coherent, band, fmt(mean_coh, 3), mis, why)
            )
        table = markdown_table(
            (
                "input",
                "output",
                "coherent freqs",
                "coherent band",
                "mean γ²",
                "mismatch",
                "not counted",
            ),
            rows,
        )
        how = {
            "exact": "exact (linear time-invariant model)",
            "linearised": "the model linearised at the record's first sample",
        }.get(self.model_response, "Welch estimate from the simulated outputs")
        lo, hi = self.frequency_range
        wins = ", ".join(str(w) for w in (self.windows or (self.nperseg,)))
        step = self.frequency_step
        if not np.isfinite(step):
            step = self.sample_rate / self.nperseg
        record = (
            " and the whole record's transform averaged over "
            + ", ".join(str(b) for b in self.record_bins)
            + " neighbouring bins"
            if self.record_bins
            else ""
        )
        notes = "".join(f" Note: {n}." for n in self.notes)
        return "\n".join(
            [
                "## Frequency response",
                "",
                table,
                "",
                f"Welch estimates (Hann, half-overlapping) with windows of {wins} samples"
                f"{record}, evaluated every {fmt(step, 3)} Hz over "
                f"{fmt(lo, 3)}–{fmt(hi, 3)} Hz; at each frequency the window with the most "
                "averages among those that qualify: at least two periods in the window, the "
                f"input's spectral density at least 1/{round(1 / _EXCITED_FRACTION)} of its "
                f"peak, γ² ≥ {fmt(self.coherence_threshold, 3)} or more (the requested "
                "threshold, raised to beat chance for each window's averages: "
                f"{fmt(self.n_averages, 3)} independent averages in the longest) and the "
                f"window's estimate of the model's own response within "
                f"{100 * _RESOLVED_BIAS:.0f} % of its transfer function. Model response: "
                f"{how}.{notes} Mismatch is the "
                "coherence-weighted mean relative error of the transfer function.",
            ]
        )


# -- estimation ---------------------------------------------------------------------------


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


def _affine_measurement(
    model: Model, p: Mapping[str, FloatArray], time: FloatArray
) -> tuple[FloatArray, FloatArray] | None:
    """(C, D) if the model's outputs are affine in state and control over `time`, else None."""
    n_x, n_u = model.n_states, model.n_controls
    if model._measurement_batch is None:
        return _state_outputs(model)
    p1 = {k: np.asarray(v[:1], dtype=np.float64) for k, v in p.items()}
    mats, _ = _integrate.lti_form(
        model._measurement_batch, time, n_x, n_u, p1, trusted=model.linear is True
    )
    if mats is None:
        return None
    return mats[0][0], mats[1][0]


def _exact_response(
    model: Model, values: Mapping[str, float], time: FloatArray, freqs: FloatArray
) -> ComplexArray | None:
    """Analytic H(j 2π f) of shape (n_f, n_u, n_y), or None when the model is not LTI.

    LTI over the record's own time grid: a model whose forcing or gains change
    during the record has no transfer function.
    """
    if not model._maybe_lti:
        return None
    p = {k: np.array([float(v)]) for k, v in values.items()}
    mats, _ = _integrate.lti_form(
        model._dynamics_batch,
        time,
        model.n_states,
        model.n_controls,
        p,
        trusted=model.linear is True,
    )
    if mats is None:
        return None
    cd = _affine_measurement(model, p, time)
    if cd is None:
        return None
    return _transfer(mats[0][0], mats[1][0], *cd, freqs)


def _state_outputs(model: Model) -> tuple[FloatArray, FloatArray]:
    """(C, D) of a model without a measurement function: its outputs are states."""
    c = np.zeros((model.n_outputs, model.n_states))
    for i, o in enumerate(model.output_names):
        c[i, list(model.states).index(o)] = 1.0
    return c, np.zeros((model.n_outputs, model.n_controls))


def _transfer(
    a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray, freqs: FloatArray
) -> ComplexArray:
    """``C (j 2π f I - A)^-1 B + D`` at each of `freqs` (Hz), shape (n_f, n_u, n_y)."""
    with np.errstate(all="ignore"):
        h = state_space_response(a, b, c, d, 2.0 * np.pi * freqs)  # (n_f, n_y, n_u)
    return np.transpose(h, (0, 2, 1))


def _linearised_response(
    model: Model,
    values: Mapping[str, float],
    t0: float,
    x_ref: FloatArray,
    u_ref: FloatArray,
    freqs: FloatArray,
) -> ComplexArray | None:
    """H(j 2π f), shape (n_f, n_u, n_y), of the model linearised at (`x_ref`, `u_ref`).

    Central differences of the dynamics and the measurement about the
    reference (the record's first sample: its trim, for a manoeuvre flown from
    trim), all in one batched call each. None where a function cannot be
    evaluated there or gives non-finite values.
    """
    n_x = model.n_states
    z = np.concatenate([x_ref, u_ref]).astype(np.float64)
    n = z.size
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    Z = np.repeat(z[:, None], 2 * n, axis=1)
    cols = np.arange(n)
    Z[cols, 2 * cols] += h
    Z[cols, 2 * cols + 1] -= h
    P = {k: np.full(2 * n, float(v)) for k, v in values.items()}

    def jacobian(f: Any) -> FloatArray | None:
        try:
            with np.errstate(all="ignore"):
                F = np.asarray(f(float(t0), Z[:n_x], Z[n_x:], P), dtype=np.float64)
        except Exception:  # a function that cannot be evaluated there: simulated instead
            return None
        if not np.all(np.isfinite(F)):
            return None
        return (F[:, 0::2] - F[:, 1::2]) / (2.0 * h)

    J = jacobian(model._dynamics_batch)
    if J is None:
        return None
    if model._measurement_batch is None:
        c, d = _state_outputs(model)
    else:
        Jm = jacobian(model._measurement_batch)
        if Jm is None:
            return None
        c, d = Jm[:, :n_x], Jm[:, n_x:]
    return _transfer(J[:, :n_x], J[:, n_x:], c, d, freqs)


def _reference_state(model: Model, data: FlightData, x0: Any) -> FloatArray:
    """The state a response is linearised about: `x0` (a mapping or a vector), else the
    record's first sample of each measured state (0 for the others)."""
    if x0 is None:
        x0 = measured_start(data, model.states)
    if isinstance(x0, Mapping):
        return np.array([float(x0.get(s, 0.0)) for s in model.states])
    return np.asarray(x0, dtype=np.float64).reshape(-1)[: model.n_states]


def _independent_averages(n: int, nperseg: int) -> float:
    """Independent averages equivalent to the overlapping Welch segments of a record.

    K Hann segments overlapping by half average like
    ``K / (1 + 2 Σ_j (1 - j/K) ρ_j²)`` independent ones, ``ρ_j`` the window's
    overlap correlation at a shift of j segments (Welch 1967): 5.7 for the six
    segments of a 10 s record at 50 Hz. One count for every window
    (`frequency_id._independent_averages`).
    """
    from .frequency_id import _independent_averages as count

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
    from .frequency_id import _condition

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
    from .frequency_id import _window_spectra

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
    from .frequency_id import _random_error

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
        two = np.broadcast_to((f >= e.lowest)[:, None, None] & (e.n_averages > n_u), shape)
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


@small_blas
def frequency_response(
    model: Model | SimulatorModel,
    data: FlightData,
    parameters: Any = None,
    *,
    inputs: Sequence[str] | None = None,
    outputs: Sequence[str] | None = None,
    nperseg: int | None = None,
    frequency_range: tuple[float, float] | None = None,
    coherence_threshold: float = 0.6,
    x0: Any = None,
    model_response: str = "simulated",
    min_coherent: int = 3,
) -> FrequencyResponseResult:
    """Compare empirical and model transfer functions, weighted by coherence.

    Parameters
    ----------
    model : Model or SimulatorModel
    data : FlightData
        Uniformly sampled record with the model's controls and measured outputs.
    parameters : mapping or result, optional
        Model parameter values (merged onto the nominal ones), or a result
        with ``.parameters``.
    inputs : sequence of str, optional
        Controls to analyse (default: all the model's controls). The estimate
        is conditioned on the listed inputs only.
    outputs : sequence of str, optional
        Outputs to analyse (default: the model outputs present in the data).
    nperseg : int, optional
        One Welch segment length in samples, evaluated at its own frequency
        bins (default: several windows from half to a sixteenth of the record,
        chosen per frequency; see the module notes).
    frequency_range : (float, float), optional
        Band in Hz to analyse (default: from two periods of the longest
        window to Nyquist). A top above Nyquist is clipped there, with a note
        in the result's ``notes``.
    coherence_threshold : float
        γ² at or above which a frequency counts as coherent. Raised, when
        the record gives few averages, to the level that noise alone exceeds
        at any of a channel's frequencies with 1 % chance (the result's
        ``coherence_threshold`` is the one applied). A frequency counts only
        where the input's spectral density is also at least 1/20 of its peak.
    x0 : array_like or mapping, optional
        Initial state of a simulated model response (default: the state an
        identification result given as `parameters` used for this record, else
        the measured states). An identification result's estimated time delays
        enter the model's response: simulated on the delayed controls, or as
        ``exp(-j ω τ)`` on the exact and linearised ones.
    model_response : {"simulated", "exact", "auto"}
        ``"simulated"``: the same Welch estimate from the model's outputs
        simulated on the measured inputs (any model), which shares the
        estimator's bias. ``"exact"``: the analytic response of a linear
        time-invariant `Model`. In every mode a frequency also counts only
        where the window resolves the response (see the module notes), so a
        counted estimate is within about 10 % of the truth on noise-free data.
        ``"auto"``: exact where the model is linear time-invariant over the
        record; else the transfer function of the model linearised by central
        differences at the record's first sample (its trim, for a manoeuvre
        flown from trim: the initial state `x0` and the first controls),
        recorded as ``"linearised"``; simulated where neither can be evaluated
        (the campaign pipeline's default).
    min_coherent : int
        Warn when a channel has fewer coherent frequencies than this.

    Returns
    -------
    FrequencyResponseResult

    Raises
    ------
    DataFormatError
        The time grid is not uniform, or too short for the segment length.
    ChannelError
        An input or output is missing from the data or the model.
    IdentificationError
        Bad options (threshold, range, segment length, model_response,
        min_coherent), text or a bool where a number is expected, or a
        frequency range that holds no analysis frequency.

    Warns
    -----
    UserWarning
        When a channel has too few coherent frequencies to judge the model.
    """
    require_model(model, IdentificationError)
    if not isinstance(data, FlightData):
        raise DataFormatError(f"data: expected FlightData, got {type(data).__name__}")
    if not data.is_uniform:
        steps = np.diff(data.time)
        raise DataFormatError(
            "data: frequency_response needs a uniform time grid (Welch spectra); sample "
            f"spacing ranges from {steps.min():.6g} to {steps.max():.6g} s — resample first"
        )
    if model_response not in _MODEL_RESPONSES:
        raise IdentificationError(
            f"model_response: expected one of {list(_MODEL_RESPONSES)}, got {model_response!r}"
        )
    thr = as_float(coherence_threshold)
    if thr is None or not 0.0 <= thr <= 1.0:
        raise IdentificationError(
            f"coherence_threshold: expected a number in [0, 1], got {coherence_threshold!r}"
        )
    values = resolve_parameters(model, parameters, error=IdentificationError)
    if x0 is None:
        x0 = fitted_start(parameters, data)[0]
    controls = tuple(model.controls)
    model_outputs = model.output_names if isinstance(model, Model) else tuple(model.outputs)
    ins = (
        list(controls)
        if inputs is None
        else ([inputs] if isinstance(inputs, str) else list(inputs))
    )
    bad = [i for i in ins if i not in controls]
    if bad or not ins:
        raise ChannelError(
            f"inputs: {bad or ins} are not controls of model {model.name!r}; "
            f"controls: {list(controls)}"
        )
    if outputs is None:
        outs = [o for o in model_outputs if o in data]
        if not outs:
            raise ChannelError(
                f"data carry none of the outputs of model {model.name!r} "
                f"({list(model_outputs)}); channels: {sorted(data.channels)}"
            )
    else:
        outs = [outputs] if isinstance(outputs, str) else list(outputs)
        bad = [o for o in outs if o not in model_outputs]
        if bad or not outs:  # no output would give an empty result
            raise ChannelError(
                f"outputs: {bad or outs} are not outputs of model {model.name!r}; "
                f"outputs: {list(model_outputs)}"
            )
    data.require(controls, role="control")
    data.require(outs, role="output")
    n = data.n_samples
    try:
        seg = n if nperseg is None else int(nperseg)
        ok = nperseg is None or (
            not isinstance(nperseg, (bool, np.bool_)) and seg == nperseg and 8 <= seg <= n
        )
    except (TypeError, ValueError, OverflowError):  # NaN, infinity, text
        ok = False
    if not ok:
        raise IdentificationError(
            f"nperseg: expected an integer between 8 and the record length {n}, got {nperseg!r}"
        )
    min_coherent = whole_number(min_coherent, "min_coherent", IdentificationError, least=0)
    fs = data.sample_rate
    if frequency_range is None:
        # the Hann main lobe spans two bins: the first bin is mostly leakage from DC
        band = (2.0 * fs / (max(_default_windows(n)) if nperseg is None else seg), fs / 2.0)
    else:
        try:
            if isinstance(frequency_range, (str, bytes)) or any(
                isinstance(v, (bool, np.bool_, str, bytes)) for v in frequency_range
            ):  # float() would read "0.1" as 0.1
                raise TypeError
            lo, hi = (float(v) for v in frequency_range)
        except (TypeError, ValueError):
            raise IdentificationError(
                f"frequency_range: expected (low, high) in Hz, got {frequency_range!r}"
            ) from None
        if not (0.0 <= lo < hi):
            raise IdentificationError(
                f"frequency_range: expected 0 <= low < high, got {frequency_range!r}"
            )
        band = (lo, hi)

    u = data.array(ins).T
    y_meas = data.array(outs).T
    n_u, n_y = len(ins), len(outs)
    segs = _default_windows(n) if nperseg is None else (seg,)
    longest = max(segs)
    nyquist = fs / 2.0
    notes: list[str] = []
    if band[1] > nyquist:
        notes.append(
            f"the requested band's top {band[1]:.6g} Hz lies above Nyquist; clipped to "
            f"{nyquist:.6g} Hz"
        )
        band = (band[0], nyquist)
    # the analysis grid: the longest window's bins (what it can resolve), every window
    # transformed at them by chirp-z; evaluated up to Nyquist so that each input's
    # excitation is judged against its peak anywhere, then cut to the band
    smoothing = _RECORD_SMOOTHING if nperseg is None else ()
    grid = n if smoothing else longest
    f = np.arange(1, grid // 2 + 1) * fs / grid
    keep = (f >= band[0]) & (f <= band[1])
    if not keep.any():  # every channel would be empty
        raise IdentificationError(
            f"frequency_range: {frequency_range!r} Hz holds none of the analysis frequencies "
            f"({f[0]:.4g} to {f[-1]:.4g} Hz for {longest}-sample windows at {fs:.6g} Hz)"
        )

    # the model's response: the same windowed estimate from its simulated outputs
    # (noise-free, so it measures what each window does to a response like the model's),
    # and, where the model allows, its transfer function
    values_ref: ComplexArray | None = None
    how = "simulated"
    if isinstance(model, Model):
        full = _exact_response(model, values, data.time, f)
        how = "exact"
        if full is None:
            u_ref = data.array(list(controls))[:, 0]
            x_ref = _reference_state(model, data, x0)
            full = _linearised_response(model, values, data.time[0], x_ref, u_ref, f)
            how = "linearised"
        if full is not None:
            idx_u = [controls.index(i) for i in ins]
            idx_y = [model_outputs.index(o) for o in outs]
            values_ref = full[:, idx_u][:, :, idx_y]
            # a fit's estimated time delays: u(t - tau) is e^(-j omega tau) U
            delays = dict(getattr(parameters, "time_delays", None) or {})
            lag = np.array([float(delays.get(i, 0.0)) for i in ins])
            values_ref = values_ref * np.exp(-2j * np.pi * f[:, None, None] * lag[None, :, None])
    if model_response == "exact" and (values_ref is None or how != "exact"):
        raise IdentificationError(
            f"model_response='exact' needs a linear time-invariant aeroid.Model; "
            f"{model.name!r} is not (use 'simulated')"
        )
    try:
        y_sim = _simulated_outputs(model, delayed_controls(parameters, data), values, x0)
    except SimulationError:
        if values_ref is None or model_response == "simulated":
            raise
        y_sim = None  # judged against the transfer function alone
    idx_y = [model_outputs.index(o) for o in outs]
    signals = np.vstack([u, y_meas] + ([] if y_sim is None else [y_sim[:, idx_y].T])).T
    est = [_window_estimate(signals, fs, s, f, n_u, n_y) for s in segs]
    est += [_record_estimate(signals, fs, m, n_u, n_y) for m in smoothing]
    lowest = min(e.lowest for e in est)
    if band[0] < lowest and frequency_range is not None:
        notes.append(
            f"frequencies below {lowest:.4g} Hz hold fewer than two periods in every window "
            "and are not counted"
        )
    if values_ref is None:
        # no transfer function (so y_sim exists): the whole-record ratio of the simulated
        # outputs (no window, no averaging) for one input, else the longest window's
        assert y_sim is not None
        longest_sim = max(est, key=lambda e: e.seg).h_sim
        assert longest_sim is not None
        values_ref = _record_ratio(u, y_sim[:, idx_y].T, fs, f) if n_u == 1 else longest_sim
    h_ref: ComplexArray = values_ref
    use_ref = model_response != "simulated" and how in ("exact", "linearised")
    if not use_ref:
        how = "simulated"
    band_hz = float(np.sum(keep)) * fs / grid
    chosen, reason = _choose_windows(est, h_ref, f, thr, fs, n_u, band_hz)
    f, h_ref = f[keep], h_ref[keep]
    chosen, reason = chosen[keep], reason[keep]
    thr_used = min(e.threshold for e in est)

    # each frequency's values from the window chosen for it
    rows = np.arange(f.size)
    h_all = np.stack([e.h[keep] for e in est])  # (n_est, n_f, n_u, n_y)
    coh_all = np.stack([e.coherence[keep] for e in est])
    sims = [e.h_sim for e in est]
    sim_all = (
        None
        if use_ref or any(h is None for h in sims)
        else np.stack([h[keep] for h in sims if h is not None])
    )
    chans = []
    few = []
    for i, inp in enumerate(ins):
        for k, out in enumerate(outs):
            pick = chosen[:, i, k]
            he = h_all[pick, rows, i, k]
            g = coh_all[pick, rows, i, k]
            hm = h_ref[:, i, k] if sim_all is None else sim_all[pick, rows, i, k]
            why = reason[:, i, k]
            mask = why == 0
            with np.errstate(all="ignore"):
                rel = np.abs(he - hm) / np.abs(hm)
            good = mask & np.isfinite(rel)
            mis = float(np.sum(g[good] * rel[good]) / np.sum(g[good])) if good.any() else np.nan
            n_coh = int(mask.sum())
            dropped = {
                text: int(np.sum(why == code))
                for code, text in enumerate(_REASONS)
                if code and np.any(why == code)
            }
            if n_coh < min_coherent:
                few.append(
                    f"{inp}->{out} ({n_coh}; "
                    + (", ".join(f"{v} {t}" for t, v in dropped.items()) or "none dropped")
                    + ")"
                )
            chans.append(
                ResponseChannel(
                    input_name=inp,
                    output_name=out,
                    frequency=2.0 * np.pi * f,
                    response=he,
                    coherence=g,
                    model_response=hm,
                    coherent=mask,
                    mismatch=mis,
                    window=np.array([est[j].seg for j in pick], dtype=np.int64),
                    dropped=dropped,
                )
            )
    if few:
        warnings.warn(
            f"frequency_response: too few coherent frequencies in "
            f"{band[0]:.3g}–{band[1]:.3g} Hz for {', '.join(few)} (windows of "
            f"{', '.join(str(e.seg) for e in est)} samples; a frequency counts with γ² above "
            f"the requested threshold and chance, the input within "
            f"{10 * np.log10(1 / _EXCITED_FRACTION):.0f} dB of its peak, two periods in the "
            f"window and the window's bias on the model's response within "
            f"{100 * _RESOLVED_BIAS:.0f} %)",
            UserWarning,
            stacklevel=3,  # frequency_response, its BLAS wrapper (aeroid._threads), the caller
        )
    longest_est = est[list(segs).index(longest)]
    return FrequencyResponseResult(
        channels=tuple(chans),
        input_names=tuple(ins),
        output_names=tuple(outs),
        sample_rate=float(fs),
        nperseg=longest,
        coherence_threshold=thr_used,
        frequency_range=(float(band[0]), float(band[1])),
        model_response=how,
        model_name=str(model.name),
        n_averages=longest_est.n_averages,
        windows=tuple(int(v) for v in segs),
        window_averages=tuple(e.n_averages for e in est[: len(segs)]),
        record_bins=tuple(2 * m + 1 for m in smoothing),
        frequency_step=float(fs / grid),
        notes=tuple(notes),
    )


def _simulated_outputs(
    model: Model | SimulatorModel, data: FlightData, values: Mapping[str, float], x0: Any
) -> FloatArray:
    if isinstance(model, Model):
        if x0 is None:
            x0 = measured_start(data, model.states)
        sim = model.simulate_batch(data.time, data, x0, values, method="auto")
        if not sim.ok[0]:
            raise SimulationError(
                f"frequency_response: model {model.name!r} failed to simulate the record: "
                f"{sim.failure[0]}"
            )
        return np.asarray(sim.outputs[0])
    res = model.simulate_data(data, x0=x0, parameters=values)
    return np.asarray(res.outputs, dtype=np.float64)
