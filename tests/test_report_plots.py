"""The report's residual-autocorrelation and held-out-prediction figures draw what they claim."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest

from aeroid import IdentificationError, report, validate
from aeroid.models import catalog
from aeroid.reports.plotting import plot_prediction, plot_residual_autocorrelation
from aeroid.uncertainty.validation import ljung_box


def _validation(**kw):
    t = np.arange(1001) / 50.0  # a doublet at 1 s and another at 13 s, in the held-out part
    de = catalog.doublet(t, start=1.0, width=1.0, amplitude=0.05) + catalog.doublet(
        t, start=13.0, width=1.0, amplitude=0.05
    )
    data = catalog.short_period_flight(duration=20.0, seed=3, elevator=de)
    return validate(catalog.short_period(catalog.SHORT_PERIOD_TRUTH), data, None, **kw)


def test_autocorrelation_plot_draws_the_sample_autocorrelation_and_its_band():
    v = _validation()
    fig = plot_residual_autocorrelation(v, max_lag=15)
    n = v.residuals.shape[0]
    band = 1.96 / np.sqrt(n)
    assert len(fig.axes) == len(v.output_names)
    for j, ax in enumerate(fig.axes):
        e = v.residuals[:, j] - v.residuals[:, j].mean()
        expected = np.array([e[: n - k] @ e[k:] / (e @ e) for k in range(1, 16)])
        k, r = ax.lines[0].get_data()  # the markers on the stems
        np.testing.assert_array_equal(k, np.arange(1, 16))
        np.testing.assert_allclose(r, expected, rtol=1e-12, atol=1e-15)
        # the same r_k the Ljung-Box statistic sums
        q, _ = ljung_box(v.residuals[:, j], 15)
        assert q == pytest.approx(n * (n + 2) * np.sum(expected**2 / (n - np.arange(1, 16))))
        box = ax.patches[0].get_bbox()  # the band, from the first lag to the last
        assert (box.x0, box.x1) == (0.0, 15.0)
        assert box.y1 == pytest.approx(band) and box.y0 == pytest.approx(-band)
        assert v.output_names[j] in ax.get_title(loc="left")
    assert "0.02 s" in fig.axes[-1].get_xlabel()
    plt.close(fig)


def test_prediction_plot_shows_measured_and_predicted_on_the_held_out_window():
    v = _validation(holdout={"t0": 12.0, "t1": 20.0})
    assert v.prediction is not None
    fig = plot_prediction(v.prediction)
    for j, ax in enumerate(fig.axes):
        t, y = ax.lines[0].get_data()
        t_hat, y_hat = ax.lines[1].get_data()
        np.testing.assert_array_equal(t_hat, t)
        np.testing.assert_array_equal(t, v.prediction.time)
        np.testing.assert_array_equal(y, v.prediction.measured[:, j])
        np.testing.assert_array_equal(y_hat, v.prediction.predicted[:, j])
        assert "Theil U" in ax.get_title(loc="left")
    assert fig.axes[0].get_ylabel() == "alpha [rad]"
    plt.close(fig)


def test_report_writes_both_figures_and_the_prediction_table(tmp_path):
    v = _validation(holdout={"fraction": 0.3})
    text = report(v, path=tmp_path / "f.md")
    names = sorted(p.name for p in (tmp_path / "f_figures").iterdir())
    assert names == ["prediction.png", "residual_autocorrelation.png", "time_histories.png"]
    assert "Theil U" in text and "Residual autocorrelation at lags" in text


def test_autocorrelation_plot_needs_three_residuals():
    from types import SimpleNamespace

    two = SimpleNamespace(
        output_names=("q",), residuals=np.zeros((2, 1)), time=np.arange(2.0), whiteness_lags=1
    )
    with pytest.raises(IdentificationError, match="at least 3 residuals"):
        plot_residual_autocorrelation(two)
