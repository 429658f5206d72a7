"""Options models built from a library function's signature, not mirrored by hand.

`library_fields` reads the function's keywords (types and existence) from its
source without importing it: planning a campaign imports no numerics. A keyword
whose type is not plain configuration data (``Any``, a record) needs its type
given; bounds (``ge``, ``lt``...) are the stage's and are given as a `Field`.
Every generated field defaults to None: the library's own default applies.
"""

from __future__ import annotations

import ast
import copy
import importlib.util
from functools import cache
from pathlib import Path
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

from pydantic import create_model
from pydantic.fields import FieldInfo

from ...errors import PipelineError
from .._options import Options

__all__ = ["library_fields"]

# what a signature's annotation may name: the collection types read as their plain forms
_TYPES: dict[str, Any] = {
    "Sequence": list,
    "list": list,
    "Mapping": dict,
    "dict": dict,
    "tuple": tuple,
    "str": str,
    "int": int,
    "float": float,
    "bool": bool,
    "None": None,
    "Literal": Literal,
    "Any": Any,
}


@cache
def _keywords(spec: str) -> dict[str, str]:
    """The keyword-capable parameters of ``module:function`` -> annotation source."""
    module, _, name = spec.partition(":")
    found = importlib.util.find_spec(module)
    if found is None or found.origin is None:
        raise PipelineError(f"{spec}: no module {module!r}")
    tree = ast.parse(Path(found.origin).read_text(encoding="utf-8"))
    # the last definition is the implementation (earlier ones may be @overload stubs)
    defs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == name]
    if not defs:
        raise PipelineError(f"{spec}: {module} defines no function {name!r}")
    args = defs[-1].args
    return {
        a.arg: ast.unparse(a.annotation) if a.annotation is not None else "Any"
        for a in (*args.args, *args.kwonlyargs)
    }


def _plain_type(spec: str, keyword: str, source: str) -> Any:
    try:
        kind = eval(source, {"__builtins__": {}}, dict(_TYPES))
    except Exception:
        kind = Any
    # `Any` inside a container (a mapping's values) is plain data; as the type, it is not
    if kind is Any or (get_origin(kind) in (Union, UnionType) and Any in get_args(kind)):
        raise PipelineError(
            f"{spec}: keyword {keyword!r} is typed {source!r}, not plain configuration data; "
            "give its type"
        )
    return kind


def library_fields(
    spec: str, *keywords: str, **given: FieldInfo | tuple[Any, FieldInfo]
) -> type[Options]:
    """A base options model holding `keywords` of the function ``module:function``
    (named in its ``library``).

    Each field's type is the signature's (``Sequence`` read as list, ``Mapping``
    as dict), or None for the library's default. `given` adds bounds (a
    `pydantic.Field`) or a type with them (``(type, Field(...))``) by keyword.
    A keyword the function does not take is refused.
    """
    params = _keywords(spec)
    fields: dict[str, Any] = {}
    for keyword in keywords:
        if keyword not in params:
            raise PipelineError(f"{spec} takes no keyword {keyword!r}")
        extra = given.get(keyword)
        if isinstance(extra, tuple):  # copied: one given field may serve several models
            fields[keyword] = (extra[0], copy.copy(extra[1]))
            continue
        kind = _plain_type(spec, keyword, params[keyword])
        info = copy.copy(extra) if extra is not None else FieldInfo(default=None)
        fields[keyword] = (kind | None, info)
    unused = set(given) - set(keywords)
    if unused:
        raise PipelineError(f"{spec}: bounds given for keywords not listed: {sorted(unused)}")
    name = "_" + spec.rpartition(":")[2].title().replace("_", "") + "Fields"
    model: type[Options] = create_model(name, __base__=Options, **fields)
    # the stage built on it wraps this function (`Stage.library` reads it)
    model.library = spec  # type: ignore[attr-defined]
    return model
