"""Figures for every result type (matplotlib, no GUI: figures are built directly).

Each function returns a `matplotlib.figure.Figure`; the result classes expose
them as ``.plot()``. Nothing here touches pyplot's global state, so it works
headless and leaves a user's chosen backend alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator

from .errors import IdentificationError

__all__ = [
    "plot_campaign_trend",
    "plot_design",
    "plot_filter",
    "plot_frequency_response",
    "plot_identification",
    "plot_posterior",
    "plot_propagation",
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


def _figure(
    rows: int, cols: int = 1, *, sharex: bool | str = False, **layout: float
) -> tuple[Figure, Any]:
    fig, grid = _grid(rows, cols, **layout)
    return fig, grid.subplots(squeeze=False, sharex=sharex)


def _hist(ax: Any, x: np.ndarray, bins: int) -> None:
    # one filled step artist instead of a patch per bin: the same picture, drawn faster
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return
    counts, edges = np.histogram(x, bins=bins)
    ax.stairs(counts, edges, fill=True, color="C0", alpha=0.8)


def plot_time_histories(validation: Any) -> Figure:
    """Measured vs model time histories, with a residual panel under each output."""
    names = list(validation.output_names)
    fig, axes = _figure(2 * len(names), height=1.9, hgap=0.5)
    t = validation.time
    for j, name in enumerate(names):
        ax = axes[2 * j, 0]
        ax.plot(t, validation.measured[:, j], color="0.55", lw=1.0, label="measured")
        ax.plot(t, validation.simulated[:, j], color="C0", lw=1.4, label="model")
        m = validation.metrics[name]
        ax.set_ylabel(name)
        ax.set_title(f"{name}: fit {m.fit:.1f} %, RMSE {m.rmse:.3g}", fontsize=9, loc="left")
        ax.legend(loc="upper right", fontsize=8)
        rax = axes[2 * j + 1, 0]
        rax.plot(t, validation.residuals[:, j], color="C3", lw=0.9)
        rax.axhline(0.0, color="k", lw=0.6)
        rax.set_ylabel(f"{name} residual")
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def _log_label(value: float, _pos: object) -> str:
    # log axes read as plain numbers at 1, 2 and 5 of each decade (0.2, 0.5, 1, 2 Hz)
    # instead of a power of ten on every minor tick
    if not np.isfinite(value) or value <= 0:
        return ""
    mantissa = value / 10.0 ** np.floor(np.log10(value) + 1e-9)
    return f"{value:g}" if any(abs(mantissa - m) < 1e-6 for m in (1, 2, 5)) else ""


_LOG_LABELS = FuncFormatter(_log_label)


def plot_frequency_response(freq: Any) -> Figure:
    """Empirical vs model Bode plot per channel, with coherence."""
    chans = list(freq.channels)
    fig, axes = _figure(
        3, len(chans), width=4.2 * len(chans), height=2.1, right=0.3, hgap=0.3, sharex="col"
    )
    for c, ch in enumerate(chans):
        f = ch.frequency
        ok = ch.coherent
        mag, pha = axes[0, c], axes[1, c]
        mag.loglog(f, ch.magnitude, color="0.6", lw=0.8, label="empirical")
        mag.loglog(f[ok], ch.magnitude[ok], "o", color="C1", ms=3, label="coherent")
        mag.loglog(f, ch.model_magnitude, color="C0", lw=1.4, label="model")
        mag.set_title(
            f"{ch.input_name} → {ch.output_name} (mismatch {ch.mismatch:.2g})", fontsize=9
        )
        mag.legend(fontsize=7)
        pha.semilogx(f, np.degrees(ch.phase), color="0.6", lw=0.8)
        pha.semilogx(f, np.degrees(ch.model_phase), color="C0", lw=1.4)
        pha.set_ylabel("phase [deg]")
        coh = axes[2, c]
        coh.semilogx(f, ch.coherence, color="C2")
        coh.axhline(freq.coherence_threshold, color="k", ls="--", lw=0.7)
        coh.set_ylim(0, 1.05)
        coh.set_ylabel("coherence")
        coh.set_xlabel("frequency [Hz]")
        for axis in (coh.xaxis, mag.yaxis):
            axis.set_major_formatter(_LOG_LABELS)
            axis.set_minor_formatter(_LOG_LABELS)
    axes[0, 0].set_ylabel("magnitude")
    return fig


def plot_filter(result: Any) -> Figure:
    """Filtered (and smoothed) states with ±1σ bands."""
    names = list(result.state_names)
    fig, axes = _figure(len(names))
    t = result.time
    smoothed = result.smoothed_states is not None
    states = result.smoothed_states if smoothed else result.filtered_states
    cov = result.smoothed_covariance if smoothed else result.filtered_covariance
    for j, name in enumerate(names):
        ax = axes[j, 0]
        sd = np.sqrt(np.clip(cov[:, j, j], 0, None))
        ax.fill_between(t, states[:, j] - sd, states[:, j] + sd, color="C0", alpha=0.25, lw=0)
        ax.plot(t, result.filtered_states[:, j], color="0.5", lw=0.8, label="filtered")
        if smoothed:
            ax.plot(t, states[:, j], color="C0", lw=1.3, label="smoothed ±1σ")
        ax.set_ylabel(name)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    return fig


def plot_posterior(inference: Any, *, max_parameters: int = 6) -> Figure:
    """Corner plot: marginal histograms and pairwise scatter of the posterior."""
    names = list(inference.parameter_names)[:max_parameters]
    s = inference.samples[:, : len(names)]
    n = len(names)
    fig, grid = _grid(
        n, n, width=1.7 * n + 1, height=1.7, left=0.8, top=0.2, bottom=0.5, hgap=0.12, wgap=0.12
    )
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
            else:
                row.setdefault(i, ax)
                ax.plot(s[::step, j], s[::step, i], ".", ms=1, color="C0", alpha=0.4)
                ax.yaxis.set_major_locator(MaxNLocator(3))
            ax.xaxis.set_major_locator(MaxNLocator(3))
            ax.tick_params(labelsize=6, labelbottom=i == n - 1, labelleft=j == 0 and i > 0)
            if i == n - 1:
                ax.set_xlabel(names[j], fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
    return fig


def plot_traces(inference: Any) -> Figure:
    """Sample traces per parameter (the kept, thinned chain in sampling order)."""
    names = list(inference.parameter_names)
    fig, axes = _figure(len(names), height=1.4, hgap=0.35)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        ax.plot(inference.samples[:, j], lw=0.3, color="C0")
        ax.set_ylabel(name, fontsize=8)
    axes[-1, 0].set_xlabel("sample")
    return fig


def plot_sensitivities(sens: Any) -> Figure:
    """Output sensitivity histories dy/dθ scaled by each parameter's value."""
    outs = list(sens.output_names)
    fig, axes = _figure(len(outs))
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
    fig, axes = _figure(2)
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
    bx.bar(x + 0.2, [design.predicted_stderr[n] for n in names], 0.4, label="optimised", color="C0")
    bx.set_xticks(x, names)
    bx.set_ylabel("predicted std. error")
    bx.legend(fontsize=8)
    return fig


def plot_propagation(prop: Any, *, label: str = "metric") -> Figure:
    """Histogram of the propagated metric with its percentiles."""
    fig, axes = _figure(1, height=3.0)
    ax = axes[0, 0]
    _hist(ax, prop.samples, 50)
    for k, v in prop.percentiles.items():
        ax.axvline(v, color="k", ls="--", lw=0.8)
        ax.text(v, ax.get_ylim()[1] * 0.95, k, fontsize=7, ha="center")
    ax.set_xlabel(label)
    ax.set_ylabel("draws")
    return fig


def plot_campaign_trend(
    records: Sequence[Mapping[str, Any]],
    *,
    condition: str | None = None,
    parameters: Sequence[str] | None = None,
) -> Figure:
    """Each parameter's estimate ±1.96σ across flights.

    Parameters
    ----------
    records : sequence of mapping
        One per flight: ``{"flight": label, "parameters": {...}, "stderr": {...},
        "metadata": {...}}``.
    condition : str, optional
        Metadata key to plot against (airspeed, Mach, dynamic pressure...);
        default the first of those present, else the flight index.
    parameters : sequence of str, optional
        The parameters to draw, a panel each, in this order; default those of
        the first flight. A flight without an estimate of one leaves a gap.

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
        for key in ("airspeed", "mach", "Mach", "dynamic_pressure", "qbar"):
            if key in meta:
                condition = key
                break
    labels = [str(r.get("flight", i)) for i, r in enumerate(ok)]
    # flight names are written at 45 degrees under the last panel: room for the longest
    bottom = 0.55 if condition is not None else 0.45 + 0.065 * max(map(len, labels), default=0)
    # one x axis for every panel: tick labels under the last one only
    fig, axes = _figure(max(len(names), 1), height=1.8, bottom=bottom, hgap=0.15, sharex=True)
    if condition is not None:
        x = np.array([float(r.get("metadata", {}).get(condition, np.nan)) for r in ok])
        xlabel = condition.replace("_", " ")
    else:
        x = np.arange(len(ok), dtype=float)
        xlabel = "flight"
    for j, name in enumerate(names):
        ax = axes[j, 0]
        y = np.array([r["parameters"].get(name, np.nan) for r in ok])
        e = np.array([1.96 * r["stderr"].get(name, np.nan) for r in ok])
        ax.errorbar(x, y, yerr=e, fmt="o", ms=4, capsize=3, color="C0")
        ax.set_ylabel(name)
    if names:
        axes[-1, 0].set_xlabel(xlabel)
        if condition is None:
            axes[-1, 0].set_xticks(x, labels, rotation=45, ha="right", rotation_mode="anchor")
    return fig


def plot_identification(result: Any) -> Figure:
    """Residual histories of the fit and the estimates with 95 % error bars."""
    names = list(result.parameter_names)
    outs = list(result.output_names)
    fig, axes = _figure(len(outs) + 1, height=2.0)
    for k, out in enumerate(outs):
        ax = axes[k, 0]
        for i, r in enumerate(result.residuals):
            ax.plot(r[:, k], lw=0.8, label=f"manoeuvre {i}" if len(result.residuals) > 1 else None)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(f"{out} residual")
        ax.set_xlabel("sample")
    ax = axes[-1, 0]
    est = np.array([result.parameters[n] for n in names])
    err = np.array([1.96 * result.stderr[n] for n in names])
    ax.errorbar(np.arange(len(names)), est, yerr=err, fmt="o", capsize=4)
    ax.set_xticks(np.arange(len(names)), names)
    ax.set_ylabel("estimate ±1.96σ")
    return fig
