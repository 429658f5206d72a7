"""The start a data-compatibility fit holds (``estimate_x0=False``).

A held initial state is taken from the first samples low-passed at 2 Hz without
leaning on the first sample (`_held_start`, as SIDPAC's ``dcmp`` holds it). On
SIDPAC's HARV flight 153b the vane's jitter moved the start that a 9-sample
cubic gave by a degree of alpha, and the biases that absorbed it by up to 66
of SIDPAC's sigma (the reference suite's ``demo_dcmp``; 2.8 now).
"""

from __future__ import annotations

import numpy as np
import pytest
from _compat_flight import NOISE, simulated_flight, truth

from aeroid import IdentificationError, check_compatibility
from aeroid.estimation._compat_arguments import START_CUTOFF, _held_start

DT = 0.02
N = 700


def _weights(n: int = N, dt: float = DT) -> np.ndarray:
    """The held start is linear in the samples: its weights, one unit sample at a time."""
    return np.array([_held_start(row, dt) for row in np.eye(n)])


def test_the_start_is_linear_with_unit_gain() -> None:
    c = _weights()
    assert c.sum() == pytest.approx(1.0, abs=1e-12)
    y = np.random.default_rng(0).standard_normal(N)
    assert _held_start(3.0 * y + 2.5, DT) == pytest.approx(3.0 * (c @ y) + 2.5, abs=1e-12)
    assert START_CUTOFF == 2.0


def test_white_noise_share_is_under_half_a_sample() -> None:
    """Over 400 seeds the held start of white noise scatters as sqrt(sum c^2) (0.44 of
    one sample's), within the sampling error of a standard deviation, 4 SE."""
    c = _weights()
    expected = float(np.sqrt(c @ c))
    assert expected < 0.5
    rng = np.random.default_rng(1)
    starts = np.array([_held_start(rng.standard_normal(N), DT) for _ in range(400)])
    assert np.std(starts) == pytest.approx(expected, rel=4.0 / np.sqrt(2.0 * 400))
    assert abs(np.mean(starts)) < 4.0 * expected / np.sqrt(400)


@pytest.mark.parametrize("hz", [3.0, 4.0, 6.0])
def test_jitter_above_the_cutoff_is_held_off(hz: float) -> None:
    """A vane jitter of random phase moves the start by at most half its amplitude in
    root mean square (the first raw sample: 0.71 of it)."""
    t = np.arange(N) * DT
    phases = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    moved = np.array([_held_start(np.cos(2.0 * np.pi * hz * t + ph), DT) for ph in phases])
    assert np.sqrt(np.mean(moved**2)) < 0.5


def test_slow_motion_passes() -> None:
    """A ramp is held late by the weights' first moment (2.5 samples at 50 Hz, the lag
    of a one-sided mean); a swing at 0.05, 0.2 and 0.5 Hz to a share of its amplitude
    whatever its phase."""
    c = _weights()
    lag = float(c @ (np.arange(N) * DT))
    assert 0.0 < lag < 3.0 * DT
    t = np.arange(N) * DT
    assert _held_start(1.0 + 0.7 * t, DT) == pytest.approx(1.0 + 0.7 * lag, abs=1e-12)
    for hz, share in ((0.05, 0.02), (0.2, 0.07), (0.5, 0.17)):
        for ph in np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False):
            y = np.cos(2.0 * np.pi * hz * t + ph)
            assert abs(_held_start(y, DT) - y[0]) < share, (hz, ph)


def test_check_compatibility_holds_that_start() -> None:
    """Through `check_compatibility`: each held initial state is the held start of its
    channels (theta, phi directly; u, w from V and alpha), and a channel's noise moves
    it by no more than 4 of the start's own standard deviations."""
    data = simulated_flight(20.0, 50.0, errors={}, seed=4)
    res = check_compatibility(data, estimate=["b_q"], estimate_x0=False, error_bars="white")
    s = res.initial_states
    start = {o: _held_start(np.asarray(data[o]), DT) for o in ("V", "alpha", "theta", "phi")}
    assert s["theta"] == pytest.approx(start["theta"], abs=1e-12)
    assert s["phi"] == pytest.approx(start["phi"], abs=1e-12)
    assert np.arctan2(s["w"], s["u"]) == pytest.approx(start["alpha"], abs=1e-9)
    clean = truth(data.time)
    c = _weights(data.time.size)
    sd = float(np.sqrt(c @ c))
    for o in ("V", "alpha", "theta", "phi"):
        assert abs(start[o] - _held_start(clean[o], DT)) < 4.0 * sd * NOISE[o], o


def test_a_held_start_does_not_absorb_the_errors_it_is_made_of() -> None:
    """A start held at the measured values carries the air-data offsets: estimated with it
    (scale_about='zero'), an airspeed offset of 1.5 m/s came back -0.04 +- 0.01. They are
    refused, by default or by name, naming the ways out, and kept where the start is
    estimated, given, or the offset is the error at the start (scale_about='initial')."""
    errors = {"b_V": 1.5, "b_q": -0.002}
    data = simulated_flight(20.0, 50.0, errors=errors, seed=4)
    with pytest.raises(IdentificationError, match=r"\['b_V', 'b_alpha', .*\(the default set\)"):
        check_compatibility(data, estimate_x0=False)
    with pytest.raises(
        IdentificationError, match=r"estimate: \['b_V'\]: the start of \['u', 'v', 'w'\]"
    ):
        check_compatibility(data, estimate=["b_V", "b_q"], estimate_x0=False)
    held_theta = ["u", "v", "w", "phi", "psi", "h"]
    with pytest.raises(IdentificationError, match=r"\['b_theta'\]: the start of \['theta'\]"):
        check_compatibility(data, estimate=["b_theta", "b_q"], estimate_x0=held_theta)
    tr = truth(data.time[:1])
    a, b, v = tr["alpha"][0], tr["beta"][0], tr["V"][0]
    start = {"u": v * np.cos(a) * np.cos(b), "v": v * np.sin(b), "w": v * np.sin(a) * np.cos(b)}
    given = check_compatibility(data, estimate=["b_V", "b_q"], estimate_x0=False, x0=start)
    assert "b_V" in given.parameters  # a start given is not the measured one
    initial = check_compatibility(
        data, estimate=["b_V", "b_q"], estimate_x0=False, scale_about="initial"
    )
    assert "b_V" in initial.parameters
