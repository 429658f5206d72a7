"""A parameter the record does not see (its control never moves, or the dynamics never
read it) is held where it starts, with an infinite bar, and the others are those of the
fit without it (Klein & Morelli: an unidentifiable parameter is held, the rest fitted)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog

START = {"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -6.0}
NAMES = list(START)


def _short_period(extra: str):
    def dynamics(t, x, u, p):
        alpha, q = x
        moment = p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0]
        if extra == "flap":
            moment = moment + p["M_flap"] * u[1]
        return np.array([p["Z_alpha"] * alpha + q, moment])

    controls = ["elevator", "flap"] if extra == "flap" else ["elevator"]
    return aeroid.Model(
        states=["alpha", "q"],
        controls=controls,
        parameters={**START, ("M_flap" if extra == "flap" else "unused"): -1.0},
        dynamics=dynamics,
    )


@pytest.mark.parametrize("extra", ["flap", "unused"])
@pytest.mark.parametrize("seed", [42, 7])
def test_an_unseen_parameter_is_held_and_the_others_fitted_as_without_it(extra, seed):
    data = catalog.short_period_flight(seed=seed)
    flap = np.zeros(data.n_samples)
    record = aeroid.FlightData(data.time, {**data.channels, "flap": flap}, units=dict(data.units))
    name = "M_flap" if extra == "flap" else "unused"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = aeroid.identify(_short_period("none"), record, NAMES)
        with pytest.warns(aeroid.IdentifiabilityWarning, match=name):
            fit = aeroid.identify(_short_period(extra), record, [*NAMES, name])
    assert fit.success
    assert fit.parameters[name] == -1.0
    assert fit.standard_errors[name] == np.inf
    for n in NAMES:
        # before: stuck 4-10 standard errors away (and `unused` at 1.8e135)
        assert fit.parameters[n] == pytest.approx(reference.parameters[n], rel=1e-6)
        assert fit.standard_errors[n] == pytest.approx(reference.standard_errors[n], rel=1e-3)


@pytest.mark.parametrize("how", ["filter_error", "two_records"])
def test_an_unseen_parameter_is_held_in_filter_error_and_joint_fits(how):
    # before: filter error stopped at the start (success reported), two records at 0
    # iterations
    data = catalog.short_period_flight(seed=42)
    other = catalog.short_period_flight(seed=3)

    def flapless(d):
        return aeroid.FlightData(
            d.time, {**d.channels, "flap": np.zeros(d.n_samples)}, units=dict(d.units)
        )

    records = flapless(data) if how == "filter_error" else [flapless(data), flapless(other)]
    options = (
        {"method": "filter_error", "process_noise": {"q": 0.01}} if how == "filter_error" else {}
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = aeroid.identify(_short_period("none"), records, NAMES, **options)
        fit = aeroid.identify(_short_period("flap"), records, [*NAMES, "M_flap"], **options)
    assert fit.success and fit.parameters["M_flap"] == -1.0
    for n in NAMES:
        assert fit.parameters[n] == pytest.approx(reference.parameters[n], rel=1e-5)
