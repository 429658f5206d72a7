"""The campaign report: its stage (a table over the flights, figures drawn in parallel
parts) and the Markdown and HTML files a run writes from it.

The files a run writes are its own: it overwrites only a file an earlier run
wrote (recognised by a marker), never a campaign input, and it refuses a
report path whose HTML twin would be the report itself.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...errors import AeroidError
from ..plans.config import Options
from ..plans.run_plan import HTML_MARKER, MD_MARKER, html_report_path
from . import FIGURE_IMPORTS, CampaignReport, Stage, StageContext, register_stage
from ._campaign_tables import (
    campaign_units,
    condition_text,
    estimate_tables,
    fit_whiteness,
    html_report,
    identification_brief,
    metric_heading,
    name_the_metric,
    what_was_flown,
    with_warnings,
)
from .analysis_stages import hq_brief, hq_table
from .database_stage import with_database
from .flight_status import determined_shares, flight_status, legend, one_step_fits, severity

if TYPE_CHECKING:
    from ..plans.planning import Plan
    from ..running.execution import TaskStatus
    from ..storage.store import ResultStore

__all__ = ["CampaignReportOptions", "ReportWriteError", "html_report_path"]


class CampaignReportOptions(Options):
    """Options of the campaign report."""

    title: str | None = None
    include_flight_reports: bool = True
    figures: bool = True


_METRIC_COLUMN = "metric (mean ± std)"
# units of the metrics `propagate` computes by name
_METRIC_UNITS = {"natural_frequency": "rad/s", "damping_ratio": "-", "time_constant": "s"}
_METRIC_UNITS["static_margin"] = "mean aerodynamic chords"


def _campaign_brief(role: str, record: Any) -> Any:
    """What the campaign report uses of one flight's `role` input (see `Stage.brief`).

    The status flags come from the records themselves, so a cached rerun shows
    the same flags as the run that computed them.
    """
    if role == "data":
        meta = dict(getattr(record, "metadata", {}) or {})
        quality = meta.pop("quality", None)
        if quality is not None:
            meta["quality_flags"] = {n: list(f) for n, f in quality.flags.items() if f}
        return meta
    if role == "identification":
        return identification_brief(record)
    if role == "validation":
        return fit_whiteness(record)
    if role == "propagation":
        if getattr(record, "mean", None) is None:
            return "—"
        mean, std = float(np.ravel(record.mean)[0]), float(np.ravel(record.std)[0])
        label = str(getattr(record, "source", "") or "").rsplit(":", 1)[-1]
        unit = _METRIC_UNITS.get(label, "")
        text = f"{mean:.4g} ± {std:.2g}" + (f" {unit}" if unit else "")
        return f"{label} {text}" if label in _METRIC_UNITS else text
    if role == "inference":
        return {"converged": bool(getattr(record, "converged", True))}
    if role == "reports":
        return record.markdown
    if role == "handling_qualities":
        return hq_brief(record)
    return None  # the figures' inputs: read whole by the figure parts


# The figures of each flight, drawn from its records: (role, file label, title).
_FLIGHT_FIGURES = (
    ("validation", "time_histories", "measured and model outputs, inputs underneath"),
    ("validation", "residual_autocorrelation", "residual autocorrelation, white-noise band"),
    ("validation", "prediction", "prediction of the held-out manoeuvre, measured vs predicted"),
    ("identification", "identification", "residuals and estimates (95 % bars)"),
    ("filtering", "filter_states", "filtered states and measurements"),
    ("frequency", "bode", "Bode plot and coherence"),
    ("inference", "posterior", "posterior (output-error fit marked)"),
)

# The campaign report is split into parts that run in parallel: parts 0 and 1 draw
# the cross-flight trend of the first and the second half of the parameters, part 2
# writes the tables and text (these three need every flight), and each of the
# `_FIGURE_PARTS` further parts draws the figures of every `_FIGURE_PARTS`-th flight as
# soon as those flights are done, so the figures overlap the flights still running.
# Sixteen: up to sixteen flights, a part draws one flight, so the part that waits for
# the run's last flight draws that flight alone (with eight, the demo's last part
# drew two flights after every flight was done, on the run's critical path); an
# empty part costs a few milliseconds.
_TRENDS, _TEXT, _FIRST_FIGURES = (0, 1), 2, 3
_FIGURE_PARTS = 16
_MAX_FLIGHTS = 1 << 16


def _campaign_parts(options: Any, roles: frozenset[str]) -> int:
    # 1 (not split) without figures
    if not options.figures or "identification" not in roles:
        return 1
    return _FIRST_FIGURES + _FIGURE_PARTS


def _campaign_part_flights(
    options: Any, roles: frozenset[str], index: int
) -> tuple[int, ...] | None:
    # the trend and the text read all flights; a figure part every _FIGURE_PARTS-th
    if index < _FIRST_FIGURES:
        return None
    return tuple(range(index - _FIRST_FIGURES, _MAX_FLIGHTS, _FIGURE_PARTS))


def _figure_key(flight: str, label: str) -> str:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in flight)
    return f"{safe}_{label}.png"


def _flight_units(records: Mapping[str, Any]) -> dict[str, str]:
    """Units of one flight's channels (its data and validation) and its parameters."""
    from ...support import parameter_units

    units: dict[str, str] = {}
    for role in ("data", "validation"):
        rec = records.get(role)
        units.update({k: v for k, v in (getattr(rec, "units", {}) or {}).items() if v})
    names = [
        n
        for role in ("identification", "inference")
        for n in getattr(records.get(role), "parameter_names", ())
    ]
    declared = getattr(records.get("identification"), "parameter_units", None)
    units.update(parameter_units(names, declared, units))
    # an output's noise standard deviation (inference's sigma_<output>) has its unit
    units.update({n: units[n[6:]] for n in names if n.startswith("sigma_") and n[6:] in units})
    return units


def flight_figures(records: Mapping[str, Any]) -> list[tuple[str, Any]]:
    """The figures of one flight, from its records by role: (label, matplotlib Figure).

    Every figure labels its axes with the units of the flight's channels and of
    the model's parameters.
    """
    from ...reports.plotting import plot_residual_autocorrelation

    units = _flight_units(records)
    out = []
    for role, label, _ in _FLIGHT_FIGURES:
        rec = records.get(role)
        if rec is None or not hasattr(rec, "plot"):
            continue
        if label == "residual_autocorrelation":
            out.append((label, plot_residual_autocorrelation(rec)))
            continue
        if label == "prediction":
            held = getattr(rec, "prediction", None)  # only where the flight held data out
            if held is not None:
                out.append((label, held.plot(units=units)))
            continue
        kw: dict[str, Any] = {"units": units}
        if role == "filtering":
            kw["data"] = records.get("data")
        if role == "identification" and records.get("data") is not None:
            kw["time"] = records["data"].time  # residuals against time
        if role == "inference" and records.get("identification") is not None:
            kw["marker"] = dict(records["identification"].parameters)
        out.append((label, rec.plot(**kw)))
    return out


def _flight_figures(ctx: StageContext, flight: int) -> list[tuple[str, bytes]]:
    """The figures of flight `flight`: (file name, PNG bytes)."""
    from ...reports.plotting import recycle_figure, reusing_figures
    from ...support import figure_png

    records = {
        role: ctx.inputs[role][flight]
        for role in ("data", "identification", *(r for r, _, _ in _FLIGHT_FIGURES))
        if role in ctx.inputs
    }
    out = []
    # the next flight drawn in this process redraws these figures instead of making new
    with reusing_figures():
        for label, fig in flight_figures(records):
            out.append(
                (_figure_key(ctx.flights[flight], label), figure_png(fig, dpi=72, colors=32))
            )
            recycle_figure(fig)
    return out


def _trend_figure(ctx: StageContext, index: int) -> tuple[str, bytes] | None:
    from ...reports.plotting import plot_campaign_trend
    from ...support import figure_png

    records = []
    for i, f in enumerate(ctx.flights):
        r = ctx.brief("identification", i)
        if r is not None:
            meta = ctx.brief("data", i)
            records.append(
                {
                    "flight": f,
                    "parameters": r["parameters"],
                    "stderr": r["stderr"],
                    "metadata": {} if meta is None else meta,
                }
            )
    names = list(dict.fromkeys(n for r in records for n in r["parameters"]))
    half = -(-len(names) // len(_TRENDS))
    names = names[index * half : (index + 1) * half]
    if not names:
        return None
    units, _ = campaign_units([ctx.brief("identification", i) for i in range(len(ctx.flights))])
    fig = plot_campaign_trend(records, parameters=names, units=units)
    png = figure_png(fig, colors=64)
    return f"campaign_trend_{index}.png", png


def _run_campaign_part(ctx: StageContext, index: int) -> Any:
    """Part `index` of the campaign report.

    A trend part returns (file name, PNG bytes) or None; the text part the
    `CampaignReport` without figures; a figure part a list of (flight index, file name, PNG
    bytes) of its flights.
    """
    if index == _TEXT:
        return _run_campaign_report(ctx)
    if index in _TRENDS:
        return _trend_figure(ctx, index)
    drawn: list[tuple[int, str, bytes]] = []
    for i in range(index - _FIRST_FIGURES, len(ctx.flights), _FIGURE_PARTS):
        drawn += [(i, name, png) for name, png in _flight_figures(ctx, i)]
    return drawn


def _combine_campaign(ctx: StageContext, parts: list[Any]) -> CampaignReport:
    report = next((p for p in parts if isinstance(p, CampaignReport)), None)
    if report is None:
        report = _run_campaign_report(ctx)
    drawn: dict[str, bytes] = {}
    for part in parts:
        if isinstance(part, tuple):
            drawn[part[0]] = part[1]
    # the flights' figures in flight order, however the parts split the flights
    flown = sorted(
        (f for part in parts if isinstance(part, list) for f in part), key=lambda f: f[0]
    )
    drawn.update((name, png) for _, name, png in flown)
    # the text links every figure a flight could have: drop those not drawn
    lines = [
        ln
        for ln in report.markdown.splitlines()
        if not (m := _FIGURE_LINK.match(ln.strip())) or m.group(1) in drawn
    ]
    return dataclasses.replace(
        report,
        markdown="\n".join(lines) + "\n",
        figure_titles=tuple(drawn),
        figures=tuple(np.frombuffer(png, dtype=np.uint8) for png in drawn.values()),
    )


_FIGURE_DIR = "figures"
_FIGURE_LINK = re.compile(r"^!\[[^\]]*\]\(" + _FIGURE_DIR + r"/([^)]+)\)$")


def _run_campaign(ctx: StageContext) -> CampaignReport:
    # unsplit (a rerun, a pipeline run without Dask parts): the parts one after the
    # other, so the record is the one the parallel parts give
    n = _campaign_parts(ctx.options, frozenset(ctx.inputs))
    if n == 1:
        return _combine_campaign(ctx, [_run_campaign_report(ctx)])
    return _combine_campaign(ctx, [_run_campaign_part(ctx, i) for i in range(n)])


def _anchor(flight: str) -> str:
    # ASCII only, as the HTML converter's section and link patterns read them; another
    # character by its code point, so that two names never share an anchor
    return "flight-" + "".join(
        c if (c.isascii() and c.isalnum()) or c in "-_." else f"_{ord(c):x}_" for c in flight
    )


def _run_campaign_report(ctx: StageContext) -> CampaignReport:
    import html

    from ...support import markdown_table

    flights = ctx.flights
    ident = [ctx.brief("identification", i) for i in range(len(flights))]
    names: list[str] = []
    for r in ident:
        for n in r["names"] if r is not None else ():
            if n not in names:
                names.append(n)
    punits, guessed = campaign_units(ident)
    columns = (
        "flight",
        "condition",
        *(f"{n} [{punits[n]}]" if n in punits else n for n in names),
        "fit",
        "whiteness",
        _METRIC_COLUMN,
        "status",
    )
    n_est = len(names)
    shares = determined_shares(ident)
    rows = []
    statuses = []
    for i, f in enumerate(flights):
        r, v, meta = ident[i], ctx.brief("validation", i), ctx.brief("data", i)
        est = []
        for n in names:
            if r is not None and n in r["parameters"]:
                est.append(f"{r['parameters'][n]:.4g} ± {r['stderr'][n]:.2g}")
            else:
                est.append("—")
        fit, white = ("—", "—") if v is None else (one_step_fits(r, v) or v[0], v[1])
        metric = ctx.brief("propagation", i) or "—"
        infer = ctx.brief("inference", i)
        status = flight_status(ctx.failures.get(f), r, v, infer, meta, determined=shares[i])
        statuses.append(status)
        rows.append(
            (f, "—" if meta is None else condition_text(meta), *est, fit, white, metric, status)
        )
    title = ctx.options.title or "Campaign report"
    parts = [f"# {title}", ""]
    n_flagged = sum(s not in ("ok", "failed") for s in statuses)
    parts += [
        f"{len(flights)} flights, {len(ctx.failures)} failed, {n_flagged} flagged (status).",
        "",
        "## Campaign",
        "",
        "Each estimate against the flight condition, with its 95 % confidence bar "
        "(±1.96 standard errors).",
        "",
    ]
    if ctx.options.figures and names:
        for k in _TRENDS:
            parts += [
                f"![estimates across flights ({k + 1})]({_FIGURE_DIR}/campaign_trend_{k}.png)"
            ]
            parts.append("")
    parts += ["### Flights at a glance", ""]
    parts += [
        "Fit: each output's normalised fit 100 (1 - |e| / |y - mean y|), in percent, of "
        "its simulation (of a filter-error fit, its one-step prediction: e the innovations). "
        "Metric: the propagated metric, mean ± 1 standard deviation over its draws.",
        "",
    ]
    # whiteness output by output is in each flight's section; the status counts it
    glance = [j for j in (0, 1, *range(2 + n_est, len(columns))) if columns[j] != "whiteness"]
    parts += [markdown_table([columns[j] for j in glance], [[r[j] for j in glance] for r in rows])]
    parts += ["", *legend(ident)]
    if names:
        marked = {n: u + (" (guessed)" if n in guessed else "") for n, u in punits.items()}
        parts += estimate_tables(names, marked, flights, [r[2 : 2 + n_est] for r in rows])
        if guessed & set(names):
            parts += [
                "A unit marked (guessed) is read from the parameter's name and the flights' "
                "channel units; the model declares none.",
                "",
            ]
    parts += hq_table(
        list(flights),
        [r[1] for r in rows],
        [ctx.brief("handling_qualities", i) for i in range(len(flights))],
    )
    if ctx.failures:
        parts += ["## Failures", ""]
        parts += [f"- **{f}**: {err}" for f, err in ctx.failures.items()]
        parts.append("")
    parts += ["## Flights, worst first", ""]
    order = sorted(range(len(flights)), key=lambda i: severity(statuses[i]))
    parts += [f"- [{flights[i]}](#{_anchor(flights[i])}): {statuses[i]}" for i in order]
    for i, f in enumerate(flights):
        # open, so that a printout shows every flight
        parts += ["", f'<details id="{_anchor(f)}" open>']
        parts.append(f"<summary>{html.escape(f)}: {html.escape(statuses[i])}</summary>")
        parts.append("")
        text = ctx.brief("reports", i) if ctx.options.include_flight_reports else None
        if text is not None:
            # demote the per-flight headings under the campaign's
            parts += ["#" + ln if ln.startswith("#") else ln for ln in text.splitlines()]
        elif f in ctx.failures:
            parts.append(f"Failed: {ctx.failures[f]}")
        if ctx.options.figures and f not in ctx.failures:
            parts += ["", "### Figures", ""]
            for _, label, caption in _FLIGHT_FIGURES:
                parts += [f"![{f}: {caption}]({_FIGURE_DIR}/{_figure_key(f, label)})", ""]
        parts.append("</details>")
    return CampaignReport(
        title=title,
        markdown="\n".join(parts) + "\n",
        flights=tuple(flights),
        columns=columns,
        rows=tuple(tuple(r) for r in rows),
        failures=dict(ctx.failures),
    )


register_stage(
    Stage(
        "campaign_report",
        # 3: figures with fixed margins; 4: corner plot with shared axes (other bytes);
        # 5: the trend across flights as two figures, drawn in parallel; 6: figures of
        # every flight beside its tables, status flags from every stage, units;
        # 7: data-quality flags in the status, handling qualities across flights;
        # 8: handling-qualities Levels and right-half-plane zeros named; 9: estimates
        # transposed and split to fit a page, 1σ labelled, poor-fit and error flags,
        # flights worst first and open for printing; 10: residual autocorrelation
        # and held-out prediction figures per flight; 11: trends against alpha (deg)
        # where given, a colour per altitude, each point labelled with its flight;
        # 12: a filter-error fit's poor-fit and coloured flags from its innovations,
        # palette figures drawn straight from the canvas; 13: "not determined" against
        # the other flights, the model-structure note, filter error's one-step fits;
        # 14: a flight's figures drawn by a part of their own up to sixteen flights,
        # stored in flight order; 15: text drawn a string at a time (other bytes);
        # 16: no file name for a flight without a condition (a renamed file's is old)
        # 17: units guessed only from the flights' channel units, marked so
        # 18: ASCII anchors; undefined values as a dash; biases and noise tabled
        # 19: nondimensional rates' derivatives per rad; feet where the model is
        "19",
        CampaignReportOptions,
        "CampaignReport",
        _run_campaign,
        uses_model=False,
        per_flight=False,
        parts=_campaign_parts,
        run_part=_run_campaign_part,
        combine=_combine_campaign,
        part_flights=_campaign_part_flights,
        brief=_campaign_brief,
        imports=FIGURE_IMPORTS,
    )
)


# -- the files a run writes ---------------------------------------------------------------


class ReportWriteError(AeroidError):
    """A campaign report could not be written (a full disk, a permission): names the path."""


def _write(path: Path, data: bytes) -> None:
    from ...support import atomic_write as _atomic_write

    try:
        _atomic_write(path, data)
    except OSError as exc:
        raise ReportWriteError(f"cannot write the report {path}: {exc.strerror or exc}") from None


def write_report(
    the_plan: Plan,
    store: ResultStore,
    statuses: dict[str, TaskStatus],
    *,
    database_dir: Path | None = None,
) -> tuple[Path | None, list[str], list[list[str]], str | None]:
    """Write the campaign report's Markdown and HTML files (with the aerodynamic
    database's section and plots from `database_dir`, where the database was written).

    Returns (Markdown path or None, table columns, table rows, the error that kept a
    file from being written or None): the table comes back even when the files
    cannot be written.
    """
    task = the_plan.report_task
    if task is None:
        return None, [], [], None
    status = statuses[task.key]
    if status.status == "failed":
        return None, [], [], None
    record = None
    if status.markdown is not None:
        text, columns, rows = status.markdown, list(status.columns), [list(r) for r in status.rows]
    else:
        try:
            record = store.load(task.key, task.stage)
        except AeroidError as exc:
            statuses[task.key] = status.replace(status="failed", error=str(exc))
            return None, [], [], None
        text = getattr(record, "markdown", str(record))
        columns = list(getattr(record, "columns", ()))
        rows = [list(r) for r in getattr(record, "rows", ())]
    text = what_was_flown(with_warnings(text, the_plan, statuses), the_plan.config.source)
    extra: dict[str, bytes] = {}
    if database_dir is not None:
        text, extra = with_database(text, database_dir)
    # the propagated metric by its name and unit (the config names it)
    heading = metric_heading(the_plan.config.stages, _METRIC_UNITS)
    if heading is not None:
        text = name_the_metric(text, _METRIC_COLUMN, heading)
        columns = [heading if c == _METRIC_COLUMN else c for c in columns]
    path = the_plan.config.report_path
    folder = f"{path.stem}_figures"
    # the Markdown links its figures, written beside it
    text = text.replace(f"]({_FIGURE_DIR}/", f"]({folder}/")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        marked = text.rstrip("\n") + "\n\n" + MD_MARKER + "\n"
        target = html_report_path(path)
        # rebuilt only when the campaign report or its text (the config shown, the
        # warnings) changes: an unchanged rerun stays cheap
        digest = hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
        marker = f"{HTML_MARKER} {task.key} {digest} -->"
        fresh = target.is_file() and marker in target.read_text(encoding="utf-8", errors="replace")
        if not fresh:
            if status.figures is not None:
                figures = dict(status.figures)
            else:
                if record is None:
                    with contextlib.suppress(AeroidError):
                        record = store.load(task.key, task.stage)
                draw = getattr(record, "figure_bytes", None)
                figures = draw() if draw is not None else {}
            named = {f"{folder}/{k}": png for k, png in figures.items()}
            for rel, png in named.items():
                _write(path.parent / rel, png)
            named.update(extra)  # written beside the report already
            if not path.is_file() or path.read_text(encoding="utf-8") != marked:
                _write(path, marked.encode("utf-8"))
            _write(target, html_report(text, named, marker).encode("utf-8"))
        elif not path.is_file() or path.read_text(encoding="utf-8") != marked:
            _write(path, marked.encode("utf-8"))
    except ReportWriteError as exc:
        return None, columns, rows, str(exc)
    except OSError as exc:
        return None, columns, rows, f"cannot write the report {path}: {exc.strerror or exc}"
    return path, columns, rows, None
