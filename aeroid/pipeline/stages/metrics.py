"""The built-in metrics the ``propagate`` stage takes by name, and the resolver of a
config's metric (a built-in name or ``package.module:function``)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from ...errors import PipelineError
from . import resolve_callable

__all__ = ["METRICS", "damping_ratio", "metric", "natural_frequency", "static_margin"]


def natural_frequency(p: Mapping[str, float]) -> float:
    """Short-period undamped natural frequency sqrt(M_q Z_alpha - M_alpha), rad/s."""
    return math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"])


def damping_ratio(p: Mapping[str, float]) -> float:
    """Short-period damping ratio -(Z_alpha + M_q) / (2 omega_n)."""
    return -(p["Z_alpha"] + p["M_q"]) / (2.0 * natural_frequency(p))


def static_margin(p: Mapping[str, float]) -> float:
    """Static margin -Cm_alpha / CL_alpha, in mean aerodynamic chords (stick fixed: the
    neutral point's distance behind the centre of gravity)."""
    return -p["Cm_alpha"] / p["CL_alpha"]


METRICS: dict[str, Callable[[Mapping[str, float]], float]] = {
    "natural_frequency": natural_frequency,
    "damping_ratio": damping_ratio,
    "static_margin": static_margin,
}


def metric(name: str, base_dir: str | None = None) -> Callable[[Mapping[str, float]], float]:
    """The metric `name` names: a built-in one, else ``module:function`` imported from
    the config's folder `base_dir` where the module's file is there (as the config
    check finds it), else from the installed modules."""
    if name in METRICS:
        return METRICS[name]
    if ":" not in name:
        raise PipelineError(
            f"propagate metric {name!r}: expected one of {sorted(METRICS)} or 'package.module:function'"
        )
    fn = resolve_callable(name, what="propagate metric", base_dir=base_dir)
    if not callable(fn):
        raise PipelineError(f"propagate metric {name!r} is not callable")
    return fn
