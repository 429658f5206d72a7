"""Campaign configuration: YAML validated by pydantic models (unknown keys are errors).

A config names the model, the flights, the pipeline, per-stage options and
where results are stored. Every error raises `ConfigError` naming the file,
the key path (``stages.identify.max_iterations``) and what was expected.
Relative paths are relative to the config file.
"""

from __future__ import annotations

import difflib
import glob
import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, ClassVar

from pydantic import (
    BaseModel,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from ...errors import ConfigError
from .._options import Options
from ._paths import glob_files, network_refusal
from ._yaml import read_yaml
from .flight_specs import (
    _UNION_TAGS,
    ChannelEntry,
    FileFlights,
    FlightSpec,
    SegmentSpec,
    SimulatedFlights,
    SimulatedSource,
    WindowSpec,
)

__all__ = [
    "CampaignConfig",
    "ChannelEntry",
    "FileFlights",
    "Options",
    "SegmentSpec",
    "SimulatedFlights",
    "WindowSpec",
    "format_validation_error",
    "load_config",
]


def workers_problem(v: int | None) -> str | None:
    """Why `v` workers cannot run here, or None: each worker is a forked process with
    its own BLAS threads, so more than four a core only thrash (and exhaust memory)."""
    limit = 4 * (os.cpu_count() or 1)
    if v is not None and not isinstance(v, bool) and v > limit:
        return f"{v} workers on {os.cpu_count()} CPU cores; at most {limit}"
    return None


class CampaignConfig(Options):
    """The top level of a campaign config file."""

    name: str | None = None
    # a built-in name, "package.module:attribute", or an aeroid.models.aircraft model as a
    # mapping ({aircraft: longitudinal, constants: {...}, terms: {...}, ...})
    model: Annotated[str, Field(min_length=1)] | dict[str, Any] = Field(...)
    pipeline: str = "campaign"
    seed: int = Field(0, ge=0)
    flights: list[FlightSpec] = Field(..., min_length=1)
    stages: dict[str, dict[str, Any] | None] = Field(default_factory=dict)
    store: str = ".aeroid-store"
    report: str | None = None
    scheduler: str | None = None
    workers: int | None = Field(None, ge=0)
    # ``package.module:attribute`` models, metrics and generators (and pipelines from
    # installed modules) import and run code the config names: refused unless it opts in
    allow_imports: bool = False
    # a scheduler on another host, or a store URL (``s3://``...), sends flight data and
    # results off this machine (and a dask scheduler speaks pickle): refused unless opted in
    allow_network: bool = False

    # each stage's options are validated by the stage's own model when a plan is made
    checked_later: ClassVar[frozenset[str]] = frozenset({"stages"})

    # where the file lives (set by load_config; not a config key)
    source: str = Field("<config>", exclude=True)
    base_dir: str = Field(".", exclude=True)

    @field_validator("scheduler")
    @classmethod
    def _check_scheduler(cls, v: str | None) -> str | None:
        if v is not None and "://" not in v:
            raise ValueError("expected a scheduler address such as tcp://127.0.0.1:8786")
        return v

    @field_validator("name")
    @classmethod
    def _check_name(cls, v: str | None) -> str | None:
        # the name becomes the report's file name
        if v is not None and (
            not v.strip() or len(v) > 200 or any(c in v for c in "/\\") or not v.isprintable()
        ):
            raise ValueError(
                "expected a campaign name of 1 to 200 printable characters without '/' or '\\' "
                "(it names the report file)"
            )
        return v

    @field_validator("workers")
    @classmethod
    def _check_workers(cls, v: int | None) -> int | None:
        problem = workers_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    @field_validator("store", "report")
    @classmethod
    def _check_store(cls, v: str | None) -> str | None:
        problem = None if v is None else _path_problem(v)
        if problem:
            raise ValueError(problem)
        return v

    @model_validator(mode="after")
    def _check_network(self, info: ValidationInfo) -> CampaignConfig:
        # what the caller passes (``--store``, ``run(store=...)``) is its own choice;
        # these checks are for what a config file asks for
        given = (info.context or {}).get("caller_set", frozenset())
        refusal = network_refusal(self.scheduler, self.store, self.allow_network, given)
        if refusal:
            raise ValueError(refusal)
        return self

    @property
    def campaign_name(self) -> str:
        return self.name or Path(self.source).stem

    def resolve(self, path: str) -> Path:
        """A path from the config, made absolute relative to the config file."""
        p = Path(path).expanduser()
        return p if p.is_absolute() else (Path(self.base_dir) / p).resolve()

    @property
    def store_is_url(self) -> bool:
        """True when the store is an object-store URL (``s3://...``) rather than a folder."""
        from ..storage.store import is_url

        return is_url(self.store)

    @property
    def store_location(self) -> str:
        """The store as `ResultStore` takes it: an absolute folder, or the URL (`store.parse`)."""
        from ..storage.store import parse

        location = parse(self.store)
        if location.is_url:
            return location.root
        # a relative folder is relative to the config file, not to the working directory
        return parse(self.resolve(self.store.removeprefix("file://"))).root

    @property
    def store_path(self) -> Path:
        """The store's folder (a local or shared-filesystem store only)."""
        if self.store_is_url:
            raise ConfigError(f"{self.source}: store: {self.store} is a URL, not a folder")
        return Path(self.store_location)

    @property
    def report_path(self) -> Path:
        """The campaign report: as configured, else in the store's folder (for an
        object store, in ``reports/`` beside the config file)."""
        if self.report:
            return self.resolve(self.report)
        folder = self.resolve("reports") if self.store_is_url else self.store_path / "reports"
        return folder / f"{self.campaign_name}.md"

    def expand_files(self) -> list[tuple[int, Path, FileFlights]]:
        """Every flight file named by a path or glob: (entry index, path, loader options).

        Files are sorted within an entry; a file that globs match more than once with
        the same loader options is kept once (with other options, such as another
        window, it is another flight). A file named by its path in two entries with
        the same options is a `ConfigError`: one flight listed twice.
        """
        out: list[tuple[int, Path, FileFlights]] = []
        seen: set[tuple[Path, str]] = set()
        named: dict[tuple[Path, str], int] = {}
        for i, item in enumerate(self.flights):
            if isinstance(item, SimulatedSource):
                continue
            spec = FileFlights(path=item) if isinstance(item, str) else item
            pattern = str(self.resolve(spec.path))
            # a file that exists is the flight named, whatever its name holds ('run[1].csv')
            pattern_glob = glob.has_magic(pattern) and not Path(pattern).is_file()
            if pattern_glob:
                matches = glob_files(pattern)
                if not matches:
                    raise ConfigError(
                        f"{self.source}: flights[{i}]: the pattern {spec.path!r} matches no file"
                    )
            else:
                matches = [Path(pattern)]
            options = json.dumps(spec.model_dump(mode="json", exclude={"path"}), sort_keys=True)
            if not pattern_glob:
                first = named.setdefault((matches[0], options), i)
                if first != i:
                    raise ConfigError(
                        f"{self.source}: flights[{i}]: {spec.path!r} is listed already in "
                        f"flights[{first}] with the same options (one flight listed twice)"
                    )
            for m in matches:
                if (m, options) not in seen:
                    seen.add((m, options))
                    out.append((i, m, spec))
        return out


def _path_problem(v: str) -> str | None:
    """Why a store or report path written in a config cannot be used as written."""
    if re.search(r"\$\{?[A-Za-z_]|%[A-Za-z_]+%", v):
        return (
            f"{v!r} names an environment variable; aeroid does not expand them, "
            "write the path itself"
        )
    if "\x00" in v or len(v) > 1024:
        return "expected a folder or URL (no NUL character, at most 1024 characters)"
    if v.startswith("~"):
        try:
            Path(v).expanduser()
        except RuntimeError:  # ~name of a user this machine does not have
            return f"{v!r} names the home folder of a user this machine does not know"
    return None


def _loc(loc: Sequence[Any]) -> str:
    out = ""
    for part in loc:
        if part == "[key]":  # pydantic's marker for an error in a mapping's key
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _is_tag(loc: Sequence[Any], i: int) -> bool:
    """True when loc[i] is a union tag pydantic inserted (it follows a list index)."""
    return (i > 0 and isinstance(loc[i - 1], int)) or loc[i] in ("str", "int", "float")


def _allowed_keys(model: type[BaseModel], loc: Sequence[Any]) -> list[str] | None:
    """Keys allowed at the parent of `loc` (best effort, for friendlier messages)."""
    current: Any = model
    for part in loc[:-1]:
        is_model = isinstance(current, type) and issubclass(current, BaseModel)
        if isinstance(part, str) and not (is_model and part in current.model_fields):
            member = _union_member(current, part)
            if member is not None:
                current = member
                continue
        if is_model:
            field = current.model_fields.get(str(part))
            if field is None:
                # a union member name inserted by pydantic (e.g. 'FileFlights')
                cand = _union_member(current, str(part))
                if cand is None:
                    return None
                current = cand
                continue
            current = field.annotation
        current = _strip(current, part)
        if current is None:
            return None
    if isinstance(current, type) and issubclass(current, BaseModel):
        return sorted(k for k, f in current.model_fields.items() if not f.exclude)
    return None


def _union_member(model: Any, name: str) -> Any:
    tags = {"file": FileFlights, "simulated": SimulatedSource, "glob": None}
    if name in tags:
        return tags[name]
    for cls in (
        FileFlights,
        SimulatedSource,
        SimulatedFlights,
        ChannelEntry,
        WindowSpec,
        SegmentSpec,
    ):
        if cls.__name__ == name:
            return cls
    return None


def _strip(tp: Any, part: Any) -> Any:
    import typing

    args = typing.get_args(tp)
    origin = typing.get_origin(tp)
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return tp
    if origin in (list, tuple, dict) and args:
        return args[-1]
    if args:  # a union: pick the BaseModel member if there is one
        models = [a for a in args if isinstance(a, type) and issubclass(a, BaseModel)]
        if isinstance(part, str):
            for m in models:
                if m.__name__ == part:
                    return m
        return models[0] if len(models) == 1 else tp
    return tp


def _model_names() -> set[str]:
    """Names of the options models (pydantic puts a union member's name in error paths;
    a capitalised key such as a parameter name M_q is the user's and stays)."""
    names: set[str] = set()
    todo: list[type] = [Options]
    while todo:
        cls = todo.pop()
        names.add(cls.__name__)
        todo.extend(cls.__subclasses__())
    return names


def format_validation_error(
    exc: ValidationError,
    source: str,
    model: type[BaseModel],
    prefix: Sequence[Any] = (),
    written: Mapping[str, str] | None = None,
) -> str:
    """One line per problem: ``file: key.path: what was expected``.

    `written` maps a top-level field to the key the config wrote for it (an
    old name the model accepts), so the key path is the one in the file.
    """
    lines = []
    # pydantic adds union tags and member types to locations; users never wrote them
    skip = {"glob", "file", "simulated", "str", "int", "float", "dict[str,str]", "list[str]"}
    models = _model_names()
    errors = exc.errors()
    for err in errors:
        if _scalar_member_noise(err, errors):
            continue
        loc = [
            p
            for i, p in enumerate(err["loc"])
            if not (
                isinstance(p, str)
                and (p in models or p in _UNION_TAGS or (p in skip and _is_tag(err["loc"], i)))
            )
        ]
        if loc and written and loc[0] in written:
            loc[0] = written[str(loc[0])]
        path = _loc([*prefix, *loc])
        if err["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, err["loc"])
            hint = f"; allowed keys: {', '.join(allowed)}" if allowed else ""
            close = difflib.get_close_matches(str(err["loc"][-1]), allowed or [], n=1)
            hint += f"; did you mean {close[0]!r}?" if close else ""
            msg = f"unknown key{hint}"
        elif err["type"] == "missing":
            msg = "required key is missing"
        else:
            text = err["msg"].removeprefix("Value error, ")
            given = err.get("input")
            key, _, rest = text.partition(": ")
            if not loc and isinstance(given, Mapping) and key in given:
                # a check across keys that names its key: located there, not at the top
                # level, and quoting that key's value rather than the whole config
                path, text, given = _loc([*prefix, key]), rest, given[key]
            shown = isinstance(given, str) and text.startswith(given)  # the value leads
            msg = (text if shown else f"{text} (got {_brief(given)})") + _suggestion(err)
        line = f"{source}: {path}: {msg}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)


_SCALAR_TAGS = frozenset({"bool", "str", "int", "float", "none"})


def _scalar_member_noise(err: Mapping[str, Any], errors: Sequence[Mapping[str, Any]]) -> bool:
    """Whether `err` is a scalar member of a union refusing a mapping (``quality.bool``:
    not a boolean) while the union's mapping member reports what is wrong inside it."""
    loc = tuple(err["loc"])
    if not loc or loc[-1] not in _SCALAR_TAGS or not isinstance(err.get("input"), Mapping):
        return False
    parent = loc[:-1]
    return any(
        tuple(o["loc"])[: len(parent)] == parent
        and len(o["loc"]) > len(parent)
        and o["loc"][len(parent)] not in _SCALAR_TAGS
        for o in errors
    )


def _brief(value: Any, limit: int = 120) -> str:
    """A value's repr, cut short (a message must stay readable whatever was written)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 4] + " ..."


def _suggestion(err: Mapping[str, Any]) -> str:
    """'; did you mean ...?' for a literal choice written with a typo."""
    expected = (err.get("ctx") or {}).get("expected")
    given = err.get("input")
    if err.get("type") != "literal_error" or not isinstance(given, str) or not expected:
        return ""
    choices = [c.strip().strip("'") for c in str(expected).replace(" or ", ",").split(",")]
    close = difflib.get_close_matches(given, [c for c in choices if c], n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def validate_options(
    model: type[Options], values: Mapping[str, Any] | None, *, source: str, where: str
) -> Options:
    """Validate one stage's options, with errors located at `where` (under the keys as
    written: an old name the model still accepts, its ``renamed``, stays)."""
    given = dict(values or {})
    renamed: Mapping[str, str] = getattr(model, "renamed", None) or {}
    written = {new: old for old, new in renamed.items() if old in given}
    try:
        return model.model_validate(given)
    except ValidationError as exc:
        raise ConfigError(
            format_validation_error(exc, source, model, prefix=where.split("."), written=written)
        ) from None


# A campaign config is a page or two of YAML (the demo: 3 KB, 150 values): limits far
# above any real one, far below what would tie up a process (PyYAML, pure Python,
# reads some ten thousand values a second)


def load_config(path: str | Path, **overrides: Any) -> CampaignConfig:
    """Read and validate a campaign YAML file; `overrides` replace top-level keys."""
    p = Path(path)
    source = str(path)
    raw = read_yaml(p, source)
    given = {k: v for k, v in overrides.items() if v is not None}
    raw.update(given)
    raw["source"] = source
    raw["base_dir"] = str(p.resolve().parent)
    try:
        return CampaignConfig.model_validate(raw, context={"caller_set": frozenset(given)})
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, CampaignConfig)) from None
