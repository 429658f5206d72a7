"""The campaign report: its stage (a table over the flights, figures drawn in parallel
parts) and the Markdown and HTML files a run writes from it.

The files a run writes are its own: it overwrites only a file an earlier run
wrote (recognised by a marker), never a campaign input, and it refuses a
report path whose HTML twin would be the report itself.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import AeroidError, ConfigError
from .config import CampaignConfig, Options
from .stages import CampaignReport, Stage, StageContext, register_stage

if TYPE_CHECKING:
    from .execution import TaskStatus
    from .planning import Plan
    from .store import ResultStore

__all__ = ["CampaignReportOptions", "ReportWriteError", "html_report_path"]


class CampaignReportOptions(Options):
    """Options of the campaign report."""

    title: str | None = None
    include_flight_reports: bool = True
    figures: bool = True


def _fit_whiteness(validation: Any) -> tuple[str, str]:
    metrics = getattr(validation, "metrics", None)
    if not isinstance(metrics, Mapping) or not metrics:
        return "—", "—"
    fits, white = [], []
    for name, m in metrics.items():
        fit = getattr(m, "fit", None)
        if fit is not None:
            fits.append(f"{name} {float(fit):.1f}%")
        w = getattr(m, "white", getattr(m, "is_white", None))
        if w is None and getattr(m, "whiteness_pvalue", None) is not None:
            w = float(m.whiteness_pvalue) > 0.05
        if w is not None:
            white.append(f"{name} {'white' if w else 'coloured'}")
    return (", ".join(fits) or "—"), (", ".join(white) or "—")


def _condition(meta: Mapping[str, Any]) -> str:
    parts = []
    for key, unit in (("airspeed", "m/s"), ("dynamic_pressure", "Pa")):
        if key in meta:
            parts.append(f"{key.replace('_', ' ')} {float(meta[key]):.4g} {unit}")
    return ", ".join(parts) or str(meta.get("source", "—"))


def _campaign_brief(role: str, record: Any) -> Any:
    """What the campaign report uses of one flight's `role` input (see `Stage.brief`)."""
    if role == "data":
        return dict(getattr(record, "metadata", {}) or {})
    if role == "identification":
        return {
            "names": list(getattr(record, "parameter_names", ())),
            "parameters": dict(record.parameters),
            "stderr": dict(record.stderr),
            "success": bool(getattr(record, "success", True)),
        }
    if role == "validation":
        return _fit_whiteness(record)
    if role == "propagation":
        if getattr(record, "mean", None) is None:
            return "—"
        mean, std = float(np.ravel(record.mean)[0]), float(np.ravel(record.std)[0])
        return f"{mean:.4g} ± {std:.2g}"
    if role == "reports":
        return record.markdown
    return None  # the detailed figures' inputs: read whole, for the first flight only


# The campaign report is split into parts that run in parallel: parts 0 and 1 draw
# the cross-flight trend of the first and the second half of the parameters, part 2
# writes the tables and text (these three need every flight, so they run after the
# last one: as two figures the trend is drawn by two workers at once), and each
# further part draws one detailed figure of the first flight that was identified,
# as soon as that flight is done.
_DETAIL_FIGURES = (
    ("validation", "time histories"),
    ("identification", "fit residuals"),
    ("frequency", "bode"),
    ("inference", "posterior"),
    ("propagation", "propagation"),
    ("experiment", "design"),
    ("filtering", "filter states"),
)
_TRENDS, _TEXT, _FIRST_DETAIL = (0, 1), 2, 3


def _detail_roles(roles: Any) -> list[tuple[str, str]]:
    return [(role, label) for role, label in _DETAIL_FIGURES if role in roles]


def _campaign_parts(options: Any, roles: frozenset[str]) -> int:
    # 1 (not split) without figures
    if not options.figures or "identification" not in roles:
        return 1
    return _FIRST_DETAIL + len(_detail_roles(roles))


def _first_identified(ctx: StageContext) -> int | None:
    for i, r in enumerate(ctx.inputs.get("identification", ())):
        if r is not None:
            return i
    return None


def _campaign_part_flights(
    options: Any, roles: frozenset[str], index: int
) -> tuple[int, ...] | None:
    # the detailed figures read the first flight only; the trend and the text read all
    return None if index < _FIRST_DETAIL else (0,)


def _detail_figure(ctx: StageContext, index: int, flight: int) -> tuple[str, bytes] | None:
    from .._html import figure_png

    role, label = _detail_roles(ctx.inputs)[index - _FIRST_DETAIL]
    result = ctx.inputs[role][flight]
    if result is None or not hasattr(result, "plot"):
        return None
    return f"{ctx.flights[flight]}: {label}", figure_png(result.plot())


def _run_campaign_part(ctx: StageContext, index: int) -> Any:
    """Part `index` of the campaign report.

    The trend and the detailed figures return (title, PNG bytes) or None; the
    text part returns the `CampaignReport` without figures. A detailed figure
    part reads the first flight only; if that flight was not identified it
    returns its index, and `_combine_campaign` draws the figure for the first
    flight that was.
    """
    from .._html import figure_png
    from ..plotting import plot_campaign_trend

    if index == _TEXT:
        return _run_campaign_report(ctx)
    if index in _TRENDS:
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
        fig = plot_campaign_trend(records, parameters=names)
        return f"campaign: estimates across flights ({', '.join(names)})", figure_png(fig)
    if not ctx.flights:
        return None
    if ctx.inputs["identification"][0] is None:
        return index
    return _detail_figure(ctx, index, 0)


def _combine_campaign(ctx: StageContext, parts: list[Any]) -> CampaignReport:
    report = next((p for p in parts if isinstance(p, CampaignReport)), None)
    if report is None:
        report = _run_campaign_report(ctx)
    drawn = []
    for part in parts:
        if isinstance(part, CampaignReport):
            continue
        if isinstance(part, int):  # the first flight failed: draw for the first identified
            first = _first_identified(ctx)
            part = None if first is None else _detail_figure(ctx, part, first)
        if part is not None:
            drawn.append(part)
    return dataclasses.replace(
        report,
        figure_titles=tuple(t for t, _ in drawn),
        figures=tuple(png for _, png in drawn),
    )


def _run_campaign(ctx: StageContext) -> CampaignReport:
    # unsplit (a rerun, a pipeline run without Dask parts): the parts one after the
    # other, so the record is the one the parallel parts give
    n = _campaign_parts(ctx.options, frozenset(ctx.inputs))
    if n == 1:
        return _run_campaign_report(ctx)
    return _combine_campaign(ctx, [_run_campaign_part(ctx, i) for i in range(n)])


def _run_campaign_report(ctx: StageContext) -> CampaignReport:
    from .._records import markdown_table

    flights = ctx.flights
    ident = [ctx.brief("identification", i) for i in range(len(flights))]
    names: list[str] = []
    for r in ident:
        for n in r["names"] if r is not None else ():
            if n not in names:
                names.append(n)
    columns = ("flight", "condition", *names, "fit", "whiteness", "metric", "status")
    rows = []
    for i, f in enumerate(flights):
        r, v, meta = ident[i], ctx.brief("validation", i), ctx.brief("data", i)
        est = []
        for n in names:
            if r is not None and n in r["parameters"]:
                est.append(f"{r['parameters'][n]:.4g} ± {r['stderr'][n]:.2g}")
            else:
                est.append("—")
        fit, white = ("—", "—") if v is None else v
        metric = ctx.brief("propagation", i) or "—"
        status = ctx.failures.get(f, "ok")
        if status == "ok" and r is not None and not r["success"]:
            status = "not converged"
        rows.append(
            (f, "—" if meta is None else _condition(meta), *est, fit, white, metric, status)
        )
    title = ctx.options.title or "Campaign report"
    parts = [f"# {title}", "", f"{len(flights)} flights, {len(ctx.failures)} failed.", ""]
    parts.append(markdown_table(columns, rows))
    if ctx.failures:
        parts += ["", "## Failures", ""]
        parts += [f"- **{f}**: {err}" for f, err in ctx.failures.items()]
    if ctx.options.include_flight_reports:
        for i in range(len(flights)):
            text = ctx.brief("reports", i)
            if text is not None:
                # demote the per-flight headings under the campaign's
                text = "\n".join(
                    "#" + line if line.startswith("#") else line for line in text.splitlines()
                )
                parts += ["", text]
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
        # 5: the trend across flights as two figures, drawn in parallel
        "5",
        CampaignReportOptions,
        "CampaignReport",
        _run_campaign,
        uses_model=False,
        per_flight=False,
        parts=_campaign_parts,
        run_part=_run_campaign_part,
        combine=_combine_campaign,
        part_flights=_campaign_part_flights,
        preload=("aeroid.plotting", "aeroid._html"),
        brief=_campaign_brief,
    )
)


# -- the files a run writes ---------------------------------------------------------------

# the last line of every Markdown report a run writes: a file without it is not one of
# ours, and is never overwritten
_MD_MARKER = "<!-- written by aeroid: every run of the campaign rewrites this file -->"
_HTML_MARKER = "<!-- aeroid campaign report"


class ReportWriteError(AeroidError):
    """A campaign report could not be written (a full disk, a permission): names the path."""


def html_report_path(markdown_path: Path) -> Path:
    """Where the HTML twin of a campaign report lives."""
    return markdown_path.with_suffix(".html")


def _ours(path: Path, marker: str) -> bool:
    """`path` is absent, or a report an earlier run wrote (it holds `marker`)."""
    if not path.exists():
        return True
    try:
        return marker.encode() in path.read_bytes()
    except OSError:
        return False


def check_report_path(config: CampaignConfig, inputs: list[Path]) -> None:
    """Refuse, before anything runs, a report path that cannot or must not be written.

    `inputs`: the campaign's files (flight data, the config, the pipeline), which a
    report must never replace.
    """
    path = config.report_path
    where = f"{config.source}: report" if config.report else f"store {config.store}"
    if config.name is not None and ("/" in config.name or "\\" in config.name):
        raise ConfigError(
            f"{config.source}: name: {config.name!r} names the report file; "
            "no path separators in it"
        )
    if path.suffix.lower() in (".html", ".htm"):
        raise ConfigError(
            f"{where}: {path.name}: name the Markdown report (.md); its HTML twin is written "
            "beside it"
        )
    if path.is_dir():
        raise ConfigError(f"{where}: {path} is a folder; name a .md file")
    resolved = {p.resolve() for p in inputs}
    for target in (path, html_report_path(path)):
        if target.resolve() in resolved:
            raise ConfigError(f"{where}: {target} is an input of the campaign; name another file")
    html = html_report_path(path)
    # a Markdown report of an earlier version has no marker; its HTML twin has one
    md_ours = _ours(path, _MD_MARKER) or (html.is_file() and _ours(html, _HTML_MARKER))
    for target, ours in ((path, md_ours), (html, _ours(html, _HTML_MARKER))):
        if not ours:
            raise ConfigError(
                f"{where}: {target} exists and was not written by aeroid; "
                "move it away or name another report file"
            )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{where}: cannot make {path.parent} ({exc.strerror or exc})") from None
    if not os.access(path.parent, os.W_OK):
        raise ConfigError(f"{where}: {path.parent} is not writable")


def _write(path: Path, data: bytes) -> None:
    from .._html import _atomic_write

    try:
        _atomic_write(path, data)
    except OSError as exc:
        raise ReportWriteError(f"cannot write the report {path}: {exc.strerror or exc}") from None


def write_report(
    the_plan: Plan, store: ResultStore, statuses: dict[str, TaskStatus]
) -> tuple[Path | None, list[str], list[list[str]], str | None]:
    """Write the campaign report's Markdown and HTML files.

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
    path = the_plan.config.report_path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        marked = text.rstrip("\n") + "\n\n" + _MD_MARKER + "\n"
        if not path.is_file() or path.read_text(encoding="utf-8") != marked:
            _write(path, marked.encode("utf-8"))
        target = html_report_path(path)
        marker = f"{_HTML_MARKER} {task.key} -->"
        # rebuilt only when the campaign report's key changes (an unchanged rerun stays cheap)
        if not (
            target.is_file() and marker in target.read_text(encoding="utf-8", errors="replace")
        ):
            if status.figures is not None:
                figures = dict(status.figures)
            else:
                if record is None:
                    with contextlib.suppress(AeroidError):
                        record = store.load(task.key, task.stage)
                draw = getattr(record, "figure_bytes", None)
                figures = draw() if draw is not None else {}
            _write(target, html_report(text, figures, marker).encode("utf-8"))
    except ReportWriteError as exc:
        return None, columns, rows, str(exc)
    except OSError as exc:
        return None, columns, rows, f"cannot write the report {path}: {exc.strerror or exc}"
    return path, columns, rows, None


def html_report(text: str, figures: Mapping[str, bytes], marker: str) -> str:
    """The self-contained HTML campaign report: the Markdown plus the report's figures."""
    from .._html import markdown_to_html

    body = text.rstrip()
    if figures:
        body += "\n\n## Figures\n\n" + "\n\n".join(
            f"### {name}\n\n![{name}](fig{i})" for i, name in enumerate(figures)
        )
    images = {f"fig{i}": png for i, png in enumerate(figures.values())}
    return markdown_to_html(body, images).replace("<body>", "<body>\n" + marker, 1)
