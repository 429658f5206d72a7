"""The user's code a campaign names, loaded by file path and never through `sys.path`.

A config is code: its pipeline (``pipelines/<name>.py`` beside it) runs when
the campaign is planned. Nothing else is imported by surprise: no folder is
put on `sys.path` (where a ``dask.py`` beside a config would replace Dask),
and a file is found only where the config's name for it says.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

from ..errors import AeroidError, ConfigError

__all__: list[str] = []


def module_file(module: str, base_dir: str | Path | None) -> Path | None:
    """The file of dotted `module` in the folder `base_dir` (a module or a package), if any."""
    if not base_dir or not module.replace(".", "").replace("_", "").isalnum():
        return None
    base = Path(base_dir).joinpath(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate.resolve()
    return None


def load_file(path: Path, name: str) -> ModuleType:
    """Run the Python file `path` as module `name` (once per process, and again when
    the file changes).

    The module is entered in `sys.modules`, so that results of its types
    travel between processes by reference like any other module's.
    """
    try:
        stat = path.stat()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    stamp = (str(path), stat.st_mtime_ns, stat.st_size)
    loaded = sys.modules.get(name)
    if loaded is not None and getattr(loaded, "__aeroid_stamp__", None) == stamp:
        return loaded  # run again only when the file changed
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ConfigError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    module.__aeroid_stamp__ = stamp  # type: ignore[attr-defined]
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


def user_module_name(module: str) -> str:
    """The `sys.modules` name of a user's file: never one of an installed package."""
    return "_aeroid_user_" + module.replace(".", "__")


def resolve(
    spec: str,
    base_dir: str | Path | None,
    *,
    what: str,
    error: type[AeroidError] = ConfigError,
) -> Any:
    """``module:attribute`` (dotted attributes allowed): the module's file in `base_dir`
    when there is one, else the installed module of that name; a problem raises `error`."""
    module, sep, attr = spec.partition(":")
    if not sep or not module or not attr:
        raise error(f"{what} {spec!r}: expected 'package.module:attribute'")
    path = module_file(module, base_dir)
    try:
        if path is not None:
            obj: Any = load_file(path, user_module_name(module))
        else:
            obj = importlib.import_module(module)
    except Exception as exc:  # a module runs its code on import: any error is the module's
        raise error(
            f"{what} {spec!r}: cannot import {module!r} ({type(exc).__name__}: {exc})"
        ) from None
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise error(f"{what} {spec!r}: {module!r} has no attribute {attr!r}") from None
    return obj
