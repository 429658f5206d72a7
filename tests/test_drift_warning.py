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
