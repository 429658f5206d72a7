"""Frequency-domain validation against exact transfer functions."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.signal
from _sidpac_files import sidpac_mat

import aeroid
from aeroid import ChannelError, DataFormatError, FlightData, IdentificationError, Model
from aeroid.frequency.response import FrequencyResponseResult, frequency_response
from aeroid.models import catalog
from aeroid.uncertainty.maneuvers import orthogonal_multisine

TRUTH = dict(catalog.SHORT_PERIOD_TRUTH)


def exact_short_period(f, p=TRUTH):
    """alpha/u = Mδ / ((s - Mq)(s - Zα) - Mα), q/u = (s - Zα) alpha/u."""
    s = 2j * np.pi * np.asarray(f)
    den = (s - p["M_q"]) * (s - p["Z_alpha"]) - p["M_alpha"]
    h_alpha = p["M_delta"] / den
    return {"alpha": h_alpha, "q": (s - p["Z_alpha"]) * h_alpha}


@pytest.fixture(scope="module")
def multisine_record():
    """60 s at 50 Hz: 60 Schroeder sines 0.1-4 Hz of 0.005 rad, catalog noise, seed 0."""
    t = np.arange(3001) / 50.0
    u = catalog.multisine(t, np.linspace(0.1, 4.0, 60), 0.005)
    return catalog.short_period_flight(duration=60.0, elevator=u, seed=0)


def test_empirical_response_matches_exact_short_period(multisine_record):
    res = frequency_response(catalog.short_period(), multisine_record, TRUTH)
    for out in ("alpha", "q"):
        ch = res.channel("elevator", out)
        # the counted frequencies: a coherence from a window's few averages reads high
        # where nothing counts
        good = ch.coherent & (ch.coherence > 0.95)
        assert good.sum() >= (1 if out == "alpha" else 5)
        h = exact_short_period(ch.frequency_hz[good])[out]
        np.testing.assert_allclose(ch.gain[good], np.abs(h), rtol=0.10)
        dphase = np.angle(np.exp(1j * (np.angle(ch.response[good]) - np.angle(h))))
        assert np.max(np.abs(dphase)) < 0.15


def test_exact_model_response_is_the_closed_form(multisine_record):
    res = _quiet_response(  # alpha has no resolved frequency on this record: it warns
        catalog.short_period(), multisine_record, TRUTH, model_response="exact"
    )
    assert res.model_response == "exact"
    for out in ("alpha", "q"):
        ch = res.channel("elevator", out)
        h = exact_short_period(ch.frequency_hz)[out]
        np.testing.assert_allclose(ch.model_gain, np.abs(h), rtol=1e-9)
        np.testing.assert_allclose(
            np.angle(np.exp(1j * (np.angle(ch.model_response) - np.angle(h)))), 0.0, atol=1e-9
        )


def test_mismatch_separates_right_and_wrong_parameters(multisine_record):
    model = catalog.short_period()
    right = frequency_response(model, multisine_record, TRUTH).channel("elevator", "q")
    wrong = frequency_response(model, multisine_record).channel("elevator", "q")  # the guesses
    assert right.mismatch < 0.05
    assert wrong.mismatch > 3 * right.mismatch
    assert right.n_coherent == int(right.coherent.sum()) > 5
    # counted: coherent beyond the threshold, and resolved by the window
    assert np.all(right.coherence[right.coherent] >= 0.6)


def test_result_record_and_summary(multisine_record):
    res = frequency_response(
        catalog.short_period(), multisine_record, TRUTH, frequency_range=(0.2, 3.0)
    )
    assert isinstance(res, FrequencyResponseResult)
    assert res.model_response == "simulated"
    ch = res.channel("elevator", "alpha")
    assert ch.frequency_hz.min() >= 0.2 and ch.frequency_hz.max() <= 3.0
    with pytest.raises(ValueError):
        ch.response[0] = 0.0
    text = res.summary()
    assert "elevator" in text and "mismatch" in text and "Welch" in text
    with pytest.raises(ChannelError, match="rudder"):
        res.channel("rudder", "q")


def test_two_inputs_conditioned_estimate():
    # y' = -a y + b1 u1 + b2 u2, excited by orthogonal multisines on both inputs:
    # the conditioned estimate recovers H_i = b_i / (s + a) for each input.
    a, b1, b2 = 2.0, 1.5, -0.7
    model = Model(
        states=["y"],
        controls=["u1", "u2"],
        parameters={"a": a, "b1": b1, "b2": b2},
        dynamics=lambda t, x, u, p: np.array([-p["a"] * x[0] + p["b1"] * u[0] + p["b2"] * u[1]]),
    )
    om = orthogonal_multisine(
        ["u1", "u2"], duration=20.0, sample_rate=50.0, band=(0.1, 3.0), amplitudes=1.0, seed=0
    )
    t = np.concatenate([om.time[:-1] + 20.0 * k for k in range(4)])
    u = np.tile(om.signals[:-1], (4, 1))
    y = model.simulate(t, u, [0.0], method="exact").output("y")
    y = y + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    data = FlightData(t, {"u1": u[:, 0], "u2": u[:, 1], "y": y})
    res = frequency_response(model, data, nperseg=500, frequency_range=(0.2, 2.8))
    for name, b in (("u1", b1), ("u2", b2)):
        ch = res.channel(name, "y")
        good = ch.coherence > 0.95
        assert good.sum() >= 5
        h = b / (2j * np.pi * ch.frequency_hz[good] + a)
        np.testing.assert_allclose(ch.gain[good], np.abs(h), rtol=0.1)
        assert (
            np.max(np.abs(np.angle(np.exp(1j * (np.angle(ch.response[good]) - np.angle(h))))))
            < 0.15
        )


def test_too_few_coherent_frequencies_warn(multisine_record):
    with pytest.warns(UserWarning, match="too few coherent"):
        res = frequency_response(
            catalog.short_period(), multisine_record, TRUTH, coherence_threshold=0.9999
        )
    assert res.channel("elevator", "alpha").n_coherent < 3


def test_no_warning_on_a_well_excited_record(multisine_record):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frequency_response(catalog.short_period(), multisine_record, TRUTH, outputs=["q"])


def test_unexcited_frequencies_are_not_coherent(multisine_record):
    # above 4 Hz the input has only window leakage: never counted as coherent
    ch = frequency_response(catalog.short_period(), multisine_record, TRUTH).channel(
        "elevator", "q"
    )
    assert not np.any(ch.coherent & (ch.frequency_hz > 4.5))


def test_non_uniform_time_grid_rejected(sp_noisy):
    t = sp_noisy.time.copy()
    t[10] += 0.005
    data = FlightData(t, dict(sp_noisy.channels))
    with pytest.raises(DataFormatError, match="uniform"):
        frequency_response(catalog.short_period(), data)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"inputs": ["rudder"]}, ChannelError, "rudder"),
        ({"outputs": ["nz"]}, ChannelError, "nz"),
        ({"coherence_threshold": 1.5}, IdentificationError, "coherence_threshold"),
        ({"frequency_range": (3.0, 1.0)}, IdentificationError, "frequency_range"),
        ({"nperseg": 4}, IdentificationError, "nperseg"),
        ({"model_response": "analytic"}, IdentificationError, "model_response"),
    ],
)
def test_bad_arguments_raise(sp_noisy, kwargs, error, match):
    with pytest.raises(error, match=match):
        frequency_response(catalog.short_period(), sp_noisy, **kwargs)


def test_exact_response_needs_a_linear_model(sp_noisy):
    model = Model(
        states=["alpha", "q"],
        controls=["elevator"],
        parameters=dict(TRUTH),
        dynamics=lambda t, x, u, p: np.array(
            [
                p["Z_alpha"] * x[0] + x[1],
                p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0] + 0.5 * x[0] ** 3,
            ]
        ),
    )
    with pytest.raises(IdentificationError, match="linear"):
        frequency_response(model, sp_noisy, model_response="exact")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a 10 s doublet excites alpha little
        res = frequency_response(model, sp_noisy)  # simulated works for any model
        auto = frequency_response(model, sp_noisy, model_response="auto")
        linear = frequency_response(catalog.short_period(), sp_noisy, model_response="auto")
    assert res.model_response == "simulated"
    # auto: exact where the model is linear time-invariant, else linearised at the
    # record's first sample: M_alpha gains d(0.5 alpha^3)/d alpha = 1.5 alpha_0^2 there
    assert linear.model_response == "exact"
    assert auto.model_response == "linearised"
    alpha0 = float(sp_noisy["alpha"][0])
    at_trim = {**TRUTH, "M_alpha": TRUTH["M_alpha"] + 1.5 * alpha0**2}
    for out in ("alpha", "q"):
        ch = auto.channel("elevator", out)
        h = exact_short_period(ch.frequency_hz, at_trim)[out]
        np.testing.assert_allclose(ch.model_gain, np.abs(h), rtol=1e-6)
        np.testing.assert_allclose(
            np.angle(np.exp(1j * (np.angle(ch.model_response) - np.angle(h)))), 0, atol=1e-6
        )
    # about a state where the cubic term matters, the linearisation moves with it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # as above: few coherent frequencies
        far = frequency_response(
            model, sp_noisy, model_response="auto", x0={"alpha": 1.0, "q": 0.0}
        )

    h = exact_short_period(
        far.channel("elevator", "q").frequency_hz, {**TRUTH, "M_alpha": TRUTH["M_alpha"] + 1.5}
    )["q"]
    np.testing.assert_allclose(far.channel("elevator", "q").model_gain, np.abs(h), rtol=1e-6)


# -- which frequencies count ----------------------------------------------------------------


def _relative_error(ch):
    """|Ĥ - H| / |H| per frequency, from a channel's magnitudes and phases."""
    he = ch.response
    hm = ch.model_response
    return np.abs(he - hm) / np.abs(hm)


def _quiet_response(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return frequency_response(*args, **kwargs)


def test_doublet_flight_averages_and_chance_threshold():
    # 501 samples in 128-sample segments: six half-overlapping Hann segments, whose
    # overlap correlation is 1/6, worth 6 / (1 + 2 (5/6) / 36) = 5.73 independent ones
    # (Welch 1967); 63 frequencies from 0.78 Hz to Nyquist
    res = _quiet_response(
        catalog.short_period(), catalog.short_period_flight(seed=0), TRUTH, nperseg=128
    )
    _, _, seg = scipy.signal.spectrogram(np.zeros(501), nperseg=128, noverlap=64)
    assert seg.shape[-1] == 6
    assert res.n_averages == pytest.approx(6 / (1 + 2 * (5 / 6) / 36), rel=1e-12)
    assert res.n_averages == pytest.approx(5.73, abs=0.005)
    n_f = res.channel("elevator", "q").frequency.size
    assert n_f == 63
    assert res.coherence_threshold == pytest.approx(
        1 - (0.01 / n_f) ** (1 / (res.n_averages - 1)), rel=1e-12
    )
    assert res.coherence_threshold == pytest.approx(0.842, abs=0.001)
    text = res.summary()
    assert "0.842" in text and "5.73 independent averages" in text and "1/20" in text


def test_a_short_doublet_resolves_no_frequency_and_says_so():
    # The audit: γ² ≥ 0.6 alone counted chance frequencies and gave the true model a
    # mismatch of 2.36, 2.50 and 0.94 on seeds 0-2; beating chance and the input's
    # 13 dB band then left the doublet's 0.78 and 1.56 Hz. On the noise-free flight
    # those two estimates are 63 % and 9 % off the true response: 2.56 s segments
    # cannot resolve it, so no frequency counts and the flight warns.
    model = catalog.short_period(TRUTH)
    for seed in range(3):
        data = catalog.short_period_flight(seed=seed)
        with pytest.warns(UserWarning, match="not resolved by any window"):
            ch = frequency_response(model, data, TRUTH, nperseg=128).channel("elevator", "q")
        # at most the 1.56 Hz bin, whose bias on the true model is under a tenth
        assert ch.n_coherent <= 1
        old = ch.coherence >= 0.6
        rel = _relative_error(ch)
        before = np.sum(ch.coherence[old] * rel[old]) / np.sum(ch.coherence[old])
        assert before == pytest.approx([2.36, 2.50, 0.94][seed], abs=0.01)
    clean = catalog.short_period_flight(seed=0)
    sim = model.simulate(clean.time, clean.array(["elevator"]), method="exact")
    clean = FlightData(clean.time, {"elevator": clean["elevator"], "q": sim.output("q").copy()})
    ch = _quiet_response(model, clean, TRUTH, outputs=["q"], nperseg=128).channel("elevator", "q")
    h = exact_short_period(ch.frequency_hz)["q"]
    rel = np.abs(ch.response - h) / np.abs(h)
    at = np.isin(ch.frequency_hz, [0.78125, 1.5625])
    assert np.all(ch.coherence[at] > 0.9) and np.all(rel[at] > 0.09)
    assert not ch.coherent[np.isclose(ch.frequency_hz, 0.78125)].any()  # 63 % off
    assert np.all(rel[ch.coherent] < 0.10)


def test_wrong_model_is_flagged_on_the_multisine_flight():
    # A 30 % gain error shows at every counted frequency. M_alpha moves q near the
    # 0.48 Hz short period, which half-record windows resolve (Tischler's longest):
    # the default twelfth counts q only above 2 Hz, where M_alpha barely shows.
    model = catalog.short_period()
    t = np.arange(3001) / 50.0
    u = catalog.multisine(t, np.linspace(0.1, 4.0, 60), 0.005)
    cases = [(None, "M_delta", 0.7), (1500, "M_alpha", 0.7), (1500, "M_alpha", 1.3)]
    for seed in range(3):
        data = catalog.short_period_flight(duration=60.0, elevator=u, seed=seed)
        for nperseg, name, factor in cases:
            kw = {"nperseg": nperseg, "outputs": ["q"]}
            true = _quiet_response(model, data, TRUTH, **kw)
            assert true.mismatch < 0.07
            wrong = _quiet_response(model, data, {**TRUTH, name: factor * TRUTH[name]}, **kw)
            assert wrong.mismatch > true.mismatch + 0.05, (seed, nperseg, name, factor)


def _noise_outputs_model(n_outputs):
    names = [f"y{k}" for k in range(n_outputs)]
    return names, Model(
        states=names,
        controls=["u"],
        parameters={"a": 1.0},
        dynamics=lambda t, x, u, p: -p["a"] * x + u[0],
    )


def test_noise_alone_passes_the_raised_threshold_rarely():
    # White input, outputs of pure noise (true coherence zero), six averages as on a
    # 10 s record. Per frequency the chance tail lies between that of 6 and of the
    # 5.73 independent averages, about 1.2 % above 0.6; per channel the raised
    # threshold is passed with at most 1 % chance.
    rng = np.random.default_rng(7)
    names, model = _noise_outputs_model(20)
    t = np.arange(501) / 50.0
    coh, hit = [], []
    for _ in range(30):
        data = FlightData(
            t, {"u": rng.standard_normal(t.size)} | {y: rng.standard_normal(t.size) for y in names}
        )
        res = _quiet_response(model, data, model_response="exact", nperseg=128)
        coh += [c.coherence for c in res.channels]
        hit += [c.n_coherent > 0 for c in res.channels]
    g = np.concatenate(coh)
    n = g.size  # 37 800 frequencies, 600 channels
    k, n_d = 6, res.n_averages
    for c in (0.5, 0.6):
        rate = np.mean(g >= c)
        # 5 binomial standard deviations: neighbouring Hann bins are correlated
        tol = 5 * np.sqrt(rate * (1 - rate) / n)
        assert (1 - c) ** (k - 1) - tol < rate < (1 - c) ** (n_d - 1) + tol
    assert 0.010 < np.mean(g >= 0.6) < 0.014
    # 600 channels at a 1 % family-wise level (3 to 9 over 12 generator seeds):
    # P(more than 16) = 1.6e-4
    assert sum(hit) <= 16
    # the unraised threshold: noise passes it somewhere in half of the channels
    assert 0.4 < np.mean([np.any(c >= 0.6) for c in coh]) < 0.6


def test_partial_coherence_chance_level_counts_the_conditioning_inputs():
    # two white inputs, noise output: the partial coherence given the other input has
    # one degree of freedom fewer, (1 - c)^(n_d - 2)
    rng = np.random.default_rng(8)
    model = Model(
        states=["y"],
        controls=["u1", "u2"],
        parameters={"a": 2.0},
        dynamics=lambda t, x, u, p: np.array([-p["a"] * x[0] + u[0] + u[1]]),
    )
    t = np.arange(501) / 50.0
    coh = []
    for _ in range(150):
        data = FlightData(t, {name: rng.standard_normal(t.size) for name in ("u1", "u2", "y")})
        res = _quiet_response(model, data, model_response="exact", nperseg=128)
        coh += [c.coherence for c in res.channels]
    g = np.concatenate(coh)
    rate = np.mean(g >= 0.6)
    tol = 5 * np.sqrt(rate * (1 - rate) / g.size)
    assert 0.4**4 - tol < rate < 0.4 ** (res.n_averages - 2) + tol
    assert rate > 2 * 0.4 ** (res.n_averages - 1)  # the single-input level would let it in
    assert res.coherence_threshold == pytest.approx(
        1 - (0.01 / 63) ** (1 / (res.n_averages - 2)), rel=1e-12
    )


def test_weakly_excited_frequencies_do_not_count():
    # Seed 0: the doublet's third side lobe (3.5 Hz) beats the chance level, but the
    # input there is 17 dB below its peak and the estimate is off by 1.4.
    data = catalog.short_period_flight(seed=0)
    res = _quiet_response(catalog.short_period(), data, TRUTH, nperseg=128)
    ch = res.channel("elevator", "q")
    i = int(np.argmin(np.abs(ch.frequency_hz - 3.52)))
    assert ch.coherence[i] >= res.coherence_threshold
    assert not ch.coherent[i]
    assert _relative_error(ch)[i] == pytest.approx(1.36, abs=0.01)
    f, puu = scipy.signal.welch(data["elevator"], fs=50.0, nperseg=res.nperseg)
    rel_input = np.interp(ch.frequency_hz, f, puu / puu.max())
    assert 10 * np.log10(rel_input[i]) == pytest.approx(-17.4, abs=0.1)
    for seed in range(20):  # the same doublet on every seed: rel_input holds for all
        data = catalog.short_period_flight(seed=seed)
        for c in _quiet_response(catalog.short_period(), data, TRUTH, nperseg=128).channels:
            assert np.all(rel_input[c.coherent] >= 0.05)
            assert np.all(c.frequency_hz[c.coherent] < 2.0)  # inside the second null


def test_doublet_side_lobes_straddle_the_excitation_fraction():
    # A twentieth of the peak (-13 dB) keeps a doublet's main lobe and first side lobe
    # and drops the second: its energy spectrum, sin⁴(π f w) / f², has side lobes
    # 10.6, 15.1 and 18.0 dB down.
    fs = 1000.0
    t = np.arange(round(400 * fs)) / fs
    e = np.abs(np.fft.rfft(catalog.doublet(t, start=1.0, width=1.0))) ** 2
    f = np.fft.rfftfreq(t.size, 1 / fs)
    peaks = scipy.signal.argrelmax(e)[0]
    peaks = peaks[f[peaks] < 4.0]
    db = 10 * np.log10(e[peaks] / e.max())
    np.testing.assert_allclose(f[peaks], [0.37, 1.47, 2.48, 3.49], atol=0.01)
    np.testing.assert_allclose(db, [0.0, -10.6, -15.1, -18.0], atol=0.05)
    assert db[1] > 10 * np.log10(0.05) > db[2]


def test_a_single_segment_counts_nothing(multisine_record):
    # one Welch segment: the coherence is 1 by construction and says nothing
    n = multisine_record.n_samples
    with pytest.warns(UserWarning, match="too few coherent"):
        res = frequency_response(catalog.short_period(), multisine_record, TRUTH, nperseg=n)
    assert res.n_averages == 1.0
    assert all(c.n_coherent == 0 for c in res.channels)
    assert all(np.isnan(c.mismatch) for c in res.channels)


def _noise_free_multisine(model, duration=60.0):
    """The multisine fixture's input (60 Schroeder sines 0.1-4 Hz) without noise."""
    t = np.arange(round(duration * 50.0) + 1) / 50.0
    u = catalog.multisine(t, np.linspace(0.1, 4.0, 60), 0.005)
    sim = model.simulate(t, u, method="exact")
    return FlightData(
        t, {model.controls[0]: u} | {o: sim.output(o).copy() for o in model.output_names}
    )


def _second_order(wn, zeta):
    model = Model(
        states=["y", "v"],
        controls=["u"],
        parameters={"wn": wn, "zeta": zeta},
        dynamics=lambda t, x, u, p: np.array(
            [x[1], p["wn"] ** 2 * (u[0] - x[0]) - 2 * p["zeta"] * p["wn"] * x[1]]
        ),
        outputs=["y"],
        measurement=lambda t, x, u, p: np.array([x[0]]),
        name="oscillator",
    )

    def exact(f):
        s = 2j * np.pi * np.asarray(f)
        return {"y": wn**2 / (s**2 + 2 * zeta * wn * s + wn**2)}

    return model, exact


@pytest.mark.parametrize(
    "system", ["short period", "lag", "oscillator (zeta 0.1)", "short period, 120 s"]
)
def test_exact_mode_counts_only_frequencies_within_10_percent_of_the_transfer_function(system):
    # Noise-free records: every counted frequency's estimate within 10 % of the closed
    # form. The coherence alone counted bins 10-40 % off (the window averages the
    # response over neighbouring bins, and leaks a spectral line into the next bin).
    duration = 120.0 if "120" in system else 60.0
    if system.startswith("short period"):
        model, exact = catalog.short_period(TRUTH), exact_short_period
    elif system == "lag":
        model = catalog.first_order(K=2.0, tau=0.5)

        def exact(f):
            return {"y": 2.0 / (1.0 + 2j * np.pi * np.asarray(f) * 0.5)}
    else:
        model, exact = _second_order(2 * np.pi * 1.0, 0.1)
    data = _noise_free_multisine(model, duration)
    res = _quiet_response(model, data, None, model_response="exact")
    counted, worst_before = 0, 0.0
    for ch in res.channels:
        h = exact(ch.frequency_hz)[ch.output_name]
        rel = np.abs(ch.response - h) / np.abs(h)
        np.testing.assert_allclose(ch.model_gain, np.abs(h), rtol=1e-9)
        assert np.all(rel[ch.coherent] < 0.10), (ch.output_name, ch.frequency_hz[ch.coherent])
        counted += ch.n_coherent
        # what the coherence and excitation rules alone counted
        excited = (ch.coherence >= res.coherence_threshold) & (ch.frequency_hz < 4.5)
        worst_before = max(worst_before, float(np.max(rel[excited])))
    assert counted >= 3  # the default min_coherent: still enough to judge a model
    assert worst_before > 0.09


def test_noise_free_multisine_band_resolves_many_frequencies():
    # The case: a noise-free 60 s multisine (60 lines 0.1-4 Hz, 0.005 rad,
    # 50 Hz) through the short period, band 0.2-3 Hz. One 5 s window resolved no q
    # frequency; windows of several periods of the band's low end resolve the band.
    model = catalog.short_period(TRUTH)
    data = _noise_free_multisine(model)
    for how in ("exact", "simulated"):
        res = _quiet_response(model, data, None, model_response=how, frequency_range=(0.2, 3.0))
        assert res.model_response == how
        # several windows, none of a single segment (coherence 1 by construction)
        assert len(res.windows) > 1 and min(res.window_averages) > 2.5
        for ch in res.channels:
            assert 0.2 <= ch.frequency_hz[0] < 0.2 + 50.0 / data.n_samples
            assert ch.frequency_hz[-1] <= 3.0
            h = exact_short_period(ch.frequency_hz)[ch.output_name]
            rel = np.abs(ch.response - h) / np.abs(h)
            # counted: the window's bias on the model's own response within 10 %
            assert np.all(rel[ch.coherent] < 0.10)
            good = ch.coherent & (ch.coherence > 0.95)
            assert good.sum() > 5
            np.testing.assert_allclose(ch.gain[good], np.abs(h[good]), rtol=0.10)
            assert np.max(np.abs(np.angle(ch.response[good] / h[good]))) < 0.15
    q = res.channel("elevator", "q")
    assert q.n_coherent > 5 and q.mismatch < 0.05
    # a 50 % M_alpha error: more than three times the true model's mismatch (the default,
    # simulated response shares the estimator's bias; the exact one carries it, up to
    # the 10 % a counted frequency allows)
    wrong = {**TRUTH, "M_alpha": 1.5 * TRUTH["M_alpha"]}
    kw = {"frequency_range": (0.2, 3.0), "outputs": ["q"]}
    right = _quiet_response(model, data, TRUTH, **kw).channel("elevator", "q")
    off = _quiet_response(model, data, wrong, **kw).channel("elevator", "q")
    assert right.mismatch < 0.05 and off.mismatch > 3 * right.mismatch
    kw["model_response"] = "exact"
    right = _quiet_response(model, data, TRUTH, **kw).channel("elevator", "q")
    off = _quiet_response(model, data, wrong, **kw).channel("elevator", "q")
    assert right.mismatch < 0.05 and off.mismatch > 2 * right.mismatch
    # each frequency's window holds at least two periods of it
    assert np.all(q.frequency_hz[q.coherent] * q.window[q.coherent] / data.sample_rate >= 2.0)


@pytest.mark.parametrize(("n_t", "nperseg"), [(1501, 256), (1000, 255), (64, 64), (100, 8)])
def test_spectral_matrix_matches_scipy_csd(n_t: int, nperseg: int) -> None:
    """The numpy Welch cross-spectra equal `scipy.signal.csd` with the defaults used."""
    from aeroid.frequency.response import _spectral_matrix

    x = np.random.default_rng(n_t).standard_normal((4, n_t)) + 3.0
    f0, s0 = scipy.signal.csd(
        x[:, None, :],
        x[None, :, :],
        fs=50.0,
        nperseg=nperseg,
        window="hann",
        detrend="constant",
        axis=-1,
    )
    f1, s1 = _spectral_matrix(x, 50.0, nperseg)
    assert np.array_equal(f0, f1)
    s0 = np.moveaxis(s0, -1, 0)
    assert s1.shape == s0.shape
    assert np.abs(s1 - s0).max() <= 1e-12 * np.abs(s0).max()


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"coherence_threshold": "0.5"}, IdentificationError, "coherence_threshold"),
        ({"coherence_threshold": True}, IdentificationError, "coherence_threshold"),
        ({"coherence_threshold": [0.5]}, IdentificationError, "coherence_threshold"),
        ({"frequency_range": ("0.1", "2")}, IdentificationError, "frequency_range"),
        ({"frequency_range": (100.0, 200.0)}, IdentificationError, "frequency_range"),
        ({"min_coherent": "3"}, IdentificationError, "min_coherent"),
        ({"min_coherent": True}, IdentificationError, "min_coherent"),
        ({"nperseg": float("nan")}, IdentificationError, "nperseg"),
        ({"outputs": []}, ChannelError, "outputs"),
    ],
)
def test_bad_option_values_name_the_culprit(sp_noisy, kwargs, error, match):
    with pytest.raises(error, match=match):
        frequency_response(catalog.short_period(), sp_noisy, **kwargs)


def _with_noise(data, outputs, sigma, seed):
    rng = np.random.default_rng(seed)
    return data.with_channels(
        {o: data[o] + sigma * rng.standard_normal(data.n_samples) for o in outputs}
    )


def test_noise_lowers_the_coherence():
    model = catalog.short_period(TRUTH)
    clean = _noise_free_multisine(model)
    band = {"frequency_range": (0.2, 3.0), "nperseg": 500}  # one window: same estimator
    before = _quiet_response(model, clean, None, **band).channel("elevator", "q")
    after = _quiet_response(model, _with_noise(clean, ["q"], 0.03, seed=3), None, **band).channel(
        "elevator", "q"
    )
    assert np.all(before.coherence > 0.9)
    # the output's noise adds to the auto-spectrum only: γ² = S / (S + N) on average
    assert np.mean(after.coherence) < np.mean(before.coherence) - 0.05
    assert np.mean(after.coherence < before.coherence) > 0.9
    # with the default windows too, the counted frequencies lose coherence
    clean_d = _quiet_response(model, clean, None, frequency_range=(0.2, 3.0)).channel(
        "elevator", "q"
    )
    noisy_d = _quiet_response(
        model, _with_noise(clean, ["q"], 0.03, seed=3), None, frequency_range=(0.2, 3.0)
    ).channel("elevator", "q")
    assert np.median(noisy_d.coherence) < np.median(clean_d.coherence)


def test_a_band_above_nyquist_is_clipped_and_noted():
    model = catalog.short_period(TRUTH)
    data = _noise_free_multisine(model, 20.0)
    res = _quiet_response(model, data, None, frequency_range=(0.5, 40.0))
    assert res.frequency_range == (0.5, 25.0)
    assert any("Nyquist" in n for n in res.notes) and "Nyquist" in res.summary()
    for ch in res.channels:
        assert ch.frequency_hz[-1] <= 25.0 and ch.frequency_hz[-1] > 24.9


def test_frequencies_below_two_periods_of_every_window_are_reported():
    model = catalog.short_period(TRUTH)
    data = _noise_free_multisine(model, 20.0)
    res = _quiet_response(model, data, None, frequency_range=(0.01, 3.0))
    # the whole record with one bin either side: three bins of 1/T, two periods at 3/T
    lowest = 3.0 / (data.n_samples / 50.0)
    assert any("two periods" in n for n in res.notes)
    for ch in res.channels:
        below = ch.frequency_hz < lowest
        assert below.any() and not ch.coherent[below].any()
        assert ch.dropped["below two periods of every window"] == below.sum()
        assert np.all(ch.frequency_hz[ch.coherent] * ch.window[ch.coherent] / 50.0 >= 2.0)
    assert "below two periods" in res.summary()


def test_a_lightly_damped_mode_is_resolved_and_judged():
    # not the short period: a 1 Hz mode with 5 % damping, noisy, 60 s multisine
    model, exact = _second_order(2 * np.pi * 1.0, 0.05)
    data = _with_noise(_noise_free_multisine(model), ["y"], 0.002, seed=5)
    res = _quiet_response(model, data, None, frequency_range=(0.2, 3.0))
    ch = res.channel("u", "y")
    h = exact(ch.frequency_hz)["y"]
    rel = np.abs(ch.response - h) / np.abs(h)
    assert ch.n_coherent > 20
    # counted near the resonance, where the gain changes fastest
    assert np.any(ch.coherent & (np.abs(ch.frequency_hz - 1.0) < 0.05))
    assert np.median(rel[ch.coherent]) < 0.05
    wrong, _ = _second_order(2 * np.pi * 1.1, 0.05)
    off = _quiet_response(wrong, data, None, frequency_range=(0.2, 3.0)).channel("u", "y")
    assert off.mismatch > 3 * ch.mismatch


def _zero_ends(x):
    """The record less the line through its end points (SIDPAC's zep)."""
    return x - (x[0] + np.linspace(0.0, 1.0, x.size) * (x[-1] - x[0]))


def test_twin_otter_pitch_record_agrees_with_the_whole_record_ratio():
    # SIDPAC's tfest demo: 8 s of Twin Otter elevator -> pitch rate at 50 Hz. Its
    # estimate is Z/U, one Fourier transform of each end-zeroed record. The counted
    # frequencies must agree with that ratio: median within 1 dB and 5 deg.
    mat = sidpac_mat("Demos", "totter_demo_data.mat")
    t = mat["t"][:, 0] - mat["t"][0, 0]
    de = np.radians(mat["fdata"][:, 13])
    q = np.radians(mat["fdata"][:, 5])
    data = FlightData(t, {"elevator": de - de[0], "q": q - q[0]})

    def ratio(w):
        kern = np.exp(-1j * np.outer(w, t))
        return (kern @ _zero_ends(q)) / (kern @ _zero_ends(de))

    # a model to judge resolution: tfest's (b1 s + b0) / (s^2 + a1 s + a0), fitted by
    # equation error to Z/U over SIDPAC's 0.3-1.3 Hz band
    w = 2 * np.pi * np.arange(0.3, 1.3001, 0.01)
    kern = np.exp(-1j * np.outer(w, t))
    u_f, z_f = kern @ _zero_ends(de), kern @ _zero_ends(q)
    jw = 1j * w
    x = np.column_stack([jw * u_f, u_f, -jw * z_f, -z_f])
    b1, b0, a1, a0 = np.linalg.lstsq(
        np.vstack([x.real, x.imag]),
        np.concatenate([(jw**2 * z_f).real, (jw**2 * z_f).imag]),
        rcond=None,
    )[0]
    model = Model(
        states=["x1", "x2"],
        controls=["elevator"],
        parameters={"b1": b1, "b0": b0, "a1": a1, "a0": a0},
        dynamics=lambda t, x, u, p: np.array([x[1], -p["a0"] * x[0] - p["a1"] * x[1] + u[0]]),
        outputs=["q"],
        measurement=lambda t, x, u, p: np.array([p["b0"] * x[0] + p["b1"] * x[1]]),
        name="q_over_elevator",
    )
    ch = _quiet_response(model, data, outputs=["q"]).channel("elevator", "q")
    assert ch.n_coherent >= 5
    ref = ratio(ch.frequency_rad_s[ch.coherent])
    est = ch.response[ch.coherent]
    assert np.median(np.abs(20 * np.log10(np.abs(est / ref)))) < 1.0
    assert np.median(np.abs(np.degrees(np.angle(est / ref)))) < 5.0
    assert sum(ch.dropped.values()) + ch.n_coherent == ch.frequency_hz.size


def test_one_response_type_for_every_frequency_tool():
    from aeroid.frequency.frequency_id import ResponseChannel

    model = catalog.short_period(TRUTH)
    data = _noise_free_multisine(model, 20.0)
    ch = _quiet_response(model, data, None, frequency_range=(0.2, 3.0)).channel("elevator", "q")
    # the spec's name is the one record: rad/s inside, complex responses
    assert aeroid.ChannelFrequencyResponse is ResponseChannel
    assert isinstance(ch, ResponseChannel) and ch.as_response_channel() is ch
    comp = aeroid.composite_response(data, "elevator", "q").channel("elevator", "q")
    assert type(comp) is type(ch)
    np.testing.assert_allclose(ch.frequency_rad_s, 2 * np.pi * ch.frequency_hz, rtol=1e-15)
    assert ch.frequency is ch.frequency_rad_s
    # dB and degrees are derived from the complex response, the same on every record
    for rec in (ch, comp):
        np.testing.assert_allclose(rec.magnitude_db, 20 * np.log10(np.abs(rec.response)))
        np.testing.assert_allclose(rec.gain, np.abs(rec.response))
        np.testing.assert_allclose(
            np.exp(1j * np.radians(rec.phase_deg)), rec.response / np.abs(rec.response),
            atol=1e-12,
        )  # fmt: skip
        assert -270.0 < rec.phase_deg[0] <= 90.0
    np.testing.assert_allclose(
        np.exp(1j * np.radians(ch.model_phase)),
        ch.model_response / np.abs(ch.model_response),
        atol=1e-12,
    )
    assert np.all(np.abs(ch.phase_error) <= 180.0)
    assert np.isnan(comp.model_response).all() and np.isnan(comp.mismatch)
    h = exact_short_period(ch.frequency_hz)["q"]
    exact_res = _quiet_response(
        model, data, None, frequency_range=(0.2, 3.0), model_response="exact"
    ).channel("elevator", "q")
    np.testing.assert_allclose(exact_res.model_response, h, rtol=1e-9)
    with pytest.raises(ValueError):
        ch.frequency_rad_s[0] = 0.0


class _SteppedShortPeriod:
    """A SimulatorModel look-alike: no transfer function, only simulations."""

    name = "stepped_short_period"
    controls = ("elevator",)
    outputs = ("alpha", "q")

    def __init__(self, parameters):
        self._m = catalog.short_period(parameters)
        self.parameters = dict(self._m.parameters)

    def simulate(self, time, controls=None, x0=None, parameters=None, **options):
        return self._m.simulate(time, controls, x0, parameters, method="exact")

    def simulate_data(self, data, *, x0=None, parameters=None, **options):
        return self._m.simulate_data(data, x0=x0, parameters=parameters, method="exact")


def test_a_simulator_is_judged_against_its_whole_record_ratio():
    # no transfer function: resolution is judged against the ratio of the simulated
    # output's and the input's Fourier transforms over the whole record
    model = catalog.short_period(TRUTH)
    data = _noise_free_multisine(model)
    sim = _SteppedShortPeriod(TRUTH)
    res = _quiet_response(sim, data, None, frequency_range=(0.2, 3.0))
    assert res.model_response == "simulated"
    ch = res.channel("elevator", "q")
    h = exact_short_period(ch.frequency_hz)["q"]
    assert ch.n_coherent > 5
    assert np.all(np.abs(ch.response[ch.coherent] / h[ch.coherent] - 1) < 0.12)
    wrong = _SteppedShortPeriod({**TRUTH, "M_alpha": 1.5 * TRUTH["M_alpha"]})
    off = _quiet_response(wrong, data, None, frequency_range=(0.2, 3.0)).channel("elevator", "q")
    assert off.mismatch > 3 * ch.mismatch and ch.mismatch < 0.05


def test_model_phase_is_one_continuous_branch_under_a_noisy_measured_phase():
    # a second-order lag to -180 deg; past the coherent band the measured phase is
    # noise, which taken frequency by frequency would throw the model's curve by 360 deg
    from aeroid.frequency.response import ResponseChannel

    w = np.logspace(-1, 2, 200)
    model = 1.0 / ((1j * w) ** 2 + 0.8 * (1j * w) + 1.0)
    rng = np.random.default_rng(3)
    coherent = w < 10.0
    noise = np.where(coherent, 0.0, rng.uniform(-np.pi, np.pi, w.size))
    measured = model * np.exp(1j * noise)
    ch = ResponseChannel("u", "y", w, measured, model_response=model, coherent=coherent)
    assert np.max(np.abs(np.diff(ch.model_phase))) < 10.0
    exact = np.degrees(np.unwrap(np.angle(model)))
    np.testing.assert_allclose(ch.model_phase, exact, atol=1e-9)
    np.testing.assert_allclose(ch.model_phase[coherent], (ch.phase - ch.phase_error)[coherent])


@pytest.mark.parametrize("origin", [1e3, 1e5])
def test_the_time_origin_changes_nothing(multisine_record, origin):
    # stamps from boot or GPS time round each sample, and the mean rate with them; the
    # band's edge and each window's two-period limit sit on bins of 3000 samples
    record = multisine_record.window(0.0, 59.98)
    base = frequency_response(catalog.short_period(), record, TRUTH)
    later = FlightData(record.time + origin, dict(record.channels), {})
    moved = frequency_response(catalog.short_period(), later, TRUTH)
    for out in ("alpha", "q"):
        a, b = base.channel("elevator", out), moved.channel("elevator", out)
        assert a.frequency.size == b.frequency.size
        np.testing.assert_allclose(b.frequency, a.frequency, rtol=1e-9)
        coherent = a.coherence > 0.5  # elsewhere noise over noise amplifies the rounding
        np.testing.assert_allclose(b.response[coherent], a.response[coherent], rtol=1e-6)
        assert b.mismatch == pytest.approx(a.mismatch, rel=1e-6)


@pytest.mark.parametrize("spacing", ["even", "uneven"])
def test_spectra_taken_in_blocks_equal_those_taken_at_once(monkeypatch, spacing):
    # a long record's analysis grid is transformed a group of segments and a block of
    # frequencies at a time; the spectral matrix must not depend on the blocks
    from aeroid.frequency import _cross_spectra as cs

    rng = np.random.default_rng(3)
    signals = rng.standard_normal((4000, 3))
    if spacing == "even":
        omega = 2 * np.pi * np.arange(1, 2501) * 0.01  # three blocks of frequencies
    else:
        omega = np.geomspace(0.5, 150.0, 300)
    g, x, nd = cs._window_spectra(signals, 0.02, 500, 250, omega, first_transforms=True)
    monkeypatch.setattr(cs, "_TRANSFORM_BUDGET", 48 * 3 * 600)
    g_b, x_b, nd_b = cs._window_spectra(signals, 0.02, 500, 250, omega, first_transforms=True)
    assert nd_b == nd
    np.testing.assert_allclose(g_b, g, rtol=1e-12, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(x_b, x, rtol=1e-12, atol=1e-12 * np.abs(x).max())
    assert cs._window_spectra(signals, 0.02, 500, 250, omega)[1] is None
