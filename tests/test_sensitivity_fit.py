"""Sensitivities at a fit: replayed as fitted (biases, start), the fit's noise, its bars."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid import FlightData, Model

T = np.arange(0.0, 8.0001, 0.01)
U = np.sin(2 * np.pi * 0.3 * T)


def _msd(t, x, u, p):
    return np.array([x[1], -p["k"] * x[0] - p["c"] * x[1] + p["b"] * u[0]])


def _model() -> Model:
    return Model(
        states=["x", "v"],
        controls=["u"],
        parameters={"k": 4.0, "c": 0.6, "b": 2.0},
        dynamics=_msd,
    )


def _record(seed: int, *, x_bias: float = 0.0, v_rate: float = 0.0, v: bool = True) -> FlightData:
    """A mass-spring-damper record: x read `x_bias` high, `v_rate` added to v's equation."""
    truth = Model(
        states=["x", "v"],
        controls=["u"],
        parameters={"k": 4.0, "c": 0.6, "b": 2.0},
        dynamics=lambda t, x, u, p: _msd(t, x, u, p) + np.array([0.0, v_rate]),
    )
    y = np.asarray(truth.simulate(T, {"u": U}).outputs)
    rng = np.random.default_rng(seed)
    channels = {"u": U, "x": y[:, 0] + x_bias + 0.002 * rng.standard_normal(T.size)}
    if v:
        channels["v"] = y[:, 1] + 0.05 * rng.standard_normal(T.size)
    return FlightData(T, channels)


def _bars_match(fit: aeroid.IdentificationResult, res: aeroid.SensitivityResult) -> None:
    white = np.sqrt(np.diag(fit.covariance_white))
    crb = [res.cramer_rao_bound[n] for n in fit.parameter_names]
    np.testing.assert_allclose(crb, white, rtol=1e-6)


@pytest.mark.parametrize(
    ("option", "truth", "nuisance"),
    [
        # the x sensor reads 0.05 high: before, the noise of x was estimated as the bias
        # (0.0499) and the bounds were 7-9 times the fit's
        (True, {"x_bias": 0.05}, ("x0.x", "x0.v", "bias.x", "bias.v")),
        # v' += 0.5: before, the replay left it out (noise x 0.129, bounds 13 times)
        ({"v": "state"}, {"v_rate": 0.5}, ("x0.x", "x0.v", "bias.state.v")),
    ],
)
def test_bounds_at_a_biased_fit_are_its_white_bars(option, truth, nuisance):
    model, data = _model(), _record(1, **truth)
    fit = aeroid.identify(model, data, ["k", "c", "b"], estimate_bias=option, error_bars="white")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no unit noise, nothing unidentifiable
        res = aeroid.sensitivities(model, data, fit)
    assert res.noise_source == "fit"
    assert res.nuisance == nuisance
    sigma = np.sqrt(np.diag(fit.noise_covariance))
    np.testing.assert_allclose([res.noise[o] for o in fit.output_names], sigma, rtol=1e-12)
    _bars_match(fit, res)
    # the replayed outputs are the fit's: measured minus them are its residuals
    np.testing.assert_allclose(
        data.array(list(res.output_names)) - res.outputs, fit.residuals[0], atol=1e-9
    )


def test_validate_replays_a_state_bias():
    # before: x RMSE 0.129 (fit 84 %), residuals not white, for a correct fit
    model, data = _model(), _record(2, v_rate=0.5)
    fit = aeroid.identify(model, data, ["k", "c", "b"], estimate_bias={"v": "state"})
    assert fit.biases[0]["state.v"] == pytest.approx(0.5, abs=0.01)
    val = aeroid.validate(model, data, fit)
    np.testing.assert_allclose(val.residuals, fit.residuals[0], atol=1e-9)
    # 801 samples: the residual RMS is within a few per cent of the noise
    assert val.metrics["x"].rmse == pytest.approx(0.002, rel=0.1)
    assert val.metrics["v"].rmse == pytest.approx(0.05, rel=0.1)
    assert val.metrics["x"].fit > 99.0
    # another record starts from its own state without the fit's biases, as before
    other = aeroid.validate(model, _record(3, v_rate=0.5), fit)
    assert other.metrics["x"].rmse > 0.05


def test_a_record_without_an_output_uses_the_noise_of_those_it_has():
    # v is not measured: before, unit noise for x and v alike (bounds ~200 times the fit's)
    model, data = _model(), _record(0, v=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # identify: v is not in the record
        fit = aeroid.identify(model, data, ["k", "c", "b"], error_bars="white")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = aeroid.sensitivities(model, data, fit)
        bare = aeroid.sensitivities(model, data, x0=[0.0, 0.0])
    assert res.output_names == ("x",) and res.noise_source == "fit"
    _bars_match(fit, res)
    # without a fit: the measured output, its noise from the residuals (N = 801: ~3 %)
    assert bare.output_names == ("x",) and bare.noise_source == "residuals"
    assert bare.noise["x"] == pytest.approx(0.002, rel=0.1)
    assert bare.nuisance == ()
    np.testing.assert_allclose(
        [bare.cramer_rao_bound[n] for n in "kcb"],
        [res.cramer_rao_bound[n] for n in "kcb"],
        rtol=0.5,  # x0 held at the truth here, estimated in the fit
    )


def test_unit_noise_only_for_the_output_that_has_none():
    model, data = _model(), _record(0, v=False)
    with pytest.warns(UserWarning, match=r"\['v'\].*for \['v'\] only") as rec:
        res = aeroid.sensitivities(model, data, outputs=["x", "v"], x0=[0.0, 0.0])
    assert len(rec) == 1
    assert res.noise["v"] == 1.0
    assert res.noise["x"] == pytest.approx(0.002, rel=0.1)
    assert res.noise_source == "residuals (x); unit (v)"
    assert "residuals (x); unit (v)" in res.summary()
    # a record with no output at all: unit noise for every one, as before
    empty = FlightData(T, {"u": U})
    with pytest.warns(UserWarning, match="all outputs"):
        pre = aeroid.sensitivities(model, empty, x0=[0.0, 0.0])
    assert pre.noise_source == "unit" and pre.output_names == ("x", "v")
