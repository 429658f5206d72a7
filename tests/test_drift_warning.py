"""The drift warning says which bias is estimated, and the identifiability message
names each parameter combination once (issue 48 part 3)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.estimation._noise_model import _warn_unabsorbed_drift
from aeroid.estimation._output_error import _combinations, _Manoeuvre


def _manoeuvre(n: int, x0_free: list[int], bias_free: list[int]) -> _Manoeuvre:
    t = np.arange(n) * 0.02
    return _Manoeuvre(
        data=aeroid.FlightData(time=t, channels={"u": np.zeros(n)}),
        time=t,
        controls=np.zeros((n, 1)),
        measured=np.zeros((n, 2)),
        x0=np.zeros(3),
        x0_free=x0_free,
        bias=np.zeros(2),
        bias_free=bias_free,
    )


def _told(mans: list[_Manoeuvre], states: list[str]) -> str:
    phi = np.array([0.9999999, 0.1])  # 'phi' drifts over the 500 samples, 'p' does not
    cov = np.diag([400.0, 1.0])
    white = np.eye(2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _warn_unabsorbed_drift(phi, mans, ["phi", "p"], cov, white, ["a", "b"], states)
    drift = [w.message for w in caught if isinstance(w.message, aeroid.ResidualDriftWarning)]
    assert len(drift) == 1
    return str(drift[0])


def test_state_bias_is_not_reported_as_no_bias() -> None:
    states = ["phi", "p", "bias.phi"]
    text = _told([_manoeuvre(500, [2], [])], states)
    assert "no output bias is estimated" not in text
    assert "state equation of ['phi']" in text
    assert "20x" in text and "(on a)" in text


def test_a_renamed_state_bias_is_found() -> None:
    # a model that already has a 'bias.phi' name gets '_bias.phi' for the added state
    text = _told([_manoeuvre(500, [2], [])], ["phi", "p", "_bias.phi"])
    assert "no output bias is estimated" not in text


def test_no_bias_is_said_when_none_is_estimated() -> None:
    text = _told([_manoeuvre(500, [], [])], ["phi", "p", "q"])
    assert "no output bias is estimated on ['phi']" in text


def test_an_output_bias_silences_the_warning() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_unabsorbed_drift(
            np.array([0.9999999, 0.1]),
            [_manoeuvre(500, [], [0])],
            ["phi", "p"],
            np.diag([400.0, 1.0]),
            np.eye(2),
            ["a", "b"],
            ["phi", "p", "q"],
        )


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_a_combination_is_listed_once(scale: float) -> None:
    # a, b, c always move together: two null directions with the same three members
    x = np.random.default_rng(0).standard_normal((50, 1))
    cols = np.hstack([x, scale * x, -x, np.random.default_rng(1).standard_normal((50, 1))])
    combos, null = _combinations(cols.T @ cols, ["a", "b", "c", "d"])
    assert len(combos) == len(set(combos))
    assert combos == [("a", "b", "c")]
    assert null.tolist() == [True, True, True, False]


def _lag_model(offset: bool) -> aeroid.Model:
    params = {"a": 1.0, "b": 1.0} | ({"c": 0.0} if offset else {})

    def measurement(t: float, x: np.ndarray, u: np.ndarray, p: dict) -> np.ndarray:
        return np.array([x[0] + (p["c"] if offset else 0.0)])

    return aeroid.Model(
        states=["x"],
        controls=["u"],
        parameters=params,
        dynamics=lambda t, x, u, p: np.array([-p["a"] * x[0] + p["b"] * u[0]]),
        outputs=["y"],
        measurement=measurement,
        name="lag_with_offset" if offset else "lag",
    )


def _drifting_record() -> aeroid.FlightData:
    rng = np.random.default_rng(3)
    t = np.arange(1500) * 0.02
    u = np.sign(np.sin(2 * np.pi * 0.3 * t))
    truth = _lag_model(False).simulate(t, {"u": u}, [0.0], {"a": 2.0, "b": 3.0})
    y = truth.outputs[:, 0] + 0.3 + np.cumsum(rng.normal(0.0, 0.01, t.size))
    return aeroid.FlightData(time=t, channels={"u": u, "y": y})


def test_a_model_parameter_that_is_an_output_bias_counts_as_one() -> None:
    data = _drifting_record()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        aeroid.identify(_lag_model(True), data, {"a": 1.0, "b": 1.0, "c": 0.0})
    drift = [w.message for w in caught if isinstance(w.message, aeroid.ResidualDriftWarning)]
    assert not drift, drift
    # the same record fitted without the offset is told that no bias is estimated
    with pytest.warns(aeroid.ResidualDriftWarning, match=r"no output bias is estimated on \['y'\]"):
        aeroid.identify(_lag_model(False), data, {"a": 1.0, "b": 1.0})


def test_only_a_constant_sensitivity_on_one_output_is_an_offset() -> None:
    from aeroid.estimation._noise_model import _offset_outputs

    n = 200
    g = np.zeros((n, 2, 4))
    g[:, 0, 0] = 1.0  # an offset on output 0
    g[:, 1, 1] = 1.0 + 0.01 * np.sin(np.arange(n))  # nearly constant: a gain, not an offset
    g[:, 0, 2] = g[:, 1, 2] = 2.0  # constant on two outputs: not one output's bias
    g[:, 1, 3] = np.linspace(0.0, 1.0, n)  # a ramp
    assert _offset_outputs([g[:100], g[100:]]) == {0}
    assert _offset_outputs(None) == set()


def test_a_fit_to_rounding_tells_no_drift() -> None:
    # noise-free records fitted to 1e-13 had their integrator's residual correlation
    # told as a random-walk drift ('up to 3.4e-05x the white ones')
    from aeroid.models import catalog

    model = catalog.first_order(2.0, 0.5)
    t = np.arange(0.0, 8.0, 0.02)
    u = np.where((t > 1.0) & (t < 2.0), 1.0, 0.0) - np.where((t > 2.0) & (t < 3.0), 1.0, 0.0)
    y = model.simulate(t, {"u": u}, {"y": 0.0}, method="exact").output("y")
    data = aeroid.FlightData(t, {"u": u, "y": y + 0.05})
    with warnings.catch_warnings():
        warnings.simplefilter("error", aeroid.ResidualDriftWarning)
        fit = aeroid.identify(model, data, ["K", "tau"], estimate_bias={"y": "state"})
    assert max(float(np.max(np.abs(r))) for r in fit.residuals) < 1e-6
