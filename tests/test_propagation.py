"""propagate: Gaussian closed forms, failure counting, posterior rows, seeding."""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from types import MappingProxyType

import numpy as np
import pytest

from aeroid import IdentificationResult, combine_batches, propagate, propagate_batch
from aeroid.uncertainty.propagation import BLOCK_SIZE, PropagationError, draw_parameters


def _result(mean=(1.0, 2.0), cov=((0.04, 0.01), (0.01, 0.09))):
    cov = np.asarray(cov)
    return IdentificationResult(
        parameters=dict(zip(("a", "b"), mean, strict=True)),
        stderr={"a": math.sqrt(cov[0, 0]), "b": math.sqrt(cov[1, 1])},
        covariance=cov,
        parameter_names=("a", "b"),
        fixed={"c": 10.0},
        covariance_white=cov,
        error_bars="white",
        identifiable=True,
        unidentifiable=(),
        success=True,
        message="",
        n_iterations=1,
        cost=0.0,
        method="output_error",
        output_names=("y",),
        noise_covariance=np.eye(1),
    )


def test_linear_metric_matches_gaussian_closed_form():
    # f = 2a - b + c: mean 2 - 2 + 10 = 10, var 4*0.04 + 0.09 - 4*0.01 = 0.21.
    # With 20000 draws the sample mean has sd sqrt(0.21/20000) = 0.0032 and the
    # sample sd a relative sd of 1/sqrt(40000) = 0.5 %.
    res = propagate(_result(), lambda p: 2 * p["a"] - p["b"] + p["c"], n_samples=20000, seed=1)
    assert res.mean == pytest.approx(10.0, abs=0.015)
    assert res.std == pytest.approx(math.sqrt(0.21), rel=0.03)
    assert res.percentiles["P2.5"] == pytest.approx(10 - 1.96 * math.sqrt(0.21), abs=0.03)
    assert res.n_failed == 0 and res.source == "covariance"
    assert "| mean" in res.summary()


def test_failures_are_counted_not_fatal():
    def metric(p):
        if p["a"] > 1.0:
            raise ValueError("outside envelope")
        return p["a"]

    with pytest.warns(UserWarning, match=r"failed for \d+ of 2000 draws .*outside envelope"):
        res = propagate(_result(), metric, n_samples=2000, seed=3)
    assert 800 < res.n_failed < 1200  # P(a > 1) = 1/2
    assert res.samples.size == 2000 - res.n_failed and np.all(res.samples <= 1.0)
    with pytest.raises(PropagationError, match="failed for all"):
        propagate(_result(), lambda p: float("nan"), n_samples=10, seed=0)


def test_same_seed_same_bits_and_batching_independent():
    r = _result()
    a = propagate(r, lambda p: p["a"] * p["b"], n_samples=700, seed=11)
    b = propagate(r, lambda p: p["a"] * p["b"], n_samples=700, seed=11)
    assert np.array_equal(a.samples, b.samples)
    whole = draw_parameters(r, 700, 11)
    parts = np.vstack(
        [draw_parameters(r, 300, 11, start=0), draw_parameters(r, 400, 11, start=300)]
    )
    assert np.array_equal(whole, parts)


class _Posterior:
    parameter_names = ("a", "b")
    fixed = MappingProxyType({"c": 1.0})

    def __init__(self):
        rng = np.random.default_rng(5)
        self.samples = np.column_stack([rng.gamma(2.0, size=300), rng.uniform(size=300)])


def test_posterior_rows_are_resampled_exactly():
    post = _Posterior()
    draws = draw_parameters(post, 1000, 4)
    rows = {tuple(r) for r in post.samples}
    assert all(tuple(r) in rows for r in draws)
    res = propagate(post, lambda p: p["a"] + p["c"], n_samples=1000, seed=4)
    assert res.source == "posterior"
    np.testing.assert_array_equal(res.samples, draws[:, 0] + 1.0)


def test_bad_arguments():
    with pytest.raises(PropagationError, match="n_samples"):
        propagate(_result(), lambda p: 1.0, n_samples=0)
    with pytest.raises(PropagationError, match="percentiles"):
        propagate(_result(), lambda p: 1.0, percentiles=(120,), seed=0)
    for bad in ((True,), ("50",), 5):  # True read as 1, text as a number, a bare number
        with pytest.raises(PropagationError, match="percentiles must be a list of numbers"):
            propagate(_result(), lambda p: 1.0, percentiles=bad, seed=0)
    with pytest.raises(PropagationError, match="takes an IdentificationResult"):
        propagate(object(), lambda p: 1.0, seed=0)


def _same(a, b):
    assert a.samples.tobytes() == b.samples.tobytes()
    assert (a.mean, a.std, a.n_samples, a.n_failed, a.seed, a.source) == (
        b.mean,
        b.std,
        b.n_samples,
        b.n_failed,
        b.seed,
        b.source,
    )
    assert dict(a.percentiles) == dict(b.percentiles)


@pytest.mark.filterwarnings("ignore:propagate. the metric failed")
@pytest.mark.parametrize("source", [_result(), _Posterior()], ids=["covariance", "posterior"])
def test_batches_anywhere_combine_into_exactly_the_one_call_result(source):
    def metric(p):  # fails on part of the draws, so failures are pooled across batches too
        if p["a"] > 1.4:
            raise ValueError("outside envelope")
        return p["a"] * p["b"] + p["c"]

    n, seed = 1500, 21
    whole = propagate(source, metric, n_samples=n, seed=seed, percentiles=(5, 50, 95))
    assert whole.n_failed > 0
    # cuts inside blocks, on a block boundary, and an empty batch; given out of order
    for cuts in ([0, 700, n], [0, 1, BLOCK_SIZE, 2 * BLOCK_SIZE + 7, 1100, 1100, n]):
        batches = [
            propagate_batch(source, metric, start=a, n_samples=b - a, seed=seed)
            for a, b in itertools.pairwise(cuts)
        ]
        assert sum(b.values.size for b in batches) == n
        _same(combine_batches(batches[::-1], percentiles=(5, 50, 95)), whole)
    assert (
        "draws 0-700 of seed 21"
        in propagate_batch(source, metric, start=0, n_samples=700, seed=seed).summary()
    )


def test_combining_refuses_gaps_overlaps_and_other_propagations():
    r = _result()

    def batch(start, n, seed=3):
        return propagate_batch(r, lambda p: p["a"], start=start, n_samples=n, seed=seed)

    with pytest.raises(PropagationError, match="gap at draw 0"):
        combine_batches([batch(10, 5)])
    with pytest.raises(PropagationError, match="gap at draw 10"):
        combine_batches([batch(0, 10), batch(20, 5)])
    with pytest.raises(PropagationError, match="overlap at draw 5"):
        combine_batches([batch(0, 10), batch(5, 10)])
    with pytest.raises(PropagationError, match="different propagations"):
        combine_batches([batch(0, 10), batch(10, 10, seed=4)])
    with pytest.raises(PropagationError, match="at least one batch"):
        combine_batches([])
    with pytest.raises(PropagationError, match="no draws"):
        combine_batches([batch(0, 0), batch(7, 0)])
    with pytest.raises(PropagationError, match="start"):
        batch(-1, 5)
    with pytest.raises(PropagationError, match="seed"):
        batch(0, 5, seed=-2)
    with pytest.raises(PropagationError, match="failed for all 10"):
        combine_batches([propagate_batch(r, lambda p: float("inf"), start=0, n_samples=10, seed=1)])
    assert propagate(r, lambda p: p["a"], n_samples=2e3, seed=1).n_samples == 2000
    with pytest.raises(PropagationError, match="n_samples"):
        propagate(r, lambda p: p["a"], n_samples=2.5, seed=1)


@pytest.mark.parametrize(
    ("percentiles", "fragment"),
    [
        ("50", r"got the string '50'"),
        (50, "list of numbers in \\[0, 100\\], got 50"),
        (["a"], "list of numbers"),
        ([150], r"lie in \[0, 100\], got \[150\]"),
        ([-1.0, 50.0], r"got \[-1, 50\]"),
    ],
)
def test_percentiles_must_be_numbers_in_0_100(percentiles, fragment):
    with pytest.raises(PropagationError, match=fragment):
        propagate(_result(), lambda p: 1.0, n_samples=10, percentiles=percentiles, seed=0)
    with pytest.raises(PropagationError, match=fragment):
        combine_batches([], percentiles=percentiles)


def test_messages_print_numpy_numbers_plainly():
    with pytest.raises(PropagationError, match=r"got 2\.5$"):
        propagate(_result(), lambda p: 1.0, n_samples=np.float64(2.5), seed=0)
    with pytest.raises(PropagationError, match=r"got -1$"):
        propagate(_result(), lambda p: 1.0, n_samples=10, seed=np.int64(-1))


def test_vector_metric_gives_one_result_per_component_equal_to_the_scalar_runs():
    import warnings

    from aeroid import VectorPropagationResult

    r = _result()

    def linear(p):
        return 2 * p["a"] - p["b"] + p["c"]

    def product(p):
        return p["a"] * p["b"]

    def both(p):
        return [linear(p), product(p)]

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no draw fails: no warning
        vec = propagate(r, both, n_samples=3000, seed=7, percentiles=(5, 95))
    assert isinstance(vec, VectorPropagationResult)
    assert vec.names == ("both[0]", "both[1]") and vec.n_failed == 0
    for name, scalar in (("both[0]", linear), ("both[1]", product)):
        _same(vec[name], propagate(r, scalar, n_samples=3000, seed=7, percentiles=(5, 95)))
    # the linear component against its closed form (as in the scalar test above):
    # mean 10, sd sqrt(0.21); 3000 draws: sd of the mean 0.0084, of the sd 1.3 %
    assert vec["both[0]"].mean == pytest.approx(10.0, abs=0.034)
    assert vec["both[0]"].std == pytest.approx(math.sqrt(0.21), rel=0.052)
    assert vec.values.shape == (3000, 2)
    np.testing.assert_array_equal(vec.values[:, 1], vec["both[1]"].samples)
    assert "| both[1]" in vec.summary() and "P95" in vec.summary()
    with pytest.raises(PropagationError, match=r"no component 'x'; components: \['both\[0\]'"):
        vec["x"]
    # an array works the same; a lambda's components are called metric[i]
    arr = propagate(r, lambda p: np.array([p["a"], p["b"]]), n_samples=50, seed=7)
    assert arr.names == ("metric[0]", "metric[1]")


def test_mapping_metric_components_are_named_by_its_keys_and_combine_across_batches():
    r = _result()

    def metric(p):  # "ratio" fails (inf) on some draws, "sum" never
        return {
            "sum": p["a"] + p["b"],
            "ratio": p["a"] / (p["b"] - 2.0) if p["b"] > 2.0 else np.inf,
        }

    with pytest.warns(UserWarning, match=r"failed for \d+ of 1000 draws.*non-finite"):
        whole = propagate(r, metric, n_samples=1000, seed=9)
    assert whole.names == ("sum", "ratio")
    assert whole["sum"].n_failed == 0
    # b ~ N(2, 0.3): about half the draws have b <= 2; sd of the count 16
    assert 420 < whole["ratio"].n_failed < 580 and whole.n_failed == whole["ratio"].n_failed
    assert np.all(np.isfinite(whole["ratio"].samples))
    batches = [
        propagate_batch(r, metric, start=a, n_samples=b - a, seed=9)
        for a, b in ((0, 300), (300, 300), (300, 1000))
    ]
    assert batches[0].names == ("sum", "ratio") and batches[1].names == ()
    with pytest.warns(UserWarning, match="failed for"):
        pooled = combine_batches(batches[::-1])
    for name in whole.names:
        _same(pooled[name], whole[name])
    np.testing.assert_array_equal(pooled.values, whole.values)
    # a batch of another metric, or of a scalar metric, is refused
    other = propagate_batch(r, lambda p: [p["a"]], start=1000, n_samples=10, seed=9)
    with pytest.raises(PropagationError, match="different metrics"):
        combine_batches([*batches, other])
    scalar = propagate_batch(r, lambda p: p["a"], start=1000, n_samples=10, seed=9)
    with pytest.raises(PropagationError, match="different metrics"):
        combine_batches([*batches, scalar])


def test_failures_warn_only_beyond_one_percent_and_name_the_first_failure():
    import warnings

    r = _result()
    n, seed = 1000, 5
    a = np.sort(draw_parameters(r, n, seed)[:, 0])

    def failing(k):
        cut = a[n - k]  # exactly k draws have a >= cut

        def metric(p):
            if p["a"] >= cut:
                raise ValueError(f"a = {p['a']:.3f} outside envelope")
            return p["a"]

        return metric

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert propagate(r, failing(10), n_samples=n, seed=seed).n_failed == 10  # 1 %: quiet
    with pytest.warns(UserWarning, match=r"failed for 11 of 1000 draws \(1\.1 %\)") as rec:
        assert propagate(r, failing(11), n_samples=n, seed=seed).n_failed == 11
    assert "ValueError: a = " in str(rec[0].message)
    # a metric that never works says why
    with pytest.raises(
        PropagationError, match=r"failed for all 20 draws \(first failure: draw 0: "
    ):
        propagate(r, lambda p: [[p["a"]]], n_samples=20, seed=0)
    with pytest.raises(PropagationError, match=r"component\(s\) \['bad'\] failed for all 20"):
        propagate(r, lambda p: {"good": p["a"], "bad": float("nan")}, n_samples=20, seed=0)


def test_a_metric_that_changes_its_shape_fails_those_draws():
    r = _result()

    def metric(p):
        return [p["a"], p["b"]] if p["a"] < 1.2 else p["a"]

    with pytest.warns(UserWarning, match=r"returned a number after \['metric\[0\]'"):
        res = propagate(r, metric, n_samples=500, seed=2)
    # P(a >= 1.2) = P(z >= 1) = 0.159 with sd 0.016 of the fraction over 500 draws
    assert 0.11 < res.n_failed / 500 < 0.21
    assert np.all(res["metric[0]"].samples < 1.2)


# -- input audit ------------------------------------------------------------------------------


def test_too_many_draws_refused_before_allocating():
    with pytest.raises(PropagationError, match="n_samples"):
        propagate(_result(), lambda p: p["a"], n_samples=10**12, seed=0)


def test_too_large_vector_metric_refused():
    with pytest.raises(PropagationError, match="n_samples"):
        propagate(_result(), lambda p: np.zeros(10**6), n_samples=10**4, seed=0)


def test_empty_percentiles_refused():
    with pytest.raises(PropagationError, match="percentiles"):
        propagate(_result(), lambda p: p["a"], n_samples=10, seed=0, percentiles=())


def test_progress_must_be_a_bool():
    with pytest.raises(PropagationError, match="progress"):
        propagate(_result(), lambda p: p["a"], n_samples=10, seed=0, progress="no")


def test_complex_vector_metric_is_a_failed_draw_not_a_truncated_one():
    with pytest.raises(PropagationError, match="complex"):
        propagate(_result(), lambda p: np.array([1.0 + 1j, 2.0]), n_samples=10, seed=0)


def test_percentiles_take_the_shape_every_result_shares():
    # name -> level (percent) -> value; a 1-D Gaussian metric: the closed form as above
    res = propagate(_result(), lambda p: 2 * p["a"] - p["b"] + p["c"], n_samples=20000, seed=1)
    table = res.percentile_table
    assert list(table) == ["metric"] and list(table["metric"]) == [2.5, 50.0, 97.5]
    assert table["metric"][2.5] == res.percentiles["P2.5"]  # the old shape, one more release
    assert table["metric"][97.5] == pytest.approx(10 + 1.96 * math.sqrt(0.21), abs=0.03)
    with pytest.raises(TypeError):
        table["metric"][2.5] = 0.0  # type: ignore[index]
    vec = propagate(_result(), lambda p: {"u": p["a"], "v": p["b"]}, n_samples=4000, seed=2)
    assert list(vec.percentile_table) == ["u", "v"]
    for name in ("u", "v"):
        expect = np.percentile(vec[name].samples, [2.5, 50.0, 97.5])
        np.testing.assert_array_equal(list(vec.percentile_table[name].values()), expect)
    assert "| P2.5" in vec.summary() and "| P2.5" in res.summary()


def test_a_metric_near_the_float_range_keeps_a_finite_spread():
    # squares of deviations near 1e297 overflow; the standard deviation itself does not
    from aeroid import identify
    from aeroid.models import catalog

    data = catalog.short_period_flight(seed=3)
    fit = identify(catalog.short_period(), data, ["M_q", "M_delta"])
    small = propagate(fit, lambda p: p["M_q"], n_samples=400, seed=2)
    huge = propagate(fit, lambda p: 1e300 * p["M_q"], n_samples=400, seed=2)
    assert huge.std == pytest.approx(1e300 * small.std, rel=1e-12)
    assert huge.mean == pytest.approx(1e300 * small.mean, rel=1e-12)


def test_a_mapping_metric_is_keyed_by_name_not_by_order():
    # the same keys built in two branches, in two orders: one metric. Counted as failed
    # before, these were exactly the draws with a <= 1 (1003 of 2000 in the report).
    r = _result()

    def two_branches(p):
        if p["a"] > 1.0:
            return {"x": p["a"], "y": p["b"]}
        return {"y": p["b"], "x": p["a"]}

    first = draw_parameters(r, 1, 4)[0, 0]
    order = ("x", "y") if first > 1.0 else ("y", "x")
    res = propagate(r, two_branches, n_samples=600, seed=4)
    fixed = propagate(
        r, lambda p: {k: p["a" if k == "x" else "b"] for k in order}, n_samples=600, seed=4
    )
    assert res.n_failed == 0 and res.names == order
    np.testing.assert_array_equal(res.values, fixed.values)
    assert res["x"].mean == fixed["x"].mean and res["x"].std == fixed["x"].std


@pytest.mark.filterwarnings("ignore:propagate. the metric failed")
def test_batches_of_a_shape_changing_metric_combine_into_the_one_call_result():
    # the draw that first returns fixes the shape for the whole stream: a batch that
    # starts on a draw of the other shape still counts that shape as failed
    r = _result()

    def metric(p):
        return [p["a"]] * (1 if p["a"] > 1.0 else 2)

    n, seed = 50, 0
    whole = propagate(r, metric, n_samples=n, seed=seed)
    assert 0 < whole.n_failed < n
    for cut in range(1, n):
        batches = [
            propagate_batch(r, metric, start=a, n_samples=b - a, seed=seed)
            for a, b in ((0, cut), (cut, n))
        ]
        pooled = combine_batches(batches[::-1])
        assert pooled.names == whole.names and pooled.n_failed == whole.n_failed
        np.testing.assert_array_equal(pooled.values, whole.values)

    # a metric failing on the first draws: later batches learn the shape further on
    def late(p):
        if p["a"] < 1.1:
            raise ValueError("not yet")
        return metric(p)

    whole = propagate(r, late, n_samples=n, seed=seed)
    pooled = combine_batches(
        [propagate_batch(r, late, start=a, n_samples=5, seed=seed) for a in range(0, n, 5)]
    )
    assert pooled.names == whole.names and pooled.n_failed == whole.n_failed
    np.testing.assert_array_equal(pooled.values, whole.values)


def test_combine_batches_names_what_is_not_a_batch():
    r = _result()
    batch = propagate_batch(r, lambda p: p["a"], start=0, n_samples=5, seed=1)
    with pytest.raises(PropagationError, match=r"batches\[0\]: expected a PropagationBatch .*int"):
        combine_batches([1, 2])
    with pytest.raises(PropagationError, match=r"batches\[1\]: .*got str"):
        combine_batches([batch, "draws"])
    with pytest.raises(PropagationError, match="expected a sequence of PropagationBatch"):
        combine_batches(batch)
    with pytest.raises(PropagationError, match="expected a sequence of PropagationBatch"):
        combine_batches(7)


def _wn(p):
    return math.sqrt(abs(p["a"] * p["b"]))


def test_combining_refuses_batches_of_another_result_or_metric():
    # a stale batch from another fit, or of another metric, pooled silently before
    r, other = _result(), _result(mean=(1.5, 2.0))
    head = propagate_batch(r, _wn, start=0, n_samples=300, seed=1)
    with pytest.raises(PropagationError, match=r"different results .*digest [0-9a-f]{16} "):
        combine_batches([head, propagate_batch(other, _wn, start=300, n_samples=300, seed=1)])
    # a result that differs only in its degrees of freedom draws other values too
    nu = dataclasses.replace(r, degrees_of_freedom={"a": 5.0})
    with pytest.raises(PropagationError, match="different results"):
        combine_batches([head, propagate_batch(nu, _wn, start=300, n_samples=300, seed=1)])
    lam = propagate_batch(r, lambda p: p["b"], start=300, n_samples=300, seed=1)
    with pytest.raises(PropagationError, match=r"different metrics .*test_propagation\._wn#"):
        combine_batches([head, lam])

    def scaled(k):
        return lambda p: k * p["a"]  # one lambda, told apart by what it closes over

    one = propagate_batch(r, scaled(1.0), start=0, n_samples=5, seed=1)
    with pytest.raises(PropagationError, match="different metrics"):
        combine_batches([one, propagate_batch(r, scaled(2.0), start=5, n_samples=5, seed=1)])
    # the same code and result in another call (another process, the pipeline) pools
    again = propagate_batch(_result(), scaled(1.0), start=5, n_samples=5, seed=1)
    pooled = combine_batches([one, again])
    assert np.array_equal(pooled.samples, propagate(r, scaled(1.0), n_samples=10, seed=1).samples)
    half = functools.partial(lambda p, k: k * p["a"], k=0.5)
    with pytest.raises(PropagationError, match="different metrics"):
        combine_batches(
            [
                propagate_batch(r, half, start=0, n_samples=5, seed=1),
                propagate_batch(r, functools.partial(half.func, k=3), start=5, n_samples=5, seed=1),
            ]
        )


def test_percentile_table_is_keyed_by_the_levels_asked_for():
    res = propagate(
        _result(), lambda p: p["a"], n_samples=300, seed=0, percentiles=[100 / 3, 200 / 3]
    )
    table = res.percentile_table["metric"]
    assert list(table) == [100 / 3, 200 / 3]
    assert table[100 / 3] == np.percentile(res.samples, 100 / 3)
    # levels that share a rounded label stay apart, in the table and in the labels
    close = propagate(
        _result(), lambda p: p["a"], n_samples=300, seed=0, percentiles=[33.3333331, 33.3333332]
    )
    assert list(close.percentile_table["metric"]) == [33.3333331, 33.3333332]
    assert list(close.percentiles) == ["P33.3333331", "P33.3333332"]
    assert list(res.percentiles) == ["P33.3333", "P66.6667"]


def test_a_covariance_that_is_no_covariance_is_refused():
    def edited(cov):
        return dataclasses.replace(_result(), covariance=np.asarray(cov))

    negative = edited(((0.01, 0.005), (0.005, -0.01)))
    with pytest.raises(PropagationError, match="gives b a negative variance"):
        propagate(negative, lambda p: p["a"], n_samples=10, seed=0)
    two = edited(((0.01, 0.02), (0.02, 0.01)))  # correlation 2
    with pytest.raises(PropagationError, match=r"not positive semi-definite .*eigenvalue -1\b"):
        propagate(two, lambda p: p["a"], n_samples=10, seed=0)
    with pytest.raises(PropagationError, match=r"covariance is \(3, 3\)"):
        propagate(edited(np.eye(3)), lambda p: p["a"], n_samples=10, seed=0)
    # a rounding-level negative eigenvalue (a correlation of 1 stored as 1 + 1e-15) draws
    edge = _result(cov=((0.04, 0.06 * (1 + 1e-15)), (0.06 * (1 + 1e-15), 0.09)))
    res = propagate(edge, lambda p: 3 * p["a"] - 2 * p["b"], n_samples=50, seed=0)
    assert res.std < 1e-6


def test_one_draw_has_no_standard_deviation():
    assert math.isnan(propagate(_result(), lambda p: p["a"], n_samples=1, seed=0).std)
    assert propagate(_result(), lambda p: p["a"], n_samples=2, seed=0).std > 0
