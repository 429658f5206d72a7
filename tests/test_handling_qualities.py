"""Handling-qualities metrics against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import (
    IdentificationError,
    ResponseChannel,
    bandwidth,
    equivalent_system,
    stability_margins,
)


def test_bandwidth_of_integrator_with_delay():
    """K/s e^{-τs}: phase -90 - ωτ; ω_180 = π/(2τ), ω_BW,phase = π/(4τ)."""
    tau = 0.1
    res = bandwidth(([2.0], [1.0, 0.0], tau))
    assert res.omega_180 == pytest.approx(np.pi / (2 * tau), rel=1e-9)
    assert res.bandwidth_phase == pytest.approx(np.pi / (4 * tau), rel=1e-9)
    # gain 6 dB above |H(ω_180)|: K/ω = 10^{6/20} K/ω_180
    assert res.bandwidth_gain == pytest.approx(res.omega_180 / 10 ** (6 / 20), rel=1e-9)
    assert res.bandwidth == pytest.approx(np.pi / (4 * tau), rel=1e-9)
    # φ(2ω_180) = -90 - 180 = -270 deg, so τ_p = 90 / (57.3 · π/τ) = τ/2 for this form
    assert res.phase_delay == pytest.approx(tau / 2, rel=1e-9)


def test_phase_delay_of_lagged_integrator_with_delay():
    """K e^{-τs}/(s(Ts+1)): φ(ω) = -90 - atan(ωT) - ωτ (deg), ω_180 from φ = -180."""
    import scipy.optimize

    t_lag, tau = 0.2, 0.05

    def phase(w):
        return -90.0 - np.degrees(np.arctan(w * t_lag) + w * tau)

    w180 = scipy.optimize.brentq(lambda w: phase(w) + 180.0, 0.1, 100.0, xtol=1e-14)
    res = bandwidth(([1.5], [t_lag, 1.0, 0.0], tau))
    assert res.omega_180 == pytest.approx(w180, rel=1e-9)
    expect = -(phase(2 * w180) + 180.0) / (np.degrees(1.0) * 2 * w180)
    assert res.phase_delay == pytest.approx(expect, rel=1e-9)


def test_bandwidth_of_first_order_attitude_response():
    """K/(s(Ts+1)) never reaches -180: the phase bandwidth 1/T is the bandwidth."""
    t_lag = 0.5
    res = bandwidth(([3.0], [t_lag, 1.0, 0.0]))
    assert res.bandwidth == pytest.approx(1.0 / t_lag, rel=1e-9)
    assert np.isnan(res.omega_180) and np.isnan(res.phase_delay)
    # a rate response q/δ = K/(Ts+1) integrates to the same attitude response
    rate = bandwidth(([3.0], [t_lag, 1.0]), kind="rate")
    assert rate.bandwidth == pytest.approx(1.0 / t_lag, rel=1e-9)
    assert "Bandwidth" in res.summary()


def test_bandwidth_from_tabulated_response_matches_analytic():
    tau = 0.1
    w = np.geomspace(0.5, 40.0, 400)
    ch = ResponseChannel(
        "d", "theta", w, 2.0 / (1j * w) * np.exp(-1j * w * tau), coherence=np.ones(w.size)
    )
    res = bandwidth(ch)
    assert res.bandwidth_phase == pytest.approx(np.pi / (4 * tau), rel=1e-3)
    assert res.phase_delay == pytest.approx(tau / 2, rel=1e-3)


def test_margins_of_third_order_loop():
    """L = K/(s(s+1)(s+2)): ω_180 = √2 and |L(jω_180)| = K/6."""
    k = 3.0
    m = stability_margins(([k], [1.0, 3.0, 2.0, 0.0]))
    assert m.phase_crossover == pytest.approx(np.sqrt(2.0), rel=1e-9)
    assert m.gain_margin == pytest.approx(20 * np.log10(6.0 / k), rel=1e-9)
    # phase margin at the gain crossover, from the closed-form phase
    wc = m.gain_crossover
    assert k / (wc * np.sqrt(wc**2 + 1) * np.sqrt(wc**2 + 4)) == pytest.approx(1.0, rel=1e-9)
    pm = 180 - 90 - np.degrees(np.arctan(wc) + np.arctan(wc / 2))
    assert m.phase_margin == pytest.approx(pm, rel=1e-9)


def test_margins_of_delayed_integrator():
    """L = K/s e^{-τs}: ω_c = K, PM = 90° - Kτ, GM = π/(2τK), delay margin = PM/ω_c."""
    k, tau = 2.0, 0.1
    m = stability_margins(([k], [1.0, 0.0], tau))
    assert m.gain_crossover == pytest.approx(k, rel=1e-9)
    assert m.phase_margin == pytest.approx(90 - np.degrees(k * tau), rel=1e-9)
    assert m.gain_margin == pytest.approx(20 * np.log10(np.pi / (2 * tau * k)), rel=1e-9)
    assert m.delay_margin == pytest.approx(np.radians(m.phase_margin) / k, rel=1e-9)
    assert "Stability margins" in m.summary()


def test_loes_recovers_short_period_form():
    k, inv_t, zeta, omega, tau = 4.0, 1.2, 0.55, 3.5, 0.09
    tf = ([k, k * inv_t], [1.0, 2 * zeta * omega, omega**2], tau)
    fit = equivalent_system(tf, kind="short_period")
    expect = {"K": k, "1/T_theta2": inv_t, "zeta": zeta, "omega": omega, "tau": tau}
    for name, v in expect.items():
        assert fit.parameters[name] == pytest.approx(v, rel=1e-6)
    assert fit.mismatch < 1e-8
    assert "short_period" in fit.summary()


def test_loes_roll_mode_and_mismatch_of_higher_order_system():
    fit = equivalent_system(([5.0], [1.0, 2.0], 0.05), kind="roll")
    assert fit.parameters["K"] == pytest.approx(5.0, rel=1e-6)
    assert fit.parameters["1/T_R"] == pytest.approx(2.0, rel=1e-6)
    # an added actuator lag the form cannot hold: nonzero mismatch, delay absorbs the lag
    hos = ([5.0 * 30.0], np.polymul([1.0, 2.0], [1.0, 30.0]))
    fit = equivalent_system(hos, kind="roll")
    assert fit.mismatch > 1e-4
    assert fit.parameters["tau"] == pytest.approx(1.0 / 30.0, rel=0.2)


def test_bad_inputs_raise():
    with pytest.raises(IdentificationError, match="kind"):
        bandwidth(([1.0], [1.0, 0.0]), kind="pitch")
    with pytest.raises(IdentificationError, match="response_or_tf"):
        bandwidth("not a response")
    with pytest.raises(IdentificationError, match="-135"):
        bandwidth(([1.0], [1.0, 1.0]))
    with pytest.raises(IdentificationError, match="kind"):
        equivalent_system(([1.0], [1.0, 1.0]), kind="phugoid")
    with pytest.raises(IdentificationError, match="frequency_range"):
        equivalent_system(([1.0], [1.0, 1.0]), kind="roll", frequency_range=(0.0, 10.0))


def test_bandwidth_plot_draws_given_boundaries():
    res = bandwidth(([2.0], [1.0, 0.0], 0.1))
    fig = res.plot(boundaries={"Level 1": [(2, 0), (10, 0), (10, 0.1), (2, 0.1)]}, source="user")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "bandwidth ω_BW [rad/s]" and ax.get_ylabel() == "phase delay τ_p [s]"
    with pytest.raises(IdentificationError, match="vertices"):
        res.plot(boundaries={"bad": [(1, 1)]})


# -- input audit ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("tf", "culprit"),
    [
        (([np.nan], [1.0, 3.0, 2.0, 0.0]), "numerator"),
        (([10.0], [np.inf, 3.0, 2.0, 0.0]), "denominator"),
        (([[10.0]], [1.0, 3.0, 2.0, 0.0]), "numerator"),
        (([10.0], [1.0, 3.0, 2.0, 0.0], "0.1"), "response_or_tf"),
        (([10.0], [1.0, 3.0, 2.0, 0.0], True), "response_or_tf"),
    ],
)
def test_margins_refuse_bad_coefficients(tf, culprit):
    with pytest.raises(IdentificationError, match=culprit):
        stability_margins(tf)
    with pytest.raises(IdentificationError, match=culprit):
        bandwidth(tf)


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"delay": "no"}, "delay"),
        ({"delay": 0}, "delay"),
        ({"frequency_range": ("0.1", "10")}, "frequency_range"),
        ({"start": {"b1": "1"}}, r"start\['b1'\]"),
    ],
)
def test_equivalent_system_refuses_bad_options(kwargs, culprit):
    with pytest.raises(IdentificationError, match=culprit):
        equivalent_system(([4.0, 2.0], [1.0, 2.0, 4.0], 0.02), **kwargs)
