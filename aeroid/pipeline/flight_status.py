"""The status of a flight in the campaign report: the flags every stage's records raise."""

from __future__ import annotations

from typing import Any

__all__ = ["LEGEND", "POOR_FIT_R2", "flight_status", "severity"]

# an output whose model explains less than this share of its variance is a poor fit
POOR_FIT_R2 = 0.75
# an estimate whose standard error exceeds its magnitude is not determined by the data
_MAX_RELATIVE_ERROR = 1.0

LEGEND = (
    "Status, worst first: **failed** a stage raised (see Failures); "
    "**not converged** the optimiser stopped short; "
    "**not excited** no output's fitted response stands out of its residual noise "
    "(the record holds no manoeuvre: the estimates describe noise); "
    f"**poor fit Y** the model explains less than {POOR_FIT_R2:.0%} of output Y's "
    "variance (R² shown; of its simulation, or for a filter-error fit of the filter's "
    "one-step prediction); **not identifiable** the data cannot separate some parameters; "
    "**error > 100 %** estimates whose standard error exceeds their magnitude; "
    "**bound X** estimate X ended at a bound; "
    "**posterior not converged** the MCMC chains are too short; "
    "**data F C** the data-quality check of channel C as read (or of several channels) "
    "raised F (see the flight's Data quality); "
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
    "error >",
    "bound",
    "posterior",
    "data",
    "coloured",
)


def severity(status: str) -> tuple[int, int]:
    """Sort key of a status: its worst flag's rank, then fewer flags first."""
    if status == "ok":
        return (len(_RANK), 0)
    flags = status.split("; ")
    ranks = [next((k for k, w in enumerate(_RANK) if f.startswith(w)), len(_RANK)) for f in flags]
    return (min(ranks), -len(flags))


def flight_status(failure: str | None, ident: Any, valid: Any, infer: Any, meta: Any = None) -> str:
    """The flags of one flight from the briefs of its records (see `LEGEND`), worst
    first, or "ok"."""
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
        loose = [
            n
            for n, v in ident.get("parameters", {}).items()
            if abs(float(ident.get("stderr", {}).get(n, 0.0))) > _MAX_RELATIVE_ERROR * abs(float(v))
        ]
        if loose:
            flags.append("error > 100 % " + ", ".join(loose))
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
