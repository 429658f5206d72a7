"""Shared fixtures: the short-period truth case used across the suite."""

from __future__ import annotations

import os

# Small matrices run far faster single-threaded on a 2-core machine; this must be
# set before numpy loads its BLAS.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import matplotlib  # noqa: E402
import pytest  # noqa: E402

matplotlib.use("Agg")

from aeroid.models import catalog  # noqa: E402


@pytest.fixture
def sp_model():
    """The spec's short-period model at the initial guesses."""
    return catalog.short_period()


@pytest.fixture
def sp_truth():
    return dict(catalog.SHORT_PERIOD_TRUTH)


@pytest.fixture
def sp_clean():
    """Noise-free truth-case record (10 s, 50 Hz, doublet)."""
    return catalog.short_period_flight(noise={})


@pytest.fixture
def sp_noisy():
    """Noisy truth-case record (σ 0.005 rad alpha, 0.01 rad/s q), seed 0."""
    return catalog.short_period_flight(seed=0)
