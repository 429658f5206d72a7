"""What a config names, resolved and checked before planning: the vehicle model
(built-in, ``module:attribute`` or an aircraft mapping), code imports the config
asks for, per-flight models, and steps run on chosen flights."""

from __future__ import annotations

import difflib
import re
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

from ...errors import ConfigError
from .. import _code
from ..definition import Pipeline
from ..keys import canonical_json
from ..stages import STAGES
from ..vehicle import BUILTIN_MODELS, resolve_model
from ._flights import _flight_model
from .checks import check_campaign
from .config import CampaignConfig, FileFlights

__all__ = ["BUILTIN_MODELS", "resolve_model"]

# -- models -----------------------------------------------------------------------------

# "flights[3]" in a check's message: the flight's index in the list checked
_FLIGHT_INDEX = re.compile(r"flights\[(\d+)\]")


_IMPORTS_REFUSED = (
    "runs Python code from {what}: allow it with `allow_imports: true` in the config "
    "or `--allow-imports` on the command line"
)


def _check_model_import(config: CampaignConfig, allowed: bool) -> None:
    """Refuse a ``module:attribute`` model unless allowed: it imports and runs code."""
    if not allowed and isinstance(config.model, str) and ":" in config.model:
        module = config.model.partition(":")[0]
        where = _code.module_file(module, config.base_dir) or f"the installed module {module!r}"
        raise ConfigError(
            f"{config.source}: model: {config.model!r} " + _IMPORTS_REFUSED.format(what=where)
        )


def _check_imports(config: CampaignConfig, options: Mapping[str, Any], allowed: bool) -> None:
    """Refuse the ``module:attribute`` names of stage options (metrics) unless allowed:
    each imports and runs code the config names."""
    if allowed:
        return
    for step, opts in options.items():
        for name in getattr(type(opts), "code_fields", ()):
            value = getattr(opts, name, None)
            if isinstance(value, str) and ":" in value:
                what = f"the module {value.partition(':')[0]!r}"
                raise ConfigError(
                    f"{config.source}: stages.{step}.{name}: {value!r} "
                    + _IMPORTS_REFUSED.format(what=what)
                )


def _warn_old_names(config: CampaignConfig, steps: list[Any]) -> None:
    for step in steps:
        renamed = getattr(STAGES[step.stage_name].options, "renamed", {})
        for old in set(config.stages.get(step.name) or {}) & set(renamed):
            warnings.warn(
                f"{config.source}: stages.{step.name}.{old} is the old name of "
                f"{renamed[old]} (the library's keyword); write {renamed[old]}",
                FutureWarning,
                stacklevel=3,
            )


def _check_flight_models(
    config: CampaignConfig, model: Any, pipeline: Pipeline, allowed: bool
) -> None:
    """The pre-flight checks, once per distinct model: each flight against its own.

    Every group's faults are reported together, each under the flight's own index in
    the config (a group's checks see only its flights, numbered from zero).
    """
    groups: dict[str, tuple[dict[str, Any] | None, list[Any], list[int]]] = {}
    for i, item in enumerate(config.flights):
        spec = item if isinstance(item, FileFlights) else None
        own = None if spec is None else _flight_model(config, i, spec)
        text = "" if own is None else canonical_json(own).decode()
        group = groups.setdefault(text, (own, [], []))
        group[1].append(item)
        group[2].append(i)
    if set(groups) == {""}:
        check_campaign(config, model, pipeline, base_dir=config.base_dir, allow_imports=allowed)
        return
    faults: list[str] = []

    def collect(sub: CampaignConfig, checked: Any, index: list[int] | None) -> None:
        try:
            check_campaign(sub, checked, pipeline, base_dir=config.base_dir, allow_imports=allowed)
        except ConfigError as exc:
            for line in str(exc).splitlines():
                if index is not None:
                    line = _FLIGHT_INDEX.sub(lambda m: f"flights[{index[int(m[1])]}]", line)
                if line not in faults:
                    faults.append(line)

    for own, items, index in groups.values():
        sub = config.model_copy(
            update={"flights": items}
            if own is None
            else {
                "flights": items,
                "model": own,
            }
        )
        checked = model if own is None else resolve_model(own, config.base_dir)
        collect(sub, checked, index)
    if "" not in groups:  # the campaign-level steps keep the campaign's model
        collect(config.model_copy(update={"flights": []}), model, None)
    if faults:
        raise ConfigError("\n".join(faults))


def _check_selected(
    config: CampaignConfig, pipeline: Pipeline, selected: Mapping[str, list[str]]
) -> None:
    """A step may run on some flights only when nothing needs it for every flight: an
    optional per-flight step whose results other steps read where they exist."""
    for step in pipeline.steps:
        if step.name not in selected:
            continue
        if step not in pipeline.flight_steps or not step.optional:
            raise ConfigError(
                f"{config.source}: stages.{step.name}.flights: only an optional per-flight "
                f"step runs on chosen flights; {step.name!r} runs on every flight"
            )


def _check_selected_names(
    config: CampaignConfig, selected: Mapping[str, list[str]], flights: Sequence[str]
) -> None:
    for step, names in selected.items():
        unknown = [n for n in names if n not in flights]
        if unknown:
            close = difflib.get_close_matches(unknown[0], flights, n=1)
            raise ConfigError(
                f"{config.source}: stages.{step}.flights: {unknown} are not flights of the "
                f"campaign (its flights: {', '.join(flights[:10])}"
                + (", ..." if len(flights) > 10 else "")
                + ")"
                + (f"; did you mean {close[0]!r}?" if close else "")
            )
