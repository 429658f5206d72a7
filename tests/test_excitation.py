"""Excitation and magnitude checks before an estimate (issue 49, part 3)."""

from __future__ import annotations

import numpy as np
import pytest
from _compat_flight import simulated_flight

from aeroid import FlightData, check_compatibility, identify
from aeroid.errors import ChannelError, IdentificationError

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]


def _with(data: FlightData, **channels: np.ndarray) -> FlightData:
    return FlightData(data.time, {**data.channels, **channels})


def test_a_constant_non_zero_control_is_no_excitation(sp_model, sp_noisy):
    held = _with(sp_noisy, elevator=np.full(sp_noisy.n_samples, 0.02))
    with pytest.raises(IdentificationError, match=r"no excitation: .*'elevator' = 0\.02"):
        identify(sp_model, held, NAMES)
    # the same control moving in one manoeuvre of two is excitation (the held record's
    # outputs do not follow its control, so its initial states are held, not fitted)
    fit = identify(sp_model, [held, sp_noisy], NAMES, estimate_x0=False)
    assert fit.success


@pytest.fixture(scope="module")
def flight():
    return simulated_flight(duration=10.0, rate=25.0)


def test_airspeed_off_by_a_unit_factor_is_refused_naming_its_channel(flight):
    for factor in (1000.0, 1e-3):  # mm/s, km/s
        wrong = _with(flight, V=flight.channels["V"] * factor)
        with pytest.raises(ChannelError, match=r"channel 'V' \(airspeed V\): median"):
            check_compatibility(wrong, max_passes=1, n_draws=2)


def test_a_rate_in_degrees_per_second_is_refused_naming_its_channel(flight):
    fast = flight.channels["q"] * 20.0 / np.max(np.abs(flight.channels["q"]))  # 20 rad/s peak
    check = {"max_passes": 1, "n_draws": 2}
    with pytest.raises(ChannelError, match=r"channel 'q' \(q\): reaches 1146"):
        check_compatibility(_with(flight, q=np.rad2deg(fast)), **check)


def test_a_record_without_motion_is_refused_before_the_fit(flight):
    n = flight.n_samples
    still = _with(
        flight,
        **{c: np.zeros(n) for c in ("p", "q", "r", "ax", "ay")},
        az=np.full(n, -9.80665),
    )
    with pytest.raises(IdentificationError, match="no excitation: every rate and acceleration"):
        check_compatibility(still, max_passes=1, n_draws=2)


def test_a_step_from_rest_at_the_first_sample_is_excitation():
    """A control constant from the first sample is a step when the states start away from
    its equilibrium: the transient carries the derivatives (the first-order step response
    behind the sensitivities' closed form), with the start given or estimated."""
    import aeroid

    def roll(t, x, u, p):
        return np.array([p["L_p"] * x[0] + p["L_da"] * u[0]])

    model = aeroid.Model(["p"], ["aileron"], {"L_p": -1.0, "L_da": 5.0}, roll)
    t = np.arange(201) / 50.0
    exact = 12.0 / 2.5 * (1.0 - np.exp(-2.5 * t))  # L_p = -2.5, L_da = 12
    noise = 0.05 * np.random.default_rng(0).standard_normal(t.size)
    record = FlightData(t, {"p": exact + noise, "aileron": np.ones_like(t)})
    for options in ({"x0": [0.0]}, {}):
        fit = identify(model, record, ["L_p", "L_da"], **options)
        for name, truth in (("L_p", -2.5), ("L_da", 12.0)):
            assert abs(fit.parameters[name] - truth) < 4.0 * fit.stderr[name]
    clean = identify(model, FlightData(t, {"p": exact, "aileron": np.ones_like(t)}), ["L_p", "L_da"],
                     x0=[0.0])  # fmt: skip
    assert clean.parameters["L_p"] == pytest.approx(-2.5, rel=1e-4)
    assert clean.parameters["L_da"] == pytest.approx(12.0, rel=1e-4)
