"""Estimated biases and filter-error noise levels appear in summary() and report()."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog

P = ["Z_alpha", "M_alpha", "M_q", "M_delta"]


def _table(text: str, first: str) -> dict[str, list[str]]:
    """The Markdown table whose header starts with `first`, rows keyed by their first cell."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"| {first} "))
    rows: dict[str, list[str]] = {}
    for ln in lines[start + 2 :]:
        if not ln.startswith("|"):
            break
        cells = [c.strip() for c in ln.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


@pytest.fixture(scope="module")
def vane_offset() -> tuple[aeroid.FlightData, aeroid.IdentificationResult]:
    """The README flight with the alpha vane reading 0.02 rad high, biases estimated."""
    data = catalog.short_period_flight(seed=1)
    channels = dict(data.channels)
    channels["alpha"] = np.asarray(channels["alpha"]) + 0.02
    record = aeroid.FlightData(data.time, channels, data.units)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = aeroid.identify(catalog.short_period(), record, P, estimate_bias=True)
    return record, result


def test_output_biases_are_in_the_summary_and_the_report(vane_offset):
    record, result = vane_offset
    bias, se = result.biases[0]["alpha"], result.extra_stderr["bias[0].alpha"]
    assert abs(bias - 0.02) < 3 * se  # 0.01982 ± 0.00021 on this seed
    rows = _table(result.summary(), "bias or noise level")
    assert rows["bias[0].alpha"] == [f"{bias:.4g}", f"{se:.4g}"] == ["0.01982", "0.0002088"]
    assert rows["bias[0].q"][1] == f"{result.extra_stderr['bias[0].q']:.4g}"
    assert "bias[i].y: the bias of output y on record i, in y's unit." in result.summary()
    text = aeroid.report(aeroid.validate(catalog.short_period(), record, result), result)
    ident = text.split("## Validation")[0]
    rows = _table(ident, "bias or noise level")
    assert rows["bias[0].alpha"] == ["rad", "0.01982", "0.0002088"]
    assert rows["bias[0].q"][0] == "rad/s"


def test_filter_error_noise_levels_are_in_the_summary_and_the_report():
    model, data = catalog.short_period(), catalog.short_period_flight(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fe = aeroid.identify(model, data, P, method="filter_error", estimate_process_noise=True)
    rows = _table(fe.summary(), "bias or noise level")
    assert rows["process_noise.q"] == [
        f"{fe.process_noise['q']:.4g}",
        f"{fe.extra_stderr['process_noise.q']:.4g}",
    ]
    for j, y in enumerate(fe.output_names):
        variance = float(fe.noise_covariance[j, j])
        # the noise standard deviations the flight was simulated with: 0.005 and 0.01
        assert np.sqrt(variance) == pytest.approx({"alpha": 0.005, "q": 0.01}[y], rel=0.1)
        assert rows[f"measurement_noise.{y}"] == [
            f"{variance:.4g}",
            f"{fe.extra_stderr[f'measurement_noise.{y}']:.4g}",
        ]
    assert not any(k.startswith("bias[") for k in rows)
    text = aeroid.report(aeroid.validate(model, data, fe), fe)
    units = {k: v[0] for k, v in _table(text, "bias or noise level").items()}
    assert units["process_noise.q"] == "(rad/s)²/s"
    assert units["measurement_noise.alpha"] == "rad²"


def test_noise_levels_given_not_estimated_are_not_listed():
    model, data = catalog.short_period(), catalog.short_period_flight(seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fe = aeroid.identify(
            model, data, P, method="filter_error", process_noise={"alpha": 1e-6, "q": 1e-5}
        )
    rows = _table(fe.summary(), "bias or noise level")
    assert set(rows) == {"measurement_noise.alpha", "measurement_noise.q"}


def test_a_plain_fit_has_no_bias_table(vane_offset):
    record, _ = vane_offset
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = aeroid.identify(catalog.short_period(), record, P)
    assert "bias or noise level" not in result.summary()


def test_a_model_held_whole_lists_its_biases_once():
    # its main table already shows the initial states and biases it fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = aeroid.identify(
            catalog.short_period(), catalog.short_period_flight(seed=1), [], estimate_bias=True
        )
    text = result.summary()
    assert text.count("bias[0].alpha") == 1 and "bias or noise level" not in text
