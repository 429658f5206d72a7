"""Recursive least squares against the batch solutions it must equal at every sample."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid


def _record(n: int = 400, seed: int = 0, noise: float = 0.05) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    a = np.sin(1.3 * t) + 0.3 * rng.normal(size=n)
    b = np.cos(0.7 * t) * np.exp(-0.1 * t) + 0.2 * rng.normal(size=n)
    c = np.sign(np.sin(2.1 * t))
    z = 0.4 - 1.2 * a + 2.5 * b + 0.8 * c + noise * rng.normal(size=n)
    return {"a": a, "b": b, "c": c, "z": z}


def _weighted_solution(x, z, lam, theta0, p0):
    """The minimiser of the exponentially weighted cost with the start's term, and the cost."""
    n = x.shape[0]
    w = lam ** np.arange(n - 1, -1, -1.0)
    prior = lam**n * np.linalg.inv(p0)
    m = (x * w[:, None]).T @ x + prior
    theta = np.linalg.solve(m, (x * w[:, None]).T @ z + prior @ theta0)
    r = z - x @ theta
    cost = float(w @ r**2 + (theta - theta0) @ prior @ (theta - theta0))
    return theta, cost


def test_diffuse_start_without_forgetting_is_the_batch_estimator():
    d = _record()
    names = ["a", "b", "c"]
    rls = aeroid.recursive_least_squares(d, "z", names, initial_covariance=1e10)
    batch = aeroid.equation_error(d, "z", names)
    white = aeroid.equation_error(d, "z", names, error_bars="white")
    assert rls.parameter_names == ("const", "a", "b", "c")
    assert rls.error_bars == "colored" and rls.forgetting == 1.0
    for k in rls.parameter_names:
        assert rls.parameters[k] == pytest.approx(batch.parameters[k], rel=1e-6, abs=1e-9)
        assert rls.stderr[k] == pytest.approx(batch.stderr[k], rel=1e-5)
        j = rls.parameter_names.index(k)
        assert rls.stderr_history[-1, j] == pytest.approx(white.stderr[k], rel=1e-5)
    # each sample's estimate is the batch least squares of the samples so far
    x = np.column_stack([np.ones(d["z"].size), d["a"], d["b"], d["c"]])
    for k in (10, 57, 200):
        exact = np.linalg.lstsq(x[: k + 1], d["z"][: k + 1], rcond=None)[0]
        np.testing.assert_allclose(rls.history[k], exact, rtol=1e-6, atol=1e-8)
    # and its running fit error is the batch one of those samples
    k = 120
    exact = np.linalg.lstsq(x[: k + 1], d["z"][: k + 1], rcond=None)[0]
    res = d["z"][: k + 1] - x[: k + 1] @ exact
    s = np.sqrt(res @ res / (k + 1 - 4))
    assert rls.fit_error_history[k] == pytest.approx(s, rel=1e-6)
    assert np.all(np.isnan(rls.stderr_history[:4]))  # no more samples than parameters


@pytest.mark.parametrize("lam", [0.999, 0.97, 0.9])
def test_forgetting_minimises_the_exponentially_weighted_cost(lam):
    d = _record(n=300, seed=1)
    x = np.column_stack([d["a"], d["b"], d["c"]])
    theta0 = np.array([-1.0, 2.0, 0.5])
    p0 = np.diag([10.0, 4.0, 1.0])
    rls = aeroid.recursive_least_squares(
        x, d["z"] - 0.4, ["a", "b", "c"], intercept=False, forgetting=lam,
        initial=dict(zip(["a", "b", "c"], theta0, strict=True)), initial_covariance=p0,
    )  # fmt: skip
    assert rls.error_bars == "white"
    for k in (40, 150, 299):
        theta, cost = _weighted_solution(x[: k + 1], d["z"][: k + 1] - 0.4, lam, theta0, p0)
        np.testing.assert_allclose(rls.history[k], theta, rtol=1e-9, atol=1e-11)
        # the noise variance is unbiased for the weighting: the cost over
        # sum w - tr(P Q), Q the information with the weights squared
        w = lam ** np.arange(k, -1, -1.0)
        xk = x[: k + 1]
        p_k = np.linalg.inv((xk * w[:, None]).T @ xk + lam ** (k + 1) * np.linalg.inv(p0))
        q_k = (xk * w[:, None] ** 2).T @ xk
        s2 = cost / (w.sum() - np.trace(p_k @ q_k))
        assert rls.fit_error_history[k] ** 2 == pytest.approx(s2, rel=1e-9)
        sandwich = s2 * p_k @ q_k @ p_k
        np.testing.assert_allclose(rls.stderr_history[k], np.sqrt(np.diag(sandwich)), rtol=1e-8)
        assert rls.dof_history[k, 0] == pytest.approx(w.sum() ** 2 / (w @ w) - 3, rel=1e-12)
    # the final covariance is the weighted estimate's sandwich s^2 P Q P
    np.testing.assert_allclose(rls.covariance, sandwich, rtol=1e-8)


def _coverage(lam: float, seeds: int, n: int, at: int) -> tuple[np.ndarray, np.ndarray]:
    """How often the final and the running 95 % intervals hold the truth."""
    from scipy import stats

    truth = np.array([0.5, 2.0, -1.5])
    final = np.zeros(3)
    running = np.zeros(3)
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        x1, x2 = rng.standard_normal((2, n))
        z = truth[0] + truth[1] * x1 + truth[2] * x2 + 0.1 * rng.standard_normal(n)
        rls = aeroid.recursive_least_squares(
            {"z": z, "x1": x1, "x2": x2}, "z", ["x1", "x2"], forgetting=lam
        )
        bounds = rls.interval(0.95)
        final += [lo <= v <= hi for (lo, hi), v in zip(bounds.values(), truth, strict=True)]
        half = stats.t.ppf(0.975, rls.dof_history[at]) * rls.stderr_history[at]
        running += np.abs(rls.history[at] - truth) <= half
    return final / seeds, running / seeds


def test_forgetting_intervals_cover_at_the_nominal_rate():
    # with lambda = 0.98 the classical s^2 P bars were sqrt(1 + lambda) too wide
    # (coverage 0.995); the sandwich s^2 P Q P covers at 95 %
    seeds = 240
    band = 3.0 * np.sqrt(0.95 * 0.05 / seeds)
    final, running = _coverage(0.98, seeds, n=400, at=250)
    assert np.all(np.abs(final - 0.95) < band), final
    assert np.all(np.abs(running - 0.95) < band), running


def test_without_forgetting_the_bars_are_the_classical_ones():
    d = _record(n=200, seed=5)
    x = np.column_stack([np.ones(200), d["a"], d["b"], d["c"]])
    rls = aeroid.recursive_least_squares(d, "z", ["a", "b", "c"], error_bars="white")
    k = 150
    info = x[: k + 1].T @ x[: k + 1] + np.eye(4) / 1e6
    theta = np.linalg.solve(info, x[: k + 1].T @ d["z"][: k + 1])
    r = d["z"][: k + 1] - x[: k + 1] @ theta
    s2 = (r @ r + theta @ theta / 1e6) / (k + 1 - 4)
    se = np.sqrt(s2 * np.diag(np.linalg.inv(info)))
    np.testing.assert_allclose(rls.stderr_history[k], se, rtol=1e-9)
    assert rls.dof_history[k, 0] == k + 1 - 4
    np.testing.assert_allclose(rls.covariance, rls.fit_error_history[-1] ** 2 * np.linalg.inv(
        x.T @ x + np.eye(4) / 1e6), rtol=1e-8)  # fmt: skip


def test_forgetting_tracks_a_derivative_that_changes_and_memory_does_not():
    n = 1000
    d = _record(n=n, seed=2, noise=0.02)
    step = np.where(np.arange(n) < n // 2, 2.5, 1.5)  # b's coefficient drops at mid-record
    z = (
        0.4
        - 1.2 * d["a"]
        + step * d["b"]
        + 0.8 * d["c"]
        + 0.02 * np.random.default_rng(3).normal(size=n)
    )
    data = dict(d, z=z)
    fading = aeroid.recursive_least_squares(data, "z", ["a", "b", "c"], forgetting=0.98)
    whole = aeroid.recursive_least_squares(data, "z", ["a", "b", "c"])
    assert fading.parameters["b"] == pytest.approx(1.5, abs=0.05)
    assert fading.parameter("b")[n // 2 - 1] == pytest.approx(2.5, abs=0.05)
    assert whole.parameters["b"] > 2.0  # remembering both halves, the first weighing more
    assert "memory about 50 samples" in fading.summary()


def test_prediction_errors_and_gains_follow_the_update():
    d = _record(n=80, seed=4)
    rls = aeroid.recursive_least_squares(d, "z", ["a", "b"], initial_covariance=100.0)
    x = np.column_stack([np.ones(80), d["a"], d["b"]])
    before = np.vstack([np.zeros(3), rls.history[:-1]])
    np.testing.assert_allclose(rls.prediction_errors, d["z"] - np.sum(x * before, axis=1))
    np.testing.assert_allclose(
        rls.history - before, rls.gain_history * rls.prediction_errors[:, None], atol=1e-12
    )


def test_result_is_a_frozen_record():
    t = np.arange(200) * 0.05
    d = _record(n=200)
    fd = aeroid.FlightData(t, d)
    rls = aeroid.recursive_least_squares(fd, "z", ["a", "b", "c"])
    np.testing.assert_array_equal(rls.time, t)
    for name in ("history", "stderr_history", "gain_history", "covariance", "time"):
        assert not getattr(rls, name).flags.writeable
    with pytest.raises(TypeError):
        rls.parameters["a"] = 0.0  # type: ignore[index]
    with pytest.raises(aeroid.ChannelError, match="'d'"):
        rls.parameter("d")
    lo, hi = rls.interval()["a"]
    assert lo < rls.parameters["a"] < hi
    assert "Recursive least squares for z" in rls.summary()
    assert "| b " in rls.summary()


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"forgetting": 0.0}, "forgetting"),
        ({"forgetting": 1.5}, "forgetting"),
        ({"forgetting": "0.9"}, "forgetting"),
        ({"forgetting": float("nan")}, "forgetting"),
        ({"forgetting": 0.95, "error_bars": "colored"}, "error_bars"),
        ({"error_bars": "bogus"}, "error_bars"),
        ({"intercept": "yes"}, "intercept"),
        ({"initial": {"q": 1.0}}, "'q'"),
        ({"initial": [1.0]}, "initial"),
        ({"initial": {"a": "x"}}, r"initial\['a'\]"),
        ({"initial_covariance": -1.0}, "initial_covariance"),
        ({"initial_covariance": np.eye(3)}, "initial_covariance"),
        ({"initial_covariance": np.array([[1.0, 0.5], [0.0, 1.0]])}, "symmetric"),
        ({"initial_covariance": np.array([[1.0, 2.0], [2.0, 1.0]])}, "positive definite"),
        ({"initial_covariance": np.array([[1.0, np.nan], [np.nan, 1.0]])}, "NaN"),
    ],
)
def test_bad_options_are_named(options, match):
    d = _record(n=50)
    with pytest.raises(aeroid.DataFormatError, match=match):
        aeroid.recursive_least_squares(d, "z", ["a"], **options)  # const and a: 2 x 2


def test_bad_data_is_named():
    d = _record(n=50)
    with pytest.raises(aeroid.ChannelError, match="'q'"):
        aeroid.recursive_least_squares(aeroid.FlightData(np.arange(50.0), d), "z", ["q"])
    bad = dict(d, z=np.where(np.arange(50) == 7, np.nan, d["z"]))
    with pytest.raises(aeroid.DataFormatError, match="sample 7"):
        aeroid.recursive_least_squares(bad, "z", ["a"])
    with pytest.raises(aeroid.IdentificationError, match="3 samples"):
        aeroid.recursive_least_squares({k: v[:3] for k, v in d.items()}, "z", ["a", "b"])


def test_what_the_regressors_cannot_separate_keeps_the_starts_bars():
    """Collinear or constant regressors: the batch fit refuses them; the recursion runs
    on its start, and the coloured sandwich (which sees no data along that direction)
    read a = 0.667 +- 0.005 for a truth of 1. The start's covariance is what bounds it."""
    d = _record(n=200, seed=5)
    tied = dict(d, tied=2.0 * d["a"] - d["b"])
    with pytest.warns(aeroid.IdentifiabilityWarning, match="'tied'"):
        res = aeroid.recursive_least_squares(tied, "z", ["a", "b", "tied"])
    assert res.error_bars == "white"
    lo, hi = res.interval()["a"]
    assert lo < -1.2 < hi and hi - lo > 10.0
    with pytest.warns(aeroid.IdentifiabilityWarning, match="'flat'"):
        flat = aeroid.recursive_least_squares(dict(d, flat=np.full(200, 3.0)), "z", ["a", "flat"])
    assert flat.stderr["const"] > 100.0


def test_nearly_collinear_regressors_keep_the_starts_share():
    """x2 = x1 + 1e-8 w: the batch fit still runs, but the data tell x1 from x2 by
    nothing the start does not outweigh, so the estimates rest on it (1.49 and 1.49
    for a truth of 1 and 2). The coloured sandwich alone read +-0.045 (11 sigma off);
    the start's share s^2 P P0^-1 P brings back the classical bars there, and leaves a
    well-separated pair's coloured bars as they were."""
    rng = np.random.default_rng(0)
    n = 1000
    t = np.arange(n) * 0.02
    x1 = np.sin(1.3 * t) + 0.5 * np.sin(3.1 * t + 0.4)
    w = np.sin(0.7 * t + 1.0) + 0.3 * rng.standard_normal(n)
    e = np.zeros(n)
    g = rng.standard_normal(n)
    for k in range(1, n):
        e[k] = 0.9 * e[k - 1] + g[k]
    for eps, leans in ((1e-8, True), (1.0, False)):
        d = {"x1": x1, "x2": x1 + eps * w, "z": x1 + 2.0 * (x1 + eps * w) + 0.05 * e}
        res = aeroid.recursive_least_squares(d, "z", ["x1", "x2"], intercept=False)
        white = aeroid.recursive_least_squares(
            d, "z", ["x1", "x2"], intercept=False, error_bars="white"
        )
        for k, truth in (("x1", 1.0), ("x2", 2.0)):
            assert abs(res.parameters[k] - truth) < 3.0 * res.stderr[k]
            if leans:
                assert res.stderr[k] == pytest.approx(white.stderr[k], rel=1e-3)
            else:
                assert res.stderr[k] > 2.0 * white.stderr[k]  # AR(1) 0.9: coloured


def test_a_memory_shorter_than_the_parameters_is_refused():
    with pytest.raises(aeroid.DataFormatError, match="remembers about 2 samples"):
        aeroid.recursive_least_squares(_record(n=50), "z", ["a", "b"], forgetting=0.5)
