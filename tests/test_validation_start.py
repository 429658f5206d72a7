"""A prediction started from a fitted initial state and output shifts (time-domain verification).

Another manoeuvre flies from another trim and starts at a noisy sample;
``validate(holdout_start="estimated")`` fits only its initial state and one
constant per output, the model held whole, through ``identify(model, data, [])``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _aircraft_data import LATERAL_LINEAR as LATERAL
from _aircraft_data import LATERAL_STATES as STATES

from aeroid import FlightData, IdentificationError, Model, identify, validate
from aeroid.models import catalog
from aeroid.models.aircraft import lateral_linear

TRUTH = {"Z_alpha": -1.2, "M_alpha": -6.0, "M_q": -2.5, "M_delta": -9.0}
NOISE = np.array([0.002, 0.004])  # alpha, q
T = np.arange(500) / 50.0


def _short_period(values: dict[str, float]) -> Model:
    def f(t, x, u, p):
        return np.array(
            [
                p["Z_alpha"] * x[0] + x[1],
                p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0],
            ]
        )

    return Model(states=["alpha", "q"], controls=["de"], parameters=values, dynamics=f)


def _record(u, x0, trim, offsets, seed):
    """Truth flown on ``u - trim`` (the elevator's measured trim offset) from `x0`, its
    sensors reading `offsets` high, with white noise."""
    flown = FlightData(T, {"de": u - trim, "alpha": 0 * T, "q": 0 * T})
    y = _short_period(TRUTH).simulate_data(flown, x0=x0, method="exact").outputs
    y = y + offsets + np.random.default_rng(seed).normal(0.0, NOISE, y.shape)
    return FlightData(T, {"de": u, "alpha": y[:, 0], "q": y[:, 1]})


def _steady(trim: float) -> np.ndarray:
    """The state a constant elevator offset `trim` holds the truth at: A x + B trim = 0."""
    a = np.array([[TRUTH["Z_alpha"], 1.0], [TRUTH["M_alpha"], TRUTH["M_q"]]])
    return -np.linalg.solve(a, np.array([0.0, TRUTH["M_delta"] * trim]))


def test_identify_with_no_parameter_is_the_closed_form_least_squares_start_and_shift():
    # one output, so the noise weighting cannot matter: the fit is linear least squares
    # of q on its free responses to a unit alpha(0) and q(0), and a constant
    model = _short_period(TRUTH)
    u = 0.05 * (((T > 1) & (T < 2)).astype(float) - ((T > 2) & (T < 3)))
    data = _record(u, {"alpha": 0.01, "q": -0.02}, 0.0, [0.0, 0.004], seed=3)
    fit = identify(model, data, [], outputs=["q"], estimate_x0=True, estimate_bias=True)
    run = dict(method="exact", parameters=TRUTH)
    forced = model.simulate_data(data, x0=[0.0, 0.0], **run).output("q")
    still = data.with_channels({"de": 0 * T})
    free = [model.simulate_data(still, x0=x, **run).output("q") for x in ([1, 0], [0, 1])]
    design = np.column_stack([*free, np.ones_like(T)])
    exact, *_ = np.linalg.lstsq(design, data["q"] - forced, rcond=None)
    got = [fit.initial_states[0]["alpha"], fit.initial_states[0]["q"], fit.biases[0]["q"]]
    np.testing.assert_allclose(got, exact, rtol=1e-5, atol=1e-8)
    assert fit.parameters == {} and set(fit.fixed) == set(TRUTH)
    table = fit.summary()
    assert "x0[0].alpha" in table and "bias[0].q" in table


@pytest.mark.parametrize(
    ("options", "says"),
    [
        ({}, "name at least one parameter"),
        ({"estimate_x0": []}, "name at least one parameter"),
        ({"estimate_x0": [], "estimate_bias": []}, "name at least one parameter"),
        ({"method": "filter_error", "estimate_x0": True}, "name at least one parameter"),
    ],
)
def test_identify_refuses_a_fit_with_nothing_to_estimate(options, says):
    data = _record(0.05 * np.sin(T), {"alpha": 0.0, "q": 0.0}, 0.0, [0.0, 0.0], seed=0)
    with pytest.raises(IdentificationError, match=says):
        identify(_short_period(TRUTH), data, [], **options)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_manoeuvre_from_another_trim_is_predicted_to_its_noise(seed):
    model = _short_period({k: 0.8 * v for k, v in TRUTH.items()})
    doublet = 0.05 * (((T > 1) & (T < 2)).astype(float) - ((T > 2) & (T < 3)))
    train = _record(doublet, {"alpha": 0.0, "q": 0.0}, 0.0, [0.0, 0.0], seed=10 + seed)
    fit = identify(model, train, list(TRUTH))
    trim, offsets, x0 = 0.01, np.array([0.003, -0.002]), {"alpha": 0.01, "q": 0.02}
    other = _record(0.04 * np.sin(2 * np.pi * 0.4 * T) * (T < 6), x0, trim, offsets, seed)
    measured = validate(model, train, fit, holdout=other).prediction
    verified = validate(model, train, fit, holdout=other, holdout_start="estimated").prediction
    assert measured is not None and verified is not None
    assert measured.start == "measured" and verified.start == "estimated"
    ratio = {o: verified.metrics[o].rmse / s for o, s in zip(("alpha", "q"), NOISE, strict=True)}
    # 500 samples less 4 fitted constants: rms/sigma within about 4 of its 3 % scatter
    assert all(0.88 < r < 1.12 for r in ratio.values()), ratio
    assert measured.metrics["alpha"].rmse > 3 * NOISE[0]  # the trim offset counted against it
    # the model sees the trim offset as an input: it settles at the truth's steady
    # state for it, which the start and the shifts take back out (closed form)
    steady = _steady(trim)
    expected_shift = offsets - steady
    expected_x0 = np.array([x0["alpha"], x0["q"]]) + steady
    tol = 6 * NOISE / np.sqrt(T.size) + 0.03 * np.abs(expected_shift)
    got_shift = np.array([verified.shifts["alpha"], verified.shifts["q"]])
    np.testing.assert_array_less(np.abs(got_shift - expected_shift), tol)
    got_x0 = np.array([verified.initial_state["alpha"], verified.initial_state["q"]])
    np.testing.assert_allclose(got_x0, expected_x0, atol=2e-3)
    assert "output shifts fitted" in verified.summary()
    with pytest.raises(TypeError):
        verified.shifts["q"] = 0.0  # type: ignore[index]


def test_a_lateral_manoeuvre_with_biased_sensors_and_a_moving_start():
    model = lateral_linear(V0=60.0, parameters=LATERAL, outputs=STATES)
    t = np.arange(751) / 50.0
    da = catalog.doublet(t, start=1.0, width=1.0, amplitude=0.03)
    dr = catalog.doublet(t, start=5.0, width=1.0, amplitude=0.05)
    noise = {"beta": 0.002, "p": 0.005, "r": 0.003, "phi": 0.003}
    offsets = {"beta": 0.01, "p": -0.01, "r": 0.006, "phi": 0.02}
    x0 = {"beta": 0.02, "p": 0.05, "r": -0.02, "phi": 0.05}
    sim = model.simulate(t, np.column_stack([da, dr]), x0=x0, method="exact")
    rng = np.random.default_rng(7)
    channels = {"delta_a": da, "delta_r": dr}
    for name, sd in noise.items():
        channels[name] = sim.output(name) + offsets[name] + sd * rng.standard_normal(t.size)
    other = FlightData(t, channels, {})
    measured = validate(model, other, LATERAL, holdout=other).prediction
    verified = validate(model, other, LATERAL, holdout=other, holdout_start="estimated").prediction
    assert measured is not None and verified is not None
    for name, sd in noise.items():
        assert 0.88 < verified.metrics[name].rmse / sd < 1.12, name
    for name in ("beta", "p"):  # seen through the dynamics: start and shift apart
        assert abs(verified.shifts[name] - offsets[name]) < 1e-3, name
        assert abs(verified.initial_state[name] - x0[name]) < 2e-3, name
    # the bank angle nearly only integrates: its start and its shift are one sum
    together = verified.initial_state["phi"] + verified.shifts["phi"]
    assert together == pytest.approx(x0["phi"] + offsets["phi"], abs=3e-3)
    assert max(measured.metrics[n].rmse / sd for n, sd in noise.items()) > 3


def test_an_unknown_start_and_a_stepped_simulator_are_refused():
    data = catalog.short_period_flight(duration=10.0, sample_rate=50.0, seed=0)
    model = catalog.short_period(catalog.SHORT_PERIOD_TRUTH)
    with pytest.raises(IdentificationError, match="holdout_start 'first' is unknown"):
        validate(model, data, None, holdout={"fraction": 0.3}, holdout_start="first")
    with pytest.raises(IdentificationError, match="needs a holdout"):
        validate(model, data, None, holdout_start="estimated")

    class Stepped:  # a stepped simulator: no dynamics callable to hold and refit
        def __init__(self, wrapped: Model) -> None:
            self.wrapped = wrapped

        def __getattr__(self, name):
            return getattr(self.wrapped, name)

    with warnings.catch_warnings(), pytest.raises(IdentificationError, match="needs a Model"):
        warnings.simplefilter("ignore")
        from aeroid.uncertainty.prediction import _fitted_start

        _fitted_start(Stepped(model), data, {}, ["q"], {}, {})


def test_the_validate_stage_takes_the_start():
    from pydantic import ValidationError

    from aeroid.pipeline.stages.library_stages import ValidateOptions

    opts = ValidateOptions(holdout={"fraction": 0.25}, holdout_start="estimated")
    assert opts.library_kwargs() == {"holdout": {"fraction": 0.25}, "holdout_start": "estimated"}
    with pytest.raises(ValidationError, match="holdout_start"):
        ValidateOptions(holdout_start="first")


def test_the_prediction_record_is_public():
    import aeroid
    from aeroid.uncertainty.prediction import PredictionResult

    assert aeroid.PredictionResult is PredictionResult
