"""Campaign configuration: YAML validated by pydantic models (unknown keys are errors).

A config names the model, the flights, the pipeline, per-stage options and
where results are stored. Every error raises `ConfigError` naming the file,
the key path (``stages.identify.max_iterations``) and what was expected.
Relative paths are relative to the config file.
"""

from __future__ import annotations

import functools
import glob
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from ..errors import ConfigError

__all__ = [
    "CampaignConfig",
    "FileFlights",
    "Options",
    "SimulatedFlights",
    "format_validation_error",
    "load_config",
]


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


class FileFlights(Options):
    """Flight files: a path or glob (CSV, Parquet, .mat) plus loader options."""

    path: str
    time_column: str | None = None
    channels: list[str] | dict[str, str] | None = None
    units: dict[str, str] | None = None


class SimulatedFlights(Options):
    """Flights flown by the library's truth model at a range of flight conditions."""

    generator: Literal["short_period_campaign"] = "short_period_campaign"
    n_flights: int = Field(12, ge=1, le=10000)
    seed: int = Field(0, ge=0)
    # m/s, first and last flight (either order); the derivatives scale with airspeed
    airspeed: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)]] = (60.0, 120.0)
    duration: float = Field(10.0, gt=0)
    sample_rate: float = Field(50.0, gt=0)
    # sensor noise standard deviations of the truth model's outputs
    noise: dict[Literal["alpha", "q"], Annotated[float, Field(ge=0)]] | None = None
    colored: float = Field(0.0, ge=0.0, lt=1.0)
    # "doublet_sweep": the doublet, then from 4 s a 0.2-3 Hz frequency sweep of the same
    # amplitude to the end of the record (for frequency-domain checks)
    maneuver: Literal["doublet", "doublet_sweep"] = "doublet"

    @model_validator(mode="after")
    def _record_length(self) -> SimulatedFlights:
        samples = self.duration * self.sample_rate
        if samples < 10 or samples > _MAX_SAMPLES:
            raise ValueError(
                f"duration x sample_rate gives {samples:.4g} samples per flight; "
                f"expected 10 to {_MAX_SAMPLES:.0e}"
            )
        return self


_MAX_SAMPLES = 1e7  # a simulated record longer than this is a typo, not a flight


class SimulatedSource(Options):
    simulated: SimulatedFlights


def _flight_kind(value: Any) -> str:
    if isinstance(value, str):
        return "glob"
    if isinstance(value, Mapping) and "simulated" in value:
        return "simulated"
    if isinstance(value, (FileFlights, SimulatedSource)):
        return "simulated" if isinstance(value, SimulatedSource) else "file"
    return "file"


FlightSpec = Annotated[
    Annotated[str, Tag("glob")]
    | Annotated[FileFlights, Tag("file")]
    | Annotated[SimulatedSource, Tag("simulated")],
    Discriminator(_flight_kind),
]


class CampaignConfig(Options):
    """The top level of a campaign config file."""

    name: str | None = None
    # a built-in name, "package.module:attribute", or an aeroid.aircraft model as a
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
        from .store import is_url

        return is_url(self.store)

    @property
    def store_location(self) -> str:
        """The store as `ResultStore` takes it: an absolute folder, or the URL as given."""
        if self.store_is_url:
            return self.store
        return str(self.resolve(self.store.removeprefix("file://")))

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

        Files are sorted within an entry; a file named twice is kept once.
        """
        out: list[tuple[int, Path, FileFlights]] = []
        seen: set[Path] = set()
        for i, item in enumerate(self.flights):
            if isinstance(item, SimulatedSource):
                continue
            spec = FileFlights(path=item) if isinstance(item, str) else item
            pattern = str(self.resolve(spec.path))
            if glob.has_magic(pattern):
                matches = sorted(Path(p) for p in glob.glob(pattern, recursive=True))
                if not matches:
                    raise ConfigError(
                        f"{self.source}: flights[{i}]: the pattern {spec.path!r} matches no file"
                    )
            else:
                matches = [Path(pattern)]
            for m in matches:
                if m not in seen:
                    seen.add(m)
                    out.append((i, m, spec))
        return out


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
    for cls in (FileFlights, SimulatedSource, SimulatedFlights):
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
    exc: ValidationError, source: str, model: type[BaseModel], prefix: Sequence[Any] = ()
) -> str:
    """One line per problem: ``file: key.path: what was expected``."""
    lines = []
    # pydantic adds union tags and member types to locations; users never wrote them
    skip = {"glob", "file", "simulated", "str", "int", "float", "dict[str,str]", "list[str]"}
    models = _model_names()
    for err in exc.errors():
        loc = [
            p
            for i, p in enumerate(err["loc"])
            if not (isinstance(p, str) and (p in models or (p in skip and _is_tag(err["loc"], i))))
        ]
        path = _loc([*prefix, *loc])
        if err["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, err["loc"])
            hint = f"; allowed keys: {', '.join(allowed)}" if allowed else ""
            msg = f"unknown key{hint}"
        elif err["type"] == "missing":
            msg = "required key is missing"
        else:
            msg = f"{err['msg'].removeprefix('Value error, ')} (got {err.get('input')!r})"
        line = f"{source}: {path}: {msg}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)


def validate_options(
    model: type[Options], values: Mapping[str, Any] | None, *, source: str, where: str
) -> Options:
    """Validate one stage's options, with errors located at `where`."""
    try:
        return model.model_validate(dict(values or {}))
    except ValidationError as exc:
        raise ConfigError(
            format_validation_error(exc, source, model, prefix=where.split("."))
        ) from None


@functools.lru_cache(maxsize=1)
def _unique_key_loader() -> type:
    import yaml

    class Loader(yaml.SafeLoader):
        """YAML's safe loader, refusing a key given twice in one mapping (the last
        would otherwise win without a word)."""

        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            seen: set[Any] = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"the key {key!r} is given twice", key_node.start_mark
                    )
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    return Loader


def load_config(path: str | Path, **overrides: Any) -> CampaignConfig:
    """Read and validate a campaign YAML file; `overrides` replace top-level keys."""
    import yaml

    _UniqueKeyLoader = _unique_key_loader()
    p = Path(path)
    source = str(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read the config file ({exc.strerror})") from None
    try:
        raw = yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(
            f"{source}: {where}not valid YAML ({' '.join(problem.split())})"
        ) from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    for key in ("source", "base_dir"):
        if key in raw:
            raise ConfigError(f"{source}: {key}: unknown key")
    raw.update({k: v for k, v in overrides.items() if v is not None})
    raw["source"] = source
    raw["base_dir"] = str(p.resolve().parent)
    try:
        return CampaignConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, CampaignConfig)) from None
