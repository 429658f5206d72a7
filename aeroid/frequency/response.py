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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt, markdown_table
from .._threads import small_blas
from .._units import require_model_units
from .._value_checks import check_distinct
from ..errors import ChannelError, DataFormatError, IdentificationError, SimulationError
from ..io.data import FlightData, as_float, whole_number
from ..models.model import (
    Model,
    SimulatorModel,
    delayed_controls,
    fitted_start,
    require_model,
    resolve_parameters,
)
from ._model_response import _affine_measurement as _affine_measurement
from ._model_response import (
    _exact_response,
    _linearised_response,
    _reference_state,
    _simulated_outputs,
)
from ._model_response import _state_outputs as _state_outputs
from ._model_response import _transfer as _transfer
from ._response_estimates import _EXCITATION_FLOOR as _EXCITATION_FLOOR
from ._response_estimates import (
    _EXCITED_FRACTION,
    _REASONS,
    _RECORD_SMOOTHING,
    _choose_windows,
    _default_windows,
    _record_estimate,
    _record_ratio,
    _window_estimate,
)
from ._response_estimates import _FALSE_COHERENCE_LEVEL as _FALSE_COHERENCE_LEVEL
from ._response_estimates import _MIN_WINDOW as _MIN_WINDOW
from ._response_estimates import _RESOLVED_BIAS as _RESOLVED_BIAS
from ._response_estimates import _WINDOW_DIVISORS as _WINDOW_DIVISORS
from ._response_estimates import _chance_coherence as _chance_coherence
from ._response_estimates import _Estimate as _Estimate
from ._response_estimates import _estimate as _estimate
from ._response_estimates import _independent_averages as _independent_averages
from ._response_estimates import _spectral_matrix as _spectral_matrix
from ._response_estimates import _zero_ends as _zero_ends
from ._response_records import _pick_channel
from .frequency_id import ResponseChannel

__all__ = ["ChannelFrequencyResponse", "FrequencyResponseResult", "frequency_response"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_MODEL_RESPONSES = ("simulated", "exact", "auto")
# Welch spectra need two segments of at least 8 samples
_MIN_SAMPLES = 16


# One response record for every frequency tool: rad/s, complex response, dB and
# degrees as properties (`frequency_id.ResponseChannel`); the spec's name stays.
ChannelFrequencyResponse = ResponseChannel


@dataclass(frozen=True, eq=False)
class FrequencyResponseResult(FrozenState):
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
        ch: ChannelFrequencyResponse = _pick_channel(self, input, output, "frequency response")
        return ch

    @property
    def mismatch(self) -> float:
        """Largest channel mismatch (NaN if no channel has a coherent frequency)."""
        vals = [c.mismatch for c in self.channels if np.isfinite(c.mismatch)]
        return float(max(vals)) if vals else float("nan")

    def plot(self, **kwargs: Any) -> Any:
        """Empirical vs model Bode plot with coherence. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_frequency_response

        return plot_frequency_response(self, **kwargs)

    def summary(self) -> str:
        """Markdown section: per-channel coherent band, the mean coherence over its coherent
        frequencies, and the coherence-weighted mismatch."""
        rows = []
        for c in self.channels:
            band = (
                f"{fmt(float(c.frequency_hz[c.coherent].min()), 3)}–"
                f"{fmt(float(c.frequency_hz[c.coherent].max()), 3)} Hz"
                if c.n_coherent
                else "—"
            )
            # over the frequencies judged, as the band beside it: the whole grid runs far
            # past the excitation and would read a good sweep as a poor one
            coherent = c.coherence[c.coherent]
            mean_coh = float(np.mean(coherent)) if coherent.size else float("nan")
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
                "mean γ² (coherent freqs)",
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
    require_model_units(
        model, [data], [*model.controls, *getattr(model, "output_names", ())], IdentificationError
    )
    if data.n_samples < _MIN_SAMPLES:
        raise DataFormatError(
            f"data: {data.n_samples} samples are too few for a frequency response (Welch "
            f"spectra need at least {_MIN_SAMPLES}: two segments of 8)"
        )
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
        check_distinct(outs, "outputs", ChannelError)
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
    # a band's edge on a bin keeps it however the time stamps' rounding moved the rate
    edge = 1e-9 * fs / grid
    keep = (f >= band[0] - edge) & (f <= band[1] + edge)
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
