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


@pytest.mark.parametrize(
    ("num", "den", "kind"),
    [
        ([2.0], [1.0, 0.0], "attitude"),  # K/s: an attitude per rate command
        ([-8.0, -6.4], [1.0, 3.6, 9.0, 0.0], "attitude"),  # pitch attitude per elevator
        ([3.0], [0.5, 1.0], "rate"),  # a rate response, integrated
        ([4.0], [1.0, 1.2, 4.0], "attitude"),  # an attitude command
    ],
)
def test_a_negative_gain_is_read_with_its_sign_reversed(num, den, kind):
    # M_delta < 0 makes theta/delta_e start at +90 deg: the definitions take the response
    # with a positive low-frequency gain, so -H has exactly the bandwidths of H
    tau = 0.08
    plus = bandwidth(([abs(c) for c in num], den, tau), kind=kind)
    minus = bandwidth(([-abs(c) for c in num], den, tau), kind=kind)
    assert not plus.sign_reversed and minus.sign_reversed
    for name in ("bandwidth", "bandwidth_gain", "bandwidth_phase", "omega_180", "phase_delay"):
        assert getattr(minus, name) == pytest.approx(getattr(plus, name), rel=1e-12, nan_ok=True)
    assert "sign reversed" in minus.summary() and "sign reversed" not in plus.summary()
    w = np.geomspace(0.3, 40.0, 300)  # a measured response, its first points noisy
    rng = np.random.default_rng(3)
    h = -np.polyval([abs(c) for c in num], 1j * w) / np.polyval(den, 1j * w)
    h = h * np.exp(-1j * w * tau)
    h = h * (1 + 0.05 * (rng.standard_normal(w.size) + 1j * rng.standard_normal(w.size)))
    measured = bandwidth(ResponseChannel("d", "y", w, h, coherence=np.ones(w.size)), kind=kind)
    assert measured.sign_reversed


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


@pytest.mark.parametrize("delay", [np.nan, np.inf, -np.inf, "0.1", True])
@pytest.mark.parametrize(
    ("fn", "arg"),
    [
        (bandwidth, "response_or_tf"),
        (stability_margins, "loop_response_or_tf"),
        (equivalent_system, "response"),
    ],
)
def test_a_bad_delay_or_zero_denominator_is_named(fn, arg, delay):
    # each function names its own argument and the delay's value, not a generic "got tuple"
    with pytest.raises(IdentificationError, match=rf"^{arg}: the delay .*, got {delay!r}$"):
        fn(([1.0], [1.0, 2.0, 0.0], delay))
    with pytest.raises(IdentificationError, match=rf"^{arg}: the denominator is zero"):
        fn(([1.0], [0.0, 0.0]))


def test_bandwidth_says_when_the_sweep_starts_past_minus_135_deg():
    # 4 e^(-0.05 s) / (s (s + 2)) measured from 2 rad/s: -140.7 deg at the first point,
    # its -135 deg crossing lies below the band
    w = np.geomspace(2.0, 100.0, 200)
    h = 4.0 / ((1j * w) * (1j * w + 2.0)) * np.exp(-0.05j * w)
    with pytest.raises(IdentificationError, match=r"-140\.7 deg.*does not go low enough"):
        bandwidth(ResponseChannel("de", "theta", w, h))
    with pytest.raises(IdentificationError, match="never reaches -135"):
        bandwidth(ResponseChannel("de", "theta", w, 4.0 / (1j * w + 2.0)))


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


# -- global start and standard errors of equivalent systems -----------------------------

# A high-order pitch response (short period, lead-lag, second-order actuator, delay)
# whose fit from the single best linear start ends with a right-half-plane zero.
_HOS_NUM = np.polymul(np.polymul([1.0, 2.229], [1.0 / 7.463, 1.0]), [13.361**2])
_HOS_DEN = np.polymul(
    np.polymul([1.0, 2 * 0.389 * 4.721, 4.721**2], [1.0, 2 * 0.552 * 13.361, 13.361**2]),
    [1.0 / 2.093, 1.0],
)
_HOS = (_HOS_NUM, _HOS_DEN, 0.261)


def test_global_start_leaves_the_right_half_plane_minimum():
    from aeroid import fit_transfer_function
    from aeroid.frequency.handling_qualities import _exact_channel

    ch = _exact_channel(_HOS, (0.1, 10.0))
    single = fit_transfer_function(ch, numerator_order=1, denominator_order=2)
    assert single.parameters["b1"] < 0  # the minimum the single start finds: a RHP zero
    fit = equivalent_system(_HOS)
    assert fit.flags == ()
    assert fit.parameters["1/T_theta2"] > 0 and fit.parameters["tau"] > 0
    assert fit.mismatch < single.cost / 5
    # no start from the short-period mode itself over a grid of delays does better
    for tau in np.linspace(0.0, 0.5, 6):
        start = {"b0": 2.229 * 12.0, "b1": 12.0, "a0": 4.721**2, "a1": 3.7, "tau": tau}
        other = equivalent_system(_HOS, start=start)
        assert fit.mismatch <= other.mismatch * (1 + 1e-6) or other.flags
    # and the optimum is a stationary point: refitting from it stays there
    again = equivalent_system(_HOS, start=dict(fit.fit.parameters))
    assert again.mismatch == pytest.approx(fit.mismatch, rel=1e-6)


def test_rhp_zero_and_negative_delay_are_flagged():
    # an exact non-minimum-phase, advanced response: the fit must reproduce and flag it
    fit = equivalent_system(([2.0, -3.0], [1.0, 2.0, 9.0], -0.05))
    assert fit.parameters["1/T_theta2"] == pytest.approx(-1.5, rel=1e-6)
    assert fit.parameters["tau"] == pytest.approx(-0.05, abs=1e-8)
    assert any("right-half-plane" in f for f in fit.flags)
    assert any("negative time delay" in f for f in fit.flags)
    assert "Warning" in fit.summary()


@pytest.mark.parametrize(
    ("kind", "tf", "expect"),
    [
        ("roll", ([4.0], [1.0, 2.5], 0.08), {"K": 4.0, "1/T_R": 2.5, "tau": 0.08}),
        (
            "dutch_roll",
            ([3.0], [1.0, 2 * 0.2 * 2.2, 2.2**2], 0.05),
            {"K": 3.0, "zeta": 0.2, "omega": 2.2, "tau": 0.05},
        ),
    ],
)
def test_global_start_recovers_other_forms(kind, tf, expect):
    fit = equivalent_system(tf, kind=kind)
    for k, v in expect.items():
        assert fit.parameters[k] == pytest.approx(v, rel=1e-6, abs=1e-9)
    assert set(fit.standard_errors) == set(fit.parameters)
    assert fit.flags == ()


def _record(rng, tf, n=2001, dt=0.02, noise=0.3):
    """A seeded random-step input through `tf` (delay a whole number of samples) plus noise."""
    import scipy.signal

    import aeroid

    num, den, tau = tf
    t = dt * np.arange(n)
    steps = np.repeat(np.random.default_rng(0).standard_normal(n // 25 + 1), 25)[:n]
    u = np.convolve(steps, np.ones(5) / 5, mode="same")
    # at rest at both ends, so the finite Fourier transforms carry no end effects
    u[(t < 1.0) | (t > t[-1] - 10.0)] = 0.0
    lag = round(tau / dt)
    u_late = np.concatenate([np.zeros(lag), u[: n - lag]])
    y = scipy.signal.lsim((num, den), u_late, t)[1]
    y = y + noise * np.std(y) * rng.standard_normal(n)
    return aeroid.FlightData(time=t, channels={"u": u, "y": y})


def test_delta_method_standard_errors_match_monte_carlo():
    """Delta-method SEs of ω, ζ, T_θ2 and τ against the scatter over 40 seeded records."""
    truth = ([2.0, 3.0], [1.0, 2 * 0.6 * 3.0, 9.0], 0.1)
    names = ("omega", "zeta", "T_theta2", "tau")
    draws, ses = [], []
    for seed in range(40):
        fit = equivalent_system(_record(np.random.default_rng(seed), truth), input="u", output="y")
        p = dict(fit.parameters)
        p["T_theta2"] = 1.0 / p["1/T_theta2"]
        draws.append([p[k] for k in names])
        ses.append([fit.standard_errors[k] for k in names])
    spread = np.std(np.asarray(draws), axis=0, ddof=1)
    mean_se = np.mean(np.asarray(ses), axis=0)
    # the sample standard deviation of 40 draws is within ~3/sqrt(2*39) = 34 % of the truth
    np.testing.assert_allclose(mean_se / spread, 1.0, atol=0.34)
    # and the estimates centre on the truth within 4 standard errors of their mean
    centre = np.mean(np.asarray(draws), axis=0)
    np.testing.assert_array_less(
        np.abs(centre - [3.0, 0.6, 2.0 / 3.0, 0.1]), 4 * spread / np.sqrt(40) + 1e-3
    )


def test_record_path_errors_name_the_option():
    import aeroid

    data = _record(np.random.default_rng(0), ([2.0, 3.0], [1.0, 3.6, 9.0], 0.1))
    with pytest.raises(aeroid.ChannelError):
        equivalent_system(data)
    with pytest.raises(IdentificationError, match="frequencies"):
        equivalent_system(([1.0], [1.0, 1.0]), kind="roll", frequencies=[1.0, 2.0])
    fit = equivalent_system(data, input="u", output="y")
    assert np.isnan(fit.mismatch) and "no mismatch J" in fit.summary()
    assert "T_theta2" in fit.summary()


def test_equivalent_system_names_bad_frequencies_and_a_record_without_channels():
    from aeroid import ChannelError, FlightData, IdentificationError, equivalent_system

    fit = equivalent_system(([1.0, 1.0], [1.0, 2.8, 4.0], 0.05))
    for bad in ("a", [np.nan, 1.0], [-1.0, 1.0]):
        with pytest.raises(IdentificationError, match="omega"):
            fit.mismatch_envelopes(bad)
        with pytest.raises(IdentificationError, match="frequency"):
            fit.evaluate(bad)
    with pytest.raises(IdentificationError, match=r"frequency_range: expected .*finite"):
        equivalent_system(([1.0, 1.0], [1.0, 2.8, 4.0], 0.05), frequency_range=(0.1, np.inf))
    t = np.arange(2000) / 100.0
    u = np.sin(0.5 * t * t)
    record = FlightData(t, {"de": u, "q": np.convolve(u, np.ones(5) / 5, mode="same")})
    with pytest.raises(ChannelError, match="input: a record needs the input channel named"):
        equivalent_system(record, output="q")
    with pytest.raises(IdentificationError, match="above the record's Nyquist"):
        equivalent_system(record, input="de", output="q", frequency_range=(0.1, 1000.0))


# -- unstable equivalent systems ---------------------------------------------------------------


def test_unstable_short_period_is_flagged_and_level_3():
    """q/δ = -9 (s + 1.2) e^{-0.02 s} / ((s + 3)(s - 0.5)), M_alpha > 0: a0 = -1.5 < 0, real
    roots -3 and +0.5, so no ω or ζ; Level 3 with ζ and ω beyond its limits, τ Level 1."""
    fit = equivalent_system(([-9.0, -10.8], np.polymul([1.0, 3.0], [1.0, -0.5]), 0.02))
    p = fit.parameters
    assert (p["K"], p["1/T_theta2"]) == pytest.approx((-9.0, 1.2), rel=1e-6)
    assert p["tau"] == pytest.approx(0.02, abs=1e-8)
    assert np.isnan(p["omega"]) and np.isnan(p["zeta"])
    assert len(fit.flags) == 1 and "s = 0.5 >= 0" in fit.flags[0]
    level = fit.level
    assert level is not None and level.level == 3
    assert level.beyond_level_3 == ("zeta", "omega")
    assert level.criteria["tau"] == 1
    assert "s = 0.5" in level.notes[0]
    text = fit.summary()
    assert "Level 3, beyond the Level 3 limits on zeta, omega" in text
    assert "Warning: real denominator roots" in text


def test_degenerate_short_period_fit_summarises():
    """1/(s + 1) in the short-period form: the fit cancels a pole at s > 0 with a
    right-half-plane zero; both are flagged and the summary still reads."""
    fit = equivalent_system(([1.0], [1.0, 1.0]))
    assert len(fit.flags) == 2
    assert "real denominator roots" in fit.flags[0] and "right-half-plane" in fit.flags[1]
    assert fit.level is not None and fit.level.level == 3
    assert "Level 3" in fit.summary()


@pytest.mark.parametrize(
    ("kind", "tf", "pole"),
    [
        ("short_period", ([4.0, 2.0], [1.0, -0.4, 4.0], 0.05), "0.2+1.99j"),
        ("roll", ([5.0], [1.0, -1.0], 0.05), "1+0j"),
    ],
)
def test_unstable_complex_or_roll_pole_is_flagged(kind, tf, pole):
    """s^2 - 0.4 s + 4: ζ = -0.1, poles 0.2 ± 1.99j; 5/(s - 1): 1/T_R = -1."""
    fit = equivalent_system(tf, kind=kind)
    assert any(f"unstable pole (s = {pole}" in f for f in fit.flags)
    if kind == "short_period":
        assert fit.parameters["zeta"] == pytest.approx(-0.1, rel=1e-6)
        assert fit.level is not None and fit.level.level == 3
        assert fit.level.beyond_level_3 == ("zeta",)
    else:
        assert fit.parameters["1/T_R"] == pytest.approx(-1.0, rel=1e-6)
        assert fit.level is None
