"""design_experiment: criteria of designs that cannot identify, failed candidates,
user families that break the protocol, bounds, delays."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
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
