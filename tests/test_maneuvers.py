"""Manoeuvre families and orthogonal phase-optimised multisines."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import aeroid
from aeroid import ModelDefinitionError
from aeroid.models import catalog
from aeroid.uncertainty.maneuvers import (
    Chirp,
    Doublet,
    ManeuverFamily,
    Multisine,
    Multistep,
    orthogonal_multisine,
    relative_peak_factor,
    schroeder_phases,
)

T = np.arange(501) / 50.0


def test_builtins_satisfy_the_protocol():
    fams = [
        Doublet("elevator", amplitude=(0.0, 0.05)),
        Multisine("elevator", frequencies=(0.2, 0.5), amplitude=(0.0, 0.05)),
        Chirp("elevator", f0=0.1, f1=(1.0, 3.0), amplitude=(0.0, 0.05)),
        Chirp("elevator", f0=0.1, f1=(1.0, 3.0), amplitude=(0.0, 0.05), sweep="exponential"),
        Multistep("elevator", amplitude=(0.0, 0.05)),
    ]
    for fam in fams:
        assert isinstance(fam, ManeuverFamily)
        x = fam.initial()
        assert x.shape == (len(fam.variable_names),) == (len(fam.bounds),)
        assert fam.signal(x, T).shape == (T.size, 1)
        assert fam.controls == ("elevator",)
        assert "elevator" in fam.describe(x, T)


def test_fixed_numbers_are_not_variables():
    d = Doublet("elevator", amplitude=(0.01, 0.05), width=1.0, start=1.0)
    assert d.variable_names == ("amplitude",)
    c = Chirp("elevator", f0=0.1, f1=2.0, amplitude=(0.0, 0.1))
    assert c.variable_names == ("amplitude",)


def test_doublet_on_grid_matches_catalog_and_is_balanced():
    d = Doublet("elevator", amplitude=(0.0, 0.1), width=(0.5, 2.0), start=1.0)
    np.testing.assert_allclose(
        d.signal([0.05, 1.0], T)[:, 0],
        catalog.doublet(T, start=1.0, width=1.0, amplitude=0.05),
        atol=1e-12,
    )
    # off-grid widths are area-averaged: zero net area, continuous in the width
    for w in (0.713, 1.237):
        assert abs(d.signal([0.05, w], T).sum()) < 1e-12
    a = d.signal([0.05, 1.0], T)
    b = d.signal([0.05, 1.0 + 1e-6], T)
    assert np.max(np.abs(a - b)) < 1e-4 * 0.05 * 50


def test_schroeder_phases_equal_power_closed_form():
    k = np.arange(1, 9)
    np.testing.assert_allclose(schroeder_phases(np.ones(8)), -np.pi * k * (k - 1) / 8, atol=1e-12)


def test_multisine_is_schroeders_cosine_sum_started_at_a_zero_crossing():
    # ten harmonics of a 20 s period at equal power: Schroeder's phases are for a sum of
    # cosines (his 1970 paper; SIDPAC's mkmsswp), and a shift in time to the first zero
    # crossing keeps the crest and starts the input from trim
    t = np.arange(1000) / 50.0
    f = np.arange(2, 12) / 20.0
    m = Multisine("elevator", frequencies=tuple(f), amplitude=(0.0, 0.05), peak=1.0)
    u = m.signal([0.01] * 10, t)[:, 0]
    assert abs(u[0]) < 1e-6 * np.max(np.abs(u))
    lines = np.abs(np.fft.rfft(u))[np.arange(2, 12)]
    np.testing.assert_allclose(lines, 0.01 * t.size / 2, rtol=1e-9)  # amplitude 0.01 each

    def crest(x: np.ndarray) -> float:
        return float(np.max(np.abs(x)) / np.sqrt(2.0 * np.mean(x**2)))

    arg = 2 * np.pi * f[None, :] * t[:, None] + schroeder_phases(np.ones(10))[None, :]
    assert crest(u) == pytest.approx(crest(np.cos(arg).sum(axis=1)), rel=2e-3)
    assert crest(u) < crest(np.sin(arg).sum(axis=1)) - 0.02


def test_multisine_phases_follow_frequency_order_not_list_order():
    # Schroeder's rule runs over the lines in frequency order: the same twelve lines listed
    # shuffled are the same signal (listed in that order they had a peak factor of 1.84
    # instead of Schroeder's 1.18)
    t = np.arange(1000) / 100.0
    f = np.arange(1, 13) / 10.0
    perm = np.random.default_rng(0).permutation(12)
    a = np.linspace(0.5, 1.0, 12)
    listed = Multisine("e", frequencies=tuple(f), amplitude=(0.0, 1.0), peak=100.0)
    shuffled = Multisine("e", frequencies=tuple(f[perm]), amplitude=(0.0, 1.0), peak=100.0)
    u = listed.signal(a, t)[:, 0]
    np.testing.assert_allclose(shuffled.signal(a[perm], t)[:, 0], u, atol=1e-9)
    flat = listed.signal(np.ones(12), t)[:, 0]
    assert relative_peak_factor(flat) == pytest.approx(1.182, abs=2e-3)


def test_multisine_never_exceeds_its_peak_limit():
    m = Multisine("elevator", frequencies=(0.2, 0.5, 1.0, 1.5), amplitude=(0.0, 0.05))
    u = m.signal([0.05] * 4, T)[:, 0]
    assert np.max(np.abs(u)) == pytest.approx(0.05, rel=1e-12)
    flown = m.canonical([0.05] * 4, T)
    np.testing.assert_allclose(m.signal(flown, T), m.signal([0.05] * 4, T), atol=1e-12)
    assert "peak amplitude 0.05" in m.describe([0.05] * 4, T)


def test_multisine_peak_limit_keeps_every_line_within_its_bounds():
    # the peak limit scaled all lines alike: a line at its lower bound 0.005 was flown at
    # about half of it; now only the excess over the lower bounds shrinks
    t = np.arange(1000) / 50.0  # 20 s: the lines are harmonics of 0.05 Hz
    f = (0.2, 0.5, 0.8, 1.1, 1.4)
    m = Multisine("elevator", frequencies=f, amplitude=(0.005, 0.04), peak=0.06)
    a = [0.04, 0.04, 0.005, 0.005, 0.04]
    u = m.signal(a, t)[:, 0]
    assert np.max(np.abs(u)) <= 0.06 * (1 + 1e-12)
    assert np.max(np.abs(u)) == pytest.approx(0.06, rel=1e-6)  # the limit is reached
    lines = 2 * np.abs(np.fft.rfft(u))[np.round(np.array(f) * 20).astype(int)] / t.size
    np.testing.assert_allclose(lines, m.canonical(a, t), rtol=1e-9)
    assert np.all(lines >= 0.005 * (1 - 1e-9)) and np.all(lines <= 0.04)
    np.testing.assert_allclose(lines[2:4], 0.005, rtol=1e-9)  # the floor lines stay put
    # lower bounds whose lines alone exceed the limit cannot be flown: refused by name
    tight = Multisine("elevator", frequencies=f, amplitude=(0.02, 0.04))
    with pytest.raises(ModelDefinitionError, match=r"lower bound .* above the peak limit"):
        tight.signal([0.04] * 5, t)


def test_chirp_sweeps_its_band():
    c = Chirp("elevator", f0=0.2, f1=2.0, amplitude=0.1)
    u = c.signal(np.array([]), T)[:, 0]
    assert u[0] == 0.0 and np.max(np.abs(u)) <= 0.1
    # zero crossings = 2 * cycles = 2 * ∫ f dt = 2 * (0.2 + 2.0) / 2 * 10 = 22
    crossings = np.count_nonzero(np.diff(np.signbit(u[1:])))
    assert abs(crossings - 21) <= 1


def test_multistep_of_one_one_is_the_doublet():
    # pattern (1, 1) is a doublet: the same samples for edges on and between samples
    m = Multistep(
        "elevator", amplitude=(0.0, 0.1), width=(0.3, 2.0), start=(0.0, 3.0), pattern=(1, 1)
    )
    d = Doublet("elevator", amplitude=(0.0, 0.1), width=(0.3, 2.0), start=(0.0, 3.0))
    assert (m.variable_names, m.bounds) == (d.variable_names, d.bounds)
    for x in ([0.05, 1.0, 1.0], [0.05, 0.713, 1.0], [0.031, 1.237, 0.4567], [0.1, 0.3, 2.99]):
        np.testing.assert_allclose(m.signal(x, T), d.signal(x, T), rtol=0, atol=1e-15)
    assert np.any(m.signal([0.031, 1.237, 0.4567], T) != 0.0)
    # and the same band: a lobe's first spectral null at the smallest width
    assert m.highest_frequency() == d.highest_frequency() == pytest.approx(1.0 / 0.3)


def test_3211_on_the_grid_is_the_textbook_sequence():
    # +A for 3 base steps, -A for 2, +A for 1, -A for 1, from the start sample
    m = Multistep("elevator", amplitude=(0.0, 0.1), width=0.5, start=1.0)
    u = m.signal([0.04], T)[:, 0]
    want = np.zeros(T.size)
    for lo, hi, sign in ((1.0, 2.5, 1), (2.5, 3.5, -1), (3.5, 4.0, 1), (4.0, 4.5, -1)):
        want[(T >= lo - 1e-9) & (T < hi - 1e-9)] = sign * 0.04
    np.testing.assert_allclose(u, want, rtol=0, atol=1e-15)
    assert m.describe([0.04], T) == (
        "3-2-1-1 multistep on 'elevator': amplitude 0.04, 0.5 s base step from t = 1 s"
    )


def _pulse_spectrum(f, amplitude, edges):
    """Fourier transform of alternating rectangular pulses between `edges` (closed form)."""
    out = np.zeros(f.size, dtype=complex)
    for j, (a, b) in enumerate(itertools.pairwise(edges)):
        pulse = (np.exp(-2j * np.pi * f * a) - np.exp(-2j * np.pi * f * b)) / (2j * np.pi * f)
        out += (-1) ** j * amplitude * pulse
    return out


@pytest.mark.parametrize(("width", "start"), [(0.5, 1.0), (0.4837, 1.0123)])
def test_3211_energy_spectrum_is_that_of_its_pulses(width, start):
    # each sample holds a level over its interval [t_k, t_k + dt): the transform of that
    # held signal is sum u_k exp(-iωt_k) (1 - exp(-iω dt)) / iω. With the edges on the
    # grid it is the pulses' transform itself; between samples the held level moves a
    # pulse edge's area within one interval, which changes the transform by at most
    # 2A ω dt² per interior edge (A ω dt² at the two ends)
    dt = 1e-3
    t = np.arange(round(8.0 / dt) + 1) * dt
    amp = 0.05
    m = Multistep("elevator", amplitude=amp, width=(0.1, 1.0), start=start)
    u = m.signal([width], t)[:, 0]
    f = np.linspace(0.01, 3.0, 150)
    w = 2 * np.pi * f
    held = (np.exp(-1j * np.outer(w, t)) @ u) * (1 - np.exp(-1j * w * dt)) / (1j * w)
    edges = start + width * np.array([0.0, 3, 5, 6, 7])
    exact = _pulse_spectrum(f, amp, edges)
    on_grid = width == 0.5
    bound = np.full(f.size, 1e-11 * amp) if on_grid else (2 * 3 + 2) * amp * w * dt**2
    assert np.all(np.abs(held - exact) <= bound)
    # so the energy spectra differ by at most (2 |U| + bound) bound
    energy = np.abs(exact) ** 2
    assert np.all(np.abs(np.abs(held) ** 2 - energy) <= (2 * np.abs(exact) + bound) * bound)
    # the net area, +3 -2 +1 -1 steps, is one base step's: A w, on the grid or not
    assert np.sum(u) * dt == pytest.approx(amp * width, rel=1e-12)
    low = _pulse_spectrum(np.array([1e-6]), amp, edges)[0]  # the spectrum's low end
    assert abs(low) == pytest.approx(amp * width, rel=1e-6)


def test_multistep_band_is_its_shortest_pulse_first_null():
    assert Multistep("e", amplitude=0.1, width=(0.5, 2.0)).highest_frequency() == 2.0
    assert Multistep("e", amplitude=0.1, width=0.25, pattern=(3, 2)).highest_frequency() == 2.0
    # that null: the shortest pulse alone has no energy at 1/w
    f = np.array([1.0 / 0.5])
    assert abs(_pulse_spectrum(f, 1.0, np.array([0.0, 0.5]))[0]) < 1e-15


def _sweep_frequency(u: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Instantaneous frequency of ``u = sin(phase)`` by differencing its phase.

    The phase is c π + θ with c the zero crossings so far and θ = arcsin|u| while
    |u| rises (π - arcsin|u| while it falls); kept where |u| < 0.5 (far from the
    peaks, where the branch is plain) and three neighbours share c.
    """
    c = np.concatenate([[0], np.cumsum(np.signbit(u[2:]) != np.signbit(u[1:-1]))])
    c = np.concatenate([c, [c[-1]]])
    a = np.abs(u)
    rising = np.zeros(u.size, dtype=bool)
    rising[1:-1] = a[2:] > a[:-2]
    phase = c * np.pi + np.where(rising, np.arcsin(np.minimum(a, 1.0)), np.pi - np.arcsin(a))
    n = np.arange(2, u.size - 1)
    ok = (
        (c[n - 1] == c[n])
        & (c[n + 1] == c[n])
        & (a[n - 1] < 0.5)
        & (a[n] < 0.5)
        & (a[n + 1] < 0.5)
        & (rising[n - 1] == rising[n])
        & (rising[n + 1] == rising[n])
    )
    n = n[ok]
    return n, (phase[n + 1] - phase[n - 1]) / (2 * h) / (2 * np.pi)


@pytest.mark.parametrize("sweep", ["linear", "exponential"])
def test_sweep_instantaneous_frequency_follows_its_formula(sweep):
    # unit amplitude on a 0.1 ms grid: the central difference of the phase is exact to
    # h² f''/6f ≈ 3e-10 here, so 1e-6 relative is the formula or a wrong sweep
    h, span, f0, f1 = 1e-4, 10.0, 0.2, 2.0
    t = np.arange(round(span / h) + 1) * h
    u = Chirp("elevator", f0=f0, f1=f1, amplitude=1.0, sweep=sweep).signal(np.array([]), t)[:, 0]
    n, measured = _sweep_frequency(u, h)
    assert n.size > 0.3 * t.size and t[n].max() > 0.99 * span  # the whole sweep is seen
    x = t[n] / span
    if sweep == "linear":
        want = f0 + (f1 - f0) * x
    else:
        # Tischler & Remple: f0 + (f1 - f0) C2 (exp(C1 t/T) - 1), C1 = 4, C2 so K(T) = 1
        want = f0 + (f1 - f0) * (np.exp(4.0 * x) - 1.0) / (np.exp(4.0) - 1.0)
        tischler = f0 + (f1 - f0) * 0.0187 * (np.exp(4.0 * x) - 1.0)  # tabled C2, K(T) = 1.0023
        assert np.max(np.abs(measured / tischler - 1.0)) > 1e-3
    np.testing.assert_allclose(measured, want, rtol=1e-6)


def test_sweeps_are_their_closed_forms():
    t = np.arange(1001) / 100.0
    span, f0, f1, amp = 10.0, 0.3, 2.5, 0.07
    lin = Chirp("elevator", f0=f0, f1=f1, amplitude=amp)
    u = lin.signal(np.array([]), t)[:, 0]
    np.testing.assert_allclose(
        u, amp * np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * span))), rtol=0, atol=1e-14
    )
    # the default is the linear sweep, bit for bit
    same = Chirp("elevator", f0=f0, f1=f1, amplitude=amp, sweep="linear")
    np.testing.assert_array_equal(same.signal(np.array([]), t)[:, 0], u)
    # the exponential sweep's phase: 2π (f0 t + (f1 - f0) C2 (T/C1 (e^{C1 t/T} - 1) - t))
    c1, c2 = 4.0, 1.0 / (np.exp(4.0) - 1.0)
    phase = 2 * np.pi * (f0 * t + (f1 - f0) * c2 * (span / c1 * (np.exp(c1 * t / span) - 1) - t))
    exp = Chirp("elevator", f0=f0, f1=f1, amplitude=amp, sweep="exponential")
    np.testing.assert_allclose(
        exp.signal(np.array([]), t)[:, 0], amp * np.sin(phase), rtol=0, atol=1e-12
    )
    assert "0.3-2.5 Hz exponential sweep" in exp.describe(np.array([]), t)
    assert "0.3-2.5 Hz sweep" in lin.describe(np.array([]), t)
    assert repr(exp).endswith("sweep='exponential')") and "sweep" not in repr(lin)


@pytest.mark.parametrize(
    "make",
    [
        lambda: Doublet("elevator", amplitude=(0.05, 0.01)),
        lambda: Doublet("elevator", amplitude=(0.0, 0.05), width=(-1.0, 1.0)),
        lambda: Doublet("", amplitude=0.05),
        lambda: Multisine("elevator", frequencies=(), amplitude=(0, 1)),
        lambda: Multisine("elevator", frequencies=(0.5, 0.5), amplitude=(0, 1)),
        lambda: Multisine("elevator", frequencies=(-1.0,), amplitude=(0, 1)),
        lambda: Chirp("elevator", f0=0.0, f1=1.0, amplitude=1.0),
        lambda: Chirp("elevator", f0=0.1, f1=1.0, amplitude="big"),
        lambda: Multistep("elevator", amplitude=(0.0, 0.05), width=(0.0, 1.0)),
    ],
)
def test_bad_family_definitions_raise(make):
    with pytest.raises(ModelDefinitionError):
        make()


@pytest.mark.parametrize("pattern", [(), (3, 0), (3, -1), (1.5, 1), (3.0, 2), "3211", (True, 1), 3])
def test_a_bad_multistep_pattern_is_named(pattern):
    with pytest.raises(ModelDefinitionError, match="Multistep pattern"):
        Multistep("elevator", amplitude=0.05, pattern=pattern)


@pytest.mark.parametrize("sweep", ["log", "Linear", None, 1])
def test_an_unknown_sweep_is_named(sweep):
    with pytest.raises(ModelDefinitionError, match="Chirp sweep"):
        Chirp("elevator", f0=0.1, f1=1.0, amplitude=0.05, sweep=sweep)


def test_wrong_number_of_variables_raises():
    d = Doublet("elevator", amplitude=(0.0, 0.05))
    with pytest.raises(ModelDefinitionError, match="2 design variables"):
        d.signal([0.05], T)


# -- orthogonal phase-optimised multisines ----------------------------------------------


@pytest.fixture(scope="module")
def oms():
    return orthogonal_multisine(
        ["elevator", "aileron", "rudder"],
        duration=20.0,
        sample_rate=50.0,
        band=(0.1, 2.0),
        amplitudes=[0.05, 0.1, 0.08],
        seed=0,
    )


def test_orthogonal_inputs_are_uncorrelated_over_the_period(oms):
    s = oms.signals[:-1]  # one period
    gram = s.T @ s
    corr = gram / np.sqrt(np.outer(np.diag(gram), np.diag(gram)))
    np.testing.assert_allclose(corr, np.eye(3), atol=1e-12)
    # and the harmonics are mutually exclusive and inside the band
    sets = [set(h.astype(int)) for h in oms.harmonics]
    assert all(not (sets[i] & sets[j]) for i in range(3) for j in range(i + 1, 3))
    for c in oms.control_names:
        f = oms.frequencies(c)
        assert f.min() >= 0.1 - 1e-12 and f.max() <= 2.0 + 1e-12


def test_orthogonal_inputs_start_and_end_at_zero_within_their_peak(oms):
    np.testing.assert_allclose(oms.signals[0], 0.0, atol=1e-15)
    np.testing.assert_allclose(oms.signals[-1], 0.0, atol=1e-15)
    peaks = np.max(np.abs(oms.signals), axis=0)
    assert np.all(peaks <= np.array([0.05, 0.1, 0.08]) * (1 + 1e-12))
    assert np.all(peaks >= 0.97 * np.array([0.05, 0.1, 0.08]))


def test_phase_optimisation_lowers_the_peak_factor(oms):
    # zero phases pile all 13 cosines up at t = 0: RPF ~ 3; optimised ones stay near 1.1
    assert np.all(oms.zero_phase_peak_factors > 2.0)
    assert np.all(oms.peak_factors < 0.5 * oms.zero_phase_peak_factors)
    assert np.all(oms.peak_factors < 1.3)
    for j in range(3):
        assert oms.peak_factors[j] == pytest.approx(relative_peak_factor(oms.signals[:-1, j]))


def test_orthogonal_multisine_continuous_signal_peaks_at_its_amplitude():
    # a band reaching 0.43 of the sample rate: the 8x grid missed the crest, and the
    # continuous signal peaked 0.33 % above the amplitude; its samples fall 8 % short,
    # as the docstring now says
    om = orthogonal_multisine(["c"], duration=10.0, sample_rate=25.0, band=(1.79, 10.76), seed=0)
    k, ph = om.harmonics[0], om.phases[0]
    tf = np.linspace(0.0, 10.0, 250 * 256 + 1)
    u = om.line_amplitudes[0] * np.cos(2 * np.pi * om.base_frequency * np.outer(tf, k) + ph)
    peak = float(np.max(np.abs(u.sum(axis=1))))
    assert 1.0 - 1e-4 < peak <= 1.0 + 1e-9  # the 256x grid may miss the crest by 1e-4
    assert 0.9 < np.max(np.abs(om.signals)) < 0.93


def test_relative_peak_factor_of_a_sine_is_one():
    t = np.arange(1000) / 1000.0
    assert relative_peak_factor(np.sin(2 * np.pi * 3 * t)) == pytest.approx(1.0, rel=1e-4)


def test_orthogonal_multisine_is_seeded(oms):
    again = orthogonal_multisine(
        ["elevator", "aileron", "rudder"],
        duration=20.0,
        sample_rate=50.0,
        band=(0.1, 2.0),
        amplitudes=[0.05, 0.1, 0.08],
        seed=0,
    )
    np.testing.assert_array_equal(again.signals, oms.signals)
    data = oms.to_flight_data()
    np.testing.assert_array_equal(data["aileron"], oms.signal("aileron"))
    assert "rel. peak factor" in oms.summary()


@pytest.mark.parametrize(
    "kwargs",
    [
        {"band": (1.0, 1.01)},  # no harmonic of 1/20 s inside
        {"band": (2.0, 1.0)},
        {"amplitudes": [0.1, -0.1]},
        {"duration": 20.01},  # not an integer number of samples
    ],
)
def test_orthogonal_multisine_bad_arguments(kwargs):
    args = {"duration": 20.0, "sample_rate": 50.0, "band": (0.1, 2.0), **kwargs}
    with pytest.raises(ModelDefinitionError):
        orthogonal_multisine(["elevator", "aileron"], **args)


@pytest.mark.parametrize(
    "family",
    [
        Doublet("elevator", amplitude=(0.0, 0.1), width=(0.5, 2.0)),
        Multisine("elevator", frequencies=(0.2, 0.5), amplitude=(0.0, 0.1)),
    ],
)
def test_design_variables_that_are_no_finite_numbers_are_named(family):
    n = len(family.variable_names)
    for bad in ([np.nan] * n, ["x"] * n):
        with pytest.raises(ModelDefinitionError, match=r"design variables .* finite numbers"):
            family.signal(bad, T)


@pytest.mark.parametrize(
    "family",
    [
        aeroid.Doublet("u", amplitude=0.1, width=0.5, start=0.0),
        aeroid.Multistep("u", amplitude=0.1, width=0.5, start=0.0),
        aeroid.Multisine("u", frequencies=[0.5, 1.0], amplitude=0.1),
        aeroid.Chirp("u", f0=0.1, f1=1.0, amplitude=0.1),
    ],
    ids=lambda f: type(f).__name__,
)
@pytest.mark.parametrize("time", [[], [0.0], [0.0, 0.0], [0.0, float("nan")], [1.0, 0.5]])
def test_a_signal_on_a_grid_that_is_not_one_is_refused(family, time):
    with pytest.raises(aeroid.DataFormatError, match=f"{type(family).__name__} time"):
        family.signal([], np.array(time))


@pytest.mark.parametrize(
    "make",
    [
        lambda: Doublet("e", amplitude=("0", "1")),
        lambda: Doublet("e", amplitude=(False, True)),
        lambda: Chirp("e", f0=("0.1", "0.5"), f1=1.0, amplitude=1.0),
        lambda: Multisine("e", frequencies="12", amplitude=(0, 1)),
        lambda: Multisine("e", frequencies=["0.5", "1.0"], amplitude=(0, 1)),
        lambda: Multisine("e", frequencies=[True, 2.0], amplitude=(0, 1)),
        lambda: Multisine("e", frequencies=[1.0], amplitude=(0, 1), peak="2"),
        lambda: Multisine("e", frequencies=[1.0], amplitude=(0, 1), peak=True),
        lambda: orthogonal_multisine(["a"], duration="10", sample_rate=50.0, band=(0.1, 2)),
        lambda: orthogonal_multisine(["a"], duration=10.0, sample_rate=50.0, band=("0.1", "2")),
        lambda: orthogonal_multisine(
            ["a"], duration=10.0, sample_rate=50.0, band=(0.1, 2), amplitudes=True
        ),
    ],
    ids=[
        "doublet_text",
        "doublet_bool",
        "chirp_text",
        "ms_text",
        "ms_texts",
        "ms_bool",
        "ms_peak_text",
        "ms_peak_bool",
        "om_duration",
        "om_band",
        "om_amplitude",
    ],
)
def test_text_and_bools_are_no_numbers(make):
    # each was read as a number: ("0", "1") as (0, 1), [True, 2.0] as a 1 Hz line, ...
    with pytest.raises(ModelDefinitionError, match="expected"):
        make()


def test_numbers_in_arrays_still_read():
    assert Doublet("e", amplitude=np.array([0.01, 0.1])).bounds[0] == (0.01, 0.1)
    m = Multisine("e", frequencies=np.array([0.5, 1.0]), amplitude=(0, 1), peak=np.float64(2))
    assert m.frequencies == (0.5, 1.0) and m.peak == 2.0


def test_orthogonal_multisine_without_a_seed_records_the_one_it_drew():
    kw = {"duration": 10.0, "sample_rate": 50.0, "band": (0.1, 2.0)}
    a = orthogonal_multisine(["e", "a"], seed=None, **kw)
    b = orthogonal_multisine(["e", "a"], seed=None, **kw)
    assert isinstance(a.seed, int) and a.seed != b.seed
    again = orthogonal_multisine(["e", "a"], seed=a.seed, **kw)
    np.testing.assert_array_equal(again.signals, a.signals)
