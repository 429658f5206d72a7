"""The status of a flight in the campaign report: the flags every stage's records raise."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "LEGEND",
    "POOR_FIT_R2",
    "T_SIGNIFICANT",
    "determined_shares",
    "flight_status",
    "legend",
    "one_step_fits",
    "severity",
    "structure_note",
]

# an output whose model explains less than this share of its variance is a poor fit
POOR_FIT_R2 = 0.75
# |estimate| / standard error below this: the data cannot tell the term from zero (the
# two-sided t-test at about 5 %, Klein & Morelli's test of a model term, ch. 5)
T_SIGNIFICANT = 2.0
# a term is one the campaign determines where at least this share of its other fitted
# flights tells it from zero: a flight that does not is then short of excitation; a
# term most flights cannot tell from zero is the model's structure, not a flight's fault
_DETERMINED_SHARE = 0.5

LEGEND = (
    "Status, worst first: **failed** a stage raised (see Failures); "
    "**not converged** the optimiser stopped short; "
    "**not excited** no output's fitted response stands out of its residual noise "
    "(the record holds no manoeuvre: the estimates describe noise); "
    f"**poor fit Y** the model explains less than {POOR_FIT_R2:.0%} of output Y's "
    "variance (R² shown; of its simulation, or for a filter-error fit of the filter's "
    "one-step prediction); **not identifiable** the data cannot separate some parameters; "
    "**not determined X** this flight cannot tell X from zero (|X| < 2 standard "
    "errors) where most of the campaign's other flights can: its manoeuvres did not "
    "excite a term the model needs; "
    "**bound X** estimate X ended at a bound; "
    "**posterior not converged** the MCMC chains are too short; "
    "**data F C** the data-quality check of channel C as read (or of several channels) "
    "raised F (see the flight's Data quality); "
    "**≈ 0 X** (a campaign of one flight) the data cannot tell X from zero: a term to "
    "drop, or one the manoeuvre did not excite (terms that most flights of a campaign "
    "cannot tell from zero flag no flight: they are listed under Model structure); "
    "**coloured k/n** the residuals of k of the n outputs are not white (for a "
    "filter-error fit its innovations; the standard errors are then corrected for "
    "it); **ok** every check passed."
)

# flag word -> rank (lower is worse): the campaign lists its flights worst first
_RANK = (
    "failed",
    "not converged",
    "not excited",
    "poor fit",
    "not identifiable",
    "not determined",
    "bound",
    "posterior",
    "data",
    "≈ 0",
    "coloured",
)


def one_step_fits(ident: Any, valid: Any) -> str | None:
    """A filter-error fit's normalised fit per output, of its one-step prediction
    (100 (1 - rms innovation / std of the measured output), so that R² = 1 - ms / var
    is the poor-fit flag's), as the validation brief writes fits; None for any other."""
    spread = valid[4] if valid is not None and len(valid) > 4 else {}
    innovations = (ident or {}).get("residual_ms") or {}
    if (ident or {}).get("method") != "filter_error" or not spread or not innovations:
        return None
    fits = [
        f"{n} {100.0 * (1.0 - math.sqrt(innovations[n] / v)):.1f} %"
        for n, v in spread.items()
        if n in innovations and v > 0
    ]
    return ", ".join(fits) or None


def severity(status: str) -> tuple[int, int]:
    """Sort key of a status: its worst flag's rank, then fewer flags first."""
    if status == "ok":
        return (len(_RANK), 0)
    flags = status.split("; ")
    ranks = [next((k for k, w in enumerate(_RANK) if f.startswith(w)), len(_RANK)) for f in flags]
    return (min(ranks), -len(flags))


def _weak_terms(ident: Any) -> list[str]:
    """The estimates of a fit brief within `T_SIGNIFICANT` standard errors of zero."""
    stderr = (ident or {}).get("stderr", {})
    weak = []
    for name, value in (ident or {}).get("parameters", {}).items():
        se = abs(float(stderr.get(name, 0.0)))
        if math.isfinite(se) and abs(float(value)) < T_SIGNIFICANT * se:
            weak.append(str(name))
    return weak


def determined_shares(idents: Sequence[Any]) -> list[dict[str, float] | None]:
    """Per flight (None where it has no fit, or no other flight has one), for each of
    its parameters the share of the campaign's other fitted flights that tell the
    parameter from zero."""
    weak = {j: set(_weak_terms(r)) for j, r in enumerate(idents) if r is not None}
    shares: list[dict[str, float] | None] = []
    for i, r in enumerate(idents):
        others = [(idents[j], w) for j, w in weak.items() if j != i]
        if r is None or not others:
            shares.append(None)
            continue
        shares.append(
            {
                n: sum(n in o.get("parameters", {}) and n not in w for o, w in others)
                / sum(n in o.get("parameters", {}) for o, _ in others)
                for n in r.get("parameters", {})
                if any(n in o.get("parameters", {}) for o, _ in others)
            }
        )
    return shares


def legend(idents: Sequence[Any]) -> list[str]:
    """The campaign report's lines under its status column: `LEGEND`, then the model
    structure note of these fits (see `structure_note`)."""
    return [LEGEND, "", *structure_note(idents)]


def structure_note(idents: Sequence[Any]) -> list[str]:
    """The campaign report's Model structure lines: the terms that most fitted flights
    cannot tell from zero (Markdown; empty when there are none or one flight)."""
    fitted = [r for r in idents if r is not None]
    if len(fitted) < 2:
        return []
    counts: dict[str, list[int]] = {}
    for r in fitted:
        weak = set(_weak_terms(r))
        for n in r.get("parameters", {}):
            c = counts.setdefault(str(n), [0, 0])
            c[0] += n in weak
            c[1] += 1
    zero = [f"{n} ({k} of {m})" for n, (k, m) in counts.items() if k > m * (1 - _DETERMINED_SHARE)]
    if not zero:
        return []
    return [
        "### Model structure",
        "",
        "Terms that most flights cannot tell from zero (|estimate| < 2 standard errors "
        "on k of n flights): " + ", ".join(zero) + ". These manoeuvres do not show them: "
        "drop them from the model or hold them at a priori values (Klein & Morelli, "
        "ch. 5); they flag no flight.",
        "",
    ]


def flight_status(
    failure: str | None,
    ident: Any,
    valid: Any,
    infer: Any,
    meta: Any = None,
    *,
    determined: Mapping[str, float] | None = None,
) -> str:
    """The flags of one flight from the briefs of its records (see `LEGEND`), worst
    first, or "ok". ``determined`` (from `determined_shares`) tells a term this flight
    failed to determine from one that no flight determines; without it (a flight on
    its own) a term within two standard errors of zero is flagged "≈ 0"."""
    if failure is not None:
        return "failed"
    flags = []
    by_flag: dict[str, list[str]] = {}
    for channel, raised in ((meta or {}).get("quality_flags") or {}).items():
        for f in raised:
            by_flag.setdefault(f.replace("_", " "), []).append(channel)
    for f, chans in by_flag.items():
        flags.append(f"data {f} " + (chans[0] if len(chans) == 1 else f"({len(chans)} channels)"))
    if ident is not None:
        if not ident["success"]:
            flags.append("not converged")
        flags += [f"bound {n}" for n in ident.get("active_bounds", {})]
        ratios = ident.get("response_to_noise") or {}
        if ratios and all(float(v) < 1.0 for v in ratios.values()):
            flags.append("not excited")
        if not ident.get("identifiable", True):
            flags.append("not identifiable")
        weak = _weak_terms(ident)
        if determined is None and weak:
            flags.append("≈ 0 " + ", ".join(weak))
        missed = [n for n in weak if (determined or {}).get(n, 0.0) >= _DETERMINED_SHARE]
        if determined is not None and missed:
            flags.append("not determined " + ", ".join(missed))
    if valid is not None:
        poor = valid[3] if len(valid) > 3 else ()
        spread = valid[4] if len(valid) > 4 else {}
        innovations = (ident or {}).get("residual_ms") or {}
        if (ident or {}).get("method") == "filter_error" and spread and innovations:
            # a filter-error fit models the turbulence as process noise: what it
            # claims is its one-step prediction, not an open-loop simulation, which
            # drifts with every gust it cannot know
            poor = tuple(
                (n, 1.0 - innovations[n] / v)
                for n, v in spread.items()
                if n in innovations and v > 0 and 1.0 - innovations[n] / v < POOR_FIT_R2
            )
        flags += [f"poor fit {n} (R² {r2:.2f})" for n, r2 in poor]
        coloured = valid[2]
        n_out = max(len(valid[0].split(", ")), len(coloured))
        if (ident or {}).get("method") == "filter_error" and "coloured_innovations" in ident:
            coloured = ident["coloured_innovations"]  # the filter's innovations, as above
            n_out = max(len(ident.get("residual_ms") or {}), len(coloured))
        if coloured:
            flags.append(f"coloured {len(coloured)}/{n_out}")
    if infer is not None and not infer["converged"]:
        flags.append("posterior not converged")
    flags.sort(key=severity)
    return "; ".join(flags) or "ok"
