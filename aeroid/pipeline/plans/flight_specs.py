"""The flights of a campaign config: files (with channel maps, windows and
segments) or simulated flights, as pydantic models of the YAML a user writes."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import (
    Discriminator,
    Field,
    Tag,
    field_validator,
    model_validator,
)

from ...support import CONDITION_NAMES
from .._options import Options


class ChannelEntry(Options):
    """One model channel of a channel map: ``sign * scale * unit factor * raw + offset``."""

    channel: str = Field(..., min_length=1)
    # the channel's unit in the file, converted to SI (aeroid.io.channel_map.UNIT_CONVERSIONS;
    # an unknown one is reported by the pre-flight checks with the others)
    unit: str | None = None
    scale: float | None = None
    offset: float | None = None
    sign: Literal[-1, 1] | None = None


class WindowSpec(Options):
    """A window found in the log: while a flight mode holds, or between two events."""

    # a value of the log's mode events, or [channel or event kind, value]
    mode: str | int | float | tuple[str, str | int | float] | None = None
    events: tuple[str | list[str], str | list[str]] | None = None
    # which window, when the mode or events give several
    index: int | None = None

    @model_validator(mode="after")
    def _one_way(self) -> WindowSpec:
        if (self.mode is None) == (self.events is None):
            raise ValueError("give one of mode: ... and events: [start, end]")
        return self


class SegmentSpec(Options):
    """Automatic segmentation (`aeroid.segment`): each window becomes a flight."""

    inputs: list[Annotated[str, Field(min_length=1)]] | None = Field(None, min_length=1)
    # a value of the log's mode events, or [channel or event kind, value]
    mode: str | int | float | tuple[str, str | int | float] | None = None
    events: tuple[str | list[str], str | list[str]] | None = None
    margin: (
        Annotated[float, Field(ge=0)]
        | tuple[Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)]]
        | None
    ) = None
    threshold: float | None = Field(None, gt=0)
    min_duration: float | None = Field(None, ge=0)
    merge_gap: float | None = Field(None, ge=0)
    trim_window: float | None = Field(None, gt=0)
    energy_window: float | None = Field(None, gt=0)
    # noise standard deviation of the inputs (all, or per input), in their units
    noise_floor: Annotated[float, Field(gt=0)] | dict[str, Annotated[float, Field(gt=0)]] | None = (
        None
    )

    @model_validator(mode="after")
    def _one_way(self) -> SegmentSpec:
        ways = [w for w in ("inputs", "mode", "events") if getattr(self, w) is not None]
        if len(ways) != 1:
            raise ValueError("give one of inputs: [...], mode: ... and events: [start, end]")
        return self


def _tagged(member: str, mapping: str) -> Any:
    """A union discriminator: `mapping` for a mapping (or an options model), else `member`."""

    def pick(value: Any) -> str:
        return mapping if isinstance(value, (Mapping, Options)) else member

    return Discriminator(pick)


# union tags that name a form of a value, never a key the user wrote (left out of messages)
_UNION_TAGS = frozenset({"<names>", "<map>", "<name>", "<times>"})

# a log or table channel, or a full entry (unit conversion, scale, offset, sign)
ChannelValue = Annotated[
    Annotated[str, Tag("<name>")] | Annotated[ChannelEntry, Tag("ChannelEntry")],
    _tagged("<name>", "ChannelEntry"),
]


# a flight condition's keys: the one list of `aeroid._conditions` (a typo is refused
# with the config, not found after every flight was fitted)
_ConditionName = Literal[CONDITION_NAMES]  # type: ignore[valid-type]


class FileFlights(Options):
    """Flight files: a path or glob (CSV, Parquet, .mat, flight logs) plus loader options.

    The options added for logs (``sample_rate``, ``max_gap``, ``window``,
    ``segments``, mapped ``channels``) are left out of a flight's options
    while unset, so the keys of configs without them do not change.

    Two keys are the engine's, never loader options: ``model`` (changes
    deep-merged into the campaign's model mapping: the flight's own trim, with
    its own fingerprint in its tasks' keys) and ``condition`` (the flight
    condition, e.g. ``{airspeed: 45.0, altitude: 500.0}``, handed to the load
    task as its engine-only option ``condition`` for the campaign's trends).
    """

    path: str
    time_column: str | None = None
    # a list of channels, {model_name: channel} (or {channel: model_name}: the side
    # naming the file's channels decides; one naming them on both is refused), or
    # {model_name: {channel: ..., unit: deg/s, scale: ..., offset: ..., sign: -1}}
    channels: (
        Annotated[
            Annotated[list[str], Tag("<names>")] | Annotated[dict[str, ChannelValue], Tag("<map>")],
            _tagged("<names>", "<map>"),
        ]
        | None
    ) = None
    units: dict[str, str] | None = None
    sample_rate: Annotated[float, Field(gt=0)] | None = None
    max_gap: Annotated[float, Field(gt=0)] | None = None
    # HDF5: read datasets stored outside the file (external or virtual); refused unset
    allow_external_data: bool | None = None
    # [t0, t1] seconds in the log's time, or {mode: ...} / {events: [start, end]}
    window: (
        Annotated[
            Annotated[tuple[float, float], Tag("<times>")]
            | Annotated[WindowSpec, Tag("WindowSpec")],
            _tagged("<times>", "WindowSpec"),
        ]
        | None
    ) = None
    # each manoeuvre window found becomes a flight of its own
    segments: SegmentSpec | None = None
    # engine-only, never loader options: changes deep-merged into the campaign's model
    # mapping (this flight's own trim), and the flight condition for campaign trends
    model: dict[str, Any] | None = None
    condition: dict[_ConditionName, float] | None = None

    @field_validator("window", mode="after")
    @classmethod
    def _ordered(cls, value: Any) -> Any:
        if isinstance(value, tuple) and not value[1] > value[0]:
            raise ValueError(f"the window [{value[0]}, {value[1]}] is inverted; need t0 < t1")
        return value

    @model_validator(mode="after")
    def _window_or_segments(self) -> FileFlights:
        if self.window is not None and self.segments is not None:
            raise ValueError("give window or segments, not both")
        return self

    def loader_options(self) -> dict[str, Any]:
        """The options as `aeroid.io.channel_map.load_mapped` takes them (plain JSON, unset
        ones left out, at every depth)."""
        return self.model_dump(
            mode="json", exclude={"path", "segments", "model", "condition"}, exclude_none=True
        )


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
