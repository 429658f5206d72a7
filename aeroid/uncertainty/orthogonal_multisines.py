"""Orthogonal phase-optimised multisines (Morelli), and Schroeder's low-peak phases.

`orthogonal_multisine` builds the multi-input excitation of flight-test
practice (Morelli's orthogonal phase-optimised multisines): each control gets
its own, mutually exclusive harmonics of one base period, so the inputs are
uncorrelated over the period; the phases are optimised for a low relative
peak factor and each signal starts and ends at zero. `schroeder_phases` are
the starting phases here and the phases of the single-input `Multisine`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float, plain
from .._records import FrozenState, fmt, frozen_array, markdown_table
from .._value_checks import check_seed, whole_number
from ..errors import ModelDefinitionError
from ..io.data import FlightData

__all__ = [
    "OrthogonalMultisine",
    "orthogonal_multisine",
    "relative_peak_factor",
]

FloatArray = NDArray[np.float64]


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


def _numbers(values: Any, what: str) -> FloatArray:
    """`values` (a number or a flat sequence of them) as floats, else a
    `ModelDefinitionError` naming `what`: text and bools are no numbers, though
    ``float("2")`` and ``float(True)`` would read them as such."""
    if isinstance(values, np.ndarray):
        items = values.ravel().tolist() if values.dtype.kind in "iuf" else [None]
    elif isinstance(values, (str, bytes)) or not isinstance(values, Sequence):
        items = [values]
    else:
        items = list(values)
    out = [as_float(v) for v in items]
    if any(v is None for v in out):
        raise ModelDefinitionError(f"{what}: expected numbers, got {plain(values):.200}")
    return np.array(out, dtype=np.float64)


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


def _crest(harmonics: FloatArray, phases: FloatArray, fine: FloatArray, period: float) -> float:
    """The largest absolute value of the continuous harmonic sum: the crests on the fine
    grid within 2 % of its top, each refined between its neighbours (the grid alone
    misses the true crest by up to a few tenths of a percent)."""
    import scipy.optimize  # here: building a manoeuvre (planning) needs no solver

    a = np.abs(_harmonic_sum(harmonics, phases, fine, period))
    top = float(a.max())
    inner = np.flatnonzero((a[1:-1] >= a[:-2]) & (a[1:-1] >= a[2:]) & (a[1:-1] >= 0.98 * top))
    for i in (inner + 1).tolist():
        res = scipy.optimize.minimize_scalar(
            lambda s: -abs(float(_harmonic_sum(harmonics, phases, np.array([s]), period)[0])),
            bounds=(float(fine[i - 1]), float(fine[i + 1])),
            method="bounded",
            options={"xatol": 1e-10 * period},
        )
        top = max(top, -float(res.fun))
    return top


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
class OrthogonalMultisine(FrozenState):
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
        The seed of the phase optimisation (drawn and recorded when none was
        given): the same seed gives the same signals.
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
        signal (its crests refined between the points of a grid eight times finer
        than the samples), so neither it nor the samples ever exceed it. The
        samples reach it to within a fraction of a percent while the band stays
        well below the Nyquist frequency; a band that nears it puts fewer samples
        on each crest, and their peak can fall several percent short (8 % with a
        band reaching 0.43 of the sample rate). The summary lists the samples'
        peak.
    seed : int, optional
        Seed of the random restarts of the phase optimisation. None draws one
        from the operating system's entropy and records it on the result
        (``.seed``), so that the signal can be repeated.
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
    dur, fs = as_float(duration), as_float(sample_rate)
    if (
        dur is None
        or fs is None
        or not (np.isfinite(dur) and dur > 0 and np.isfinite(fs) and fs > 0)
    ):
        raise ModelDefinitionError(
            f"duration and sample_rate: expected positive numbers, got {duration!r}, "
            f"{sample_rate!r}"
        )
    n = round(dur * fs)
    if n < 8 or abs(n - dur * fs) > 1e-6 * n:
        raise ModelDefinitionError(
            f"duration * sample_rate must be an integer number of samples (>= 8), got {dur * fs:g}"
        )
    edges = _numbers(band, "band")
    if edges.size != 2 or np.ndim(band) != 1:
        raise ModelDefinitionError(f"band: expected (low, high) in Hz, got {band!r}")
    lo, hi = float(edges[0]), float(edges[1])
    if not (0 <= lo < hi):
        raise ModelDefinitionError(f"band: expected 0 <= low < high, got {band!r}")
    if hi > fs / 2.0 * (1.0 + 1e-12):
        raise ModelDefinitionError(
            f"band: its top {hi:g} Hz lies above the Nyquist frequency {fs / 2.0:g} Hz of "
            f"sample_rate {fs:g} Hz; lower the band or raise the sample rate"
        )
    amps = _numbers(amplitudes, "amplitudes")
    if amps.size == 1:
        amps = np.full(len(names), amps[0])
    elif amps.size != len(names) or np.ndim(amplitudes) != 1:
        amps = np.array([np.nan])
    if not np.all(np.isfinite(amps)) or np.any(amps <= 0):
        raise ModelDefinitionError(
            f"amplitudes: expected positive numbers (one or one per control), got {amplitudes!r}"
        )
    iterations = whole_number(n_iterations, "n_iterations", ModelDefinitionError)
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
    if check_seed(seed, ModelDefinitionError) is None:
        # fresh entropy, recorded on the result so that the signal can be repeated
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    rng = np.random.default_rng(seed)
    t = np.arange(n + 1) / fs
    signals = np.empty((n + 1, m))
    harmonics, phases, line_amps, rpfs, rpf0 = [], [], [], [], []
    for j in range(m):
        k = k_all[j::m].astype(np.int64)
        ph = _optimise_phases(k, n, rng, iterations)
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
        # the continuous signal's crest, so the limit holds between samples too
        top = _crest(kf, ph, fine, period)
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
