"""Every result draws itself: .plot() returns a figure with the expected panels."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import aeroid
from aeroid.errors import IdentificationError
from aeroid.models import catalog
from aeroid.reports.plotting import plot_campaign_trend

NAMES = list(catalog.SHORT_PERIOD_TRUTH)


@pytest.fixture(scope="module")
def chain():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    r = aeroid.identify(model, data, NAMES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = {
            "identification": r,
            "validation": aeroid.validate(model, data, r),
            "propagation": aeroid.propagate(
                r,
                lambda p: math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"]),
                n_samples=300,
                seed=0,
            ),
            "filtering": aeroid.filter_states(
                model,
                data,
                r,
                process_noise={"alpha": 1e-8, "q": 1e-8},
                measurement_noise={"alpha": 0.005**2, "q": 0.01**2},
            ),
            "sensitivity": aeroid.sensitivities(
                model, data, values=r, noise={"alpha": 0.005, "q": 0.01}
            ),
            "frequency": aeroid.frequency_response(model, data, r),
            "inference": aeroid.infer(
                model,
                data.window(0, 4),
                {n: aeroid.Normal(v, 5.0) for n, v in r.parameters.items()},
                noise={"alpha": 0.005, "q": 0.01},
                initial=r,
                n_walkers=16,
                n_steps=60,
                seed=0,
            ),
            "design": aeroid.design_experiment(
                model,
                aeroid.Multisine("elevator", frequencies=(0.2, 0.5, 1.0), amplitude=(0.0, 0.05)),
                ["M_q", "M_delta"],
                values=r,
                noise={"alpha": 0.005, "q": 0.01},
                duration=4.0,
                sample_rate=25.0,
                seed=0,
                optimizer_options={"maxiter": 2, "popsize": 3},
            ),
        }
    return out


@pytest.mark.parametrize(
    ("name", "n_axes"),
    [
        ("identification", 3),  # two residual panels + the forest of the 4 estimates
        ("validation", 5),  # alpha, alpha residual, q, q residual, elevator input
        ("propagation", 1),
        ("filtering", 2),
        ("sensitivity", 2),
        ("frequency", 6),  # magnitude, phase, coherence for two channels
        ("inference", 10),  # lower triangle of a 4 x 4 corner grid
        ("design", 2),
    ],
)
def test_each_result_plots_itself(chain, name, n_axes):
    fig = chain[name].plot()
    assert isinstance(fig, Figure)
    assert len(fig.axes) == n_axes
    assert any(ax.lines or ax.patches or ax.collections for ax in fig.axes)
    _assert_laid_out(fig)


def _assert_laid_out(fig: Figure) -> None:
    # the margins are fixed, not computed: every panel with its tick labels, axis
    # labels and title must lie inside the figure and clear of the other panels
    renderer = FigureCanvasAgg(fig).get_renderer()
    boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
    width, height = fig.bbox.width, fig.bbox.height
    for ax, b in zip(fig.axes, boxes, strict=True):
        label = ax.get_ylabel() or ax.get_title(loc="left") or ax.get_title()
        assert b.x0 >= 0 and b.y0 >= 0, label
        assert b.x1 <= width and b.y1 <= height, label
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            overlap_w = min(a.x1, b.x1) - max(a.x0, b.x0)
            overlap_h = min(a.y1, b.y1) - max(a.y0, b.y0)
            assert overlap_w <= 0 or overlap_h <= 0


def test_traces_and_campaign_trend(chain):
    traces = chain["inference"].plot_traces()
    assert len(traces.axes) == 4
    _assert_laid_out(traces)
    r = chain["identification"]
    records = [
        {
            "flight": f"f{i}",
            "parameters": dict(r.parameters),
            "stderr": dict(r.stderr),
            "metadata": {"airspeed": 60.0 + 10 * i},
        }
        for i in range(3)
    ]
    fig = plot_campaign_trend(records)
    assert len(fig.axes) == 4 and fig.axes[-1].get_xlabel() == "airspeed [m/s]"
    _assert_laid_out(fig)
    by_name = plot_campaign_trend(
        [
            {k: v for k, v in rec.items() if k != "metadata"}
            | {"flight": f"FT-2026-11-{i:02d}-run4"}
            for i, rec in enumerate(records)
        ]
    )
    assert by_name.axes[-1].get_xlabel() == "flight"
    _assert_laid_out(by_name)
    # a subset, in the order asked; a flight without an estimate leaves a gap
    records[1] = records[1] | {"parameters": {"M_q": r.parameters["M_q"]}}
    some = plot_campaign_trend(records, parameters=["M_delta", "M_q"])
    assert [ax.get_ylabel() for ax in some.axes] == ["M_delta", "M_q"]
    _assert_laid_out(some)
    with pytest.raises(IdentificationError, match="no flight has an estimate of X_u"):
        plot_campaign_trend(records, parameters=["M_q", "X_u"])


def test_log_axes_read_as_plain_numbers_at_one_two_and_five():
    from aeroid.reports.plotting import _log_label

    labels = {
        v: _log_label(v, None) for v in (0.02, 0.03, 0.2, 0.5, 0.7, 1.0, 2.0, 3.0, 50.0, 100.0)
    }
    assert labels == {
        0.02: "0.02",
        0.03: "",
        0.2: "0.2",
        0.5: "0.5",
        0.7: "",
        1.0: "1",
        2.0: "2",
        3.0: "",
        50.0: "50",
        100.0: "100",
    }
    assert _log_label(0.0, None) == "" and _log_label(float("nan"), None) == ""


def test_residuals_against_time_bode_in_rad_per_s_and_trend_title_clear(chain):
    r = chain["identification"]
    data = catalog.short_period_flight(seed=0)
    fig = r.plot(time=data.time)
    residual_axes = fig.axes[: len(r.output_names)]
    for ax in residual_axes:  # one time axis, labelled under the last panel
        np.testing.assert_array_equal(ax.lines[0].get_xdata(), data.time)
    assert [ax.get_xlabel() for ax in residual_axes] == ["", "time [s]"]
    # residuals of another length than the time stamps: plotted against the sample index
    assert r.plot(time=data.time[:-1]).axes[1].get_xlabel() == "sample [-]"
    bode = chain["frequency"].plot()
    ch = chain["frequency"].channels[0]
    assert [ax.get_xlabel() for ax in bode.axes].count("frequency [rad/s]") == len(
        chain["frequency"].channels
    )
    np.testing.assert_allclose(bode.axes[0].lines[0].get_xdata(), ch.frequency)
    # a tall trend (15 panels): the title lies above the first panel, inside the figure
    records = [
        {
            "flight": f"f{i}",
            "parameters": {f"P{k}": float(k + i) for k in range(15)},
            "stderr": {f"P{k}": 0.1 for k in range(15)},
            "metadata": {"airspeed": 50.0 + i},
        }
        for i in range(3)
    ]
    trend = plot_campaign_trend(records)
    renderer = FigureCanvasAgg(trend).get_renderer()
    title = trend._suptitle.get_window_extent(renderer)
    first = trend.axes[0].get_tightbbox(renderer)
    assert first.y1 < title.y0 and title.y1 <= trend.bbox.height


def _lag_flight(K: float, seed: int) -> tuple[object, object]:
    """A first-order lag flown with a doublet, its outputs `K` times the unit case."""
    model = catalog.first_order(K=K, tau=0.4)
    t = np.arange(401) / 40.0
    u = catalog.doublet(t, start=1.0, width=1.5, amplitude=1.0)
    clean = model.simulate(t, u[:, None])
    rng = np.random.default_rng(seed)
    y = clean.outputs[:, 0] + 0.02 * K * rng.standard_normal(t.size)
    return model, aeroid.FlightData(t, {"u": u, "y": y}, units={"u": "rad", "y": "m"})


def _lag_results(K: float, seed: int) -> dict[str, object]:
    model, data = _lag_flight(K, seed)
    r = aeroid.identify(model, data, ["K", "tau"])
    return {
        "data": data,
        "identification": r,
        "validation": aeroid.validate(model, data, r),
        "filtering": aeroid.filter_states(
            model,
            data,
            r,
            process_noise={"y": 1e-4 * K**2},
            measurement_noise={"y": (0.02 * K) ** 2},
        ),
    }


def test_identification_forest_scales_each_row_and_labels_its_values():
    """One axes for every estimate: a row each, divided by max(|estimate|, 95 % half-width),
    so a clear estimate sits at ±1 and one whose interval holds zero inside (-1, 1), grey."""
    from types import SimpleNamespace

    values = {"big": 2.0e4, "small": -3.0e-4, "nil": 0.01, "zero": 0.0}
    half = {"big": 1.0e3, "small": 1.5e-4, "nil": 0.04, "zero": 0.0}
    fake = SimpleNamespace(
        parameter_names=list(values),
        output_names=["y"],
        parameters=values,
        parameter_units={"big": "N", "nil": "1/s"},
        residuals=[np.zeros((5, 1))],
        margin=lambda level: dict(half),
    )
    from aeroid.reports.plotting import plot_identification

    fig = plot_identification(fake)
    assert len(fig.axes) == 2
    forest = fig.axes[1]
    labels = [t.get_text() for t in forest.get_yticklabels()]
    assert labels == [
        "big = 2e+04 ± 1e+03 [N]",
        "small = -0.0003 ± 0.00015",
        "nil = 0.01 ± 0.04 [1/s]",
        "zero = 0 ± 0",
    ]
    ticks = forest.get_yticks()
    rows = {round(float(y)): lab.split(" ")[0] for y, lab in zip(ticks, labels, strict=True)}
    assert rows == {3: "big", 2: "small", 1: "nil", 0: "zero"}  # the first on top
    # errorbar draws the points as a line each call: clear estimates, then grey ones
    clear, grey = (c.lines[0] for c in forest.containers)
    np.testing.assert_allclose(clear.get_xdata(), [1.0, -1.0])
    np.testing.assert_allclose(clear.get_ydata(), [3.0, 2.0])
    np.testing.assert_allclose(grey.get_xdata(), [0.25, 0.0])  # 0.01 / 0.04; 0 / 1
    assert grey.get_color() == "0.55"
    _assert_laid_out(fig)


def test_a_recycled_figure_draws_as_a_new_one(chain):
    """Under `reusing_figures`, the next flight's figures redraw the recycled ones: the
    same PNG bytes as new figures, whatever the scale of the flight drawn before
    (here outputs 10^4 times larger, whose tick labels are wider and carry an offset)."""
    from aeroid.pipeline.stages.campaign_report import flight_figures
    from aeroid.reports.plotting import recycle_figure, reusing_figures
    from aeroid.support import figure_png

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flights = [_lag_results(1e4, 1), _lag_results(1.0, 2), _lag_results(3e-3, 3)]
    short_period = {k: chain[k] for k in ("identification", "validation", "filtering")}
    flights.insert(1, short_period)
    fresh = [{k: figure_png(f, dpi=40, colors=32) for k, f in flight_figures(r)} for r in flights]
    assert set(fresh[0]) == {
        "time_histories",
        "residual_autocorrelation",
        "identification",
        "filter_states",
    }
    reused = []
    with reusing_figures():
        for r in flights:
            drawn = {}
            for label, fig in flight_figures(r):
                drawn[label] = (fig, figure_png(fig, dpi=40, colors=32))
                recycle_figure(fig)
            reused.append(drawn)
    # the lags' layouts are the same (the short period's between them is kept apart):
    # the same figures, redrawn
    for i, before in ((2, 0), (3, 2)):
        assert all(reused[i][k][0] is reused[before][k][0] for k in reused[i])
    assert [{k: png for k, (_, png) in d.items()} for d in reused] == fresh
    # outside `reusing_figures` every figure is new
    first, second = (dict(flight_figures(flights[2])) for _ in range(2))
    assert all(first[k] is not second[k] for k in first)


@pytest.mark.parametrize(("t0", "t1", "half"), [(0.0, 20.0, 0.013), (0.3, 7.7, 2.5e-4)])
def test_a_constant_band_draws_the_pixels_of_its_fill_between(t0, t1, half):
    """`_band`'s rectangle draws the picture ``fill_between`` draws over the band's two
    ends, legend entry included, and gives the panel the same limits."""
    from aeroid.reports.plotting import _band
    from aeroid.support import figure_png

    t = np.linspace(t0, t1, 301)
    pngs, limits = [], []
    for rectangle in (False, True):
        fig = Figure(figsize=(5.0, 4.0))
        axes = fig.subplots(2, 1, sharex=True)
        for ax in axes:
            ax.plot(t, 0.8 * half * np.sin(3.0 * t), color="C3", lw=0.9)
            style = {"color": "#d62728", "alpha": 0.15, "lw": 0, "label": "band"}
            if rectangle:
                _band(ax, t[0], t[-1], half, **style)
            else:
                ax.fill_between(t[[0, -1]], -half, half, **style)
        axes[0].legend(loc="upper right", fontsize=7)
        pngs.append(figure_png(fig, dpi=72))
        limits.append([(ax.get_xlim(), ax.get_ylim()) for ax in axes])
    assert pngs[0] == pngs[1]
    assert limits[0] == limits[1]


def test_palette_png_leaves_the_figure_as_it_was_and_repeats_its_bytes():
    """`figure_png(colors=...)` renders at its own dpi and quantises the canvas itself:
    the figure keeps its dpi and canvas, the same figure gives the same bytes, and the
    palette holds at most `colors` colours close to the full-colour rendering."""
    import io

    from PIL import Image

    from aeroid.support import figure_png

    fig = Figure(figsize=(4.0, 3.0), dpi=100)
    ax = fig.add_subplot()
    t = np.linspace(0.0, 10.0, 500)
    ax.plot(t, np.sin(t), color="C0")
    ax.fill_between(t, -0.5, 0.5, color="C3", alpha=0.15)
    ax.set_title("sine", loc="left")
    canvas = fig.canvas
    png = figure_png(fig, dpi=50, colors=16)
    assert fig.dpi == 100 and fig.canvas is canvas
    assert figure_png(fig, dpi=50, colors=16) == png
    img = Image.open(io.BytesIO(png))
    assert img.size == (200, 150) and img.mode == "P"
    assert len(img.getcolors()) <= 16
    full = np.asarray(Image.open(io.BytesIO(figure_png(fig, dpi=50))).convert("RGB"), float)
    assert np.abs(np.asarray(img.convert("RGB"), float) - full).mean() < 3.0


def test_one_legend_a_figure_with_every_entry(chain):
    """Panels that repeat one legend carry it once, on the top panel; the filter's
    legend names the measured points even where the top state was not measured."""
    f = chain["filtering"]
    q = f.smoothed_states[:, list(f.state_names).index("q")]
    fig = f.plot(data={"q": q})  # alpha (the top panel) not measured
    legends = [ax.get_legend() for ax in fig.axes]
    assert legends[0] is not None and all(leg is None for leg in legends[1:])
    labels = [t.get_text() for t in legends[0].get_texts()]
    assert labels == ["measured", "±2σ", "filtered", "smoothed"]
    from aeroid.reports.plotting import plot_residual_autocorrelation

    auto = plot_residual_autocorrelation(chain["validation"])
    assert [ax.get_legend() is not None for ax in auto.axes] == [True, False]


def test_figure_png_draws_text_as_matplotlib_does():
    """`figure_png` draws each string of text as one bitmap, kept for the next draw: the
    picture matches matplotlib's own rendering (text within a pixel of where matplotlib
    puts it), mathematical text included, and repeats its bytes."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image

    from aeroid.support import figure_png

    fig = Figure(figsize=(4.0, 3.0), dpi=100)
    ax = fig.add_subplot()
    t = np.linspace(0.0, 10.0, 200)
    ax.plot(t, np.cos(t))
    ax.set_title("cosine, ±2σ", loc="left")
    ax.set_ylabel(r"$\alpha$ [rad]")
    ax.set_xlabel("time [s]")
    png = figure_png(fig, dpi=60)
    assert figure_png(fig, dpi=60) == png  # the kept bitmaps draw the same pixels
    ours = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), float)
    fig.set_dpi(60)
    stock = FigureCanvasAgg(fig)
    stock.draw()
    theirs = np.asarray(stock.buffer_rgba(), float)[..., :3]
    assert ours.shape == theirs.shape == (180, 240, 3)
    differ = np.abs(ours - theirs).max(axis=2) > 0
    assert differ.mean() < 0.05  # only text edges move, by under a pixel
    # wherever a pixel differs, matplotlib drew ink within one pixel of it
    ink = (theirs < 200).any(axis=2)
    near = ink | np.roll(ink, 1, 0) | np.roll(ink, -1, 0) | np.roll(ink, 1, 1) | np.roll(ink, -1, 1)
    assert near[differ].mean() > 0.95
