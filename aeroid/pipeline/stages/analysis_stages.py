"""Stages of the analyses around the fit: data compatibility, regression, frequency-domain
identification and handling qualities (one library function per stage, as in
`library_stages`, whose conventions these follow)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import Field, model_validator

from ...errors import PipelineError
from ..plans.config import Options
from ..storage.codec import register_record
from . import Stage, StageContext, register_stage
from .config_specs import _ERROR_BARS
from .load_stage import flight_data
from .signature_options import library_fields

__all__ = [
    "CompatibilityOptions",
    "FrequencyIdOptions",
    "FrequencyIdentifyOptions",
    "HandlingQualities",
    "HandlingQualitiesOptions",
    "RegressOptions",
    "TransferFunctionOptions",
]


# types narrower than the library's: the values it names, a list of numbers (not an array)
_FREQUENCIES: Any = (list[float] | None, Field(None))


def _kwargs(options: Options, *exclude: str) -> dict[str, Any]:
    return options.library_kwargs(exclude=exclude)


# -- compatibility ---------------------------------------------------------------------------


class CompatibilityOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.estimation.compatibility:check_compatibility",
        *("channels", "estimate", "fixed", "x0", "gravity", "error_bars", "max_iterations"),
        *("tolerance", "max_passes", "input_noise", "n_draws"),
        gravity=Field(None, gt=0),
        error_bars=_ERROR_BARS,
        max_iterations=Field(None, ge=1),
        tolerance=Field(None, gt=0),
        max_passes=Field(None, ge=1),
        n_draws=Field(None, ge=1),
    )
):
    """`aeroid.check_compatibility` keywords (the seed is the campaign's)."""


def _run_compatibility(ctx: StageContext) -> Any:
    from ...estimation.compatibility import check_compatibility

    return check_compatibility(ctx.inputs["data"], seed=ctx.seed_int(3), **_kwargs(ctx.options))


# -- regression ------------------------------------------------------------------------------

_STEPWISE_ONLY = ("forced", "f_in", "f_out", "orthogonalize", "max_steps")


class RegressOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.estimation.regression:stepwise_regression",
        *("response", "candidates", "forced", "intercept", "f_in", "f_out", "orthogonalize"),
        *("error_bars", "max_steps"),
        # `response` may be an array, `candidates` any mapping, in the library: here names
        response=(str, Field()),
        candidates=(list[str] | dict[str, str] | None, Field(None)),
        f_in=Field(None, gt=0),
        f_out=Field(None, gt=0),
        error_bars=_ERROR_BARS,
        max_steps=Field(None, ge=1),
    )
):
    """`aeroid.stepwise_regression` keywords; ``method: equation_error`` fits the
    ``candidates`` as given (`aeroid.equation_error`'s regressors) instead."""

    method: Literal["stepwise", "equation_error"] = "stepwise"

    engine_only: ClassVar[frozenset[str]] = frozenset({"method"})

    @model_validator(mode="after")
    def _stepwise_only(self) -> RegressOptions:
        given = [n for n in _STEPWISE_ONLY if getattr(self, n) is not None]
        if self.method == "equation_error" and given:
            raise ValueError(f"{', '.join(given)}: only for method stepwise")
        return self


def _run_regress(ctx: StageContext) -> Any:
    from ...estimation.regression import equation_error, stepwise_regression

    opts = ctx.options
    kw = _kwargs(opts, "response", "candidates", "method")
    if opts.method == "equation_error":
        return equation_error(flight_data(ctx), opts.response, opts.candidates, **kw)
    return stepwise_regression(flight_data(ctx), opts.response, opts.candidates, **kw)


# -- frequency-domain identification -----------------------------------------------------------


class FrequencyIdOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.frequency_id:composite_response",
        *("inputs", "outputs", "frequencies", "windows", "overlap", "frequency_range"),
        # the library also takes one name; a config lists them
        inputs=(list[str], Field()),
        outputs=(list[str], Field()),
        frequencies=_FREQUENCIES,
        overlap=Field(None, ge=0, le=0.95),
    )
):
    """`aeroid.composite_response` keywords (frequencies and ranges in rad/s, windows in s)."""


def _run_frequency_id(ctx: StageContext) -> Any:
    from ...frequency.frequency_id import composite_response

    opts = ctx.options
    kw = _kwargs(opts, "inputs", "outputs")
    return composite_response(flight_data(ctx), opts.inputs, opts.outputs, **kw)


class TransferFunctionOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.frequency_id:fit_transfer_function",
        *("numerator_order", "denominator_order", "delay", "frequency_range", "input"),
        *("output", "start", "weighting", "min_coherence"),
        numerator_order=(int, Field(ge=0)),
        denominator_order=(int, Field(ge=1)),
        min_coherence=Field(None, ge=0, le=1),
    )
):
    """`aeroid.fit_transfer_function` keywords, fitted to the frequency_id response."""


def _run_transfer_function(ctx: StageContext) -> Any:
    from ...frequency.frequency_id import fit_transfer_function

    return fit_transfer_function(ctx.inputs["response"], **_kwargs(ctx.options))


class FrequencyIdentifyOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.frequency_domain:identify_frequency_domain",
        *("parameters", "frequencies", "method", "outputs", "boundary", "error_bars"),
        *("noise", "reference", "max_iterations", "tolerance", "weighting", "delays"),
        # names to estimate (the library also takes starting values)
        parameters=(list[str] | None, Field(None)),
        frequencies=_FREQUENCIES,
        method=(Literal["output_error", "equation_error"] | None, Field(None)),
        error_bars=_ERROR_BARS,
        max_iterations=Field(None, ge=1),
        tolerance=Field(None, gt=0),
        weighting=(Literal["sidpac", "hermitian", "real"] | None, Field(None)),
    )
):
    """`aeroid.identify_frequency_domain` keywords (``parameters``: names to estimate;
    default all; ``frequencies`` in rad/s)."""


def _run_frequency_identify(ctx: StageContext) -> Any:
    from ...frequency.frequency_domain import identify_frequency_domain

    # None: every parameter; an empty list is the library's (biases or states only)
    given = ctx.options.parameters
    names = list(ctx.model.parameter_names) if given is None else list(given)
    kw = _kwargs(ctx.options, "parameters")
    return identify_frequency_domain(ctx.model, flight_data(ctx), names, **kw)


# -- handling qualities -------------------------------------------------------------------------


@register_record(name="HandlingQualities")
@dataclass(frozen=True, eq=False)
class HandlingQualities:
    """Handling-qualities metrics of one measured response (those configured; else None)."""

    bandwidth: Any = None
    equivalent_system: Any = None
    margins: Any = None

    def summary(self) -> str:
        # each part's summary carries its own heading
        parts = (self.bandwidth, self.equivalent_system, self.margins)
        return "\n\n".join(p.summary() for p in parts if p is not None)


class EquivalentSystemSpec(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.handling_qualities:equivalent_system",
        *("kind", "frequency_range", "delay", "start"),
        kind=(Literal["short_period", "roll", "dutch_roll"] | None, Field(None)),
    )
):
    """`aeroid.equivalent_system` keywords (the pair is the handling_qualities stage's)."""


class HandlingQualitiesOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.frequency.handling_qualities:bandwidth",
        *("kind", "input", "output"),
        kind=(Literal["attitude", "rate"] | None, Field(None)),
    )
):
    """`aeroid.bandwidth` keywords (``kind``: attitude or rate) for the response pair
    ``input`` -> ``output``; ``equivalent_system``: `aeroid.equivalent_system` keywords
    to fit a low-order equivalent system too; ``margins``: the pair is a broken-loop
    response, so report `aeroid.stability_margins` too. ``bandwidth: false`` skips it."""

    bandwidth: bool = True
    equivalent_system: EquivalentSystemSpec | None = None
    margins: bool = False
    engine_only: ClassVar[frozenset[str]] = frozenset({"bandwidth", "equivalent_system", "margins"})

    @model_validator(mode="after")
    def _something(self) -> HandlingQualitiesOptions:
        if not self.bandwidth and self.equivalent_system is None and not self.margins:
            raise ValueError("bandwidth, equivalent_system and margins are all off")
        return self


def _run_handling_qualities(ctx: StageContext) -> HandlingQualities:
    from ...frequency.handling_qualities import bandwidth, equivalent_system, stability_margins

    opts = ctx.options
    response = ctx.inputs.get("response")
    if response is None:
        raise PipelineError("handling_qualities needs the frequency_id stage's response")
    pair: Mapping[str, Any] = {"input": opts.input, "output": opts.output}
    bw = eq = margins = None
    if opts.bandwidth:
        bw = bandwidth(response, **_kwargs(opts, "bandwidth", "equivalent_system", "margins"))
    if opts.equivalent_system is not None:
        eq = equivalent_system(response, **pair, **_kwargs(opts.equivalent_system))
    if opts.margins:
        margins = stability_margins(response, **pair)
    return HandlingQualities(bandwidth=bw, equivalent_system=eq, margins=margins)


# what the campaign table shows of each flight's handling qualities: (label, unit)
_HQ_UNITS = {
    "bandwidth": "rad/s",
    "phase delay": "s",
    "gain margin": "dB",
    "phase margin": "deg",
    "mismatch": "-",
    "omega": "rad/s",
    "zeta": "-",
    "1/T_theta2": "1/s",
    "1/T_R": "1/s",
    "tau": "s",
    "LOES level": "MIL-STD-1797A",
    "bandwidth level": "Cat. A",
}


def hq_brief(record: Any) -> dict[str, float]:
    """The scalar handling-qualities metrics of one flight, by label."""
    out: dict[str, float] = {}
    bw, eq, margins = record.bandwidth, record.equivalent_system, record.margins
    if bw is not None:
        out.update({"bandwidth": bw.bandwidth, "phase delay": bw.phase_delay})
        level = getattr(bw, "level", None)
        if level is not None:
            out["bandwidth level"] = float(level.level)
    if eq is not None:
        out.update({n: float(v) for n, v in eq.parameters.items() if n != "K"})
        out["mismatch"] = float(eq.mismatch)
        level = getattr(eq, "level", None)
        if level is not None:
            out["LOES level"] = float(level.level)
    if margins is not None:
        out.update({"gain margin": margins.gain_margin, "phase margin": margins.phase_margin})
    return {k: float(v) for k, v in out.items()}


def hq_table(flights: list[str], conditions: list[str], briefs: list[Any]) -> list[str]:
    """The handling qualities of every flight against its condition (none: no lines)."""
    labels = list(dict.fromkeys(k for b in briefs if b for k in b))
    if not labels:
        return []
    from ...support import markdown_table

    columns = ("flight", "condition", *(f"{k} [{_HQ_UNITS.get(k, '-')}]" for k in labels))
    rows = [
        (f, c, *(f"{b[k]:.4g}" if b and k in b else "—" for k in labels))
        for f, c, b in zip(flights, conditions, briefs, strict=True)
    ]
    notes = [
        f"- {f}: 1/T_theta2 = {b['1/T_theta2']:.4g} 1/s is a right-half-plane zero, not a "
        "physical pitch response: the equivalent system (and its Level) is suspect."
        for f, b in zip(flights, briefs, strict=True)
        if b and b.get("1/T_theta2", 0.0) < 0
    ]
    notes += [
        f"- {f}: negative equivalent time delay ({b['tau']:.4g} s)."
        for f, b in zip(flights, briefs, strict=True)
        if b and b.get("tau", 0.0) < 0
    ]
    return [
        "### Handling qualities",
        "",
        "Bandwidth and phase delay of the measured response, the low-order equivalent "
        "system fitted to it and its mismatch, and the loop's margins, per flight condition. "
        "Levels: the short-period equivalent system against MIL-STD-1797A's limits (as "
        "SIDPAC's milstd states them); bandwidth and phase delay against the Category A "
        "boundaries digitised in BandwidthCrit.m (C. Regan, NASA, 2006), which its author "
        "marks unchecked.",
        "",
        markdown_table(columns, rows),
        "",
        *([*notes, ""] if notes else []),
    ]


# report role -> the section heading a flight's report gives that result
REPORT_SECTIONS: dict[str, str] = {
    "compatibility": "Data compatibility",
    "regression": "Regression",
    "composite_response": "Frequency responses",
    "transfer_function": "Transfer-function fit",
    "frequency_domain": "Frequency-domain identification",
    "handling_qualities": "Handling qualities",
}


def quality_section(inputs: Mapping[str, Any], source: Mapping[str, Any] | None = None) -> str:
    """The data-quality checks of the loaded data (role ``data``), when it has them,
    naming the flight's file as it is now (`source`: a renamed file's data are reused)."""
    quality = getattr(inputs.get("data"), "metadata", {}).get("quality")
    if quality is None:
        return ""
    if quality.source:
        # the file's name, as the task's key holds it (not where the campaign folder is)
        name = Path(str((source or {}).get("path") or quality.source)).name
        quality = replace(quality, source=name)
    if quality.ok:  # a clean record's table says nothing its one line does not
        of = f" of {quality.source}" if quality.source else ""
        text = (
            f"Data quality{of}: no flags on {len(quality.channels)} channels (time "
            "stamps, jitter, dropouts, saturation and aliasing checked)."
        )
    else:
        text = quality.summary().rstrip()
    return f"## Data quality\n\n{text}\n"


def report_sections(inputs: Mapping[str, Any]) -> str:
    """The Markdown sections of the analyses given (by report role), in report order."""
    parts = [
        f"## {heading}\n\n{inputs[role].summary().rstrip()}\n"
        for role, heading in REPORT_SECTIONS.items()
        if inputs.get(role) is not None
    ]
    return "\n".join(parts)


for _stage in (
    Stage(
        "compatibility",
        # 2: standard errors without the t widening, their degrees of freedom carried;
        # 3: integrated input noise counted once in the error bars
        # 4: coloured-residual degrees of freedom with the low band's exact covariance
        # 5: the bars carry the scatter of the estimated output weights
        # 6: a wings-level record's side velocity start is not estimated; what cannot
        # be separated keeps infinite bars with the input-noise share
        # 7: a longitudinal record's default leaves the lateral input errors out
        "7",
        CompatibilityOptions,
        "CompatibilityResult",
        _run_compatibility,
        uses_model=False,
        seeded=True,
    ),
    # regress 2: standard errors without the t widening, their degrees of freedom carried;
    # 3: coloured-residual degrees of freedom with the low band's exact covariance
    # 4: the predicted residual sum of squares (PRESS) stored with the fit; in the
    # frequency domain off the k/T grid, the fit's share of the shared noise counted
    Stage("regress", "4", RegressOptions, "RegressionResult", _run_regress, uses_model=False),
    Stage(
        "composite_response",  # once "frequency_id"
        "1",
        FrequencyIdOptions,
        "CompositeResponse",
        _run_frequency_id,
        uses_model=False,
        stored_as="frequency_id",
    ),
    Stage(
        "transfer_function",
        # 2: off the k/T grid, the fit's share of the shared noise counted in the bars
        "2",
        TransferFunctionOptions,
        "TransferFunctionFit",
        _run_transfer_function,
        uses_model=False,
    ),
    Stage(
        "frequency_domain_identify",  # once "frequency_identify"
        # 2: fdoe's noise weighting by default, record ends kept only when significant;
        # 3: the one least-squares solver and its relative stopping rule;
        # 4: the sandwich's degrees of freedom (t intervals);
        # 5: the noise that frequencies off the k/T grid share;
        # 6: the ends' Wald test on a positive definite covariance;
        # 7: the sandwich's noise spectrum smoothed over neighbouring frequencies;
        # 8: the bars carry the scatter of the estimated noise weighting;
        # 9: `parameters: []` is the library's empty list, not every parameter
        # 10: the information inverted on a unit diagonal (rounding)
        # 11: off the k/T grid, the fit's share of the shared noise counted in the bars
        "11",
        FrequencyIdentifyOptions,
        "FrequencyDomainResult",
        _run_frequency_identify,
        stored_as="frequency_identify",
    ),
    Stage(
        "handling_qualities",
        # 2: a negative-gain response's bandwidth read with its sign reversed
        "2",
        HandlingQualitiesOptions,
        "HandlingQualities",
        _run_handling_qualities,
        uses_model=False,
    ),
):
    register_stage(_stage)
