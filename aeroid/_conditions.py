"""The flight-condition keys: what a flight's ``condition:`` may give, in which unit.

One definition for every place that reads a flight's condition: the database
stage (which keys it fits over, in this order, unless told), the campaign
report's flight rows and the trend plots (their units); the JSBSim export maps
each of them to a JSBSim property (`aeroid.uncertainty.database_export`). A
condition is given in SI units, angles in rad; tables and plots show angles in
degrees. The pipeline takes these names through `aeroid.support`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CONDITION_KEYS", "CONDITION_NAMES", "ConditionKey", "condition_key"]
from ._records import FrozenState


@dataclass(frozen=True)
class ConditionKey(FrozenState):
    """A flight-condition key.

    Attributes
    ----------
    name : str
        The key in a flight's ``condition:`` and metadata.
    unit : str
        The unit it is given in (SI; ``""`` for a ratio).
    shown : str
        The unit tables and plots show it in.
    scale : float
        Factor from `unit` to `shown`.
    """

    name: str
    unit: str
    shown: str
    scale: float = 1.0


# in the order a database takes them as its axes (the angle of attack first: the
# coefficients change most with it) and a flight's row lists them
CONDITION_KEYS: tuple[ConditionKey, ...] = (
    ConditionKey("alpha", "rad", "deg", 180.0 / math.pi),
    ConditionKey("beta", "rad", "deg", 180.0 / math.pi),
    ConditionKey("airspeed", "m/s", "m/s"),
    ConditionKey("altitude", "m", "m"),
    ConditionKey("mach", "", ""),
    ConditionKey("dynamic_pressure", "Pa", "Pa"),
    ConditionKey("qbar", "Pa", "Pa"),
)
CONDITION_NAMES: tuple[str, ...] = tuple(k.name for k in CONDITION_KEYS)


def condition_key(name: str) -> ConditionKey | None:
    """The key called `name` (``Mach`` is ``mach``), or None for a key outside the list."""
    lower = name.lower() if name == "Mach" else name
    return next((k for k in CONDITION_KEYS if k.name == lower), None)
