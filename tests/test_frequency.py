"""Frequency-domain validation against exact transfer functions."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from aeroid import ChannelError, DataFormatError, FlightData, IdentificationError, Model, catalog
from aeroid.frequency import FrequencyResponseResult, frequency_response
from aeroid.maneuvers import orthogonal_multisine

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
        good = ch.coherence > 0.95
        assert good.sum() >= (1 if out == "alpha" else 5)
        h = exact_short_period(ch.frequency[good])[out]
        np.testing.assert_allclose(ch.magnitude[good], np.abs(h), rtol=0.10)
        dphase = np.angle(np.exp(1j * (ch.phase[good] - np.angle(h))))
        assert np.max(np.abs(dphase)) < 0.15


def test_exact_model_response_is_the_closed_form(multisine_record):
    res = frequency_response(
        catalog.short_period(), multisine_record, TRUTH, model_response="exact"
    )
    assert res.model_response == "exact"
    for out in ("alpha", "q"):
        ch = res.channel("elevator", out)
        h = exact_short_period(ch.frequency)[out]
        np.testing.assert_allclose(ch.model_magnitude, np.abs(h), rtol=1e-9)
        np.testing.assert_allclose(
            np.angle(np.exp(1j * (ch.model_phase - np.angle(h)))), 0.0, atol=1e-9
        )


def test_mismatch_separates_right_and_wrong_parameters(multisine_record):
    model = catalog.short_period()
    right = frequency_response(model, multisine_record, TRUTH).channel("elevator", "q")
    wrong = frequency_response(model, multisine_record).channel("elevator", "q")  # the guesses
    assert right.mismatch < 0.05
    assert wrong.mismatch > 3 * right.mismatch
    assert right.n_coherent == int(right.coherent.sum()) > 5
    np.testing.assert_array_equal(right.coherent, right.coherence >= 0.6)


def test_result_record_and_summary(multisine_record):
    res = frequency_response(
        catalog.short_period(), multisine_record, TRUTH, frequency_range=(0.2, 3.0)
    )
    assert isinstance(res, FrequencyResponseResult)
    assert res.model_response == "simulated"
    ch = res.channel("elevator", "alpha")
    assert ch.frequency.min() >= 0.2 and ch.frequency.max() <= 3.0
    with pytest.raises(ValueError):
        ch.magnitude[0] = 0.0
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
        h = b / (2j * np.pi * ch.frequency[good] + a)
        np.testing.assert_allclose(ch.magnitude[good], np.abs(h), rtol=0.1)
        assert np.max(np.abs(np.angle(np.exp(1j * (ch.phase[good] - np.angle(h)))))) < 0.15


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
    assert not np.any(ch.coherent & (ch.frequency > 4.5))


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
    assert res.model_response == "simulated"
