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
  resolution cells of the shortest window apart) and every window resolves
  the response: they carry the random error, not a short window's
  resolution bias near a lightly damped mode (Bendat & Piersol: about
  ``(B_e / B_r)² / 3`` at the peak, ``B_e = 1.5 / T`` Hz for a Hann window,
  ``B_r = 2 ζ f_n``).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float
from .._threads import small_blas
from ..errors import ChannelError, DataFormatError, IdentificationError
from ..io.data import FlightData, check_flag, plain
from ._cross_spectra import _DEPENDENT as _DEPENDENT
from ._cross_spectra import _MIN_RANDOM_ERROR
from ._cross_spectra import _RANDOM_ERROR_FLOOR as _RANDOM_ERROR_FLOOR
from ._cross_spectra import _combine as _combine
from ._cross_spectra import _condition as _condition
from ._cross_spectra import _effective_averages as _effective_averages
from ._cross_spectra import _independent_averages as _independent_averages
from ._cross_spectra import _random_error as _random_error
from ._cross_spectra import _refuse_dependent_inputs as _refuse_dependent_inputs
from ._cross_spectra import _window_spectra as _window_spectra
from ._levy_fit import fit_levy
from ._rational_fit import _EXCITED as _EXCITED
from ._rational_fit import _MIN_PERIODS as _MIN_PERIODS
from ._rational_fit import (
    FourierRequest,
    _fit_record,
    _fitted_information,
    _free_structure,
    fit_free,
    refuse_constant,
    undetermined_bars,
)
from ._rational_fit import _coherence_weight as _coherence_weight
from ._rational_fit import _detrended as _detrended
from ._rational_fit import _excited_band as _excited_band
from ._rational_fit import _fit_fourier as _fit_fourier
from ._rational_fit import _held as _held
from ._rational_fit import _levy_sk as _levy_sk
from ._rational_fit import _orders as _orders
from ._rational_fit import _record_grid as _record_grid
from ._rational_fit import _start as _start
from ._rational_fit import _start_value as _start_value
from ._rational_fit import _Structure as _Structure
from ._response_records import _CR_LIMIT as _CR_LIMIT
from ._response_records import _INSENSITIVITY_LIMIT as _INSENSITIVITY_LIMIT
from ._response_records import (
    CompositeResponse,
    ResponseChannel,
    TransferFunctionFit,
    _band,
)
from ._response_records import _bode as _bode
from ._response_records import _frequency_axis as _frequency_axis
from ._response_records import _percent as _percent
from ._response_records import _unwrapped_phase as _unwrapped_phase

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
_ERROR_BARS = ("colored", "white")
_BOUNDARIES = ("auto", "estimate", "ignore")
_METHODS = ("output_error", "equation_error")
# Reweighting passes of the random-error fit (weights from the previous pass's model).
_PASSES = 3


# -- composite response -----------------------------------------------------------------


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
    ov = as_float(overlap)
    if ov is None or not 0.0 <= ov <= 0.95:
        raise IdentificationError(f"overlap: expected a number in [0, 0.95], got {overlap!r}")
    fs = data.sample_rate
    dt = 1.0 / fs
    n = data.n_samples
    if windows is None:
        wins = [data.duration / d for d in (2.0, 4.0, 8.0)]
    else:
        listed = np.atleast_1d(np.asarray(windows, dtype=object))
        lengths = [as_float(w) for w in listed.ravel()]
        if listed.ndim != 1 or not lengths or None in lengths:  # text and bools too
            raise IdentificationError(
                f"windows: expected one or more lengths in seconds, got {windows!r}"
            )
        wins = [float(w) for w in lengths if w is not None]
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
    refuse_constant(data, ins, outs)
    n_u, n_y = len(ins), len(outs)
    signals = np.column_stack([data.array(ins), data.array(outs)])
    spectra, n_avg, weights, n_stationary = [], [], [], []
    for seg in segs:
        step = max(1, round(seg * (1.0 - ov)))
        g, x, nd_stationary = _window_spectra(
            signals, dt, seg, step, omega, first_transforms=n_u == 1
        )
        nd = (
            np.full(omega.size, nd_stationary)
            if x is None
            else _effective_averages(x, omega, seg, step, dt)
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


# -- transfer-function fit -----------------------------------------------------------------


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
    delay: bool | None = None,
    frequency_range: tuple[float, float] | None = None,
    input: str | None = None,
    output: str | None = None,
    start: Mapping[str, float] | None = None,
    weighting: str = "cifer",
    min_coherence: float = 0.6,
    fixed: Mapping[str, float] | None = None,
    fourier: bool = False,
    frequencies: ArrayLike | None = None,
    error_bars: str = "colored",
    boundary: str = "auto",
    method: str = "output_error",
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
    delay : bool, optional
        Fit the equivalent time delay τ (default: yes, except by equation
        error, which cannot).
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
        error in the frequency domain, as SIDPAC's ``fdoe``), or by equation
        error (`method`), with the error bars of `error_bars`; `weighting`
        and `min_coherence` do not apply.
    frequencies : array_like, optional
        ``fourier=True``: the frequencies in rad/s (default: the ``k/T`` grid
        of the record over the band the input excited).
    error_bars : {"colored", "white"}
        ``fourier=True``: the frequency sandwich of every frequency-domain
        estimator (default; each frequency's residual is its own noise
        spectrum, so coloured noise, turbulence or unmodelled dynamics that
        vary with frequency are counted where they are, and frequencies
        closer than ``2π/T`` share theirs), or the classical bars of white
        complex circular residuals (each complex residual two real
        observations of half its variance). A fit to a frequency response
        takes its bars from `weighting`.
    boundary : {"auto", "estimate", "ignore"}
        ``fourier=True``: the record's ends. A record that does not start and
        end at rest adds to ``D(jω) Y = N(jω) U`` what its states at both
        ends leave in the transforms of their derivatives (polynomials in
        ``jω``) and what the removed trend lines leave; unmodelled, they bias
        the fit and inflate its residuals at low frequencies.
        ``"estimate"`` fits them (linear terms over ``D(jω)``, not reported),
        ``"auto"`` (default) keeps them when they differ from zero jointly
        (Wald test at 5 %, as `identify_frequency_domain` does) and
        ``"ignore"`` leaves them out, as SIDPAC's ``tfest`` and ``fdoe`` do.
        `TransferFunctionFit.ends_estimated` says which.
    method : {"output_error", "equation_error"}
        ``fourier=True``: output error (default), or Levy's equation error,
        ``(jω)^n Y = Σ b_k (jω)^k U − Σ a_k (jω)^k Y`` solved by least squares
        as `equation_error` solves in the frequency domain (Klein & Morelli
        sec. 7.3; SIDPAC's ``tfest``, the same regression: its ``fint``
        interpolates the input cubically and keeps the trends, so its
        transforms differ a little). Linear, so no start and no iteration,
        but the output's noise in the regressors biases it where output
        error is not biased; it fits no delay (``delay`` left unset or False).

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
    if error_bars not in _ERROR_BARS:
        raise IdentificationError(
            f"error_bars: expected one of {list(_ERROR_BARS)}, got {plain(error_bars)}"
        )
    if error_bars != "colored" and not fourier:
        raise IdentificationError(
            "error_bars applies to fourier=True only; a response fit's bars follow weighting"
        )
    if boundary not in _BOUNDARIES:
        raise IdentificationError(
            f"boundary: expected one of {list(_BOUNDARIES)}, got {plain(boundary)}"
        )
    if boundary != "auto" and not fourier:
        raise IdentificationError("boundary applies to fourier=True only")
    if (
        isinstance(response_or_data, FlightData)
        and frequency_range is None
        and frequencies is None
        and input is not None
    ):
        response_or_data.require([input], role="input")
        frequency_range = _excited_band(response_or_data, input)
    if method not in _METHODS:
        raise IdentificationError(f"method: expected one of {list(_METHODS)}, got {plain(method)}")
    if delay is None:
        delay = method != "equation_error"
    if method != "output_error" and not fourier:
        raise IdentificationError("method applies to fourier=True only")
    if fourier:
        assert isinstance(response_or_data, FlightData)
        if frequency_range is not None:
            frequency_range = _band(frequency_range)  # named, as the spectral path does
        fit = fit_levy if method == "equation_error" else _fit_fourier
        return fit(
            FourierRequest(
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
                error_bars,
                boundary,
            )
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
    keep &= ~(ch.coherence < min_coh)  # an unknown (NaN) coherence is not a low one
    if frequency_range is not None:
        lo, hi = _band(frequency_range)
        keep &= (omega >= lo) & (omega <= hi)
    if weighting == "random_error":
        keep &= np.isfinite(ch.random_error)
    w = omega[keep]
    h = ch.response[keep]
    # an unknown coherence (a response given without one) weighs as a perfect one
    coh = np.where(np.isnan(ch.coherence[keep]), 1.0, ch.coherence[keep])
    err = ch.random_error[keep]
    st, held, free = _free_structure(
        m,
        n,
        delay,
        w,
        fixed,
        f"with γ² >= {min_coherence} in the band",
        f"{ch.input_name} -> {ch.output_name}",
    )
    p = int(free.sum())
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

    theta = _start(st, h, w, _coherence_weight(coh), residual, start)
    for k, v in held.items():
        theta[st.names.index(k)] = v

    for _ in range(_PASSES if weighting == "random_error" else 1):
        theta = fit_free(residual, jacobian, theta, free)
        if weighting == "random_error":
            model = np.abs(np.exp(st.log_response(theta)[0]))
            if not np.all(np.isfinite(model) & (model > 0)):
                break
            w_mag, w_ph = model / (_DB * sigma), model / (_DEG * sigma)
    # fixed parameters: zero rows and columns (no uncertainty), an infinite insensitivity
    r, inv, info = _fitted_information(
        residual, jacobian, theta, free, f"{ch.input_name} -> {ch.output_name}"
    )
    if weighting == "random_error":
        dof = r.size - p
        chi2 = float(r @ r) / dof
        cov = chi2 * inv
    else:
        chi2 = float("nan")
        cov = inv
    with np.errstate(invalid="ignore", divide="ignore"):
        pair = f"{ch.input_name} -> {ch.output_name}"
        se = undetermined_bars(cov, free, st.names, pair, 1)
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
    return _fit_record(
        st,
        theta,
        se,
        insens,
        cov,
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
