"""Priors: normalised densities (closed forms), seeded sampling, support, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.stats

from aeroid import AeroidError, HalfNormal, InferenceError, LogUniform, Normal, Prior, Uniform

PRIORS = [
    (Normal(-4.0, 2.0), scipy.stats.norm(-4.0, 2.0)),
    (Uniform(-1.0, 3.0), scipy.stats.uniform(-1.0, 4.0)),
    (LogUniform(0.01, 10.0), scipy.stats.loguniform(0.01, 10.0)),
    (HalfNormal(0.5), scipy.stats.halfnorm(0.0, 0.5)),
]


@pytest.mark.parametrize(("prior", "ref"), PRIORS)
def test_log_pdf_matches_closed_form(prior: Prior, ref) -> None:
    lo, hi = prior.support
    x = np.linspace(max(lo, -12.0), min(hi, 12.0), 41)[1:-1]
    np.testing.assert_allclose(prior.log_pdf(x), ref.logpdf(x), rtol=1e-12, atol=1e-12)
    assert prior.log_pdf(x).shape == x.shape
    assert isinstance(prior.log_pdf(float(x[3])), float)
    # the density integrates to one over the support
    f = lambda t: math.exp(prior.log_pdf(t))  # noqa: E731
    total = scipy.integrate.quad(f, lo, hi, limit=200)[0]
    assert total == pytest.approx(1.0, rel=1e-7)


@pytest.mark.parametrize(("prior", "ref"), PRIORS)
def test_center_scale_support(prior: Prior, ref) -> None:
    assert prior.center == pytest.approx(ref.median(), rel=1e-12)
    assert prior.scale == pytest.approx(ref.std(), rel=1e-12)
    lo, hi = prior.support
    assert (lo, hi) == pytest.approx(ref.support())
    if math.isfinite(lo):
        assert prior.log_pdf(lo - 1e-9) == -math.inf
    if math.isfinite(hi):
        assert prior.log_pdf(hi + 1e-9) == -math.inf


@pytest.mark.parametrize(("prior", "ref"), PRIORS)
def test_sampling_is_seeded_and_matches_moments(prior: Prior, ref) -> None:
    n = 40_000
    a = prior.sample(np.random.default_rng(7), n)
    b = prior.sample(np.random.default_rng(7), n)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (n,)
    lo, hi = prior.support
    assert np.all((a >= lo) & (a <= hi))
    # the sample mean is within 5 standard errors of the true mean
    assert abs(a.mean() - ref.mean()) < 5 * ref.std() / math.sqrt(n)
    # Kolmogorov-Smirnov against the reference distribution
    assert scipy.stats.kstest(a, ref.cdf).pvalue > 1e-3


def test_priors_are_frozen_values() -> None:
    p = Normal(1, 2)
    with pytest.raises(AttributeError):
        p.mu = 3.0  # type: ignore[misc]
    assert p == Normal(1.0, 2.0)
    assert "sigma=2.0" in repr(p)


@pytest.mark.parametrize(
    ("make", "arg"),
    [
        (lambda: Normal(0.0, 0.0), "sigma"),
        (lambda: Normal(0.0, -1.0), "sigma"),
        (lambda: Normal(float("nan"), 1.0), "mu"),
        (lambda: Normal("a", 1.0), "mu"),
        (lambda: Uniform(1.0, 1.0), "lo must be < hi"),
        (lambda: Uniform(2.0, 1.0), "lo must be < hi"),
        (lambda: Uniform(0.0, float("inf")), "hi"),
        (lambda: LogUniform(0.0, 1.0), "lo must be > 0"),
        (lambda: LogUniform(-1.0, 1.0), "lo must be > 0"),
        (lambda: LogUniform(2.0, 1.0), "lo must be < hi"),
        (lambda: HalfNormal(0.0), "sigma"),
        (lambda: HalfNormal(-2.0), "sigma"),
    ],
)
def test_invalid_arguments_raise(make, arg: str) -> None:
    with pytest.raises(InferenceError, match=arg) as info:
        make()
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, AeroidError)


@pytest.mark.parametrize(
    ("make", "culprit"),
    [
        (lambda: Normal("0", 1.0), "mu"),
        (lambda: Normal(True, 1.0), "mu"),
        (lambda: Uniform("0", 1.0), "lo"),
        (lambda: LogUniform(True, 2.0), "lo"),
        (lambda: HalfNormal("1"), "sigma"),
    ],
)
def test_prior_refuses_text_and_bools(make, culprit):
    with pytest.raises(InferenceError, match=culprit):
        make()


def test_prior_methods_name_bad_arguments() -> None:
    rng = np.random.default_rng(0)
    for prior in (Normal(0.0, 1.0), Uniform(0.0, 1.0), LogUniform(0.1, 1.0), HalfNormal(1.0)):
        name = type(prior).__name__
        with pytest.raises(AeroidError, match=rf"{name}.log_pdf: x: not numeric"):
            prior.log_pdf("x")
        for size in (-1, 1.5, (2, -3), True):
            with pytest.raises(AeroidError, match=rf"{name}.sample: size must be a count"):
                prior.sample(rng, size)
        assert prior.sample(rng, (2, 3)).shape == (2, 3) and np.ndim(prior.sample(rng)) == 0
