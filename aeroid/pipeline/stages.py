"""Pipeline stages: thin wrappers from stored inputs to a public aeroid function to a record.

A stage declares its options model (mirroring the library function's
keywords), the record type it produces, whether it needs the vehicle model
and whether it is stochastic, and a ``run(ctx)`` function. Adding a stage is
one `register_stage` call; pipelines (``pipelines/``) wire stages together.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from ..errors import AeroidError, DataFormatError, PipelineError
from .config import Options

__all__ = [
    "STAGES",
    "CampaignReport",
    "FlightReport",
    "Stage",
    "StageContext",
    "register_stage",
    "resolve_callable",
]


# -- records produced by the pipeline itself -------------------------------------


@dataclass(frozen=True, eq=False)
class FlightReport:
    """The Markdown engineering report of one flight."""

    title: str
    markdown: str

    def summary(self) -> str:
        return self.markdown


@dataclass(frozen=True, eq=False)
class CampaignReport:
    """The campaign report: a per-flight table, failures, each flight's report and figures.

    `figures` holds PNG images (bytes as ``uint8`` arrays) titled by
    `figure_titles`: the trend of every estimate across flights and the
    detailed figures of the first flight that was identified.
    """

    title: str
    markdown: str
    flights: tuple[str, ...]
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    failures: Mapping[str, str] = field(default_factory=dict)
    figure_titles: tuple[str, ...] = ()
    figures: tuple[np.ndarray, ...] = ()

    def __post_init__(self) -> None:
        pngs = []
        for png in self.figures:
            arr = np.frombuffer(png, dtype=np.uint8) if isinstance(png, bytes) else png
            arr = np.array(arr, dtype=np.uint8, copy=True)
            arr.setflags(write=False)
            pngs.append(arr)
        if len(pngs) != len(self.figure_titles):
            raise PipelineError("CampaignReport: one title per figure expected")
        object.__setattr__(self, "figures", tuple(pngs))

    def figure_bytes(self) -> dict[str, bytes]:
        """The PNG images by title."""
        return {t: f.tobytes() for t, f in zip(self.figure_titles, self.figures, strict=True)}

    def summary(self) -> str:
        return self.markdown


# -- the stage contract -------------------------------------------------------------


@dataclass
class StageContext:
    """What a stage's ``run`` receives on the worker."""

    options: Any
    inputs: dict[str, Any]
    model: Any = None
    seed: np.random.SeedSequence | None = None
    flight: str | None = None
    source: Mapping[str, Any] | None = None
    failures: Mapping[str, str] = field(default_factory=dict)
    flights: tuple[str, ...] = ()
    # role -> {flight index: brief} handed over by the flights' tasks (see `Stage.brief`)
    briefs: Mapping[str, Mapping[int, Any]] = field(default_factory=dict)
    summarize: Callable[[str, Any], Any] | None = None

    def brief(self, role: str, index: int) -> Any:
        """The brief of flight `index`'s `role` input (see `Stage.brief`): the one its task
        handed over, else made from the record (read on access); None where the flight
        failed or the role is not an input."""
        given = self.briefs.get(role)
        if given is not None and index in given:
            return given[index]
        if role not in self.inputs or self.summarize is None:
            return None
        record = self.inputs[role][index]
        return None if record is None else self.summarize(role, record)

    def seed_sequence(self, *extra: int) -> np.random.SeedSequence:
        """This task's `SeedSequence`, or its child with `extra` appended to the spawn key."""
        if self.seed is None:
            raise PipelineError("this stage has no seed specification")
        return np.random.SeedSequence(self.seed.entropy, spawn_key=(*self.seed.spawn_key, *extra))

    def seed_int(self, *extra: int) -> int:
        """A 64-bit integer seed from this task's `SeedSequence` (child `extra` if given)."""
        if self.seed is None:
            raise PipelineError("this stage has no seed specification")
        ss = self.seed
        if extra:
            ss = np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, *extra))
        return int(ss.generate_state(1, dtype=np.uint64)[0])


@dataclass(frozen=True)
class Stage:
    """A pipeline stage.

    Attributes
    ----------
    name : str
    version : str
        Bump when the wrapper's behaviour changes; it enters every key.
    options : type of Options
        The stage's options model (unknown keys are config errors).
    record_type : str
        Name of the record type produced (a label that enters the key).
    run : callable
        ``run(ctx: StageContext) -> record``.
    uses_model : bool
        The model fingerprint enters the key and the model is passed in.
    seeded : bool
        The task gets ``SeedSequence(seed, spawn_key=(flight,))``.
    library : str or None
        The public aeroid function wrapped (checked before running).
    per_flight : bool
        False for campaign-level stages whose inputs are lists over flights.
    parts : callable, optional
        ``parts(options, roles) -> n`` (`roles`: the task's input roles):
        the task splits into `n` independent parts
        (MCMC ensembles, Monte Carlo batches) that run in parallel, each with
        its own random stream; ``run_part(ctx, i)`` computes part `i` and
        ``combine(ctx, parts)`` the stored record. Results equal the unsplit
        computation whatever runs which part.
    part_flights : callable, optional
        ``part_flights(options, roles, i)``: for a campaign-level split task,
        the flights (indices) part `i` reads; it then waits only for those
        flights. None (or the callable returning None): every flight.
    preload : tuple of str
        Modules the stage imports lazily and slowly (plotting): imported once
        before worker processes are forked, instead of in every worker.
    brief : callable, optional
        ``brief(role, record) -> value``: for a campaign-level stage, the small
        part of one flight's `role` input it needs (a few numbers and strings;
        picklable). The flight's task makes it as it commits the record, while
        the record is in memory, and hands it over with its status, so the
        campaign task reads no entry for it; ``ctx.brief(role, i)`` returns it,
        or makes it from the stored record when no task handed it over (a
        cached flight, a rerun). Either way it is the same value.
    """

    name: str
    version: str
    options: type[Options]
    record_type: str
    run: Callable[[StageContext], Any]
    uses_model: bool = True
    seeded: bool = False
    library: str | None = None
    per_flight: bool = True
    parts: Callable[[Any, frozenset[str]], int] | None = None
    run_part: Callable[[StageContext, int], Any] | None = None
    combine: Callable[[StageContext, list[Any]], Any] | None = None
    preload: tuple[str, ...] = ()
    part_flights: Callable[[Any, frozenset[str], int], tuple[int, ...] | None] | None = None
    brief: Callable[[str, Any], Any] | None = None


STAGES: dict[str, Stage] = {}


def register_stage(stage: Stage) -> Stage:
    """Make a stage available to pipelines by name (replacing one of the same name)."""
    STAGES[stage.name] = stage
    return stage


def resolve_callable(spec: str, *, what: str) -> Any:
    """Import ``package.module:attribute`` (dotted attributes allowed)."""
    import importlib

    module, sep, attr = spec.partition(":")
    if not sep or not module or not attr:
        raise PipelineError(f"{what} {spec!r}: expected 'package.module:attribute'")
    try:
        obj: Any = importlib.import_module(module)
    except ImportError as exc:
        raise PipelineError(f"{what} {spec!r}: cannot import {module!r} ({exc})") from None
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise PipelineError(f"{what} {spec!r}: {module!r} has no attribute {attr!r}") from None
    return obj


def _library(name: str) -> Any:
    import aeroid

    fn = getattr(aeroid, name, None)
    if fn is None:
        raise PipelineError(f"aeroid.{name} is not available in this version of aeroid")
    return fn


def _kwargs(options: Options, *exclude: str) -> dict[str, Any]:
    return options.library_kwargs(exclude=exclude)


# -- load ---------------------------------------------------------------------------


class LoadOptions(Options):
    """`aeroid.load_flight_test` keywords (files) or the simulated-flight spec."""

    time_column: str | None = None
    channels: list[str] | dict[str, str] | None = None
    units: dict[str, str] | None = None


def _run_load(ctx: StageContext) -> Any:
    import aeroid

    from .keys import file_digest

    src = dict(ctx.source or {})
    if src.get("kind") == "simulated":
        from .synthetic import fly

        return fly(src["spec"])
    path = src["path"]
    if not Path(path).is_file():
        why = "is a folder, not a flight file" if Path(path).is_dir() else "no such file"
        raise DataFormatError(f"{path}: {why}")
    try:
        before = file_digest(path)
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if before != src.get("sha256"):
        raise PipelineError(f"{path}: the file changed since the run was planned")
    opts = _kwargs(ctx.options)
    data = aeroid.load_flight_test(path, **opts)
    if file_digest(path) != before:
        raise PipelineError(f"{path}: the file changed while it was being read")
    return data


# -- identify / filter / validate ----------------------------------------------------


class IdentifyOptions(Options):
    """`aeroid.identify` keywords (``parameters``: names to estimate; default all)."""

    parameters: list[str] | None = None
    method: str | None = None
    outputs: list[str] | None = None
    x0: dict[str, float] | None = None
    estimate_x0: bool | None = None
    estimate_bias: bool | None = None
    weights: dict[str, float] | None = None
    error_bars: str | None = None
    max_iterations: int | None = Field(None, ge=1)
    tolerance: float | None = Field(None, gt=0)
    gradient: str | None = None
    process_noise: dict[str, float] | None = None
    measurement_noise: dict[str, float] | None = None
    simulate_options: dict[str, Any] | None = None
    # parameter -> [lower, upper], null for an open side (YAML: {M_q: [null, 0.0]})
    bounds: dict[str, tuple[float | None, float | None]] | None = None

    added_later: ClassVar[frozenset[str]] = frozenset({"bounds"})

    @field_validator("bounds", mode="after")
    @classmethod
    def _check_bounds(cls, value: Any) -> Any:
        for name, (lower, upper) in (value or {}).items():
            if lower is not None and upper is not None and not lower < upper:
                raise ValueError(
                    f"{name}: the lower bound {lower} must be below the upper bound {upper}"
                )
        return value


def _run_identify(ctx: StageContext) -> Any:
    identify = _library("identify")
    names = ctx.options.parameters or list(ctx.model.parameter_names)
    return identify(ctx.model, ctx.inputs["data"], names, **_kwargs(ctx.options, "parameters"))


class FilterOptions(Options):
    """`aeroid.filter_states` keywords (both noise levels are required, as there)."""

    process_noise: dict[str, float]
    measurement_noise: dict[str, float]
    method: str | None = None
    smooth: bool | None = None


def _run_filter(ctx: StageContext) -> Any:
    fn = _library("filter_states")
    return fn(ctx.model, ctx.inputs["data"], ctx.inputs.get("parameters"), **_kwargs(ctx.options))


class ValidateOptions(Options):
    """`aeroid.validate` keywords."""

    confidence: float | None = Field(None, gt=0, lt=1)
    whiteness_lags: int | None = Field(None, ge=1)


def _run_validate(ctx: StageContext) -> Any:
    fn = _library("validate")
    return fn(ctx.model, ctx.inputs["data"], ctx.inputs.get("parameters"), **_kwargs(ctx.options))


# -- propagate ------------------------------------------------------------------------


def natural_frequency(p: Mapping[str, float]) -> float:
    """Short-period undamped natural frequency sqrt(M_q Z_alpha - M_alpha), rad/s."""
    return math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"])


def damping_ratio(p: Mapping[str, float]) -> float:
    """Short-period damping ratio -(Z_alpha + M_q) / (2 omega_n)."""
    return -(p["Z_alpha"] + p["M_q"]) / (2.0 * natural_frequency(p))


METRICS: dict[str, Callable[[Mapping[str, float]], float]] = {
    "natural_frequency": natural_frequency,
    "damping_ratio": damping_ratio,
}


class PropagateOptions(Options):
    """`aeroid.propagate` keywords; ``metric`` is a built-in name or ``pkg.mod:function``;
    ``n_batches`` splits the draws into batches run in parallel (same result)."""

    metric: str = "natural_frequency"
    n_samples: int | None = Field(None, ge=1)
    percentiles: list[float] | None = None
    n_batches: int | None = Field(None, ge=1)

    execution_only: ClassVar[frozenset[str]] = frozenset({"n_batches"})


def _metric(name: str) -> Callable[[Mapping[str, float]], float]:
    if name in METRICS:
        return METRICS[name]
    if ":" not in name:
        raise PipelineError(
            f"propagate metric {name!r}: expected one of {sorted(METRICS)} or 'package.module:function'"
        )
    fn = resolve_callable(name, what="propagate metric")
    if not callable(fn):
        raise PipelineError(f"propagate metric {name!r} is not callable")
    return fn


def _run_propagate(ctx: StageContext) -> Any:
    fn = _library("propagate")
    kw = _kwargs(ctx.options, "metric", "n_batches")
    return fn(ctx.inputs["result"], _metric(ctx.options.metric), seed=ctx.seed_int(0), **kw)


def _n_draws(options: Any) -> int:
    if options.n_samples is not None:
        return int(options.n_samples)
    return int(inspect.signature(_library("propagate")).parameters["n_samples"].default)


def _propagate_parts(options: Any, roles: frozenset[str]) -> int:
    return min(int(options.n_batches or 1), _n_draws(options))


def _run_propagate_part(ctx: StageContext, index: int) -> Any:
    from ..propagation import propagate_batch

    n, k = _n_draws(ctx.options), _propagate_parts(ctx.options, frozenset(ctx.inputs))
    start, stop = index * n // k, (index + 1) * n // k
    metric = _metric(ctx.options.metric)
    result = ctx.inputs["result"]
    return propagate_batch(
        result, metric, start=start, n_samples=stop - start, seed=ctx.seed_int(0)
    )


def _combine_propagate(ctx: StageContext, parts: list[Any]) -> Any:
    from ..propagation import combine_batches

    return combine_batches(parts, **_kwargs(ctx.options, "metric", "n_batches", "n_samples"))


# -- infer ------------------------------------------------------------------------------


class PriorSpec(Options):
    """One prior: exactly one of normal [mu, sigma], uniform [lo, hi], log_uniform [lo, hi],
    half_normal sigma."""

    normal: tuple[float, float] | None = None
    uniform: tuple[float, float] | None = None
    log_uniform: tuple[float, float] | None = None
    half_normal: float | None = None

    def build(self, name: str) -> Any:
        import aeroid

        given = self.model_dump(exclude_none=True)
        if len(given) != 1:
            raise PipelineError(
                f"prior of {name!r}: give exactly one of normal, uniform, log_uniform, half_normal"
            )
        kind, args = next(iter(given.items()))
        cls_name = {
            "normal": "Normal",
            "uniform": "Uniform",
            "log_uniform": "LogUniform",
            "half_normal": "HalfNormal",
        }[kind]
        cls = getattr(aeroid, cls_name, None)
        if cls is None:
            raise PipelineError(f"aeroid.{cls_name} is not available in this version of aeroid")
        return cls(*args) if isinstance(args, (tuple, list)) else cls(args)


class InferOptions(Options):
    """`aeroid.infer` keywords; ``priors`` by parameter name; ``initial``: start at the fit."""

    priors: dict[str, PriorSpec]
    noise: dict[str, float] | None = None
    n_walkers: int | None = Field(None, ge=2)
    n_steps: int | None = Field(None, ge=1)
    n_ensembles: int | None = Field(None, ge=1)
    burn_in: int | None = Field(None, ge=0)
    thin: int | None = Field(None, ge=1)
    stretch: float | None = Field(None, gt=1)
    move: Literal["stretch", "de"] | None = None

    added_later: ClassVar[frozenset[str]] = frozenset({"move"})
    outputs: list[str] | None = None
    backend: str | None = None
    initial: bool = True


def _infer_kwargs(ctx: StageContext) -> dict[str, Any]:
    kw = _kwargs(ctx.options, "priors", "initial", "n_ensembles")
    if ctx.options.initial and "initial" in ctx.inputs:
        kw["initial"] = ctx.inputs["initial"]
    kw["parameters"] = {name: spec.build(name) for name, spec in ctx.options.priors.items()}
    # ensemble e draws from SeedSequence(seed, spawn_key=(flight, 1, e))
    kw["seed"] = ctx.seed_sequence(1)
    return kw


def _run_infer(ctx: StageContext) -> Any:
    fn = _library("infer")
    kw = _infer_kwargs(ctx)
    if ctx.options.n_ensembles is not None:
        kw["n_ensembles"] = ctx.options.n_ensembles
    return fn(ctx.model, ctx.inputs["data"], **kw)


def _infer_parts(options: Any, roles: frozenset[str]) -> int:
    import aeroid.inference as inference

    if not hasattr(inference, "infer_ensemble"):
        return 1
    return int(options.n_ensembles or 1)


def _run_infer_part(ctx: StageContext, ensemble: int) -> Any:
    from ..inference import infer_ensemble

    return infer_ensemble(ctx.model, ctx.inputs["data"], ensemble=ensemble, **_infer_kwargs(ctx))


def _combine_infer(ctx: StageContext, parts: list[Any]) -> Any:
    from ..inference import combine_ensembles

    return combine_ensembles(parts)


# -- design -------------------------------------------------------------------------------


class ManeuverSpec(Options):
    """A built-in manoeuvre family: ``type`` and its constructor arguments."""

    type: Literal["multisine", "doublet", "chirp"]
    control: str
    options: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _builds(self) -> ManeuverSpec:
        # a missing or unknown constructor argument is a config error, found before any run
        try:
            self.build()
        except (TypeError, AeroidError) as exc:
            raise ValueError(f"options do not make a {self.type}: {exc}") from None
        return self

    def build(self) -> Any:
        import aeroid

        cls_name = {"multisine": "Multisine", "doublet": "Doublet", "chirp": "Chirp"}[self.type]
        cls = getattr(aeroid, cls_name, None)
        if cls is None:
            raise PipelineError(f"aeroid.{cls_name} is not available in this version of aeroid")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in self.options.items()}
        return cls(self.control, **kw)


class DesignOptions(Options):
    """`aeroid.design_experiment` keywords (designed at the identified values)."""

    maneuver: ManeuverSpec
    parameters: list[str] | None = None
    criterion: str | None = None
    noise: dict[str, float] | None = None
    duration: float | None = Field(None, gt=0)
    sample_rate: float | None = Field(None, gt=0)
    optimizer_options: dict[str, Any] | None = None


def _run_design(ctx: StageContext) -> Any:
    fn = _library("design_experiment")
    names = ctx.options.parameters or list(ctx.model.parameter_names)
    kw = _kwargs(ctx.options, "maneuver", "parameters")
    if "values" in ctx.inputs:
        kw["values"] = ctx.inputs["values"]
    return fn(ctx.model, ctx.options.maneuver.build(), names, seed=ctx.seed_int(2), **kw)


# -- frequency response and sensitivities --------------------------------------------------------


class FrequencyOptions(Options):
    """`aeroid.frequency_response` keywords."""

    inputs: list[str] | None = None
    outputs: list[str] | None = None
    nperseg: int | None = Field(None, ge=8)
    frequency_range: tuple[float, float] | None = None
    coherence_threshold: float | None = Field(None, ge=0, le=1)
    model_response: str | None = None
    min_coherent: int | None = Field(None, ge=1)


def _run_frequency(ctx: StageContext) -> Any:
    fn = _library("frequency_response")
    return fn(ctx.model, ctx.inputs["data"], ctx.inputs.get("parameters"), **_kwargs(ctx.options))


class SensitivityOptions(Options):
    """`aeroid.sensitivities` keywords (evaluated at the identified values when wired so)."""

    parameters: list[str] | None = None
    noise: dict[str, float] | None = None
    outputs: list[str] | None = None
    relative_step: float | None = Field(None, gt=0)


def _run_sensitivities(ctx: StageContext) -> Any:
    fn = _library("sensitivities")
    kw = _kwargs(ctx.options, "parameters")
    if "values" in ctx.inputs:
        kw["values"] = ctx.inputs["values"]
    return fn(ctx.model, ctx.inputs["data"], ctx.options.parameters, **kw)


# -- reports ---------------------------------------------------------------------------------


class ReportOptions(Options):
    """`aeroid.report` keywords for each flight's report."""

    title: str | None = None


def _run_report(ctx: StageContext) -> FlightReport:
    fn = _library("report")
    title = ctx.options.title or f"Flight {ctx.flight}"
    extra = {
        k: ctx.inputs[k]
        for k in ("experiment", "inference", "frequency", "filtering")
        if k in ctx.inputs
    }
    text = fn(
        ctx.inputs.get("validation"),
        ctx.inputs.get("identification"),
        ctx.inputs.get("propagation"),
        title=title,
        **extra,
    )
    return FlightReport(title=title, markdown=str(text))


class CampaignReportOptions(Options):
    """Options of the campaign report."""

    title: str | None = None
    include_flight_reports: bool = True
    figures: bool = True


def _fit_whiteness(validation: Any) -> tuple[str, str]:
    metrics = getattr(validation, "metrics", None)
    if not isinstance(metrics, Mapping) or not metrics:
        return "—", "—"
    fits, white = [], []
    for name, m in metrics.items():
        fit = getattr(m, "fit", None)
        if fit is not None:
            fits.append(f"{name} {float(fit):.1f}%")
        w = getattr(m, "white", getattr(m, "is_white", None))
        if w is None and getattr(m, "whiteness_pvalue", None) is not None:
            w = float(m.whiteness_pvalue) > 0.05
        if w is not None:
            white.append(f"{name} {'white' if w else 'coloured'}")
    return (", ".join(fits) or "—"), (", ".join(white) or "—")


def _condition(meta: Mapping[str, Any]) -> str:
    parts = []
    for key, unit in (("airspeed", "m/s"), ("dynamic_pressure", "Pa")):
        if key in meta:
            parts.append(f"{key.replace('_', ' ')} {float(meta[key]):.4g} {unit}")
    return ", ".join(parts) or str(meta.get("source", "—"))


def _campaign_brief(role: str, record: Any) -> Any:
    """What the campaign report uses of one flight's `role` input (see `Stage.brief`)."""
    if role == "data":
        return dict(getattr(record, "metadata", {}) or {})
    if role == "identification":
        return {
            "names": list(getattr(record, "parameter_names", ())),
            "parameters": dict(record.parameters),
            "stderr": dict(record.stderr),
            "success": bool(getattr(record, "success", True)),
        }
    if role == "validation":
        return _fit_whiteness(record)
    if role == "propagation":
        if getattr(record, "mean", None) is None:
            return "—"
        mean, std = float(np.ravel(record.mean)[0]), float(np.ravel(record.std)[0])
        return f"{mean:.4g} ± {std:.2g}"
    if role == "reports":
        return record.markdown
    return None  # the detailed figures' inputs: read whole, for the first flight only


# The campaign report is split into parts that run in parallel: parts 0 and 1 draw
# the cross-flight trend of the first and the second half of the parameters, part 2
# writes the tables and text (these three need every flight, so they run after the
# last one: as two figures the trend is drawn by two workers at once), and each
# further part draws one detailed figure of the first flight that was identified,
# as soon as that flight is done.
_DETAIL_FIGURES = (
    ("validation", "time histories"),
    ("identification", "fit residuals"),
    ("frequency", "bode"),
    ("inference", "posterior"),
    ("propagation", "propagation"),
    ("experiment", "design"),
    ("filtering", "filter states"),
)
_TRENDS, _TEXT, _FIRST_DETAIL = (0, 1), 2, 3


def _detail_roles(roles: Any) -> list[tuple[str, str]]:
    return [(role, label) for role, label in _DETAIL_FIGURES if role in roles]


def _campaign_parts(options: Any, roles: frozenset[str]) -> int:
    # 1 (not split) without figures
    if not options.figures or "identification" not in roles:
        return 1
    return _FIRST_DETAIL + len(_detail_roles(roles))


def _first_identified(ctx: StageContext) -> int | None:
    for i, r in enumerate(ctx.inputs.get("identification", ())):
        if r is not None:
            return i
    return None


def _campaign_part_flights(
    options: Any, roles: frozenset[str], index: int
) -> tuple[int, ...] | None:
    # the detailed figures read the first flight only; the trend and the text read all
    return None if index < _FIRST_DETAIL else (0,)


def _detail_figure(ctx: StageContext, index: int, flight: int) -> tuple[str, bytes] | None:
    from .._html import figure_png

    role, label = _detail_roles(ctx.inputs)[index - _FIRST_DETAIL]
    result = ctx.inputs[role][flight]
    if result is None or not hasattr(result, "plot"):
        return None
    return f"{ctx.flights[flight]}: {label}", figure_png(result.plot())


def _run_campaign_part(ctx: StageContext, index: int) -> Any:
    """Part `index` of the campaign report.

    The trend and the detailed figures return (title, PNG bytes) or None; the
    text part returns the `CampaignReport` without figures. A detailed figure
    part reads the first flight only; if that flight was not identified it
    returns its index, and `_combine_campaign` draws the figure for the first
    flight that was.
    """
    from .._html import figure_png
    from ..plotting import plot_campaign_trend

    if index == _TEXT:
        return _run_campaign_report(ctx)
    if index in _TRENDS:
        records = []
        for i, f in enumerate(ctx.flights):
            r = ctx.brief("identification", i)
            if r is not None:
                meta = ctx.brief("data", i)
                records.append(
                    {
                        "flight": f,
                        "parameters": r["parameters"],
                        "stderr": r["stderr"],
                        "metadata": {} if meta is None else meta,
                    }
                )
        names = list(dict.fromkeys(n for r in records for n in r["parameters"]))
        half = -(-len(names) // len(_TRENDS))
        names = names[index * half : (index + 1) * half]
        if not names:
            return None
        fig = plot_campaign_trend(records, parameters=names)
        return f"campaign: estimates across flights ({', '.join(names)})", figure_png(fig)
    if not ctx.flights:
        return None
    if ctx.inputs["identification"][0] is None:
        return index
    return _detail_figure(ctx, index, 0)


def _combine_campaign(ctx: StageContext, parts: list[Any]) -> CampaignReport:
    report = next((p for p in parts if isinstance(p, CampaignReport)), None)
    if report is None:
        report = _run_campaign_report(ctx)
    drawn = []
    for part in parts:
        if isinstance(part, CampaignReport):
            continue
        if isinstance(part, int):  # the first flight failed: draw for the first identified
            first = _first_identified(ctx)
            part = None if first is None else _detail_figure(ctx, part, first)
        if part is not None:
            drawn.append(part)
    return dataclasses.replace(
        report,
        figure_titles=tuple(t for t, _ in drawn),
        figures=tuple(png for _, png in drawn),
    )


def _run_campaign(ctx: StageContext) -> CampaignReport:
    # unsplit (a rerun, a pipeline run without Dask parts): the parts one after the
    # other, so the record is the one the parallel parts give
    n = _campaign_parts(ctx.options, frozenset(ctx.inputs))
    if n == 1:
        return _run_campaign_report(ctx)
    return _combine_campaign(ctx, [_run_campaign_part(ctx, i) for i in range(n)])


def _run_campaign_report(ctx: StageContext) -> CampaignReport:
    from .._records import markdown_table

    flights = ctx.flights
    ident = [ctx.brief("identification", i) for i in range(len(flights))]
    names: list[str] = []
    for r in ident:
        for n in r["names"] if r is not None else ():
            if n not in names:
                names.append(n)
    columns = ("flight", "condition", *names, "fit", "whiteness", "metric", "status")
    rows = []
    for i, f in enumerate(flights):
        r, v, meta = ident[i], ctx.brief("validation", i), ctx.brief("data", i)
        est = []
        for n in names:
            if r is not None and n in r["parameters"]:
                est.append(f"{r['parameters'][n]:.4g} ± {r['stderr'][n]:.2g}")
            else:
                est.append("—")
        fit, white = ("—", "—") if v is None else v
        metric = ctx.brief("propagation", i) or "—"
        status = ctx.failures.get(f, "ok")
        if status == "ok" and r is not None and not r["success"]:
            status = "not converged"
        rows.append(
            (f, "—" if meta is None else _condition(meta), *est, fit, white, metric, status)
        )
    title = ctx.options.title or "Campaign report"
    parts = [f"# {title}", "", f"{len(flights)} flights, {len(ctx.failures)} failed.", ""]
    parts.append(markdown_table(columns, rows))
    if ctx.failures:
        parts += ["", "## Failures", ""]
        parts += [f"- **{f}**: {err}" for f, err in ctx.failures.items()]
    if ctx.options.include_flight_reports:
        for i in range(len(flights)):
            text = ctx.brief("reports", i)
            if text is not None:
                # demote the per-flight headings under the campaign's
                text = "\n".join(
                    "#" + line if line.startswith("#") else line for line in text.splitlines()
                )
                parts += ["", text]
    return CampaignReport(
        title=title,
        markdown="\n".join(parts) + "\n",
        flights=tuple(flights),
        columns=columns,
        rows=tuple(tuple(r) for r in rows),
        failures=dict(ctx.failures),
    )


for _stage in (
    Stage(
        "load",
        "1",
        LoadOptions,
        "FlightData",
        _run_load,
        uses_model=False,
        library="load_flight_test",
    ),
    Stage(
        "identify",
        "2",
        IdentifyOptions,
        "IdentificationResult",
        _run_identify,
        library="identify",
        # imported by `identify` when it runs: once before the workers fork, not in each
        preload=("aeroid._output_error", "aeroid._filter_error"),
    ),
    # 2 (filter, infer, frequency, sensitivities): start from the fit's initial state;
    # identify 2: results name the records they were fitted to
    Stage("filter", "2", FilterOptions, "FilterResult", _run_filter, library="filter_states"),
    Stage(
        "validate",
        "1",
        ValidateOptions,
        "ValidationResult",
        _run_validate,
        library="validate",
    ),
    Stage(
        "propagate",
        "1",
        PropagateOptions,
        "PropagationResult",
        _run_propagate,
        uses_model=False,
        seeded=True,
        library="propagate",
        preload=("aeroid._progress",),
        parts=_propagate_parts,
        run_part=_run_propagate_part,
        combine=_combine_propagate,
    ),
    Stage(
        "infer",
        "2",
        InferOptions,
        "InferenceResult",
        _run_infer,
        seeded=True,
        library="infer",
        preload=("aeroid._progress",),
        parts=_infer_parts,
        run_part=_run_infer_part,
        combine=_combine_infer,
    ),
    Stage(
        "design",
        "1",
        DesignOptions,
        "ExperimentDesign",
        _run_design,
        seeded=True,
        library="design_experiment",
        preload=("aeroid._progress",),
    ),
    Stage(
        "frequency",
        "3",  # 3: only frequencies whose coherence beats chance and that the input excites
        FrequencyOptions,
        "FrequencyResponseResult",
        _run_frequency,
        library="frequency_response",
    ),
    Stage(
        "sensitivities",
        "2",
        SensitivityOptions,
        "SensitivityResult",
        _run_sensitivities,
        library="sensitivities",
    ),
    Stage(
        "report",
        "2",  # 2: a section's summary no longer repeats the section heading
        ReportOptions,
        "FlightReport",
        _run_report,
        uses_model=False,
        library="report",
    ),
    Stage(
        "campaign_report",
        # 3: figures with fixed margins; 4: corner plot with shared axes (other bytes);
        # 5: the trend across flights as two figures, drawn in parallel
        "5",
        CampaignReportOptions,
        "CampaignReport",
        _run_campaign,
        uses_model=False,
        per_flight=False,
        parts=_campaign_parts,
        run_part=_run_campaign_part,
        combine=_combine_campaign,
        part_flights=_campaign_part_flights,
        preload=("aeroid.plotting", "aeroid._html"),
        brief=_campaign_brief,
    ),
):
    register_stage(_stage)
