"""Standard errors are standard deviations; intervals take Student's t with each
estimate's degrees of freedom (issue 48: the t quantile no longer hides in the bar)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

import aeroid
from aeroid.models import catalog


def _regression(phi: float, seed: int = 3, n: int = 600) -> aeroid.RegressionResult:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 2))
    e = np.zeros(n)
    w = rng.standard_normal(n)
    for t in range(1, n):
        e[t] = phi * e[t - 1] + w[t]
    z = 0.5 + x @ np.array([1.0, -2.0]) + 0.1 * e
    return aeroid.equation_error(x, z, error_bars="white" if phi == 0 else "colored")


def test_white_regression_interval_is_the_classical_t_interval() -> None:
    res = _regression(0.0)
    n, p = res.n_samples, len(res.parameter_names)
    assert set(res.degrees_of_freedom.values()) == {float(n - p)}
    q = scipy.stats.t.ppf(0.975, n - p)
    for name, half in res.margin(0.95).items():
        assert half == pytest.approx(q * res.stderr[name], rel=1e-12)
    lo, hi = res.interval(0.9)["x1"]
    q90 = scipy.stats.t.ppf(0.95, n - p)
    assert (hi - lo) / 2 == pytest.approx(q90 * res.stderr["x1"], rel=1e-12)
    assert (hi + lo) / 2 == pytest.approx(res.parameters["x1"], rel=1e-12)


def test_coloured_bars_are_the_sandwich_and_the_interval_carries_the_t() -> None:
    from aeroid import _stats

    res = _regression(0.95)
    # the standard error is the square root of the covariance's diagonal, nothing more
    np.testing.assert_allclose(
        [res.stderr[n] for n in res.parameter_names], np.sqrt(np.diag(res.covariance))
    )
    nu = np.array([res.degrees_of_freedom[n] for n in res.parameter_names])
    assert np.all(nu < res.n_samples - 3)  # slow residuals: far fewer degrees of freedom
    q = _stats.t_quantile(nu, 0.95)
    np.testing.assert_allclose(q, scipy.stats.t.ppf(0.975, nu), rtol=1e-10)
    half = res.margin()
    np.testing.assert_allclose(
        [half[n] for n in res.parameter_names], q * np.sqrt(np.diag(res.covariance))
    )


def test_output_error_white_dof_is_observations_less_estimates() -> None:
    model = catalog.short_period()
    names = list(catalog.SHORT_PERIOD_TRUTH)
    data = catalog.short_period_flight(seed=1)
    res = aeroid.identify(model, data, names, error_bars="white")
    n_obs = sum(int(np.asarray(r).size) for r in res.residuals)
    n_est = len(res.parameters) + len(res.extra_stderr)
    assert {res.degrees_of_freedom[n] for n in names} == {float(n_obs - n_est)}
    q = scipy.stats.t.ppf(0.975, n_obs - n_est)
    for n in names:
        assert res.margin()[n] == pytest.approx(q * res.stderr[n], rel=1e-12)
        lo, hi = res.interval()[n]
        assert lo < res.parameters[n] < hi


def test_an_interval_level_outside_zero_one_is_refused() -> None:
    res = _regression(0.0)
    for level in (0.0, 1.0, 95.0):
        with pytest.raises(aeroid.IdentificationError, match="level"):
            res.margin(level)
