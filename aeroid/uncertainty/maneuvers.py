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

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import fmt
from ..errors import ModelDefinitionError
from .orthogonal_multisines import (
    OrthogonalMultisine,
    orthogonal_multisine,
    relative_peak_factor,
    schroeder_phases,
)

__all__ = [
    "Chirp",
    "Doublet",
    "ManeuverFamily",
    "Multisine",
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
        ``(low, high)`` per design variable.

    Methods
    -------
    initial() -> ndarray, shape (n_variables,)
        The reference design the optimised one is compared with.
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
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ModelDefinitionError(
                f"{what}: expected a number or a (low, high) range, got {value!r}"
            ) from None
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


class Doublet(_Family):
    """A doublet: ``+amplitude`` for `width` seconds from `start`, then ``-amplitude``.

    Each sample holds the lobe's share of the interval up to the next
    sample, so edges on the grid give the plain sampled doublet and edges
    between samples change the signal smoothly with `width` and `start`.

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
        super().__init__(
            control,
            {
                "amplitude": _range(amplitude, "Doublet amplitude"),
                "width": _range(width, "Doublet width", positive=True),
                "start": _range(start, "Doublet start"),
            },
        )

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        s = self._settings(variables)
        t = np.asarray(time, dtype=np.float64)
        t0 = float(t[0]) + s["start"]
        w = s["width"]
        up = _cell_fraction(t, t0, t0 + w)
        down = _cell_fraction(t, t0 + w, t0 + 2 * w)
        return (s["amplitude"] * (up - down))[:, None]

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        s = self._settings(variables)
        return (
            f"doublet on {self._control!r}: amplitude {fmt(s['amplitude'], 3)}, "
            f"{fmt(s['width'], 3)} s lobes from t = {fmt(s['start'], 3)} s"
        )


class Multisine(_Family):
    """Sum of cosines at fixed frequencies with per-line amplitudes and Schroeder phases.

    The design variables are the line amplitudes; the phases follow from
    their relative powers (Schroeder 1970). The upper amplitude bound is also
    the signal's peak limit: a combination whose sum would exceed it is
    scaled down as a whole, so the optimiser's freedom is the distribution
    of energy over the lines.

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
        try:
            freqs = np.asarray(frequencies, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ModelDefinitionError(
                f"Multisine frequencies: expected a sequence of numbers, got {frequencies!r}"
            ) from None
        if freqs.size == 0 or not np.all(np.isfinite(freqs)) or np.any(freqs <= 0):
            raise ModelDefinitionError(
                f"Multisine frequencies: expected positive finite values, got {frequencies!r}"
            )
        if np.unique(freqs).size != freqs.size:
            raise ModelDefinitionError(f"Multisine frequencies: duplicates in {frequencies!r}")
        amp = _range(amplitude, "Multisine amplitude")
        self.frequencies = tuple(float(f) for f in freqs)
        self.peak = float(amp[1] if peak is None else peak)
        if not (np.isfinite(self.peak) and self.peak > 0):
            raise ModelDefinitionError(f"Multisine peak: expected a positive number, got {peak!r}")
        super().__init__(control, {f"amplitude_{f:g}Hz": amp for f in self.frequencies})

    def highest_frequency(self) -> float:
        return max(self.frequencies)

    def _raw(self, a: FloatArray, t: FloatArray) -> FloatArray:
        w = 2.0 * np.pi * np.asarray(self.frequencies)
        ph = schroeder_phases(a**2)
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

    def _scale(self, raw: FloatArray) -> float:
        top = float(np.max(np.abs(raw))) if raw.size else 0.0
        return min(1.0, self.peak / top) if top > 0 else 1.0

    def signal(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        t = np.asarray(time, dtype=np.float64)
        raw = self._raw(self._amplitudes(variables), t)
        return (raw * self._scale(raw))[:, None]

    def canonical(self, variables: ArrayLike, time: ArrayLike) -> FloatArray:
        """The line amplitudes actually flown (after peak limiting)."""
        t = np.asarray(time, dtype=np.float64)
        a = self._amplitudes(variables)
        scale = self._scale(self._raw(a, t))
        s = self._settings(variables)
        scaled = {k: s[k] * scale for k in self._specs}
        return np.array([scaled[k] for k in self._free])

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        t = np.asarray(time, dtype=np.float64)
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


class Chirp(_Family):
    """Linear frequency sweep ``A sin(2π (f0 τ + (f1 - f0) τ² / 2T))`` over the record.

    Parameters
    ----------
    control : str
    f0, f1 : float or (float, float)
        Start and end frequencies in Hz (or their design ranges).
    amplitude : float or (float, float)
        Peak amplitude (or its design range).
    """

    _kind = "chirp"

    def __init__(
        self,
        control: str,
        *,
        f0: float | Range,
        f1: float | Range,
        amplitude: float | Range,
    ) -> None:
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
        t = np.asarray(time, dtype=np.float64)
        tau = t - t[0]
        span = max(float(tau[-1]), 1e-300)
        phase = 2.0 * np.pi * (s["f0"] * tau + 0.5 * (s["f1"] - s["f0"]) * tau**2 / span)
        return (s["amplitude"] * np.sin(phase))[:, None]

    def describe(self, variables: ArrayLike, time: ArrayLike) -> str:
        s = self._settings(variables)
        return (
            f"chirp on {self._control!r}: {fmt(s['f0'], 3)}-{fmt(s['f1'], 3)} Hz sweep, "
            f"amplitude {fmt(s['amplitude'], 3)}"
        )
