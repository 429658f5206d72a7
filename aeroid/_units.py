"""Units of a model's parameters from those of its equations and regressors.

A unit is a mapping of base symbols to exponents (``{"m": 1, "s": -2}`` is
m/s²); the unit of a derivative is that of the equation's left-hand side
over the product of its regressors' units, printed the way the textbooks
print them (``1/s``, ``m/s²``, ``1/(m s)``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

Unit = Mapping[str, int]

# units of the quantities the aircraft models use
METRE_PER_SECOND: Unit = {"m": 1, "s": -1}
PER_SECOND: Unit = {"s": -1}
PER_SECOND_SQUARED: Unit = {"s": -2}
METRE_PER_SECOND_SQUARED: Unit = {"m": 1, "s": -2}
NEWTON: Unit = {"N": 1}
RADIAN: Unit = {"rad": 1}
ONE: Unit = {}

_DEG = math.pi / 180.0
#: source unit -> (factor to SI, SI unit): a channel in the source unit times the
#: factor is in the SI unit. SI units themselves convert with factor 1.
UNIT_CONVERSIONS: Mapping[str, tuple[float, str]] = {
    "deg": (_DEG, "rad"),
    "cdeg": (_DEG / 100.0, "rad"),  # centidegrees (ArduPilot attitude)
    "deg/s": (_DEG, "rad/s"),
    "cdeg/s": (_DEG / 100.0, "rad/s"),
    "us": (1e-6, "s"),
    "ms": (1e-3, "s"),
    "ft": (0.3048, "m"),
    "ft/s": (0.3048, "m/s"),
    "kt": (1852.0 / 3600.0, "m/s"),
    "g": (9.80665, "m/s2"),
    "rad": (1.0, "rad"),
    "rad/s": (1.0, "rad/s"),
    "s": (1.0, "s"),
    "m": (1.0, "m"),
    "m/s": (1.0, "m/s"),
    "m/s2": (1.0, "m/s2"),
}

_POWERS = {2: "²", 3: "³", 4: "⁴"}


def _power(symbol: str, exponent: int) -> str:
    return symbol if exponent == 1 else symbol + _POWERS.get(exponent, f"^{exponent}")


def unit_text(unit: Unit) -> str:
    """``{"m": 1, "s": -2}`` -> ``"m/s²"``; the dimensionless unit is ``"-"``."""
    up = [_power(k, e) for k, e in unit.items() if e > 0]
    down = [_power(k, -e) for k, e in unit.items() if e < 0]
    if not up and not down:
        return "-"
    head = " ".join(up) or "1"
    if not down:
        return head
    tail = down[0] if len(down) == 1 else f"({' '.join(down)})"
    return f"{head}/{tail}"


def ratio(numerator: Unit, factors: Iterable[Unit], *, keep_radians: bool) -> str:
    """The unit of ``numerator / product(factors)`` as text.

    Dimensional derivatives drop the radian (M_alpha in 1/s², as Klein and
    Morelli print it); non-dimensional coefficient derivatives keep it
    (C_L_alpha in 1/rad).
    """
    out: dict[str, int] = dict(numerator)
    for f in factors:
        for k, e in f.items():
            out[k] = out.get(k, 0) - e
    if not keep_radians:
        out.pop("rad", None)
    # a stable order: length, force, time, angle
    order = {"m": 0, "N": 1, "s": 2, "rad": 3}
    return unit_text({k: out[k] for k in sorted(out, key=lambda k: order.get(k, 4)) if out[k]})


# Stability and control derivatives of the built-in aircraft and short-period models,
# by the equation (force or moment) and the variable they multiply. Moment derivatives
# (M, L, N) are angular accelerations: 1/s^2 per rad of an angle or control, 1/s per
# rad/s of a rate; force derivatives (Z, Y, X) in the alpha/beta equations are 1/s per
# rad and dimensionless per rad/s. Coefficients C* are dimensionless.
_ANGLES = ("alpha", "beta", "delta", "de", "da", "dr", "elevator", "aileron", "rudder")
_RATES = ("q", "p", "r", "alphadot", "alpha_dot")


def parameter_units(
    names: Sequence[str], declared: Mapping[str, str] | None = None
) -> dict[str, str]:
    """Units of the model parameters in `names`: those `declared` (a model's or a
    result's `parameter_units`), else guessed where the name follows the short-period
    derivative naming."""
    out = named_units(names)
    out.update({n: u for n, u in (declared or {}).items() if n in names})
    return out


def named_units(names: Sequence[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for name in names:
        head, _, var = name.partition("_")
        if name.startswith("tau_"):
            out[name] = "s"
        elif head.startswith("C") and len(head) > 1:
            out[name] = "-"
        elif head in ("M", "L", "N") and var:
            if var in _RATES:
                out[name] = "1/s"
            elif var.startswith(_ANGLES):
                out[name] = "1/s²"
        elif head in ("Z", "Y", "X") and var:
            if var in _RATES:
                out[name] = "-"
            elif var.startswith(_ANGLES):
                out[name] = "1/s"
    return out
