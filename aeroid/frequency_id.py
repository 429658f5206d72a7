"""Frequency-response identification as CIFER does it: composite responses, transfer-function fits.

Composite response (Tischler & Remple, "Aircraft and Rotorcraft System
Identification", ch. 7-8). For each window length the record is cut into
Hann-windowed segments overlapping by `overlap`; the auto- and cross-spectra
of every segment are evaluated at the requested frequencies by the finite
Fourier transform (chirp-z where the frequencies are evenly spaced, a direct
sum otherwise: no FFT bins) and averaged. A window of length ``T`` resolves
frequencies from ``4π/T`` (two periods in the window) up. Each window gives a
frequency response ``H = Gxy / Gxx``, a coherence ``γ²`` and the random error
``εr = sqrt(1 − γ²) / (|γ| sqrt(2 n_d))`` (Bendat & Piersol), ``n_d`` the
number of independent averages equivalent to the overlapped segments.

The windows are combined per frequency with CIFER's weights ``W_i = 1 / εr_i²``
(each window's random error at that frequency), but with one weight for each
window's whole spectral matrix, first scaled by its input power: the composite
is a weighted mean of positive semi-definite matrices, so its coherence is at
most 1 by construction, and with one input its response is the weighted mean
of the windows' responses. (Weighting each auto- and cross-spectrum on its own,
as a relative least-squares fit of every spectrum does, let the coherence
exceed 1.) A window counts only from two periods of a frequency up; requested
frequencies below two periods of the longest window are dropped with a
warning and a note, and a window that fits the record only once (coherence 1
whatever the data) is refused. The composite response, coherence and random
error follow from the composite spectra. All windows see the same data, so
averaging them adds no independent information: the composite's ``n_d`` is the
weighted mean of the windows' ``n_d``, not their sum. The random error
reported is at least 1 %: no estimate from windows is better (leakage and
resolution bias), and no point can outweigh the others in a fit by more than
that allows.

With several inputs every window's full spectral matrix is combined the same
way (weights from the mean random error of its pairs) and the composite is
conditioned per frequency, ``H = Gxx⁻¹ Gxy``; the coherence is the partial
coherence of each input with the output given the others, the multiple
coherence is reported per output, and the random error uses
``n_d − n_u + 1`` averages (Bendat & Piersol, ch. 7).

Transfer-function fit. ``T(s) = (b_m s^m + … + b_0) / (s^n + a_{n−1} s^{n−1} + … + a_0) e^{−τ s}``
is fitted to the response in magnitude (dB) and phase (deg). Start values come
from Sanathanan-Koerner iterations of Levy's linear complex least squares;
Levenberg-Marquardt then minimises one of two costs:

* ``weighting="cifer"``: CIFER's ``J = (20/n_ω) Σ W_γ [(ΔdB)² + 0.01745 (Δφ)²]``
  with ``W_γ = [1.58 (1 − e^{−γ²})]²``. Its Cramér-Rao bounds are
  ``sqrt(diag(H⁻¹))`` with ``H`` the Gauss-Newton Hessian of J, and the
  insensitivities ``1 / sqrt(H_ii)``. These follow the textbook's form; they
  are not calibrated probabilities (they implicitly assume about 1 dB and
  7.6° of error per point for 20 points).
* ``weighting="random_error"``: weighted least squares with each point's
  magnitude and phase weighted by the inverse variance the random error
  implies (``σ_dB = 8.686 εr``, ``σ_φ = 57.3 εr`` deg). The parameter covariance
  is ``s² (JᵀJ)⁻¹`` with ``s²`` the residual mean square; these standard
  errors are the calibrated ones (pinned by a coverage test over seeds) as
  long as the fitted frequencies are about independent (spaced at least two
  resolution cells of the window apart).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._czt import _evenly_spaced, _kernel, fourier, hann
from ._records import IntervalMixin, ReadOnlyDict, fmt, frozen_array, frozen_mapping, markdown_table
from ._records import frozen_complex as _frozen_complex
from ._threads import CALLER_STACKLEVEL, small_blas
from ._transfer import transfer_at
from .data import FlightData, _numeric, as_float, check_flag, plain
from .errors import ChannelError, DataFormatError, IdentificationError

__all__ = [
    "CompositeResponse",
    "ResponseChannel",
    "TransferFunctionFit",
    "composite_response",
    "fit_transfer_function",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_DB = 20.0 / np.log(10.0)  # dB per neper
_DEG = 180.0 / np.pi
# CIFER's phase weight: 1 dB of magnitude error costs as much as 7.57 deg of phase.
_W_PHASE = 0.01745
_WEIGHTINGS = ("cifer", "random_error")
_EXCITED = 0.01  # power, relative to the input's peak, that counts as excited
_MIN_PERIODS = 2  # periods of a frequency a window (or the whole record) must hold
# Tischler's guidelines for a reliable parameter.
_CR_LIMIT = 20.0
_INSENSITIVITY_LIMIT = 10.0
# A random error this small (γ² = 1 to rounding) still gives a finite weight.
_MIN_RANDOM_ERROR = 1e-9
# The least random error a composite reports: a windowed estimate of even a noise-free
# record is only good to about 1 % (leakage and resolution bias: the noise-free sweep
# of the tests), so no point claims less, and none outweighs a fit's others by more
# than (εr / 0.01)².
_RANDOM_ERROR_FLOOR = 0.01
# Reweighting passes of the random-error fit (weights from the previous pass's model).
_PASSES = 3
# Smallest eigenvalue of the inputs' coherence matrix taken as singular.
_DEPENDENT = 1e-10


# -- records -----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ResponseChannel:
    """Frequency response of one input-output pair: the one response record of AeroID.

    Every frequency tool returns it (`frequency_response`'s channels, also
    reachable as ``ChannelFrequencyResponse``; `composite_response`'s;
    `fit_transfer_function` and the handling-qualities tools read it):
    frequencies in rad/s and the complex response, with magnitude (dB),
    phase (degrees), Hz and linear gain as derived properties.

    Attributes
    ----------
    input_name, output_name : str
    frequency : ndarray, shape (n_ω,)
        Frequencies in rad/s, increasing.
    response : ndarray of complex, shape (n_ω,)
        The measured (conditioned) frequency response ``H(jω)``.
    coherence : ndarray
        γ² (partial coherence given the other inputs when there are
        several); NaN where unknown.
    random_error : ndarray
        Normalised random error ``εr`` of |H| (and of the phase, in
        radians); NaN where unknown.
    model_response : ndarray of complex
        A model's response at the same frequencies (`frequency_response`);
        NaN where there is none.
    coherent : ndarray of bool
        Frequencies that count (`frequency_response`: coherence above its
        threshold, input excited, resolved by a window); all of them by
        default.
    mismatch : float
        Coherence-weighted mean relative error ``Σ γ² |Ĥ − H| / |H| / Σ γ²``
        of the response against `model_response` over the coherent
        frequencies (NaN when not computed or none is coherent).
    window : ndarray of int
        Length in samples of the window each value comes from (empty when
        not recorded).
    dropped : mapping of str to int
        How many frequencies did not count, by reason.

    Raises
    ------
    DataFormatError
        A name that is not a string; frequencies that are not a non-empty 1-D
        array of finite, positive, strictly increasing values; a response
        that is not finite or not one value per frequency; a coherence
        outside [0, 1] or a negative random error, or either given with
        another length (leave them out, or pass None, when unknown: they are
        then NaN).
    """

    input_name: str
    output_name: str
    frequency: FloatArray
    response: ComplexArray
    coherence: FloatArray = field(default_factory=lambda: np.zeros(0))
    random_error: FloatArray = field(default_factory=lambda: np.zeros(0))
    model_response: ComplexArray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    coherent: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    mismatch: float = float("nan")
    window: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    dropped: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for label in ("input_name", "output_name"):
            if not isinstance(getattr(self, label), str):
                raise DataFormatError(
                    f"ResponseChannel: {label}: expected a channel name (str), got "
                    f"{getattr(self, label)!r}"
                )
        what = f"ResponseChannel {self.input_name!r} -> {self.output_name!r}"
        omega = _frequency_axis(self.frequency, f"{what}: frequency")
        h = self._complex(self.response, "response", omega.shape, what)
        bad = np.flatnonzero(~np.isfinite(h))
        if bad.size:
            i = int(bad[0])
            raise DataFormatError(
                f"{what}: response: non-finite value {plain(h[i])} at index {i} "
                f"({omega[i]:.6g} rad/s)"
            )
        object.__setattr__(self, "frequency", omega)
        object.__setattr__(self, "response", h)
        model = self.model_response
        if model is None or np.size(model) == 0:
            model = np.full(h.shape, np.nan + 0j)
        object.__setattr__(
            self, "model_response", self._complex(model, "model_response", omega.shape, what)
        )
        for name in ("coherence", "random_error"):
            given = getattr(self, name)
            if given is None or np.size(given) == 0:
                vals = np.full(h.shape, np.nan)  # not known
            else:
                vals = _numeric(given, f"{what}: {name}", "not numeric")
                if vals.shape != h.shape:
                    raise DataFormatError(
                        f"{what}: {name} has shape {vals.shape}, frequency {h.shape}; "
                        "expected one value per frequency"
                    )
                # a random error may be NaN (unknown) or infinite (no coherence)
                with np.errstate(invalid="ignore"):
                    wrong = ~((vals >= 0.0) & (vals <= 1.0)) if name == "coherence" else vals < 0.0
                if wrong.any():
                    i = int(np.flatnonzero(wrong)[0])
                    want = "in [0, 1]" if name == "coherence" else "non-negative or NaN"
                    raise DataFormatError(
                        f"{what}: {name}: expected values {want}, got {plain(vals[i])} at "
                        f"index {i} ({omega[i]:.6g} rad/s)"
                    )
            object.__setattr__(self, name, frozen_array(vals))
        mask = self.coherent
        mask = (
            np.ones(h.shape, dtype=bool)
            if mask is None or np.size(mask) == 0
            else np.array(mask, dtype=bool, copy=True)
        )
        if mask.shape != h.shape:
            raise DataFormatError(
                f"{what}: coherent has shape {mask.shape}, frequency {h.shape}; expected one "
                "flag per frequency"
            )
        mask.setflags(write=False)
        object.__setattr__(self, "coherent", mask)
        win = np.array(self.window, dtype=np.int64, copy=True)
        win.setflags(write=False)
        object.__setattr__(self, "window", win)
        object.__setattr__(self, "mismatch", float(self.mismatch))
        object.__setattr__(self, "dropped", frozen_mapping(self.dropped))

    @staticmethod
    def _complex(values: Any, name: str, shape: tuple[int, ...], what: str) -> ComplexArray:
        try:
            out = _frozen_complex(values)
        except (TypeError, ValueError) as exc:
            raise DataFormatError(f"{what}: {name}: not numeric ({exc})") from None
        if out.shape != shape:
            raise DataFormatError(
                f"{what}: {name} has shape {out.shape}, frequency {shape}; expected one value "
                "per frequency"
            )
        return out

    @property
    def frequency_rad_s(self) -> FloatArray:
        """Frequencies in rad/s (the `frequency` field)."""
        return self.frequency

    @property
    def frequency_hz(self) -> FloatArray:
        """Frequencies in Hz."""
        return frozen_array(self.frequency / (2.0 * np.pi))

    @property
    def gain(self) -> FloatArray:
        """|H|, output unit per input unit."""
        return frozen_array(np.abs(self.response))

    @property
    def magnitude(self) -> FloatArray:
        """``20 log10 |H|`` in dB."""
        with np.errstate(divide="ignore"):
            return frozen_array(20.0 * np.log10(np.abs(self.response)))

    magnitude_db = magnitude

    @property
    def phase(self) -> FloatArray:
        """Phase of H in degrees, unwrapped along frequency; the first point lies in (-270°, 90°]."""
        return frozen_array(_unwrapped_phase(self.response))

    phase_deg = phase

    @property
    def model_gain(self) -> FloatArray:
        """|model response|."""
        return frozen_array(np.abs(self.model_response))

    @property
    def model_magnitude(self) -> FloatArray:
        """The model's ``20 log10 |H|`` in dB."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return frozen_array(20.0 * np.log10(np.abs(self.model_response)))

    @property
    def model_phase(self) -> FloatArray:
        """The model's phase in degrees, on the measured phase's branch at each frequency."""
        return frozen_array(self.phase - self.phase_error)

    @property
    def phase_error(self) -> FloatArray:
        """Measured minus model phase in degrees, wrapped to (-180°, 180°]."""
        with np.errstate(invalid="ignore"):
            out = np.degrees(np.angle(self.response / self.model_response))
        return frozen_array(np.where(out <= -180.0, out + 360.0, out))

    @property
    def n_coherent(self) -> int:
        """How many frequencies count."""
        return int(np.count_nonzero(self.coherent))

    def as_response_channel(self) -> ResponseChannel:
        """This record (kept for code written when the types were two)."""
        return self

    def plot(self) -> Any:
        """Bode plot (dB, deg against rad/s) with a coherence panel. Returns a matplotlib Figure."""
        return _bode([self], [])


def _frequency_axis(values: Any, what: str) -> FloatArray:
    """`values` as a read-only 1-D array of finite, positive, strictly increasing rad/s."""
    omega = _numeric(values, what, "not numeric")
    if omega.ndim != 1 or omega.size == 0:
        raise DataFormatError(
            f"{what}: expected a non-empty 1-D array in rad/s, got shape {omega.shape}"
        )
    bad = np.flatnonzero(~np.isfinite(omega))
    if bad.size:
        raise DataFormatError(f"{what}: non-finite value at index {int(bad[0])}")
    bad = np.flatnonzero(omega <= 0.0)
    if bad.size:
        i = int(bad[0])
        raise DataFormatError(
            f"{what}: expected positive frequencies in rad/s, got {plain(omega[i])} at index {i}"
        )
    bad = np.flatnonzero(np.diff(omega) <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise DataFormatError(
            f"{what}: not strictly increasing at index {i} ({plain(omega[i - 1])} then "
            f"{plain(omega[i])} rad/s)"
        )
    return omega


def _unwrapped_phase(h: ComplexArray) -> FloatArray:
    ph = np.degrees(np.unwrap(np.angle(h)))
    if ph.size:
        # the first point in (-270, 90]: K/s reads -90 and K/s² reads -180, not +180
        ph = ph - 360.0 * np.ceil((ph[0] - 90.0) / 360.0)
    return np.asarray(ph, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class CompositeResponse:
    """Composite (multi-window) frequency responses of every input-output pair.

    Attributes
    ----------
    channels : tuple of ResponseChannel
    input_names, output_names : tuple of str
    frequency : ndarray
        Frequencies in rad/s shared by every channel.
    windows : tuple of float
        Window lengths in seconds.
    overlap : float
    n_averages : tuple of float
        Independent averages equivalent to each window's overlapped segments.
    sample_rate : float
        Hz.
    multiple_coherence : mapping of str to ndarray
        Per output, the multiple coherence with all inputs (equal to the
        ordinary coherence with one input).
    notes : tuple of str
        What was dropped and why (frequencies below two periods of the
        longest window).
    """

    channels: tuple[ResponseChannel, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    frequency: FloatArray
    windows: tuple[float, ...]
    overlap: float
    n_averages: tuple[float, ...]
    sample_rate: float
    multiple_coherence: Mapping[str, FloatArray] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "frequency", frozen_array(self.frequency))
        object.__setattr__(self, "multiple_coherence", frozen_mapping(self.multiple_coherence))

    def channel(self, input: str, output: str) -> ResponseChannel:
        """The response from `input` to `output`."""
        for ch in self.channels:
            if ch.input_name == input and ch.output_name == output:
                return ch
        raise ChannelError(
            f"no composite response for input {input!r} -> output {output!r}; "
            f"inputs {list(self.input_names)}, outputs {list(self.output_names)}"
        )

    def summary(self) -> str:
        """Markdown section: per pair, the band where γ² ≥ 0.6 and its mean random error."""
        rows = []
        for c in self.channels:
            ok = c.coherence >= 0.6
            band = (
                f"{fmt(float(c.frequency[ok].min()), 3)}–{fmt(float(c.frequency[ok].max()), 3)}"
                if ok.any()
                else "—"
            )
            err = fmt(100.0 * float(np.mean(c.random_error[ok])), 3) if ok.any() else "—"
            rows.append(
                (
                    c.input_name,
                    c.output_name,
                    int(ok.sum()),
                    band,
                    fmt(float(np.mean(c.coherence)), 3),
                    err,
                )
            )
        table = markdown_table(
            ("input", "output", "γ² ≥ 0.6", "band [rad/s]", "mean γ²", "mean εr [%] (γ² ≥ 0.6)"),
            rows,
        )
        wins = ", ".join(fmt(w, 3) for w in self.windows)
        nd = ", ".join(fmt(n, 3) for n in self.n_averages)
        return "\n".join(
            [
                "## Composite frequency response",
                "",
                table,
                "",
                f"{self.frequency.size} frequencies {fmt(float(self.frequency[0]), 3)}–"
                f"{fmt(float(self.frequency[-1]), 3)} rad/s; Hann windows of {wins} s overlapping "
                f"{fmt(100 * self.overlap, 3)} % ({nd} independent averages), combined per "
                "frequency with weights 1/εr² (CIFER's composite).",
            ]
        )

    def plot(self) -> Any:
        """Bode plot (dB, deg) with coherence, one column per pair. Returns a Figure."""
        return _bode(list(self.channels), [])


def _bode(channels: Sequence[ResponseChannel], fits: Sequence[Any]) -> Any:
    from .plotting import _LOG_LABELS, _figure

    fig, axes = _figure(
        3, len(channels), width=4.4 * len(channels), height=2.1, right=0.3, hgap=0.3, sharex="col"
    )
    for c, ch in enumerate(channels):
        w = ch.frequency
        mag, pha, coh = axes[0, c], axes[1, c], axes[2, c]
        mag.semilogx(w, ch.magnitude, "o", color="0.45", ms=2.5, label="measured")
        pha.semilogx(w, ch.phase, "o", color="0.45", ms=2.5)
        if np.isfinite(ch.model_response).any():
            mag.semilogx(w, ch.model_magnitude, color="C1", lw=1.2, label="model")
            pha.semilogx(w, ch.model_phase, color="C1", lw=1.2)
        for fit in fits:
            dense = np.geomspace(float(w[0]), float(w[-1]), 400)
            h = fit.evaluate(dense)
            mag.semilogx(dense, 20 * np.log10(np.abs(h)), color="C0", lw=1.4, label="fit")
            ph = _unwrapped_phase(h)
            # draw the fit on the data's branch of the phase
            k = int(np.argmin(np.abs(w - dense[0])))
            ph += 360.0 * np.round((ch.phase[k] - ph[0]) / 360.0)
            pha.semilogx(dense, ph, color="C0", lw=1.4)
        mag.set_title(f"{ch.input_name} → {ch.output_name}", fontsize=9)
        mag.set_ylabel("magnitude [dB]")
        pha.set_ylabel("phase [deg]")
        coh.semilogx(w, ch.coherence, color="C2")
        coh.axhline(0.6, color="k", ls="--", lw=0.7)
        coh.set_ylim(0, 1.05)
        coh.set_ylabel("coherence γ² [-]")
        coh.set_xlabel("frequency [rad/s]")
        coh.xaxis.set_major_formatter(_LOG_LABELS)
        coh.xaxis.set_minor_formatter(_LOG_LABELS)
        if fits or np.isfinite(ch.model_response).any():
            mag.legend(fontsize=7)
    return fig


# -- spectra -----------------------------------------------------------------------------


def _independent_averages(n: int, seg: int, step: int, window: FloatArray) -> float:
    """Independent averages equivalent to K overlapped segments (Welch 1967)."""
    k = (n - seg) // step + 1
    shifts = np.arange(1, k) * step
    shifts = shifts[shifts < seg]
    w2 = float(np.dot(window, window))
    rho = np.array([np.dot(window[: seg - d], window[d:]) for d in shifts]) / w2
    lag = np.arange(1, shifts.size + 1)
    return float(k / (1.0 + 2.0 * np.sum((1.0 - lag / k) * rho**2)))


def _window_spectra(
    signals: FloatArray, dt: float, seg: int, step: int, omega: FloatArray
) -> tuple[ComplexArray, ComplexArray, float]:
    """Spectral matrix G[m, a, b] = E[conj(X_a) X_b] (one-sided density) of one window length,
    the segments' transforms X (m, k, c) and the stationary count of independent averages."""
    n, c = signals.shape
    k = (n - seg) // step + 1
    win = hann(seg)
    x = np.empty((omega.size, k, c), dtype=np.complex128)
    if _evenly_spaced(omega / (2.0 * np.pi)):
        # chirp-z on every windowed, mean-removed segment
        starts = np.arange(k) * step
        segs = signals[starts[:, None] + np.arange(seg)[None, :]]  # (k, seg, c)
        segs = (segs - segs.mean(axis=1, keepdims=True)) * win[None, :, None]
        cols = np.ascontiguousarray(np.transpose(segs, (1, 0, 2)).reshape(seg, k * c))
        x[:] = fourier(cols, dt, omega / (2.0 * np.pi)).reshape(omega.size, k, c)
    else:
        # direct sum with the window folded into the kernel: the overlapping segments
        # are views of the record, and a segment's mean leaves as mean × W(ω)
        kern = _kernel(omega / (2.0 * np.pi), seg, dt) * win[None, :]
        kr, ki = np.ascontiguousarray(kern.real), np.ascontiguousarray(kern.imag)
        w_sum = kern.sum(axis=1)
        for j in range(c):
            view = np.lib.stride_tricks.sliding_window_view(signals[:, j], seg)[::step]
            block = np.ascontiguousarray(view.T)  # (seg, k)
            means = block.mean(axis=0)
            x[:, :, j] = (kr @ block + 1j * (ki @ block)) - w_sum[:, None] * means[None, :]
        x *= dt
    scale = 2.0 / (dt * float(np.dot(win, win)) * k)
    g = scale * np.einsum("mka,mkb->mab", np.conj(x), x)
    return g, x, _independent_averages(n, seg, step, win)


def _effective_averages(
    x: FloatArray | ComplexArray, omega: FloatArray, seg: int, step: int, dt: float
) -> FloatArray:
    """Independent averages behind a one-input estimate, per frequency, from the input's segments.

    ``Ĥ − H = Σ_k X̄_k N_k / Σ_k |X_k|²``; output noise in segments ``d`` samples apart
    correlates as ``E[N_k N̄_l] = S r_d e^{−jω d Δt}`` (``r_d`` the Hann window's overlap
    correlation), so ``Var Ĥ = S Q / (Σ |X_k|²)²`` with
    ``Q = Σ_{k,l} X̄_k X_l r_d e^{−jω d Δt}``; n_d = K Σ |X_k|² / Q makes it
    ``S / (n_d mean |X_k|²)``. A sweep puts each frequency in a few neighbouring,
    strongly overlapping segments, where the stationary count (Welch) would be far
    too many (and, where the overlap correlation changes sign, too few).
    """
    win = hann(seg)
    w2 = float(np.dot(win, win))
    power = np.sum(np.abs(x) ** 2, axis=1)  # (m,)
    q = power.copy()
    k = x.shape[1]
    for j in range(1, k):
        d = j * step
        if d >= seg:
            break
        r = float(np.dot(win[: seg - d], win[d:])) / w2
        lagged = np.sum(np.conj(x[:, :-j]) * x[:, j:], axis=1)
        q += 2.0 * r * np.real(lagged * np.exp(-1j * omega * d * dt))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = k * power / q
    return np.where(q > 0, np.maximum(out, 1.0), 1.0)


def _condition(g: ComplexArray, n_u: int) -> tuple[ComplexArray, FloatArray, FloatArray]:
    """H (m, n_u, n_y), partial coherence (m, n_u, n_y), multiple coherence (m, n_y)."""
    m, size, _ = g.shape
    n_y = size - n_u
    gxx = g[:, :n_u, :n_u]
    gxy = g[:, :n_u, n_u:]
    gyy = np.real(np.diagonal(g[:, n_u:, n_u:], axis1=1, axis2=2))
    with np.errstate(all="ignore"):
        if n_u == 1:
            pxx = np.real(gxx[:, 0, 0])
            h = gxy / pxx[:, None, None]
            coh = np.abs(gxy) ** 2 / (pxx[:, None, None] * gyy[:, None, :])
            mult = coh[:, 0, :].copy()
        else:
            h = np.linalg.pinv(gxx) @ gxy
            coh = np.empty((m, n_u, n_y))
            mult = np.empty((m, n_y))
            for j in range(n_y):
                idx = [*range(n_u), n_u + j]
                inv = np.linalg.pinv(g[:, idx][:, :, idx])
                giy = inv[:, :n_u, n_u]
                gii = np.real(np.diagonal(inv[:, :n_u, :n_u], axis1=1, axis2=2))
                gjj = np.real(inv[:, n_u, n_u])
                coh[:, :, j] = np.abs(giy) ** 2 / (gii * gjj[:, None])
                mult[:, j] = 1.0 - 1.0 / (gyy[:, j] * gjj)
    coh = np.clip(np.nan_to_num(coh, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    mult = np.clip(np.nan_to_num(mult, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    return np.nan_to_num(h), coh, mult


def _random_error(
    coh: FloatArray, n_d: FloatArray | float, n_u: int, *, floor: bool = True
) -> FloatArray:
    """Bendat & Piersol's ``sqrt(1 − γ²) / (|γ| sqrt(2 n_d))``, at least `_RANDOM_ERROR_FLOOR`.

    With the floor a point read at γ² = 1 weighs at most 10⁴ times a point of 100 %
    error in a fit, not 10¹⁸ (the old floor of 1e-9 let one such point decide a fit).
    Without it (`floor=False`) the error only ranks the windows of one frequency.
    """
    dof = np.maximum(np.asarray(n_d, dtype=np.float64) - n_u + 1.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt(1.0 - coh) / (np.sqrt(coh) * np.sqrt(2.0 * dof))
    least = _RANDOM_ERROR_FLOOR if floor else _MIN_RANDOM_ERROR
    return np.where(coh > 0.0, np.maximum(err, least), np.inf)


def _names(value: str | Sequence[str], what: str) -> list[str]:
    try:
        names = [value] if isinstance(value, str) else list(value)
    except TypeError:
        raise ChannelError(f"{what}: expected one or more channel names, got {value!r}") from None
    if not names or not all(isinstance(v, str) for v in names):
        raise ChannelError(f"{what}: expected one or more channel names, got {value!r}")
    if len(set(names)) != len(names):
        raise ChannelError(f"{what}: repeated channel in {names}")
    return names


@small_blas
def composite_response(
    data: FlightData,
    inputs: str | Sequence[str],
    outputs: str | Sequence[str],
    *,
    frequencies: ArrayLike | None = None,
    windows: Sequence[float] | None = None,
    overlap: float = 0.8,
    frequency_range: tuple[float, float] | None = None,
) -> CompositeResponse:
    """Composite multi-window frequency responses, as CIFER computes them.

    Parameters
    ----------
    data : FlightData
        Uniformly sampled record.
    inputs, outputs : str or sequence of str
        Input (excitation) and output channels. With several inputs the
        responses are conditioned on all of them.
    frequencies : array_like, optional
        Frequencies in rad/s (default: 100 log-spaced over `frequency_range`).
        Evenly spaced ones are transformed by chirp-z.
    windows : sequence of float, optional
        Window lengths in seconds (default: a half, a quarter and an eighth of
        the record).
    overlap : float
        Fraction of a window shared by consecutive segments, in [0, 0.95].
    frequency_range : (float, float), optional
        Band in rad/s (default: from 4π over the longest window, two periods,
        to a quarter of the sample rate in rad/s).

    Returns
    -------
    CompositeResponse

    Raises
    ------
    DataFormatError
        Non-uniform time grid, or a window that is not finite, longer than the
        record, shorter than 8 samples, or that fits the record only once at
        the given overlap (one segment: coherence 1 whatever the data).
    ChannelError
        A channel is missing or repeated, or `inputs`/`outputs` are not names.
    IdentificationError
        Bad overlap, windows, frequencies (not numbers, repeated, outside
        (0, Nyquist]) or range, or all of them below two periods of the
        longest window; a constant input (no excitation); inputs that are
        linearly dependent (their cross-spectral matrix singular at every
        frequency).

    Warns
    -----
    UserWarning
        When requested frequencies lie below two periods of the longest
        window: they are dropped, and the result's ``notes`` say so.
    """
    if not isinstance(data, FlightData):
        raise DataFormatError(f"data: expected FlightData, got {type(data).__name__}")
    if not data.is_uniform:
        raise DataFormatError(
            "data: composite_response needs a uniform time grid (Fourier transforms); resample first"
        )
    ins, outs = _names(inputs, "inputs"), _names(outputs, "outputs")
    if set(ins) & set(outs):
        raise ChannelError(f"channels {sorted(set(ins) & set(outs))} are both inputs and outputs")
    data.require(ins, role="input")
    data.require(outs, role="output")
    try:
        ov = float(overlap)
    except (TypeError, ValueError):
        raise IdentificationError(
            f"overlap: expected a number in [0, 0.95], got {overlap!r}"
        ) from None
    if not 0.0 <= ov <= 0.95:
        raise IdentificationError(f"overlap: expected a number in [0, 0.95], got {overlap!r}")
    fs = data.sample_rate
    dt = 1.0 / fs
    n = data.n_samples
    if windows is None:
        wins = [data.duration / d for d in (2.0, 4.0, 8.0)]
    else:
        try:
            arr = np.atleast_1d(np.asarray(windows, dtype=np.float64))
        except (TypeError, ValueError):
            arr = np.zeros((0, 0))  # refused below
        if arr.ndim != 1 or arr.size == 0:
            raise IdentificationError(
                f"windows: expected one or more lengths in seconds, got {windows!r}"
            )
        wins = [float(w) for w in arr]
    segs = []
    for w in wins:
        if not np.isfinite(w):
            raise DataFormatError(f"windows: a window length must be finite, got {w!r} s")
        seg = round(w * fs)
        if seg < 8 or seg > n:
            raise DataFormatError(
                f"windows: a {w!r} s window holds {seg} samples; it needs 8 to the record's {n}"
            )
        if (n - seg) // max(1, round(seg * (1.0 - ov))) + 1 < 2:
            # one segment: γ² = 1 at every frequency, whatever the data
            raise DataFormatError(
                f"windows: a {w!r} s window fits the {data.duration:.6g} s record once "
                f"(overlap {ov:g}), and one segment has coherence 1 by construction; "
                "use shorter windows"
            )
        segs.append(seg)
    nyquist = np.pi * fs
    if frequencies is None:
        if frequency_range is None:
            lo, hi = 4.0 * np.pi / (max(segs) * dt), 0.5 * nyquist
        else:
            lo, hi = _band(frequency_range)
        if not 0.0 < lo < hi <= nyquist:
            raise IdentificationError(
                f"frequency_range: need 0 < low < high <= Nyquist {nyquist:.6g} rad/s, got ({lo:.6g}, {hi:.6g})"
            )
        omega = np.geomspace(lo, hi, 100)
    else:
        given = np.asarray(frequencies)
        if given.dtype.kind not in "iuf":
            raise IdentificationError(
                f"frequencies: expected numbers in rad/s, got {plain(frequencies)}"
            )
        omega = np.sort(np.atleast_1d(given.astype(np.float64)))
        if frequency_range is not None:
            lo, hi = _band(frequency_range)
            omega = omega[(omega >= lo) & (omega <= hi)]
        if omega.ndim != 1 or omega.size == 0 or not np.all(np.isfinite(omega)):
            raise IdentificationError("frequencies: expected a non-empty 1-D array in rad/s")
        if omega[0] <= 0.0 or omega[-1] > nyquist:
            raise IdentificationError(
                f"frequencies: expected values in (0, {nyquist:.6g}] rad/s (Nyquist), got "
                f"{omega[0]:.6g}–{omega[-1]:.6g}"
            )
        repeated = np.flatnonzero(np.diff(omega) == 0.0)
        if repeated.size:
            raise IdentificationError(
                f"frequencies: {omega[repeated[0]]:.6g} rad/s is given more than once; "
                "give each frequency once"
            )
    # two periods in the longest window: below that its Hann estimate is leakage
    limit = 4.0 * np.pi / (max(segs) * dt)
    notes: list[str] = []
    low = omega < limit * (1.0 - 1e-12)
    if low.all():
        raise IdentificationError(
            f"frequencies: all below {limit:.6g} rad/s, two periods of the longest window "
            f"({max(segs) * dt:.6g} s); give higher frequencies or longer windows"
        )
    if low.any():
        notes.append(
            f"{int(low.sum())} frequencies below {limit:.4g} rad/s (two periods of the longest, "
            f"{max(segs) * dt:.4g} s, window) dropped"
        )
        warnings.warn(f"composite_response: {notes[-1]}", UserWarning, stacklevel=3)
        omega = omega[~low]
    for name in ins:
        samples = data.channels[name]
        # after the segments' means are removed a constant input is zero: nothing to divide by
        if np.ptp(samples) <= 1e-12 * float(np.max(np.abs(samples))):
            raise IdentificationError(
                f"input {name!r} is constant ({plain(samples[0])}) and carries no excitation; "
                "a frequency response needs an input that varies"
            )
    n_u, n_y = len(ins), len(outs)
    signals = np.column_stack([data.array(ins), data.array(outs)])
    spectra, n_avg, weights, n_stationary = [], [], [], []
    for seg in segs:
        step = max(1, round(seg * (1.0 - ov)))
        g, x, nd_stationary = _window_spectra(signals, dt, seg, step, omega)
        nd = (
            _effective_averages(x[:, :, 0], omega, seg, step, dt)
            if n_u == 1
            else np.full(omega.size, nd_stationary)
        )
        _, coh, _ = _condition(g, n_u)
        # CIFER's window weights: the windows' own random errors (a convex combination, so
        # a near-zero one only prefers that window)
        err = _random_error(coh, nd[:, None, None], n_u, floor=False)
        with np.errstate(over="ignore"):
            wt = 1.0 / np.mean(err**2, axis=(1, 2))
        # below two periods per window the Hann estimate is leakage, not response
        wt = np.where(omega >= 4.0 * np.pi / (seg * dt), wt, 0.0)
        spectra.append(g)
        n_avg.append(nd)
        n_stationary.append(nd_stationary)
        weights.append(wt)
    wts = np.array(weights)  # (n_w, m)
    none = ~np.any(wts > 0, axis=0)
    if np.any(none):
        # no coherent window: every window that holds two periods (the longest does: the
        # frequencies below its limit were dropped above) counts alike
        resolves = np.array([omega >= 4.0 * np.pi / (s * dt) for s in segs], dtype=float)
        wts[:, none] = resolves[:, none]
    wn = wts / np.sum(wts, axis=0)
    gc = _combine(np.array(spectra), wn, n_u)
    if n_u > 1:
        _refuse_dependent_inputs(gc[:, :n_u, :n_u], ins)
    nd_c = np.sum(wn * np.array(n_avg), axis=0)
    h, coh, mult = _condition(gc, n_u)
    err = _random_error(coh, nd_c[:, None, None], n_u)
    channels = tuple(
        ResponseChannel(
            ins[i], outs[j], omega, h[:, i, j], coherence=coh[:, i, j], random_error=err[:, i, j]
        )
        for i in range(n_u)
        for j in range(n_y)
    )
    return CompositeResponse(
        channels,
        tuple(ins),
        tuple(outs),
        omega,
        tuple(s * dt for s in segs),
        ov,
        tuple(n_stationary),
        fs,
        {o: mult[:, j] for j, o in enumerate(outs)},
        notes=tuple(notes),
    )


def _combine(spectra: ComplexArray, weights: FloatArray, n_u: int) -> ComplexArray:
    """Composite spectral matrix (m, c, c) of the windows' (n_w, m, c, c), weights (n_w, m).

    One weight per window and frequency for the whole matrix: a weighted mean of
    Hermitian, positive semi-definite matrices is one, so ``|Gxy|² <= Gxx Gyy`` and
    every coherence is at most 1 by construction (a weight per element, as a
    relative least-squares fit of each spectrum gives, broke that). Each window's
    matrix is first scaled by its inputs' power, so with one input the composite
    response is the weighted mean of the windows' responses.
    """
    power = np.mean(np.real(np.diagonal(spectra[:, :, :n_u, :n_u], axis1=2, axis2=3)), axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = np.where(power > 0, weights / power, 0.0)
    total = np.sum(scaled, axis=0)
    scaled = np.where(total > 0, scaled / np.where(total > 0, total, 1.0), weights)
    return np.asarray(np.einsum("wm,wmab->mab", scaled, spectra), dtype=np.complex128)


def _refuse_dependent_inputs(gxx: ComplexArray, names: Sequence[str]) -> None:
    """Refuse inputs whose cross-spectral matrix is singular at every frequency.

    Then one input is a combination (or a filtered copy) of the others and no
    conditioning can tell their responses apart: ``Gxx⁻¹`` does not exist and a
    pseudo-inverse would split the response between them arbitrarily.
    """
    d = np.sqrt(np.real(np.diagonal(gxx, axis1=1, axis2=2)))
    with np.errstate(all="ignore"):
        r = np.nan_to_num(gxx / (d[:, :, None] * d[:, None, :]))
    lam, vec = np.linalg.eigh(r)
    # exactly dependent inputs reach 1e-16 (rounding); a noise-free filtered copy 1e-3
    if np.all(lam[:, 0] <= _DEPENDENT):
        share = np.mean(np.abs(vec[:, :, 0]) ** 2, axis=0)
        involved = [n for n, v in zip(names, share, strict=True) if v > 0.01]
        raise IdentificationError(
            f"inputs {involved} are linearly dependent: their cross-spectral matrix is "
            "singular at every frequency (one is a multiple, combination or filtered copy "
            "of the others, or the windows hold too few segments to separate them), so "
            "their responses cannot be told apart; drop one of them"
        )


def _band(frequency_range: Any) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in frequency_range)
    except (TypeError, ValueError):
        raise IdentificationError(
            f"frequency_range: expected (low, high) in rad/s, got {frequency_range!r}"
        ) from None
    if not 0.0 <= lo < hi:
        raise IdentificationError(
            f"frequency_range: expected 0 <= low < high, got {frequency_range!r}"
        )
    return lo, hi


# -- transfer-function fit -----------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TransferFunctionFit(IntervalMixin):
    """A fitted transfer function ``(Σ b_k s^k) / (s^n + Σ a_k s^k) · e^{−τ s}``.

    Attributes
    ----------
    parameters : mapping of str to float
        ``b0``…``bm``, ``a0``…``a{n-1}`` and ``tau`` (s, when fitted).
    standard_errors : mapping of str to float
        Cramér-Rao bounds (``weighting="cifer"``, CIFER's form) or calibrated
        standard errors (``weighting="random_error"``).
    insensitivities : mapping of str to float
        Tischler's insensitivity ``1 / sqrt(H_ii)`` of each parameter.
    covariance : ndarray
        Parameter covariance in the order of `parameters`.
    numerator, denominator : ndarray
        Polynomial coefficients, highest power first (denominator monic).
    delay : float
        τ in seconds (0 when not fitted).
    cost : float
        CIFER's cost ``J = (20/n_ω) Σ W_γ [ΔdB² + 0.01745 Δφ²]`` at the fit,
        whatever the weighting.
    weighting : str
    reduced_chi_square : float
        Residual mean square of the weighted fit (about 1 when the random
        errors describe the data; NaN for ``"cifer"``).
    frequency, response, coherence, random_error : ndarray
        The fitted points (rad/s; complex response).
    input_name, output_name : str
    """

    parameters: Mapping[str, float]
    standard_errors: Mapping[str, float]
    insensitivities: Mapping[str, float]
    covariance: FloatArray
    numerator: FloatArray
    denominator: FloatArray
    delay: float
    cost: float
    weighting: str
    reduced_chi_square: float
    frequency: FloatArray
    response: ComplexArray
    coherence: FloatArray
    random_error: FloatArray
    input_name: str = ""
    output_name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", frozen_mapping(self.parameters))
        object.__setattr__(self, "standard_errors", frozen_mapping(self.standard_errors))
        object.__setattr__(self, "insensitivities", frozen_mapping(self.insensitivities))
        for name in (
            "covariance",
            "numerator",
            "denominator",
            "frequency",
            "coherence",
            "random_error",
        ):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        object.__setattr__(self, "response", _frozen_complex(self.response))

    @property
    def stderr(self) -> Mapping[str, float]:
        """The `standard_errors` (the name every estimator's result shares)."""
        return self.standard_errors

    @property
    def degrees_of_freedom(self) -> Mapping[str, float]:
        """Per parameter, the residual degrees of freedom of the fit: two real
        components per fitted frequency less the parameters (`interval` takes
        Student's t with them)."""
        nu = float(max(2 * np.size(self.frequency) - len(self.parameters), 1))
        return ReadOnlyDict({n: nu for n in self.parameters})

    def transfer_function(self, s: ArrayLike) -> ComplexArray:
        """T(s) at complex `s`."""
        return transfer_at(self.numerator, self.denominator, s, delay=self.delay)

    def evaluate(self, frequency: ArrayLike) -> ComplexArray:
        """T(jω) at frequencies ω in rad/s."""
        return self.transfer_function(1j * np.asarray(frequency, dtype=np.float64))

    @property
    def poles(self) -> ComplexArray:
        """Roots of the denominator."""
        return _frozen_complex(np.roots(self.denominator))

    @property
    def zeros(self) -> ComplexArray:
        """Roots of the numerator."""
        return _frozen_complex(np.roots(np.trim_zeros(self.numerator, "f")))

    @property
    def flagged(self) -> tuple[str, ...]:
        """Parameters beyond Tischler's guidelines (CR bound > 20 %, insensitivity > 10 %)."""
        out = []
        for k, v in self.parameters.items():
            cr = _percent(self.standard_errors[k], v)
            ins = _percent(self.insensitivities[k], v)
            if not (cr <= _CR_LIMIT and ins <= _INSENSITIVITY_LIMIT):
                out.append(k)
        return tuple(out)

    def summary(self) -> str:
        """Markdown table of estimates, bounds and insensitivities with the guideline flags."""
        rows = []
        label = "CR bound" if self.weighting == "cifer" else "std. error"
        for k, v in self.parameters.items():
            cr = _percent(self.standard_errors[k], v)
            ins = _percent(self.insensitivities[k], v)
            flag = []
            if not cr <= _CR_LIMIT:
                flag.append(f"{label} > {_CR_LIMIT:.0f} %")
            if not ins <= _INSENSITIVITY_LIMIT:
                flag.append(f"insensitivity > {_INSENSITIVITY_LIMIT:.0f} %")
            rows.append(
                (
                    k,
                    fmt(v),
                    fmt(self.standard_errors[k], 3),
                    fmt(cr, 3),
                    fmt(ins, 3),
                    "; ".join(flag) or "—",
                )
            )
        table = markdown_table(
            ("parameter", "estimate", label, f"{label} [%]", "insensitivity [%]", "flag"), rows
        )
        pair = f" {self.input_name} → {self.output_name}" if self.input_name else ""
        return "\n".join(
            [
                f"## Transfer-function fit{pair}",
                "",
                table,
                "",
                f"Numerator order {self.numerator.size - 1}, denominator order "
                f"{self.denominator.size - 1}, delay {'fitted' if 'tau' in self.parameters else 'none'}; "
                f"{self.frequency.size} frequencies {fmt(float(self.frequency[0]), 3)}–"
                f"{fmt(float(self.frequency[-1]), 3)} rad/s; weighting {self.weighting!r}; "
                f"CIFER cost J = {fmt(self.cost, 4)} (Tischler: J ≤ 100 acceptable, ≤ 50 good)."
                + (
                    f" Reduced χ² {fmt(self.reduced_chi_square, 3)}."
                    if np.isfinite(self.reduced_chi_square)
                    else ""
                ),
            ]
        )

    def plot(self) -> Any:
        """The fit over the data: Bode plot (dB, deg) with coherence. Returns a Figure."""
        ch = ResponseChannel(
            self.input_name or "input",
            self.output_name or "output",
            self.frequency,
            self.response,
            coherence=self.coherence,
            random_error=self.random_error,
        )
        return _bode([ch], [self])


def _percent(value: float, reference: float) -> float:
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(100.0 * abs(value) / abs(reference)) if reference != 0 else float("inf")


def _coherence_weight(coh: FloatArray) -> FloatArray:
    return np.asarray((1.58 * (1.0 - np.exp(-coh))) ** 2, dtype=np.float64)


class _Structure:
    """Maps the parameter vector [b_0..b_m, a_0..a_{n-1}, (tau)] to T(jω) and its log-derivatives."""

    def __init__(self, m: int, n: int, delay: bool, omega: FloatArray) -> None:
        self.m, self.n, self.delay = m, n, delay
        s = 1j * omega
        self.s = s
        self.sb = s[:, None] ** np.arange(m + 1)[None, :]  # (n_ω, m+1)
        self.sa = s[:, None] ** np.arange(n)[None, :]  # (n_ω, n)
        self.sn = s**n
        self.names = (
            [f"b{k}" for k in range(m + 1)]
            + [f"a{k}" for k in range(n)]
            + (["tau"] if delay else [])
        )

    def split(self, theta: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        m, n = self.m, self.n
        tau = float(theta[m + 1 + n]) if self.delay else 0.0
        return theta[: m + 1], theta[m + 1 : m + 1 + n], tau

    def log_response(self, theta: FloatArray) -> tuple[ComplexArray, ComplexArray]:
        """log T(jω) and d log T / dθ (n_ω, p)."""
        b, a, tau = self.split(theta)
        num = self.sb @ b
        den = self.sn + self.sa @ a
        with np.errstate(all="ignore"):
            logt = np.log(num) - np.log(den) - tau * self.s
            cols: list[ComplexArray] = [self.sb / num[:, None], -self.sa / den[:, None]]
        if self.delay:
            cols.append(np.asarray(-self.s[:, None], dtype=np.complex128))
        return logt, np.concatenate(cols, axis=1)


def _levy_sk(
    st: _Structure, h: ComplexArray, weight: FloatArray, iterations: int = 6
) -> FloatArray:
    """Rational fit N/D to the complex response by Sanathanan-Koerner iterations of Levy's method."""
    prev = np.ones(h.size)
    a_cols = -h[:, None] * st.sa
    rhs = h * st.sn
    design = np.concatenate([st.sb, a_cols], axis=1)
    theta = np.zeros(design.shape[1])
    for _ in range(iterations):
        w = np.sqrt(weight) / prev
        x = design * w[:, None]
        y = rhs * w
        xs = np.concatenate([x.real, x.imag])
        ys = np.concatenate([y.real, y.imag])
        # column scaling keeps powers of ω from ruining the conditioning
        norms = np.linalg.norm(xs, axis=0)
        norms[norms == 0] = 1.0
        sol = np.linalg.lstsq(xs / norms, ys, rcond=None)[0] / norms
        if not np.all(np.isfinite(sol)):
            break
        theta = sol
        den = np.abs(st.sn + st.sa @ theta[st.m + 1 :])
        prev = np.maximum(den, 1e-12 * max(float(den.max()), 1e-300))
    return theta


def _resolve_response(
    response_or_data: Any, input: str | None, output: str | None, what: str = "response_or_data"
) -> ResponseChannel:
    if isinstance(response_or_data, ResponseChannel):
        return response_or_data
    if isinstance(response_or_data, FlightData):
        if input is None or output is None:
            raise ChannelError(f"{what}: flight data need input= and output= channel names")
        return composite_response(response_or_data, input, output).channels[0]
    if isinstance(response_or_data, CompositeResponse):
        if input is None and output is None and len(response_or_data.channels) == 1:
            return response_or_data.channels[0]
        if input is None or output is None:
            raise ChannelError(
                f"{what}: the composite response has pairs "
                f"{[(c.input_name, c.output_name) for c in response_or_data.channels]}; "
                "pick one with input= and output="
            )
        return response_or_data.channel(input, output)
    raise IdentificationError(
        f"{what}: expected a CompositeResponse, ResponseChannel or FlightData, got "
        f"{type(response_or_data).__name__}"
    )


@small_blas
def fit_transfer_function(
    response_or_data: CompositeResponse | ResponseChannel | FlightData,
    *,
    numerator_order: int,
    denominator_order: int,
    delay: bool = True,
    frequency_range: tuple[float, float] | None = None,
    input: str | None = None,
    output: str | None = None,
    start: Mapping[str, float] | None = None,
    weighting: str = "cifer",
    min_coherence: float = 0.6,
    fixed: Mapping[str, float] | None = None,
    fourier: bool = False,
    frequencies: ArrayLike | None = None,
) -> TransferFunctionFit:
    """Fit ``(b_m s^m + … + b_0) / (s^n + a_{n−1} s^{n−1} + … + a_0) · e^{−τ s}`` to a frequency response.

    Parameters
    ----------
    response_or_data : CompositeResponse, ResponseChannel or FlightData
        The measured response (flight data are first turned into a composite
        response with the default windows; then `input` and `output` are needed).
    numerator_order, denominator_order : int
        m ≥ 0 and n ≥ 1, in any order (m > n, an improper transfer function,
        fits a band-limited response such as SIDPAC's Example 7.2).
    delay : bool
        Fit the equivalent time delay τ.
    frequency_range : (float, float), optional
        Band in rad/s (default: every frequency of the response).
    input, output : str, optional
        The pair to fit when the response holds several.
    start : mapping, optional
        Start values for some of ``b0..bm``, ``a0..a{n-1}``, ``tau`` (default:
        a Sanathanan-Koerner fit of the complex response).
    weighting : {"cifer", "random_error"}
        The cost minimised and the error bars reported (see the module notes):
        CIFER's cost with its Cramér-Rao bounds, or inverse random-error
        weighting with calibrated standard errors.
    min_coherence : float
        Frequencies with a lower coherence γ² are left out (CIFER: 0.6).
    fixed : mapping, optional
        Parameters held at the given values (names as `start`); they are
        reported with zero standard error and zero covariance.
    fourier : bool
        Flight data only: fit the model to the record's finite Fourier
        transforms directly, minimising ``Σ_ω |Y(ω) − T(jω) U(ω)|²`` (output
        error in the frequency domain, as SIDPAC's ``tfest``/``fdoe``), with
        the error bars of complex circular residuals (each complex residual
        two real observations); `weighting` and `min_coherence` do not apply.
    frequencies : array_like, optional
        ``fourier=True``: the frequencies in rad/s (default: the ``k/T`` grid
        of the record over the band the input excited).

    When flight data are given without `frequency_range` (or `frequencies`),
    the band is the one the input excited: from the lowest to the highest
    frequency of the ``k/T`` grid where the input's power is at least 1 % of
    its peak. A record's Fourier fit never goes below ``4π/T`` rad/s (two
    periods in the record, the rule every window of `composite_response`
    obeys); explicit `frequencies` below it are kept with a warning.

    Returns
    -------
    TransferFunctionFit

    Raises
    ------
    IdentificationError
        Bad orders, weighting or start values (unknown names, values that are
        not finite numbers); too few coherent frequencies for the parameters;
        the fit diverges.
    ChannelError
        The requested pair is not in the response.
    """
    fourier = check_flag(fourier, "fourier", IdentificationError)
    if fourier and not isinstance(response_or_data, FlightData):
        raise IdentificationError(
            "fourier=True fits a record's Fourier transforms: give FlightData with input= "
            "and output="
        )
    if frequencies is not None and not fourier:
        raise IdentificationError("frequencies applies to fourier=True only")
    if (
        isinstance(response_or_data, FlightData)
        and frequency_range is None
        and frequencies is None
        and input is not None
    ):
        response_or_data.require([input], role="input")
        frequency_range = _excited_band(response_or_data, input)
    if fourier:
        assert isinstance(response_or_data, FlightData)
        return _fit_fourier(
            response_or_data,
            input,
            output,
            numerator_order,
            denominator_order,
            delay,
            frequency_range,
            frequencies,
            start,
            fixed,
        )
    ch = _resolve_response(response_or_data, input, output)
    m, n = _orders(numerator_order, denominator_order)
    if weighting not in _WEIGHTINGS:
        raise IdentificationError(
            f"weighting: expected one of {list(_WEIGHTINGS)}, got {weighting!r}"
        )
    try:
        min_coh = float(min_coherence)
    except (TypeError, ValueError):
        min_coh = float("nan")
    if not 0.0 <= min_coh <= 1.0:
        raise IdentificationError(
            f"min_coherence: expected a number in [0, 1], got {min_coherence!r}"
        )
    omega = ch.frequency
    keep = np.isfinite(ch.response) & (np.abs(ch.response) > 0)
    keep &= ch.coherence >= min_coh
    if frequency_range is not None:
        lo, hi = _band(frequency_range)
        keep &= (omega >= lo) & (omega <= hi)
    if weighting == "random_error":
        keep &= np.isfinite(ch.random_error)
    w = omega[keep]
    h = ch.response[keep]
    coh = ch.coherence[keep]
    err = ch.random_error[keep]
    st = _Structure(m, n, check_flag(delay, "delay", IdentificationError), w)
    held = _held(st, fixed)
    free = np.array([nm not in held for nm in st.names])
    p = int(free.sum())
    if p == 0:
        raise IdentificationError("fixed: every parameter is fixed; nothing left to fit")
    if 2 * w.size <= p:
        raise IdentificationError(
            f"{w.size} frequencies with γ² >= {min_coherence} in the band cannot fit {p} parameters "
            f"({ch.input_name} -> {ch.output_name})"
        )
    if weighting == "cifer":
        wg = np.sqrt(20.0 / w.size * _coherence_weight(coh))
        w_mag, w_ph = wg, wg * np.sqrt(_W_PHASE)
    else:
        # εr |Ĥ| is the absolute standard error of Ĥ from the residual spectrum, which
        # (unlike εr alone, through γ̂²) does not grow with the point's own error; the
        # relative error is that over the model's |T|, updated between passes
        sigma = np.maximum(err, _MIN_RANDOM_ERROR) * np.abs(h)
        w_mag, w_ph = 1.0 / (_DB * sigma / np.abs(h)), 1.0 / (_DEG * sigma / np.abs(h))
    logh = np.log(h)

    def residual(theta: FloatArray) -> FloatArray:
        logt, _ = st.log_response(theta)
        d = logh - logt
        d_ph = np.angle(np.exp(1j * d.imag))  # wrapped: the branch of the data's phase is free
        return np.concatenate([w_mag * _DB * d.real, w_ph * _DEG * d_ph])

    def jacobian(theta: FloatArray) -> FloatArray:
        _, g = st.log_response(theta)
        return np.concatenate([-(w_mag * _DB)[:, None] * g.real, -(w_ph * _DEG)[:, None] * g.imag])

    import scipy.optimize  # only a fit needs it; composite responses do not

    theta = _start(st, h, w, _coherence_weight(coh), residual, start)
    for k, v in held.items():
        theta[st.names.index(k)] = v

    def full(x: FloatArray) -> FloatArray:
        out = theta.copy()
        out[free] = x
        return out

    for _ in range(_PASSES if weighting == "random_error" else 1):
        with np.errstate(all="ignore"):
            sol = scipy.optimize.least_squares(
                lambda x: residual(full(x)),
                theta[free],
                jac=lambda x: jacobian(full(x))[:, free],
                method="lm",
                x_scale="jac",
                xtol=1e-12,
                ftol=1e-12,
            )
        theta = full(sol.x)
        if weighting == "random_error":
            model = np.abs(np.exp(st.log_response(theta)[0]))
            if not np.all(np.isfinite(model) & (model > 0)):
                break
            w_mag, w_ph = model / (_DB * sigma), model / (_DEG * sigma)
    r = residual(theta)
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(r))):
        raise IdentificationError(
            f"transfer-function fit {ch.input_name} -> {ch.output_name} diverged; give start values"
        )
    jac = jacobian(theta)[:, free]
    info_free = jac.T @ jac
    try:
        inv_free = np.linalg.inv(info_free)
    except np.linalg.LinAlgError:
        inv_free = np.full((p, p), np.inf)
    # fixed parameters: zero rows and columns (no uncertainty), an infinite insensitivity
    inv = np.zeros((free.size, free.size))
    inv[np.ix_(free, free)] = inv_free
    info = np.full((free.size, free.size), 0.0)
    info[np.ix_(free, free)] = info_free
    if weighting == "random_error":
        dof = r.size - p
        chi2 = float(r @ r) / dof
        cov = chi2 * inv
    else:
        chi2 = float("nan")
        cov = inv
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        insens = 1.0 / np.sqrt(np.diag(info))
    # the reported cost is CIFER's whatever was minimised
    logt, _ = st.log_response(theta)
    d = logh - logt
    cost = float(
        20.0
        / w.size
        * np.sum(
            _coherence_weight(coh)
            * ((_DB * d.real) ** 2 + _W_PHASE * (_DEG * np.angle(np.exp(1j * d.imag))) ** 2)
        )
    )
    b, a, tau = st.split(theta)
    names = st.names
    return TransferFunctionFit(
        dict(zip(names, theta.tolist(), strict=True)),
        dict(zip(names, se.tolist(), strict=True)),
        dict(zip(names, insens.tolist(), strict=True)),
        np.asarray(cov, dtype=np.float64),
        b[::-1].copy(),
        np.concatenate([[1.0], a[::-1]]),
        tau,
        cost,
        weighting,
        chi2,
        w,
        h,
        coh,
        err,
        ch.input_name,
        ch.output_name,
    )


def _start(
    st: _Structure,
    h: ComplexArray,
    w: FloatArray,
    weight: FloatArray,
    residual: Any,
    start: Mapping[str, float] | None,
) -> FloatArray:
    """Sanathanan-Koerner start, with τ from the phase the rational part leaves unexplained."""

    def cost(theta: FloatArray) -> float:
        r = residual(theta)
        return float(r @ r) if np.all(np.isfinite(r)) else np.inf

    best = _levy_sk(st, h, weight)
    if st.delay:
        best = np.append(best, 0.0)
        ratio = h / np.exp(st.log_response(best)[0])
        ph = np.unwrap(np.angle(ratio))
        # the phase left over is about −τω: its least-squares slope through the origin
        tau = max(0.0, -float(np.sum(w * ph) / np.sum(w * w)))
        candidates = [best]
        # and a grid up to half a turn of phase at the top frequency: a numerator of
        # higher order than the denominator lets the rational part mimic a lead and
        # leaves the phase slope above useless
        grid = np.linspace(0.0, np.pi / float(w.max()), 25)[1:]
        for t in (tau, 2.0 * tau, *grid):
            if t > 0:
                cand = np.append(_levy_sk(st, h * np.exp(1j * w * t), weight), t)
                candidates.append(cand)
        best = min(candidates, key=cost)
    if start is not None:
        if not isinstance(start, Mapping):
            raise IdentificationError(
                f"start: expected a mapping of parameter name to value, got {start!r}"
            )
        unknown = sorted(set(start) - set(st.names))
        if unknown:
            raise IdentificationError(
                f"start: unknown parameters {unknown}; parameters: {st.names}"
            )
        best = best.copy()
        for k, v in start.items():
            best[st.names.index(k)] = _start_value(k, v)
    return np.asarray(best, dtype=np.float64)


def _orders(numerator_order: Any, denominator_order: Any) -> tuple[int, int]:
    try:
        m, n = int(numerator_order), int(denominator_order)
        ok = m == numerator_order and n == denominator_order and m >= 0 and n >= 1
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise IdentificationError(
            "numerator_order, denominator_order: expected integers m >= 0, n >= 1, got "
            f"{numerator_order!r}, {denominator_order!r}"
        )
    return m, n


def _record_grid(data: FlightData) -> tuple[float, float]:
    """Sample interval and record length of a uniformly sampled record."""
    if data.n_samples < 4 or not data.is_uniform:
        raise IdentificationError(
            "data: a transfer-function fit from flight data needs a uniformly sampled record "
            "of at least 4 samples"
        )
    dt = float(np.mean(np.diff(data.time)))
    return dt, dt * (data.n_samples - 1)


def _excited_band(data: FlightData, input: str) -> tuple[float, float]:
    """The band (rad/s) over which the input's power is at least 1 % of its peak."""
    from .frequency_domain import _transform

    dt, T = _record_grid(data)
    k = np.arange(1, data.n_samples // 2)
    omega = np.asarray(2 * np.pi * k / T, dtype=np.float64)
    u = np.asarray(data[input], dtype=np.float64)
    power = np.abs(_transform((u - u.mean())[:, None], dt, omega, cubic=False)[:, 0]) ** 2
    if not np.any(power > 0):
        raise IdentificationError(f"input {input!r} is constant: it excites no frequency")
    hit = np.flatnonzero(power >= _EXCITED * power.max())
    return float(omega[hit[0]]), float(omega[hit[-1]])


def _fit_fourier(
    data: FlightData,
    input: str | None,
    output: str | None,
    numerator_order: Any,
    denominator_order: Any,
    delay: Any,
    frequency_range: tuple[float, float] | None,
    frequencies: ArrayLike | None,
    start: Mapping[str, float] | None,
    fixed: Mapping[str, float] | None,
) -> TransferFunctionFit:
    """Output error on the record's Fourier transforms: min Σ |Y − T U|², real parameters."""
    import scipy.optimize

    from .frequency_domain import _frequency_grid, _transform

    if input is None or output is None:
        raise ChannelError("response_or_data: flight data need input= and output= channel names")
    data.require([input], role="input")
    data.require([output], role="output")
    m, n = _orders(numerator_order, denominator_order)
    dt, T = _record_grid(data)
    if frequencies is None:
        lo, hi = frequency_range if frequency_range is not None else _excited_band(data, input)
        # two periods in the record, the rule every window obeys (the whole record is
        # the window here): below it the detrend and the record's ends decide Y/U
        k = np.arange(
            max(_MIN_PERIODS, int(np.ceil(lo * T / (2 * np.pi) - 1e-9))),
            1 + int(hi * T / (2 * np.pi) + 1e-9),
        )
        w = np.asarray(2 * np.pi * k / T, dtype=np.float64)
        w = w[w < np.pi / dt]
    else:
        w = _frequency_grid(frequencies, dt, T, depth=2)
        if frequency_range is not None:
            lo, hi = _band(frequency_range)
            w = w[(w >= lo) & (w <= hi)]
        short = w < _MIN_PERIODS * 2.0 * np.pi / T * (1 - 1e-9)
        if np.any(short):
            warnings.warn(
                f"frequencies: {int(short.sum())} below {_MIN_PERIODS * 2 * np.pi / T:.4g} "
                "rad/s, two periods of the record; their transforms are decided by the "
                "detrend and the record's ends",
                UserWarning,
                stacklevel=CALLER_STACKLEVEL + 1,
            )
    u = np.asarray(data[input], dtype=np.float64)
    y = np.asarray(data[output], dtype=np.float64)
    # linear trends (trim, drift) removed as SIDPAC's detrend; on the k/T grid a constant
    # has no transform anyway
    U = _transform(_detrended(data.time, u)[:, None], dt, w, cubic=False)[:, 0]
    Y = _transform(_detrended(data.time, y)[:, None], dt, w, cubic=True)[:, 0]
    st = _Structure(m, n, check_flag(delay, "delay", IdentificationError), w)
    held = _held(st, fixed)
    free = np.array([nm not in held for nm in st.names])
    p = int(free.sum())
    if p == 0:
        raise IdentificationError("fixed: every parameter is fixed; nothing left to fit")
    if 2 * w.size <= p:
        raise IdentificationError(
            f"{w.size} frequencies in the band cannot fit {p} parameters ({input} -> {output})"
        )
    ok = np.abs(U) > 0
    h = np.where(ok, Y / np.where(ok, U, 1.0), 0.0)

    def model(theta: FloatArray) -> tuple[ComplexArray, ComplexArray]:
        logt, g = st.log_response(theta)
        t = np.exp(logt)
        return t * U, (t * U)[:, None] * g

    def residual(theta: FloatArray) -> FloatArray:
        v = Y - model(theta)[0]
        return np.concatenate([v.real, v.imag])

    def jacobian(theta: FloatArray) -> FloatArray:
        d = -model(theta)[1]
        return np.concatenate([d.real, d.imag])

    # the start: the rational fit of Y/U weighted by |U| (its equation-error form)
    theta = _start(st, h, w, np.abs(U) ** 2, residual, start)
    for k_, v_ in held.items():
        theta[st.names.index(k_)] = v_

    def full(x: FloatArray) -> FloatArray:
        out = theta.copy()
        out[free] = x
        return out

    with np.errstate(all="ignore"):
        sol = scipy.optimize.least_squares(
            lambda x: residual(full(x)),
            theta[free],
            jac=lambda x: jacobian(full(x))[:, free],
            method="lm",
            x_scale="jac",
            xtol=1e-12,
            ftol=1e-12,
        )
    theta = full(sol.x)
    r = residual(theta)
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(r))):
        raise IdentificationError(
            f"transfer-function fit {input} -> {output} diverged; give start values"
        )
    jac = jacobian(theta)[:, free]
    info_free = jac.T @ jac
    # complex circular residuals: each real and imaginary part is one observation of
    # variance σ²/2, estimated from the 2M real residuals less the unknowns
    s2 = float(r @ r) / (r.size - p)
    inv = np.zeros((free.size, free.size))
    info = np.zeros((free.size, free.size))
    info[np.ix_(free, free)] = info_free
    try:
        inv[np.ix_(free, free)] = np.linalg.inv(info_free)
    except np.linalg.LinAlgError:
        inv[np.ix_(free, free)] = np.inf
    cov = s2 * inv
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        insens = np.sqrt(s2) / np.sqrt(np.diag(info))
    b, a, tau = st.split(theta)
    names = st.names
    return TransferFunctionFit(
        dict(zip(names, theta.tolist(), strict=True)),
        dict(zip(names, se.tolist(), strict=True)),
        dict(zip(names, insens.tolist(), strict=True)),
        np.asarray(cov, dtype=np.float64),
        b[::-1].copy(),
        np.concatenate([[1.0], a[::-1]]),
        tau,
        0.5 * float(r @ r) / s2,
        "fourier",
        1.0,
        w,
        h,
        np.ones(w.size),
        np.full(w.size, np.nan),
        input,
        output,
    )


def _detrended(t: Any, x: FloatArray) -> FloatArray:
    tt = np.asarray(t, dtype=np.float64)
    coef = np.polyfit(tt - tt[0], x, 1)
    return np.asarray(x - np.polyval(coef, tt - tt[0]), dtype=np.float64)


def _held(st: _Structure, fixed: Any) -> dict[str, float]:
    """The `fixed` option checked: known names -> finite values."""
    if fixed is None:
        return {}
    if not isinstance(fixed, Mapping):
        raise IdentificationError(
            f"fixed: expected a mapping of parameter name to value, got {plain(fixed)}"
        )
    unknown = sorted(set(fixed) - set(st.names))
    if unknown:
        raise IdentificationError(f"fixed: unknown parameters {unknown}; parameters: {st.names}")
    return {str(k): _start_value(str(k), v) for k, v in fixed.items()}


def _start_value(name: str, value: Any) -> float:
    """A start value as a finite float, else an error naming the parameter."""
    out = as_float(value)
    if out is None or not np.isfinite(out):
        raise IdentificationError(f"start[{name!r}]: expected a finite number, got {plain(value)}")
    return out
