"""The campaign report's tables: each flight's fit brief and the estimates side by side."""

from __future__ import annotations

import html
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...support import guessed_units, markdown_table
from .flight_status import POOR_FIT_R2

__all__ = [
    "campaign_units",
    "coloured_innovations",
    "estimate_tables",
    "fit_whiteness",
    "identification_brief",
    "name_the_metric",
    "residual_mean_squares",
    "what_was_flown",
    "with_warnings",
]


def fit_whiteness(
    validation: Any,
) -> tuple[str, str, tuple[str, ...], tuple[tuple[str, float], ...], dict[str, float]]:
    """(fits, whiteness, coloured outputs, (output, R²) of each output whose simulation
    fits poorly, each output's measured variance)."""
    metrics = getattr(validation, "metrics", None)
    if not isinstance(metrics, Mapping) or not metrics:
        return "—", "—", (), (), {}
    fits, white, coloured, poor = [], [], [], []
    for name, m in metrics.items():
        fit = getattr(m, "fit", None)
        if fit is not None:
            fits.append(f"{name} {float(fit):.1f} %")
            # fit = 100 (1 - |e|/|y - mean y|), so R² = 1 - (1 - fit/100)²
            r2 = 1.0 - (1.0 - float(fit) / 100.0) ** 2
            if r2 < POOR_FIT_R2:
                poor.append((str(name), r2))
        w = getattr(m, "white", getattr(m, "is_white", None))
        if w is None and getattr(m, "whiteness_pvalue", None) is not None:
            w = float(m.whiteness_pvalue) > 0.05
        if w is not None:
            white.append(f"{name} {'white' if w else 'coloured'}")
            if not w:
                coloured.append(str(name))
    measured = getattr(validation, "measured", None)
    names = tuple(getattr(validation, "output_names", ()) or ())
    spread: dict[str, float] = {}
    if measured is not None and len(names) == np.shape(measured)[-1]:
        var = np.var(np.asarray(measured, dtype=np.float64), axis=0)
        spread = {str(n): float(v) for n, v in zip(names, var, strict=True)}
    fits_text, white_text = (", ".join(fits) or "—"), (", ".join(white) or "—")
    return fits_text, white_text, tuple(coloured), tuple(poor), spread


def identification_brief(record: Any) -> dict[str, Any]:
    """What the campaign's tables and status flags read of one flight's fit."""
    names = list(getattr(record, "parameter_names", ()))
    declared = dict(getattr(record, "parameter_units", {}) or {})
    return {
        "names": names,
        "parameters": dict(record.parameters),
        "stderr": dict(record.stderr),
        "success": bool(getattr(record, "success", True)),
        "active_bounds": dict(getattr(record, "active_bounds", {}) or {}),
        "unidentifiable": [list(c) for c in getattr(record, "unidentifiable", ())],
        "identifiable": bool(getattr(record, "identifiable", True)),
        "units": declared,
        # from the names and the flight's channel units, where the model declares none
        "guessed_units": {
            n: u
            for n, u in guessed_units(names, getattr(record, "units", None)).items()
            if n not in declared
        },
        "response_to_noise": dict(getattr(record, "response_to_noise", {}) or {}),
        "method": str(getattr(record, "method", "")),
        "residual_ms": residual_mean_squares(record),
        **(
            {"coloured_innovations": coloured_innovations(record)}
            if getattr(record, "method", "") == "filter_error"
            else {}
        ),
    }


def coloured_innovations(record: Any, lags: int = 20) -> list[str]:
    """The outputs whose filter-error innovations fail the Ljung-Box test at 5 %: a
    filter that models the turbulence leaves white innovations where the model
    is right, so these point at what it gets wrong (an open-loop simulation of
    such a fit drifts on every output and would say nothing)."""
    from ...uncertainty.validation import ljung_box

    names = tuple(getattr(record, "output_names", ()) or ())
    out = []
    for j, name in enumerate(names):
        parts = [np.asarray(r, dtype=np.float64)[:, j] for r in getattr(record, "residuals", ())]
        parts = [v - v.mean() for v in parts if v.size > lags + 2]
        if parts and min(ljung_box(v, lags)[1] for v in parts) < 0.05:
            out.append(str(name))
    return out


def residual_mean_squares(identification: Any) -> dict[str, float]:
    """Each output's mean square residual over a fit's records: for a filter-error fit,
    of its innovations (the one-step predictions), which judge such a fit."""
    names = tuple(getattr(identification, "output_names", ()) or ())
    parts = [np.asarray(r, dtype=np.float64) for r in getattr(identification, "residuals", ())]
    parts = [r for r in parts if r.ndim == 2 and r.shape[1] == len(names) and r.shape[0]]
    if not parts:
        return {}
    stacked = np.concatenate(parts)
    return {str(n): float(v) for n, v in zip(names, np.mean(stacked**2, axis=0), strict=True)}


# flights side by side in one estimates table: more are split into further tables, so
# that each fits a printed page
_FLIGHTS_PER_TABLE = 6


def campaign_units(
    briefs: Sequence[Mapping[str, Any] | None],
) -> tuple[dict[str, str], set[str]]:
    """The parameters' units over the flights' identification briefs: those declared,
    else a guess every flight that guesses it agrees on; and the names guessed."""
    units: dict[str, str] = {}
    for b in briefs:
        units.update((b or {}).get("units", {}))
    votes: dict[str, set[str]] = {}
    for b in briefs:
        for n, u in (b or {}).get("guessed_units", {}).items():
            votes.setdefault(n, set()).add(u)
    guessed = {n: v.pop() for n, v in votes.items() if len(v) == 1 and n not in units}
    return {**units, **guessed}, set(guessed)


def estimate_tables(
    names: list[str], punits: Mapping[str, str], flights: Any, cells: list[Any]
) -> list[str]:
    """The estimates transposed (a parameter a row, a flight a column), split by flights."""
    out = [
        "### Estimates",
        "",
        "Each estimate ± 1 standard error (1σ; the plots' bars are 95 %, ±1.96σ).",
        "",
    ]
    for start in range(0, len(flights), _FLIGHTS_PER_TABLE):
        cols = list(range(start, min(start + _FLIGHTS_PER_TABLE, len(flights))))
        header = ["parameter", "unit", *(flights[i] for i in cols)]
        body = [[n, punits.get(n, "—"), *(cells[i][k] for i in cols)] for k, n in enumerate(names)]
        out += [markdown_table(header, body), ""]
    return out


def with_warnings(text: str, the_plan: Any, statuses: Mapping[str, Any]) -> str:
    """The report with each flight's warnings (stored with its results, so a cached
    rerun shows them too) at the top of that flight's section."""
    by_flight: dict[str, list[str]] = {}
    for t in the_plan.tasks:
        for w in statuses[t.key].warnings if t.key in statuses else ():
            by_flight.setdefault(t.flight or "", []).append(f"- **{t.step}**: {w}")
    if not by_flight:
        return text
    out = []
    for line in text.splitlines():
        out.append(line)
        m = _SUMMARY.match(line)
        if m and html.unescape(m.group(1)) in by_flight:
            out += ["", "**Warnings**", "", *by_flight[html.unescape(m.group(1))]]
    campaign = by_flight.get("", [])
    if campaign:
        out += ["", "## Campaign warnings", "", *campaign]
    return "\n".join(out) + "\n"


_SUMMARY = re.compile(r"^<summary>(.*?): .*</summary>$")


def what_was_flown(text: str, source: Any) -> str:
    """The report with a "What was flown" section before its flights: the campaign's
    config as run (aircraft and model equations, each flight's trim and condition,
    every stage's settings, the filter's noise levels among them)."""
    from pathlib import Path

    try:
        config = Path(source).read_text(encoding="utf-8")
    except (OSError, TypeError, ValueError):
        return text
    section = [
        "## What was flown",
        "",
        f"The campaign's config, `{Path(source).name}`, as run: the aircraft and its "
        "model equations (`model:`), each flight's file, condition and trim "
        "(`flights:`) and the settings of every step (`stages:`; the filter's process "
        "and measurement noise among them).",
        "",
        "```yaml",
        *config.replace("```", "` ` `").splitlines(),
        "```",
        "",
    ]
    marker = "## Flights, worst first"
    if marker not in text:
        return text.rstrip("\n") + "\n\n" + "\n".join(section)
    head, tail = text.split(marker, 1)
    return head + "\n".join(section) + "\n" + marker + tail


def name_the_metric(text: str, column: str, heading: str) -> str:
    """The report with the propagated metric named, with its unit, in the campaign
    table's column (`column` -> `heading`) and in each flight's propagation section."""
    name = heading.split(" (mean ± ")[0]
    text = text.replace(column, heading)
    section = re.compile(r"(?m)^(#+ Uncertainty propagation)$")
    return section.sub(lambda m: f"{m.group(1)}: {name}", text)


def metric_heading(stages: Mapping[str, Any], units: Mapping[str, str]) -> str | None:
    """The propagated metric's column heading, by its name and unit (the config names it)."""
    metric = (stages.get("propagate") or {}).get("metric", "natural_frequency")
    if not isinstance(metric, str) or "propagate" not in stages:
        return None
    unit = units.get(metric)
    return f"{metric}{f' [{unit}]' if unit else ''} (mean ± 1σ)"


def html_report(text: str, figures: Mapping[str, bytes], marker: str) -> str:
    """The self-contained HTML campaign report: the Markdown with its figures embedded
    where it links them (any figure it does not link is appended under "Figures")."""
    from ...support import markdown_to_html

    body = text.rstrip()
    unlinked = [name for name in figures if f"]({name})" not in body]
    if unlinked:
        body += "\n\n## Figures\n\n" + "\n\n".join(
            f"### {name}\n\n![{name}]({name})" for name in unlinked
        )
    return markdown_to_html(body, figures).replace("<body>", "<body>\n" + marker, 1)


def condition_text(meta: Mapping[str, Any]) -> str:
    """A flight's condition as its row shows it: every condition key it gives, with units."""
    from ...support import CONDITION_KEYS

    parts = []
    for c in CONDITION_KEYS:
        value = meta.get(c.name)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            text = f"{c.name.replace('_', ' ')} {float(value) * c.scale:.4g}"
            parts.append(f"{text} {c.shown}".rstrip())
    # (no condition given: the flight's file is in the run's record of what was flown)
    return ", ".join(parts) or "—"
