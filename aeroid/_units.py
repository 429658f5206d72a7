"""Units of a model's parameters from those of its equations and regressors.

A unit is a mapping of base symbols to exponents (``{"m": 1, "s": -2}`` is
m/s²); the unit of a derivative is that of the equation's left-hand side
over the product of its regressors' units, printed the way the textbooks
print them (``1/s``, ``m/s²``, ``1/(m s)``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

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
    order = {"m": 0, "ft": 0, "N": 1, "lbf": 1, "s": 2, "rad": 3}
    return unit_text({k: out[k] for k in sorted(out, key=lambda k: order.get(k, 4)) if out[k]})


# Guessed units of stability and control derivatives a model does not declare, by the
# naming of Klein & Morelli and of the library's own models: the head names the
# equation (the state whose derivative it is), the tail the regressor. A guess is made
# only where the record's units make it right: derived from the two channels' units
# where the record has both, else the radian-based table below where the equation's
# channel is in radians and no channel of the record is in degrees.
_EQUATIONS: dict[str, tuple[str, ...]] = {
    "M": ("q",),
    "L": ("p",),
    "N": ("r",),
    "Z": ("alpha",),
    "Y": ("beta",),
}
_EQUATIONS["X"] = ("V", "u")  # an airspeed equation: m/s² per rad (no table guess)
_ANGLES = frozenset(
    {"alpha", "beta", "delta", "delta_e", "delta_a", "delta_r", "de", "da", "dr"}
    | {"elevator", "aileron", "rudder"}
)
_RATES = frozenset(("q", "p", "r", "alphadot", "alpha_dot"))
_ANGLE_SYMBOLS = frozenset(("rad", "deg", "cdeg"))
# the equation's channel in radians: (head's table unit per angle, per rate)
_TABLE = {
    "M": ("1/s²", "1/s"),
    "L": ("1/s²", "1/s"),
    "N": ("1/s²", "1/s"),
    "Z": ("1/s", "-"),
    "Y": ("1/s", "-"),
}
_SUPERSCRIPTS = str.maketrans("²³⁴", "234")
_FACTOR = re.compile(r"([A-Za-z]+)\^?(-?\d*)$")
_SPELLED = {"degree": "deg", "degrees": "deg", "radian": "rad", "radians": "rad"}
# the unit symbols read; a unit with another (``percent``) is not read
_SYMBOLS = frozenset(("m", "s", "N", "kg", "rad", "deg", "cdeg", "g", "ft", "kt", "ms", "us"))


def parameter_units(
    names: Sequence[str],
    declared: Mapping[str, str] | None = None,
    channel_units: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """Units of the model parameters in `names`: those `declared` (a model's or a
    result's `parameter_units`), else guessed from the derivative naming where the
    record's `channel_units` make the guess right (see `guessed_units`)."""
    out = guessed_units(names, channel_units)
    out.update({n: u for n, u in (declared or {}).items() if n in names})
    return out


def guessed_units(
    names: Sequence[str], channel_units: Mapping[str, str] | None = None
) -> dict[str, str]:
    """Units guessed from the parameters' names and the record's `channel_units`.

    ``tau_*`` is in s and a coefficient's constant ``C*_0`` is dimensionless whatever
    the record. A derivative ``M_alpha`` (head M, L, N, Z, Y or X: the equation of q,
    p, r, alpha, beta or V/u) is the unit of its equation's rate over its regressor's
    unit where the record gives both channels' units (``(deg/s²)/rad`` is printed
    ``deg/(s² rad)``; a radian left alone is dropped, as Klein and Morelli print
    dimensional derivatives); a regressor that is no channel (``M_delta`` on an
    ``elevator``) gets the radian-based table value only where the equation's
    channel is in radians and no channel is in degrees. A coefficient derivative
    ``CL_alpha`` is per its angle's unit (``1/rad``), ``Cm_q`` per rad too where
    the rate is in rad/s (the non-dimensional rate q c/(2V) is an angle). Other
    names get none.
    """
    units = {
        k: parsed for k, v in (channel_units or {}).items() if (parsed := _parse(v)) is not None
    }
    # a channel whose unit this does not read may be in degrees
    unread = {k for k, v in (channel_units or {}).items() if v and k not in units}
    in_degrees = bool(unread) or any(
        s in _ANGLE_SYMBOLS and s != "rad" for u in units.values() for s in u
    )
    out: dict[str, str] = {}
    for name in names:
        head, _, var = name.partition("_")
        if name.startswith("tau_"):
            out[name] = "s"
        elif head.startswith("C") and len(head) > 1 and var:
            guess = _coefficient_unit(var, units, in_degrees)
            if guess is not None:
                out[name] = guess
        elif head in _EQUATIONS and var:
            guess = _derivative_unit(head, var, units, in_degrees)
            if guess is not None:
                out[name] = guess
    return out


def _parse(text: str) -> dict[str, int] | None:
    """``"deg/s"`` -> ``{"deg": 1, "s": -1}``; ``"-"`` and ``"1"`` are dimensionless;
    None for a unit this does not read (``%``)."""
    text = text.strip().translate(_SUPERSCRIPTS)
    if text in ("-", "1", ""):
        return {} if text else None
    top, _, bottom = text.partition("/")
    out: dict[str, int] = {}
    for part, sign in ((top, 1), (bottom.strip("()"), -1)):
        for factor in part.replace("*", " ").replace("·", " ").split():
            if factor == "1" and sign == 1:
                continue
            m = _FACTOR.match(factor)
            if m is None or "/" in bottom:
                return None
            symbol = _SPELLED.get(m.group(1), m.group(1))
            if symbol not in _SYMBOLS:
                return None
            out[symbol] = out.get(symbol, 0) + sign * int(m.group(2) or 1)
    return {k: e for k, e in out.items() if e}


def _over(numerator: Mapping[str, int], denominator: Mapping[str, int]) -> str:
    # the radian is a ratio and is dropped; one beside degrees is a scale and is kept
    degrees = any(
        k in _ANGLE_SYMBOLS and k != "rad" and numerator.get(k, 0) != denominator.get(k, 0)
        for k in {*numerator, *denominator}
    )
    return ratio(numerator, [denominator], keep_radians=degrees)


def _derivative_unit(
    head: str, var: str, units: Mapping[str, Mapping[str, int]], in_degrees: bool
) -> str | None:
    equation = next((c for c in _EQUATIONS[head] if c in units), None)
    if equation is None:
        return None
    rate = dict(units[equation])
    rate["s"] = rate.get("s", 0) - 1
    if var in units:
        return _over(rate, units[var])
    radians = {k: e for k, e in units[equation].items() if k in _ANGLE_SYMBOLS} == {"rad": 1}
    if head not in _TABLE or in_degrees or not radians:
        return None
    per_angle, per_rate = _TABLE[head]
    return per_angle if var in _ANGLES else per_rate if var in _RATES else None


def _coefficient_unit(
    var: str, units: Mapping[str, Mapping[str, int]], in_degrees: bool
) -> str | None:
    if var == "0":
        return "-"
    unit = units.get(var)
    if unit is not None:
        angle = {k: e for k, e in unit.items() if k in _ANGLE_SYMBOLS}
        if angle and unit == angle:  # an angle: per rad or per deg
            return _over({}, unit) if angle != {"rad": 1} else "1/rad"
        # a rate enters as the non-dimensional q c / (2 V), an angle, only when in rad/s
        return "1/rad" if unit == {"rad": 1, "s": -1} else None
    if in_degrees or not units:
        return None
    return "1/rad" if var in _ANGLES or var in _RATES else None


def _unit_key(unit: str) -> str:
    # the aircraft models print m/s²; the channel map spells it m/s2
    return unit.strip().replace("²", "2").replace("^2", "2").replace(" ", "")


def require_model_units(
    model: Any,
    datas: Sequence[Any],
    channels: Iterable[str],
    error: type[Exception] | None = None,
) -> None:
    """Refuse a record whose stated unit for a channel contradicts the model's.

    A record that says ``alpha`` is in deg fitted by a model in rad would be
    fitted as if a degree were a radian: derivatives off by 57.3 with tight
    error bars. Units either side leaves unstated, or that AeroID does not
    know, are not judged.

    Raises
    ------
    IdentificationError (or `error`)
        Naming the channel, both units and the factor between them.
    """
    from .errors import IdentificationError

    declared = dict(getattr(model, "channel_units", None) or {})
    for name in channels:
        want = declared.get(name)
        if not want:
            continue
        ours = UNIT_CONVERSIONS.get(_unit_key(want))
        for i, data in enumerate(datas):
            stated = dict(getattr(data, "units", None) or {}).get(name)
            theirs = UNIT_CONVERSIONS.get(_unit_key(stated)) if stated else None
            if ours is None or theirs is None or theirs == ours:
                continue
            where = str(getattr(data, "metadata", {}).get("source", f"record {i}"))
            apart = (
                f"1 {stated} = {theirs[0] / ours[0]:.6g} {want}"
                if theirs[1] == ours[1]
                else "not even the same quantity"
            )
            raise (error or IdentificationError)(
                f"{where}: channel {name!r} is stated in {stated!r} but the model expects "
                f"{want!r} ({apart}); convert the channel (aeroid.apply_channel_map with a "
                "unit) or correct its unit label"
            )
