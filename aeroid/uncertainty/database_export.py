"""Export of an `AeroDatabase`: a JSBSim aerodynamics section and a tidy Parquet table.

JSBSim builds each force and moment as a sum of functions per axis, each a
product of ``aero/qbar-area`` (``q̄ S``), a reference length for the moments,
a regressor (``aero/alpha-rad``, ``aero/ci2vel · velocities/q-aero-rad_sec``, a
surface position) and a table of the coefficient over the flight condition.
Coefficient names follow the package's convention ``<C>_<regressor>``:
``C`` one of CL, CD, CY, Cl, Cm, Cn; the regressor alpha, beta, p, q, r,
delta_e, delta_a, delta_r (rates nondimensional, ``p b/2V``, ``q c/2V``), or
``V`` the speed regressor ``V/V0 − 1`` (``Cm_V``), or
``0`` (``CL_0``) for the coefficient at the flight condition itself, or a
product of regressors as an aircraft model names it (``CD_beta_beta``, drag with
``β²``; ``CL_alpha_delta_e``), flown as the product of their properties, any of them
an absolute value (``CD_abs_beta``, drag with ``|β|``, the model's ``abs(beta)``;
``CD_abs_beta_alpha``), flown through JSBSim's ``<abs>``. When the
static ``<C>_0`` is tabulated over a condition key that is also a regressor
(``CL_0`` over alpha), ``<C>_<key>`` is its slope and is not exported again.

Each table also stands alone as ``aero/aeroid/<term>`` (without the products),
so that a simulation can read the database's value directly.

A speed term refers to the trim speed over the condition keys
(`AeroDatabase.speed_reference`, argued in `aeroid.uncertainty._database_speed`):
the section tabulates it as ``aero/aeroid/trim-speed-fps`` and flies ``C_V``
times ``velocities/vt-fps / aero/aeroid/trim-speed-fps − 1``. With the airspeed a
key of the static coefficient's table, its slope holds the speed's effect and the
speed term is not exported again (as ``C_alpha`` beside a table over alpha).

The moments are about the centre of gravity: an identification fits the
equations of motion about it, so its moment coefficients already hold the
moments of the lift, drag and side force about the centre of gravity. JSBSim
applies an ``<aerodynamics>`` section's forces at the aircraft's aerodynamic
reference point (``AERORP`` in its ``<metrics>``) and adds their moment about the
centre of gravity; on the c172x, 24 in above and 2 in ahead of it, that moment
would count the lift's and the drag's arms twice (about 0.4 in Cm_alpha). Each
moment axis of the section therefore carries ``aero/coefficient/aeroid-cg-<axis>``,
the opposite of that moment (``(cg − rp) × F`` in body axes, from JSBSim's own
reference point, centre of gravity and the section's forces), so the section
flies the database's moments about the centre of gravity wherever the
aircraft's reference point sits.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

from ..errors import DataFormatError, OutputError

if TYPE_CHECKING:
    from .database import AeroDatabase

_FT = 0.3048
_PSF = 47.88025898

# condition key -> (JSBSim property, factor from the condition's SI unit to the property's)
CONDITION_PROPERTIES: Mapping[str, tuple[str, float]] = {
    "alpha": ("aero/alpha-rad", 1.0),
    "beta": ("aero/beta-rad", 1.0),
    "mach": ("velocities/mach", 1.0),
    "airspeed": ("velocities/vt-fps", 1.0 / _FT),
    "altitude": ("position/h-sl-ft", 1.0 / _FT),
    "qbar": ("aero/qbar-psf", 1.0 / _PSF),
    "dynamic_pressure": ("aero/qbar-psf", 1.0 / _PSF),
}

# the speed terms' reference, the trim speed over the condition keys (ft/s)
TRIM_SPEED = "aero/aeroid/trim-speed-fps"

# regressor -> JSBSim properties whose product it is
REGRESSOR_PROPERTIES: Mapping[str, tuple[str, ...]] = {
    "0": (),
    "alpha": ("aero/alpha-rad",),
    "beta": ("aero/beta-rad",),
    "p": ("aero/bi2vel", "velocities/p-aero-rad_sec"),
    "q": ("aero/ci2vel", "velocities/q-aero-rad_sec"),
    "r": ("aero/bi2vel", "velocities/r-aero-rad_sec"),
    "delta_e": ("fcs/elevator-pos-rad",),
    # the mean deflection of the two ailerons, right trailing edge up positive: what a
    # record's delta_a holds (the c172x's fcs/effective-aileron-pos); the left
    # aileron alone deflects 15 deg up and 20 deg down on the c172x
    "delta_a": (
        "<product><value>0.5</value><difference><property>fcs/left-aileron-pos-rad"
        "</property><property>fcs/right-aileron-pos-rad</property></difference></product>",
    ),
    "delta_r": ("fcs/rudder-pos-rad",),
    # V/V0 - 1 about the database's trim speed over the condition keys
    "V": (
        "<difference><quotient><property>velocities/vt-fps</property><property>"
        f"{TRIM_SPEED}</property></quotient><value>1</value></difference>",
    ),
}

# a regressor that is also a condition key: a table over the key holds its slope
_REGRESSOR_KEY: Mapping[str, str] = {"V": "airspeed"}

# coefficient -> (JSBSim axis, reference length property or None)
AXES: Mapping[str, tuple[str, str | None]] = {
    "CL": ("LIFT", None),
    "CD": ("DRAG", None),
    "CY": ("SIDE", None),
    "Cl": ("ROLL", "metrics/bw-ft"),
    "Cm": ("PITCH", "metrics/cbarw-ft"),
    "Cn": ("YAW", "metrics/bw-ft"),
}


# how a term's name marks a factor's absolute value (the aircraft models' abs(beta))
_ABS = "abs_"


def _factors(regressor: str) -> tuple[str, ...] | None:
    """``"beta_beta"`` -> ``("beta", "beta")``, ``"alpha_delta_e"`` -> ``("alpha",
    "delta_e")``, ``"abs_beta_alpha"`` -> ``("abs_beta", "alpha")``: the regressors a
    product term's name joins with ``_``, ``abs_`` before one in absolute value (None
    if it is not one). The longest name first, so ``delta_e`` is not read as ``delta``."""
    names = sorted((n for n in REGRESSOR_PROPERTIES if n != "0"), key=len, reverse=True)
    out: list[str] = []
    rest = regressor
    while True:
        absolute = rest.startswith(_ABS)
        if absolute:
            rest = rest[len(_ABS) :]
        name = next((n for n in names if rest == n or rest.startswith(n + "_")), None)
        if name is None:
            return None
        out.append(_ABS + name if absolute else name)
        if rest == name:
            return tuple(out)
        rest = rest[len(name) + 1 :]


def _inner(factor: str) -> str:
    """The regressor a factor reads: ``"abs_beta"`` -> ``"beta"``."""
    return factor.removeprefix(_ABS)


def _factor_xml(factor: str) -> tuple[str, ...]:
    """The JSBSim properties (or XML) whose product is `factor`; an absolute value is
    one ``<abs>`` element around their product."""
    props = REGRESSOR_PROPERTIES[_inner(factor)]
    if factor == _inner(factor):
        return props
    body = "".join(p if p.startswith("<") else f"<property>{p}</property>" for p in props)
    return (f"<abs>{body if len(props) == 1 else f'<product>{body}</product>'}</abs>",)


def split_term(term: str) -> tuple[str, str]:
    """``"Cm_delta_e"`` -> ``("Cm", "delta_e")``; a bare ``"CL"`` is ``("CL", "0")``;
    a product ``"CD_beta_beta"`` -> ``("CD", "beta_beta")``; an absolute value
    ``"CD_abs_beta"`` -> ``("CD", "abs_beta")``."""
    base, _, regressor = term.partition("_")
    regressor = regressor or "0"
    if base not in AXES or (regressor != "0" and _factors(regressor) is None):
        raise DataFormatError(
            f"term {term!r} is not <C>_<regressor> with C in {', '.join(AXES)} and regressor "
            f"in {', '.join(REGRESSOR_PROPERTIES)} or a product of them joined by '_' "
            "(CD_beta_beta), abs_ before one in absolute value (CD_abs_beta): JSBSim "
            "export cannot place it"
        )
    return base, regressor


def _regressor_properties(regressor: str) -> tuple[str, ...]:
    """The JSBSim properties (or XML) whose product is `regressor` (`split_term`'s)."""
    if regressor == "0":
        return ()
    return tuple(p for f in _factors(regressor) or () for p in _factor_xml(f))


def _table_keys(db: AeroDatabase, term: str) -> list[str]:
    exps = db._exponents[term]
    return [k for i, k in enumerate(db.keys) if any(e[i] for e in exps)]


def _fmt(x: float) -> str:
    return f"{x:.8g}"


def _table_xml(db: AeroDatabase, term: str, n: int, indent: str) -> list[str]:
    """`term`'s table over the keys it varies with."""
    return _tabulated(db, term, _table_keys(db, term), lambda c: db.predict(term, c)[0], n, indent)


def _trim_speed_xml(db: AeroDatabase, n: int, indent: str) -> list[str]:
    """The speed terms' trim speed (ft/s) over the keys its model varies with."""
    ref = db.speed_reference
    if ref is None:
        raise DataFormatError(
            f"speed term(s) {', '.join(db.speed_terms)} need the database's trim-speed "
            "reference, which it lacks"
        )
    keys = [k for i, k in enumerate(db.keys) if any(e[i] for e in ref._exponents)]
    return _tabulated(db, "V0", keys, lambda c: db.trim_speed(c)[0] / _FT, n, indent)


def _tabulated(
    db: AeroDatabase,
    term: str,
    keys: list[str],
    value: Callable[[dict[str, Any]], NDArray[np.float64]],
    n: int,
    indent: str,
) -> list[str]:
    base: dict[str, Any] = {k: db.centres[k] for k in db.keys}
    if not keys:
        return [f"{indent}<value>{_fmt(float(value(base)[0]))}</value>"]
    for k in keys:
        if k not in CONDITION_PROPERTIES:
            raise DataFormatError(
                f"term {term!r} varies with condition {k!r}, which has no JSBSim property "
                f"(known: {', '.join(CONDITION_PROPERTIES)})"
            )
    if len(keys) > 3:
        raise DataFormatError(
            f"term {term!r} varies with {len(keys)} condition keys; JSBSim tables take 3"
        )
    grids = [db.grid(k, n) for k in keys]
    lines = [f"{indent}<table>"]
    for k, how in zip(keys, ("row", "column", "table"), strict=False):
        lines.append(
            f'{indent}  <independentVar lookup="{how}">{CONDITION_PROPERTIES[k][0]}</independentVar>'
        )
    conv = [CONDITION_PROPERTIES[k][1] for k in keys]
    if len(keys) == 1:
        lines.append(f"{indent}  <tableData>")
        values = value({**base, keys[0]: grids[0]})
        for x, v in zip(grids[0], values, strict=True):
            lines.append(f"{indent}    {_fmt(x * conv[0])} {_fmt(v)}")
        lines.append(f"{indent}  </tableData>")
    else:
        # a 2-D table, or one per breakpoint of the third key (JSBSim's 3-D table)
        layers = grids[2] if len(keys) == 3 else [None]
        for layer in layers:
            at = dict(base) if layer is None else {**base, keys[2]: layer}
            if layer is None:
                lines.append(f"{indent}  <tableData>")
            else:
                lines.append(f'{indent}  <tableData breakPoint="{_fmt(layer * conv[2])}">')
            rows, cols = np.meshgrid(grids[0], grids[1], indexing="ij")
            values = value({**at, keys[0]: rows.ravel(), keys[1]: cols.ravel()})
            values = values.reshape(rows.shape)
            lines.append(f"{indent}    " + " ".join(_fmt(c * conv[1]) for c in grids[1]))
            for i, x in enumerate(grids[0]):
                row = " ".join(_fmt(v) for v in values[i])
                lines.append(f"{indent}    {_fmt(x * conv[0])} {row}")
            lines.append(f"{indent}  </tableData>")
    lines.append(f"{indent}</table>")
    return lines


def _offset(axis: str) -> str:
    """JSBSim's ``(cg − aero reference point)`` along body `axis` (x, y, z), ft, as XML:
    the structural frame runs x aft and z up, the body frame x forward and z down."""
    cg, rp = f"inertia/cg-{axis}-in", f"metrics/aero-rp-{axis}-in"
    # body x = −structural x: cg − rp in body is rp − cg in structural (likewise z);
    # for y the frames agree
    first, second = (rp, cg) if axis != "y" else (cg, rp)
    return (
        f"<quotient><difference><property>{first}</property><property>{second}</property>"
        "</difference><value>12</value></quotient>"
    )


# moment axis -> the two (offset axis, force axis) products of (cg − rp) × F, the first
# minus the second
_CROSS = {
    "ROLL": (("y", "z"), ("z", "y")),
    "PITCH": (("z", "x"), ("x", "z")),
    "YAW": (("x", "y"), ("y", "x")),
}


def _cg_shift(axis: str) -> list[str]:
    """The function cancelling JSBSim's moment of the section's forces about the cg."""
    (o1, f1), (o2, f2) = _CROSS[axis]
    term = "<product>{}<property>forces/fb{}-aero-lbs</property></product>"
    return [
        f'    <function name="aero/coefficient/aeroid-cg-{axis}">',
        "      <description>the forces' moment about the cg, which the database's",
        "        moments already hold (module notes of aeroid.uncertainty.database_export)",
        "      </description>",
        "      <difference>",
        f"        {term.format(_offset(o1), f1)}",
        f"        {term.format(_offset(o2), f2)}",
        "      </difference>",
        "    </function>",
    ]


def jsbsim_aerodynamics(db: AeroDatabase, *, n: int = 21) -> str:
    """The ``<aerodynamics>`` XML section of `db` (module notes), `n` breakpoints per key."""
    placed: dict[str, list[tuple[str, str]]] = {axis: [] for axis, _ in AXES.values()}
    for term in db.terms:
        base, regressor = split_term(term)
        static = next((t for t in (f"{base}_0", base) if t in db.terms), None)
        key = _REGRESSOR_KEY.get(regressor, regressor)
        if static is not None and regressor != "0" and key in _table_keys(db, static):
            continue  # the slope of the static table, already in it
        placed[AXES[base][0]].append((term, regressor))
    out = ["<aerodynamics>", "  <!-- written by AeroID from an aerodynamic database -->"]
    if any(
        "V" in map(_inner, _factors(r) or ()) for entries in placed.values() for _, r in entries
    ):
        # defined first: the speed terms' regressor reads it
        out.append(f'  <function name="{TRIM_SPEED}">')
        out.append("    <description>the trim speed the speed terms refer to</description>")
        out.extend(_trim_speed_xml(db, n, "    "))
        out.append("  </function>")
    for term in db.terms:
        out.append(f'  <function name="aero/aeroid/{escape(term)}">')
        out.extend(_table_xml(db, term, n, "    "))
        out.append("  </function>")
    for base, (axis, length) in AXES.items():
        entries = [(t, r) for t, r in placed[axis] if t.partition("_")[0] == base]
        if not entries:
            continue
        out.append(f'  <axis name="{axis}">')
        for term, regressor in entries:
            out.append(f'    <function name="aero/coefficient/aeroid-{escape(term)}">')
            out.append("      <product>")
            props = [
                "aero/qbar-area",
                *([length] if length else []),
                *_regressor_properties(regressor),
            ]
            props.append(f"aero/aeroid/{term}")
            out.extend(
                f"        {p}" if p.startswith("<") else f"        <property>{p}</property>"
                for p in props
            )
            out.append("      </product>")
            out.append("    </function>")
        if axis in _CROSS:
            out.extend(_cg_shift(axis))
        out.append("  </axis>")
    out.append("</aerodynamics>")
    return "\n".join(out) + "\n"


def write_jsbsim(db: AeroDatabase, path: str | Path, *, n: int = 21) -> Path:
    """Write `jsbsim_aerodynamics` to `path`."""
    target = Path(path)
    try:
        target.write_text(jsbsim_aerodynamics(db, n=n), encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"cannot write the JSBSim aerodynamics to {target}: {exc}") from exc
    return target


def write_parquet(db: AeroDatabase, path: str | Path, *, n: int = 11) -> Path:
    """Write the tidy table of `db` (`AeroDatabase.table`) as Parquet."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    target = Path(path)
    table = pa.table(db.table(n=n))
    try:
        pq.write_table(table, target)
    except OSError as exc:
        raise OutputError(f"cannot write the database table to {target}: {exc}") from exc
    return target


def replace_aerodynamics(aircraft_xml: str, section: str) -> str:
    """The aircraft definition `aircraft_xml` with its ``<aerodynamics>`` replaced by `section`."""
    start = aircraft_xml.find("<aerodynamics")
    end = aircraft_xml.find("</aerodynamics>")
    if start < 0 or end < 0:
        raise DataFormatError("the aircraft definition has no <aerodynamics> section to replace")
    return aircraft_xml[:start] + section.strip() + aircraft_xml[end + len("</aerodynamics>") :]
