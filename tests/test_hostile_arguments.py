"""Arguments an independent test suite passed that numpy, not AeroID, refused (or nobody
did): each is now an `AeroidError` naming the argument at fault."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid
from aeroid.errors import (
    AdapterError,
    InferenceError,
    ModelDefinitionError,
    PropagationError,
    SimulationError,
)
from aeroid.models import catalog


def _decay() -> aeroid.Model:
    return aeroid.Model(["x"], [], {"k": 0.7}, lambda t, x, u, p: -p["k"] * x)


@pytest.fixture(scope="module")
def sim() -> aeroid.SimulationResult:
    return _decay().simulate(np.linspace(0.0, 2.0, 41), None, [1.0])


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"noise": {"x": -1.0}, "seed": 0}, r"noise\['x'\]: expected a standard deviation >= 0"),
        ({"noise": {"x": "a"}, "seed": 0}, r"noise\['x'\]"),
        ({"noise": {"x": float("nan")}, "seed": 0}, r"noise\['x'\]"),
        ({"noise": 0.1, "seed": 0}, "noise: expected a dict"),
        ({"noise": {"x": 0.1}, "seed": "a"}, "seed: expected a non-negative integer"),
        ({"noise": {"x": 0.1}, "seed": -3}, "seed"),
        ({"noise": {"x": 0.1}, "seed": 1.5}, "seed"),
        ({"noise": {"x": 0.1}}, "needs a seed"),
    ],
)
def test_to_flight_data_names_bad_noise_and_seeds(sim, options, match):
    with pytest.raises(SimulationError, match=match):
        sim.to_flight_data(**options)


def test_to_flight_data_noise_is_still_seeded_and_unknown_outputs_named(sim):
    a = sim.to_flight_data(noise={"x": 0.1}, seed=3)
    b = sim.to_flight_data(noise={"x": 0.1}, seed=3)
    np.testing.assert_array_equal(a["x"], b["x"])
    assert np.std(a["x"] - sim.output("x")) > 0.05
    with pytest.raises(aeroid.ChannelError, match="'y'"):
        sim.to_flight_data(noise={"y": 0.1}, seed=0)


def test_catalog_flight_names_a_bad_seed():
    with pytest.raises(SimulationError, match="seed"):
        catalog.short_period_flight(seed="x")
    with pytest.raises(SimulationError, match="needs a seed"):
        catalog.short_period_flight(seed=None)


@pytest.mark.parametrize("seed", ["x", -1, 1.5, True])
def test_orthogonal_multisine_names_a_bad_seed(seed):
    with pytest.raises(ModelDefinitionError, match="seed"):
        aeroid.orthogonal_multisine(
            ["u1"], duration=10.0, sample_rate=20.0, band=(0.1, 2.0), seed=seed
        )


@pytest.mark.parametrize("substeps", ["x", 0, 2.5, True, 10**9])
def test_simulate_rk4_names_bad_substeps(substeps):
    pytest.importorskip("jax")
    with pytest.raises(AdapterError, match="substeps must be a positive integer of at most"):
        aeroid.simulate_rk4(_decay(), np.arange(3) * 0.05, x0=[1.0], substeps=substeps)


def test_sampler_diagnostics_name_text_input():
    for fn in (aeroid.autocorrelation_time, aeroid.effective_sample_size, aeroid.split_r_hat):
        with pytest.raises(InferenceError, match="expected an array of numbers"):
            fn("abc")
        with pytest.raises(InferenceError, match="complex"):
            fn(np.ones((20, 2)) * 1j)


def test_propagation_error_is_public():
    assert aeroid.PropagationError is PropagationError
    assert issubclass(PropagationError, aeroid.AeroidError)
    data = catalog.short_period_flight(seed=0)
    fit = aeroid.identify(catalog.short_period(), data, list(catalog.SHORT_PERIOD_TRUTH))
    with pytest.raises(aeroid.PropagationError, match="n_samples"):
        aeroid.propagate(fit, lambda p: p["M_q"], n_samples=0, seed=0)


def test_an_output_listed_twice_is_refused_everywhere():
    """Filtering or fitting one channel twice counts it as two independent measurements
    (filter error's sigma2 read 0.47 where one copy gives 0.89)."""
    import warnings

    data = catalog.short_period_flight(seed=0)
    model = catalog.short_period()
    q = {"alpha": 1e-6, "q": 1e-6}
    calls = [
        lambda: aeroid.identify(model, data, ["M_q"], outputs=["q", "q"]),
        lambda: aeroid.identify(
            model, data, ["M_q"], method="filter_error", outputs=["q", "q"], process_noise=q
        ),
        lambda: aeroid.validate(model, data, None, outputs=["q", "q"]),
        lambda: aeroid.filter_states(
            model, data, process_noise=q, measurement_noise={"q": 1e-4}, outputs=["q", "q"]
        ),
        lambda: aeroid.sensitivities(model, data, outputs=["q", "q"], noise={"q": 0.01}),
        lambda: aeroid.frequency_response(model, data, None, outputs=["q", "q"]),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for call in calls:
            with pytest.raises(aeroid.AeroidError, match=r"twice|more than once"):
                call()
