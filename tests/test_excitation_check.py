"""A flat window is not called a fit: `identify` measures each output's fitted
response against its residual noise and warns when none stands out (issue 46)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog
from aeroid.pipeline.stages.flight_status import flight_status


def _first_order_record(amplitude: float, seed: int = 0) -> aeroid.FlightData:
    model = catalog.first_order(K=2.0, tau=0.5)
    t = np.arange(0.0, 10.0, 0.02)
    u = amplitude * catalog.doublet(t, start=1.0, width=1.0, amplitude=1.0)
    sim = model.simulate(t, {"u": u}, {"y": 0.0})
    rng = np.random.default_rng(seed)
    y = np.asarray(sim.outputs)[:, 0] + 0.01 * rng.standard_normal(t.size)
    return aeroid.FlightData(time=t, channels={"y": y, "u": u})


def test_an_excited_record_stands_well_out_of_its_noise() -> None:
    model = catalog.first_order(K=1.0, tau=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", aeroid.IdentifiabilityWarning)
        res = aeroid.identify(model, _first_order_record(0.5), ["K", "tau"])
    # a 0.5 doublet through K = 2 moves y by about 0.5 RMS against 0.01 of noise
    assert res.response_to_noise["y"] > 10.0


def test_a_flat_record_is_told_not_excited() -> None:
    model = catalog.first_order(K=1.0, tau=1.0)
    with pytest.warns(aeroid.IdentifiabilityWarning, match="not excited") as caught:
        res = aeroid.identify(model, _first_order_record(1e-4), ["K", "tau"])
    assert res.response_to_noise["y"] < 1.0
    assert "'y'" in str(caught[0].message) and caught[0].filename == __file__


def test_the_ratio_is_the_rms_of_the_fitted_response_over_that_of_the_residual() -> None:
    data = catalog.short_period_flight(seed=2)
    res = aeroid.identify(catalog.short_period(), data, list(catalog.SHORT_PERIOD_TRUTH))
    for k, name in enumerate(res.output_names):
        r = np.asarray(res.residuals[0])[:, k]
        fit = np.asarray(data[name]) - r
        want = np.std(fit) / np.std(r)
        assert res.response_to_noise[name] == pytest.approx(want, rel=1e-9)
        assert want > 1.0  # the doublet excites both outputs


def test_one_excited_output_is_enough() -> None:
    from aeroid.estimation._excitation import warn_unexcited

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_unexcited({"alpha": 0.3, "q": 4.0})
        warn_unexcited({})


def test_the_campaign_flags_a_flat_flight_first_after_failures() -> None:
    ident = {
        "success": True,
        "parameters": {"K": 1.0},
        "stderr": {"K": 0.1},
        "response_to_noise": {"y": 0.2},
    }
    assert flight_status(None, ident, None, None) == "not excited"
    ident["response_to_noise"] = {"y": 5.0}
    assert flight_status(None, ident, None, None) == "ok"
