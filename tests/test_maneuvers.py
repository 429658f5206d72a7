"""Manoeuvre families and orthogonal phase-optimised multisines."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import ModelDefinitionError
from aeroid.models import catalog
from aeroid.uncertainty.maneuvers import (
    Chirp,
    Doublet,
    ManeuverFamily,
    Multisine,
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


def test_multisine_never_exceeds_its_peak_limit():
    m = Multisine("elevator", frequencies=(0.2, 0.5, 1.0, 1.5), amplitude=(0.0, 0.05))
    u = m.signal([0.05] * 4, T)[:, 0]
    assert np.max(np.abs(u)) == pytest.approx(0.05, rel=1e-12)
    flown = m.canonical([0.05] * 4, T)
    np.testing.assert_allclose(m.signal(flown, T), m.signal([0.05] * 4, T), atol=1e-12)
    assert "peak amplitude 0.05" in m.describe([0.05] * 4, T)


def test_chirp_sweeps_its_band():
    c = Chirp("elevator", f0=0.2, f1=2.0, amplitude=0.1)
    u = c.signal(np.array([]), T)[:, 0]
    assert u[0] == 0.0 and np.max(np.abs(u)) <= 0.1
    # zero crossings = 2 * cycles = 2 * ∫ f dt = 2 * (0.2 + 2.0) / 2 * 10 = 22
    crossings = np.count_nonzero(np.diff(np.signbit(u[1:])))
    assert abs(crossings - 21) <= 1


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
    ],
)
def test_bad_family_definitions_raise(make):
    with pytest.raises(ModelDefinitionError):
        make()


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
