"""Records for multi-rate flight logs: what a reader returns before resampling."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import FrozenState
from ..errors import DataFormatError

FloatArray = NDArray[np.float64]


def _frozen(values: ArrayLike) -> FloatArray:
    array = np.array(values, dtype=np.float64)
    array.setflags(write=False)
    return array


@dataclass(frozen=True)
class LogChannel(FrozenState):
    """One signal of a log, on its own time stamps.

    Parameters
    ----------
    name : str
        ``topic.field`` as the log names it (``IMU.GyrY``).
    time : array_like
        Seconds, as the log recorded them: repeated stamps, and the stamps of a
        damaged log that step back, are kept (the quality checks report them, and
        `resample` sorts a channel whose time steps back, counting the stamps it
        moved). Non-finite stamps are refused.
    values : array_like
        One value per stamp.
    unit : str, optional
        The unit the log states, or ``""`` when it states none.
    """

    name: str
    time: FloatArray
    values: FloatArray
    unit: str = ""

    def __post_init__(self) -> None:
        time = _frozen(self.time)
        values = _frozen(self.values)
        if time.ndim != 1 or values.shape != time.shape:
            raise DataFormatError(
                f"log channel {self.name!r}: time and values must be 1-D of one length "
                f"(got {time.shape} and {values.shape})"
            )
        bad = np.flatnonzero(~np.isfinite(time))
        if bad.size:
            raise DataFormatError(
                f"log channel {self.name!r}: time stamp {time[bad[0]]} at index {bad[0]} is "
                "not finite"
            )
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "values", values)

    @property
    def rate(self) -> float:
        """Median sample rate in Hz (0 for fewer than two samples)."""
        if self.time.size < 2:
            return 0.0
        step = float(np.median(np.diff(self.time)))
        return 1.0 / step if step > 0 else 0.0


@dataclass(frozen=True)
class LogEvent(FrozenState):
    """A discrete event of a log: a mode change, a message, a marker."""

    time: float
    kind: str
    value: str


@dataclass(frozen=True)
class FlightLog(FrozenState):
    """A whole log: channels at their own rates, events, and where it came from.

    Parameters
    ----------
    channels : mapping of str to LogChannel
        Keyed by channel name.
    events : tuple of LogEvent
        In time order (flight-mode changes, system-identification mode, messages).
    metadata : mapping
        Source file name, format, and anything else the reader recorded.
    """

    channels: Mapping[str, LogChannel]
    events: tuple[LogEvent, ...] = ()
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", MappingProxyType(dict(self.channels)))
        object.__setattr__(self, "events", tuple(sorted(self.events, key=lambda e: e.time)))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    def __getitem__(self, name: str) -> LogChannel:
        try:
            return self.channels[name]
        except KeyError:
            raise DataFormatError(f"the log has no channel {name!r}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self.channels)

    def __len__(self) -> int:
        return len(self.channels)
