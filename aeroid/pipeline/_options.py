"""The base of every options model: frozen, unknown keys forbidden, numbers finite and
given as numbers (a quoted ``'100'`` or a ``true`` where a number is meant is refused)."""

from __future__ import annotations

import math
import types
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, ClassVar, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, ValidationInfo, field_validator

from ..errors import ConfigError

__all__ = ["Options"]


class Options(BaseModel):
    """Base of every options model: frozen, unknown keys forbidden, numbers finite and
    written as numbers (not quoted, not a boolean)."""

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
    def _numbers_as_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        # pydantic reads `true` as 1 for a count: `n_samples: true` would run one draw
        field = cls.model_fields.get(info.field_name or "")
        if field is None:
            return value
        if isinstance(value, bool) and not _admits_bool(field.annotation):
            raise ValueError(f"expected a number, got the boolean {str(value).lower()}")
        # and '100' as 100: a quoted number is a typo or a templating slip the run would
        # hide (`n_samples: '1e9'` is not what a reader of the config sees as a count)
        where = _not_a_number(field.annotation, value)
        if where is not None:
            raise ValueError(where)
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


_NUMBERS = (int, float)


def _members(annotation: Any) -> list[Any]:
    """The types a field's annotation allows (a union's members, Annotated unwrapped),
    None left out."""
    origin = get_origin(annotation)
    if origin is Annotated:
        return _members(get_args(annotation)[0])
    if origin is Union or origin is types.UnionType:
        return [m for a in get_args(annotation) for m in _members(a)]
    return [] if annotation is type(None) else [annotation]


def _numeric_only(members: list[Any]) -> bool:
    """True when every allowed type is a number (int or float)."""
    return bool(members) and all(m in _NUMBERS for m in members)


def _reads_as_number(text: str) -> bool:
    """True when pydantic would read `text` as a number (``'100'``, ``' 1e9 '``)."""
    try:
        float(text.strip().replace("_", ""))
    except ValueError:
        return False
    return True


def _not_a_number(annotation: Any, value: Any, path: str = "") -> str | None:
    """Why `value` is refused where `annotation` means a number: a string, or (inside a
    list or mapping) a boolean, where only numbers are allowed; else None. Walks lists,
    tuples and mappings of numbers; leaves any other type to pydantic."""
    members = _members(annotation)
    at = f" at {path.lstrip('.')}" if path else ""
    if isinstance(value, str):
        # any other text pydantic refuses itself ("a valid integer")
        if _numeric_only(members) and _reads_as_number(value):
            got = f", got the string {value[:40]!r}" if path else ", not a string"
            return f"expected a number{at}{got} (write it without quotes)"
        return None
    if isinstance(value, bool):
        if path and _numeric_only(members):
            return f"expected a number{at}, got the boolean {str(value).lower()}"
        return None
    if isinstance(value, Mapping):
        inner = [get_args(m) for m in members if get_origin(m) in (dict, Mapping)]
        if len(inner) == 1 and len(inner[0]) == 2:
            for k, v in value.items():
                found = _not_a_number(inner[0][1], v, f"{path}.{k}")
                if found is not None:
                    return found
        return None
    if isinstance(value, (list, tuple)):
        seqs = [m for m in members if get_origin(m) in (list, tuple, Sequence, set, frozenset)]
        if len(seqs) != 1:
            return None
        args = get_args(seqs[0])
        for i, v in enumerate(value):
            if get_origin(seqs[0]) is tuple and not (len(args) == 2 and args[1] is Ellipsis):
                if i >= len(args):
                    return None
                item = args[i]
            else:
                item = args[0] if args else Any
            found = _not_a_number(item, v, f"{path}[{i}]")
            if found is not None:
                return found
    return None


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
