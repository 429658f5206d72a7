"""Manoeuvre families for experiment design, and orthogonal phase-optimised multisines.

A manoeuvre family maps a few design variables (amplitudes, widths,
frequencies) to control histories. `design_experiment` searches the
variables within their bounds; any object with the `ManeuverFamily`
interface works, the built-ins are `Doublet`, `Multisine` (Schroeder 1970
phases) and `Chirp`.

Every family argument given as a number is held fixed; given as a
``(low, high)`` range it becomes a design variable. The upper amplitude bound
is the actuator or safety limit: no built-in family ever exceeds it.

`orthogonal_multisine` builds the multi-input excitation of flight-test
practice (Morelli's orthogonal phase-optimised multisines): each control gets
its own, mutually exclusive harmonics of one base period, so the inputs are
uncorrelated over the period; the phases are optimised for a low relative
peak factor and each signal starts and ends at zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import fmt, frozen_array, markdown_table
from .._value_checks import check_seed
from ..errors import ModelDefinitionError
from ..io.data import FlightData

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


def schroeder_phases(powers: ArrayLike) -> FloatArray:
    """Schroeder (1970) low-peak phases for lines with the given relative powers."""
    p = np.asarray(powers, dtype=np.float64)
    total = float(p.sum())
    if total <= 0:
        return np.zeros(p.size)
    p = p / total
    k = np.arange(1, p.size + 1)
    # φ_k = -2π Σ_{l<k} (k - l) p_l
    cum = np.cumsum(p)
    cum_l = np.cumsum(p * k)
    phases = np.zeros(p.size)
    phases[1:] = -2.0 * np.pi * (k[1:] * cum[:-1] - cum_l[:-1])
    return phases


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


# -- orthogonal phase-optimised multisines ------------------------------------------------


def relative_peak_factor(signal: ArrayLike) -> float:
    """``(max - min) / (2 sqrt(2) rms)``: 1 for a single sinusoid, lower is better."""
    u = np.asarray(signal, dtype=np.float64)
    rms = float(np.sqrt(np.mean(u**2)))
    if rms == 0:
        return float("inf")
    return float((u.max() - u.min()) / (2.0 * math.sqrt(2.0) * rms))


def _harmonic_sum(
    harmonics: FloatArray, phases: FloatArray, t: FloatArray, period: float
) -> FloatArray:
    return np.cos(2.0 * np.pi * np.outer(t, harmonics) / period + phases[None, :]).sum(axis=1)


def _optimise_phases(
    harmonics: NDArray[np.int64], n: int, rng: np.random.Generator, n_iterations: int
) -> FloatArray:
    """Phases of equal-power harmonics k (of an n-sample period) with a low peak factor.

    Iterative clipping: clip the signal's peaks, keep the phases of the
    clipped signal's harmonics, repeat; restarts from Schroeder and random
    phases, and the best relative peak factor wins.
    """
    m = harmonics.size
    best_phases = schroeder_phases(np.ones(m))
    if m == 1:
        return best_phases
    # evaluate on a 4x finer grid than the samples so peaks between samples count
    fine = 4 * n

    def synth(ph: FloatArray) -> FloatArray:
        spec = np.zeros(fine // 2 + 1, dtype=complex)
        spec[harmonics] = np.exp(1j * ph)
        return np.fft.irfft(spec, fine)

    best = relative_peak_factor(synth(best_phases))
    starts = [best_phases] + [rng.uniform(-np.pi, np.pi, m) for _ in range(3)]
    for ph0 in starts:
        ph = ph0.copy()
        level = 0.9
        for _ in range(n_iterations):
            u = synth(ph)
            rpf = relative_peak_factor(u)
            if rpf < best - 1e-12:
                best, best_phases = rpf, ph.copy()
            lim = level * np.max(np.abs(u))
            ph = np.angle(np.fft.rfft(np.clip(u, -lim, lim))[harmonics])
            level = max(0.6, level * 0.995)
    return best_phases


@dataclass(frozen=True, eq=False)
class OrthogonalMultisine:
    """Orthogonal phase-optimised multisine inputs for several controls.

    Attributes
    ----------
    time : ndarray, shape (n_t,)
        One full period, both ends included (the signals are zero at both).
    signals : ndarray, shape (n_t, n_controls)
    control_names : tuple of str
    base_frequency : float
        1 / period (Hz); every line is an integer multiple of it.
    harmonics : tuple of ndarray
        Harmonic numbers per control (mutually exclusive).
    phases : tuple of ndarray
        Cosine phases per control (radians), after the shift that starts the signal at zero.
    line_amplitudes : ndarray, shape (n_controls,)
        Amplitude of each line (flat spectrum per control).
    peak_factors : ndarray, shape (n_controls,)
        Relative peak factor of each optimised signal.
    zero_phase_peak_factors : ndarray, shape (n_controls,)
        The same with all phases zero, for comparison.
    seed : int or None
    """

    time: FloatArray
    signals: FloatArray
    control_names: tuple[str, ...]
    base_frequency: float
    harmonics: tuple[FloatArray, ...]
    phases: tuple[FloatArray, ...]
    line_amplitudes: FloatArray
    peak_factors: FloatArray
    zero_phase_peak_factors: FloatArray
    seed: int | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in (
            "time",
            "signals",
            "line_amplitudes",
            "peak_factors",
            "zero_phase_peak_factors",
        ):
            set_(self, name, frozen_array(getattr(self, name)))
        set_(self, "harmonics", tuple(frozen_array(h) for h in self.harmonics))
        set_(self, "phases", tuple(frozen_array(p) for p in self.phases))
        set_(self, "control_names", tuple(self.control_names))

    def signal(self, control: str) -> FloatArray:
        """History of one control."""
        if control not in self.control_names:
            raise ModelDefinitionError(
                f"control {control!r} not in this multisine; controls: {list(self.control_names)}"
            )
        return self.signals[:, self.control_names.index(control)]

    def frequencies(self, control: str) -> FloatArray:
        """Line frequencies (Hz) of one control."""
        self.signal(control)
        out = self.harmonics[self.control_names.index(control)] * self.base_frequency
        out.setflags(write=False)
        return out

    def to_flight_data(self) -> FlightData:
        """The inputs as a `FlightData` record (one channel per control)."""
        return FlightData(
            self.time,
            {n: self.signals[:, j] for j, n in enumerate(self.control_names)},
            metadata={"maneuver": "orthogonal phase-optimised multisine"},
        )

    def summary(self) -> str:
        """Markdown table: band, line count, peak and relative peak factor per control."""
        rows = []
        for j, n in enumerate(self.control_names):
            f = self.frequencies(n)
            rows.append(
                (
                    n,
                    f.size,
                    f"{fmt(float(f.min()), 3)}–{fmt(float(f.max()), 3)} Hz",
                    fmt(float(np.max(np.abs(self.signals[:, j]))), 3),
                    fmt(float(self.peak_factors[j]), 3),
                    fmt(float(self.zero_phase_peak_factors[j]), 3),
                )
            )
        table = markdown_table(
            ("control", "lines", "band", "peak", "rel. peak factor", "zero-phase RPF"), rows
        )
        period = 1.0 / self.base_frequency
        return (
            f"## Orthogonal multisine\n\n{table}\n\nPeriod {fmt(period)} s "
            f"(base frequency {fmt(self.base_frequency)} Hz); harmonics are mutually "
            "exclusive between controls, so the inputs are uncorrelated over the period."
        )


def orthogonal_multisine(
    controls: Sequence[str] | str,
    *,
    duration: float,
    sample_rate: float,
    band: tuple[float, float],
    amplitudes: float | Sequence[float] = 1.0,
    seed: int | None = 0,
    n_iterations: int = 200,
) -> OrthogonalMultisine:
    """Orthogonal phase-optimised multisines: one excitation per control, flown together.

    Parameters
    ----------
    controls : sequence of str
        Control names; each gets every n-th harmonic of ``1 / duration`` in `band`.
    duration : float
        Period (s); the signals are periodic with it and zero at both ends.
    sample_rate : float
        Hz; ``duration * sample_rate`` must be (close to) an integer.
    band : (float, float)
        Frequency band in Hz (inclusive) from which the harmonics are drawn.
    amplitudes : float or sequence of float
        Peak amplitude per control: the largest absolute value of the continuous
        signal (found on a grid eight times finer than the samples), so the samples
        themselves come within a fraction of a percent of it and never exceed it.
    seed : int, optional
        Seed of the random restarts of the phase optimisation.
    n_iterations : int
        Clipping iterations per restart.

    Returns
    -------
    OrthogonalMultisine

    Raises
    ------
    ModelDefinitionError
        Bad names, band, amplitudes, or too few harmonics in the band.
    """
    names = [controls] if isinstance(controls, str) else list(controls)
    if not names or any(not isinstance(c, str) or not c for c in names):
        raise ModelDefinitionError(f"controls: expected control names, got {controls!r}")
    if len(set(names)) != len(names):
        raise ModelDefinitionError(f"controls: duplicate names in {names}")
    dur = float(duration)
    fs = float(sample_rate)
    if not (np.isfinite(dur) and dur > 0 and np.isfinite(fs) and fs > 0):
        raise ModelDefinitionError(
            f"duration and sample_rate must be positive, got {duration!r}, {sample_rate!r}"
        )
    n = round(dur * fs)
    if n < 8 or abs(n - dur * fs) > 1e-6 * n:
        raise ModelDefinitionError(
            f"duration * sample_rate must be an integer number of samples (>= 8), got {dur * fs:g}"
        )
    try:
        lo, hi = (float(v) for v in band)
    except (TypeError, ValueError):
        raise ModelDefinitionError(f"band: expected (low, high) in Hz, got {band!r}") from None
    if not (0 <= lo < hi):
        raise ModelDefinitionError(f"band: expected 0 <= low < high, got {band!r}")
    amps = np.broadcast_to(np.asarray(amplitudes, dtype=np.float64), (len(names),)).copy()
    if not np.all(np.isfinite(amps)) or np.any(amps <= 0):
        raise ModelDefinitionError(
            f"amplitudes: expected positive numbers (one or one per control), got {amplitudes!r}"
        )
    if int(n_iterations) < 1:
        raise ModelDefinitionError(f"n_iterations: expected >= 1, got {n_iterations!r}")
    period = n / fs
    f_base = 1.0 / period
    k_all = np.arange(max(1, math.ceil(lo / f_base - 1e-9)), math.floor(hi / f_base + 1e-9) + 1)
    k_all = k_all[k_all < n / 2]  # below Nyquist keeps the sampled lines orthogonal
    m = len(names)
    if k_all.size < m:
        raise ModelDefinitionError(
            f"band {band!r} holds {k_all.size} harmonics of 1/{period:g} s; need at least "
            f"one per control ({m}) — widen the band or lengthen the duration"
        )
    rng = np.random.default_rng(check_seed(seed, ModelDefinitionError))
    t = np.arange(n + 1) / fs
    signals = np.empty((n + 1, m))
    harmonics, phases, line_amps, rpfs, rpf0 = [], [], [], [], []
    for j in range(m):
        k = k_all[j::m].astype(np.int64)
        ph = _optimise_phases(k, n, rng, int(n_iterations))
        kf = k.astype(np.float64)

        def u_of(tt: Any, ph: FloatArray = ph, kf: FloatArray = kf) -> Any:
            return _harmonic_sum(kf, ph, np.atleast_1d(tt), period)

        # shift time so the periodic signal starts (and so ends) at an upward zero crossing
        fine = np.linspace(0.0, period, 8 * n + 1)
        uf = u_of(fine)
        ups = np.flatnonzero((uf[:-1] < 0) & (uf[1:] >= 0))
        i0 = int(ups[0]) if ups.size else int(np.argmin(np.abs(uf)))
        if ups.size:
            import scipy.optimize  # here: building a manoeuvre (planning) needs no solver

            tau = scipy.optimize.brentq(
                lambda s: float(u_of(s)[0]), fine[i0], fine[i0 + 1], xtol=1e-14
            )
        else:
            tau = float(fine[i0])
        ph = np.angle(np.exp(1j * (ph + 2.0 * np.pi * kf * tau / period)))
        u = _harmonic_sum(kf, ph, t, period)
        u[0] = u[-1] = 0.0  # remove the last rounding error at the shifted zero crossing
        # peak over a fine grid, so the limit holds between samples too
        top = float(np.max(np.abs(_harmonic_sum(kf, ph, fine, period))))
        scale = amps[j] / max(top, float(np.max(np.abs(u))))
        signals[:, j] = u * scale
        harmonics.append(kf)
        phases.append(ph)
        line_amps.append(scale)
        rpfs.append(relative_peak_factor(u[:-1]))
        rpf0.append(relative_peak_factor(_harmonic_sum(kf, np.zeros(k.size), t[:-1], period)))
    return OrthogonalMultisine(
        time=t,
        signals=signals,
        control_names=tuple(names),
        base_frequency=f_base,
        harmonics=tuple(harmonics),
        phases=tuple(phases),
        line_amplitudes=np.array(line_amps),
        peak_factors=np.array(rpfs),
        zero_phase_peak_factors=np.array(rpf0),
        seed=seed,
    )
