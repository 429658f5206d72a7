"""Input time delays: output error (`identify(time_delays=...)`) and equation error.

Truth: controls delayed by 0.07 s (3.5 samples at 50 Hz) before simulation,
recovered within 3 standard errors; records without a delay give estimates
within 3 standard errors of 0.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _aircraft_data import LATERAL_LINEAR as LATERAL
from _aircraft_data import LATERAL_STATES as STATES

from aeroid import FlightData, IdentificationError, SimulationError, equation_error, identify
from aeroid.errors import ChannelError, DataFormatError
from aeroid.models import catalog
from aeroid.models.aircraft import lateral_linear
from aeroid.models.integration import shifted_controls

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
DELAY = 0.07


def _short_period(tau: float, seed: int) -> FlightData:
    """The truth-case record flown with the elevator delayed by `tau`; the record
    carries the undelayed elevator."""
    t = np.arange(501) / 50.0
    u = catalog.doublet(t)
    late = shifted_controls(t, u[:, None], [0], [tau])[:, 0]
    d = catalog.short_period_flight(elevator=late, seed=seed)
    return FlightData(d.time, {**d.channels, "elevator": u}, {})


def _lateral(tau: float, seed: int) -> tuple[object, FlightData]:
    """Linear lateral model with the aileron delayed by `tau` (multisine aileron,
    rudder doublet), states and a noisy roll acceleration measured."""
    model = lateral_linear(V0=60.0, parameters=LATERAL, outputs=[*STATES, "p_dot"])
    t = np.arange(751) / 50.0
    da = catalog.multisine(t, [0.2, 0.5, 0.9, 1.4, 2.1], 0.02)
    dr = catalog.doublet(t, start=4.0, width=1.0, amplitude=0.06)
    u = np.column_stack([da, dr])
    sim = model.simulate(t, shifted_controls(t, u, [0], [tau]), method="exact")
    rng = np.random.default_rng(seed)
    noise = {"beta": 0.002, "p": 0.005, "r": 0.003, "phi": 0.003, "p_dot": 0.05}
    channels = {"delta_a": da, "delta_r": dr}
    for name, sd in noise.items():
        channels[name] = sim.output(name) + sd * rng.standard_normal(t.size)
    return model, FlightData(t, channels, {})


def test_shifted_controls_is_linear_interpolation_of_the_delayed_signal():
    t = np.arange(6) * 0.5
    u = np.column_stack([np.arange(6.0) ** 2, np.ones(6)])
    out = shifted_controls(t, u, [0], [0.2])
    # u(t - 0.2) between samples: 40 % of the way back to the previous sample
    np.testing.assert_allclose(out[1:, 0], u[1:, 0] - 0.4 * np.diff(u[:, 0]))
    assert out[0, 0] == u[0, 0]  # held before the record
    np.testing.assert_array_equal(out[:, 1], u[:, 1])


@pytest.mark.parametrize("tau", [DELAY, 0.0])
def test_output_error_recovers_delay_short_period(tau):
    r = identify(catalog.short_period(), _short_period(tau, 1), NAMES, time_delays=["elevator"])
    est, se = r.parameters["tau_elevator"], r.stderr["tau_elevator"]
    assert r.success and 0 < se < 0.02
    assert abs(est - tau) < 3 * se
    assert r.time_delays == {"elevator": pytest.approx(est)}
    assert r.parameter_names[-1] == "tau_elevator" and r.covariance.shape == (5, 5)
    assert "tau_elevator" not in r.all_parameters
    assert "| tau_elevator" in r.summary() and "Time delays" in r.summary()


@pytest.mark.parametrize("tau", [DELAY, 0.0])
def test_output_error_recovers_delay_lateral(tau):
    model, data = _lateral(tau, 2)
    r = identify(
        model, data, list(LATERAL), outputs=STATES, x0=np.zeros(4), time_delays={"delta_a": 0.02}
    )
    est, se = r.parameters["tau_delta_a"], r.stderr["tau_delta_a"]
    assert r.success and 0 < se < 0.01
    assert abs(est - tau) < 3 * se
    for name, value in LATERAL.items():
        assert abs(r.parameters[name] - value) < 4 * r.stderr[name]


def test_output_error_delay_gradients_agree():
    # the compiled forward-mode route and finite differences give the same fit
    data = _short_period(DELAY, 3)
    a = identify(catalog.short_period(), data, NAMES, time_delays="elevator", gradient="auto")
    b = identify(catalog.short_period(), data, NAMES, time_delays="elevator", gradient="fd")
    assert a.parameters["tau_elevator"] == pytest.approx(b.parameters["tau_elevator"], rel=1e-5)
    assert a.stderr["tau_elevator"] == pytest.approx(b.stderr["tau_elevator"], rel=1e-3)


def test_output_error_without_the_delay_is_biased():
    # the delay matters: ignoring it moves M_q by many standard errors
    data = _short_period(DELAY, 1)
    plain = identify(catalog.short_period(), data, NAMES)
    truth = catalog.SHORT_PERIOD_TRUTH["M_q"]
    assert abs(plain.parameters["M_q"] - truth) > 3 * plain.stderr["M_q"]


@pytest.mark.parametrize("tau", [DELAY, 0.0])
def test_equation_error_recovers_delay(tau):
    _, data = _lateral(tau, 4)
    r = equation_error(
        data, "p_dot", ["beta", "p", "r", "delta_a", "delta_r"], time_delays="delta_a"
    )
    est, se = r.parameters["tau_delta_a"], r.stderr["tau_delta_a"]
    assert 0 < se < 0.01 and abs(est - tau) < 3 * se
    assert abs(r.parameters["delta_a"] - LATERAL["L_delta_a"]) < 3 * r.stderr["delta_a"]
    assert r.time_delays == {"delta_a": pytest.approx(est)}
    assert r.covariance.shape == (7, 7) and "| tau_delta_a" in r.summary()


def test_equation_error_delay_short_period_measured_acceleration():
    # q_dot measured (noisy) from the delayed elevator: the delay of 3.5 samples is found
    t = np.arange(501) / 50.0
    u = catalog.multisine(t, [0.3, 0.7, 1.2, 1.9], 0.02)
    late = shifted_controls(t, u[:, None], [0], [DELAY])[:, 0]
    model = catalog.short_period(catalog.SHORT_PERIOD_TRUTH)
    sim = model.simulate(t, late, method="exact")
    p = catalog.SHORT_PERIOD_TRUTH
    q_dot = p["M_alpha"] * sim.state("alpha") + p["M_q"] * sim.state("q") + p["M_delta"] * late
    rng = np.random.default_rng(5)
    data = {
        "alpha": sim.state("alpha") + 1e-4 * rng.standard_normal(t.size),
        "q": sim.state("q") + 1e-4 * rng.standard_normal(t.size),
        "elevator": u,
        "q_dot": q_dot + 0.02 * rng.standard_normal(t.size),
    }
    r = equation_error(
        data, "q_dot", ["alpha", "q", "elevator"], time_delays={"elevator": 0.0}, dt=0.02
    )
    assert abs(r.parameters["tau_elevator"] - DELAY) < 3 * r.stderr["tau_elevator"]
    assert r.stderr["tau_elevator"] < 0.005


def test_time_delay_errors():
    model = catalog.short_period()
    data = _short_period(0.0, 0)
    with pytest.raises(IdentificationError, match="not a control"):
        identify(model, data, NAMES, time_delays=["aileron"])
    with pytest.raises(IdentificationError, match="finite number"):
        identify(model, data, NAMES, time_delays={"elevator": float("nan")})
    with pytest.raises(ChannelError, match="aileron"):
        equation_error(data, "q", ["alpha", "elevator"], time_delays="aileron")
    with pytest.raises(DataFormatError, match="time domain"):
        equation_error(
            data, "q", ["alpha"], time_delays="elevator", domain="frequency", frequencies=[0.5]
        )
    with pytest.raises(DataFormatError, match="dt="):
        equation_error(dict(data.channels), "q", ["alpha", "elevator"], time_delays="elevator")
    with pytest.raises(IdentificationError, match="do not change"):
        equation_error(data, "q", ["alpha"], time_delays="elevator")


def test_a_fits_delay_reaches_validate_filter_sensitivities_and_frequency_response():
    # The lateral model with a 0.07 s aileron delay: functions given the fit simulate
    # its model on the delayed aileron, on the fitted record and on another one. Noise-
    # free, the truth with the true delay reproduces the outputs to integration error.
    import dataclasses

    import aeroid

    model, noisy = _lateral(DELAY, 2)
    fit = identify(
        model, noisy, list(LATERAL), outputs=STATES, x0=np.zeros(4), time_delays="delta_a"
    )
    assert abs(fit.time_delays["delta_a"] - DELAY) < 3 * fit.stderr["tau_delta_a"]
    v = aeroid.validate(model, noisy, fit, outputs=STATES)
    plain = aeroid.validate(model, noisy, fit.all_parameters, outputs=STATES, x0=np.zeros(4))
    for s, sd in zip(STATES, (0.002, 0.005, 0.003, 0.003), strict=True):
        assert v.metrics[s].rmse < 1.3 * sd  # the noise, nothing more
    assert plain.metrics["p"].rmse > 3 * v.metrics["p"].rmse  # without the delay: a misfit

    # the truth with the true delay, on a noise-free record it was not fitted to
    t = noisy.time
    u = np.column_stack([noisy["delta_a"], noisy["delta_r"]])
    sim = model.simulate(t, shifted_controls(t, u, [0], [DELAY]), method="exact")
    clean = FlightData(
        t, {"delta_a": u[:, 0], "delta_r": u[:, 1]} | {s: sim.output(s).copy() for s in STATES}
    )
    truth = dataclasses.replace(
        fit,
        parameters={**LATERAL, "tau_delta_a": DELAY},
        time_delays={"delta_a": DELAY},
        data_fingerprints=(),
    )
    assert truth.time_delays == {"delta_a": DELAY}
    v = aeroid.validate(model, clean, truth, outputs=STATES, x0=np.zeros(4))
    assert max(v.metrics[s].rmse for s in STATES) < 1e-6

    filtered = aeroid.filter_states(
        model,
        clean,
        truth,
        outputs=STATES,
        x0=np.zeros(4),
        measurement_noise={s: 1e-3 for s in STATES},
        process_noise={s: 0.0 for s in STATES},
    )
    np.testing.assert_allclose(filtered.filtered_states, sim.states, atol=1e-6)
    assert np.abs(filtered.innovations).max() < 1e-6

    kw = {"x0": np.zeros(4), "outputs": STATES, "noise": dict.fromkeys(STATES, 0.003)}
    names = ["L_p", "L_delta_a"]
    sens = aeroid.sensitivities(model, clean, names, values=truth, **kw)
    bare = aeroid.sensitivities(model, clean, names, values=dict(LATERAL), **kw)
    late = clean.with_channels({"delta_a": shifted_controls(t, u, [0], [DELAY])[:, 0]})
    delayed = aeroid.sensitivities(model, late, names, values=dict(LATERAL), **kw)
    np.testing.assert_allclose(sens.fisher_information, delayed.fisher_information, rtol=1e-9)
    assert not np.allclose(sens.fisher_information, bare.fisher_information, rtol=1e-3)

    kw = {"model_response": "exact", "outputs": ["p"], "inputs": ["delta_a"]}
    h = aeroid.frequency_response(model, clean, truth, **kw).channel("delta_a", "p")
    assert h.n_coherent >= 3  # the windows chosen per frequency resolve the 15 s record
    with warnings.catch_warnings():  # the wrong model may leave few resolved frequencies
        warnings.simplefilter("ignore", UserWarning)
        bare_h = aeroid.frequency_response(model, clean, dict(LATERAL), **kw)
    ratio = h.model_response / bare_h.channel("delta_a", "p").model_response
    np.testing.assert_allclose(ratio, np.exp(-1j * h.frequency * DELAY), atol=1e-9)


def test_a_delayed_fit_and_its_draws_simulate_with_the_delay():
    # Model.simulate given the fit (or a mapping with tau_<control>, as propagate's
    # draws are) delays the control as identify did; a delay of three whole samples
    # is exactly the samples shifted
    model = catalog.short_period()
    data = _short_period(DELAY, 3)
    fit = identify(model, data, NAMES, time_delays=["elevator"])
    t, u = data.time, data["elevator"]
    late = shifted_controls(t, u[:, None], [0], [fit.time_delays["elevator"]])[:, 0]
    x0 = [0.0, 0.0]
    by_fit = model.simulate(t, {"elevator": u}, x0, fit, method="rk4", substeps=2)
    own = {k: fit.parameters[k] for k in NAMES}
    by_hand = model.simulate(t, {"elevator": late}, x0, own, method="rk4", substeps=2)
    np.testing.assert_array_equal(by_fit.states, by_hand.states)
    np.testing.assert_array_equal(by_fit.controls[:, 0], u)  # the record's own control
    draw = {**{k: fit.parameters[k] for k in NAMES}, "tau_elevator": 3 * 0.02}
    shifted = np.concatenate([np.full(3, u[0]), u[:-3]])
    a = model.simulate(t, {"elevator": u}, x0, draw, method="rk4", substeps=2)
    b = model.simulate(
        t, {"elevator": shifted}, x0, {k: draw[k] for k in NAMES}, method="rk4", substeps=2
    )
    np.testing.assert_allclose(a.states, b.states, rtol=0, atol=1e-15)
    with pytest.raises(SimulationError, match=r"'tau_elevator' \(the delay of control"):
        model.simulate(t, {"elevator": u}, x0, {"tau_elevator": "x"})
    with pytest.raises(SimulationError, match=r"'tau_aileron' is not a parameter"):
        model.simulate(t, {"elevator": u}, x0, {"tau_aileron": 0.1})
