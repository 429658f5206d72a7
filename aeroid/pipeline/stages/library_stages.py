"""The stages that wrap aeroid's library functions: stored inputs -> one call -> a record.

Each stage imports the function it calls from its module (inside the stage,
so that planning an unchanged campaign imports no numerics). Its options
model is built on `library_fields`: the fields are the function's keywords,
typed from its signature; only what the engine itself uses (a metric's name,
how many parallel parts to run; ``engine_only``) and what a config describes
in its own terms (priors, a manoeuvre) are declared here.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Literal

from pydantic import AfterValidator, AliasChoices, Field, field_validator, model_validator

from ...errors import AeroidError
from ..plans.config import Options
from . import FlightReport, Stage, StageContext, register_stage
from .config_specs import _ERROR_BARS, _GRADIENT, _SIMULATE, ManeuverSpec, PriorSpec
from .load_stage import HoldoutSpec, LoadOptions, flight_data, outside_holdout, record_start
from .metrics import METRICS, damping_ratio, metric, natural_frequency, static_margin
from .signature_options import library_fields

__all__ = [
    "METRICS",
    "DesignOptions",
    "FilterOptions",
    "FrequencyOptions",
    "IdentifyOptions",
    "InferOptions",
    "LoadOptions",
    "PropagateOptions",
    "ReportOptions",
    "SensitivityOptions",
    "ValidateOptions",
    "damping_ratio",
    "natural_frequency",
    "static_margin",
]


def _kwargs(options: Options, *exclude: str) -> dict[str, Any]:
    return options.library_kwargs(exclude=exclude)


# -- identify / filter / validate ----------------------------------------------------


def _distinct(value: Any) -> Any:
    """Names listed once each: a repeat is a typo the library would refuse per flight."""
    repeated = sorted({n for n in value or () if list(value).count(n) > 1})
    if repeated:
        raise ValueError(f"{repeated} listed more than once")
    return value


_NAMES: Any = (  # names to estimate (not starting values)
    Annotated[list[str] | None, AfterValidator(_distinct)],
    Field(None),
)
_BY_NAME: Any = (dict[str, float] | None, Field(None))


class IdentifyOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.estimation.identification:identify",
        *("parameters", "method", "outputs", "x0", "estimate_x0", "estimate_bias", "weights"),
        *("error_bars", "max_iterations", "tolerance", "gradient", "process_noise"),
        *("measurement_noise", "simulate_options", "bounds", "filter_options"),
        *("estimate_process_noise", "time_delays", "start"),
        parameters=_NAMES,
        method=(Literal["output_error", "filter_error"] | None, Field(None)),
        x0=_BY_NAME,
        weights=_BY_NAME,
        process_noise=_BY_NAME,
        measurement_noise=_BY_NAME,
        simulate_options=_SIMULATE,
        gradient=_GRADIENT,
        error_bars=_ERROR_BARS,
        max_iterations=Field(None, ge=1),
        tolerance=Field(None, gt=0),
        # parameter -> [lower, upper], null for an open side (YAML: {M_q: [null, 0.0]})
        bounds=(dict[str, tuple[float | None, float | None]] | None, Field(None)),
    )
):
    """`aeroid.identify` keywords (``parameters``: names to estimate; default all);
    ``holdout`` (as the validate stage's) keeps that part of the record out of the fit,
    which then uses the data before and after it as records of their own, so that
    validate's prediction of the same part is a check on data the fit never saw."""

    holdout: HoldoutSpec | None = None

    # unset, they leave the keys of results stored before they existed unchanged
    added_later: ClassVar[frozenset[str]] = frozenset(
        {"bounds", "filter_options", "estimate_process_noise", "time_delays", "start", "holdout"}
    )
    engine_only: ClassVar[frozenset[str]] = frozenset({"holdout"})

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
    from ...estimation.identification import identify

    # None: every parameter; an empty list is the library's (biases or states only)
    given = ctx.options.parameters
    names = list(ctx.model.parameter_names) if given is None else list(given)
    data = flight_data(ctx)
    if ctx.options.holdout is not None:
        data = outside_holdout(data, ctx.options.holdout)
    kw = _kwargs(ctx.options, "parameters", "holdout")
    return identify(ctx.model, data, names, **kw)


class FilterOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.estimation.filtering:filter_states",
        *("process_noise", "measurement_noise", "method", "smooth", "control_interpolation"),
        process_noise=(dict[str, float], Field()),
        measurement_noise=(dict[str, float], Field()),
    )
):
    """`aeroid.filter_states` keywords (both noise levels are required, as there)."""

    # unset, it leaves the keys of results stored before it existed unchanged
    added_later: ClassVar[frozenset[str]] = frozenset({"control_interpolation"})


def _run_filter(ctx: StageContext) -> Any:
    from ...estimation.filtering import filter_states

    return filter_states(
        ctx.model, ctx.inputs["data"], ctx.inputs.get("parameters"), **_kwargs(ctx.options)
    )


class ValidateOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.validation:validate",
        "confidence",
        "whiteness_lags",
        "holdout",
        "holdout_start",
        "simulate_options",
        simulate_options=_SIMULATE,
        confidence=Field(None, gt=0, lt=1),
        whiteness_lags=Field(None, ge=1),
        holdout=(HoldoutSpec | None, Field(None)),
    )
):
    """`aeroid.validate` keywords (``simulate_options``: as the fit's, its controls')."""

    # unset, it leaves the keys of results stored before it existed unchanged
    added_later: ClassVar[frozenset[str]] = frozenset({"simulate_options", "holdout_start"})


def _run_validate(ctx: StageContext) -> Any:
    from ...uncertainty.validation import validate

    return validate(
        ctx.model, flight_data(ctx), ctx.inputs.get("parameters"), **_kwargs(ctx.options)
    )


# -- propagate ------------------------------------------------------------------------


class PropagateOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.propagation:propagate",
        "n_samples",
        "percentiles",
        # bounded so a typo cannot queue a run of days (1e7 draws is minutes per flight)
        n_samples=Field(None, ge=1, le=10_000_000),
    )
):
    """`aeroid.propagate` keywords; ``metric`` is a built-in name or ``pkg.mod:function``;
    ``n_batches`` splits the draws into batches run in parallel (same result)."""

    metric: str = "natural_frequency"
    n_batches: int | None = Field(None, ge=1, le=10_000)

    execution_only: ClassVar[frozenset[str]] = frozenset({"n_batches"})
    engine_only: ClassVar[frozenset[str]] = frozenset({"metric", "n_batches"})
    # names of code to import (``module:function``): only with the user's consent
    code_fields: ClassVar[frozenset[str]] = frozenset({"metric"})


def _run_propagate(ctx: StageContext) -> Any:
    from ...uncertainty.propagation import propagate

    fn, kw = metric(ctx.options.metric, ctx.code_dir), _kwargs(ctx.options, "metric", "n_batches")
    return propagate(ctx.inputs["result"], fn, seed=ctx.seed_int(0), **kw)


def _n_draws(options: Any) -> int:
    if options.n_samples is not None:
        return int(options.n_samples)
    from ...uncertainty.propagation import propagate

    return int(inspect.signature(propagate).parameters["n_samples"].default)


def _propagate_parts(options: Any, roles: frozenset[str]) -> int:
    return min(int(options.n_batches or 1), _n_draws(options))


def _run_propagate_part(ctx: StageContext, index: int) -> Any:
    from ...uncertainty.propagation import propagate_batch

    n, k = _n_draws(ctx.options), _propagate_parts(ctx.options, frozenset(ctx.inputs))
    start, stop = index * n // k, (index + 1) * n // k
    fn = metric(ctx.options.metric, ctx.code_dir)
    result = ctx.inputs["result"]
    return propagate_batch(result, fn, start=start, n_samples=stop - start, seed=ctx.seed_int(0))


def _combine_propagate(ctx: StageContext, parts: list[Any]) -> Any:
    from ...uncertainty.propagation import combine_batches

    return combine_batches(parts, **_kwargs(ctx.options, "metric", "n_batches", "n_samples"))


# -- infer ------------------------------------------------------------------------------


class InferOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.inference:infer",
        *("noise", "n_walkers", "n_steps", "n_ensembles", "burn_in", "thin", "stretch"),
        *("move", "outputs", "backend", "simulate_options"),
        n_walkers=Field(None, ge=2, le=100_000),
        n_steps=Field(None, ge=1, le=10_000_000),
        n_ensembles=Field(None, ge=1, le=1_000),
        burn_in=Field(None, ge=0),
        thin=Field(None, ge=1),
        stretch=Field(None, gt=1),
        move=(Literal["stretch", "de", "demcz"] | None, Field(None)),
        simulate_options=_SIMULATE,
    )
):
    """`aeroid.infer` keywords: ``parameters``, the prior of each parameter by name (once
    called ``priors``, still accepted); ``initial``: start at the fit."""

    # the library takes `Prior` objects: a config describes each (`PriorSpec`)
    parameters: dict[str, PriorSpec] = Field(validation_alias=AliasChoices("parameters", "priors"))
    initial: bool = True

    added_later: ClassVar[frozenset[str]] = frozenset({"move", "simulate_options"})
    # `initial` here says whether to start at the fit (the library takes the fit itself)
    engine_only: ClassVar[frozenset[str]] = frozenset({"initial"})
    # old name -> name: accepted in configs (with a warning) and in stored tasks
    renamed: ClassVar[dict[str, str]] = {"priors": "parameters"}

    def key_document(self) -> dict[str, Any]:
        # keyed under the old name: results stored before the rename keep their keys
        doc = super().key_document()
        return {("priors" if k == "parameters" else k): v for k, v in doc.items()}


def _infer_kwargs(ctx: StageContext) -> dict[str, Any]:
    kw = _kwargs(ctx.options, "parameters", "initial", "n_ensembles")
    if ctx.options.initial and "initial" in ctx.inputs:
        kw["initial"] = ctx.inputs["initial"]
    kw["parameters"] = {name: spec.build(name) for name, spec in ctx.options.parameters.items()}
    # ensemble e draws from SeedSequence(seed, spawn_key=(flight, 1, e))
    kw["seed"] = ctx.seed_sequence(1)
    return kw


def _infer_model(ctx: StageContext) -> Any:
    """The model with the parameters not inferred held at the fit (not at their nominal
    values): a posterior of a few parameters is conditional on the others."""
    fit = ctx.inputs.get("initial")
    values = getattr(fit, "parameters", None)
    model = ctx.model
    nominal = getattr(model, "parameters", None)
    if not isinstance(values, Mapping) or not isinstance(nominal, Mapping):
        return model
    held = {k: float(values[k]) for k in nominal if k in values}
    if not held or not dataclasses.is_dataclass(model) or isinstance(model, type):
        return model
    return dataclasses.replace(model, parameters={**nominal, **held})


def _run_infer(ctx: StageContext) -> Any:
    from ...uncertainty.inference import infer

    kw = _infer_kwargs(ctx)
    if ctx.options.n_ensembles is not None:
        kw["n_ensembles"] = ctx.options.n_ensembles
    return infer(_infer_model(ctx), ctx.inputs["data"], **kw)


def _infer_parts(options: Any, roles: frozenset[str]) -> int:
    return int(options.n_ensembles or 1)


def _run_infer_part(ctx: StageContext, ensemble: int) -> Any:
    from ...uncertainty.inference import infer_ensemble

    data = ctx.inputs["data"]
    return infer_ensemble(_infer_model(ctx), data, ensemble=ensemble, **_infer_kwargs(ctx))


def _combine_infer(ctx: StageContext, parts: list[Any]) -> Any:
    from ...uncertainty.inference import combine_ensembles

    return combine_ensembles(parts)


# -- design -------------------------------------------------------------------------------


class DesignOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.design:design_experiment",
        *("parameters", "criterion", "noise", "duration", "sample_rate", "optimizer_options"),
        parameters=_NAMES,
        duration=Field(None, gt=0),
        sample_rate=Field(None, gt=0),
    )
):
    """`aeroid.design_experiment` keywords (designed at the identified values);
    ``at_record_start`` flies the design from the flight's own trim: the identified
    initial state of its record (else its first sample) and its controls' first samples,
    to which the manoeuvre adds (a nonlinear model; a perturbation model starts at zero)."""

    # the library takes a manoeuvre family: a config describes one (`ManeuverSpec`)
    maneuver: ManeuverSpec
    at_record_start: bool = False

    engine_only: ClassVar[frozenset[str]] = frozenset({"at_record_start"})

    @model_validator(mode="after")
    def _designable(self) -> DesignOptions:
        # what design_experiment would refuse at run time, found before any run
        from ...support import optimizer_settings

        try:
            optimizer_settings(self.optimizer_options)
        except AeroidError as exc:
            raise ValueError(str(exc)) from None
        if not self.maneuver.build().variable_names:
            raise ValueError(
                f"maneuver: a {self.maneuver.type} with every option fixed has nothing to "
                "design; give a (low, high) range for at least one of its options"
            )
        return self


def _run_design(ctx: StageContext) -> Any:
    from ...uncertainty.design import design_experiment

    # None: every parameter; an empty list is the library's (biases or states only)
    given = ctx.options.parameters
    names = list(ctx.model.parameter_names) if given is None else list(given)
    kw = _kwargs(ctx.options, "maneuver", "parameters", "at_record_start")
    if "values" in ctx.inputs:
        kw["values"] = ctx.inputs["values"]
    if ctx.options.at_record_start:
        kw.update(record_start(ctx))
    return design_experiment(
        ctx.model, ctx.options.maneuver.build(), names, seed=ctx.seed_int(2), **kw
    )


# -- frequency response and sensitivities --------------------------------------------------------


class FrequencyOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.response:frequency_response",
        "inputs",
        "outputs",
        "nperseg",
        "frequency_range",
        "coherence_threshold",
        "model_response",
        "min_coherent",
        nperseg=Field(None, ge=8),
        coherence_threshold=Field(None, ge=0, le=1),
        min_coherent=Field(None, ge=1),
    )
):
    """`aeroid.frequency_response` keywords."""


def _run_frequency(ctx: StageContext) -> Any:
    from ...frequency.response import frequency_response

    kw = _kwargs(ctx.options)
    # the model's own transfer function where it has one, a smooth curve under the points
    kw.setdefault("model_response", "auto")
    return frequency_response(ctx.model, ctx.inputs["data"], ctx.inputs.get("parameters"), **kw)


class SensitivityOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.sensitivity:sensitivities",
        "parameters",
        "noise",
        "outputs",
        "relative_step",
        # the library also takes a mapping of values or a record; a config names parameters
        parameters=(list[str] | None, Field(None)),
        relative_step=Field(None, gt=0),
    )
):
    """`aeroid.sensitivities` keywords (evaluated at the identified values when wired so)."""


def _run_sensitivities(ctx: StageContext) -> Any:
    from ...uncertainty.sensitivity import sensitivities

    kw = _kwargs(ctx.options, "parameters")
    if "values" in ctx.inputs:
        kw["values"] = ctx.inputs["values"]
    return sensitivities(ctx.model, ctx.inputs["data"], ctx.options.parameters, **kw)


# -- reports ---------------------------------------------------------------------------------


class ReportOptions(library_fields("aeroid.reports.reporting:report", "title")):  # type: ignore[misc]
    """`aeroid.report` keywords for each flight's report."""


def _run_report(ctx: StageContext) -> FlightReport:
    from ...reports.reporting import report

    title = ctx.options.title or f"Flight {ctx.flight}"
    extra = {
        k: ctx.inputs[k]
        for k in ("experiment", "inference", "frequency", "filtering")
        if k in ctx.inputs
    }
    text = report(
        ctx.inputs.get("validation"),
        ctx.inputs.get("identification"),
        ctx.inputs.get("propagation"),
        title=title,
        **extra,
    )
    from .analysis_stages import quality_section, report_sections

    text = str(text)
    quality = quality_section(ctx.inputs, ctx.source)
    if quality:
        # what arrived comes first: after the title, before the results drawn from it
        head, sep, rest = text.partition("\n\n")
        text = f"{head}\n\n{quality}\n{rest}" if sep else f"{text.rstrip()}\n\n{quality}"
    more = report_sections(ctx.inputs)
    text = f"{text.rstrip()}\n\n{more}" if more else text
    return FlightReport(title=title, markdown=text)


for _stage in (
    Stage(
        "identify",
        # 3: results carry the model's parameter units; 4: standard errors without the
        # t widening, their degrees of freedom carried
        # 5: the one least-squares solver; filter error on a nonlinear model with a
        #    steady-state gain by default
        # 6: the filter error's likelihood and information summed in another order
        #    (rounding: a fit stopped by its tolerance may stop an iteration apart)
        # 7: the filter error's derivatives by forward differences; 8: it holds a process noise the likelihood no longer feels out
        #    of its steps (a fit whose noise vanishes takes fewer, other steps)
        # 9: coloured-residual degrees of freedom with the low band's exact covariance
        # 10: the filter error's Riccati inverses refined by Newton-Schulz steps and its
        #     information summed by matrix products (rounding)
        # 11: the filter error's process noise started from the state equations'
        #     residuals, its steps extrapolated or a noise's held to a decade (other steps)
        # 12: output error estimates the measured initial states by default
        # 13: output error's coloured bars carry its estimated weights' scatter
        # 14: RK4 substeps read along the path too (a model stiffening away)
        # 15: `parameters: []` is the library's empty list, not every parameter
        # 16: filter error's gradient by the chain rule; the information inverted on a
        #     unit diagonal (bars of parameters of very different sizes; rounding)
        # 17: results carry the fitted channels' units; 18: q c/2V per rad, US units
        "18",
        IdentifyOptions,
        "IdentificationResult",
        _run_identify,
    ),
    # 2 (filter, infer, frequency, sensitivities): start from the fit's initial state;
    # identify 2: results name the records they were fitted to
    # filter 3: the compiled EKF's matrix exponential is the numpy pass's Padé 13 (rounding);
    # 4: its RK4 substeps read along the record's measured states too
    Stage("filter", "4", FilterOptions, "FilterResult", _run_filter),
    Stage(
        "validate",
        # 2: units the model declares where the record gives none;
        # 3: the prediction of held-out data (`holdout`) in the result; 4: RK4 substeps
        # read along the simulated path too (as every stage that simulates: a model
        # that stiffens away from its start); 5: residuals and inputs prewhitened before
        # their cross-correlation, the bias interval on Student's t
        "6",  # 6: a fit's state-equation biases replayed on its record
        ValidateOptions,
        "ValidationResult",
        _run_validate,
    ),
    Stage(
        "propagate",
        "2",  # 2: draws keep each parameter's t degrees of freedom, as its interval()
        PropagateOptions,
        "PropagationResult",
        _run_propagate,
        uses_model=False,
        seeded=True,
        parts=_propagate_parts,
        run_part=_run_propagate_part,
        combine=_combine_propagate,
    ),
    Stage(
        "infer",
        # 3: parameters not inferred held at the fit; 4: the sampler's simulations compiled
        # from the first (log-densities equal to rounding, the same draws); 5: RK4 substeps;
        # 6: the residuals' colour at the best draw recorded
        "6",
        InferOptions,
        "InferenceResult",
        _run_infer,
        seeded=True,
        parts=_infer_parts,
        run_part=_run_infer_part,
        combine=_combine_infer,
    ),
    Stage(
        "design",
        # 2: the flight's record as an input (at_record_start), trim controls; 3: RK4;
        # 4: a multisine is Schroeder's cosine sum, started at a zero crossing
        "5",  # 5: phases in frequency order, lines in bounds, a fit's delays, failures
        DesignOptions,
        "ExperimentDesign",
        _run_design,
        seeded=True,
    ),
    Stage(
        "frequency_response",  # once "frequency"
        # 3: only frequencies whose coherence beats chance and that the input excites;
        # 4: the model's exact response by default where it is linear time-invariant;
        # 5: else the transfer function of the model linearised at the record's start;
        # 6: one response record (rad/s, complex responses; dB and degrees derived); 7: RK4
        "7",
        FrequencyOptions,
        "FrequencyResponseResult",
        _run_frequency,
        stored_as="frequency",
    ),
    Stage(
        "sensitivities",
        "4",  # 3: RK4 substeps along the path; 4: at a fit, replayed as fitted, its bars
        SensitivityOptions,
        "SensitivityResult",
        _run_sensitivities,
    ),
    Stage(
        "report",
        # 2: a section's summary no longer repeats the section heading; 3: the loaded
        # data's quality checks (role data); 4: a clean record's checks in one line;
        # 5: equivalent systems and bandwidths state their handling-qualities Level;
        # 6: parameter correlations and residual autocorrelation against its band;
        # 7: the filtered or smoothed states' standard deviations with their units
        # 8: the flight's name and file as they are now (a renamed file's data reused)
        # 9: units guessed only where the record's units make them right, marked so;
        #    the fitted outputs named
        # 10: undefined values as a dash; coherent mean coherence; biases and noise tabled
        "11",  # 11: nondimensional rates' derivatives per rad; feet where the model is
        ReportOptions,
        "FlightReport",
        _run_report,
        uses_model=False,
        names_flight=True,
        # the residuals' autocorrelation is the plotting module's
        imports=("aeroid.reports.plotting",),
    ),
):
    register_stage(_stage)
