"""Gain margins of conditionally stable and open-loop unstable loops.

Every phase crossover counts, the phase rising or falling through -180 deg
(mod 360), and ω = 0 where L(0) is real and negative. The reported gain margin
is the crossover nearest 0 dB (python-control's margin_test.py pins, systems of
Bavafi-Toosi 2015), checked against the closed-loop roots: a gain change a
little short of the margin keeps the loop stable, a little past it does not.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import ResponseChannel, fit_transfer_function, stability_margins

P = np.polymul

# type3: L = (s + 0.1)^2 / (s^3 (s + 1))
TYPE3 = (P([1.0, 0.1], [1.0, 0.1]), P([1.0, 0.0, 0.0, 0.0], [1.0, 1.0]))


def _product(*factors: list[float]) -> np.ndarray:
    out = np.array([1.0])
    for f in factors:
        out = P(out, f)
    return out


# example21 x 1000: one open-loop pole at s = +0.0005
EX21 = (
    1000 * 0.002 * _product([1, 0.02], [1, 0.05], [1, 5], [1, 10]),
    _product([1, -0.0005], [1, 0.0001], [1, 0.01], [1, 0.2], [1, 1], [1, 100], [1, 100]),
)


def _stable(num: np.ndarray, den: np.ndarray, gain: float) -> bool:
    """Whether 1 + gain · num/den = 0 has all its roots in the left half plane."""
    padded = np.zeros(len(den))
    padded[-len(num) :] = num
    return bool(np.roots(den + gain * padded).real.max() < 0)


def _margin_is_the_stability_edge(num: np.ndarray, den: np.ndarray, gm_db: float) -> None:
    """Nominal loop stable; the gain change of `gm_db` (either way) ends stability."""
    edge = 10 ** (gm_db / 20)
    assert _stable(num, den, 1.0)
    assert _stable(num, den, edge ** (1 - 0.01))  # 1 % (in dB) short of the margin
    assert not _stable(num, den, edge ** (1 + 0.01))  # 1 % past it


def test_type3_rising_crossover_against_routh():
    """Closed loop s^4 + s^3 + K(s^2 + 0.2 s + 0.01): the s^1 Routh entry 0.2K - 0.0125
    vanishes at K = 1/16, the s^2 row 0.8K s^2 + 0.01K then gives ω^2 = 0.0125."""
    m = stability_margins(TYPE3)
    assert m.gain_margin == pytest.approx(20 * np.log10(1 / 16), rel=1e-9)
    assert m.phase_crossover == pytest.approx(np.sqrt(0.0125), rel=1e-9)
    assert m.phase_crossovers == pytest.approx((np.sqrt(0.0125),), rel=1e-9)
    # python-control margin_test.py (4 digits)
    assert 10 ** (m.gain_margin / 20) == pytest.approx(0.0626, abs=1.5e-4)
    assert m.phase_margin == pytest.approx(37.1748, abs=1e-3)
    assert m.gain_crossover == pytest.approx(0.7951, abs=1e-4)
    _margin_is_the_stability_edge(*TYPE3, m.gain_margin)


def test_type3_on_a_measured_response_and_a_fit():
    """The same crossover on tabulated points (log-linear between them) and on a
    transfer-function fit of them."""
    w = np.geomspace(0.01, 10.0, 200)
    h = np.polyval(TYPE3[0], 1j * w) / np.polyval(TYPE3[1], 1j * w)
    channel = ResponseChannel("e", "y", w, h, coherence=np.ones(w.size))
    measured = stability_margins(channel)
    # interpolation error over a grid step of 3.5 % in ω: well below 1e-4 rel, 0.01 dB
    assert measured.phase_crossover == pytest.approx(np.sqrt(0.0125), rel=1e-4)
    assert measured.gain_margin == pytest.approx(20 * np.log10(1 / 16), abs=1e-2)
    fit = fit_transfer_function(channel, numerator_order=2, denominator_order=4)
    fitted = stability_margins(fit)
    assert fitted.phase_crossover == pytest.approx(np.sqrt(0.0125), rel=1e-6)
    assert fitted.gain_margin == pytest.approx(20 * np.log10(1 / 16), rel=1e-6)


def test_example21_reports_the_crossover_nearest_0_db():
    m = stability_margins(EX21)
    # python-control margin_test.py: gm 0.1793 at 0.0243 rad/s, pm 22.5215 at 0.0630 (the
    # real-axis crossing is at L = -5.57395, gm 0.179406: within their last digit)
    assert 10 ** (m.gain_margin / 20) == pytest.approx(0.1793, abs=1.5e-4)
    assert m.phase_crossover == pytest.approx(0.0243, abs=1e-4)
    assert m.phase_margin == pytest.approx(22.5215, abs=1e-3)
    assert m.gain_crossover == pytest.approx(0.0630, abs=1e-4)
    # the others: ω = 0 (the open-loop pole at +0.0005) and the upward margin at 0.4385
    assert m.phase_crossovers[0] == 0.0
    assert m.phase_crossovers[2] == pytest.approx(0.4385, abs=1e-4)
    assert m.gain_margins[2] > 27.0
    assert abs(m.gain_margin) == min(abs(g) for g in m.gain_margins)
    _margin_is_the_stability_edge(*EX21, m.gain_margin)
    # the upward margin is real too, but farther
    assert not _stable(*EX21, 10 ** (m.gain_margins[2] * 1.01 / 20))
    assert "Every phase crossover" in m.summary()


@pytest.mark.parametrize(
    ("num", "den", "dc_gain"),
    [([2.0], [1.0, -1.0], -2.0), ([10.0, 20.0], P([1.0, -1.0], [1.0, 5.0]), -4.0)],
)
def test_open_loop_unstable_loop_margin_at_zero_frequency(num, den, dc_gain):
    """2/(s - 1): closed-loop pole 1 - 2K, stable for K > 0.5 only; 10(s + 2)/((s - 1)(s + 5))
    stable for K > 0.25 (python-control and MATLAB: gm 0.5 and 0.25 at ω = 0)."""
    m = stability_margins((num, den))
    assert m.phase_crossover == 0.0
    assert m.gain_margin == pytest.approx(-20 * np.log10(abs(dc_gain)), rel=1e-12)
    _margin_is_the_stability_edge(np.asarray(num), np.asarray(den), m.gain_margin)


def test_a_single_falling_crossover_is_unchanged():
    """K/(s(s+1)(s+2)): the one crossover at √2, GM = 6/K."""
    k = 2.0
    m = stability_margins(([k], [1.0, 3.0, 2.0, 0.0]))
    assert m.phase_crossovers == pytest.approx((np.sqrt(2.0),), rel=1e-9)
    assert m.gain_margins == pytest.approx((20 * np.log10(6.0 / k),), rel=1e-9)
    assert "Every phase crossover" not in m.summary()
