"""The status of a flight in the campaign report: the flags every stage's records raise."""

from __future__ import annotations

from typing import Any

__all__ = ["LEGEND", "flight_status"]

LEGEND = (
    "Status: **ok** every check passed; **failed** a stage raised (see Failures); "
    "**not converged** the optimiser stopped short; **bound X** estimate X ended at a bound; "
    "**not identifiable** the data cannot separate some parameters; "
    "**coloured Y** residuals of output Y are not white; "
    "**posterior not converged** the MCMC chains are too short; "
    "**data F C** the data-quality check of channel C as read (or of several channels) "
    "raised F (see the flight's Data quality)."
)


def flight_status(failure: str | None, ident: Any, valid: Any, infer: Any, meta: Any = None) -> str:
    """The flags of one flight from the briefs of its records (see `LEGEND`), or "ok"."""
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
        if not ident.get("identifiable", True):
            flags.append("not identifiable")
    if valid is not None:
        flags += [f"coloured {n}" for n in valid[2]]
    if infer is not None and not infer["converged"]:
        flags.append("posterior not converged")
    return "; ".join(flags) or "ok"
