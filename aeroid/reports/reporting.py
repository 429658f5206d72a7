"""The Markdown engineering report that ties a chain of results together."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

from ..errors import AeroidError, OutputError

__all__ = ["report", "report_figures", "report_sections"]


def _identification_notes(result: Any, guessed: set[str]) -> list[str]:
    notes = []
    if not getattr(result, "success", True):
        notes.append("The fit did not converge; treat the estimates as provisional.")
    if not getattr(result, "identifiable", True):
        notes.append("Some parameter combinations are not identifiable from this manoeuvre.")
    if getattr(result, "error_bars", "") == "colored":
        notes.append(
            "Residuals are coloured, so the standard errors are corrected for their "
            "autocorrelation (the classical bounds would be too small)."
        )
    corr = getattr(result, "correlation", None)
    names = list(getattr(result, "parameter_names", ()))
    if corr is not None and len(names) > 1:
        worst = max(
            (
                (abs(float(corr[i][j])), names[i], names[j])
                for i in range(len(names))
                for j in range(i)
                if math.isfinite(float(corr[i][j]))  # unknown where not identifiable
            ),
            default=None,
        )
        if worst and worst[0] > 0.9:
            notes.append(
                f"{worst[1]} and {worst[2]} are strongly correlated (|r| = {worst[0]:.2f})."
            )
    if guessed & set(names):
        notes.append(_GUESSED_NOTE)
    return notes


def _validation_notes(validation: Any) -> list[str]:
    notes = []
    for name, m in validation.metrics.items():
        fit = f"{m.fit:.1f} %" if math.isfinite(m.fit) else "undefined (the output is constant)"
        line = f"{name}: fit {fit}"
        if not m.white:
            line += "; residuals are not white (unmodelled dynamics or coloured noise)"
        if m.input_correlated:
            line += "; residuals correlate with the input (model structure may be incomplete)"
        lo, hi = m.bias_ci
        if lo > 0 or hi < 0:
            line += "; significant bias"
        notes.append(line + ".")
    return notes


# the full correlation matrix up to this many parameters; above, the strongest pairs
_FULL_MATRIX = 10
_STRONGEST = 10


def _correlation_table(result: Any) -> str:
    """The parameter correlation matrix (lower triangle), or its strongest pairs."""
    import numpy as np

    from .._records import markdown_table

    corr = getattr(result, "correlation", None)
    names = list(getattr(result, "parameter_names", ()))
    if corr is None or len(names) < 2:
        return ""
    c = np.asarray(corr, dtype=float)

    def cell(v: float) -> str:  # unknown where the data cannot separate the parameter
        return f"{v:+.2f}" if np.isfinite(v) else "—"

    if len(names) <= _FULL_MATRIX:
        rows = [
            [n, *(cell(c[i, j]) if j <= i else "" for j in range(len(names)))]
            for i, n in enumerate(names)
        ]
        return "Parameter correlation matrix:\n\n" + markdown_table(["", *names], rows)
    pairs = sorted(
        ((abs(c[i, j]), names[i], names[j], c[i, j]) for i in range(len(names)) for j in range(i)),
        key=lambda p: -p[0] if np.isfinite(p[0]) else 0.0,
    )[:_STRONGEST]
    rows = [[a, b, cell(r)] for _, a, b, r in pairs]
    return (
        f"Parameter correlations, the {len(rows)} strongest of {len(names)} parameters:\n\n"
        + markdown_table(["parameter", "parameter", "correlation"], rows)
    )


def _autocorrelation_table(validation: Any) -> str:
    """Each output's residual autocorrelation at a few lags against the 95 % band of
    white noise, ±1.96/sqrt(N)."""
    import numpy as np

    from .._records import markdown_table

    res = getattr(validation, "residuals", None)
    names = list(getattr(validation, "output_names", ()))
    if res is None or not names:
        return ""
    e = np.asarray(res, dtype=float)
    if e.ndim != 2 or e.shape[0] < 4:
        return ""
    n = e.shape[0]
    max_lag = int(min(getattr(validation, "whiteness_lags", 20) or 20, n - 1))
    shown = [k for k in (1, 2, 5, 10, 20) if k <= max_lag]
    band = 1.96 / np.sqrt(n)
    from .plotting import residual_autocorrelation

    acf = residual_autocorrelation(e, max_lag)
    rows = []
    for j, name in enumerate(names):
        r = [float(v) for v in acf[1:, j]]
        outside = sum(abs(v) > band for v in r)
        rows.append([name, *(f"{r[k - 1]:+.2f}" for k in shown), f"{outside} of {max_lag}"])
    header = ["output", *(f"r({k})" for k in shown), f"lags outside ±{band:.3f}"]
    return (
        "Residual autocorrelation at lags of k samples, against the 95 % band of white "
        f"noise (±1.96/√N = ±{band:.3f}, N = {n}):\n\n" + markdown_table(header, rows)
    )


# a table whose header holds one of these gets a unit column after its first
_VALUED = ("estimate", "RMSE", "innovation", "max std")


def _with_units(body: str, units: dict[str, str]) -> str:
    """Each table of estimates, residual statistics or innovations with a unit column:
    the unit of the parameter or output its row names ("—" where none is known)."""
    if not units:
        return body
    out: list[str] = []
    header = False
    for line in body.split("\n"):
        cells = line.split("|")
        if not line.startswith("|") or len(cells) < 3:
            header = False
            out.append(line)
            continue
        first = cells[1].strip()
        if not header and any(v in line for v in _VALUED) and "unit" not in line:
            header = True
            cells.insert(2, " unit ")
        elif header and set(first) <= set("-: ") and first:
            cells.insert(2, "-" * 6)
        elif header:
            cells.insert(2, f" {units.get(first, '—')} ")
        out.append("|".join(cells))
    return "\n".join(out)


def _report_units(*results: Any) -> tuple[dict[str, str], set[str]]:
    """Units of the channels and parameters the results know of, and the parameters
    whose unit is guessed (from the name and the channels' units: none declared)."""
    from .._units import guessed_units

    units: dict[str, str] = {}
    for r in results:
        units.update({k: v for k, v in (getattr(r, "units", None) or {}).items() if v})
    channels = dict(units)
    # a unit one result declares (the fit's) holds for the others (an inference's)
    declared: dict[str, str] = {}
    names: list[str] = []
    for r in results:
        own = list(getattr(r, "parameter_names", ()) or ())
        names += [n for n in own if n not in names]
        stated = getattr(r, "parameter_units", None) or {}
        declared.update({n: u for n, u in stated.items() if n in own})
    guesses = {n: u for n, u in guessed_units(names, channels).items() if n not in declared}
    units.update({**guesses, **declared})
    return units, set(guesses)


def _squared(unit: str) -> str:
    return f"{unit}²" if unit.isalpha() else f"({unit})²"


def _nuisance_units(result: Any, units: dict[str, str]) -> dict[str, str]:
    """Units of a fit's estimated biases and noise levels (its summary's second table),
    from the units of the channels they belong to."""
    out: dict[str, str] = {}
    for name in getattr(result, "extra_stderr", None) or {}:
        kind, _, channel = name.partition(".")
        state = channel.removeprefix("state.")
        unit = units.get(state)
        if not unit or unit == "-":
            continue
        if kind.startswith("bias[") and state == channel:
            out[name] = unit
        elif kind.startswith("bias["):  # a constant added to the state's derivative
            out[name] = f"{unit}²" if unit.endswith("/s") else f"{unit}/s"
        elif kind == "process_noise":
            out[name] = f"{_squared(unit)}/s"
        elif kind == "measurement_noise":
            out[name] = _squared(unit)
    return out


_GUESSED = " (guessed)"
_GUESSED_NOTE = (
    "A unit marked (guessed) is read from the parameter's name (M_alpha: the q equation's "
    "derivative in alpha) and the record's channel units; the model declares none."
)


def _without_heading(body: str) -> str:
    # a summary that opens with its own heading would repeat the section's heading
    lines = body.lstrip("\n").split("\n")
    if lines and lines[0].startswith("#"):
        return "\n".join(lines[1:]).lstrip("\n")
    return body


# What each slot reads of its result beyond summary(): a result in the wrong slot (an
# identification passed first, where the validation goes) is named, not an AttributeError.
_SLOT_ATTRIBUTES: dict[str, tuple[str, ...]] = {
    "identification": ("parameters", "stderr"),
    "validation": ("metrics",),
    "filtering": ("log_likelihood",),
    "sensitivity": ("fisher_information",),
    "frequency": ("channels",),
    "inference": ("samples", "r_hat"),
    "propagation": ("n_samples", "n_failed"),  # one metric or several (components)
    "experiment": ("recommendation",),
}


def report_sections(
    validation: Any = None,
    identification: Any = None,
    propagation: Any = None,
    *,
    experiment: Any = None,
    inference: Any = None,
    frequency: Any = None,
    filtering: Any = None,
    sensitivity: Any = None,
) -> list[tuple[str, str]]:
    """The report as a list of (heading, Markdown body) sections, in report order."""
    sections: list[tuple[str, str]] = []
    given = {
        "identification": identification,
        "validation": validation,
        "filtering": filtering,
        "sensitivity": sensitivity,
        "frequency": frequency,
        "inference": inference,
        "propagation": propagation,
        "experiment": experiment,
    }
    for slot, result in given.items():  # before any slot's notes read its attributes
        if result is None:
            continue
        if not callable(getattr(result, "summary", None)):
            raise AeroidError(
                f"report: the {slot} argument is not a result (it has no summary()): "
                f"{type(result).__name__}"
            )
        missing = [a for a in _SLOT_ATTRIBUTES[slot] if not hasattr(result, a)]
        if missing:
            raise AeroidError(
                f"report: the {slot} argument ({type(result).__name__}) has no "
                f"{missing[0]!r}: not a {slot} result (report takes validation, "
                "identification and propagation by position, the others by keyword)"
            )
    units, guessed = _report_units(validation, identification, filtering, sensitivity, inference)
    units.update({n: units[n] + _GUESSED for n in guessed})
    units.update(_nuisance_units(identification, units))

    def add(heading: str, result: Any, notes: list[str] | None = None, extra: str = "") -> None:
        if result is None:
            return
        body = _with_units(_without_heading(result.summary()), units)
        if notes:
            body += "\n\n" + "\n".join(f"- {n}" for n in notes)
        if extra:
            body += "\n\n" + extra
        sections.append((heading, body))

    add(
        "Identification",
        identification,
        _identification_notes(identification, guessed) if identification else None,
        _correlation_table(identification) if identification else "",
    )
    add(
        "Validation",
        validation,
        _validation_notes(validation) if validation else None,
        _autocorrelation_table(validation) if validation else "",
    )
    add("State estimation", filtering)
    add("Sensitivities", sensitivity)
    add("Frequency response", frequency)
    add("Bayesian inference", inference)
    add("Uncertainty propagation", propagation)
    add("Experiment design", experiment)
    return sections


def report_figures(
    validation: Any = None,
    identification: Any = None,
    propagation: Any = None,
    *,
    experiment: Any = None,
    inference: Any = None,
    frequency: Any = None,
    filtering: Any = None,
    sensitivity: Any = None,
) -> dict[str, Any]:
    """Figures of the given results, keyed by a file-name-safe label."""
    figs: dict[str, Any] = {}
    named = {
        "time_histories": validation,
        "identification": identification,
        "bode": frequency,
        "filter_states": filtering,
        "sensitivities": sensitivity,
        "posterior": inference,
        "propagation": propagation,
        "design": experiment,
    }
    for label, result in named.items():
        if result is not None and hasattr(result, "plot"):
            figs[label] = result.plot()
    if validation is not None and getattr(validation, "residuals", None) is not None:
        from .plotting import plot_residual_autocorrelation

        figs["residual_autocorrelation"] = plot_residual_autocorrelation(validation)
        held = getattr(validation, "prediction", None)
        if held is not None:
            figs["prediction"] = held.plot()
    if inference is not None and hasattr(inference, "plot_traces"):
        figs["posterior_traces"] = inference.plot_traces()
    return figs


def report(
    validation: Any = None,
    identification: Any = None,
    propagation: Any = None,
    *,
    experiment: Any = None,
    inference: Any = None,
    frequency: Any = None,
    filtering: Any = None,
    sensitivity: Any = None,
    title: str = "AeroID engineering report",
    path: str | os.PathLike[str] | None = None,
    date: str | None = None,
    figures: bool = True,
) -> str:
    """Render the Markdown engineering report.

    Parameters
    ----------
    validation, identification, propagation : results, optional
    experiment, inference, frequency, filtering, sensitivity : results, optional
        Each result given becomes a section built from its ``summary()``, with
        short interpretation notes where they apply.
    title : str
    path : path-like, optional
        Also write the report there (atomically: a temporary file renamed into
        place). With `figures`, every result's plot is written as a PNG into
        ``<stem>_figures/`` beside it, and a self-contained HTML twin
        (``<stem>.html``, images embedded) is written too.
    date : str, optional
        A date line; none by default, so identical inputs give identical bytes.
    figures : bool
        Write figures and the HTML version when `path` is given.

    Returns
    -------
    str
        The Markdown text.
    """
    if path is not None and not isinstance(path, (str, os.PathLike)):
        raise OutputError(f"report: path must be a file path, got {type(path).__name__}")
    sections = report_sections(
        validation,
        identification,
        propagation,
        experiment=experiment,
        inference=inference,
        frequency=frequency,
        filtering=filtering,
        sensitivity=sensitivity,
    )
    lines = [f"# {title}", ""]
    if date is not None:
        lines += [f"Date: {date}", ""]
    if not sections:
        lines += ["No results were given.", ""]
    for heading, body in sections:
        lines += [f"## {heading}", "", body.rstrip(), ""]
    text = "\n".join(lines)
    if path is not None and figures:
        from .html import write_report_bundle

        figs = report_figures(
            validation,
            identification,
            propagation,
            experiment=experiment,
            inference=inference,
            frequency=frequency,
            filtering=filtering,
            sensitivity=sensitivity,
        )
        md_path, _ = write_report_bundle(text, figs, path)
        return md_path.read_text(encoding="utf-8")
    if path is not None:
        from .html import _atomic_write

        _atomic_write(Path(path), text.encode("utf-8"))
    return text
