"""Handling-qualities metrics from frequency responses: LOES, bandwidth, phase delay, margins.

Low-order equivalent systems (MIL-STD-1797A; Hodgkinson, "Aircraft Handling
Qualities") fit the standard forms with `fit_transfer_function` and its CIFER
(Hodgkinson) mismatch cost ``J = (20/n) Σ W_γ [ΔdB² + 0.01745 Δφ²]`` over the
0.1–10 rad/s band:

* ``"short_period"``: ``q/δ = K (s + 1/T_θ2) e^{−τs} / (s² + 2ζω s + ω²)``;
* ``"roll"``: ``p/δ = K e^{−τs} / (s + 1/T_R)``;
* ``"dutch_roll"``: ``β/δ = K e^{−τs} / (s² + 2ζ_d ω_d s + ω_d²)`` (the roll and
  spiral modes left out).

Bandwidth and phase delay follow ADS-33E / MIL-STD-1797A for an attitude
response: ``ω_BW,phase`` where the phase is −135° (45° phase margin),
``ω_BW,gain`` where the gain is 6 dB above its value at ``ω_180`` (the frequency
of −180° phase), the bandwidth the smaller of the two (the phase bandwidth
when the phase never reaches −180°), and the phase delay
``τ_p = −(φ(2ω_180) + 180°) / (57.3 · 2ω_180)``. A rate response (``kind="rate"``)
is integrated first (divided by jω).

Levels come from the published boundaries in `aeroid.frequency._criteria`, each cited
there: a short-period equivalent system against MIL-STD-1797A's limits on ζ,
ω, ω T_θ2 and τ as SIDPAC's ``milstd`` states them (`short_period_level`, the
same Level as ``milstd`` for the same inputs, and the criteria beyond even the
Level 3 limits named); bandwidth and phase delay against the Category A
boundaries digitised in ``BandwidthCrit.m`` (`bandwidth_level`), drawn on
`BandwidthResult.plot`; the LOES mismatch against the maximum unnoticeable
added dynamics envelopes of ``LoesBound.m``
(`EquivalentSystemFit.mismatch_envelopes`). The authors of the last two
routines mark their values unchecked, and every caption and summary says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import FrozenState, IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table
from .._threads import small_blas
from ..errors import ChannelError, IdentificationError
from ..io.data import FlightData, check_flag, plain
from ._criteria import (
    BANDWIDTH_LEVEL_1,
    BANDWIDTH_LEVEL_2,
    BANDWIDTH_SOURCE,
    DELAY_ROUNDING,
    HandlingQualitiesLevel,
    _unstable_short_period_level,
    bandwidth_level,
    muad_envelopes,
    short_period_level,
)
from ._loes_fit import _CLOSE as _CLOSE
from ._loes_fit import _DELAY_GRID as _DELAY_GRID
from ._loes_fit import _STARTS as _STARTS
from ._loes_fit import (
    _cifer_cost,
    _delta_covariance,
    _delta_method,
    _global_fit,
    _loes_parameters,
)
from ._loes_fit import _derived as _derived
from ._loes_fit import _fourier_residual as _fourier_residual
from ._loes_fit import _mismatch as _mismatch
from ._loes_fit import _physical as _physical
from ._response_function import _DENSE as _DENSE
from ._response_function import _as_function, _integrate, _Response
from ._response_records import angular_frequencies
from .frequency_id import (
    CompositeResponse,
    ResponseChannel,
    TransferFunctionFit,
    _band,
    _resolve_response,
    fit_transfer_function,
)

__all__ = [
    "BandwidthResult",
    "EquivalentSystemFit",
    "HandlingQualitiesLevel",
    "Margins",
    "bandwidth",
    "bandwidth_level",
    "equivalent_system",
    "short_period_level",
    "stability_margins",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# MIL-STD-1797A evaluates equivalent systems over 0.1-10 rad/s.
_LOES_BAND = (0.1, 10.0)
# kind: (numerator order, denominator order)
_LOES_FORMS = {"short_period": (1, 2), "roll": (0, 1), "dutch_roll": (0, 2)}
# Tischler's guideline for a transfer-function fit: J <= 100 acceptable.
_MISMATCH_GUIDELINE = 100.0


# -- bandwidth -----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BandwidthResult(FrozenState):
    """Bandwidth and phase delay of an attitude response (ADS-33E, MIL-STD-1797A).

    Attributes
    ----------
    bandwidth : float
        min(gain, phase bandwidth) in rad/s (the phase bandwidth when ω_180
        does not exist).
    bandwidth_gain, bandwidth_phase : float
        rad/s (NaN where undefined).
    omega_180 : float
        First frequency of −180° phase, rad/s (NaN when never reached).
    phase_delay : float
        τ_p in seconds (NaN when ω_180 or 2ω_180 lies outside the response).
    kind : str
    sign_reversed : bool
        The response had a negative low-frequency gain (a pitch attitude per
        trailing-edge-down elevator) and was read with its sign reversed, as the
        definitions take it.
    """

    bandwidth: float
    bandwidth_gain: float
    bandwidth_phase: float
    omega_180: float
    phase_delay: float
    kind: str = "attitude"
    sign_reversed: bool = False

    def summary(self) -> str:
        """Markdown table of the metrics."""
        rows = [
            ("bandwidth ω_BW [rad/s]", fmt(self.bandwidth)),
            ("gain bandwidth (6 dB margin) [rad/s]", fmt(self.bandwidth_gain)),
            ("phase bandwidth (45° margin) [rad/s]", fmt(self.bandwidth_phase)),
            ("ω_180 [rad/s]", fmt(self.omega_180)),
            ("phase delay τ_p [s]", fmt(self.phase_delay)),
        ]
        return "\n".join(
            [
                "## Bandwidth and phase delay",
                "",
                markdown_table(("metric", "value"), rows),
                "",
                f"Response kind: {self.kind} (ADS-33E / MIL-STD-1797A definitions)"
                + (
                    "; read with its sign reversed (a negative gain)."
                    if self.sign_reversed
                    else "."
                ),
                "",
                self._level_line(),
            ]
        )

    @property
    def level(self) -> HandlingQualitiesLevel | None:
        """Category A Level of (ω_BW, τ_p) (`aeroid.bandwidth_level`); None where either
        is undefined."""
        if not (np.isfinite(self.bandwidth) and np.isfinite(self.phase_delay)):
            return None
        return bandwidth_level(self.bandwidth, self.phase_delay)

    def _level_line(self) -> str:
        level = self.level
        if level is None:
            return "Level: not assessed (bandwidth or phase delay undefined)."
        return f"Level {level.level} (Category A; {level.source})."

    def plot(
        self,
        *,
        boundaries: Mapping[str, Sequence[tuple[float, float]]] | None = None,
        source: str = "",
    ) -> Any:
        """The point (ω_BW, τ_p) against Level boundaries. Returns a matplotlib Figure.

        Parameters
        ----------
        boundaries : mapping of str to sequence of (ω_BW, τ_p), optional
            Region polygons by label (for example ``"Level 1"``), vertices in
            rad/s and s, copied from the criterion you cite. Default: the
            Category A patches of `aeroid.frequency._criteria` (digitised, unverified).
        source : str
            The criterion's citation, printed under the plot (default: the
            built-in boundaries' source).
        """
        from ..reports.plotting import figure

        if boundaries is None:
            boundaries = {
                "Level 1 (Category A)": BANDWIDTH_LEVEL_1,
                "Level 2 (Category A)": BANDWIDTH_LEVEL_2,
            }
            source = source or BANDWIDTH_SOURCE
        fig, axes = figure(1, height=4.0)
        ax = axes[0, 0]
        for i, (label, poly) in enumerate(boundaries.items()):
            pts = np.asarray(poly, dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3:
                raise IdentificationError(
                    f"boundaries[{label!r}]: expected three or more (ω_BW, τ_p) vertices"
                )
            ax.fill(pts[:, 0], pts[:, 1], alpha=0.15, color=f"C{i}", label=label)
            ax.plot(np.r_[pts[:, 0], pts[0, 0]], np.r_[pts[:, 1], pts[0, 1]], color=f"C{i}", lw=1)
        ax.plot([self.bandwidth], [self.phase_delay], "k*", ms=12, label="this response")
        ax.set_xlabel("bandwidth ω_BW [rad/s]")
        ax.set_ylabel("phase delay τ_p [s]")
        ax.set_xlim(left=0.0)
        ax.set_ylim(bottom=0.0)
        ax.legend(fontsize=8)
        if source:
            ax.set_title(source, fontsize=8, loc="left")
        return fig


@small_blas
def bandwidth(
    response_or_tf: Any,
    *,
    kind: str = "attitude",
    input: str | None = None,
    output: str | None = None,
) -> BandwidthResult:
    """Bandwidth (gain and phase) and phase delay of an attitude response.

    Parameters
    ----------
    response_or_tf : CompositeResponse, ResponseChannel, fit or (num, den[, delay])
        The response: measured, a fitted transfer function, or polynomial
        coefficients (highest power first) with an optional delay in seconds.
    kind : {"attitude", "rate"}
        ``"rate"``: the response is an angular rate; it is integrated (÷ jω).
    input, output : str, optional
        The pair, for a composite response with several.

    Returns
    -------
    BandwidthResult

    Raises
    ------
    IdentificationError
        Unknown kind or response type, or a response whose phase never reaches −135°
        (or is past it from the first frequency: the sweep starts too high).
    """
    if kind not in ("attitude", "rate"):
        raise IdentificationError(f"kind: expected 'attitude' or 'rate', got {kind!r}")
    resp = _Response(response_or_tf, input, output)
    if kind == "rate":
        resp = resp.scaled(_integrate)
    resp, reversed_sign = _positive_sense(resp)
    w_phase = resp.phase_crossing(-135.0)
    if not np.isfinite(w_phase):
        band = f"({resp.omega[0]:.3g}-{resp.omega[-1]:.3g} rad/s)"
        first = float(resp.phase()[0])
        if first <= -135.0:  # the crossing lies below the band, not beyond it
            raise IdentificationError(
                f"bandwidth: the phase is already {first:.1f} deg, past -135 deg, at the "
                f"response's first frequency {band}: the sweep does not go low enough "
                "in frequency to find the phase bandwidth"
            )
        raise IdentificationError(
            f"bandwidth: the phase never reaches -135 deg over the response's frequencies {band}"
        )
    w180 = resp.phase_crossing(-180.0)
    if np.isfinite(w180):
        gain180 = 20.0 * np.log10(abs(resp.at(w180)))
        w_gain = resp.gain_crossing(gain180 + 6.0)
        phase2 = resp.phase_at(2.0 * w180)
        tau_p = -(phase2 + 180.0) / (np.degrees(1.0) * 2.0 * w180)
    else:
        w_gain = tau_p = float("nan")
    bw = float(np.nanmin([w_gain, w_phase])) if np.isfinite(w_gain) else w_phase
    return BandwidthResult(
        bw, float(w_gain), float(w_phase), float(w180), float(tau_p), kind, reversed_sign
    )


def _positive_sense(resp: _Response) -> tuple[_Response, bool]:
    """The response with the sign that gives it a positive low-frequency gain, and whether
    that reversed it: a pitch attitude per trailing-edge-down elevator (M_delta < 0)
    starts at +90° where the definitions expect the −90° of K/s. The integrators at
    the lowest frequencies (the gain's slope over the first decade, in −20 dB/decade)
    give the phase expected there; a phase half a turn from it is a reversed sign.
    """
    w = resp.omega
    first = w <= w[0] * 10.0
    if int(first.sum()) < 3:
        first = np.arange(w.size) < 3
    gain = 20.0 * np.log10(np.maximum(np.abs(resp.values[first]), 1e-300))
    slope = float(np.polyfit(np.log10(w[first]), gain, 1)[0])
    integrators = int(np.clip(np.round(-slope / 20.0), 0, 2))
    # (the median over that decade: a measured response's first point may be noise)
    off = (float(np.median(resp.phase()[first])) + 90.0 * integrators + 180.0) % 360.0 - 180.0
    if abs(off) <= 90.0:
        return resp, False
    return resp.scaled(lambda omega: -np.ones(omega.shape, dtype=np.complex128)), True


# -- margins --------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Margins(FrozenState):
    """Gain and phase margins of a loop transfer function.

    Attributes
    ----------
    gain_margin : float
        dB, ``−20 log10 |L(jω_180)|`` at the phase crossover nearest 0 dB (the
        smallest gain change, up or down, that puts L on −1; negative: a gain
        reduction); inf when the phase never reaches −180° (mod 360°).
    phase_crossover : float
        ω_180 in rad/s of that crossover (0 where L(0) is real and negative).
    phase_margin : float
        Degrees, ``180 + ∠L(jω_c)`` (inf when |L| never falls through 1).
    gain_crossover : float
        ω_c in rad/s.
    delay_margin : float
        Extra delay the loop tolerates, ``PM / ω_c`` in seconds.
    phase_crossovers : tuple of float
        Every ω (rad/s, ascending) where the phase crosses −180° (mod 360°),
        rising or falling, ω = 0 included where L(0) is real and negative.
    gain_margins : tuple of float
        The gain margin in dB at each of `phase_crossovers`.
    """

    gain_margin: float
    phase_crossover: float
    phase_margin: float
    gain_crossover: float
    delay_margin: float
    phase_crossovers: tuple[float, ...] = ()
    gain_margins: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "phase_crossovers", tuple(map(float, self.phase_crossovers)))
        object.__setattr__(self, "gain_margins", tuple(map(float, self.gain_margins)))
        if len(self.gain_margins) != len(self.phase_crossovers):
            raise IdentificationError(
                "gain_margins: expected one per phase crossover, got "
                f"{len(self.gain_margins)} for {len(self.phase_crossovers)}"
            )

    def summary(self) -> str:
        """Markdown table of the margins."""
        rows = [
            ("gain margin [dB]", fmt(self.gain_margin)),
            ("phase crossover ω_180 [rad/s]", fmt(self.phase_crossover)),
            ("phase margin [deg]", fmt(self.phase_margin)),
            ("gain crossover ω_c [rad/s]", fmt(self.gain_crossover)),
            ("delay margin [s]", fmt(self.delay_margin)),
        ]
        lines = ["## Stability margins", "", markdown_table(("margin", "value"), rows)]
        if len(self.phase_crossovers) > 1:
            pairs = zip(self.phase_crossovers, self.gain_margins, strict=True)
            each = [(fmt(w), fmt(g)) for w, g in pairs]
            lines += [
                "",
                "Every phase crossover (the gain margin is the one nearest 0 dB):",
                "",
                markdown_table(("ω_180 [rad/s]", "gain margin [dB]"), each),
            ]
        return "\n".join(lines)


@small_blas
def stability_margins(
    loop_response_or_tf: Any, *, input: str | None = None, output: str | None = None
) -> Margins:
    """Gain and phase margins of a (broken-loop) response.

    Parameters
    ----------
    loop_response_or_tf : CompositeResponse, ResponseChannel, fit or (num, den[, delay])
        The loop transfer function L(jω).
    input, output : str, optional
        The pair, for a composite response with several.

    Returns
    -------
    Margins

    Notes
    -----
    A phase crossover is any ω where the phase crosses −180° (mod 360°), falling
    or rising (a conditionally stable loop has both), and ω = 0 when L(0) is real
    and negative (an open-loop unstable loop such as ``2/(s − 1)``; read only from
    a transfer function or a fit, a measured response has no ω = 0 point). With
    several, the gain margin is the one nearest 0 dB, as python-control and
    MATLAB report it: for a stable closed loop, the smallest gain change either
    way that destabilises it.
    """
    resp = _Response(loop_response_or_tf, input, output, "loop_response_or_tf")
    crossovers = [float(w) for w in resp.phase_crossings(-180.0)]
    with np.errstate(divide="ignore"):
        margins = [float(-20.0 * np.log10(abs(resp.at(w)))) for w in crossovers]
        dc = resp.at_zero()
        # L(0) real and negative: the Nyquist plot starts on the negative real axis
        if np.isfinite(dc) and dc.real < 0.0 and abs(dc.imag) <= 1e-12 * abs(dc):
            crossovers.insert(0, 0.0)
            margins.insert(0, float(-20.0 * np.log10(abs(dc))))
    known = [i for i, g in enumerate(margins) if np.isfinite(g)]
    if known:
        pick = min(known, key=lambda i: abs(margins[i]))
        w180, gm = crossovers[pick], margins[pick]
    else:
        w180, gm = float("nan"), float("inf")
    wc = resp.gain_crossing(0.0)
    if np.isfinite(wc):
        pm = 180.0 + resp.phase_at(wc)
        dm = np.radians(pm) / wc
    else:
        pm = dm = float("inf")
    return Margins(
        float(gm), float(w180), float(pm), float(wc), float(dm), tuple(crossovers), tuple(margins)
    )


# -- equivalent systems -----------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EquivalentSystemFit(IntervalMixin):
    """A low-order equivalent system fitted to a response.

    Attributes
    ----------
    kind : str
    parameters : mapping of str to float
        ``short_period``: K, 1/T_theta2, zeta, omega, tau; ``roll``: K, 1/T_R,
        tau; ``dutch_roll``: K, zeta, omega, tau (rad/s, s).
    mismatch : float
        The Hodgkinson/CIFER mismatch J over the band (NaN for a fit to a
        record's Fourier transforms).
    fit : TransferFunctionFit
        The underlying transfer-function fit (its polynomial parameters and bounds).
    frequency_range : (float, float)
        The band in rad/s.
    standard_errors : mapping of str to float
        Standard error of each parameter (and, for the short period, of
        ``T_theta2``) by the delta method from the fit's covariance: first-order
        propagation through the map from the polynomial coefficients.
    """

    kind: str
    parameters: Mapping[str, float]
    mismatch: float
    fit: TransferFunctionFit
    frequency_range: tuple[float, float] = field(default=_LOES_BAND)
    standard_errors: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", frozen_mapping(self.parameters))
        object.__setattr__(self, "standard_errors", frozen_mapping(self.standard_errors))

    @property
    def stderr(self) -> Mapping[str, float]:
        """The `standard_errors` (the name every estimator's result shares)."""
        return self.standard_errors

    @property
    def covariance(self) -> FloatArray:
        """Covariance of the derived parameters (``omega``, ``zeta``, ...) by the delta
        method, in the order of `standard_errors`; NaN for names that have none."""
        keys, cov = _delta_covariance(self.kind, self.fit)
        names = list(self.standard_errors)
        out = np.full((len(names), len(names)), np.nan)
        idx = [keys.index(n) if n in keys else -1 for n in names]
        for a, i in enumerate(idx):
            for b, j in enumerate(idx):
                if i >= 0 and j >= 0:
                    out[a, b] = cov[i, j]
        return frozen_array(out)

    def evaluate(self, frequency: ArrayLike) -> ComplexArray:
        """The equivalent system's response at ω (rad/s)."""
        return self.fit.evaluate(frequency)

    @property
    def level(self) -> HandlingQualitiesLevel | None:
        """MIL-STD-1797A Level of a short-period fit (`aeroid.short_period_level`, as
        SIDPAC's ``milstd``); None for the other kinds, which it does not cover.

        An unstable short period with real roots (no ω or ζ) is Level 3, with ζ and ω
        named beyond the Level 3 limits and the root in its notes."""
        if self.kind != "short_period":
            return None
        p = self.parameters
        inv = p["1/T_theta2"]
        t_theta2 = 1.0 / inv if inv != 0 else float("inf")
        root = self._real_root()
        if root is not None:
            return _unstable_short_period_level(t_theta2, p["tau"], root)
        return short_period_level(p["omega"], p["zeta"], t_theta2, p["tau"])

    def _real_root(self) -> float | None:
        """The largest denominator root of a second-order form with a0 <= 0 (real roots,
        one at s >= 0: no ω or ζ); None otherwise."""
        if self.kind == "roll" or self.fit.parameters["a0"] > 0:
            return None
        return float(np.max(np.real(self.fit.poles)))

    @property
    def flags(self) -> tuple[str, ...]:
        """What makes the fit suspect: an unstable pole, a right-half-plane zero, a
        negative delay, a mismatch beyond the guideline."""
        p = self.parameters
        out = []
        root = self._real_root()
        unstable = [complex(z) for z in self.fit.poles if z.real > 0]
        if root is not None:
            out.append(
                f"real denominator roots, one at s = {root:.4g} >= 0 (a0 <= 0): "
                "an unstable mode with no zeta or omega"
            )
        elif unstable:
            where = ", ".join(f"{z:.4g}" for z in unstable)
            out.append(f"unstable pole (s = {where}): an open-loop unstable mode")
        if self.kind == "short_period" and p["1/T_theta2"] < 0:
            out.append("right-half-plane zero (1/T_theta2 < 0): not a physical pitch response")
        if p.get("tau", 0.0) < -DELAY_ROUNDING:
            out.append("negative time delay")
        if self.mismatch > _MISMATCH_GUIDELINE:
            out.append(f"mismatch J above {_MISMATCH_GUIDELINE:.0f}")
        return tuple(out)

    def summary(self) -> str:
        """Markdown table of the equivalent-system parameters, the mismatch and the Level."""
        se = self.standard_errors
        rows = [(k, fmt(v), fmt(se.get(k, float("nan")))) for k, v in self.parameters.items()]
        if "T_theta2" in se:
            inv = self.parameters["1/T_theta2"]
            rows.append(
                ("T_theta2", fmt(1.0 / inv if inv != 0 else float("inf")), fmt(se["T_theta2"]))
            )
        verdict = "within" if self.mismatch <= _MISMATCH_GUIDELINE else "beyond"
        lo, hi = self.frequency_range
        j_line = (
            f"Mismatch J = {fmt(self.mismatch, 4)} over {fmt(lo, 3)}–{fmt(hi, 3)} rad/s "
            f"({verdict} the J ≤ {_MISMATCH_GUIDELINE:.0f} guideline)."
            if np.isfinite(self.mismatch)
            else f"Fitted to the record's Fourier transforms over {fmt(lo, 3)}–{fmt(hi, 3)} "
            "rad/s (no averaged response: no mismatch J)."
        )
        lines = [
            f"## Low-order equivalent system ({self.kind})",
            "",
            markdown_table(("parameter", "value", "standard error"), rows),
            "",
            j_line,
        ]
        level = self.level
        if level is not None:
            beyond = (
                f", beyond the Level 3 limits on {', '.join(level.beyond_level_3)}"
                if level.beyond_level_3
                else ""
            )
            lines += ["", f"Level {level.level}{beyond} ({level.source})."]
        lines += [f"Warning: {f}." for f in self.flags]
        return "\n".join(lines)

    def mismatch_envelopes(self, omega: ArrayLike | None = None) -> dict[str, FloatArray]:
        """The maximum unnoticeable added dynamics envelopes at ω (rad/s; default the
        fit's band) with the mismatch HOS/LOES, gain in dB and phase in degrees.

        Returns a dict with ``omega``, ``gain_db``, ``phase_deg`` (the mismatch; NaN
        where the response has no point) and the four envelopes of
        `aeroid.frequency._criteria.MUAD_ENVELOPES` (digitised, unverified by their source).
        """
        fit_w = np.asarray(self.fit.frequency, dtype=np.float64)
        w = fit_w if omega is None else angular_frequencies(omega, "omega")
        measured = np.asarray(self.fit.response, dtype=np.complex128)
        loes = np.asarray(self.fit.evaluate(fit_w), dtype=np.complex128)
        with np.errstate(all="ignore"):
            ratio = measured / loes
        gain = np.interp(w, fit_w, 20.0 * np.log10(np.abs(ratio)), left=np.nan, right=np.nan)
        phase = np.interp(
            w, fit_w, np.degrees(np.unwrap(np.angle(ratio))), left=np.nan, right=np.nan
        )
        return {"omega": w, "gain_db": gain, "phase_deg": phase, **muad_envelopes(w)}

    def plot(self) -> Any:
        """The equivalent system over the response. Returns a matplotlib Figure."""
        return self.fit.plot()


def _items(value: Any) -> list[Any]:
    """The entries of `value`, or none when it is not iterable (`_band` then says so)."""
    try:
        return list(value)
    except TypeError:
        return []


def _exact_channel(tf: Any, band: tuple[float, float]) -> ResponseChannel:
    h = _as_function(tf, "response")
    w = np.geomspace(band[0], band[1], 100)
    return ResponseChannel("input", "output", w, h(w), coherence=np.ones(w.size))


@small_blas
def equivalent_system(
    response: Any,
    *,
    kind: str = "short_period",
    frequency_range: tuple[float, float] = _LOES_BAND,
    delay: bool = True,
    input: str | None = None,
    output: str | None = None,
    start: Mapping[str, float] | None = None,
    frequencies: ArrayLike | None = None,
) -> EquivalentSystemFit:
    """Fit a MIL-STD-1797A low-order equivalent system.

    Parameters
    ----------
    response : CompositeResponse, ResponseChannel, FlightData, fit or (num, den[, delay])
        The measured response, a record (fitted directly on its finite Fourier
        transforms over the band's ``k/T`` frequencies, as SIDPAC's Example 7.3,
        with the record's ends and the frequency sandwich's error bars of
        `fit_transfer_function` with ``fourier=True``; `input` and `output`
        name the channels), or a high-order system's
        transfer function (evaluated at 100 log-spaced frequencies over the band).
    kind : {"short_period", "roll", "dutch_roll"}
        The standard form (see the module notes).
    frequency_range : (float, float)
        Band in rad/s (MIL-STD-1797A: 0.1–10).
    delay : bool
        Fit the equivalent time delay.
    input, output : str, optional
        The pair, for a composite response with several.
    start : mapping, optional
        Start values of the polynomial parameters (see `fit_transfer_function`);
        given, they replace the global start.
    frequencies : array_like, optional
        A record only: the frequencies (rad/s) of its Fourier transforms
        (default: the ``k/T`` grid over the band; see `fit_transfer_function`).

    Returns
    -------
    EquivalentSystemFit

    Notes
    -----
    The global start: for each delay on a grid from 0 to half a turn of phase at
    the band's top frequency, a linear (Sanathanan-Koerner) fit of the rational
    form to ``H(jω) e^{jωτ}``; the best four with stable poles, ranked by their
    mismatch, and the default start each start the nonlinear fit. The lowest
    final cost wins; among costs within 10 % of it a physical solution
    (minimum-phase zero, ``τ ≥ 0``) is preferred. Standard errors of the
    parameters follow by the delta method.

    Raises
    ------
    IdentificationError
        Unknown kind, a `delay` that is not a bool, a bad frequency range,
        text among the start values, or a response that cannot be fitted.
    """
    if kind not in _LOES_FORMS:
        raise IdentificationError(f"kind: expected one of {sorted(_LOES_FORMS)}, got {kind!r}")
    check_flag(delay, "delay", IdentificationError)
    # float() would read "0.1" as 0.1 and "1" as a start value
    if isinstance(frequency_range, (str, bytes)) or any(
        isinstance(v, (bool, np.bool_, str, bytes)) for v in _items(frequency_range)
    ):
        raise IdentificationError(
            f"frequency_range: expected (low, high) in rad/s, got {frequency_range!r}"
        )
    if isinstance(start, Mapping):
        for name, value in start.items():
            if isinstance(value, (str, bytes)):
                raise IdentificationError(
                    f"start[{name!r}]: expected a finite number, got {plain(value)}"
                )
    lo, hi = _band(frequency_range)
    if not lo > 0.0:
        raise IdentificationError(
            f"frequency_range: expected 0 < low < high, got {frequency_range!r}"
        )
    m, n = _LOES_FORMS[kind]
    if frequencies is not None and not isinstance(response, FlightData):
        raise IdentificationError("frequencies applies to a record (FlightData) only")
    if isinstance(response, FlightData):
        data = response
        for role, channel in (("input", input), ("output", output)):
            if channel is None:  # a record has many channels: which ones is not guessed
                raise ChannelError(f"{role}: a record needs the {role} channel named")
        nyquist = math.pi * data.sample_rate
        if hi > nyquist * (1.0 + 1e-9):
            raise IdentificationError(
                f"frequency_range: its top {hi:g} rad/s lies above the record's Nyquist "
                f"frequency {nyquist:.6g} rad/s"
            )

        def fitter(s: Mapping[str, float] | None) -> TransferFunctionFit:
            return fit_transfer_function(
                data,
                input=input,
                output=output,
                numerator_order=m,
                denominator_order=n,
                delay=delay,
                frequency_range=(lo, hi),
                start=s,
                fourier=True,
                frequencies=frequencies,
            )

    else:
        if isinstance(response, (CompositeResponse, ResponseChannel)):
            ch = _resolve_response(response, input, output, "response")
        else:
            ch = _exact_channel(response, (lo, hi))

        def fitter(s: Mapping[str, float] | None) -> TransferFunctionFit:
            return fit_transfer_function(
                ch,
                numerator_order=m,
                denominator_order=n,
                delay=delay,
                frequency_range=(lo, hi),
                start=s,
            )

    objective: Callable[[TransferFunctionFit], float] = _cifer_cost
    if isinstance(response, FlightData):
        objective = _fourier_residual(response, input, output)
    fit = fitter(start) if start is not None else _global_fit(fitter, objective, kind, m, n, delay)
    out = _loes_parameters(kind, fit.parameters)
    # a Fourier fit's Y/U ratios are raw (no averaging, no coherence): no mismatch J
    mismatch = float("nan") if isinstance(response, FlightData) else fit.cost
    return EquivalentSystemFit(kind, out, mismatch, fit, (lo, hi), _delta_method(kind, fit))
