"""The closed-form distribution functions that replace `scipy.stats` at import time."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from aeroid._stats import chi2_sf, norm_ppf


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 7, 20, 21, 99, 400])
def test_chi2_upper_tail_matches_scipy_over_its_range(dof):
    for q in (1e-9, 0.01, 0.5, 1.0, 3.0, 10.0, 30.0, 100.0, 700.0, 2000.0):
        expected = scipy.stats.chi2.sf(q, dof)
        got = chi2_sf(q, np.int64(dof))
        if expected > 1e-290:
            assert got == pytest.approx(expected, rel=1e-11, abs=0.0)
        else:
            assert got < 1e-280


def test_chi2_edges_and_closed_forms():
    assert chi2_sf(0.0, 3) == 1.0 and chi2_sf(-1.0, 3) == 1.0
    assert chi2_sf(math.inf, 3) == 0.0
    assert math.isnan(chi2_sf(math.nan, 3)) and math.isnan(chi2_sf(2.0, 0))
    assert chi2_sf(3.0, 2) == pytest.approx(math.exp(-1.5), rel=1e-15)  # 2 dof: e^{-q/2}
    assert chi2_sf(2.0, 1) == pytest.approx(math.erfc(1.0), rel=1e-15)  # 1 dof: erfc(sqrt(q/2))


def test_normal_quantiles_match_scipy():
    for p in (1e-12, 1e-4, 0.025, 0.3, 0.5, 0.975, 1 - 0.025 / 41, 1 - 1e-10):
        assert norm_ppf(p) == pytest.approx(scipy.stats.norm.ppf(p), rel=1e-12, abs=1e-14)


def test_importing_the_numerics_does_not_import_scipy_stats():
    import subprocess
    import sys

    code = (
        "import sys, aeroid.estimation.filtering, aeroid.uncertainty.validation, aeroid.uncertainty.propagation; "
        "print('scipy.stats' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_wald_p_value_uses_the_first_positive_definite_covariance() -> None:
    from aeroid._stats import wald_p_value

    b = np.array([1.0, -2.0, 0.5])
    cov = np.diag([0.5, 2.0, 0.25])
    q = float(np.sum(b**2 / np.diag(cov)))  # 2 + 2 + 1
    assert wald_p_value(b, [cov]) == pytest.approx(chi2_sf(q, 3), rel=1e-12)
    assert wald_p_value(b, [cov]) == pytest.approx(scipy.stats.chi2.sf(5.0, 3), rel=1e-12)
    # an indefinite sandwich (its quadratic form could come out negative and read as
    # "no evidence") gives way to the next covariance; none positive definite: p = 0
    indefinite = np.diag([0.5, -2.0, 0.25])
    assert wald_p_value(b, [indefinite, cov]) == wald_p_value(b, [cov])
    assert wald_p_value(b, [indefinite]) == 0.0
