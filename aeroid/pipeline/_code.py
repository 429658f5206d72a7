"""The user's code a campaign names, loaded by file path and never through `sys.path`.

A config is code: its pipeline (``pipelines/<name>.py`` beside it) runs when
the campaign is planned. Nothing else is imported by surprise: no folder is
put on `sys.path` (where a ``dask.py`` beside a config would replace Dask),
and a file is found only where the config's name for it says; the modules
such a file imports from its folder are found there after every installed
one (`_UserFolders`).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import importlib.abc
import importlib.machinery
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


class _UserFolders(importlib.abc.MetaPathFinder):
    """Finds a top-level module in a folder the user's files were loaded from, after
    every other finder: ``from helper import GAIN`` in a model file beside a config
    (or ``from .helper import GAIN`` in a package there) imports as it would were the
    folder on `sys.path`, while no installed module is shadowed by a file there."""

    def __init__(self) -> None:
        self.folders: list[str] = []

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if path is not None or "." in fullname:
            return None  # a submodule is found through its package's __path__
        for folder in self.folders:
            spec = importlib.machinery.PathFinder.find_spec(fullname, [folder])
            if spec is not None:
                return spec
        return None


_USER_FOLDERS = _UserFolders()


def _open_folder(path: Path, module: str) -> str:
    """Make the folder that holds user module `module` (file `path`) a place its
    imports are found (`_UserFolders`); returns the module's package ("" for none)."""
    parts = module.split(".")
    package = module if path.name == "__init__.py" else ".".join(parts[:-1])
    root = str(path.parents[len(parts) - (path.name != "__init__.py")])
    if root not in _USER_FOLDERS.folders:
        _USER_FOLDERS.folders.append(root)
    if _USER_FOLDERS not in sys.meta_path:
        sys.meta_path.append(_USER_FOLDERS)
    return package


def load_file(path: Path, name: str, module: str | None = None) -> ModuleType:
    """Run the Python file `path` as module `name` (once per process, and again when
    the file changes).

    The module is entered in `sys.modules`, so that results of its types
    travel between processes by reference like any other module's. Given its
    dotted name in the user's folder (`module`), its imports of the folder's other
    modules, absolute or relative, find them there (`_UserFolders`).
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
    loaded = importlib.util.module_from_spec(spec)
    loaded.__aeroid_stamp__ = stamp  # type: ignore[attr-defined]
    if module is not None and _is_users(path):
        loaded.__package__ = _open_folder(path, module)
    sys.modules[name] = loaded
    try:
        spec.loader.exec_module(loaded)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return loaded


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
            _forget_edited(module, base_dir)
            obj: Any = load_file(path, user_module_name(module), module)
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


# the installed aeroid package: its code is keyed by the stages' versions, never by file
_AEROID = Path(__file__).resolve().parents[1]


def _is_users(path: Path) -> bool:
    """Whether `path` is a user's file (not aeroid's own, not an installed package's)."""
    if path.is_relative_to(_AEROID):
        return False
    return not {"site-packages", "dist-packages"} & set(path.parts)


def _text_digest(data: bytes) -> str:
    # line endings normalised: a checkout on Windows keys as one on Linux
    return hashlib.sha256(data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")).hexdigest()


def _imported(tree: ast.AST, name: str, is_package: bool) -> list[str]:
    """The modules the import statements of module `name` name, each with its parents
    (importing ``a.b`` runs ``a`` too) and, for ``from a import b``, ``a.b`` (``b`` may
    be a submodule); relative imports made absolute."""
    out: list[str] = []
    package = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(tree):  # every import, also those inside functions
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".") if package else []
                if node.level - 1 > len(parts) or not parts:
                    continue  # above the top: the import fails when it runs
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join([*parts, base] if base else parts)
            if not base:
                continue
            targets = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        for target in targets:
            pieces = target.split(".")
            out += [".".join(pieces[: i + 1]) for i in range(len(pieces))]
    return out


def user_code(module: str, base_dir: str | Path | None) -> dict[str, str]:
    """The user's code that module `module` runs: its file in `base_dir` and, found from
    the import statements (read, never run), every module it imports whose file is in
    `base_dir` too, transitively; {dotted name: SHA-256 of the text}. Empty when
    `module` has no file there. Names and contents, never paths or times, so a
    campaign folder copied to another machine keys alike."""
    out: dict[str, str] = {}
    todo = [module]
    while todo:
        name = todo.pop()
        if name in out:
            continue
        path = module_file(name, base_dir)
        if path is None or not _is_users(path):
            continue
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read it ({exc.strerror or exc})") from None
        out[name] = digest = _text_digest(data)
        todo += _imports_of(digest, data, name, path.name == "__init__.py")
    return dict(sorted(out.items()))


@functools.lru_cache(maxsize=256)
def _imports_of(digest: str, data: bytes, name: str, is_package: bool) -> tuple[str, ...]:
    # parsed once per text (`digest` makes the cache's key short to compare)
    try:
        tree = ast.parse(data)
    except (SyntaxError, ValueError):
        return ()  # importing it fails, and says so; its text is keyed all the same
    return tuple(_imported(tree, name, is_package))


# (module, base_dir) -> the `user_code` it had when last resolved in this process
_RESOLVED: dict[tuple[str, str], dict[str, str]] = {}


def _forget_edited(module: str, base_dir: str | Path | None) -> None:
    """Drop from `sys.modules` the user's modules `module` imports from `base_dir` once
    any of them changed since it was last resolved here: a session that edits a helper
    module then runs as edited, as its keys say (`import helper` would reuse the old)."""
    if not base_dir:
        return
    code = user_code(module, base_dir)
    seen = _RESOLVED.get((module, str(base_dir)))
    _RESOLVED[(module, str(base_dir))] = code
    if seen is None or seen == code:
        return
    sys.modules.pop(user_module_name(module), None)
    for name in code:
        loaded = getattr(sys.modules.get(name), "__file__", None)
        if loaded and Path(loaded).resolve() == module_file(name, base_dir):
            del sys.modules[name]


def function_module(function: Any, base_dir: str | Path | None) -> str | None:
    """The dotted name, relative to `base_dir`, of the user's file that defines
    `function` (a stage's code in a pipeline file); None for code elsewhere."""
    code = getattr(getattr(function, "__func__", function), "__code__", None)
    if code is None or not base_dir:
        return None
    path = Path(code.co_filename)
    base = Path(base_dir).resolve()
    try:
        path = path.resolve()
        relative = path.relative_to(base)
    except (OSError, ValueError):
        return None
    if path.suffix != ".py" or not _is_users(path):
        return None
    parts = list(relative.with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    name = ".".join(parts)
    return name if parts and module_file(name, base) == path else None


# a stage's functions: the code its tasks run
_STAGE_FUNCTIONS = ("run", "parts", "run_part", "combine", "part_flights", "brief", "files")


def step_code(stage: Any, options: Any, base_dir: str) -> dict[str, Any]:
    """The user's code a step's tasks run, as its keys hold it: for each option the
    stage declares as code (``code_fields``: a metric) naming ``module:attribute`` of
    a file in the config's folder, ``options.<name>``; for a stage whose functions
    are defined in a file there (a pipeline file's own stage), ``stage``. Each is
    that file and the user's modules it imports from the folder (`user_code`)."""
    out: dict[str, Any] = {}
    for name in sorted(getattr(type(options), "code_fields", ())):
        value = getattr(options, name, None)
        if isinstance(value, str) and ":" in value:
            if found := user_code(value.partition(":")[0], base_dir):
                out[f"options.{name}"] = found
    modules = {function_module(getattr(stage, f), base_dir) for f in _STAGE_FUNCTIONS}
    stage_code: dict[str, str] = {}
    for module in sorted(m for m in modules if m is not None):
        stage_code |= user_code(module, base_dir)
    if stage_code:
        out["stage"] = dict(sorted(stage_code.items()))
    return out
