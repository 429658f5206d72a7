"""The base of every options model: frozen, unknown keys forbidden, numbers finite."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, get_args

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from ..errors import ConfigError

__all__ = ["Options"]


class Options(BaseModel):
    """Base of every options model: frozen, unknown keys forbidden, numbers finite."""

    # NaN and infinity are refused where a float is declared, and (below) anywhere
    # inside free-form options: no config option means "not a number"
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    #: Options added after the stage's keys were first computed: left out of the
    #: key while unset, so adding one does not recompute every stored result.
    added_later: ClassVar[frozenset[str]] = frozenset()
    #: Options that change how a result is computed, never the result (how many
    #: parallel parts): kept out of the key, so changing one recomputes nothing.
    execution_only: ClassVar[frozenset[str]] = frozenset()
    #: Free-form fields validated by another model later (with better key paths).
    checked_later: ClassVar[frozenset[str]] = frozenset()

    @field_validator("*", mode="before")
    @classmethod
    def _no_stray_bool(cls, value: Any, info: ValidationInfo) -> Any:
        # pydantic reads `true` as 1 for a count: `n_samples: true` would run one draw
        field = cls.model_fields.get(info.field_name or "")
        if isinstance(value, bool) and field is not None and not _admits_bool(field.annotation):
            raise ValueError(f"expected a number, got the boolean {str(value).lower()}")
        return value

    @field_validator("*", mode="after")
    @classmethod
    def _finite(cls, value: Any, info: ValidationInfo) -> Any:
        if info.field_name in cls.checked_later:
            return value
        where = _non_finite(value)
        if where is not None:
            raise ValueError(f"must be a finite number{where}")
        return value

    def key_document(self) -> dict[str, Any]:
        """The options as they enter a task's key (plain JSON)."""
        doc = self.model_dump(mode="json")
        return {
            k: v
            for k, v in doc.items()
            if k not in self.execution_only and not (v is None and k in self.added_later)
        }

    def task_document(self) -> dict[str, Any]:
        """The options a task runs with: `key_document` plus the execution-only ones set."""
        doc = self.model_dump(mode="json")
        extra = {k: doc[k] for k in self.execution_only if doc.get(k) is not None}
        return {**self.key_document(), **extra}

    def library_kwargs(self, *, exclude: Sequence[str] = ()) -> dict[str, Any]:
        """Options given (not None) as keyword arguments for the library function."""
        out = self.model_dump(mode="python", exclude_none=True, exclude=set(exclude))
        return out


def _admits_bool(annotation: Any) -> bool:
    """True when a field's type takes a boolean as itself (bool, Any, a union with bool)."""
    if annotation is bool or annotation is Any:
        return True
    return any(_admits_bool(a) for a in get_args(annotation))


def _non_finite(value: Any, path: str = "") -> str | None:
    """Where in a plain value (mappings, lists, numbers) a NaN or infinity sits, else None."""
    if isinstance(value, float) and not math.isfinite(value):
        return f" (at {path.lstrip('.')}: {value})" if path else f" (got {value})"
    if isinstance(value, Mapping):
        for k, v in value.items():
            found = _non_finite(v, f"{path}.{k}")
            if found is not None:
                return found
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            found = _non_finite(v, f"{path}[{i}]")
            if found is not None:
                return found
    return None


def stage_flights(
    values: Mapping[str, Any] | None, *, where: str = "stages.<step>"
) -> tuple[dict[str, Any] | None, list[str] | None]:
    """A step's options without the engine's key ``flights`` (the flights an optional
    per-flight step runs on; default every flight), and that list.

    Raises
    ------
    ConfigError
        ``flights`` is not a non-empty list of flight names.
    """
    if not isinstance(values, Mapping) or "flights" not in values:
        return (dict(values) if isinstance(values, Mapping) else None), None
    rest = {k: v for k, v in values.items() if k != "flights"}
    only = values["flights"]
    if not isinstance(only, list) or not only or not all(isinstance(n, str) and n for n in only):
        raise ConfigError(
            f"{where}.flights: expected a non-empty list of flight names (the flights this step "
            f"runs on), got {only!r}"
        )
    return rest, list(dict.fromkeys(only))
