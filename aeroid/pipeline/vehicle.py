"""The vehicle model a campaign names, resolved: a built-in name, ``module:attribute``
(a Model or a factory) or a mapping that defines an aircraft model.

Planning resolves it to check the config and key the tasks; a worker resolves it
again from the task's reference (a model is not plain data that travels). Both
seams use this one module, which belongs to neither.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from typing import Any

from ..errors import AeroidError, ConfigError
from . import _code
from .keys import canonical_json

__all__ = ["BUILTIN_MODELS", "resolve_model"]

BUILTIN_MODELS = ("short_period", "first_order")


def resolve_model(spec: str | Mapping[str, Any], base_dir: str | None = None) -> Any:
    """A model from a built-in name, ``module:attribute`` (a Model or a factory; the
    module's file in `base_dir`, else an installed module), or a mapping that defines
    an `aeroid.models.aircraft` model (see `model_from_config`). Resolved once per process."""
    if isinstance(spec, Mapping):
        return _model_from_mapping(canonical_json(dict(spec)).decode())
    # a user's module file edited since: resolved again (its source is in the task keys,
    # so the model that runs must be the one the keys describe)
    path = _code.module_file(spec.partition(":")[0], base_dir) if ":" in spec else None
    try:
        stamp = None if path is None else (path.stat().st_mtime_ns, path.stat().st_size)
    except OSError:
        stamp = None  # `_code.resolve` names the file
    return _named_model(spec, base_dir, stamp)


@functools.lru_cache(maxsize=32)
def _model_from_mapping(text: str) -> Any:
    from ..errors import ModelDefinitionError
    from ..models.aircraft import model_from_config

    try:
        return model_from_config(json.loads(text))
    except ModelDefinitionError as exc:
        raise ConfigError(f"model: {exc}") from None


@functools.lru_cache(maxsize=32)
def _named_model(spec: str, base_dir: str | None, stamp: tuple[int, int] | None) -> Any:
    from ..models.model import Model, SimulatorModel

    if ":" in spec:
        obj = _code.resolve(spec, base_dir, what="model")
    elif spec in BUILTIN_MODELS:
        from ..models import catalog

        obj = getattr(catalog, spec)
    else:
        raise ConfigError(
            f"model {spec!r}: expected a built-in model ({', '.join(BUILTIN_MODELS)}) "
            "or 'package.module:attribute'"
        )
    if not isinstance(obj, (Model, SimulatorModel)) and callable(obj):
        try:
            obj = obj()
        except AeroidError:
            raise
        except Exception as exc:
            raise ConfigError(
                f"model {spec!r}: calling it failed: {type(exc).__name__}: {exc}"
            ) from None
    if not isinstance(obj, (Model, SimulatorModel)):
        raise ConfigError(
            f"model {spec!r}: expected a Model (or a function returning one), got {type(obj).__name__}"
        )
    return obj
