"""The pieces every aircraft model is built from: the ISA, `AircraftConstants`,
coefficient expansions, option checks and the `AircraftModel` record (see `aeroid.models.aircraft`)."""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _units
from .._records import FrozenState, ReadOnlyDict
from .._value_checks import body_position
from ..errors import ModelDefinitionError
from .model import Model

FloatArray = NDArray[np.float64]

# International Standard Atmosphere (ICAO Doc 7488), troposphere and lower stratosphere.
_ISA_T0 = 288.15  # K
_ISA_P0 = 101325.0  # Pa
_ISA_LAPSE = 0.0065  # K/m
_ISA_R = 287.05287  # J/(kg K)
_ISA_G0 = 9.80665  # m/s^2
_ISA_TROPOPAUSE = 11000.0  # m
_ISA_TOP = 20000.0  # m, end of the isothermal layer
_ISA_BOTTOM = -610.0  # m, lowest altitude the standard tabulates


def isa_density(altitude: float) -> float:
    """Air density of the International Standard Atmosphere, kg/m^3.

    Troposphere (``T = 288.15 - 0.0065 h``, ``p = p0 (T/T0)^(g0/(R L))``) up
    to 11 km and the isothermal layer above it to 20 km; ``rho = p / (R T)``.

    Parameters
    ----------
    altitude : float
        Geopotential pressure altitude, m.

    Returns
    -------
    float
        The density, kg/m^3.

    Raises
    ------
    ModelDefinitionError
        If `altitude` is not finite or lies outside -610 m to 20 km.
    """
    h = float(altitude)
    if not math.isfinite(h) or not _ISA_BOTTOM <= h <= _ISA_TOP:
        raise ModelDefinitionError(
            f"altitude: {altitude!r} m is outside the standard atmosphere's "
            f"{_ISA_BOTTOM:g} m to {_ISA_TOP:g} m"
        )
    exponent = _ISA_G0 / (_ISA_R * _ISA_LAPSE)
    if h <= _ISA_TROPOPAUSE:
        T = _ISA_T0 - _ISA_LAPSE * h
        p = _ISA_P0 * (T / _ISA_T0) ** exponent
    else:
        T = _ISA_T0 - _ISA_LAPSE * _ISA_TROPOPAUSE
        p11 = _ISA_P0 * (T / _ISA_T0) ** exponent
        p = p11 * math.exp(-_ISA_G0 * (h - _ISA_TROPOPAUSE) / (_ISA_R * T))
    return p / (_ISA_R * T)


def _finite(name: str, value: Any) -> float:
    if isinstance(value, (bool, np.bool_, str, bytes)):
        # float() reads True as 1 and "3000" as 3000: a flag or text is no quantity
        raise ModelDefinitionError(f"{name}: expected a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ModelDefinitionError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ModelDefinitionError(f"{name}: {value!r} is not finite")
    return v


def _position(name: str, value: Any) -> tuple[float, float, float]:
    return body_position(value, name, ModelDefinitionError)


_LATERAL_ONLY = ("Ixx", "Izz", "b")


@dataclass(frozen=True)
class AircraftConstants(FrozenState):
    """The known constants of an aircraft model, validated.

    Parameters
    ----------
    mass : float
        Mass, kg.
    Ixx, Iyy, Izz : float
        Moments of inertia about the body axes through the centre of gravity,
        kg m^2. ``Ixx`` and ``Izz`` (and the span `b`) may be left out
        (``nan``, the default) for a longitudinal model, which does not use
        them; the lateral and six-degree-of-freedom models then refuse the record.
    Ixz : float
        Product of inertia ``∫ x z dm``, kg m^2 (the tensor is
        ``[[Ixx, 0, -Ixz], [0, Iyy, 0], [-Ixz, 0, Izz]]``, aircraft symmetric in x-z).
    S : float
        Wing reference area, m^2.
    b : float
        Wing span, m.
    cbar : float
        Mean aerodynamic chord, m.
    rho : float, optional
        Air density, kg/m^3; when None it is the ISA density at `altitude`.
    altitude : float, optional
        Pressure altitude, m, for the ISA density when `rho` is None.
    g : float
        Gravitational acceleration, m/s^2.
    accel_position, alpha_vane_position, beta_vane_position : tuple of 3 floats
        Sensor positions relative to the centre of gravity, body axes
        (x forward, y right, z down), m.
    thrust_angle : float
        Angle of the thrust line above the body x axis, rad (thrust has body
        components ``T cos σ``, ``-T sin σ``).
    thrust_offset : float
        Perpendicular distance of the thrust line below the centre of gravity,
        m (positive: thrust pitches the nose up, ``M_T = T d``).
    engine_momentum : float
        Angular momentum of the engine's rotating parts (propeller, rotor,
        spool) along the body x axis, kg m^2/s (positive: turning clockwise
        seen from behind). Its gyroscopic moment ``-ω × h`` pitches the
        aircraft by ``-h r`` and yaws it by ``h q`` (Stevens & Lewis,
        *Aircraft Control and Simulation*, the engine angular momentum in the
        moment equations); the longitudinal model then takes the yaw rate
        ``r`` and the lateral model the pitch rate ``q`` as inputs.

    Raises
    ------
    ModelDefinitionError
        A value that is not a finite number, a non-positive mass, inertia or
        dimension, an inertia tensor that is not positive definite or whose
        principal moments violate the triangle inequality, or neither `rho`
        nor `altitude`. The message names the field.
    """

    mass: float
    Ixx: float = math.nan
    Iyy: float = math.nan
    Izz: float = math.nan
    S: float = math.nan
    b: float = math.nan
    cbar: float = math.nan
    Ixz: float = 0.0
    rho: float | None = None
    altitude: float | None = None
    g: float = 9.80665
    accel_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alpha_vane_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    beta_vane_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thrust_angle: float = 0.0
    thrust_offset: float = 0.0
    engine_momentum: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mass", "Ixx", "Iyy", "Izz", "S", "b", "cbar", "g"):
            value = getattr(self, name)
            if name in _LATERAL_ONLY and isinstance(value, float) and math.isnan(value):
                continue  # not given: only a longitudinal model may use the record
            if name in ("Iyy", "S", "cbar") and isinstance(value, float) and math.isnan(value):
                raise ModelDefinitionError(f"{name}: required (a positive number), not given")
            v = _finite(name, value)
            if not v > 0:
                raise ModelDefinitionError(f"{name}: must be positive, got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("Ixz", "thrust_angle", "thrust_offset", "engine_momentum"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.rho is None and self.altitude is None:
            raise ModelDefinitionError(
                "rho: give the air density rho, or an altitude for the ISA density"
            )
        if self.rho is not None:
            rho = _finite("rho", self.rho)
            if not rho > 0:
                raise ModelDefinitionError(f"rho: must be positive, got {rho!r}")
            object.__setattr__(self, "rho", rho)
        if self.altitude is not None:
            object.__setattr__(self, "altitude", _finite("altitude", self.altitude))
            if self.rho is None:
                isa_density(self.altitude)  # range check, naming the altitude
        for name in ("accel_position", "alpha_vane_position", "beta_vane_position"):
            object.__setattr__(self, name, _position(name, getattr(self, name)))
        if math.isnan(self.Ixx) or math.isnan(self.Izz):
            return  # the tensor is checked whenever its moments are given, span or not
        if not self.Ixx * self.Izz - self.Ixz**2 > 0:
            raise ModelDefinitionError(
                f"Ixz: inertia tensor is not positive definite (Ixx Izz - Ixz^2 = "
                f"{self.Ixx * self.Izz - self.Ixz**2:.6g} kg^2 m^4)"
            )
        principal = np.linalg.eigvalsh(self.inertia_tensor())
        total = float(principal.sum())
        # A real body has each principal moment at most the sum of the other two.
        worst = int(np.argmax(principal))
        if principal[worst] > total - principal[worst] + 1e-12 * total:
            raise ModelDefinitionError(
                f"Ixx, Iyy, Izz, Ixz: principal moments {principal.round(6).tolist()} kg m^2 "
                "violate the triangle inequality (no rigid body has them)"
            )

    @property
    def lateral_complete(self) -> bool:
        """Whether ``Ixx``, ``Izz`` and ``b`` are given (the lateral axes need them)."""
        return not any(math.isnan(getattr(self, n)) for n in _LATERAL_ONLY)

    def inertia_tensor(self) -> np.ndarray:
        """The body-axis inertia tensor, kg m^2."""
        return np.array(
            [[self.Ixx, 0.0, -self.Ixz], [0.0, self.Iyy, 0.0], [-self.Ixz, 0.0, self.Izz]]
        )

    def density(self) -> float:
        """Air density, kg/m^3: `rho` if given, else the ISA density at `altitude`."""
        if self.rho is not None:
            return float(self.rho)
        assert self.altitude is not None  # checked in __post_init__
        return isa_density(self.altitude)


# -- aerodynamic coefficient expansions ------------------------------------------------

# A coefficient is a tuple of terms, each (parameter name, regressor factors); the
# constant term has no factors. A factor is a regressor's name or its absolute value,
# written ``abs(<regressor>)``.
_Expansion = tuple[tuple[str, tuple[str, ...]], ...]

_CONSTANT_TERMS = ("0", "1", "const")

# A factor in |x| (Klein & Morelli ch. 5: the nonsmooth regressors of a global model).
# An aerodynamic effect that is even in an angle and grows from zero at a corner (the
# V-shaped sideslip drag of a fuselage, a table like CD(β) = k |β|) has no smooth
# polynomial that follows it through zero: β² is flat there and steep outside, and a
# fit trades one against the other. |β| follows it at every β with one parameter, and
# its product with another regressor (``abs(beta)*alpha``) lets the V's slope change.
_ABS_OPEN, _ABS_CLOSE = "abs(", ")"


def _factor_regressor(factor: str) -> str:
    """The regressor a factor reads: ``"abs(beta)"`` -> ``"beta"``, ``"alpha"`` -> ``"alpha"``."""
    if factor.startswith(_ABS_OPEN) and factor.endswith(_ABS_CLOSE):
        return factor[len(_ABS_OPEN) : -len(_ABS_CLOSE)]
    return factor


def _factor_name(factor: str) -> str:
    """A factor as it appears in a parameter's name: ``"abs(beta)"`` -> ``"abs_beta"``."""
    inner = _factor_regressor(factor)
    return f"abs_{inner}" if inner != factor else factor


_REGRESSOR_TEXT = {
    "alpha": "α",
    "beta": "β",
    "V": "(V/V0 - 1)",
    "p": "p b/(2V)",
    "q": "q c̄/(2V)",
    "r": "r b/(2V)",
    "alpha_dot": "α̇ c̄/(2V)",
}
_LINEAR_REGRESSOR_TEXT = {"alpha": "α", "beta": "β"}


def _expand(expansion: _Expansion, regressors: Mapping[str, Any], p: Mapping[str, Any]) -> Any:
    """Sum of parameter × product of regressors; plain arithmetic so any array namespace works.

    ``abs(x)`` is ``x sign(x)``: the same value, and a derivative that automatic
    differentiation takes as ``sign(x)``, zero at zero (as a central difference
    does), where ``abs``'s own rule would say one there."""
    total: Any = 0.0
    for name, factors in expansion:
        term = p[name]
        for f in factors:
            if f in regressors:
                term = term * regressors[f]
            else:
                x = regressors[_factor_regressor(f)]
                term = term * (x * np.sign(x))
        total = total + term
    return total


def _parse_term(
    item: str, coefficient: str, regressors: Sequence[str], model: str
) -> tuple[str, ...]:
    """The factors of one product term (``"alpha*delta_e"``, ``"abs(beta)*alpha"``)."""
    factors = tuple(item.replace(" ", "").split("*"))
    hint = (
        f"its regressors are {list(regressors)}, the constant '0', products as "
        "'alpha*delta_e' and absolute values as 'abs(beta)'"
    )
    for f in factors:
        inner = _factor_regressor(f)
        if inner in regressors:
            continue
        if inner != f or "(" in f or ")" in f:
            where = repr(item) if f == item.replace(" ", "") else f"{item!r}: {f!r}"
            raise ModelDefinitionError(
                f"terms[{coefficient!r}]: {where} is not the absolute value of a "
                f"regressor of the {model} model; {hint}"
            )
        raise ModelDefinitionError(
            f"terms[{coefficient!r}]: {item!r} uses {[f]}, which the {model} model does not "
            f"have; {hint}"
        )
    return factors


def _parse_expansions(
    terms: Mapping[str, Sequence[str]] | None,
    defaults: Mapping[str, Sequence[str]],
    regressors: Sequence[str],
    model: str,
) -> dict[str, _Expansion]:
    """Validate the user's choice of terms per coefficient and name their parameters."""
    chosen: dict[str, Sequence[str]] = dict(defaults)
    if terms is not None:
        if not isinstance(terms, Mapping):
            raise ModelDefinitionError(
                f"terms: expected a mapping of coefficient -> list of terms, got {terms!r}"
            )
        unknown = sorted(set(terms) - set(defaults))
        if unknown:
            raise ModelDefinitionError(
                f"terms: {unknown} are not coefficients of the {model} model; "
                f"its coefficients are {list(defaults)}"
            )
        chosen.update(terms)
    out: dict[str, _Expansion] = {}
    for coefficient, items in chosen.items():
        if isinstance(items, str):
            items = [items]
        expansion: list[tuple[str, tuple[str, ...]]] = []
        for item in items:
            if not isinstance(item, str) or not item.strip():
                raise ModelDefinitionError(
                    f"terms[{coefficient!r}]: every term must be a non-empty string, got {item!r}"
                )
            text = item.replace(" ", "")
            if text in _CONSTANT_TERMS:
                factors: tuple[str, ...] = ()
            else:
                factors = _parse_term(item, coefficient, regressors, model)
            joined = "_".join(_factor_name(f) for f in factors)
            name = f"{coefficient}_{joined if factors else '0'}"
            if any(name == n for n, _ in expansion):
                raise ModelDefinitionError(f"terms[{coefficient!r}]: term {item!r} given twice")
            expansion.append((name, factors))
        out[coefficient] = tuple(expansion)
    return out


def _factor_text(factor: str, *, linear: bool = False) -> str:
    inner = _factor_regressor(factor)
    # the linear models' regressors are the perturbation states themselves
    text = _LINEAR_REGRESSOR_TEXT.get(inner, inner) if linear else _REGRESSOR_TEXT.get(inner, inner)
    return text if inner == factor else f"|{text}|"


def _expansion_text(coefficient: str, expansion: _Expansion, *, linear: bool = False) -> str:
    if not expansion:
        return f"{coefficient} = 0"
    parts = []
    for name, factors in expansion:
        reg = " ".join(_factor_text(f, linear=linear) for f in factors)
        parts.append(f"{name} {reg}".rstrip())
    return f"{coefficient} = " + " + ".join(parts)


# units of the regressors of the non-dimensional coefficient expansions: angles in
# rad, V as V/V0 - 1 and the rates as p b/(2V), q c̄/(2V), r b/(2V) (dimensionless)
_COEFFICIENT_REGRESSOR_UNITS: Mapping[str, _units.Unit] = {
    "alpha": _units.RADIAN,
    "beta": _units.RADIAN,
    "V": _units.ONE,
    # the nondimensional rates (p b/2V, q c/2V, alpha_dot c/2V) are angles: Cm_q per rad
    "p": _units.RADIAN,
    "q": _units.RADIAN,
    "r": _units.RADIAN,
    "alpha_dot": _units.RADIAN,
    "thrust": _units.NEWTON,
}
_RATE: _units.Unit = {"rad": 1, "s": -1}
# and of the linear models' perturbation states (m/s, rad, rad/s)
_LINEAR_REGRESSOR_UNITS: Mapping[str, _units.Unit] = {
    "V": _units.METRE_PER_SECOND,
    "alpha": _units.RADIAN,
    "beta": _units.RADIAN,
    "p": _RATE,
    "q": _RATE,
    "r": _RATE,
    "thrust": _units.NEWTON,
}


def _expansion_units(
    expansions: Mapping[str, _Expansion],
    equations: Mapping[str, _units.Unit] | None,
    *,
    linear: bool,
    g: float,
) -> dict[str, str]:
    """Each term's parameter unit: its equation's unit (dimensionless coefficients when
    `equations` is None) over its regressors' (a surface deflection in rad), in feet
    and pounds where the constants' g is in ft/s² (`_us_system`)."""
    regs = _LINEAR_REGRESSOR_UNITS if linear else _COEFFICIENT_REGRESSOR_UNITS
    names = _US_SYMBOLS if _us_system(g) else {}

    def system(unit: _units.Unit) -> _units.Unit:
        return {names.get(k, k): e for k, e in unit.items()}

    out = {}
    for coefficient, expansion in expansions.items():
        lhs = _units.ONE if equations is None else equations[coefficient]
        for name, factors in expansion:
            units = [system(regs.get(_factor_regressor(f), _units.RADIAN)) for f in factors]
            out[name] = _units.ratio(system(lhs), units, keep_radians=not linear)
    return out


def _parameter_values(
    expansions: Mapping[str, _Expansion], parameters: Mapping[str, float] | None
) -> dict[str, float]:
    names = [n for e in expansions.values() for n, _ in e]
    values = dict.fromkeys(names, 0.0)
    if parameters is not None:
        if not isinstance(parameters, Mapping):
            raise ModelDefinitionError(
                f"parameters: expected a mapping of name -> nominal value, got {parameters!r}"
            )
        unknown = sorted(set(parameters) - set(values))
        if unknown:
            raise ModelDefinitionError(
                f"parameters {unknown} are not terms of this model; its parameters are {names} "
                "(choose the terms with terms=...)"
            )
        for k, v in parameters.items():
            values[k] = _finite(f"parameter {k!r}", v)
    return values


def _outputs(
    outputs: Sequence[str] | None, default: Sequence[str], allowed: Sequence[str]
) -> tuple[str, ...]:
    chosen = tuple(
        default if outputs is None else ([outputs] if isinstance(outputs, str) else outputs)
    )
    bad = [o for o in chosen if o not in allowed]
    if bad:
        raise ModelDefinitionError(f"outputs {bad} are not available; choose from {list(allowed)}")
    if not chosen:
        raise ModelDefinitionError("outputs: choose at least one output")
    return chosen


def _surfaces(surfaces: Sequence[str], reserved: Sequence[str]) -> tuple[str, ...]:
    names = tuple([surfaces] if isinstance(surfaces, str) else surfaces)
    for s in names:
        if not isinstance(s, str) or not s.isidentifier() or "_" == s[:1]:
            raise ModelDefinitionError(f"surfaces: {s!r} is not a valid control name")
        if s in reserved:
            raise ModelDefinitionError(
                f"surfaces: {s!r} is already a regressor name (a state or rate of the "
                f"model); to drive the model with a measured {s!r}, as a control, name it "
                f"otherwise (e.g. {s + '_m'!r}) and map the channel to that name"
            )
        if s == "abs" or s.startswith("abs_"):
            # a term's name writes abs(x) as abs_x: such a surface would read the same
            raise ModelDefinitionError(
                f"surfaces: {s!r} would read as an absolute value in parameter names "
                "(abs(beta) names CD_abs_beta); choose another name"
            )
    if len(set(names)) != len(names):
        raise ModelDefinitionError(f"surfaces: duplicate names in {list(names)}")
    return names


def _lateral_speed(
    c: AircraftConstants, V0: float, surfaces: tuple[str, ...]
) -> tuple[int, float, float, float]:
    """The numbers a lateral model flies its airspeed with: (the index of its input ``V``
    among the surfaces, -1 flying the trim's V0; rho S / 2; q̄ S and b/2V at V0).

    Plain numbers, each its own closure cell in the model function: the JAX translation
    lifts a closure's numbers out of the compiled program, so that one compilation
    serves every flight condition (an object holding them is baked in).
    """
    rho = c.density()
    column = surfaces.index("V") if "V" in surfaces else -1
    return column, 0.5 * rho * c.S, 0.5 * rho * V0 * V0 * c.S, 0.5 * c.b / V0


def _speed_at(
    u: Any, column: int, V0: float, half_rho_S: float, b: float, qbar_S0: float, half_b_V0: float
) -> tuple[Any, Any, Any]:
    """V, q̄ S and b/2V at the inputs `u` (rows: the surfaces), from `_lateral_speed`'s
    numbers."""
    if column < 0:
        return V0, qbar_S0, half_b_V0
    V = u[column]
    return V, half_rho_S * V * V, 0.5 * b / V


def _gyro_input(c: AircraftConstants, surfaces: tuple[str, ...], rate: str, part: str) -> int:
    """The index among `surfaces` of the other axis's `rate` that the engine's gyroscopic
    moment needs (-1 without an engine momentum)."""
    if c.engine_momentum == 0.0:
        return -1
    if rate not in surfaces:
        raise ModelDefinitionError(
            f"surfaces: the {part} model with an engine_momentum needs the "
            f"{'yaw' if rate == 'r' else 'pitch'} rate {rate!r} among its inputs (its "
            f"gyroscopic moment); add {rate!r} to surfaces"
        )
    return surfaces.index(rate)


def _accel_scale(accel_units: str, g: float) -> float:
    """Output scale of the specific forces: 1, or 1/g with the model's own g (US units too)."""
    if accel_units == "m/s2":
        return 1.0
    if accel_units == "g":
        return 1.0 / g
    raise ModelDefinitionError(f"accel_units: expected 'm/s2' or 'g', got {accel_units!r}")


_RATE_REFERENCES = ("V", "V0")


def _positive_g(g: float) -> float:
    if not g > 0:
        raise ModelDefinitionError(f"g: must be positive, got {g!r}")
    return g


def _check_rate_reference(rate_reference: Any) -> str:
    if rate_reference not in _RATE_REFERENCES:
        raise ModelDefinitionError(
            f"rate_reference: expected 'V' (q c̄/2V) or 'V0' (q c̄/2V0), got {rate_reference!r}"
        )
    return str(rate_reference)


def _content_version(version: str | None, *content: Any) -> str:
    """Fold the constants and term choice into the model's version (dynamics source is shared)."""
    digest = hashlib.sha256(repr(content).encode()).hexdigest()[:16]
    return f"{version}+aircraft-{digest}" if version else f"aircraft-{digest}"


# -- the model record ---------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class AircraftModel(Model):
    """An `aeroid.Model` built by this module, carrying its constants and printed equations.

    It is a `Model` in every respect (every path that takes a model takes it);
    it adds the aircraft constants, the kind of model, the reference condition,
    the names of the control surfaces and `summary()`, which prints the
    equations so they can be checked against the textbook.

    Attributes
    ----------
    constants : AircraftConstants or None
        The aircraft's constants (None for the linear models, whose
        derivatives are dimensional).
    kind : str
        The building function: ``"longitudinal"``, ``"lateral"``,
        ``"six_dof"``, ``"longitudinal_linear"`` or ``"lateral_linear"``.
    reference : mapping of str to float
        The reference or trim condition (``V0``, and ``alpha0``, ``theta0``
        or ``gamma0`` where the model has them).
    surfaces : tuple of str
        The control-surface inputs, in control order.
    equations : str
        The equations of motion and outputs as printed by `summary`.
    channel_units : mapping of str to str
        The unit of each state, control and output (``V`` m/s, ``alpha`` rad,
        ``q`` rad/s, ``q_dot`` rad/s², ``ax`` m/s² or g, surfaces rad,
        ``thrust`` N): what plots and tables label a record's channels with
        where the record itself gives no unit.
    parameter_units : mapping of str to str
        Each parameter's unit, from its equation's and regressors' units:
        dimensional derivatives without the radian (``M_alpha``: 1/s²,
        ``X_0``: m/s²), coefficient derivatives per radian (``CL_alpha``:
        1/rad), ``-`` for a dimensionless one. Reports and plots label
        estimates with them.
    """

    constants: AircraftConstants | None = None
    kind: str = ""
    reference: Mapping[str, float] = field(default_factory=dict)
    surfaces: tuple[str, ...] = ()
    equations: str = ""
    parameter_units: Mapping[str, str] = field(default_factory=dict)
    channel_units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        super().__post_init__()
        ref = ReadOnlyDict({str(k): float(v) for k, v in self.reference.items()})
        object.__setattr__(self, "reference", ref)
        units = ReadOnlyDict({str(k): str(v) for k, v in self.parameter_units.items()})
        object.__setattr__(self, "parameter_units", units)
        chans = ReadOnlyDict({str(k): str(v) for k, v in self.channel_units.items()})
        object.__setattr__(self, "channel_units", chans)
        object.__setattr__(self, "surfaces", tuple(self.surfaces))

    def _traced_as_jax(self, fun: Any) -> Any:
        # the JAX paths trace this copy bound to jax.numpy (the functions use only
        # module-level ``np`` calls; the compiled path checks the same against numpy)
        from ._jax_translation import _translate
        from .jax_compiled import require_jax

        return _translate(fun, require_jax()[1])

    def summary(self) -> str:
        """The model's equations, constants, parameters and outputs as text."""
        lines = [f"{self.name}: {self.kind} aircraft model", ""]
        lines.append(f"states:   {', '.join(self.states)}")
        lines.append(f"controls: {', '.join(self.controls)}")
        lines.append(f"outputs:  {', '.join(self.output_names)}")
        if self.reference:
            ref = ", ".join(f"{k} = {v:.6g}" for k, v in self.reference.items())
            lines.append(f"reference: {ref}")
        if self.constants is not None:
            c = self.constants
            lines.append(
                f"constants: m = {c.mass:.6g} kg, Ixx = {c.Ixx:.6g}, Iyy = {c.Iyy:.6g}, "
                f"Izz = {c.Izz:.6g}, Ixz = {c.Ixz:.6g} kg m^2, S = {c.S:.6g} m^2, "
                f"b = {c.b:.6g} m, c̄ = {c.cbar:.6g} m, ρ = {c.density():.6g} kg/m^3, "
                f"g = {c.g:.6g} m/s^2"
            )
            lines.append(
                f"sensors (body axes from the c.g., m): accelerometer {c.accel_position}, "
                f"α vane {c.alpha_vane_position}, β vane {c.beta_vane_position}"
            )
        lines += ["", self.equations, "", f"parameters ({len(self.parameters)}):"]
        lines += [f"  {k} = {v:.6g}" for k, v in self.parameters.items()]
        return "\n".join(lines)


# units of the channels the aircraft models name (surfaces, not listed, are in rad)
_CHANNEL_UNITS = {
    "V": "m/s",
    "u": "m/s",
    "v": "m/s",
    "w": "m/s",
    "p": "rad/s",
    "q": "rad/s",
    "r": "rad/s",
    "p_dot": "rad/s²",
    "q_dot": "rad/s²",
    "r_dot": "rad/s²",
    "h": "m",
    "x": "m",
    "y": "m",
    "z": "m",
    "thrust": "N",
}


# the same channels in US customary units, told by g (32.174 ft/s^2)
_US_UNITS = {"m/s": "ft/s", "m/s²": "ft/s²", "m": "ft", "N": "lbf"}
_US_SYMBOLS = {"m": "ft", "N": "lbf"}
_US_GRAVITY = (30.0, 34.0)


def _us_system(g: float) -> bool:
    """Whether constants with this g compute in feet, pounds and seconds."""
    return _US_GRAVITY[0] < g < _US_GRAVITY[1]


def _channel_units(names: Sequence[str], accel_units: str, g: float) -> dict[str, str]:
    """Each channel's unit label; the models compute in the units of their constants, so
    a g of about 32.2 (ft/s²) labels feet, pounds and seconds."""
    us = _us_system(g)
    accel = "g" if accel_units == "g" else ("ft/s²" if us else "m/s²")
    out = {}
    for n in names:
        unit = accel if n in ("ax", "ay", "az") else _CHANNEL_UNITS.get(n, "rad")
        out[n] = _US_UNITS.get(unit, unit) if us else unit
    return out


def _aircraft_model(
    kind: str,
    function: Callable[..., Callable[[Any, Any, Any, Any], Any]],
    args: tuple[Any, ...],
    *,
    version: str | None,
    accel_units: str = "m/s2",
    gravity: float = _ISA_G0,
    **fields: Any,
) -> AircraftModel:
    """The model whose dynamics and measurement are ``function(*args, role)``.

    `args` (constants, reference condition, terms, options) are also folded
    into the version, as the function source is the same for every such model.
    """
    names = [*fields["states"], *fields["controls"], *fields["outputs"]]
    constants = fields.get("constants")
    g = constants.g if constants is not None else gravity
    return AircraftModel(
        dynamics=function(*args, "dynamics"),
        measurement=function(*args, "measurement"),
        version=_content_version(version, kind, *args),
        kind=kind,
        channel_units=_channel_units(names, accel_units, g),
        **fields,
    )


def _alpha_dot_alone(expansions: Mapping[str, _Expansion]) -> None:
    """The α̇ regressor enters linearly (so the α equation stays solvable): never in a
    product or an absolute value."""
    for coefficient, expansion in expansions.items():
        for name, factors in expansion:
            if "alpha_dot" in factors and len(factors) > 1:
                raise ModelDefinitionError(
                    f"terms[{coefficient!r}]: {name!r} multiplies alpha_dot by another "
                    "regressor; alpha_dot may only enter alone"
                )
            if any(f != "alpha_dot" and _factor_regressor(f) == "alpha_dot" for f in factors):
                raise ModelDefinitionError(
                    f"terms[{coefficient!r}]: {name!r} takes the absolute value of alpha_dot; "
                    "alpha_dot may only enter alone, linearly"
                )


def _check_speed(V0: Any) -> float:
    v = _finite("V0", V0)
    if not v > 0:
        raise ModelDefinitionError(f"V0: the reference airspeed must be positive, got {v!r}")
    return v


def _check_trim_angles(alpha0: Any, theta0: Any) -> tuple[float, float]:
    alpha0, theta0 = _finite("alpha0", alpha0), _finite("theta0", theta0)
    if not abs(theta0) < 0.5 * math.pi:
        raise ModelDefinitionError(f"theta0: {theta0!r} rad is not within ±π/2")
    return alpha0, theta0


def _check_constants(constants: Any, kind: str = "longitudinal") -> AircraftConstants:
    if not isinstance(constants, AircraftConstants):
        raise ModelDefinitionError(
            f"constants: expected an AircraftConstants record, got {type(constants).__name__}"
        )
    if kind != "longitudinal" and not constants.lateral_complete:
        lacking = [n for n in _LATERAL_ONLY if math.isnan(getattr(constants, n))]
        raise ModelDefinitionError(
            f"constants: a {kind} model needs {', '.join(lacking)}, which the record lacks"
        )
    return constants


def _accel_text(axes: str, accel_units: str) -> str:
    unit = " / g0 (outputs in g)" if accel_units == "g" else " (outputs in m/s^2)"
    return (
        "accelerometer at r = (xa, ya, za) from the c.g.: a = F/m + ω̇ × r + ω × (ω × r)"
        f"{unit}, F the aerodynamic plus thrust force ({axes})"
    )
