"""The settings of experiment design's optimiser (scipy's differential evolution):
defaults and checks, apart from the design so a campaign checks them at planning
without importing the solver."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .._value_checks import check_flag
from ..errors import IdentificationError

__all__ = ["OPTIMIZER_DEFAULTS", "optimizer_settings"]

OPTIMIZER_DEFAULTS: dict[str, Any] = {
    "maxiter": 30,
    "popsize": 10,
    "tol": 1e-6,
    "atol": 0.0,
    "mutation": (0.5, 1.0),
    "recombination": 0.7,
    "strategy": "best1bin",
    "init": "latinhypercube",
    "polish": True,
}


def optimizer_settings(options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The optimiser settings `design_experiment` uses: its defaults updated by
    `options`, each key and value checked (the campaign checks them at planning)."""
    merged = dict(OPTIMIZER_DEFAULTS)
    if options is None:
        return merged
    if not isinstance(options, Mapping):
        raise IdentificationError(
            f"optimizer_options: expected a dict, got {type(options).__name__}"
        )
    unknown = sorted(set(options) - set(OPTIMIZER_DEFAULTS))
    if unknown:
        raise IdentificationError(
            f"optimizer_options: unknown keys {unknown}; valid keys are "
            f"{sorted(OPTIMIZER_DEFAULTS)}"
        )
    merged.update(options)
    check_flag(merged["polish"], "optimizer_options['polish']", IdentificationError)
    for key in ("tol", "atol", "recombination"):
        v = merged[key]
        if isinstance(v, (bool, np.bool_, str, bytes)):  # float() would read "0.01" as 0.01
            raise IdentificationError(f"optimizer_options[{key!r}]: expected a number, got {v!r}")
    for key in ("maxiter", "popsize"):
        v = merged[key]
        if (
            isinstance(v, bool)
            or not isinstance(v, (int, np.integer))
            or v < (0 if key == "maxiter" else 1)
        ):
            raise IdentificationError(
                f"optimizer_options[{key!r}]: expected a {'non-negative' if key == 'maxiter' else 'positive'} "
                f"integer, got {v!r}"
            )
    return merged
