"""propagate's draws make the result's own interval() statement: Student's t marginals
with each parameter's degrees of freedom, joined by the covariance's correlations."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
from scipy import stats

import aeroid
from aeroid import IdentificationResult, equivalent_system, propagate
from aeroid.models import catalog
from aeroid.uncertainty.propagation import draw_parameters

NAMES = ("Z_alpha", "M_alpha", "M_q", "M_delta")


def _result(dof=None):
    cov = np.array([[0.04, 0.018], [0.018, 0.09]])  # correlation 0.3
    return IdentificationResult(
        parameters={"a": 1.0, "b": 2.0},
        stderr={"a": 0.2, "b": 0.3},
        covariance=cov,
        parameter_names=("a", "b"),
        fixed={},
        covariance_white=cov,
        error_bars="colored" if dof else "white",
        identifiable=True,
        unidentifiable=(),
        success=True,
        message="",
        n_iterations=1,
        cost=0.0,
        method="output_error",
        output_names=("y",),
        noise_covariance=np.eye(1),
        degrees_of_freedom=dof or {},
    )


def _quantile_tolerance(dist, se: float, n: int, p: float = 0.025) -> float:
    """Five standard errors of the sample p-quantile of n draws of se * dist."""
    q = dist.ppf(p)
    return 5.0 * se * math.sqrt(p * (1 - p) / n) / dist.pdf(q)


def _band_matches_interval(result, names, n=200_000, seed=0):
    rows = draw_parameters(result, n, seed)
    iv = result.interval()
    for j, name in enumerate(names):
        nu = result.degrees_of_freedom.get(name, math.inf)
        dist = stats.t(max(nu, 1.0)) if math.isfinite(nu) else stats.norm()
        tol = _quantile_tolerance(dist, result.stderr[name], n)
        lo, hi = np.percentile(rows[:, j], [2.5, 97.5])
        assert lo == pytest.approx(iv[name][0], abs=tol), name
        assert hi == pytest.approx(iv[name][1], abs=tol), name


def test_identity_metric_band_is_the_interval_and_correlations_keep_their_ranks():
    r = _result({"a": 4.0})  # b: none given, the normal
    # t_4's 97.5 % point is 2.776, the normal's 1.960: a 42 % wider band for a
    res = propagate(r, lambda p: p["a"], n_samples=50_000, seed=3)
    tol = _quantile_tolerance(stats.t(4), 0.2, 50_000)
    assert res.percentiles["P2.5"] == pytest.approx(1.0 - 2.7764 * 0.2, abs=tol)
    assert res.percentiles["P97.5"] == pytest.approx(r.interval()["a"][1], abs=tol)
    _band_matches_interval(r, ("a", "b"))
    # the same draws as the normal ones, each column through a monotone map: b (no
    # degrees of freedom) bit for bit, a's ranks (so its rank correlation with b) kept
    t_rows, z_rows = draw_parameters(r, 5000, 7), draw_parameters(_result(), 5000, 7)
    assert np.array_equal(t_rows[:, 1], z_rows[:, 1])
    assert np.array_equal(np.argsort(t_rows[:, 0]), np.argsort(z_rows[:, 0]))
    assert not np.array_equal(t_rows[:, 0], z_rows[:, 0])


def test_a_result_without_degrees_of_freedom_draws_the_same_bits_as_before():
    # pinned from the Gaussian draws before Student's t marginals were added
    rows = draw_parameters(_result(), 3, 5, start=254)
    before = [
        [1.008492216857605, 2.0065586107972413],
        [0.9633109208904251, 2.2652130968877686],
        [1.1185698395605246, 2.31518095457935],
    ]
    np.testing.assert_allclose(rows, before, rtol=0, atol=1e-14)


def test_tail_draws_stay_finite_and_one_degree_of_freedom_is_the_floor():
    r = _result({"a": 0.3, "b": 2.0})  # a below one reads as one, as interval() reads it
    rows = draw_parameters(r, 100_000, 1)
    assert np.all(np.isfinite(rows))
    _band_matches_interval(r, ("a", "b"), n=100_000)


def test_frequency_domain_result_draws_its_own_intervals():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=3, colored=0.9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = aeroid.identify_frequency_domain(model, data, list(NAMES))
    assert all(v < 30 for v in r.degrees_of_freedom.values())  # few: t matters
    _band_matches_interval(r, r.parameter_names)


def test_coloured_fits_propagated_bands_cover_as_their_intervals_do():
    # 60 flights with AR(1) 0.98 residuals (degrees of freedom 6-10): the propagated
    # P2.5-P97.5 band of each parameter and its interval() cover the truth on the same
    # trials but where the truth falls between the band's Monte Carlo end and the
    # interval's (about 1 in 240 here; 8 of 240 with normal draws, whose band is z/t =
    # 0.8-0.87 of the interval's), and the coverage is 0.95's within 3 binomial sd
    truth, model = catalog.SHORT_PERIOD_TRUTH, catalog.short_period()
    hits, differ, trials = 0, 0, 0
    for seed in range(60):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = catalog.short_period_flight(seed=seed, colored=0.98)
            r = aeroid.identify(model, data, list(NAMES))
        iv = r.interval()
        mc = propagate(r, lambda p: {k: p[k] for k in NAMES}, n_samples=4000, seed=seed)
        for k in NAMES:
            band = mc[k].percentile_table["metric"]
            inside = band[2.5] <= truth[k] <= band[97.5]
            hits += inside
            differ += inside != (iv[k][0] <= truth[k] <= iv[k][1])
            trials += 1
    assert differ <= 3
    sd = math.sqrt(0.95 * 0.05 / trials)
    assert abs(hits / trials - 0.95) < 3 * sd


def test_equivalent_system_and_transfer_function_fits_propagate():
    fit = equivalent_system(([5.0, 6.0], [1.0, 3.6, 9.0], 0.07))
    seen = []
    res = propagate(fit, lambda p: seen.append(set(p)) or p["omega"], n_samples=20_000, seed=0)
    # the drawn parameters are the fit's own; T_theta2 is a function of 1/T_theta2
    assert seen[0] == {"K", "1/T_theta2", "zeta", "omega", "tau"}
    se = fit.standard_errors["omega"]
    assert res.mean == pytest.approx(3.0, abs=5 * se / math.sqrt(20_000))
    assert res.std == pytest.approx(se, rel=5 / math.sqrt(2 * 20_000))
    # the fit's covariance over its coefficients, with their degrees of freedom
    tf = fit.fit
    _band_matches_interval(tf, tuple(tf.standard_errors))
    # a parameter without a standard error reaches the metric at its value
    held = dataclasses.replace(tf, standard_errors={"b0": tf.standard_errors["b0"]})
    held = dataclasses.replace(held, covariance=tf.covariance[:1, :1])
    out = propagate(held, lambda p: [p["b0"], p["a1"]], n_samples=100, seed=0)
    assert np.all(out["metric[1]"].samples == tf.parameters["a1"])
    assert out["metric[0]"].std > 0.0
