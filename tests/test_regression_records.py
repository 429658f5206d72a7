"""Equation error on several records (manoeuvres) joined: one parameter set for all."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid
from aeroid.errors import DataFormatError


def _record(rng: np.random.Generator, n: int, *, phi: float = 0.9) -> aeroid.FlightData:
    """A smooth regressor with its own offset, AR(1) equation noise; z = 0.3 + 2 x + w."""
    x = np.zeros(n)
    e = rng.standard_normal(n)
    for k in range(1, n):
        x[k] = 0.95 * x[k - 1] + 0.3 * e[k]
    x += rng.normal()
    w = np.zeros(n)
    e = rng.standard_normal(n)
    for k in range(1, n):
        w[k] = phi * w[k - 1] + 0.1 * e[k]
    return aeroid.FlightData(np.arange(n) * 0.02, {"x": x, "z": 0.3 + 2.0 * x + w})


def _joined(records: list[aeroid.FlightData]) -> aeroid.FlightData:
    t = np.concatenate([r.time + 100.0 * k for k, r in enumerate(records)])
    return aeroid.FlightData(
        t, {c: np.concatenate([r.channels[c] for r in records]) for c in ("x", "z")}
    )


def test_several_records_fit_as_the_records_joined() -> None:
    rng = np.random.default_rng(1)
    records = [_record(rng, n) for n in (300, 200, 450)]
    several = aeroid.equation_error(records, "z", ["x"], error_bars="white")
    joined = aeroid.equation_error(_joined(records), "z", ["x"], error_bars="white")
    for name in ("const", "x"):
        assert several.parameters[name] == pytest.approx(joined.parameters[name], abs=1e-12)
        assert several.stderr[name] == pytest.approx(joined.stderr[name], rel=1e-12)
    assert several.record_lengths == (300, 200, 450)
    assert several.residuals.shape == (950,)
    np.testing.assert_array_equal(several.time[:300], records[0].time)
    assert several.n_samples == 950
    # one record in a list is that record
    one = aeroid.equation_error(records[:1], "z", ["x"])
    alone = aeroid.equation_error(records[0], "z", ["x"])
    assert one.stderr == alone.stderr and one.record_lengths == ()


def test_coloured_bars_on_several_short_records_cover() -> None:
    # 200 seeds of four 250-sample records under AR(1) 0.9 equation noise: the 95 %
    # intervals cover at 0.95 +- 0.03 (two binomial sigma at 200 draws ~ 0.031)
    hits = 0
    errors, bars = [], []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        fit = aeroid.equation_error([_record(rng, 250) for _ in range(4)], "z", ["x"])
        lo, hi = fit.interval(0.95)["x"]
        hits += lo <= 2.0 <= hi
        errors.append(fit.parameters["x"] - 2.0)
        bars.append(fit.stderr["x"])
    assert 0.90 <= hits / 200 <= 0.99
    # the bars' rms over the estimates' scatter: 1 within the scatter's own noise
    # (the sd of 200 draws is known to about 5 %)
    assert 0.85 <= np.sqrt(np.mean(np.square(bars))) / np.std(errors) <= 1.2


def test_several_records_refusals_name_the_option() -> None:
    rng = np.random.default_rng(2)
    records = [_record(rng, 100), _record(rng, 120)]
    with pytest.raises(DataFormatError, match="time domain only"):
        aeroid.equation_error(records, "z", ["x"], domain="frequency", frequencies=[0.5, 1.0])
    with pytest.raises(DataFormatError, match="time_delays"):
        aeroid.equation_error(records, "z", ["x"], time_delays=["x"])
    with pytest.raises(DataFormatError, match="reml"):
        aeroid.equation_error(records, "z", ["x"], error_bars="reml")
    with pytest.raises(DataFormatError, match="response"):
        aeroid.equation_error(records, np.zeros(220), ["x"])
    with pytest.raises(DataFormatError, match="item 1"):
        aeroid.equation_error([records[0], {"x": [1.0]}], "z", ["x"])
    with pytest.raises(DataFormatError, match="dt"):
        aeroid.equation_error(records, "z", ["x"], dt=0.05)
    with pytest.raises(aeroid.ChannelError, match="record 1"):
        aeroid.equation_error(
            [records[0], aeroid.FlightData(records[1].time, {"x": records[1]["x"]})], "z", ["x"]
        )


def test_estimators_of_one_record_say_so_for_a_list_of_records() -> None:
    rng = np.random.default_rng(5)
    records = [_record(rng, 80), _record(rng, 90)]
    for fit in (
        lambda: aeroid.stepwise_regression(records, "z", ["x"]),
        lambda: aeroid.recursive_least_squares(records, "z", ["x"]),
        lambda: aeroid.orthogonal_function_model(records, "z", ["x"]),
    ):
        with pytest.raises(DataFormatError, match=r"takes one record.*equation_error"):
            fit()


def test_an_empty_list_is_named_as_empty() -> None:
    with pytest.raises(DataFormatError, match="data: empty"):
        aeroid.equation_error([], "z", ["x"])
