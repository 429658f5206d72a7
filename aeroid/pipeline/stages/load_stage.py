"""The load stage: a flight file (through its channel map and window) or a simulated
flight, checked as it arrives, into the `FlightData` every later stage reads."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from pydantic import Field, model_validator

from ...errors import DataFormatError, PipelineError
from ..plans.config import Options
from . import Stage, StageContext, register_stage
from .signature_options import library_fields

__all__ = ["LoadOptions", "QualityLimits", "flight_data"]


def flight_data(ctx: StageContext) -> Any:
    """The flight's data: corrected by the compatibility check where that ran (an input
    role ``corrected``), else as loaded."""
    checked = ctx.inputs.get("corrected")
    return ctx.inputs["data"] if checked is None else checked.corrected


def record_start(ctx: StageContext) -> dict[str, Any]:
    """``x0`` and ``trim`` of `design_experiment` from the flight's record (the stage's
    ``at_record_start``)."""
    model = ctx.model
    assert model is not None
    data = flight_data(ctx)
    first = {n: float(data[n][0]) for n in data.names}
    missing = [c for c in model.controls if c not in first]
    if missing:
        raise PipelineError(f"design at_record_start: the record has no control channel {missing}")
    fitted = getattr(ctx.inputs.get("values"), "initial_states", ())
    start = dict(fitted[0]) if fitted else {}
    x0 = {s: start.get(s, first.get(s, 0.0)) for s in model.states}
    return {"x0": x0, "trim": {c: first[c] for c in model.controls}}


class HoldoutSpec(Options):
    """Data held out of the fit, predicted by `validate`: a window ``t0``..``t1``
    (seconds) of the flight's record, or its last ``fraction``."""

    t0: float | None = None
    t1: float | None = None
    fraction: float | None = Field(None, gt=0, lt=1)

    @model_validator(mode="after")
    def _one_form(self) -> HoldoutSpec:
        window = self.t0 is not None or self.t1 is not None
        if window and self.fraction is not None:
            raise ValueError("give either t0 and t1, or fraction, not both")
        if window and (self.t0 is None or self.t1 is None):
            raise ValueError("a held-out window needs both t0 and t1")
        if not window and self.fraction is None:
            raise ValueError("give t0 and t1 (seconds), or fraction (the record's last part)")
        if self.t0 is not None and self.t1 is not None and not self.t1 > self.t0:
            raise ValueError(f"need t1 > t0, got t0={self.t0:g}, t1={self.t1:g}")
        return self


def outside_holdout(data: Any, holdout: Any) -> list[Any]:
    """The parts of `data` before and after its held-out window, each a record."""
    from ...errors import IdentificationError
    from ...support import holdout_record

    spec = holdout.model_dump(exclude_none=True)
    try:
        held, _, _ = holdout_record(data, spec)
    except IdentificationError as exc:
        raise PipelineError(f"stages.identify.{exc}") from None
    t, first, last = data.time, float(held.time[0]), float(held.time[-1])
    parts = [data.window(float(t[0]), float(t[t < first][-1])) if (t < first).sum() >= 10 else None]
    parts.append(
        data.window(float(t[t > last][0]), float(t[-1])) if (t > last).sum() >= 10 else None
    )
    kept = [p for p in parts if p is not None]
    if not kept:
        raise PipelineError(
            f"stages.identify.holdout: the window [{first:g}, {last:g}] s leaves fewer than 10 "
            "samples of the record to fit on either side"
        )
    return kept


class QualityLimits(Options):
    """Limits of `aeroid.check_data_quality` (its keywords)."""

    jitter_limit: float = Field(0.1, ge=0)
    dropout_factor: float = Field(3.0, gt=1)
    saturation_run: int = Field(5, ge=2)
    alias_band: float = Field(0.1, gt=0, lt=1)
    alias_limit: float = Field(0.2, ge=0, le=1)


class LoadOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.io.channel_map:load_mapped",
        *("time_column", "channels", "units", "sample_rate", "max_gap", "window", "quality"),
        # HDF5: read data stored outside the flight file (refused unless set)
        "allow_external_data",
        channels=(list[str] | dict[str, str | dict[str, Any]] | None, Field(None)),
        sample_rate=Field(None, gt=0),
        max_gap=Field(None, gt=0),
        window=(list[float] | dict[str, Any] | None, Field(None)),
        # the data-quality check of the channels as read (`aeroid.check_data_quality`):
        # unset or true (default limits), false, or limits such as {jitter_limit: 0.05}
        quality=(bool | QualityLimits | None, Field(None)),
    )
):
    """`aeroid.io.channel_map.load_mapped` keywords (files) or the simulated-flight spec;
    ``condition``: the flight condition the planner passes on into the data's metadata."""

    condition: dict[str, float] | None = None

    engine_only: ClassVar[frozenset[str]] = frozenset({"condition"})
    # unset, they leave the keys of flights loaded before they existed unchanged
    added_later: ClassVar[frozenset[str]] = frozenset(
        {"sample_rate", "max_gap", "window", "condition", "allow_external_data"}
    )


def _with_condition(data: Any, condition: Mapping[str, float] | None) -> Any:
    """The record with the flight condition merged into its (read-only) metadata."""
    if not condition:
        return data
    from ...io.data import FlightData

    meta = {**dict(data.metadata), **{k: float(v) for k, v in condition.items()}}
    return FlightData(data.time, data.channels, units=data.units, metadata=meta)


def _run_load(ctx: StageContext) -> Any:
    from ...io.channel_map import load_mapped
    from ..keys import file_digest

    src = dict(ctx.source or {})
    condition = ctx.options.condition
    if src.get("kind") == "simulated":
        from ...io.data import FlightData
        from ...io.quality import check_data_quality
        from ..plans.synthetic import fly

        data = fly(src["spec"])
        quality = True if ctx.options.quality is None else ctx.options.quality
        if quality:
            limits = {} if quality is True else quality.model_dump()
            meta = {**data.metadata, "quality": check_data_quality(data, **limits)}
            data = FlightData(data.time, dict(data.channels), dict(data.units), meta)
        return _with_condition(data, condition)
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
    kw = ctx.options.library_kwargs(exclude=("condition",))
    kw.setdefault("quality", True)  # every flight checked as it arrives unless told not to
    data = load_mapped(path, **kw)
    if file_digest(path) != before:
        raise PipelineError(f"{path}: the file changed while it was being read")
    return _with_condition(data, condition)


register_stage(
    Stage(
        "load",
        # 2: the data-quality report of the channels as read, in metadata["quality"]
        # 3: a log's channel at about the grid's rate filtered and evaluated band-limited
        # 4: PX4 topics on their sample stamps (metadata["stamps"]); a units label that
        #    contradicts the loaded unit and sample_rate on a table refused
        "4",
        LoadOptions,
        "FlightData",
        _run_load,
        uses_model=False,
        # a CSV file is read by pyarrow, whose arrays become numpy's through pandas
        imports=("pyarrow.csv", "pyarrow.compute", "pandas"),
    )
)
