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

A frequency counts in the comparison ("coherent") only where the data show a
response to the input: its coherence beats both the requested threshold and
the level noise alone would reach by chance with the record's number of
averages, and the input's spectral density there is at least a twentieth of
its peak. A frequency must also be resolved by the window, whatever the
model's response: the estimate changes by at most 15 % to either neighbouring
frequency and the input's power there is not mostly leakage from a neighbour,
so that on noise-free data a counted frequency is within about 5 % of the true
transfer function. The mismatch is the
coherence-weighted mean relative error over those frequencies.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import _integrate
from ._czt import hann
from ._records import fmt, frozen_array, markdown_table
from ._threads import small_blas
from .data import FlightData, as_float, measured_start, whole_number
from .errors import ChannelError, DataFormatError, IdentificationError, SimulationError
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
# The estimate is reported as the data's transfer function, so a frequency counts only
# where the estimator's own bias is small, whatever the model's response (a simulated
# one shares the bias and would hide it: on a noise-free 10 s doublet the two counted
# bins were 9 % and 63 % off the true response). Welch's Hann estimate at a bin is
# about the response averaged over that bin and its two neighbours with power weights
# 2/3, 1/6, 1/6: a resolution bias near (H[k-1] - 2 H[k] + H[k+1]) / 6. A frequency
# counts only (c) where the model's response (exact, linearised, or its own Welch
# estimate when simulated: noise-free in every case, so noise cannot hide a resolved
# bin) changes by at most this fraction to either neighbour, which bounds that bias by
# (0.15 + 0.15) / 6 = 5 % for a right model (on a noise-free 60 s multisine at the
# default segments the short-period bins counted before were up to 22 % off, near the
# 0.48 Hz mode) ...
_RESOLVED_STEP = 0.15
# ... and (d) where the input's own power is at least this fraction of a neighbour's:
# one bin from a spectral line (a multisine's, or the last line of its band) the Hann
# window leaks a quarter of the line's power, and the estimate there is the line's
# response, not the bin's (9 % off at 4.2 Hz above that multisine's 4 Hz top line).
_LEAKED_FRACTION = 0.5


@dataclass(frozen=True, eq=False)
class ChannelFrequencyResponse:
    """Empirical and model frequency response of one input-output pair.

    Attributes
    ----------
    input_name, output_name : str
    frequency : ndarray, shape (n_f,)
        Frequencies in Hz (inside the requested range; no DC).
    magnitude, phase : ndarray, shape (n_f,)
        Empirical gain (output unit per input unit) and phase in radians,
        wrapped to (-π, π].
    coherence : ndarray, shape (n_f,)
        Coherence γ² of the input with the output (partial coherence given
        the other inputs when there are several); zero where the input's
        spectral density is more than 60 dB below its peak (not excited).
    model_magnitude, model_phase : ndarray, shape (n_f,)
        The model's gain and wrapped phase at the same frequencies.
    coherent : ndarray of bool, shape (n_f,)
        Frequencies that count: γ² at or above the result's
        ``coherence_threshold`` and the input's spectral density at least a
        twentieth of its peak.
    mismatch : float
        Coherence-weighted mean relative error ``Σ γ² |Ĥ − H| / |H| / Σ γ²``
        over the coherent frequencies (NaN when none is coherent).
    n_coherent : int
    """

    input_name: str
    output_name: str
    frequency: FloatArray
    magnitude: FloatArray
    phase: FloatArray
    coherence: FloatArray
    model_magnitude: FloatArray
    model_phase: FloatArray
    coherent: NDArray[np.bool_]
    mismatch: float
    n_coherent: int

    def __post_init__(self) -> None:
        for name in (
            "frequency",
            "magnitude",
            "phase",
            "coherence",
            "model_magnitude",
            "model_phase",
        ):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        mask = np.array(self.coherent, dtype=bool, copy=True)
        mask.setflags(write=False)
        object.__setattr__(self, "coherent", mask)

    @property
    def phase_error(self) -> FloatArray:
        """Empirical minus model phase, wrapped to (-π, π]."""
        out = np.angle(np.exp(1j * (self.phase - self.model_phase)))
        out.setflags(write=False)
        return out

    @property
    def magnitude_db(self) -> FloatArray:
        """Empirical gain in decibels."""
        with np.errstate(divide="ignore"):
            out = 20.0 * np.log10(self.magnitude)
        out.setflags(write=False)
        return out


@dataclass(frozen=True, eq=False)
class FrequencyResponseResult:
    """Frequency responses of every analysed input-output pair.

    Attributes
    ----------
    channels : tuple of ChannelFrequencyResponse
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
        Independent averages equivalent to the overlapping Welch segments.
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
                f"{fmt(float(c.frequency[c.coherent].min()), 3)}–"
                f"{fmt(float(c.frequency[c.coherent].max()), 3)} Hz"
                if c.n_coherent
                else "—"
            )
            mean_coh = float(np.mean(c.coherence)) if c.coherence.size else float("nan")
            mis = f"{100 * c.mismatch:.3g}%" if np.isfinite(c.mismatch) else "—"
            rows.append((c.input_name, c.output_name, c.n_coherent, band, fmt(mean_coh, 3), mis))
        table = markdown_table(
            ("input", "output", "coherent freqs", "coherent band", "mean γ²", "mismatch"), rows
        )
        how = {
            "exact": "exact (linear time-invariant model)",
            "linearised": "the model linearised at the record's first sample",
        }.get(self.model_response, "Welch estimate from the simulated outputs")
        how += (
            "; a frequency counts only where the window resolves the estimate (at most "
            f"{100 * _RESOLVED_STEP:.0f} % change to either neighbour, input not leaked "
            "from a neighbour)"
        )
        lo, hi = self.frequency_range
        return "\n".join(
            [
                "## Frequency response",
                "",
                table,
                "",
                f"Welch estimate, {self.nperseg}-sample segments "
                f"({fmt(self.sample_rate / self.nperseg, 3)} Hz resolution) over "
                f"{fmt(lo, 3)}–{fmt(hi, 3)} Hz; coherent means γ² ≥ "
                f"{fmt(self.coherence_threshold, 3)} (at least the requested threshold and "
                f"above chance for {fmt(self.n_averages, 3)} independent averages) with the "
                f"input's spectral density at least 1/{round(1 / _EXCITED_FRACTION)} of its "
                f"peak. Model response: {how}. Mismatch is the "
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


def _empirical(
    inputs: FloatArray, outputs: FloatArray, fs: float, nperseg: int
) -> tuple[FloatArray, ComplexArray, FloatArray, FloatArray]:
    """Frequencies, H (n_f, n_u, n_y), (partial) coherence (n_f, n_u, n_y) and excitation.

    The excitation (n_f, n_u) is each input's spectral density relative to its peak.
    """
    n_u = inputs.shape[0]
    f, s = _spectral_matrix(np.vstack([inputs, outputs]), fs, nperseg)
    suu = s[:, :n_u, :n_u]
    puu = np.real(np.diagonal(suu, axis1=1, axis2=2))  # (n_f, n_u)
    peak = np.max(puu, axis=0, initial=0.0)
    with np.errstate(all="ignore"):
        excitation = np.where(peak > 0, puu / peak, 0.0)
    excited = puu >= _EXCITATION_FLOOR * peak
    suy = s[:, :n_u, n_u:]
    syy = np.real(np.diagonal(s[:, n_u:, n_u:], axis1=1, axis2=2))  # (n_f, n_y)
    with np.errstate(all="ignore"):
        if n_u == 1:
            pxx = np.real(suu[:, 0, 0])
            h = suy / pxx[:, None, None]
            coh = np.abs(suy) ** 2 / (pxx[:, None, None] * syy[:, None, :])
        else:
            # Conditioned estimate and partial coherence from the inverse spectral matrix.
            h = np.linalg.pinv(suu) @ suy
            coh = np.empty(suy.shape)
            for k in range(outputs.shape[0]):
                idx = [*range(n_u), n_u + k]
                g = np.linalg.pinv(s[:, idx][:, :, idx])
                giy = g[:, :n_u, n_u]
                gii = np.real(np.diagonal(g[:, :n_u, :n_u], axis1=1, axis2=2))
                gyy = np.real(g[:, n_u, n_u])
                coh[:, :, k] = np.abs(giy) ** 2 / (gii * gyy[:, None])
    coh = np.clip(np.nan_to_num(coh, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    coh = np.where(excited[:, :, None] & (peak > 0)[None, :, None], coh, 0.0)
    return f, h, coh, excitation


def _resolved(h: ComplexArray, excitation: FloatArray) -> NDArray[np.bool_]:
    """Bins (n_f, n_u, n_y) that the window resolves: rules (c) and (d) above.

    `h` (the model's response) and `excitation` on the full Welch grid, so a band's edge bins are judged
    against both neighbours; the grid's first and last bins never count.
    """
    ok = np.zeros(h.shape, dtype=bool)
    if h.shape[0] < 3:
        return ok
    mid = h[1:-1]
    with np.errstate(all="ignore"):
        step = np.maximum(np.abs(h[:-2] - mid), np.abs(h[2:] - mid)) / np.abs(mid)
    own = excitation[1:-1] >= _LEAKED_FRACTION * np.maximum(excitation[:-2], excitation[2:])
    ok[1:-1] = (step <= _RESOLVED_STEP) & own[:, :, None]
    return ok


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
    """``C (j 2π f I - A)^-1 B + D`` at each of `freqs`, shape (n_f, n_u, n_y)."""
    s = 2j * np.pi * freqs
    m = s[:, None, None] * np.eye(a.shape[0])[None] - a[None]
    with np.errstate(all="ignore"):
        x = np.linalg.solve(m, np.broadcast_to(b, (freqs.size, *b.shape)).astype(complex))
    h = c[None] @ x + d[None]  # (n_f, n_y, n_u)
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
    segments of a 10 s record at 50 Hz.
    """
    step = nperseg - nperseg // 2
    k = (n - nperseg) // step + 1
    w = hann(nperseg)
    shifts = np.arange(1, k) * step
    shifts = shifts[shifts < nperseg]
    rho = np.array([np.dot(w[: nperseg - d], w[d:]) for d in shifts]) / np.dot(w, w)
    lag = np.arange(1, shifts.size + 1)
    return float(k / (1.0 + 2.0 * np.sum((1.0 - lag / k) * rho**2)))


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


def _default_nperseg(n: int) -> int:
    # About 20 averages (12 segments with 50 % overlap) keep the random error of |H|
    # near 3 % where γ² = 0.95 (Bendat & Piersol: sqrt(1 - γ²) / (|γ| sqrt(2 n_d)));
    # short records keep at least 128-sample segments for resolution.
    return int(n // 12 if n // 12 >= 128 else min(n, 128))


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
        Welch segment length in samples (default: a twelfth of the record,
        about 20 averages with the 50 % overlap, but at least 128 samples).
        Longer segments resolve more frequencies, with fewer averages.
    frequency_range : (float, float), optional
        Band in Hz to analyse (default: from the second non-zero bin, above
        the window's leakage from DC, to Nyquist).
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
        counted estimate is within about 5 % of the truth on noise-free data.
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
        seg = _default_nperseg(n) if nperseg is None else int(nperseg)
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
        band = (2.0 * fs / seg, fs / 2.0)
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
    f, h_emp, coh, excitation = _empirical(u, y_meas, fs, seg)
    keep = (f > 0) & (f >= band[0]) & (f <= band[1])
    if not keep.any():  # every channel would be empty
        raise IdentificationError(
            f"frequency_range: {frequency_range!r} Hz holds none of the analysis frequencies "
            f"({f[1]:.4g} to {f[-1]:.4g} Hz for nperseg={seg} at {fs:.6g} Hz)"
        )
    # which frequencies count: see _FALSE_COHERENCE_LEVEL and _EXCITED_FRACTION
    n_avg = _independent_averages(n, seg)
    thr_used = max(thr, _chance_coherence(n_avg, len(ins), int(keep.sum())))
    # with no more averages than inputs the coherence is 1 whatever the data
    resolvable = n_avg > len(ins)

    # the model's response on the whole Welch grid: the window's resolution is judged
    # on it (noise-free), a band's edge bins against both neighbours
    h_model: ComplexArray | None = None
    how = "simulated"
    if model_response in ("exact", "auto") and isinstance(model, Model):
        full = _exact_response(model, values, data.time, f)
        how = "exact"
        if full is None and model_response == "auto":
            u_ref = data.array(list(controls))[:, 0]
            x_ref = _reference_state(model, data, x0)
            full = _linearised_response(model, values, data.time[0], x_ref, u_ref, f)
            how = "linearised"
        if full is not None:
            idx_u = [controls.index(i) for i in ins]
            idx_y = [model_outputs.index(o) for o in outs]
            h_model = full[:, idx_u][:, :, idx_y]
            # a fit's estimated time delays: u(t - tau) is e^(-j omega tau) U
            delays = dict(getattr(parameters, "time_delays", None) or {})
            lag = np.array([float(delays.get(i, 0.0)) for i in ins])
            h_model = h_model * np.exp(-2j * np.pi * f[:, None, None] * lag[None, :, None])
        else:
            how = "simulated"
    if h_model is None:
        if model_response == "exact":
            raise IdentificationError(
                f"model_response='exact' needs a linear time-invariant aeroid.Model; "
                f"{model.name!r} is not (use 'simulated')"
            )
        y_sim = _simulated_outputs(model, delayed_controls(parameters, data), values, x0)
        idx_y = [model_outputs.index(o) for o in outs]
        _, h_model, _, _ = _empirical(u, y_sim[:, idx_y].T, fs, seg)
    resolved = _resolved(h_model, excitation)
    f, h_emp, h_model, coh = f[keep], h_emp[keep], h_model[keep], coh[keep]
    excitation, resolved = excitation[keep], resolved[keep]

    chans = []
    few = []
    unresolved = 0  # coherent, excited frequencies of the few channels the window blurs
    for i, inp in enumerate(ins):
        for k, out in enumerate(outs):
            he, hm, g = h_emp[:, i, k], h_model[:, i, k], coh[:, i, k]
            responding = (g >= thr_used) & (excitation[:, i] >= _EXCITED_FRACTION) & resolvable
            mask = responding & resolved[:, i, k]  # see _RESOLVED_STEP
            with np.errstate(all="ignore"):
                rel = np.abs(he - hm) / np.abs(hm)
            good = mask & np.isfinite(rel)
            mis = float(np.sum(g[good] * rel[good]) / np.sum(g[good])) if good.any() else np.nan
            n_coh = int(mask.sum())
            if n_coh < min_coherent:
                few.append(f"{inp}->{out} ({n_coh})")
                unresolved += int(responding.sum()) - n_coh
            chans.append(
                ChannelFrequencyResponse(
                    input_name=inp,
                    output_name=out,
                    frequency=f,
                    magnitude=np.abs(he),
                    phase=np.angle(he),
                    coherence=g,
                    model_magnitude=np.abs(hm),
                    model_phase=np.angle(hm),
                    coherent=mask,
                    mismatch=mis,
                    n_coherent=n_coh,
                )
            )
    if few:
        warnings.warn(
            f"frequency_response: too few coherent frequencies (γ² ≥ {thr_used:.3g} with "
            f"{n_avg:.3g} independent averages, input within "
            f"{10 * np.log10(1 / _EXCITED_FRACTION):.0f} dB of its peak) in "
            f"{band[0]:.3g}–{band[1]:.3g} Hz for {', '.join(few)}; "
            + (
                f"{unresolved} more respond but are not resolved by {seg}-sample segments "
                "(longer segments, `nperseg`, resolve lower and sharper responses)"
                if unresolved
                else "the input does not excite these channels enough to judge the model there"
            ),
            UserWarning,
            stacklevel=3,  # frequency_response, its BLAS wrapper (aeroid._threads), the caller
        )
    return FrequencyResponseResult(
        channels=tuple(chans),
        input_names=tuple(ins),
        output_names=tuple(outs),
        sample_rate=float(fs),
        nperseg=seg,
        coherence_threshold=thr_used,
        frequency_range=(float(band[0]), float(band[1])),
        model_response=how,
        model_name=str(model.name),
        n_averages=n_avg,
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
