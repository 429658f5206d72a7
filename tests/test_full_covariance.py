"""Every estimate's covariance together: parameters, initial states, biases, noise levels."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog


def _static(rng: np.random.Generator) -> tuple[aeroid.Model, aeroid.FlightData, np.ndarray]:
    # y = a u1 + c u2 with an output bias: output error is least squares on [u1, u2, 1]
    n = 400
    t = np.arange(n) * 0.05
    u = np.column_stack([np.sin(0.7 * t) + 0.3 * rng.standard_normal(n), np.cos(0.3 * t)])
    y = 1.5 * u[:, 0] - 0.4 * u[:, 1] + 0.2 + 0.05 * rng.standard_normal(n)
    model = aeroid.Model(
        states=["x"],
        controls=["u1", "u2"],
        parameters={"a": 1.0, "c": 0.0},
        dynamics=lambda t, x, u, p: 0.0 * x,
        outputs=["y"],
        measurement=lambda t, x, u, p: np.stack([p["a"] * u[0] + p["c"] * u[1] + x[0]]),
    )
    data = aeroid.FlightData(t, {"u1": u[:, 0], "u2": u[:, 1], "y": y})
    return model, data, np.column_stack([u, np.ones(n)])


def test_full_covariance_is_least_squares_with_the_bias() -> None:
    model, data, x = _static(np.random.default_rng(3))
    fit = aeroid.identify(
        model, data, ["a", "c"], estimate_bias=["y"], x0=[0.0], error_bars="white"
    )
    assert fit.full_names == ("a", "c", "bias[0].y")
    r = fit.noise_covariance[0, 0]
    np.testing.assert_allclose(fit.full_covariance, r * np.linalg.inv(x.T @ x), rtol=1e-6)
    np.testing.assert_array_equal(fit.full_covariance[:2, :2], fit.covariance)
    assert fit.full_covariance[2, 2] == pytest.approx(fit.extra_stderr["bias[0].y"] ** 2)
    assert not fit.full_covariance.flags.writeable


def test_full_covariance_matches_the_bars_it_extends() -> None:
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    data = catalog.short_period_flight(seed=58)
    fit = aeroid.identify(catalog.short_period(), data, names, estimate_bias=["q"])
    k = len(fit.parameter_names)
    np.testing.assert_array_equal(fit.full_covariance[:k, :k], fit.covariance)
    for j, name in enumerate(fit.full_names[k:], start=k):
        assert np.sqrt(fit.full_covariance[j, j]) == pytest.approx(fit.extra_stderr[name])
    # a state-equation bias is renamed in both places
    model = catalog.short_period()
    fit = aeroid.identify(model, data, names, estimate_bias={"q": "state"})
    assert set(fit.full_names[k:]) == set(fit.extra_stderr)


def test_filter_error_and_frequency_domain_carry_it_too() -> None:
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    data = catalog.short_period_flight(seed=58)
    fe = aeroid.identify(
        catalog.short_period(),
        data,
        names,
        method="filter_error",
        process_noise={"alpha": 1e-5, "q": 1e-5},
        estimate_process_noise=True,
    )
    k = len(fe.parameter_names)
    assert fe.full_names[:k] == fe.parameter_names
    np.testing.assert_allclose(fe.full_covariance[:k, :k], fe.covariance, rtol=1e-12)
    for j, name in enumerate(fe.full_names[k:], start=k):
        # the noise levels' errors are on their own scale, as extra_stderr gives them
        assert np.sqrt(fe.full_covariance[j, j]) == pytest.approx(
            fe.extra_stderr[name], nan_ok=True
        )
    fd = aeroid.identify_frequency_domain(
        catalog.short_period(), data, names, frequencies=np.linspace(0.1, 1.5, 30)
    )
    k = len(fd.parameter_names)
    np.testing.assert_array_equal(fd.full_covariance[:k, :k], fd.covariance)
    assert set(fd.full_names[k:]) == set(fd.extra_stderr)
