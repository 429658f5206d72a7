"""Calibration of the error bars over many seeded flights (slow).

The issue's bands are 93–97 % for white noise and >= 90 % for AR(1) noise.
With n seeds the empirical coverage of a 95 % interval has a binomial
standard deviation of sqrt(0.95 * 0.05 / n): 1.5 % at 200, where 93–97 % is
only ±1.3 standard deviations and a calibrated method fails one of four
parameters about half the time (blocks of 200 seeds of the white-noise case
range over 0.92–0.975). The white-noise case therefore runs 1000 seeds
(0.69 %, the band ±2.9 standard deviations); the AR(1) case, whose band is
one-sided and 5 % below nominal, keeps 200.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import identify
from aeroid.models import catalog

NAMES = list(catalog.SHORT_PERIOD_TRUTH)
TRUTH = np.array(list(catalog.SHORT_PERIOD_TRUTH.values()))


def _coverage(colored: float, seeds: int = 200) -> tuple[np.ndarray, np.ndarray]:
    model = catalog.short_period()
    hits = np.zeros(len(NAMES))
    hits_white = np.zeros(len(NAMES))
    for seed in range(seeds):
        r = identify(model, catalog.short_period_flight(seed=seed, colored=colored), NAMES)
        est = np.array([r.parameters[n] for n in NAMES])
        half = r.margin(0.95)  # the result's own 95 % interval (t with its dof)
        se_w = np.array([r.stderr_white[n] for n in NAMES])
        hits += np.abs(est - TRUTH) <= np.array([half[n] for n in NAMES])
        hits_white += np.abs(est - TRUTH) <= 1.96 * se_w
    return hits / seeds, hits_white / seeds


@pytest.mark.slow
def test_white_noise_coverage_is_nominal():
    cover, _ = _coverage(0.0, seeds=1000)
    assert np.all((cover >= 0.93) & (cover <= 0.97)), cover


@pytest.mark.slow
def test_colored_noise_coverage_holds_where_classical_bounds_fail():
    cover, cover_white = _coverage(0.9)
    assert np.all(cover >= 0.90), cover
    # The classical white-residual bounds are far too small here.
    assert np.all(cover_white < 0.6), cover_white
