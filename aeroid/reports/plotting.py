"""Figures for every result type (matplotlib, no GUI: figures are built directly).

Each function returns a `matplotlib.figure.Figure`; the result classes expose
them as ``.plot()``. Nothing here touches pyplot's global state, so it works
headless and leaves a user's chosen backend alone.
"""

from __future__ import annotations

import contextlib
import threading
import weakref
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import matplotlib as mpl
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.ticker import FuncFormatter, MaxNLocator

from .._conditions import CONDITION_KEYS, condition_key
from ..errors import IdentificationError

__all__ = [
    "plot_campaign_trend",
    "plot_design",
    "plot_filter",
    "plot_frequency_response",
    "plot_identification",
    "plot_posterior",
    "plot_prediction",
    "plot_propagation",
    "plot_residual_autocorrelation",
    "plot_sensitivities",
    "plot_time_histories",
    "plot_traces",
]


def _grid(
    rows: int,
    cols: int = 1,
    *,
    width: float = 8.0,
    height: float = 2.4,
    left: float = 0.95,
    right: float = 0.2,
    top: float = 0.35,
    bottom: float = 0.55,
    hgap: float = 0.6,
    wgap: float = 0.95,
) -> tuple[Figure, Any]:
    # Margins and gaps are fixed in inches rather than left to a layout engine:
    # constrained layout makes every savefig draw the figure twice and measure
    # every tick label, which more than doubles the time to render a report.
    fig_h = max(height * rows, 2.5)
    axis_h = (fig_h - top - bottom - (rows - 1) * hgap) / rows
    axis_w = (width - left - right - (cols - 1) * wgap) / cols
    fig = Figure(figsize=(width, fig_h))
    grid = fig.add_gridspec(
        rows,
        cols,
        left=left / width,
        right=1.0 - right / width,
        bottom=bottom / fig_h,
        top=1.0 - top / fig_h,
        hspace=hgap / axis_h,
        wspace=wgap / axis_w,
    )
    return fig, grid


def figure(
    rows: int,
    cols: int = 1,
    *,
    sharex: bool | str = False,
    reuse: str | None = None,
    **layout: float,
) -> tuple[Figure, Any]:
    """A figure with a grid of panels; `reuse` names the figure kind under which
    `reusing_figures` may hand back a recycled one of the same layout."""
    key = (reuse, rows, cols, sharex, tuple(sorted(layout.items())))
    fig = _pooled(key) if reuse is not None else None
    if fig is not None:
        return fig, np.asarray(fig.axes, dtype=object).reshape(rows, cols)
    fig, grid = _grid(rows, cols, **layout)
    axes = grid.subplots(squeeze=False, sharex=sharex)
    if sharex:
        # a shared x axis is labelled under the last row only: the other rows' labels
        # stay empty, and a fixed place spares matplotlib measuring their tick labels
        # on every draw to keep an empty label clear of them
        for ax in axes[:-1].flat:
            ax.xaxis.set_label_coords(0.5, 0.0)
    if reuse is not None:
        _KEYS[fig] = key
    return fig, axes


def _cells(
    reuse: str, rows: int, cols: int, cells: Sequence[tuple[Any, Any]], **layout: float
) -> tuple[Figure, list[Any]]:
    """A figure with a panel on each of `cells` (row, column; either may be a slice) of a
    rows x cols grid, recycled as `figure` does."""
    spans = tuple((_span(r), _span(c)) for r, c in cells)
    key = (reuse, rows, cols, spans, tuple(sorted(layout.items())))
    fig = _pooled(key)
    if fig is not None:
        return fig, list(fig.axes)
    fig, grid = _grid(rows, cols, **layout)
    axes = [fig.add_subplot(grid[r, c]) for r, c in cells]
    _KEYS[fig] = key
    return fig, axes


def _span(index: Any) -> Any:
    return (index.start, index.stop, index.step) if isinstance(index, slice) else index


# Figures a campaign report has drawn and rendered, kept to be drawn again for the next
# flight: creating a figure's panels and their ticks costs as much as drawing it, and
# a campaign draws the same layouts over and over. Only while `reusing_figures` is on.
_POOL: dict[Any, Figure] = {}
_POOL_SIZE = 16
_KEYS: weakref.WeakKeyDictionary[Figure, Any] = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()
_STATE = threading.local()


@contextlib.contextmanager
def reusing_figures() -> Iterator[None]:
    """While on (in this thread), the per-flight figures of a campaign report reuse the
    figures given back with `recycle_figure`: same layout, panels wiped and redrawn.

    A recycled figure draws pixel for pixel as a new one would.
    """
    before = getattr(_STATE, "on", False)
    _STATE.on = True
    try:
        yield
    finally:
        _STATE.on = before


def recycle_figure(fig: Figure) -> None:
    """Give back a figure drawn under `reusing_figures` once it is rendered: the next
    figure of its kind and layout redraws it. Others are left alone."""
    key = _KEYS.get(fig)
    if key is None or not getattr(_STATE, "on", False):
        return
    with _LOCK:
        _POOL.pop(key, None)
        _POOL[key] = fig
        while len(_POOL) > _POOL_SIZE:
            _POOL.pop(next(iter(_POOL)))


def _pooled(key: Any) -> Figure | None:
    """A recycled figure of `key`, wiped of what was drawn on it, or None."""
    if not getattr(_STATE, "on", False):
        return None
    with _LOCK:
        fig = _POOL.pop(key, None)
    if fig is None:
        return None
    for ax in fig.axes:
        for artist in [*ax.lines, *ax.collections, *ax.patches, *ax.texts, *ax.images]:
            artist.remove()
        ax.containers.clear()
        legend = ax.get_legend()
        if legend is not None:
            legend.remove()
        for loc in ("left", "center", "right"):
            ax.set_title("", loc=loc)
        for label in (ax.xaxis.label, ax.yaxis.label):
            label.set_text("")
            label.set_fontsize(mpl.rcParams["axes.labelsize"])
        ax.set_prop_cycle(None)  # colours start again at C0
        ax.relim()  # no data: the next plot sets the limits afresh
        ax.set_autoscale_on(True)
    return fig


def _cn(n: int) -> str:
    """The colour ``"C<n>"`` of the colour cycle, as its hex code: matplotlib resolves a
    ``"C<n>"`` afresh on every draw of every artist that carries it (a walk through
    the cycle each time, a quarter of the time to draw the campaign's trend figure),
    a hex code from its cache."""
    return str(mpl.colors.to_hex(f"C{n}"))


def _label(name: str, units: Mapping[str, str] | None, *, what: str = "") -> str:
    """An axis label: the quantity, then its unit in brackets where one is known."""
    unit = (units or {}).get(name, "")
    text = f"{name} {what}".strip()
    return f"{text} [{unit}]" if unit else text


def _title(ax: Any, text: str, *, fontsize: float = 9) -> None:
    # a title at a fixed height: left to find its own, matplotlib measures every tick
    # label of the panel on each draw to keep clear of ticks that are never on top
    ax.set_title(text, fontsize=fontsize, loc="left", y=1.0)


def _hline(ax: Any, y: float, **style: Any) -> Line2D:
    """A horizontal line across the panel at `y` (kept in the data limits), as
    ``axhline`` draws it, without the autoscale of every panel sharing the x axis
    that ``axhline`` runs to see whether `y` is in view."""
    line = Line2D([0.0, 1.0], [y, y], transform=ax.get_yaxis_transform(which="grid"), **style)
    ax.add_line(line)
    return line


def _band(ax: Any, x0: float, x1: float, half: float, **style: Any) -> Rectangle:
    """A constant band from `x0` to `x1` between ``-half`` and ``half``: the rectangle
    ``fill_between`` draws there, without the autoscale of every panel sharing the x
    axis that adding its polygon runs first."""
    band = Rectangle((x0, -half), x1 - x0, 2.0 * half, **style)
    ax.add_patch(band)
    return band


def _hist(ax: Any, x: np.ndarray, bins: int) -> None:
    # one filled step artist instead of a patch per bin: the same picture, drawn faster
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return
    counts, edges = np.histogram(x, bins=bins)
    ax.stairs(counts, edges, fill=True, color=_cn(0), alpha=0.8)


def plot_time_histories(validation: Any, *, units: Mapping[str, str] | None = None) -> Figure:
    """Measured vs model time histories, residuals with their ±2σ band, and the inputs.

    SIDPAC's layout: each output over its residual, the control inputs that
    drove the manoeuvre in the panels underneath. Units come from the
    validation (its flight data) unless `units` gives them.
    """
    names = list(validation.output_names)
    unit_of = {**dict(getattr(validation, "units", {}) or {}), **dict(units or {})}
    controls = getattr(validation, "controls", None)
    control_names = list(getattr(validation, "control_names", ()) or ())
    n_inputs = len(control_names) if controls is not None else 0
    fig, axes = figure(
        2 * len(names) + n_inputs, height=1.9, hgap=0.5, sharex=True, reuse="time_histories"
    )
    t = validation.time
    for j, name in enumerate(names):
        ax = axes[2 * j, 0]
        ax.plot(t, validation.measured[:, j], color="0.55", lw=1.0, label="measured")
        ax.plot(t, validation.simulated[:, j], color=_cn(0), lw=1.4, label="model")
        m = validation.metrics[name]
        ax.set_ylabel(_label(name, unit_of))
        _title(ax, f"{name}: fit {m.fit:.1f} %, RMSE {m.rmse:.3g}")
        if j == 0:  # the same legend on every pair of panels: drawn once, at the top
            ax.legend(loc="upper right", fontsize=8)
        rax = axes[2 * j + 1, 0]
        e = validation.residuals[:, j]
        band = 2.0 * float(np.std(e))
        # a constant band: a rectangle (a vertex per sample costs 20 times more)
        _band(rax, t[0], t[-1], band, color=_cn(3), alpha=0.15, lw=0, label="±2σ")
        rax.plot(t, e, color=_cn(3), lw=0.9)
        _hline(rax, 0.0, color="k", lw=0.6)
        rax.set_ylabel(_label(name, unit_of, what="residual"))
        if j == 0:
            rax.legend(loc="upper right", fontsize=7)
    for k, name in enumerate(control_names[:n_inputs]):
        ax = axes[2 * len(names) + k, 0]
        assert controls is not None
        ax.plot(t, controls[:, k], color=_cn(2), lw=1.2)
        ax.set_ylabel(_label(name, unit_of))
        _title(ax, f"input {name}")
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_prediction(prediction: Any, *, units: Mapping[str, str] | None = None) -> Figure:
    """Measured vs predicted outputs on data held out of the fit, one panel per output.

    Each panel's title gives the output's Theil inequality coefficient and R^2.
    """
    names = list(prediction.output_names)
    unit_of = {**dict(getattr(prediction, "units", {}) or {}), **dict(units or {})}
    fig, axes = figure(len(names), height=1.9, hgap=0.5, sharex=True, reuse="prediction")
    t = prediction.time
    for j, name in enumerate(names):
        ax = axes[j, 0]
        m = prediction.metrics[name]
        ax.plot(t, prediction.measured[:, j], color="0.55", lw=1.0, label="measured")
        ax.plot(t, prediction.predicted[:, j], color=_cn(1), lw=1.4, label="predicted")
        ax.set_ylabel(_label(name, unit_of))
        _title(
            ax,
            f"{name} predicted ({prediction.source}): Theil U {m.theil_u:.3f}, "
            f"R² {m.r_squared:.3f}",
        )
        if j == 0:  # the same legend on every panel: drawn once, at the top
            ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def residual_autocorrelation(residuals: Any, max_lag: int) -> np.ndarray:
    """Sample autocorrelation of each residual column at lags 0..max_lag, shape (max_lag + 1, n_y)."""
    e = np.asarray(residuals, dtype=float)
    e = e - e.mean(axis=0)
    den = np.sum(e * e, axis=0)
    n = e.shape[0]
    r = np.array([np.sum(e[: n - k] * e[k:], axis=0) for k in range(max_lag + 1)])
    return np.divide(r, den, out=np.zeros_like(r), where=den > 0)


def plot_residual_autocorrelation(validation: Any, *, max_lag: int | None = None) -> Figure:
    """Each output's residual autocorrelation against lag, with the 95 % band of white
    noise, ±1.96/sqrt(N): a model that leaves white residuals stays inside it at
    about 19 lags in 20.

    Lags run to the validation's ``whiteness_lags`` unless `max_lag` is given,
    along the bottom in samples and, where the sample interval is known, in seconds.
    """
    names = list(validation.output_names)
    e = np.asarray(validation.residuals, dtype=float)
    n = e.shape[0]
    if n < 3 or not names:
        raise IdentificationError("plot_residual_autocorrelation: needs at least 3 residuals")
    lags = int(max_lag if max_lag is not None else (validation.whiteness_lags or 20))
    lags = max(1, min(lags, n - 1))
    r = residual_autocorrelation(e, lags)
    band = 1.96 / np.sqrt(n)
    t = np.asarray(validation.time, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    k = np.arange(lags + 1)
    fig, axes = figure(len(names), height=1.7, hgap=0.55, sharex=True, reuse="autocorrelation")
    for j, name in enumerate(names):
        ax = axes[j, 0]
        _band(ax, k[0], k[-1], band, color=_cn(0), alpha=0.15, lw=0, label="95 % band")
        ax.vlines(k[1:], 0.0, r[1:, j], color=_cn(3), lw=1.4)
        ax.plot(k[1:], r[1:, j], "o", color=_cn(3), ms=3)
        _hline(ax, 0.0, color="k", lw=0.6)
        outside = int(np.sum(np.abs(r[1:, j]) > band))
        _title(ax, f"{name} residual autocorrelation: {outside} of {lags} lags outside ±{band:.3f}")
        ax.set_ylabel("r(k)")
        if j == 0:  # the same legend on every panel: drawn once, at the top
            ax.legend(loc="upper right", fontsize=7)
    lag_unit = f" ({dt:.3g} s each)" if dt > 0 else ""
    axes[-1, 0].set_xlabel(f"lag k [samples{lag_unit}]")
    return fig


def _log_label(value: float, _pos: object) -> str:
    # log axes read as plain numbers at 1, 2 and 5 of each decade (0.2, 0.5, 1, 2 Hz)
    # instead of a power of ten on every minor tick
    if not np.isfinite(value) or value <= 0:
        return ""
    mantissa = value / 10.0 ** np.floor(np.log10(value) + 1e-9)
    return f"{value:g}" if any(abs(mantissa - m) < 1e-6 for m in (1, 2, 5)) else ""


LOG_LABELS = FuncFormatter(_log_label)


def _ratio_unit(output: str, input: str, units: Mapping[str, str]) -> str:
    uo, ui = units.get(output, ""), units.get(input, "")
    if not uo and not ui:
        return ""
    return f" [dB of {uo or '1'} per {ui or '1'}]"


def plot_frequency_response(freq: Any, *, units: Mapping[str, str] | None = None) -> Figure:
    """Bode plot per channel against frequency in rad/s, magnitude in dB and phase in
    degrees, with coherence.

    Empirical points (coherent ones marked) under the model's curve; the
    magnitude axis names the ratio's units when `units` gives them.
    """
    chans = list(freq.channels)
    unit_of = dict(units or {})
    fig, axes = figure(
        3, len(chans), width=4.2 * len(chans), height=2.1, right=0.3, hgap=0.3, sharex="col"
    )
    for c, ch in enumerate(chans):
        # rad/s, as handling-qualities work reads a Bode plot
        f = ch.frequency
        ok = ch.coherent
        mag, pha = axes[0, c], axes[1, c]
        db = np.asarray(ch.magnitude, dtype=float)
        model_db = np.asarray(ch.model_magnitude, dtype=float)
        mag.semilogx(f, db, color="0.6", lw=0.8, label="empirical")
        mag.semilogx(f[ok], db[ok], "o", color=_cn(1), ms=3, label="coherent")
        how = getattr(freq, "model_response", "")
        mag.semilogx(f, model_db, color=_cn(0), lw=1.4, label=f"model ({how})" if how else "model")
        mag.set_title(
            f"{ch.output_name} / {ch.input_name} (mismatch {ch.mismatch:.2g})", fontsize=9
        )
        mag.set_ylabel(
            "magnitude" + (_ratio_unit(ch.output_name, ch.input_name, unit_of) or " [dB]")
        )
        mag.legend(fontsize=7)
        pha.semilogx(f, ch.phase, color="0.6", lw=0.8)
        pha.semilogx(f[ok], ch.phase[ok], "o", color=_cn(1), ms=3)
        pha.semilogx(f, ch.model_phase, color=_cn(0), lw=1.4)
        pha.set_ylabel("phase [deg]")
        coh = axes[2, c]
        coh.semilogx(f, ch.coherence, color=_cn(2))
        coh.axhline(freq.coherence_threshold, color="k", ls="--", lw=0.7)
        coh.set_ylim(0, 1.05)
        coh.set_ylabel("coherence [-]")
        coh.set_xlabel("frequency [rad/s]")
        coh.xaxis.set_major_formatter(LOG_LABELS)
        coh.xaxis.set_minor_formatter(LOG_LABELS)
    return fig


def plot_filter(result: Any, *, data: Any = None, units: Mapping[str, str] | None = None) -> Figure:
    """Filtered (and smoothed) states with ±2σ bands, over the measurements of `data`.

    A state that the flight data records under its own name is drawn as measured points.
    """
    names = list(result.state_names)
    unit_of = {**dict(getattr(data, "units", {}) or {}), **dict(units or {})}
    fig, axes = figure(len(names), sharex=True, reuse="filter")
    t = result.time
    smoothed = result.smoothed_states is not None
    states = result.smoothed_states if smoothed else result.filtered_states
    cov = result.smoothed_covariance if smoothed else result.filtered_covariance
    label = "smoothed" if smoothed else "filtered"
    legend: tuple[list[Any], list[str]] = ([], [])
    for j, name in enumerate(names):
        ax = axes[j, 0]
        if data is not None and name in data and len(data[name]) == len(t):
            ax.plot(t, data[name], ".", color="0.55", ms=2, label="measured")
        sd = 2.0 * np.sqrt(np.clip(cov[:, j, j], 0, None))
        ax.fill_between(
            t, states[:, j] - sd, states[:, j] + sd, color=_cn(0), alpha=0.35, lw=0, label="±2σ"
        )
        if smoothed:
            ax.plot(t, result.filtered_states[:, j], color=_cn(1), lw=0.8, label="filtered")
        ax.plot(t, states[:, j], color=_cn(0), lw=1.3, label=label)
        ax.set_ylabel(_label(name, unit_of))
        drawn = ax.get_legend_handles_labels()
        if len(drawn[1]) > len(legend[1]):
            legend = drawn
    # one legend, on the top panel, with the entries of the panel that has the most
    # (a state the flight measured adds its points): not one legend a panel
    if names:
        axes[0, 0].legend(*legend, fontsize=8, loc="upper right", ncol=4)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_posterior(
    inference: Any,
    *,
    max_parameters: int = 6,
    marker: Mapping[str, float] | None = None,
    units: Mapping[str, str] | None = None,
) -> Figure:
    """Corner plot: marginal histograms and pairwise scatter of the posterior.

    `marker` (for instance the output-error estimates) is drawn as lines on
    the marginals and a cross on the pairs.
    """
    names = list(inference.parameter_names)[:max_parameters]
    s = inference.samples[:, : len(names)]
    n = len(names)
    fig, grid = _grid(
        n, n, width=2.0 * n + 1, height=2.0, left=1.0, top=0.3, bottom=0.75, hgap=0.12, wgap=0.12
    )
    mark = dict(marker or {})
    step = max(1, s.shape[0] // 3000)
    # A panel shares its x axis with its column and its y axis with its row, so
    # only the bottom row and the left column carry tick labels; three or four
    # ticks an axis keep the small panels legible (and each tick is costly to draw).
    column: dict[int, Any] = {}
    row: dict[int, Any] = {}
    for i in range(n):
        for j in range(i + 1):  # the lower triangle only
            ax = fig.add_subplot(
                grid[i, j], sharex=column.get(j), sharey=None if i == j else row.get(i)
            )
            column.setdefault(j, ax)
            if i == j:
                _hist(ax, s[:, i], 40)
                ax.set_yticks([])
                if names[i] in mark:
                    ax.axvline(mark[names[i]], color=_cn(3), lw=1.2)
            else:
                row.setdefault(i, ax)
                ax.plot(s[::step, j], s[::step, i], ".", ms=1, color=_cn(0), alpha=0.4)
                if names[i] in mark and names[j] in mark:
                    ax.plot(mark[names[j]], mark[names[i]], "x", color=_cn(3), ms=8, mew=2)
                ax.yaxis.set_major_locator(MaxNLocator(3))
            ax.xaxis.set_major_locator(MaxNLocator(3))
            ax.tick_params(labelsize=8, labelbottom=i == n - 1, labelleft=j == 0 and i > 0)
            if i == n - 1:
                ax.set_xlabel(_label(names[j], units), fontsize=10)
            if j == 0 and i > 0:
                ax.set_ylabel(_label(names[i], units), fontsize=10)
    if mark:
        fig.suptitle("posterior samples; red: the output-error estimate", fontsize=10)
    return fig


def plot_traces(inference: Any) -> Figure:
    """Sample traces per parameter (the kept, thinned chain in sampling order)."""
    names = list(inference.parameter_names)
    fig, axes = figure(len(names), height=1.4, hgap=0.35)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        ax.plot(inference.samples[:, j], lw=0.3, color=_cn(0))
        ax.set_ylabel(name, fontsize=8)
    axes[-1, 0].set_xlabel("sample")
    return fig


def plot_sensitivities(sens: Any) -> Figure:
    """Output sensitivity histories dy/dθ scaled by each parameter's value."""
    outs = list(sens.output_names)
    fig, axes = figure(len(outs))
    for k, out in enumerate(outs):
        ax = axes[k, 0]
        for p in sens.parameter_names:
            scale = abs(float(sens.values.get(p, 1.0))) or 1.0
            ax.plot(sens.time, scale * sens.sensitivity(out, p), lw=1.1, label=p)
        ax.set_ylabel(f"θ·∂{out}/∂θ")
        ax.legend(fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_design(design: Any) -> Figure:
    """The designed manoeuvre and the predicted parameter precision."""
    fig, axes = figure(2)
    ax = axes[0, 0]
    for j, c in enumerate(design.control_names):
        ax.plot(design.time, design.controls[:, j], lw=1.2, label=c)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("control")
    ax.legend(fontsize=8)
    ax.set_title(design.maneuver, fontsize=9, loc="left")
    bx = axes[1, 0]
    names = list(design.parameter_names)
    x = np.arange(len(names))
    bx.bar(
        x - 0.2, [design.initial_stderr[n] for n in names], 0.4, label="initial design", color="0.6"
    )
    bx.bar(
        x + 0.2, [design.predicted_stderr[n] for n in names], 0.4, label="optimised", color=_cn(0)
    )
    bx.set_xticks(x, names)
    bx.set_ylabel("predicted std. error")
    bx.legend(fontsize=8)
    return fig


def plot_propagation(prop: Any, *, label: str = "metric") -> Figure:
    """Histogram of the propagated metric with its percentiles (`label`: the quantity and
    its unit, e.g. ``"natural frequency [rad/s]"``)."""
    fig, axes = figure(1, height=3.0)
    _percentile_histogram(axes[0, 0], prop, label)
    return fig


def plot_vector_propagation(prop: Any) -> Figure:
    """One histogram per component of a propagated metric, with its percentiles."""
    names = list(prop.names)
    fig, axes = figure(len(names), height=2.4)
    for i, name in enumerate(names):
        _percentile_histogram(axes[i, 0], prop[name], name)
    return fig


def _percentile_histogram(ax: Any, prop: Any, label: str) -> None:
    """One propagated metric's draws with its percentiles marked."""
    _hist(ax, prop.samples, 50)
    for p, v in prop.percentile_table["metric"].items():
        ax.axvline(v, color="k", ls="--", lw=0.8)
        ax.text(v, ax.get_ylim()[1] * 0.95, f"P{p:g}", fontsize=7, ha="center")
    ax.set_xlabel(label)
    ax.set_ylabel("draws")


def plot_campaign_trend(
    records: Sequence[Mapping[str, Any]],
    *,
    condition: str | None = None,
    parameters: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
) -> Figure:
    """Each parameter's estimate with its 95 % bar (±1.96σ) across flights.

    Parameters
    ----------
    records : sequence of mapping
        One per flight: ``{"flight": label, "parameters": {...}, "stderr": {...},
        "metadata": {...}}``.
    condition : str, optional
        Metadata key to plot against (alpha, airspeed, Mach, dynamic pressure...);
        default the first of those present, else the flight index. Angles (alpha,
        beta, in rad) are drawn in degrees; where the flights give an altitude that
        varies, each altitude has its colour; up to 30 flights, each point is
        labelled with its flight.
    parameters : sequence of str, optional
        The parameters to draw, a panel each, in this order; default those of
        the first flight. A flight without an estimate of one leaves a gap.
    units : mapping of str to str, optional
        Units of the parameters and of the condition, for the axis labels.

    Raises
    ------
    IdentificationError
        A parameter in `parameters` that no flight estimated.
    """
    ok = [r for r in records if r.get("parameters")]
    names = list(ok[0]["parameters"]) if ok else []
    if parameters is not None:
        known = list(dict.fromkeys(n for r in ok for n in r["parameters"]))
        missing = [n for n in parameters if n not in known]
        if missing:
            raise IdentificationError(
                f"parameters: no flight has an estimate of {', '.join(missing)}; estimated: {known}"
            )
        names = list(parameters)
    if condition is None and ok:
        meta = ok[0].get("metadata", {})
        # the first condition key it gives, but for the sideslip and the altitude (a
        # trim's sideslip is zero; a varying altitude colours the points)
        for key_def in CONDITION_KEYS:
            given = [k for k in (key_def.name, key_def.name.capitalize()) if k in meta]
            if given and key_def.name not in ("beta", "altitude"):
                condition = given[0]
                break
    labels = [str(r.get("flight", i)) for i, r in enumerate(ok)]
    # flight names are written at 45 degrees under the last panel: room for the longest
    bottom = 0.55 if condition is not None else 0.45 + 0.065 * max(map(len, labels), default=0)
    # one x axis for every panel: tick labels under the last one only
    fig, axes = figure(
        max(len(names), 1), height=1.8, bottom=bottom, top=0.5, hgap=0.15, sharex=True
    )
    if condition is not None:
        x = np.array([float(r.get("metadata", {}).get(condition, np.nan)) for r in ok])
        cond_key = condition_key(condition)
        unit_of = {condition: cond_key.unit if cond_key else "", **dict(units or {})}
        if cond_key is not None and cond_key.shown != cond_key.unit:  # angles, in degrees
            x, unit_of[condition] = x * cond_key.scale, cond_key.shown
        xlabel = _label(condition, unit_of).replace("_", " ")
    else:
        x = np.arange(len(ok), dtype=float)
        xlabel = "flight"
    # a second condition, where the flights give one that varies: a colour per value
    alt = np.array([float(r.get("metadata", {}).get("altitude", np.nan)) for r in ok])
    groups = sorted(set(alt[np.isfinite(alt)].tolist())) if condition != "altitude" else []
    if len(groups) < 2:
        groups = []
    for j, name in enumerate(names):
        ax = axes[j, 0]
        y = np.array([r["parameters"].get(name, np.nan) for r in ok])
        e = np.array([1.96 * r["stderr"].get(name, np.nan) for r in ok])
        for g, sel in enumerate(
            [alt == h for h in groups] if groups else [np.ones(len(ok), dtype=bool)]
        ):
            label = f"altitude {groups[g]:g} m" if groups else None
            ax.errorbar(
                x[sel], y[sel], yerr=e[sel], fmt="o", ms=4, capsize=3, color=_cn(g), label=label
            )
        if condition is not None and len(ok) <= 30:
            for i in np.flatnonzero(np.isfinite(y)):
                ax.annotate(
                    labels[i], (x[i], y[i]), fontsize=5, xytext=(3, 2), textcoords="offset points"
                )
        ax.set_ylabel(_label(name, units), fontsize=8)
    if groups and names:
        axes[0, 0].legend(fontsize=6, loc="best", ncol=min(len(groups), 4))
    if names:
        # pinned 0.1 in below the top edge, inside the top margin, whatever the figure's
        # height (a fraction of a tall figure would reach into the first panel)
        fig.suptitle(
            "estimates across flights, bars: 95 % (±1.96σ)"
            + (f" against {xlabel}" if condition is not None else ""),
            fontsize=10,
            y=1.0 - 0.1 / fig.get_figheight(),
            va="top",
        )
        axes[-1, 0].set_xlabel(xlabel)
        if condition is None:
            axes[-1, 0].set_xticks(x, labels, rotation=45, ha="right", rotation_mode="anchor")
    return fig


def _identification_figure(n_outs: int, n_names: int, left: float) -> tuple[Figure, list[Any], Any]:
    """The identification figure's axes: a residual panel per output, then the forest
    (a row per parameter, `left` inches for its labels); recycled as `figure` does."""
    # the residual panels share one time axis, labelled under the last of them only
    width, top, bottom, gap, panel, row = 8.0, 0.35, 0.55, 0.15, 1.1, 0.2
    below = 0.8 if n_names else 0.0  # the residuals' time axis, then the forest's title
    forest_h = row * n_names + 0.15 if n_names else 0.0
    height = top + bottom + n_outs * (panel + gap) - gap * (n_outs > 0) + forest_h
    height = max(height + below * (n_outs > 0), 2.5)
    key = ("identification", n_outs, n_names)
    fig = _pooled(key)
    if fig is None:
        fig = Figure(figsize=(width, height))
        y = height - top  # inches from the bottom, walking down
        for k in range(n_outs):
            y -= panel
            rect = (0.95 / width, y / height, 6.85 / width, panel / height)
            fig.add_axes(rect, sharex=fig.axes[0] if k else None)
            if k < n_outs - 1:  # unlabelled, at a fixed place (see `figure`)
                fig.axes[-1].tick_params(labelbottom=False)
                fig.axes[-1].xaxis.set_label_coords(0.5, 0.0)
            y -= gap
        if n_names or not n_outs:  # the forest, or an empty panel where nothing was fitted
            h = forest_h if n_names else height - top - bottom
            fig.add_axes((0.95 / width, bottom / height, 6.85 / width, h / height))
        _KEYS[fig] = key
    axes = list(fig.axes)
    forest = axes[n_outs] if n_names else None
    if forest is not None:  # the width of its labels varies from flight to flight
        forest.set_position(
            (left / width, bottom / height, (width - left - 0.2) / width, forest_h / height)
        )
    return fig, axes[:n_outs], forest


def plot_identification(
    result: Any, *, units: Mapping[str, str] | None = None, time: Any = None
) -> Figure:
    """Residual histories of the fit, then a forest plot of the estimates with their 95 % bars.

    The forest has a row per parameter, labelled with its estimate, the half-width
    of its 95 % interval and its unit. Each row is divided by the larger of
    |estimate| and that half-width, so parameters of any size share the axis: an
    estimate lies at ±1 when it is larger than its half-width, and a bar that
    crosses zero (drawn grey) is an estimate not told apart from zero. `time`: the
    record's time stamps (s), the residuals' abscissa where they are as long as a
    manoeuvre's residuals (else the sample index).
    """
    names = list(result.parameter_names)
    outs = list(result.output_names)
    units = {**dict(getattr(result, "parameter_units", {}) or {}), **dict(units or {})}
    half = result.margin(0.95)  # each estimate's own 95 % interval (t with its dof)
    labels = []
    for name in names:
        unit = units.get(name, "")
        value, err = float(result.parameters[name]), float(half[name])
        labels.append(f"{name} = {value:.4g} ± {err:.2g}" + (f" [{unit}]" if unit else ""))
    # fixed margins (no layout engine): room for the longest row label at 7 pt
    left = round(max(0.95, 0.45 + 0.065 * max(map(len, labels), default=0)), 1)
    fig, panels, forest = _identification_figure(len(outs), len(names), left)
    on_time = time is not None and all(len(r) == len(time) for r in result.residuals)
    for k, out in enumerate(outs):
        ax = panels[k]
        for i, r in enumerate(result.residuals):
            x = np.asarray(time, dtype=float) if on_time else np.arange(len(r))
            label = f"manoeuvre {i}" if len(result.residuals) > 1 else None
            ax.plot(x, r[:, k], lw=0.8, label=label)
        _hline(ax, 0.0, color="k", lw=0.6)
        ax.set_ylabel(_label(out, units, what="residual"), fontsize=8)
    if panels:
        panels[-1].set_xlabel("time [s]" if on_time else "sample [-]")
    if forest is None:
        return fig
    est = np.array([float(result.parameters[n]) for n in names])
    bar = np.array([float(half[n]) for n in names])
    scale = np.maximum(np.abs(est), bar)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    rows = np.arange(len(names))[::-1]  # the first parameter on top
    zero_in = np.abs(est) <= bar
    for sel, color in ((~zero_in, _cn(0)), (zero_in, "0.55")):
        if sel.any():
            forest.errorbar(
                est[sel] / scale[sel],
                rows[sel],
                xerr=bar[sel] / scale[sel],
                fmt="o",
                ms=3.5,
                capsize=2.5,
                lw=1.1,
                color=color,
            )
    forest.axvline(0.0, color="0.7", lw=0.6)
    forest.set_xlim(-2.15, 2.15)
    forest.set_ylim(-0.6, len(names) - 0.4)
    forest.set_yticks(rows, labels, fontsize=7)
    forest.tick_params(axis="y", length=0)
    forest.tick_params(axis="x", labelsize=7)
    forest.set_xlabel("estimate / max(|estimate|, 95 % half-width)", fontsize=8)
    forest.set_ylabel("parameter", fontsize=8)
    _title(forest, "estimates, bars: 95 %; grey: the interval holds zero", fontsize=8)
    return fig
