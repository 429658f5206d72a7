"""design_experiment: criteria of designs that cannot identify, failed candidates,
user families that break the protocol, bounds, delays."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from aeroid import IdentifiabilityWarning, Model
from aeroid.uncertainty.design import design_experiment
from aeroid.uncertainty.maneuvers import Doublet


def _product_roll() -> Model:
    # g and k enter only as their product: no manoeuvre separates them
    return Model(
        states=["p"],
        controls=["da"],
        parameters={"L_p": -2.0, "g": 2.0, "k": 2.5},
        dynamics=lambda t, x, u, p: np.array([p["L_p"] * x[0] + p["g"] * p["k"] * u[0]]),
        name="product_roll",
    )


@pytest.mark.parametrize("criterion", ["D", "A"])
def test_a_design_that_cannot_identify_has_an_infinite_criterion(criterion):
    # the rank-deficient information inverted through rounding gave D 6.63 and A 3.4e10,
    # and the summary read "Criterion inf -> 6.63"
    with pytest.warns(IdentifiabilityWarning):
        d = design_experiment(
            _product_roll(), Doublet("da", amplitude=(0.01, 0.1)), ["L_p", "g", "k"],
            criterion=criterion, noise={"p": 0.01}, duration=8.0, sample_rate=25.0, seed=0,
            optimizer_options={"maxiter": 3},
        )  # fmt: skip
    assert d.success is False
    assert d.criterion_value == np.inf and d.initial_criterion_value == np.inf
    # no candidate ranks above another on rounding noise: the reference design stays
    assert dict(d.design) == dict(d.initial_design)
    text = d.summary()
    assert "Criterion infinite" in text and "→" not in text


def _table_roll(raising: bool) -> Model:
    # a roll mode whose table ends at |da| = 0.0801: beyond it the dynamics return NaN
    # (or raise), as a table looked up out of range would
    def f(t, x, u, p):
        if raising and np.any(np.abs(u[0]) > 0.0801):
            raise ValueError("table out of range")
        edge = np.where(np.abs(u[0]) > 0.0801, np.nan, 0.0)
        return np.array([p["L_p"] * x[0] + p["L_da"] * u[0] + edge])

    return Model(states=["p"], controls=["da"], parameters={"L_p": -2.0, "L_da": 5.0},
                 dynamics=f, name="table_roll")  # fmt: skip


@pytest.mark.parametrize("raising", [False, True], ids=["nan", "raises"])
def test_failed_candidates_are_dropped_with_a_warning_either_way(raising):
    # NaN candidates vanished in silence and raising dynamics ended the whole design,
    # though the initial design (amplitude 0.055) flies
    with pytest.warns(UserWarning, match=r"(\d+) of (\d+) candidate designs failed") as rec:
        d = design_experiment(
            _table_roll(raising), Doublet("da", amplitude=(0.01, 0.1), width=(0.5, 2.0)),
            ["L_p", "L_da"], noise={"p": 0.01}, duration=6.0, sample_rate=10.0, seed=0,
            optimizer_options={"maxiter": 2, "popsize": 5, "polish": False},
        )  # fmt: skip
    assert 0 < d.n_failed < d.n_candidates
    assert f"{d.n_failed} of {d.n_candidates} candidate" in str(rec[0].message)
    assert f"{d.n_failed} of the {d.n_candidates} candidates failed" in d.summary()
    # the design stays where the model flies: the amplitude at most the table's edge
    assert d.success and d.design["amplitude"] <= 0.0801


def test_a_design_without_failures_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = design_experiment(
            _table_roll(False), Doublet("da", amplitude=(0.01, 0.08)), ["L_p", "L_da"],
            noise={"p": 0.01}, duration=8.0, sample_rate=25.0, seed=0,
            optimizer_options={"maxiter": 2},
        )  # fmt: skip
    assert d.n_failed == 0 and "failed" not in d.summary()
