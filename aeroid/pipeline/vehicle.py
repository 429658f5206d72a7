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
from .keys import canonical_json, model_fingerprint

__all__ = ["BUILTIN_MODELS", "keyed_fingerprint", "resolve_model"]

BUILTIN_MODELS = ("short_period", "first_order")


def resolve_model(spec: str | Mapping[str, Any], base_dir: str | None = None) -> Any:
    """A model from a built-in name, ``module:attribute`` (a Model or a factory; the
    module's file in `base_dir`, else an installed module), or a mapping that defines
    an `aeroid.models.aircraft` model (see `model_from_config`). Resolved once per process."""
    if isinstance(spec, Mapping):
        return _model_from_mapping(canonical_json(dict(spec)).decode())
    # a user's module file, or one of the user's modules it imports, edited since:
    # resolved again (their text is in the task keys, so the model that runs must be
    # the one the keys describe)
    stamp = None
    if ":" in spec:
        try:
            stamp = tuple(_code.user_code(spec.partition(":")[0], base_dir).items()) or None
        except ConfigError:
            stamp = None  # `_code.resolve` names the file
    return _named_model(spec, base_dir, stamp)


def keyed_fingerprint(
    model: Any, spec: str | Mapping[str, Any], base_dir: str | None
) -> dict[str, Any]:
    """`model_fingerprint` of `model`, resolved from `spec`, as task keys hold it: for a
    ``module:attribute`` model whose module is a file in `base_dir`, with ``code``, the
    digests of that file and of the user's modules in `base_dir` it imports
    (`_code.user_code`), so an edited helper or constant recomputes its fits."""
    fp = model_fingerprint(model)
    if isinstance(spec, str) and ":" in spec:
        code = _code.user_code(spec.partition(":")[0], base_dir)
        if code:
            fp["code"] = code
    return fp


@functools.lru_cache(maxsize=32)
def _model_from_mapping(text: str) -> Any:
    from ..errors import ModelDefinitionError
    from ..models.aircraft import model_from_config

    try:
        return model_from_config(json.loads(text))
    except ModelDefinitionError as exc:
        raise ConfigError(f"model: {exc}") from None


@functools.lru_cache(maxsize=32)
def _named_model(spec: str, base_dir: str | None, stamp: tuple[tuple[str, str], ...] | None) -> Any:
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
