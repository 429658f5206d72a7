"""Units of a model's parameters from those of its equations and regressors.

A unit is a mapping of base symbols to exponents (``{"m": 1, "s": -2}`` is
m/s²); the unit of a derivative is that of the equation's left-hand side
over the product of its regressors' units, printed the way the textbooks
print them (``1/s``, ``m/s²``, ``1/(m s)``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

Unit = Mapping[str, int]

# units of the quantities the aircraft models use
METRE_PER_SECOND: Unit = {"m": 1, "s": -1}
PER_SECOND: Unit = {"s": -1}
PER_SECOND_SQUARED: Unit = {"s": -2}
METRE_PER_SECOND_SQUARED: Unit = {"m": 1, "s": -2}
NEWTON: Unit = {"N": 1}
RADIAN: Unit = {"rad": 1}
ONE: Unit = {}

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
