"""The records of frequency-response identification: `ResponseChannel` (one
input-output pair), `CompositeResponse` (every pair of a composite) and
`TransferFunctionFit`, with their Bode plot and the checks of a frequency axis.

Their public home is `aeroid.frequency.frequency_id`, which re-exports them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float
from .._records import (
    FrozenState,
    IntervalMixin,
    fmt,
    frozen_array,
    frozen_mapping,
    markdown_table,
)
from .._records import frozen_complex as _frozen_complex
from .._value_checks import finite_array
from ..errors import ChannelError, DataFormatError, IdentificationError
from ..io.data import numeric, plain
from ._transfer import transfer_at

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# Tischler's guidelines for a reliable parameter.
_CR_LIMIT = 20.0
_INSENSITIVITY_LIMIT = 10.0


# -- records -----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ResponseChannel(FrozenState):
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
                vals = numeric(given, f"{what}: {name}", "not numeric")
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
        """The model's phase in degrees, unwrapped along frequency and on the measured
        phase's branch where the measurement is coherent.

        One branch for the whole curve: taken frequency by frequency, a noisy
        measured phase at low coherence would make the model's curve jump by 360°.
        """
        pointwise = self.phase - self.phase_error
        model = self.model_response
        finite = np.isfinite(model)
        if not finite.all():
            return frozen_array(pointwise)
        raw = _unwrapped_phase(model)
        usable = np.isfinite(pointwise)
        chosen = usable & np.asarray(self.coherent, dtype=bool)
        chosen = chosen if chosen.any() else usable
        if not chosen.any():
            return frozen_array(raw)
        turns = np.round(np.median((pointwise - raw)[chosen]) / 360.0)
        return frozen_array(raw + 360.0 * turns)

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

    def summary(self) -> str:
        """Markdown: the frequencies, those that count (`coherent`) with their mean
        coherence and random error, those of γ² ≥ 0.6, and the mismatch to the model."""
        w, ok = self.frequency, self.coherent
        with np.errstate(invalid="ignore"):
            cifer = self.coherence >= 0.6  # NaN (unknown) is not

        def span(mask: NDArray[np.bool_]) -> str:
            if not mask.any():
                return "0"
            return (
                f"{int(mask.sum())}: {fmt(float(w[mask].min()), 3)}–{fmt(float(w[mask].max()), 3)}"
            )

        def over_counted(values: FloatArray, scale: float = 1.0) -> str:
            known = values[ok & np.isfinite(values)]  # NaN where not known
            return fmt(scale * float(np.mean(known)), 3) if known.size else "—"

        mismatch = f"{100 * self.mismatch:.3g}%" if np.isfinite(self.mismatch) else "—"
        rows = [
            ("frequencies [rad/s]", span(np.ones(w.shape, dtype=bool))),
            ("counted (`coherent`) [rad/s]", span(ok)),
            ("mean γ² (counted)", over_counted(self.coherence)),
            ("mean εr [%] (counted)", over_counted(self.random_error, 100.0)),
            ("γ² ≥ 0.6 [rad/s]", span(cifer) if np.isfinite(self.coherence).any() else "—"),
            ("mismatch to the model (counted)", mismatch),
        ]
        why = "; ".join(f"{int(v)} {k}" for k, v in self.dropped.items())
        return "\n".join(
            [
                f"## Frequency response {self.input_name} → {self.output_name}",
                "",
                markdown_table(("metric", "value"), rows),
                *(["", f"Not counted: {why}."] if why else []),
            ]
        )


def _frequency_axis(values: Any, what: str) -> FloatArray:
    """`values` as a read-only 1-D array of finite, positive, strictly increasing rad/s."""
    omega = numeric(values, what, "not numeric")
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
class CompositeResponse(FrozenState):
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
        return _pick_channel(self, input, output, "composite response")

    def summary(self) -> str:
        """Markdown section: per pair, the band where γ² ≥ 0.6, its mean coherence and its
        mean random error."""
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
                    fmt(float(np.mean(c.coherence[ok])), 3) if ok.any() else "—",
                    err,
                )
            )
        table = markdown_table(
            (
                "input",
                "output",
                "γ² ≥ 0.6",
                "band [rad/s]",
                "mean γ² (γ² ≥ 0.6)",
                "mean εr [%] (γ² ≥ 0.6)",
            ),
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


def _pick_channel(record: Any, input: str, output: str, what: str) -> Any:
    """The channel of a response record (`what` names the record kind in the error)."""
    for ch in record.channels:
        if ch.input_name == input and ch.output_name == output:
            return ch
    raise ChannelError(
        f"no {what} for input {input!r} -> output {output!r}; "
        f"inputs {list(record.input_names)}, outputs {list(record.output_names)}"
    )


def _bode(channels: Sequence[ResponseChannel], fits: Sequence[Any]) -> Any:
    from ..reports.plotting import LOG_LABELS, figure

    fig, axes = figure(
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
        coh.xaxis.set_major_formatter(LOG_LABELS)
        coh.xaxis.set_minor_formatter(LOG_LABELS)
        if fits or np.isfinite(ch.model_response).any():
            mag.legend(fontsize=7)
    return fig


def angular_frequencies(values: Any, name: str) -> FloatArray:
    """`values` as finite, non-negative frequencies in rad/s, or an `IdentificationError`
    naming `name`."""
    w = finite_array(values, f"{name} (rad/s)", IdentificationError)
    if np.any(w < 0.0):
        raise IdentificationError(f"{name}: expected non-negative frequencies in rad/s")
    return w


def _band(frequency_range: Any) -> tuple[float, float]:
    try:
        lo, hi = (as_float(v) for v in frequency_range)
    except (TypeError, ValueError):
        lo = hi = None
    if lo is None or hi is None:  # text and bools are no frequencies
        raise IdentificationError(
            f"frequency_range: expected (low, high) in rad/s, got {frequency_range!r}"
        )
    if not 0.0 <= lo < hi < math.inf:
        raise IdentificationError(
            f"frequency_range: expected 0 <= low < high, both finite, got {frequency_range!r}"
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
    degrees_of_freedom : mapping of str to float
        Per parameter, the degrees of freedom `interval` takes Student's t
        with: those of the frequency sandwich for a record's Fourier fit
        (``error_bars="colored"``), else the residual's, two real components
        per fitted frequency less the parameters.
    ends_estimated : bool
        A record's Fourier fit: whether the terms of the record's ends were
        estimated with the transfer function (``boundary``).
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
    degrees_of_freedom: Mapping[str, float] = field(default_factory=dict)
    ends_estimated: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", frozen_mapping(self.parameters))
        object.__setattr__(self, "standard_errors", frozen_mapping(self.standard_errors))
        if not self.degrees_of_freedom:
            # the residual's: two real components per fitted frequency less the parameters
            nu = float(max(2 * np.size(self.frequency) - len(self.parameters), 1))
            object.__setattr__(self, "degrees_of_freedom", {n: nu for n in self.parameters})
        object.__setattr__(self, "degrees_of_freedom", frozen_mapping(self.degrees_of_freedom))
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

    def transfer_function(self, s: ArrayLike) -> ComplexArray:
        """T(s) at complex `s`."""
        return transfer_at(self.numerator, self.denominator, s, delay=self.delay)

    def evaluate(self, frequency: ArrayLike) -> ComplexArray:
        """T(jω) at frequencies ω in rad/s."""
        return self.transfer_function(1j * angular_frequencies(frequency, "frequency"))

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
                + (
                    # raw Y/U ratios of one record: no CIFER cost to judge them by
                    "output error on the record's Fourier transforms."
                    if self.weighting == "fourier"
                    else f"CIFER cost J = {fmt(self.cost, 4)} (Tischler: J ≤ 100 acceptable, "
                    "≤ 50 good)."
                )
                + (
                    f" Reduced χ² {fmt(self.reduced_chi_square, 3)}."
                    if np.isfinite(self.reduced_chi_square) and self.weighting != "fourier"
                    else ""
                )
                + (" The record's ends estimated with it." if self.ends_estimated else ""),
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
