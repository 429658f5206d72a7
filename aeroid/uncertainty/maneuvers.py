"""Manoeuvre families for experiment design.

A manoeuvre family maps a few design variables (amplitudes, widths,
frequencies) to control histories. `design_experiment` searches the
variables within their bounds; any object with the `ManeuverFamily`
interface works, the built-ins are `Doublet`, `Multistep` (the 3-2-1-1 and
other square-pulse patterns), `Multisine` (Schroeder 1970 phases) and
`Chirp` (linear or exponential sweep).

Every family argument given as a number is held fixed; given as a
``(low, high)`` range it becomes a design variable. The upper amplitude bound
is the actuator or safety limit: no built-in family ever exceeds it.

The orthogonal multisines of several controls flown together live in
`aeroid.uncertainty.orthogonal_multisines` (re-exported here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float
from .._records import fmt
from ..errors import DataFormatError, ModelDefinitionError
from .orthogonal_multisines import (
    OrthogonalMultisine,
    _numbers,
    orthogonal_multisine,
    relative_peak_factor,
    schroeder_phases,
)

__all__ = [
    "Chirp",
    "Doublet",
    "ManeuverFamily",
    "Multisine",
    "Multistep",
    "OrthogonalMultisine",
    "orthogonal_multisine",
    "relative_peak_factor",
]

FloatArray = NDArray[np.float64]
Range = tuple[float, float]


@runtime_checkable
class ManeuverFamily(Protocol):
    """What `design_experiment` needs from a manoeuvre family.

    Attributes
    ----------
    controls : tuple of str
        The model controls the family drives (others stay at zero).
    variable_names : tuple of str
        Names of the design variables.
    bounds : tuple of (float, float)
        Finite ``(low, high)`` per design variable, low < high.

    Methods
    -------
    initial() -> ndarray, shape (n_variables,)
        The reference design the optimised one is compared with (within the bounds).
    signal(variables, time) -> ndarray, shape (n_t, n_controls)
        Control history for one vector of design variables.
    describe(variables, time) -> str
        One line for the recommendation, e.g. ``"doublet on 'elevator': ..."``.

    A family may also define ``canonical(variables, time)`` returning the
    variables that reproduce the same signal in their most direct form (the
    built-in `Multisine` returns its amplitudes after peak limiting), and
    ``highest_frequency()`` returning the highest frequency (Hz) any design
    puts in the signal, or None: `design_experiment` refuses a family that
    reaches the Nyquist frequency, where its lines would alias.
    """

    @property
    def controls(self) -> tuple[str, ...]: ...

    @property
    def variable_names(self) -> tuple[str, ...]: ...

    @property
    def bounds(self) -> tuple[tuple[float, float], ...]: ...

    def initial(self) -> FloatArray: ...

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray: ...

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str: ...


def _range(value: Any, what: str, *, positive: bool = False) -> Range:
    """A number (fixed) or a (low, high) range, validated."""
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        lo = hi = float(value)
    else:
        # text and bools are no numbers, though float() reads "1" and True as 1.0
        listed = isinstance(value, (tuple, list, np.ndarray)) and np.ndim(value) == 1
        ends = [as_float(v) for v in value] if listed else []
        if len(ends) != 2 or ends[0] is None or ends[1] is None:
            raise ModelDefinitionError(
                f"{what}: expected a number or a (low, high) range, got {value!r}"
            )
        lo, hi = ends[0], ends[1]
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ModelDefinitionError(f"{what}: expected finite low <= high, got {value!r}")
    if positive and lo <= 0:
        raise ModelDefinitionError(f"{what}: must be positive, got {value!r}")
    if not positive and lo < 0:
        raise ModelDefinitionError(f"{what}: must be non-negative, got {value!r}")
    return lo, hi


def _control_name(control: Any) -> str:
    if not isinstance(control, str) or not control:
        raise ModelDefinitionError(f"control: expected a control name, got {control!r}")
    return control


class _Family:
    """Shared bookkeeping: fixed settings versus (low, high) design variables."""

    _kind = "manoeuvre"

    def __init__(self, control: str, specs: dict[str, Range]) -> None:
        self._control = _control_name(control)
        self._specs = specs
        self._free = tuple(k for k, (lo, hi) in specs.items() if hi > lo)

    @property
    def controls(self) -> tuple[str, ...]:
        return (self._control,)

    @property
    def variable_names(self) -> tuple[str, ...]:
        return self._free

    @property
    def bounds(self) -> tuple[tuple[float, float], ...]:
        return tuple(self._specs[k] for k in self._free)

    def initial(self) -> FloatArray:
        """Mid-range design: the reference the optimised design is compared with."""
        return np.array([0.5 * (lo + hi) for lo, hi in self.bounds])

    def _settings(self, variables: ArrayLike) -> dict[str, float]:
        try:
            v = np.atleast_1d(np.asarray(variables, dtype=np.float64))
        except (TypeError, ValueError):
            v = np.full(len(self._free), np.nan)
        if v.shape != (len(self._free),):
            raise ModelDefinitionError(
                f"{type(self).__name__}: expected {len(self._free)} design variables "
                f"{list(self._free)}, got shape {v.shape}"
            )
        if not np.all(np.isfinite(v)):
            raise ModelDefinitionError(
                f"{type(self).__name__}: design variables {list(self._free)} must be finite "
                f"numbers, got {variables!r:.80}"
            )
        out = {k: lo for k, (lo, _) in self._specs.items()}
        out.update(zip(self._free, v.tolist(), strict=True))
        return out

    def _grid(self, time: ArrayLike) -> FloatArray:
        """The signal's time grid: at least two finite, strictly increasing samples."""
        try:
            t = np.asarray(time, dtype=np.float64)
        except (TypeError, ValueError):
            raise DataFormatError(f"{type(self).__name__} time: not numeric") from None
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise DataFormatError(
                f"{type(self).__name__} time: expected at least two finite, strictly "
                f"increasing samples (s), got {t.size} of shape {t.shape}"
            )
        return t

    def highest_frequency(self) -> float | None:
        """The highest frequency (Hz) any design can put in the signal, if it has one."""
        return None

    def __repr__(self) -> str:
        parts = ", ".join(
            f"{k}={lo:g}" if lo == hi else f"{k}=({lo:g}, {hi:g})"
            for k, (lo, hi) in self._specs.items()
        )
        return f"{type(self).__name__}({self._control!r}, {parts})"


def _cell_fraction(time: FloatArray, a: float, b: float) -> FloatArray:
    """Fraction of each sample's interval [t_k, t_k+1) inside [a, b)."""
    lo = time
    hi = np.concatenate([time[1:], [time[-1] + (time[-1] - time[-2])]])
    return np.clip(np.minimum(b, hi) - np.maximum(a, lo), 0.0, None) / (hi - lo)


def _pulse_train(t: FloatArray, s: dict[str, float], steps: FloatArray) -> FloatArray:
    """Square pulses of alternating sign from ``+``, between the edges ``start + width *
    steps`` after the first sample, each sample holding each pulse's share of its
    interval (a doublet, a multistep)."""
    edges = (float(t[0]) + s["start"]) + s["width"] * steps
    level = np.zeros(t.size)
    for j in range(steps.size - 1):
        share = _cell_fraction(t, float(edges[j]), float(edges[j + 1]))
        level = level - share if j % 2 else level + share
    return (s["amplitude"] * level)[:, None]


def _pulse_specs(kind: str, amplitude: Any, width: Any, start: Any) -> dict[str, Range]:
    """A pulse train's settings (fixed, or design ranges), checked and named for `kind`."""
    return {
        "amplitude": _range(amplitude, f"{kind} amplitude"),
        "width": _range(width, f"{kind} width", positive=True),
        "start": _range(start, f"{kind} start"),
    }


# a doublet's edges in lobe widths from its start
_DOUBLET_EDGES = np.array([0.0, 1.0, 2.0])


class Doublet(_Family):
    """A doublet: ``+amplitude`` for `width` seconds from `start`, then ``-amplitude``.

    Each sample holds the lobe's share of the interval up to the next
    sample, so edges on the grid give the plain sampled doublet and edges
    between samples change the signal smoothly with `width` and `start`.
    It is ``Multistep(pattern=(1, 1))``, its band too: `highest_frequency`
    is a lobe's first spectral null at the smallest width, ``1 / width``.

    Parameters
    ----------
    control : str
    amplitude : float or (float, float)
        Peak amplitude (or its design range; the upper bound is the limit).
    width : float or (float, float)
        Duration of each lobe in seconds.
    start : float or (float, float)
        Start time in seconds after the first sample.
    """

    _kind = "doublet"

    def __init__(
        self,
        control: str,
        *,
        amplitude: float | Range,
        width: float | Range = (0.5, 2.0),
        start: float | Range = 1.0,
    ) -> None:
        super().__init__(control, _pulse_specs("Doublet", amplitude, width, start))

    def highest_frequency(self) -> float:
        # a lobe's first spectral null, as for `Multistep`'s shortest pulse
        return 1.0 / self._specs["width"][0]

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        return _pulse_train(self._grid(time), self._settings(variables), _DOUBLET_EDGES)

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        s = self._settings(variables)
        return (
            f"doublet on {self._control!r}: amplitude {fmt(s['amplitude'], 3)}, "
            f"{fmt(s['width'], 3)} s lobes from t = {fmt(s['start'], 3)} s"
        )


def _pattern(pattern: Any) -> tuple[int, ...]:
    """A multistep's pulse widths in base steps: a non-empty sequence of positive integers."""
    listed = isinstance(pattern, Sequence) and not isinstance(pattern, str | bytes)
    items = (
        list(pattern) if listed or (isinstance(pattern, np.ndarray) and pattern.ndim == 1) else []
    )
    if not items or not all(
        isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n > 0 for n in items
    ):
        raise ModelDefinitionError(
            f"Multistep pattern: expected a non-empty sequence of positive integers "
            f"(base steps per pulse, e.g. (3, 2, 1, 1)), got {pattern!r}"
        )
    return tuple(int(n) for n in items)


class Multistep(_Family):
    """Alternating square pulses: the 3-2-1-1 and other multistep inputs.

    Pulse j lasts ``pattern[j] * width`` seconds and has the sign ``(-1)**j``:
    the default 3-2-1-1 flies ``+amplitude`` for three base steps from `start`,
    ``-amplitude`` for two, then one of each (Koehler's 3-2-1-1; Jategaonkar
    2015 sec. 2.5; Klein & Morelli 2006 sec. 9.3; SIDPAC's ``mksqw``). A
    doublet is ``pattern=(1, 1)``. As in `Doublet`, each sample holds each
    pulse's share of the interval up to the next sample, so edges between
    samples change the signal smoothly with `width` and `start`. (SIDPAC's
    ``mksqw`` puts each pulse one sample later, on ``(start, end]``.)

    The band it excites: a pulse of width w has the spectrum
    ``w sinc(f w)``, whose first null is at ``1 / w``. `highest_frequency` is
    that null for the shortest pulse at the smallest width allowed,
    ``1 / (min(pattern) * width_low)``; the pulses' energy above it is in
    side lobes. `design_experiment` refuses a multistep whose null reaches the
    Nyquist frequency (a shortest pulse of two samples or less).

    Parameters
    ----------
    control : str
    amplitude : float or (float, float)
        Peak amplitude (or its design range; the upper bound is the limit).
    width : float or (float, float)
        The base step in seconds (or its design range); the 3-2-1-1 lasts
        seven of them.
    start : float or (float, float)
        Start time in seconds after the first sample.
    pattern : sequence of int
        Pulse widths in base steps, signs alternating from ``+``; fixed, not a
        design variable.
    """

    _kind = "multistep"

    def __init__(
        self,
        control: str,
        *,
        amplitude: float | Range,
        width: float | Range = (0.5, 2.0),
        start: float | Range = 1.0,
        pattern: Sequence[int] = (3, 2, 1, 1),
    ) -> None:
        self.pattern = _pattern(pattern)
        # pulse edges in base steps from the start: 0, 3, 5, 6, 7 for the 3-2-1-1
        self._edges = np.concatenate([[0.0], np.cumsum(self.pattern, dtype=np.float64)])
        super().__init__(control, _pulse_specs("Multistep", amplitude, width, start))

    def highest_frequency(self) -> float:
        return 1.0 / (min(self.pattern) * self._specs["width"][0])

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        return _pulse_train(self._grid(time), self._settings(variables), self._edges)

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        s = self._settings(variables)
        name = "-".join(str(n) for n in self.pattern)
        return (
            f"{name} multistep on {self._control!r}: amplitude {fmt(s['amplitude'], 3)}, "
            f"{fmt(s['width'], 3)} s base step from t = {fmt(s['start'], 3)} s"
        )

    def __repr__(self) -> str:
        return f"{super().__repr__()[:-1]}, pattern={self.pattern})"


class Multisine(_Family):
    """Sum of cosines at fixed frequencies with per-line amplitudes and Schroeder phases.

    The design variables are the line amplitudes; the phases follow from
    their relative powers (Schroeder 1970), taken over the lines in frequency
    order whatever the order they are listed in. The upper amplitude bound is
    also the signal's peak limit (unless `peak` is given): a combination whose
    sum would exceed it is shrunk towards the lower amplitude bounds until it
    does not (scaled down as a whole where they are zero), so every line
    flown stays within its bounds and the optimiser's freedom is the
    distribution of energy over the lines. Lower bounds whose lines alone
    exceed the peak limit cannot be flown and are refused
    (`ModelDefinitionError`) when a signal needs the limit.

    Parameters
    ----------
    control : str
    frequencies : sequence of float
        Line frequencies in Hz (distinct, positive).
    amplitude : float or (float, float)
        Per-line amplitude (or its design range).
    peak : float, optional
        Peak limit of the summed signal (default: the upper amplitude bound).
    """

    _kind = "multisine"

    def __init__(
        self,
        control: str,
        *,
        frequencies: Sequence[float],
        amplitude: float | Range,
        peak: float | None = None,
    ) -> None:
        freqs = _numbers(frequencies, "Multisine frequencies")
        if freqs.size == 0 or not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
            raise ModelDefinitionError(
                f"Multisine frequencies: expected positive finite values, got {frequencies!r}"
            )
        if np.unique(freqs).size != freqs.size:
            raise ModelDefinitionError(f"Multisine frequencies: duplicates in {frequencies!r}")
        amp = _range(amplitude, "Multisine amplitude")
        self.frequencies = tuple(float(f) for f in freqs)
        limit = amp[1] if peak is None else as_float(peak)
        if limit is None or not (np.isfinite(limit) and limit > 0):
            raise ModelDefinitionError(f"Multisine peak: expected a positive number, got {peak!r}")
        self.peak = limit
        super().__init__(control, {f"amplitude_{f:g}Hz": amp for f in self.frequencies})

    def highest_frequency(self) -> float:
        return max(self.frequencies)

    def _raw(self, a: FloatArray, t: FloatArray) -> FloatArray:
        w = 2.0 * np.pi * np.asarray(self.frequencies)
        # Schroeder's rule runs over the lines in frequency order, whatever the list order
        order = np.argsort(w)
        ph = np.empty(a.size)
        ph[order] = schroeder_phases(a[order] ** 2)
        # Schroeder's phases are for a sum of cosines; moved along in time (which keeps
        # the crest) to the sum's first zero crossing, so the input starts from trim
        # without a jump, as SIDPAC's mkmsswp does
        probe = np.linspace(0.0, 2.0 * np.pi / float(np.min(w)), 4097)
        level = np.cos(w[None, :] * probe[:, None] + ph[None, :]) @ a
        cross = np.flatnonzero(np.sign(level[1:]) != np.sign(level[:-1]))
        lead = 0.0
        if level[0] != 0.0 and cross.size:
            i = int(cross[0])
            lead = float(
                probe[i] - level[i] * (probe[i + 1] - probe[i]) / (level[i + 1] - level[i])
            )
            for _ in range(3):  # Newton on the sum itself: the crossing to rounding
                value = float(np.cos(w * lead + ph) @ a)
                slope = float(-(w * np.sin(w * lead + ph)) @ a)
                if slope != 0.0:
                    lead -= value / slope
        arg = w[None, :] * ((t - t[0])[:, None] + lead) + ph[None, :]
        return np.cos(arg) @ a

    def _amplitudes(self, variables: ArrayLike) -> FloatArray:
        s = self._settings(variables)
        return np.array([s[k] for k in self._specs])

    def _flown(self, a: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The line amplitudes flown and their signal: `a` itself within the peak limit,
        else the excess over the lower bounds shrunk until it is (all of `a` scaled down
        where the lower bounds are zero), so no line leaves its bounds."""
        raw = self._raw(a, t)
        top = float(np.max(np.abs(raw)))
        if top <= self.peak:
            return a, raw
        low = np.array([lo for lo, _ in self._specs.values()])
        if not np.any(low > 0):  # the sum scales with the amplitudes, phases unchanged
            scale = self.peak / top
            return a * scale, raw * scale
        floor = self._raw(low, t)
        if float(np.max(np.abs(floor))) > self.peak:
            raise ModelDefinitionError(
                f"Multisine amplitude: every line at its lower bound {fmt(low.min(), 3)} "
                f"already peaks at {fmt(float(np.max(np.abs(floor))), 3)}, above the peak "
                f"limit {fmt(self.peak, 3)}; lower the amplitudes' lower bound or raise peak"
            )
        # the phases follow the relative powers, so the peak is no longer linear in the
        # shrink: bisect it, keeping the end that stays within the limit
        good, bad, best = 0.0, 1.0, (low, floor)
        for _ in range(40):
            mid = 0.5 * (good + bad)
            trial = low + mid * (a - low)
            u = self._raw(trial, t)
            if float(np.max(np.abs(u))) <= self.peak:
                good, best = mid, (trial, u)
            else:
                bad = mid
        return best

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        t = self._grid(time)
        return self._flown(self._amplitudes(variables), t)[1][:, None]

    def canonical(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        """The line amplitudes actually flown (after peak limiting)."""
        t = self._grid(time)
        flown = dict(zip(self._specs, self._flown(self._amplitudes(variables), t)[0], strict=True))
        return np.array([flown[k] for k in self._free])

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        t = self._grid(time)
        a = self._amplitudes(variables)
        u = self.signal(variables, t)[:, 0]
        power = a**2
        f = np.asarray(self.frequencies)
        if power.max() > 0:
            # lines carrying at least a quarter of the strongest line's power
            strong = f[power >= 0.25 * power.max()]
            band = (
                f"{fmt(strong.min(), 3)} Hz"
                if strong.min() == strong.max()
                else f"{fmt(strong.min(), 3)}-{fmt(strong.max(), 3)} Hz"
            )
        else:
            band = "none"
        return (
            f"multisine on {self._control!r}: dominant energy {band}, "
            f"peak amplitude {fmt(float(np.max(np.abs(u))), 3)}"
        )


# Tischler & Remple (2012) ch. 5, the recommended exponential sweep: the frequency
# rises as exp(C1 t / T) - 1 with C1 = 4 (SIDPAC's mkfswp type 0 has the same)
_SWEEP_RATE = 4.0
_SWEEPS = ("linear", "exponential")


class Chirp(_Family):
    """Frequency sweep from `f0` to `f1` over the record, linear or exponential.

    ``sweep="linear"``: ``A sin(2π (f0 τ + (f1 - f0) τ² / 2T))``, the
    frequency rising evenly, where τ is the time from the first sample and T
    the record's length.

    ``sweep="exponential"``: Tischler & Remple's (2012, ch. 5) recommended
    sweep, which spends longer at the low frequencies: the frequency is
    ``f0 + (f1 - f0) K(τ)`` with ``K = C2 (exp(C1 τ / T) - 1)``, ``C1 = 4``,
    and the phase is its integral in closed form,
    ``2π (f0 τ + (f1 - f0) C2 (T / C1 (exp(C1 τ / T) - 1) - τ))``. Tischler's
    tabled ``C2 = 0.0187`` is ``1 / (e⁴ - 1) = 0.018657`` to three figures: with it
    K reaches 1.0023 at T and the sweep would end 0.23 % of the band above
    `f1`. Here ``C2 = 1 / (e⁴ - 1)`` exactly, so the sweep ends at `f1`, as
    the linear one does, and never exceeds the band it is given. SIDPAC's
    ``mkfswp`` (type 0) uses the same formula with the rounded C2 and also
    sets the signal to zero after its last zero crossing; this one, like the
    linear sweep, runs to the end of the record.

    Parameters
    ----------
    control : str
    f0, f1 : float or (float, float)
        Start and end frequencies in Hz (or their design ranges).
    amplitude : float or (float, float)
        Peak amplitude (or its design range).
    sweep : {"linear", "exponential"}
        How the frequency moves from `f0` to `f1`.
    """

    _kind = "chirp"

    def __init__(
        self,
        control: str,
        *,
        f0: float | Range,
        f1: float | Range,
        amplitude: float | Range,
        sweep: str = "linear",
    ) -> None:
        if not isinstance(sweep, str) or sweep not in _SWEEPS:
            raise ModelDefinitionError(
                f"Chirp sweep: expected 'linear' or 'exponential', got {sweep!r}"
            )
        self.sweep = sweep
        super().__init__(
            control,
            {
                "f0": _range(f0, "Chirp f0", positive=True),
                "f1": _range(f1, "Chirp f1", positive=True),
                "amplitude": _range(amplitude, "Chirp amplitude"),
            },
        )

    def highest_frequency(self) -> float:
        return max(self._specs["f0"][1], self._specs["f1"][1])

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        s = self._settings(variables)
        t = self._grid(time)
        tau = t - t[0]
        span = max(float(tau[-1]), 1e-300)
        if self.sweep == "linear":
            phase = 2.0 * np.pi * (s["f0"] * tau + 0.5 * (s["f1"] - s["f0"]) * tau**2 / span)
        else:
            # ∫ (exp(C1 τ/T) - 1) dτ = T/C1 (exp(x) - 1 - x), x = C1 τ/T: expm1 keeps the
            # small-x end accurate
            x = _SWEEP_RATE * tau / span
            rise = (span / _SWEEP_RATE) * (np.expm1(x) - x) / math.expm1(_SWEEP_RATE)
            phase = 2.0 * np.pi * (s["f0"] * tau + (s["f1"] - s["f0"]) * rise)
        return (s["amplitude"] * np.sin(phase))[:, None]

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        s = self._settings(variables)
        kind = "sweep" if self.sweep == "linear" else "exponential sweep"
        return (
            f"chirp on {self._control!r}: {fmt(s['f0'], 3)}-{fmt(s['f1'], 3)} Hz {kind}, "
            f"amplitude {fmt(s['amplitude'], 3)}"
        )

    def __repr__(self) -> str:
        text = super().__repr__()
        return text if self.sweep == "linear" else f"{text[:-1]}, sweep={self.sweep!r})"
