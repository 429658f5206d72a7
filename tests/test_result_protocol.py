"""Every estimator's result shares one shape: parameters, standard errors, covariance,
summary() and plot()."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import aeroid
from aeroid._records import ESTIMATE_PROTOCOL

RESULTS = (
    "IdentificationResult",
    "FrequencyDomainResult",
    "CompatibilityResult",
    "RegressionResult",
    "StepwiseResult",
    "TransferFunctionFit",
    "EquivalentSystemFit",
    "InferenceResult",
)


@pytest.mark.parametrize("name", RESULTS)
def test_every_estimator_result_offers_the_protocol(name: str) -> None:
    cls = getattr(aeroid, name)
    fields = {f.name for f in dataclasses.fields(cls)}
    missing = [m for m in ESTIMATE_PROTOCOL if m not in fields and not hasattr(cls, m)]
    assert not missing, (name, missing)


def test_stderr_and_standard_errors_are_one_mapping() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((200, 2))
    y = 1.5 * x[:, 0] - 0.5 * x[:, 1] + 0.1 * rng.standard_normal(200)
    fit = aeroid.equation_error({"y": y, "a": x[:, 0], "b": x[:, 1]}, "y", ["a", "b"])
    assert fit.standard_errors is fit.stderr
    np.testing.assert_allclose(
        [fit.stderr[k] for k in fit.parameter_names], np.sqrt(np.diag(fit.covariance))
    )


def test_equivalent_system_covariance_is_the_delta_method_one() -> None:
    rng = np.random.default_rng(1)
    w = np.geomspace(0.5, 15.0, 60)
    s = 1j * w
    h = 4.0 * (s + 1.2) / (s**2 + 2 * 0.6 * 3.0 * s + 9.0) * np.exp(-0.05 * s)
    h = h * (1 + 0.03 * rng.standard_normal(w.size)) * np.exp(0.02j * rng.standard_normal(w.size))
    ch = aeroid.ResponseChannel("stick", "q", w, h, coherence=np.full(w.size, 0.95))
    fit = aeroid.equivalent_system(ch)
    cov = np.asarray(fit.covariance)
    names = list(fit.standard_errors)
    assert cov.shape == (len(names), len(names))
    se = np.array([fit.stderr[n] for n in names])
    ok = np.isfinite(se)
    np.testing.assert_allclose(np.sqrt(np.diag(cov))[ok], se[ok], rtol=1e-9)
    np.testing.assert_allclose(cov[np.ix_(ok, ok)], cov[np.ix_(ok, ok)].T, rtol=1e-9, atol=0)


def test_intervals_are_one_method_on_every_result() -> None:
    # equation error: the t interval; stepwise: its final regression's
    rng = np.random.default_rng(2)
    x = rng.standard_normal((300, 2))
    y = 1.5 * x[:, 0] - 0.5 * x[:, 1] + 0.1 * rng.standard_normal(300)
    data = {"y": y, "a": x[:, 0], "b": x[:, 1]}
    fit = aeroid.equation_error(data, "y", ["a", "b"])
    sw = aeroid.stepwise_regression(data, "y", ["a", "b"])
    assert dict(sw.margin()) == dict(sw.regression.margin())
    lo, hi = fit.interval(0.9)["a"]
    assert lo < fit.parameters["a"] < hi


@pytest.mark.filterwarnings("ignore:the chain has not converged")
def test_posterior_intervals_are_the_samples_quantiles() -> None:
    from aeroid.models import catalog

    model = catalog.first_order()
    t = np.arange(0.0, 6.0, 0.05)
    u = catalog.doublet(t, start=1.0, width=1.0, amplitude=1.0)
    y = np.asarray(model.simulate(t, {"u": u}, {"y": 0.0}).outputs)[:, 0]
    y = y + 0.02 * np.random.default_rng(0).standard_normal(t.size)
    data = aeroid.FlightData(time=t, channels={"y": y, "u": u})
    post = aeroid.infer(
        model,
        data,
        parameters={"K": aeroid.Normal(2.0, 1.0), "tau": aeroid.Normal(0.5, 0.5)},
        noise={"y": 0.02},
        n_walkers=8,
        n_steps=300,
        burn_in=100,
        seed=0,
    )
    samples = np.asarray(post.samples)
    for j, n in enumerate(post.parameter_names):
        lo, hi = post.interval(0.9)[n]
        np.testing.assert_allclose([lo, hi], np.quantile(samples[:, j], [0.05, 0.95]))
        assert post.margin(0.9)[n] == pytest.approx((hi - lo) / 2)
