"""Standard flight-mechanics models: longitudinal, lateral-directional and six degrees of freedom.

The equations of motion and non-dimensionalisation follow Klein & Morelli,
*Aircraft System Identification* (2006), ch. 3, which agrees with
Jategaonkar, *Flight Vehicle System Identification*, ch. 3; the sensor
models (accelerometers and air-data vanes off the centre of gravity) are the
rigid-body kinematic corrections of their data-compatibility chapters:

* `longitudinal`: nonlinear, stability (wind) axes, states V, α, θ, q (h);
* `lateral`: lateral-directional about a trim (V0, α0, θ0), states β, p, r, φ (ψ);
* `six_dof`: nonlinear, body axes, states u, v, w, p, q, r, φ, θ, ψ (position);
* `longitudinal_linear`, `lateral_linear`: small perturbations with
  dimensional derivatives (``M_alpha``, ``L_p``, ``N_r``, ...).

The aerodynamic coefficients are linear-in-parameters expansions whose terms
the user chooses (parameters ``CL_alpha``, ``Cm_q``, ``Cn_delta_r``,
``CD_0``). The constants of an aircraft (mass, inertias, reference geometry,
air density, sensor positions, thrust line) are one validated record,
`AircraftConstants`. Every model is an `aeroid.Model` (an `AircraftModel`,
whose ``summary()`` prints its equations); its functions broadcast over
batches and use only module-level ``np`` calls, so they also run on
`jax.numpy`. `trim` finds a steady flight condition, `linearize` the
Jacobians about it, and `model_from_config` builds a model from a campaign
config's mapping.
"""

from __future__ import annotations

import hashlib
import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import _units
from ._records import ReadOnlyDict, fmt, frozen_array, frozen_mapping, markdown_table
from ._threads import small_blas
from .errors import ModelDefinitionError, SimulationError
from .model import Model, resolve_parameters

FloatArray = NDArray[np.float64]

__all__ = [
    "AircraftConstants",
    "AircraftModel",
    "Linearization",
    "TrimResult",
    "decoupled",
    "isa_density",
    "lateral",
    "lateral_linear",
    "linearize",
    "longitudinal",
    "longitudinal_linear",
    "model_from_config",
    "six_dof",
    "trim",
]

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
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ModelDefinitionError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ModelDefinitionError(f"{name}: {value!r} is not finite")
    return v


def _position(name: str, value: Any) -> tuple[float, float, float]:
    try:
        items = tuple(value)
    except TypeError:
        raise ModelDefinitionError(
            f"{name}: expected three body-axis coordinates (x, y, z) in m, got {value!r}"
        ) from None
    if len(items) != 3:
        raise ModelDefinitionError(
            f"{name}: expected three body-axis coordinates (x, y, z) in m, got {len(items)}"
        )
    x, y, z = (_finite(f"{name}[{i}]", c) for i, c in enumerate(items))
    return (x, y, z)


_LATERAL_ONLY = ("Ixx", "Izz", "b")


@dataclass(frozen=True)
class AircraftConstants:
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
        for name in ("Ixz", "thrust_angle", "thrust_offset"):
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
        if not self.lateral_complete:
            return
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
# constant term has no factors.
_Expansion = tuple[tuple[str, tuple[str, ...]], ...]

_CONSTANT_TERMS = ("0", "1", "const")

_REGRESSOR_TEXT = {
    "alpha": "α",
    "beta": "β",
    "V": "(V/V0 - 1)",
    "p": "p b/(2V)",
    "q": "q c̄/(2V)",
    "r": "r b/(2V)",
    "alpha_dot": "α̇ c̄/(2V)",
}


def _expand(expansion: _Expansion, regressors: Mapping[str, Any], p: Mapping[str, Any]) -> Any:
    """Sum of parameter × product of regressors; plain arithmetic so any array namespace works."""
    total: Any = 0.0
    for name, factors in expansion:
        term = p[name]
        for f in factors:
            term = term * regressors[f]
        total = total + term
    return total


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
                factors = tuple(text.split("*"))
                bad = [f for f in factors if f not in regressors]
                if bad:
                    raise ModelDefinitionError(
                        f"terms[{coefficient!r}]: {item!r} uses {bad}, which the {model} model "
                        f"does not have; its regressors are {list(regressors)} and the "
                        f"constant '0' (products as 'alpha*delta_e')"
                    )
            name = f"{coefficient}_{'_'.join(factors) if factors else '0'}"
            if any(name == n for n, _ in expansion):
                raise ModelDefinitionError(f"terms[{coefficient!r}]: term {item!r} given twice")
            expansion.append((name, factors))
        out[coefficient] = tuple(expansion)
    return out


def _expansion_text(coefficient: str, expansion: _Expansion) -> str:
    if not expansion:
        return f"{coefficient} = 0"
    parts = []
    for name, factors in expansion:
        reg = " ".join(_REGRESSOR_TEXT.get(f, f) for f in factors)
        parts.append(f"{name} {reg}".rstrip())
    return f"{coefficient} = " + " + ".join(parts)


# units of the regressors of the non-dimensional coefficient expansions: angles in
# rad, V as V/V0 - 1 and the rates as p b/(2V), q c̄/(2V), r b/(2V) (dimensionless)
_COEFFICIENT_REGRESSOR_UNITS: Mapping[str, _units.Unit] = {
    "alpha": _units.RADIAN,
    "beta": _units.RADIAN,
    "V": _units.ONE,
    "p": _units.ONE,
    "q": _units.ONE,
    "r": _units.ONE,
    "alpha_dot": _units.ONE,
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
) -> dict[str, str]:
    """Each term's parameter unit: its equation's unit (dimensionless coefficients when
    `equations` is None) over its regressors' (a surface deflection in rad)."""
    regs = _LINEAR_REGRESSOR_UNITS if linear else _COEFFICIENT_REGRESSOR_UNITS
    out = {}
    for coefficient, expansion in expansions.items():
        lhs = _units.ONE if equations is None else equations[coefficient]
        for name, factors in expansion:
            out[name] = _units.ratio(
                lhs, [regs.get(f, _units.RADIAN) for f in factors], keep_radians=not linear
            )
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
            raise ModelDefinitionError(f"surfaces: {s!r} is already a regressor name")
    if len(set(names)) != len(names):
        raise ModelDefinitionError(f"surfaces: duplicate names in {list(names)}")
    return names


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


def _channel_units(names: Sequence[str], accel_units: str) -> dict[str, str]:
    accel = "g" if accel_units == "g" else "m/s²"
    return {n: accel if n in ("ax", "ay", "az") else _CHANNEL_UNITS.get(n, "rad") for n in names}


def _aircraft_model(
    kind: str,
    function: Callable[..., Callable[[Any, Any, Any, Any], Any]],
    args: tuple[Any, ...],
    *,
    version: str | None,
    accel_units: str = "m/s2",
    **fields: Any,
) -> AircraftModel:
    """The model whose dynamics and measurement are ``function(*args, role)``.

    `args` (constants, reference condition, terms, options) are also folded
    into the version, as the function source is the same for every such model.
    """
    names = [*fields["states"], *fields["controls"], *fields["outputs"]]
    return AircraftModel(
        dynamics=function(*args, "dynamics"),
        measurement=function(*args, "measurement"),
        version=_content_version(version, kind, *args),
        kind=kind,
        channel_units=_channel_units(names, accel_units),
        **fields,
    )


# -- longitudinal, stability axes ------------------------------------------------------------

_LONG_OUTPUTS = ("V", "alpha", "theta", "q", "q_dot", "ax", "az", "h", "gamma")
_LONG_DEFAULT_OUTPUTS = ("V", "alpha", "theta", "q", "q_dot", "ax", "az")
_LONG_DEFAULT_TERMS: Mapping[str, Sequence[str]] = {
    "CD": ("0", "alpha", "delta_e"),
    "CL": ("0", "alpha", "q", "delta_e"),
    "Cm": ("0", "alpha", "q", "delta_e"),
}


def _longitudinal_function(
    c: AircraftConstants,
    V0: float,
    expansions: Mapping[str, _Expansion],
    surfaces: tuple[str, ...],
    thrust: bool,
    with_altitude: bool,
    outputs: tuple[str, ...],
    accel_scale: float,
    rate_V0: bool,
    role: str,
) -> Callable[[Any, Any, Any, Any], Any]:
    m, S, cbar, Iyy, g = c.mass, c.S, c.cbar, c.Iyy, c.g
    half_rho_S = 0.5 * c.density() * S
    half_cbar = 0.5 * cbar
    sigma, d = c.thrust_angle, c.thrust_offset
    cos_sigma, sin_sigma = math.cos(sigma), math.sin(sigma)
    xa, _, za = c.accel_position
    xv, _, zv = c.alpha_vane_position
    inv_V0 = 1.0 / V0
    cd, cm = expansions["CD"], expansions["Cm"]
    # CL's alpha-dot terms make the alpha equation implicit (linear in alpha-dot):
    # split them off and solve for alpha-dot before the other coefficients use it.
    cl = tuple(e for e in expansions["CL"] if e[1] != ("alpha_dot",))
    cl_alpha_dot = [n for n, f in expansions["CL"] if f == ("alpha_dot",)]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"

    def longitudinal_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # Klein & Morelli (2006) ch. 3 wind/stability-axis force equations, beta = 0.
        V, alpha, theta, q = x[0], x[1], x[2], x[3]
        # nondimensional rates over the airspeed, or over V0 (the linearised book form)
        V_rate = V0 + 0.0 * V if rate_V0 else V
        reg = {"alpha": alpha, "V": V * inv_V0 - 1.0, "q": q * half_cbar / V_rate}
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        T = u[n_surf] if thrust else 0.0 * V
        qbar_S = half_rho_S * V * V
        gamma = theta - alpha
        CL = _expand(cl, reg, p)
        alpha_dot = q + (g * np.cos(gamma) - (qbar_S * CL + T * np.sin(alpha + sigma)) / m) / V
        if cl_alpha_dot:
            # CL = CL' + CL_alpha_dot α̇ c̄/(2V) in the α equation, solved for α̇
            k = p[cl_alpha_dot[0]] * half_cbar / V_rate
            alpha_dot = alpha_dot / (1.0 + qbar_S * k / (m * V))
            CL = CL + k * alpha_dot
        reg["alpha_dot"] = alpha_dot * half_cbar / V_rate
        CD = _expand(cd, reg, p)
        Cm = _expand(cm, reg, p)
        V_dot = (T * np.cos(alpha + sigma) - qbar_S * CD) / m - g * np.sin(gamma)
        q_dot = (qbar_S * cbar * Cm + T * d) / Iyy
        if dynamics:
            rates = [V_dot, alpha_dot, q, q_dot]
            if with_altitude:
                rates.append(V * np.sin(gamma))
            return np.stack(np.broadcast_arrays(*rates))
        ca, sa = np.cos(alpha), np.sin(alpha)
        # body-axis specific force at the c.g., then at the accelerometer (rigid body)
        ax = (qbar_S * (CL * sa - CD * ca) + T * cos_sigma) / m - q * q * xa + q_dot * za
        az = (qbar_S * (-CD * sa - CL * ca) - T * sin_sigma) / m - q * q * za - q_dot * xa
        values = {
            "V": V,
            "alpha": np.arctan2(V * sa - q * xv, V * ca + q * zv),
            "theta": theta,
            "q": q,
            "q_dot": q_dot,
            "ax": ax * accel_scale,
            "az": az * accel_scale,
            "gamma": gamma,
        }
        if with_altitude:
            values["h"] = x[4]
        return np.stack(np.broadcast_arrays(*[values[k] for k in outputs]))

    return longitudinal_equations


def _alpha_dot_alone(expansions: Mapping[str, _Expansion]) -> None:
    """The α̇ regressor enters linearly (so the α equation stays solvable): never in a product."""
    for coefficient, expansion in expansions.items():
        for name, factors in expansion:
            if "alpha_dot" in factors and len(factors) > 1:
                raise ModelDefinitionError(
                    f"terms[{coefficient!r}]: {name!r} multiplies alpha_dot by another "
                    "regressor; alpha_dot may only enter alone"
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


def longitudinal(
    constants: AircraftConstants,
    *,
    V0: float,
    terms: Mapping[str, Sequence[str]] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    surfaces: Sequence[str] = ("delta_e",),
    thrust: bool = True,
    with_altitude: bool = False,
    accel_units: str = "m/s2",
    rate_reference: str = "V",
    name: str = "longitudinal",
    version: str | None = None,
) -> AircraftModel:
    """Nonlinear longitudinal model in stability (wind) axes, Klein & Morelli ch. 3 form.

    States ``V`` (m/s), ``alpha`` (rad), ``theta`` (rad), ``q`` (rad/s), and
    ``h`` (m) with `with_altitude`; controls the `surfaces` (rad) and
    ``thrust`` (N)::

        V̇ = (T cos(α + σT) - q̄ S CD) / m - g sin(θ - α)
        α̇ = q + [g cos(θ - α) - (q̄ S CL + T sin(α + σT)) / m] / V
        θ̇ = q
        q̇ = (q̄ S c̄ Cm + T dT) / Iyy
        ḣ = V sin(θ - α)

    with ``q̄ = ρ V² / 2`` (ρ constant), σT and dT the thrust line's angle and
    offset (`AircraftConstants.thrust_angle`, `thrust_offset`), and each of
    CD, CL, Cm a linear-in-parameters expansion whose terms are chosen with
    `terms`: regressors ``alpha``, ``V`` (``V/V0 - 1``), ``q`` (``q c̄ / 2V``),
    each surface, their products (``"alpha*delta_e"``) and the constant
    ``"0"``; the parameters are named ``CL_alpha``, ``Cm_q``, ``CD_0``,
    ``CL_alpha_delta_e``.

    The regressor ``alpha_dot`` (``α̇ c̄ / 2V``, alone, never in a product)
    adds the unsteady terms ``CL_alpha_dot``, ``Cm_alpha_dot``,
    ``CD_alpha_dot``. α̇ is the model's own: with ``CL_alpha_dot`` the α
    equation is linear in α̇ and is solved for it, ``α̇ (1 + q̄ S CL_alpha_dot
    c̄ / (2 m V²)) = q + [g cos(θ - α) - (q̄ S CL' + T sin(α + σT)) / m] / V``
    with ``CL'`` the rest of CL (Klein & Morelli ch. 3). Without an
    ``alpha_dot`` term the α̇ effects are lumped into the α, q and surface
    terms, and ``Cm_q`` is the damping sum ``Cm_q + Cm_alpha_dot``; α̇ and q
    move almost together in a short-period response, so the two are told apart
    only by rich inputs and little turbulence.

    Outputs (any of): ``V``, ``alpha`` (at the α vane:
    ``atan2(V sin α - q xα, V cos α + q zα)``), ``theta``, ``q``, ``q_dot``,
    ``ax``, ``az`` (accelerometer specific force in body axes, with
    ``ax = ax_cg - q² xa + q̇ za``, ``az = az_cg - q² za - q̇ xa``), ``h``
    (with `with_altitude`) and ``gamma`` (``θ - α``).

    Parameters
    ----------
    constants : AircraftConstants
    V0 : float
        Reference airspeed, m/s, of the ``V`` regressor.
    terms : mapping of str to sequence of str, optional
        Terms per coefficient (``CD``, ``CL``, ``Cm``); default ``CD: 0, alpha,
        delta_e``, ``CL`` and ``Cm``: ``0, alpha, q, delta_e`` (11 parameters).
    parameters : mapping of str to float, optional
        Nominal values; parameters not given start at zero.
    outputs : sequence of str, optional
        Default ``V, alpha, theta, q, q_dot, ax, az``.
    surfaces : sequence of str
        Control-surface inputs, rad; the first is the one `trim` sets.
    thrust : bool
        Whether ``thrust`` (N) is a control (last).
    with_altitude : bool
        Add the state ``h``.
    accel_units : {"m/s2", "g"}
        Units of ``ax``, ``az``: those of `AircraftConstants.g` (m/s², or
        ft/s² with US constants), or g, divided by the constants' own g.
    rate_reference : {"V", "V0"}
        The airspeed that makes ``q`` and ``alpha_dot`` nondimensional:
        ``q c̄ / 2V`` with the current airspeed, or ``q c̄ / 2V0`` with the
        reference one (the linearised textbook form, Klein & Morelli ch. 3).
    name, version : str
        As for `aeroid.Model`; the constants and terms are folded into the version.

    Returns
    -------
    AircraftModel
        Of kind ``"longitudinal"``, reference ``V0``.

    Raises
    ------
    ModelDefinitionError
        Unknown terms, outputs or parameter names, or bad constants.
    """
    c = _check_constants(constants)
    V0 = _check_speed(V0)
    surf = _surfaces(surfaces, ("alpha", "V", "q", "alpha_dot", "thrust"))
    expansions = _parse_expansions(
        terms, _LONG_DEFAULT_TERMS, ("alpha", "V", "q", "alpha_dot", *surf), "longitudinal"
    )
    _alpha_dot_alone(expansions)
    values = _parameter_values(expansions, parameters)
    allowed = [o for o in _LONG_OUTPUTS if with_altitude or o != "h"]
    outs = _outputs(outputs, _LONG_DEFAULT_OUTPUTS, allowed)
    scale = _accel_scale(accel_units, c.g)
    rate_V0 = _check_rate_reference(rate_reference) == "V0"
    states = ["V", "alpha", "theta", "q"] + (["h"] if with_altitude else [])
    controls = [*surf] + (["thrust"] if thrust else [])
    args = (c, V0, expansions, surf, bool(thrust), bool(with_altitude), outs, scale, rate_V0)
    equations = "\n".join(
        [
            "Klein & Morelli ch. 3, stability (wind) axes, β = 0, q̄ = ρ V²/2:",
            "  V̇ = (T cos(α + σT) - q̄ S CD)/m - g sin(θ - α)",
            "  α̇ = q + [g cos(θ - α) - (q̄ S CL + T sin(α + σT))/m] / V",
            "  θ̇ = q",
            "  q̇ = (q̄ S c̄ Cm + T dT)/Iyy",
            *(["  ḣ = V sin(θ - α)"] if with_altitude else []),
            *(
                ["  α̇ enters as α̇ c̄/(2V); a CL_alpha_dot term is solved for in the α equation"]
                if any("alpha_dot" in f for e in expansions.values() for _, f in e)
                else []
            ),
            f"  σT = {c.thrust_angle:.6g} rad, dT = {c.thrust_offset:.6g} m"
            + ("" if thrust else " (no thrust input: T = 0)"),
            *(f"  {_expansion_text(k, e)}" for k, e in expansions.items()),
            "outputs:",
            "  α (vane at xα, zα) = atan2(V sin α - q xα, V cos α + q zα);  γ = θ - α",
            "  ax = [q̄ S (CL sin α - CD cos α) + T cos σT]/m - q² xa + q̇ za",
            "  az = [q̄ S (-CD sin α - CL cos α) - T sin σT]/m - q² za - q̇ xa",
            "  " + _accel_text("body axes", accel_units),
        ]
    )
    return _aircraft_model(
        "longitudinal",
        _longitudinal_function,
        args,
        states=states,
        controls=controls,
        parameters=values,
        outputs=outs,
        name=name,
        version=version,
        accel_units=accel_units,
        constants=c,
        reference={"V0": V0},
        surfaces=surf,
        equations=equations,
        parameter_units=_expansion_units(expansions, None, linear=False),
    )


# -- lateral-directional -----------------------------------------------------------------------

_LAT_OUTPUTS = ("beta", "p", "r", "phi", "psi", "p_dot", "r_dot", "ay")
_LAT_DEFAULT_OUTPUTS = ("beta", "p", "r", "phi", "p_dot", "r_dot", "ay")
_LAT_DEFAULT_TERMS: Mapping[str, Sequence[str]] = {
    "CY": ("0", "beta", "p", "r", "delta_a", "delta_r"),
    "Cl": ("0", "beta", "p", "r", "delta_a", "delta_r"),
    "Cn": ("0", "beta", "p", "r", "delta_a", "delta_r"),
}


def _lateral_function(
    c: AircraftConstants,
    V0: float,
    alpha0: float,
    theta0: float,
    expansions: Mapping[str, _Expansion],
    surfaces: tuple[str, ...],
    with_heading: bool,
    outputs: tuple[str, ...],
    accel_scale: float,
    role: str,
) -> Callable[[Any, Any, Any, Any], Any]:
    m, S, b, g = c.mass, c.S, c.b, c.g
    qbar_S = 0.5 * c.density() * V0 * V0 * S
    gamma_i = c.Ixx * c.Izz - c.Ixz**2
    Ixx, Izz, Ixz = c.Ixx, c.Izz, c.Ixz
    half_b_V0 = 0.5 * b / V0
    sin_a0, cos_a0 = math.sin(alpha0), math.cos(alpha0)
    g_V0 = g * math.cos(theta0) / V0
    tan_t0, sec_t0 = math.tan(theta0), 1.0 / math.cos(theta0)
    xa, ya, za = c.accel_position
    xb, _, zb = c.beta_vane_position
    cy, cl, cn = expansions["CY"], expansions["Cl"], expansions["Cn"]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"

    def lateral_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # Klein & Morelli ch. 3 small-perturbation lateral equations about (V0, α0, θ0),
        # body-axis rates, q = 0.
        beta, p_, r, phi = x[0], x[1], x[2], x[3]
        reg = {"beta": beta, "p": p_ * half_b_V0, "r": r * half_b_V0}
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        CY = _expand(cy, reg, p) + 0.0 * beta
        Cl = _expand(cl, reg, p)
        Cn = _expand(cn, reg, p)
        rolling = qbar_S * b * Cl
        yawing = qbar_S * b * Cn
        p_dot = (Izz * rolling + Ixz * yawing) / gamma_i
        r_dot = (Ixz * rolling + Ixx * yawing) / gamma_i
        cos_phi = np.cos(phi)
        if dynamics:
            beta_dot = qbar_S * CY / (m * V0) + p_ * sin_a0 - r * cos_a0 + g_V0 * np.sin(phi)
            rates = [beta_dot, p_dot, r_dot, p_ + tan_t0 * r * cos_phi]
            if with_heading:
                rates.append(r * cos_phi * sec_t0)
            return np.stack(np.broadcast_arrays(*rates))
        # accelerometer: F_y/m + (ω̇ × r + ω × (ω × r))_y with q = 0
        ay = qbar_S * CY / m + r_dot * xa - (p_ * p_ + r * r) * ya - p_dot * za
        values = {
            "beta": beta + (r * xb - p_ * zb) / V0,
            "p": p_,
            "r": r,
            "phi": phi,
            "p_dot": p_dot,
            "r_dot": r_dot,
            "ay": ay * accel_scale,
        }
        if with_heading:
            values["psi"] = x[4]
        return np.stack(np.broadcast_arrays(*[values[k] for k in outputs]))

    return lateral_equations


def lateral(
    constants: AircraftConstants,
    *,
    V0: float,
    alpha0: float = 0.0,
    theta0: float = 0.0,
    terms: Mapping[str, Sequence[str]] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    surfaces: Sequence[str] = ("delta_a", "delta_r"),
    with_heading: bool = False,
    accel_units: str = "m/s2",
    name: str = "lateral",
    version: str | None = None,
) -> AircraftModel:
    """Lateral-directional model about a trim (V0, α0, θ0), Klein & Morelli ch. 3 form.

    States ``beta`` (rad), ``p``, ``r`` (body-axis rates, rad/s), ``phi``
    (rad), and ``psi`` with `with_heading`; controls the `surfaces`
    (default ``delta_a``, ``delta_r``, rad)::

        β̇ = q̄ S CY / (m V0) + p sin α0 - r cos α0 + (g/V0) cos θ0 sin φ
        Ixx ṗ - Ixz ṙ = q̄ S b Cl
        Izz ṙ - Ixz ṗ = q̄ S b Cn
        φ̇ = p + tan θ0 r cos φ
        ψ̇ = r cos φ / cos θ0

    with ``q̄ = ρ V0² / 2``, and CY, Cl, Cn linear-in-parameters expansions in
    ``beta``, ``p`` (``p b / 2V0``), ``r`` (``r b / 2V0``), the surfaces,
    their products and the constant ``"0"``; parameters named ``Cl_p``,
    ``Cn_beta``, ``Cn_delta_r``, ``CY_0``.

    Outputs (any of): ``beta`` (at the β vane: ``β + (r xβ - p zβ)/V0``),
    ``p``, ``r``, ``phi``, ``psi``, ``p_dot``, ``r_dot``, ``ay``
    (``q̄ S CY / m + ṙ xa - (p² + r²) ya - ṗ za``).

    Parameters
    ----------
    constants : AircraftConstants
    V0, alpha0, theta0 : float
        Trim airspeed (m/s), angle of attack and pitch angle (rad).
    terms : mapping of str to sequence of str, optional
        Terms per coefficient (``CY``, ``Cl``, ``Cn``); default each
        ``0, beta, p, r, delta_a, delta_r`` (18 parameters).
    parameters : mapping of str to float, optional
        Nominal values; parameters not given start at zero.
    outputs : sequence of str, optional
        Default ``beta, p, r, phi, p_dot, r_dot, ay``.
    surfaces : sequence of str
        Control-surface inputs, rad; `trim` sets the first two.
    with_heading : bool
        Add the state ``psi``.
    accel_units : {"m/s2", "g"}
    name, version : str

    Returns
    -------
    AircraftModel
        Of kind ``"lateral"``, reference ``V0``, ``alpha0``, ``theta0``.

    Raises
    ------
    ModelDefinitionError
        Unknown terms, outputs or parameter names, bad constants, or a trim pitch
        angle `theta0` outside ±π/2.
    """
    c = _check_constants(constants, "lateral")
    V0 = _check_speed(V0)
    alpha0, theta0 = _check_trim_angles(alpha0, theta0)
    surf = _surfaces(surfaces, ("beta", "p", "r"))
    expansions = _parse_expansions(terms, _LAT_DEFAULT_TERMS, ("beta", "p", "r", *surf), "lateral")
    values = _parameter_values(expansions, parameters)
    allowed = [o for o in _LAT_OUTPUTS if with_heading or o != "psi"]
    outs = _outputs(outputs, _LAT_DEFAULT_OUTPUTS, allowed)
    scale = _accel_scale(accel_units, c.g)
    states = ["beta", "p", "r", "phi"] + (["psi"] if with_heading else [])
    args = (c, V0, alpha0, theta0, expansions, surf, bool(with_heading), outs, scale)
    equations = "\n".join(
        [
            "Klein & Morelli ch. 3, small perturbations about (V0, α0, θ0), body-axis rates,"
            " q̄ = ρ V0²/2:",
            "  β̇ = q̄ S CY/(m V0) + p sin α0 - r cos α0 + (g/V0) cos θ0 sin φ",
            "  Ixx ṗ - Ixz ṙ = q̄ S b Cl",
            "  Izz ṙ - Ixz ṗ = q̄ S b Cn",
            "  φ̇ = p + tan θ0 r cos φ",
            *(["  ψ̇ = r cos φ / cos θ0"] if with_heading else []),
            *(f"  {_expansion_text(k, e).replace('(2V)', '(2V0)')}" for k, e in expansions.items()),
            "outputs:",
            "  β (vane at xβ, zβ) = β + (r xβ - p zβ)/V0",
            "  ay = q̄ S CY/m + ṙ xa - (p² + r²) ya - ṗ za",
            "  " + _accel_text("body axes", accel_units),
        ]
    )
    return _aircraft_model(
        "lateral",
        _lateral_function,
        args,
        states=states,
        controls=list(surf),
        parameters=values,
        outputs=outs,
        name=name,
        version=version,
        accel_units=accel_units,
        constants=c,
        reference={"V0": V0, "alpha0": alpha0, "theta0": theta0},
        surfaces=surf,
        equations=equations,
        parameter_units=_expansion_units(expansions, None, linear=False),
    )


# -- six degrees of freedom, body axes ------------------------------------------------------------

_SIX_STATES = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
_SIX_OUTPUTS = (
    *_SIX_STATES,
    "V",
    "alpha",
    "beta",
    "p_dot",
    "q_dot",
    "r_dot",
    "ax",
    "ay",
    "az",
    "gamma",
    "north",
    "east",
    "h",
)
_SIX_DEFAULT_OUTPUTS = (
    "V",
    "alpha",
    "beta",
    "p",
    "q",
    "r",
    "phi",
    "theta",
    "psi",
    "p_dot",
    "q_dot",
    "r_dot",
    "ax",
    "ay",
    "az",
)
_LATERAL_TERMS = ("beta", "p", "r", "delta_a", "delta_r")
_SIX_DEFAULT_TERMS: dict[str, Mapping[str, Sequence[str]]] = {
    "stability": {
        "CD": ("0", "alpha", "delta_e"),
        "CY": _LATERAL_TERMS,
        "CL": ("0", "alpha", "q", "delta_e"),
        "Cl": _LATERAL_TERMS,
        "Cm": ("0", "alpha", "q", "delta_e"),
        "Cn": _LATERAL_TERMS,
    },
    "body": {
        "CX": ("0", "alpha", "delta_e"),
        "CY": _LATERAL_TERMS,
        "CZ": ("0", "alpha", "q", "delta_e"),
        "Cl": _LATERAL_TERMS,
        "Cm": ("0", "alpha", "q", "delta_e"),
        "Cn": _LATERAL_TERMS,
    },
}


def _six_dof_function(
    c: AircraftConstants,
    V0: float,
    expansions: Mapping[str, _Expansion],
    surfaces: tuple[str, ...],
    thrust: bool,
    stability: bool,
    position: bool,
    outputs: tuple[str, ...],
    accel_scale: float,
    role: str,
) -> Callable[[Any, Any, Any, Any], Any]:
    m, S, b, cbar, g = c.mass, c.S, c.b, c.cbar, c.g
    Ixx, Iyy, Izz, Ixz = c.Ixx, c.Iyy, c.Izz, c.Ixz
    gamma_i = Ixx * Izz - Ixz**2
    half_rho_S = 0.5 * c.density() * S
    half_b, half_cbar = 0.5 * b, 0.5 * cbar
    inv_V0 = 1.0 / V0
    d = c.thrust_offset
    cos_sigma, sin_sigma = math.cos(c.thrust_angle), math.sin(c.thrust_angle)
    xa, ya, za = c.accel_position
    xv, yv, zv = c.alpha_vane_position
    xb, yb, zb = c.beta_vane_position
    if stability:
        c_long, c_lift = expansions["CD"], expansions["CL"]
    else:
        c_long, c_lift = expansions["CX"], expansions["CZ"]
    cy, cl, cm, cn = expansions["CY"], expansions["Cl"], expansions["Cm"], expansions["Cn"]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"

    def six_dof_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # Body-axis rigid-body equations with Euler angles (Klein & Morelli ch. 3,
        # Stevens & Lewis), flat non-rotating Earth, constant air density.
        u_, v, w, p_, q, r = x[0], x[1], x[2], x[3], x[4], x[5]
        phi, theta, psi = x[6], x[7], x[8]
        V = np.sqrt(u_ * u_ + v * v + w * w)
        alpha = np.arctan2(w, u_)
        beta = np.arcsin(v / V)
        reg = {
            "alpha": alpha,
            "beta": beta,
            "V": V * inv_V0 - 1.0,
            "p": p_ * half_b / V,
            "q": q * half_cbar / V,
            "r": r * half_b / V,
        }
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        T = u[n_surf] if thrust else 0.0 * V
        qbar_S = half_rho_S * V * V
        ca, sa = np.cos(alpha), np.sin(alpha)
        if stability:
            CD = _expand(c_long, reg, p)
            CL = _expand(c_lift, reg, p)
            CX = CL * sa - CD * ca
            CZ = -CD * sa - CL * ca
        else:
            CX = _expand(c_long, reg, p)
            CZ = _expand(c_lift, reg, p)
        CY = _expand(cy, reg, p)
        fx = (qbar_S * CX + T * cos_sigma) / m
        fy = qbar_S * CY / m
        fz = (qbar_S * CZ - T * sin_sigma) / m
        rolling = qbar_S * b * _expand(cl, reg, p) + (Iyy - Izz) * q * r + Ixz * p_ * q
        yawing = qbar_S * b * _expand(cn, reg, p) + (Ixx - Iyy) * p_ * q - Ixz * q * r
        pitching = qbar_S * cbar * _expand(cm, reg, p) + T * d
        p_dot = (Izz * rolling + Ixz * yawing) / gamma_i
        r_dot = (Ixz * rolling + Ixx * yawing) / gamma_i
        q_dot = (pitching + (Izz - Ixx) * p_ * r + Ixz * (r * r - p_ * p_)) / Iyy
        sphi, cphi = np.sin(phi), np.cos(phi)
        sth, cth = np.sin(theta), np.cos(theta)
        h_dot = u_ * sth - v * sphi * cth - w * cphi * cth
        if dynamics:
            rates = [
                fx + r * v - q * w - g * sth,
                fy + p_ * w - r * u_ + g * cth * sphi,
                fz + q * u_ - p_ * v + g * cth * cphi,
                p_dot,
                q_dot,
                r_dot,
                p_ + (q * sphi + r * cphi) * sth / cth,
                q * cphi - r * sphi,
                (q * sphi + r * cphi) / cth,
            ]
            if position:
                spsi, cpsi = np.sin(psi), np.cos(psi)
                rates.append(
                    u_ * cth * cpsi
                    + v * (sphi * sth * cpsi - cphi * spsi)
                    + w * (cphi * sth * cpsi + sphi * spsi)
                )
                rates.append(
                    u_ * cth * spsi
                    + v * (sphi * sth * spsi + cphi * cpsi)
                    + w * (cphi * sth * spsi - sphi * cpsi)
                )
                rates.append(h_dot)
            return np.stack(np.broadcast_arrays(*rates))
        # accelerometer: F/m + ω̇ × r + ω × (ω × r)
        wx, wy, wz = q * za - r * ya, r * xa - p_ * za, p_ * ya - q * xa
        ax = fx + q_dot * za - r_dot * ya + q * wz - r * wy
        ay = fy + r_dot * xa - p_dot * za + r * wx - p_ * wz
        az = fz + p_dot * ya - q_dot * xa + p_ * wy - q * wx
        # air-data vanes see the local airflow u + ω × r
        uv, wv = u_ + q * zv - r * yv, w + p_ * yv - q * xv
        ub, vb, wb = u_ + q * zb - r * yb, v + r * xb - p_ * zb, w + p_ * yb - q * xb
        values = {
            "u": u_,
            "v": v,
            "w": w,
            "p": p_,
            "q": q,
            "r": r,
            "phi": phi,
            "theta": theta,
            "psi": psi,
            "V": V,
            "alpha": np.arctan2(wv, uv),
            "beta": np.arcsin(vb / np.sqrt(ub * ub + vb * vb + wb * wb)),
            "p_dot": p_dot,
            "q_dot": q_dot,
            "r_dot": r_dot,
            "ax": ax * accel_scale,
            "ay": ay * accel_scale,
            "az": az * accel_scale,
            "gamma": np.arcsin(h_dot / V),
        }
        if position:
            values["north"], values["east"], values["h"] = x[9], x[10], x[11]
        return np.stack(np.broadcast_arrays(*[values[k] for k in outputs]))

    return six_dof_equations


def six_dof(
    constants: AircraftConstants,
    *,
    V0: float,
    terms: Mapping[str, Sequence[str]] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    surfaces: Sequence[str] = ("delta_e", "delta_a", "delta_r"),
    thrust: bool = True,
    force_axes: str = "stability",
    position: bool = False,
    accel_units: str = "m/s2",
    name: str = "six_dof",
    version: str | None = None,
) -> AircraftModel:
    """Nonlinear six-degree-of-freedom model in body axes (Klein & Morelli ch. 3 form).

    States ``u, v, w`` (m/s), ``p, q, r`` (rad/s), ``phi, theta, psi`` (rad),
    and ``north, east, h`` (m) with `position`; controls the `surfaces` (rad)
    and ``thrust`` (N). Flat, non-rotating Earth; constant air density::

        u̇ = X/m + r v - q w - g sin θ
        v̇ = Y/m + p w - r u + g cos θ sin φ
        ẇ = Z/m + q u - p v + g cos θ cos φ
        Ixx ṗ - Ixz ṙ = q̄ S b Cl + (Iyy - Izz) q r + Ixz p q
        Iyy q̇ = q̄ S c̄ Cm + T dT + (Izz - Ixx) p r + Ixz (r² - p²)
        Izz ṙ - Ixz ṗ = q̄ S b Cn + (Ixx - Iyy) p q - Ixz q r
        φ̇ = p + (q sin φ + r cos φ) tan θ
        θ̇ = q cos φ - r sin φ
        ψ̇ = (q sin φ + r cos φ) / cos θ

    with ``X = q̄ S CX + T cos σT``, ``Y = q̄ S CY``, ``Z = q̄ S CZ - T sin σT``,
    ``V = √(u² + v² + w²)``, ``α = atan2(w, u)``, ``β = asin(v / V)``. With
    ``force_axes="stability"`` the force coefficients are CD, CY, CL
    (``CX = -CD cos α + CL sin α``, ``CZ = -CD sin α - CL cos α``); with
    ``"body"`` they are CX, CY, CZ. Every coefficient is a linear-in-parameters
    expansion in ``alpha``, ``beta``, ``V`` (``V/V0 - 1``), ``p``, ``q``,
    ``r`` (``p b/2V``, ``q c̄/2V``, ``r b/2V``), the surfaces, their products
    and the constant ``"0"``.

    Outputs (any of): the states, ``V``, ``alpha`` and ``beta`` at their
    vanes (from the local airflow ``(u, v, w) + ω × r``), ``p_dot``,
    ``q_dot``, ``r_dot``, ``ax, ay, az`` (accelerometer specific force
    ``F/m + ω̇ × r + ω × (ω × r)``) and ``gamma`` (``asin(ḣ / V)``).

    Parameters
    ----------
    constants : AircraftConstants
    V0 : float
        Reference airspeed of the ``V`` regressor, m/s.
    terms : mapping of str to sequence of str, optional
        Terms per coefficient. Default: ``CD: 0, alpha, delta_e``;
        ``CL, Cm: 0, alpha, q, delta_e``; ``CY, Cl, Cn: beta, p, r, delta_a,
        delta_r`` (26 parameters; CX, CZ in place of CD, CL in body axes).
    parameters : mapping of str to float, optional
        Nominal values; parameters not given start at zero.
    outputs : sequence of str, optional
    surfaces : sequence of str
        Control-surface inputs, rad; `trim` sets the first three (elevator,
        aileron, rudder).
    thrust : bool
        Whether ``thrust`` (N) is a control (last).
    force_axes : {"stability", "body"}
    position : bool
        Add the states ``north``, ``east``, ``h``.
    accel_units : {"m/s2", "g"}
    name, version : str

    Returns
    -------
    AircraftModel
        Of kind ``"six_dof"``, reference ``V0``.

    Raises
    ------
    ModelDefinitionError
        Unknown terms, outputs or parameter names, bad constants, or an unknown
        `force_axes`.
    """
    c = _check_constants(constants, "six-degree-of-freedom")
    V0 = _check_speed(V0)
    if force_axes not in _SIX_DEFAULT_TERMS:
        raise ModelDefinitionError(
            f"force_axes: expected 'stability' or 'body', got {force_axes!r}"
        )
    surf = _surfaces(surfaces, ("alpha", "beta", "V", "p", "q", "r", "thrust"))
    expansions = _parse_expansions(
        terms,
        _SIX_DEFAULT_TERMS[force_axes],
        ("alpha", "beta", "V", "p", "q", "r", *surf),
        "six-degree-of-freedom",
    )
    values = _parameter_values(expansions, parameters)
    nav = ("north", "east", "h")
    allowed = [o for o in _SIX_OUTPUTS if position or o not in nav]
    outs = _outputs(outputs, _SIX_DEFAULT_OUTPUTS, allowed)
    scale = _accel_scale(accel_units, c.g)
    states = [*_SIX_STATES] + (list(nav) if position else [])
    stability = force_axes == "stability"
    args = (c, V0, expansions, surf, bool(thrust), stability, bool(position), outs, scale)
    force_text = (
        ["  CX = -CD cos α + CL sin α,  CZ = -CD sin α - CL cos α  (CD, CL stability axes)"]
        if stability
        else []
    )
    equations = "\n".join(
        [
            "Klein & Morelli ch. 3, body axes, Euler angles, flat Earth, q̄ = ρ V²/2:",
            "  u̇ = (q̄ S CX + T cos σT)/m + r v - q w - g sin θ",
            "  v̇ = q̄ S CY/m + p w - r u + g cos θ sin φ",
            "  ẇ = (q̄ S CZ - T sin σT)/m + q u - p v + g cos θ cos φ",
            "  Ixx ṗ - Ixz ṙ = q̄ S b Cl + (Iyy - Izz) q r + Ixz p q",
            "  Iyy q̇ = q̄ S c̄ Cm + T dT + (Izz - Ixx) p r + Ixz (r² - p²)",
            "  Izz ṙ - Ixz ṗ = q̄ S b Cn + (Ixx - Iyy) p q - Ixz q r",
            "  φ̇ = p + (q sin φ + r cos φ) tan θ",
            "  θ̇ = q cos φ - r sin φ",
            "  ψ̇ = (q sin φ + r cos φ)/cos θ",
            *(
                [
                    "  north' = u cθ cψ + v (sφ sθ cψ - cφ sψ) + w (cφ sθ cψ + sφ sψ)",
                    "  east'  = u cθ sψ + v (sφ sθ sψ + cφ cψ) + w (cφ sθ sψ - sφ cψ)",
                    "  ḣ = u sin θ - v sin φ cos θ - w cos φ cos θ",
                ]
                if position
                else []
            ),
            "  V = √(u² + v² + w²),  α = atan2(w, u),  β = asin(v/V)",
            *force_text,
            f"  σT = {c.thrust_angle:.6g} rad, dT = {c.thrust_offset:.6g} m"
            + ("" if thrust else " (no thrust input: T = 0)"),
            *(f"  {_expansion_text(k, e)}" for k, e in expansions.items()),
            "outputs:",
            "  α, β at the vanes from the local airflow (u, v, w) + ω × r_vane",
            "  γ = asin((u sin θ - v sin φ cos θ - w cos φ cos θ)/V)",
            "  " + _accel_text("body axes", accel_units),
        ]
    )
    return _aircraft_model(
        "six_dof",
        _six_dof_function,
        args,
        states=states,
        controls=[*surf] + (["thrust"] if thrust else []),
        parameters=values,
        outputs=outs,
        name=name,
        version=version,
        accel_units=accel_units,
        constants=c,
        reference={"V0": V0},
        surfaces=surf,
        equations=equations,
        parameter_units=_expansion_units(expansions, None, linear=False),
    )


# -- linear small-perturbation models with dimensional derivatives -------------------------------

_LONG_LINEAR_TERMS: Mapping[str, Sequence[str]] = {
    "X": ("V", "alpha", "delta_e"),
    "Z": ("V", "alpha", "delta_e"),
    "M": ("V", "alpha", "q", "delta_e"),
}
_LONG_LINEAR_OUTPUTS = ("V", "alpha", "theta", "q", "q_dot", "gamma", "az")


def _longitudinal_linear_function(
    V0: float,
    gamma0: float,
    g: float,
    expansions: Mapping[str, _Expansion],
    surfaces: tuple[str, ...],
    thrust: bool,
    outputs: tuple[str, ...],
    accel_scale: float,
    role: str,
) -> Callable[[Any, Any, Any, Any], Any]:
    g_cos = g * math.cos(gamma0)
    g_sin_V0 = g * math.sin(gamma0) / V0
    cx, cz, cmm = expansions["X"], expansions["Z"], expansions["M"]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"

    def longitudinal_linear_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        V, alpha, theta, q = x[0], x[1], x[2], x[3]
        reg = {"V": V, "alpha": alpha, "q": q}
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        if thrust:
            reg["thrust"] = u[n_surf]
        gamma = theta - alpha
        q_dot = _expand(cmm, reg, p) + 0.0 * q
        normal = _expand(cz, reg, p) + 0.0 * alpha
        if dynamics:
            V_dot = _expand(cx, reg, p) - g_cos * gamma
            alpha_dot = q + normal - g_sin_V0 * gamma
            return np.stack(np.broadcast_arrays(V_dot, alpha_dot, q, q_dot))
        values = {
            "V": V,
            "alpha": alpha,
            "theta": theta,
            "q": q,
            "q_dot": q_dot,
            "gamma": gamma,
            "az": V0 * normal * accel_scale,
        }
        return np.stack(np.broadcast_arrays(*[values[k] for k in outputs]))

    return longitudinal_linear_equations


def longitudinal_linear(
    *,
    V0: float,
    gamma0: float = 0.0,
    g: float = 9.80665,
    terms: Mapping[str, Sequence[str]] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    surfaces: Sequence[str] = ("delta_e",),
    thrust: bool = False,
    accel_units: str = "m/s2",
    name: str = "longitudinal_linear",
    version: str | None = None,
) -> AircraftModel:
    """Linear small-perturbation longitudinal model with dimensional derivatives.

    Stability axes about a trim at airspeed `V0` and flight-path angle
    `gamma0` (Klein & Morelli ch. 3, Jategaonkar ch. 3 form). States are the
    perturbations ``V`` (m/s), ``alpha``, ``theta`` (rad), ``q`` (rad/s)::

        V̇ = X_V V + X_alpha α + ... + X_delta_e δe - g cos γ0 (θ - α)
        α̇ = q + Z_V V + Z_alpha α + ... + Z_delta_e δe - (g sin γ0 / V0)(θ - α)
        θ̇ = q
        q̇ = M_V V + M_alpha α + M_q q + M_delta_e δe

    ``X_*`` are derivatives of V̇ (m/s² per unit), ``Z_*`` of α̇ (that is
    ``Z / (m V0)`` of the force derivatives, 1/s per unit) and ``M_*`` of q̇;
    which terms appear is chosen with `terms` from ``V``, ``alpha``, ``q``,
    the surfaces, ``thrust`` and the constant ``"0"``. The gravity terms are
    fixed by `V0`, `gamma0` and `g`.

    Outputs (any of): ``V, alpha, theta, q, q_dot, gamma`` (``θ - α``) and
    ``az`` (``V0 ΣZ``, the change of the normal specific force at the c.g.,
    positive down, stability axes).

    Parameters
    ----------
    V0, gamma0, g : float
        Trim airspeed (m/s), flight-path angle (rad) and gravity (m/s²).
    terms : mapping of str to sequence of str, optional
        Terms per equation ``X``, ``Z``, ``M``; default ``X, Z: V, alpha,
        delta_e``; ``M: V, alpha, q, delta_e``.
    parameters : mapping of str to float, optional
    outputs : sequence of str, optional
        Default: the four states.
    surfaces : sequence of str
    thrust : bool
        Add a ``thrust`` perturbation control (N).
    accel_units : {"m/s2", "g"}
        Units of ``az``: those of `g`, or g (divided by `g`).
    name, version : str

    Returns
    -------
    AircraftModel
        Of kind ``"longitudinal_linear"``, reference ``V0``, ``gamma0``; no constants.

    Raises
    ------
    ModelDefinitionError
        Unknown terms, outputs or parameter names, or a trim value (`V0`,
        `gamma0`, `g`) that is not a finite number (`V0` positive).
    """
    V0 = _check_speed(V0)
    gamma0 = _finite("gamma0", gamma0)
    g = _finite("g", g)
    surf = _surfaces(surfaces, ("V", "alpha", "q", "thrust"))
    regs = ("V", "alpha", "q", *surf) + (("thrust",) if thrust else ())
    expansions = _parse_expansions(terms, _LONG_LINEAR_TERMS, regs, "linear longitudinal")
    values = _parameter_values(expansions, parameters)
    outs = _outputs(outputs, ("V", "alpha", "theta", "q"), _LONG_LINEAR_OUTPUTS)
    g = _positive_g(g)
    scale = _accel_scale(accel_units, g)
    args = (V0, gamma0, g, expansions, surf, bool(thrust), outs, scale)
    equations = "\n".join(
        [
            "Small perturbations about trim (V0, γ0), stability axes, dimensional derivatives:",
            "  V̇ = ΣX - g cos γ0 (θ - α)",
            "  α̇ = q + ΣZ - (g sin γ0/V0)(θ - α)",
            "  θ̇ = q",
            "  q̇ = ΣM",
            *(f"  Σ{_expansion_text(k, e)}" for k, e in expansions.items()),
            "  az = V0 ΣZ" + (" / g (in g)" if accel_units == "g" else ""),
            f"  V0 = {V0:.6g} m/s, γ0 = {gamma0:.6g} rad, g = {g:.6g} m/s^2",
        ]
    )
    return _aircraft_model(
        "longitudinal_linear",
        _longitudinal_linear_function,
        args,
        states=["V", "alpha", "theta", "q"],
        controls=[*surf] + (["thrust"] if thrust else []),
        parameters=values,
        outputs=outs,
        accel_units=accel_units,
        name=name,
        version=version,
        reference={"V0": V0, "gamma0": gamma0},
        surfaces=surf,
        equations=equations,
        parameter_units=_expansion_units(
            expansions,
            {
                "X": _units.METRE_PER_SECOND_SQUARED,
                "Z": _units.PER_SECOND,
                "M": _units.PER_SECOND_SQUARED,
            },
            linear=True,
        ),
    )


_LAT_LINEAR_TERMS: Mapping[str, Sequence[str]] = {
    "Y": ("beta", "delta_r"),
    "L": ("beta", "p", "r", "delta_a", "delta_r"),
    "N": ("beta", "p", "r", "delta_a", "delta_r"),
}
_LAT_LINEAR_OUTPUTS = ("beta", "p", "r", "phi", "psi", "p_dot", "r_dot", "ay")


def _lateral_linear_function(
    V0: float,
    alpha0: float,
    theta0: float,
    g: float,
    expansions: Mapping[str, _Expansion],
    surfaces: tuple[str, ...],
    with_heading: bool,
    outputs: tuple[str, ...],
    accel_scale: float,
    role: str,
) -> Callable[[Any, Any, Any, Any], Any]:
    sin_a0, cos_a0 = math.sin(alpha0), math.cos(alpha0)
    g_V0 = g * math.cos(theta0) / V0
    tan_t0, sec_t0 = math.tan(theta0), 1.0 / math.cos(theta0)
    cy, cl, cn = expansions["Y"], expansions["L"], expansions["N"]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"

    def lateral_linear_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        beta, p_, r, phi = x[0], x[1], x[2], x[3]
        reg = {"beta": beta, "p": p_, "r": r}
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        side = _expand(cy, reg, p) + 0.0 * beta
        p_dot = _expand(cl, reg, p) + 0.0 * p_
        r_dot = _expand(cn, reg, p) + 0.0 * r
        if dynamics:
            beta_dot = side + sin_a0 * p_ - cos_a0 * r + g_V0 * phi
            rates = [beta_dot, p_dot, r_dot, p_ + tan_t0 * r]
            if with_heading:
                rates.append(sec_t0 * r)
            return np.stack(np.broadcast_arrays(*rates))
        values = {
            "beta": beta,
            "p": p_,
            "r": r,
            "phi": phi,
            "p_dot": p_dot,
            "r_dot": r_dot,
            "ay": V0 * side * accel_scale,
        }
        if with_heading:
            values["psi"] = x[4]
        return np.stack(np.broadcast_arrays(*[values[k] for k in outputs]))

    return lateral_linear_equations


def lateral_linear(
    *,
    V0: float,
    alpha0: float = 0.0,
    theta0: float = 0.0,
    g: float = 9.80665,
    terms: Mapping[str, Sequence[str]] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    surfaces: Sequence[str] = ("delta_a", "delta_r"),
    with_heading: bool = False,
    accel_units: str = "m/s2",
    name: str = "lateral_linear",
    version: str | None = None,
) -> AircraftModel:
    """Linear small-perturbation lateral-directional model with dimensional derivatives.

    About a trim (V0, α0, θ0), body-axis rates (with ``alpha0 = 0`` the axes
    are stability axes), Klein & Morelli ch. 3 / Jategaonkar ch. 3 form::

        β̇ = Y_beta β + ... + Y_delta_r δr + p sin α0 - r cos α0 + (g cos θ0 / V0) φ
        ṗ = L_beta β + L_p p + L_r r + L_delta_a δa + L_delta_r δr
        ṙ = N_beta β + N_p p + N_r r + N_delta_a δa + N_delta_r δr
        φ̇ = p + tan θ0 r
        ψ̇ = r / cos θ0

    ``Y_*`` are derivatives of β̇ (``Y / (m V0)`` of the force), ``L_*``
    and ``N_*`` of ṗ and ṙ (the inertia-coupled, "primed" derivatives when
    Ixz ≠ 0). Terms are chosen with `terms` from ``beta``, ``p``, ``r``, the
    surfaces and the constant ``"0"``.

    Outputs (any of): ``beta, p, r, phi, psi, p_dot, r_dot`` and ``ay``
    (``V0 ΣY``, the lateral specific force at the c.g.).

    Parameters
    ----------
    V0, alpha0, theta0, g : float
    terms : mapping of str to sequence of str, optional
        Default ``Y: beta, delta_r``; ``L, N: beta, p, r, delta_a, delta_r``.
    parameters : mapping of str to float, optional
    outputs : sequence of str, optional
        Default: the states.
    surfaces : sequence of str
    with_heading : bool
    accel_units : {"m/s2", "g"}
        Units of ``ay``: those of `g`, or g (divided by `g`).
    name, version : str

    Returns
    -------
    AircraftModel
        Of kind ``"lateral_linear"``, reference ``V0``, ``alpha0``, ``theta0``; no
        constants.

    Raises
    ------
    ModelDefinitionError
        Unknown terms, outputs or parameter names, a trim value that is not a
        finite number, or `theta0` outside ±π/2.
    """
    V0 = _check_speed(V0)
    alpha0, theta0 = _check_trim_angles(alpha0, theta0)
    g = _finite("g", g)
    surf = _surfaces(surfaces, ("beta", "p", "r"))
    expansions = _parse_expansions(
        terms, _LAT_LINEAR_TERMS, ("beta", "p", "r", *surf), "linear lateral"
    )
    values = _parameter_values(expansions, parameters)
    states = ["beta", "p", "r", "phi"] + (["psi"] if with_heading else [])
    allowed = [o for o in _LAT_LINEAR_OUTPUTS if with_heading or o != "psi"]
    outs = _outputs(outputs, states, allowed)
    g = _positive_g(g)
    scale = _accel_scale(accel_units, g)
    args = (V0, alpha0, theta0, g, expansions, surf, bool(with_heading), outs, scale)
    equations = "\n".join(
        [
            "Small perturbations about trim (V0, α0, θ0), body-axis rates, dimensional derivatives:",
            "  β̇ = ΣY + p sin α0 - r cos α0 + (g cos θ0/V0) φ",
            "  ṗ = ΣL",
            "  ṙ = ΣN",
            "  φ̇ = p + tan θ0 r",
            *(["  ψ̇ = r / cos θ0"] if with_heading else []),
            *(f"  Σ{_expansion_text(k, e)}" for k, e in expansions.items()),
            "  ay = V0 ΣY" + (" / g (in g)" if accel_units == "g" else ""),
            f"  V0 = {V0:.6g} m/s, α0 = {alpha0:.6g} rad, θ0 = {theta0:.6g} rad, g = {g:.6g} m/s^2",
        ]
    )
    return _aircraft_model(
        "lateral_linear",
        _lateral_linear_function,
        args,
        states=states,
        controls=list(surf),
        parameters=values,
        outputs=outs,
        accel_units=accel_units,
        name=name,
        version=version,
        reference={"V0": V0, "alpha0": alpha0, "theta0": theta0},
        surfaces=surf,
        equations=equations,
        parameter_units=_expansion_units(
            expansions,
            {
                "Y": _units.PER_SECOND,
                "L": _units.PER_SECOND_SQUARED,
                "N": _units.PER_SECOND_SQUARED,
            },
            linear=True,
        ),
    )


# -- trim and linearisation ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TrimResult:
    """A trimmed flight condition of an aircraft model.

    Attributes
    ----------
    states, controls : mapping of str to float
        The trim state and control values.
    derivatives : mapping of str to float
        The state derivatives there (zero for the trimmed equations; ``h``
        changes at ``V sin γ``, ``psi`` and position in straight flight).
    outputs : mapping of str to float
        The model outputs at the trim.
    trimmed : tuple of str
        The states whose derivatives the solver zeroed.
    unknowns : mapping of str to float
        What the solver chose (angles, surfaces, thrust, and ``gamma`` for a
        model without thrust, which glides).
    """

    states: Mapping[str, float]
    controls: Mapping[str, float]
    derivatives: Mapping[str, float]
    outputs: Mapping[str, float]
    trimmed: tuple[str, ...]
    unknowns: Mapping[str, float]

    def __post_init__(self) -> None:
        for name in ("states", "controls", "derivatives", "outputs", "unknowns"):
            object.__setattr__(self, name, frozen_mapping(getattr(self, name)))

    @property
    def x0(self) -> FloatArray:
        """The trim state vector, in the model's state order."""
        return np.array(list(self.states.values()), dtype=np.float64)

    @property
    def u0(self) -> FloatArray:
        """The trim control vector, in the model's control order."""
        return np.array(list(self.controls.values()), dtype=np.float64)

    def summary(self) -> str:
        """The trim as a Markdown table of states, controls and derivatives."""
        rows: list[tuple[str, str, str, str]] = []
        for k, v in self.states.items():
            rows.append((k, "state", fmt(v, 8), fmt(self.derivatives[k], 3)))
        for k, v in self.controls.items():
            rows.append((k, "control", fmt(v, 8), ""))
        worst = max((abs(self.derivatives[k]) for k in self.trimmed), default=0.0)
        head = f"trim: largest trimmed derivative {worst:.3g} ({', '.join(self.trimmed)})"
        return head + "\n\n" + markdown_table(("name", "kind", "value", "derivative"), rows)


def _evaluate(
    fun: Callable[..., Any], X: FloatArray, U: FloatArray, p: Mapping[str, float]
) -> FloatArray:
    """A model function over a batch of states and controls, shape (n_out, batch)."""
    batch = X.shape[1]
    P = {k: np.full(batch, v) for k, v in p.items()}
    with np.errstate(all="ignore"):
        return np.asarray(fun(0.0, X, U, P), dtype=np.float64).reshape(-1, batch)


def _central_points(z: FloatArray, h: FloatArray) -> FloatArray:
    """Columns ``z + h_j e_j`` then ``z - h_j e_j``: the batch of a central difference."""
    E = np.diag(h)
    return np.concatenate([z[:, None] + E, z[:, None] - E], axis=1)


def _central_slopes(F: FloatArray, h: FloatArray) -> FloatArray:
    """The Jacobian from a function's values at `_central_points`."""
    return (F[:, : h.size] - F[:, h.size :]) / (2 * h)


@small_blas
def trim(
    model: AircraftModel,
    V: float | None = None,
    *,
    gamma: float = 0.0,
    parameters: Mapping[str, float] | None = None,
    controls: Mapping[str, float] | None = None,
    tolerance: float = 1e-10,
    max_iterations: int = 50,
) -> TrimResult:
    """Trim an aircraft model in straight, wings-level flight.

    ===========================  ==========================================  =====================
    model                        unknowns                                    zeroed derivatives
    ===========================  ==========================================  =====================
    longitudinal                 α, elevator, thrust (or γ without thrust)   V̇, α̇, q̇
    lateral                      β, aileron, rudder                          β̇, ṗ, ṙ
    six_dof                      α, β, elevator, aileron, rudder, thrust     u̇, v̇, ẇ, ṗ, q̇, ṙ
    longitudinal_linear          α, elevator, thrust (or γ)                  V̇, α̇, q̇
    lateral_linear               β, aileron, rudder                          β̇, ṗ, ṙ
    ===========================  ==========================================  =====================

    The elevator, aileron and rudder are the model's first, first/second and
    first three surfaces; other controls stay at `controls` (default zero).
    With ``θ = α + γ`` (six-dof: ``sin γ = cos β sin(θ - α)``), q = 0 and
    φ = 0. The perturbation (linear) models trim their perturbation states.

    Parameters
    ----------
    model : AircraftModel
        A model from this module.
    V : float, optional
        Airspeed, m/s; default the model's reference ``V0`` (the lateral
        models fly at ``V0`` only; the linear ones at zero perturbation).
    gamma : float
        Flight-path angle, rad (ignored, and solved for, without thrust).
    parameters : mapping, optional
        Parameter values merged onto the model's nominal ones.
    controls : mapping, optional
        Fixed values of controls the solver does not set.
    tolerance : float
        Largest acceptable trimmed derivative.
    max_iterations : int

    Returns
    -------
    TrimResult

    Raises
    ------
    ModelDefinitionError
        `model` is not an aircraft model of this module, or has too few controls.
    SimulationError
        The solver cannot reach the tolerance (no trim at this condition).
    """
    if not isinstance(model, AircraftModel) or model.kind not in _TRIM_SETUP:
        raise ModelDefinitionError(
            f"trim: expected a model built by aeroid.aircraft, got {type(model).__name__}"
        )
    p = resolve_parameters(model, parameters)
    fixed = dict.fromkeys(model.controls, 0.0)
    for k, v in (controls or {}).items():
        if k not in fixed:
            raise ModelDefinitionError(
                f"controls: {k!r} is not a control of {model.name!r}; its controls are "
                f"{list(model.controls)}"
            )
        fixed[k] = _finite(f"controls[{k!r}]", v)
    speed = float(model.reference.get("V0", 0.0)) if V is None else _finite("V", V)
    if model.kind in ("lateral", "lateral_linear") and V is not None:
        if not math.isclose(speed, model.reference["V0"], rel_tol=1e-12):
            raise ModelDefinitionError(
                f"V: the lateral model is linearised about V0 = {model.reference['V0']:.6g} "
                f"m/s and flies at it only, got {speed!r}"
            )
    if model.kind == "longitudinal_linear" and V is not None:
        raise ModelDefinitionError("V: the linear model trims at zero perturbation; leave V out")
    if model.kind in ("longitudinal", "six_dof") and not speed > 0:
        raise ModelDefinitionError(f"V: must be positive, got {speed!r}")
    gamma = _finite("gamma", gamma)
    unknowns, trimmed, build = _TRIM_SETUP[model.kind](model, speed, gamma, fixed)
    idx = [model.states.index(s) for s in trimmed]
    z = np.array([start for _, start in unknowns], dtype=np.float64)

    def residual(Z: FloatArray) -> FloatArray:
        X, U = build(Z)
        return _evaluate(model.dynamics, X, U, p)[idx]

    scale = np.ones(len(idx))
    r = residual(z[:, None])[:, 0]
    for _ in range(max_iterations):
        if np.all(np.isfinite(r)) and np.max(np.abs(r)) <= tolerance:
            break
        h = 1e-7 * np.maximum(1.0, np.abs(z))
        J = _central_slopes(residual(_central_points(z, h)), h)
        if not np.all(np.isfinite(J)):
            break
        step = np.linalg.lstsq(J * scale[:, None], -r * scale, rcond=None)[0]
        # halve the Newton step until the residual falls (keeps α, β in range)
        for _ in range(30):
            trial = z + step
            r_trial = residual(trial[:, None])[:, 0]
            if np.all(np.isfinite(r_trial)) and np.linalg.norm(r_trial) < np.linalg.norm(r):
                break
            step = 0.5 * step
        else:
            break
        z, r = trial, r_trial
    if not (np.all(np.isfinite(r)) and np.max(np.abs(r)) <= tolerance):
        worst = trimmed[int(np.nanargmax(np.abs(r)))] if np.any(np.isfinite(r)) else trimmed[0]
        raise SimulationError(
            f"trim of {model.name!r} at V = {speed:.6g} m/s failed: the derivative of "
            f"{worst!r} stays at {np.nanmax(np.abs(r)):.3g} (no trim with these parameters and "
            f"controls {sorted(k for k, _ in unknowns)})"
        )
    X, U = build(z[:, None])
    xdot = _evaluate(model.dynamics, X, U, p)[:, 0]
    y = (
        X[[model.states.index(o) for o in model.output_names], 0]
        if model.measurement is None
        else _evaluate(model.measurement, X, U, p)[:, 0]
    )
    return TrimResult(
        states=dict(zip(model.states, X[:, 0].tolist(), strict=True)),
        controls=dict(zip(model.controls, U[:, 0].tolist(), strict=True)),
        derivatives=dict(zip(model.states, xdot.tolist(), strict=True)),
        outputs=dict(zip(model.output_names, y.tolist(), strict=True)),
        trimmed=tuple(trimmed),
        unknowns={name: float(v) for (name, _), v in zip(unknowns, z, strict=True)},
    )


_TrimBuild = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
_TrimSetup = tuple[list[tuple[str, float]], list[str], _TrimBuild]


def _need_surfaces(model: AircraftModel, n: int, what: str) -> tuple[str, ...]:
    if len(model.surfaces) < n:
        raise ModelDefinitionError(
            f"trim: {model.name!r} needs {n} control surfaces ({what}) to trim, "
            f"it has {list(model.surfaces)}"
        )
    return model.surfaces[:n]


def _controls_matrix(
    model: AircraftModel, fixed: Mapping[str, float], set_by: Mapping[str, FloatArray], batch: int
) -> FloatArray:
    U = np.empty((model.n_controls, batch))
    for i, name in enumerate(model.controls):
        U[i] = set_by[name] if name in set_by else fixed[name]
    return U


def _trim_longitudinal(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    (elevator,) = _need_surfaces(model, 1, "an elevator")
    thrust = "thrust" in model.controls
    linear = model.kind == "longitudinal_linear"
    third = "thrust" if thrust else "gamma"
    unknowns = [("alpha", 0.0 if linear else 0.05), (elevator, 0.0), (third, 0.0)]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        alpha, de, z3 = Z[0], Z[1], Z[2]
        path = gamma if thrust else z3
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = 0.0 if linear else V
        X[1], X[2] = alpha, alpha + path
        set_by = {elevator: de, "thrust": z3} if thrust else {elevator: de}
        return X, _controls_matrix(model, fixed, set_by, Z.shape[1])

    return unknowns, ["V", "alpha", "q"], build


def _trim_lateral(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    aileron, rudder = _need_surfaces(model, 2, "aileron and rudder")
    unknowns = [("beta", 0.0), (aileron, 0.0), (rudder, 0.0)]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = Z[0]
        return X, _controls_matrix(model, fixed, {aileron: Z[1], rudder: Z[2]}, Z.shape[1])

    return unknowns, ["beta", "p", "r"], build


def _trim_six_dof(
    model: AircraftModel, V: float, gamma: float, fixed: Mapping[str, float]
) -> _TrimSetup:
    elevator, aileron, rudder = _need_surfaces(model, 3, "elevator, aileron and rudder")
    thrust = "thrust" in model.controls
    unknowns = [
        ("alpha", 0.05),
        ("beta", 0.0),
        (elevator, 0.0),
        (aileron, 0.0),
        (rudder, 0.0),
        ("thrust" if thrust else "gamma", 0.0),
    ]

    def build(Z: FloatArray) -> tuple[FloatArray, FloatArray]:
        alpha, beta = Z[0], Z[1]
        path = gamma if thrust else Z[5]
        X = np.zeros((model.n_states, Z.shape[1]))
        X[0] = V * np.cos(alpha) * np.cos(beta)
        X[1] = V * np.sin(beta)
        X[2] = V * np.sin(alpha) * np.cos(beta)
        X[7] = alpha + np.arcsin(np.sin(path) / np.cos(beta))
        set_by = {elevator: Z[2], aileron: Z[3], rudder: Z[4]}
        if thrust:
            set_by["thrust"] = Z[5]
        return X, _controls_matrix(model, fixed, set_by, Z.shape[1])

    return unknowns, ["u", "v", "w", "p", "q", "r"], build


_TRIM_SETUP: dict[str, Callable[..., _TrimSetup]] = {
    "longitudinal": _trim_longitudinal,
    "longitudinal_linear": _trim_longitudinal,
    "lateral": _trim_lateral,
    "lateral_linear": _trim_lateral,
    "six_dof": _trim_six_dof,
}


@dataclass(frozen=True, eq=False)
class Linearization:
    """A model linearised about a point: ``ẋ = A x + B u``, ``y = C x + D u`` (perturbations).

    Attributes
    ----------
    A, B, C, D : ndarray
        Jacobians of the dynamics and measurement (central differences).
    state_names, control_names, output_names : tuple of str
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def __post_init__(self) -> None:
        for name in ("A", "B", "C", "D"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))

    @property
    def eigenvalues(self) -> NDArray[np.complex128]:
        """Eigenvalues of ``A``, sorted by real part then imaginary part."""
        ev = np.linalg.eigvals(self.A).astype(np.complex128)
        return ev[np.lexsort((ev.imag, ev.real))]

    def derivative(self, of: str, by: str) -> float:
        """One entry of ``A`` or ``B``: ``∂(d of/dt)/∂ by``.

        Parameters
        ----------
        of : str
            The state whose derivative is differentiated.
        by : str
            A state (entry of ``A``) or a control (entry of ``B``).

        Returns
        -------
        float

        Raises
        ------
        ModelDefinitionError
            `of` is not a state, or `by` neither a state nor a control.
        """
        if of not in self.state_names:
            raise ModelDefinitionError(f"{of!r} is not a state; states: {list(self.state_names)}")
        i = self.state_names.index(of)
        if by in self.state_names:
            return float(self.A[i, self.state_names.index(by)])
        if by in self.control_names:
            return float(self.B[i, self.control_names.index(by)])
        raise ModelDefinitionError(f"{by!r} is neither a state nor a control of this linearisation")

    def summary(self) -> str:
        """Eigenvalues with their frequency, damping and time constant, and ``A``."""
        rows = []
        for ev in self.eigenvalues:
            wn = abs(ev)
            zeta = -ev.real / wn if wn > 0 else float("nan")
            tau = -1.0 / ev.real if ev.real != 0 and ev.imag == 0 else float("nan")
            rows.append((f"{ev.real:.6g}{ev.imag:+.6g}j", fmt(wn), fmt(zeta), fmt(tau)))
        table = markdown_table(("eigenvalue", "ω (rad/s)", "ζ", "τ (s)"), rows)
        a_rows = [
            (s, *(fmt(v) for v in row)) for s, row in zip(self.state_names, self.A, strict=True)
        ]
        a_table = markdown_table(("ẋ \\ x", *self.state_names), a_rows)
        return f"{table}\n\nA =\n\n{a_table}"


@small_blas
def linearize(
    model: Model,
    x0: Any,
    u0: Any = None,
    *,
    parameters: Mapping[str, float] | None = None,
    step: float = 1e-6,
) -> Linearization:
    """Linearise a model about a state and control by central differences.

    Parameters
    ----------
    model : Model
    x0 : TrimResult, mapping or array_like
        The point: a `TrimResult` (then `u0` comes from it), or a state.
    u0 : mapping or array_like, optional
        Controls (default zero).
    parameters : mapping, optional
    step : float
        Relative difference step.

    Returns
    -------
    Linearization

    Raises
    ------
    ModelDefinitionError
        `model` is not a model, or `x0` or `u0` does not fit it.
    SimulationError
        The model is not finite near the point.
    """
    if not isinstance(model, Model):
        raise ModelDefinitionError(
            f"linearize: expected an aeroid.Model, got {type(model).__name__}"
        )
    if isinstance(x0, TrimResult):
        u0 = x0.controls if u0 is None else u0
        x0 = x0.states
    p = resolve_parameters(model, parameters)
    x = model.initial_state(x0)[0]
    if u0 is None:
        u = np.zeros(model.n_controls)
    elif isinstance(u0, Mapping):
        unknown = sorted(set(u0) - set(model.controls))
        if unknown:
            raise ModelDefinitionError(f"u0: unknown controls {unknown}")
        u = np.array([_finite(f"u0[{c!r}]", u0.get(c, 0.0)) for c in model.controls])
    else:
        u = np.asarray(u0, dtype=np.float64).reshape(-1)
        if u.size != model.n_controls:
            raise ModelDefinitionError(
                f"u0: expected {model.n_controls} controls {list(model.controls)}, got {u.size}"
            )
    n, m = x.size, u.size
    z = np.concatenate([x, u])
    h = step * np.maximum(1.0, np.abs(z))
    Z = _central_points(z, h)
    X, U = Z[:n], Z[n:]
    J = _central_slopes(_evaluate(model._dynamics_batch, X, U, p), h)
    if model._measurement_batch is None:
        sel = [model.states.index(o) for o in model.output_names]
        C = np.eye(n)[sel]
        D = np.zeros((len(sel), m))
    else:
        JG = _central_slopes(_evaluate(model._measurement_batch, X, U, p), h)
        C, D = JG[:, :n], JG[:, n:]
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(C)) and np.all(np.isfinite(D))):
        raise SimulationError(f"linearize: {model.name!r} is not finite near the given point")
    return Linearization(
        J[:, :n],
        J[:, n:],
        C,
        D,
        tuple(model.states),
        tuple(model.controls),
        model.output_names,
    )


# -- models from a configuration --------------------------------------------------------------------

# -- longitudinal and lateral-directional together -------------------------------------------


def _decoupled_function(
    parts: tuple[Callable[[Any, Any, Any, Any], Any], Callable[[Any, Any, Any, Any], Any]],
    n_states: int,
    controls: tuple[list[int], list[int]],
) -> Callable[[Any, Any, Any, Any], Any]:
    longitudinal_f, lateral_f = parts
    lon_u, lat_u = controls

    def decoupled_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # The two sets of equations share no state: stacked, they are one model.
        first = longitudinal_f(t, x[:n_states], u[lon_u], p)
        second = lateral_f(t, x[n_states:], u[lat_u], p)
        return np.concatenate([first, second])

    return decoupled_equations


def decoupled(
    longitudinal: AircraftModel,
    lateral: AircraftModel,
    *,
    name: str = "decoupled",
    version: str | None = None,
) -> AircraftModel:
    """A longitudinal and a lateral-directional model flown as one (motion without coupling).

    For small perturbations about wings-level flight the two sets of equations
    share no state (Klein & Morelli ch. 3; Jategaonkar ch. 3), so one
    identification of the stacked model gives the same estimates as two
    separate ones (each output keeps its own noise variance) while a
    campaign handles one model per flight. States, outputs and parameters
    are the longitudinal model's then the lateral model's; controls are the
    union in that order (a control both use is one input).

    Parameters
    ----------
    longitudinal : AircraftModel
        From `longitudinal` or `longitudinal_linear`.
    lateral : AircraftModel
        From `lateral` or `lateral_linear`.
    name, version : str
        As for `aeroid.Model`; the parts' versions are folded into the version.

    Returns
    -------
    AircraftModel
        Of kind ``"decoupled"``; its reference is the parts' references (the
        lateral model's where both name a value).

    Raises
    ------
    ModelDefinitionError
        A part of the wrong kind, or a state, output or parameter name both
        parts use.
    """
    if not isinstance(longitudinal, AircraftModel) or not longitudinal.kind.startswith(
        "longitudinal"
    ):
        raise ModelDefinitionError(
            "decoupled: 'longitudinal' must be a longitudinal aircraft model"
        )
    if not isinstance(lateral, AircraftModel) or not lateral.kind.startswith("lateral"):
        raise ModelDefinitionError("decoupled: 'lateral' must be a lateral aircraft model")
    for what in ("states", "output_names", "parameters"):
        shared = sorted(set(getattr(longitudinal, what)) & set(getattr(lateral, what)))
        if shared:
            raise ModelDefinitionError(f"decoupled: both parts have the {what} {shared}")
    controls = list(longitudinal.controls) + [
        c for c in lateral.controls if c not in longitudinal.controls
    ]
    index = (
        [controls.index(c) for c in longitudinal.controls],
        [controls.index(c) for c in lateral.controls],
    )
    n = len(longitudinal.states)
    measurement_parts = (longitudinal.measurement, lateral.measurement)
    if measurement_parts[0] is None or measurement_parts[1] is None:
        raise ModelDefinitionError("decoupled: both parts must have a measurement function")
    linear = True if longitudinal.linear and lateral.linear else None
    return AircraftModel(
        states=[*longitudinal.states, *lateral.states],
        controls=controls,
        parameters={**longitudinal.parameters, **lateral.parameters},
        dynamics=_decoupled_function((longitudinal.dynamics, lateral.dynamics), n, index),
        measurement=_decoupled_function(measurement_parts, n, index),  # type: ignore[arg-type]
        outputs=[*longitudinal.output_names, *lateral.output_names],
        name=name,
        version=_content_version(version, "decoupled", longitudinal.version, lateral.version),
        linear=linear,
        constants=longitudinal.constants or lateral.constants,
        kind="decoupled",
        reference={**longitudinal.reference, **lateral.reference},
        surfaces=tuple(c for c in controls if c in (*longitudinal.surfaces, *lateral.surfaces)),
        equations="longitudinal part:\n"
        + longitudinal.equations
        + "\n\nlateral-directional part:\n"
        + lateral.equations,
        parameter_units={**longitudinal.parameter_units, **lateral.parameter_units},
        channel_units={**longitudinal.channel_units, **lateral.channel_units},
    )


_FACTORIES: dict[str, Callable[..., AircraftModel]] = {
    "longitudinal": longitudinal,
    "lateral": lateral,
    "six_dof": six_dof,
    "longitudinal_linear": longitudinal_linear,
    "lateral_linear": lateral_linear,
}


def model_from_config(spec: Mapping[str, Any]) -> AircraftModel:
    """Build an aircraft model from a plain mapping (a campaign config's YAML).

    ``aircraft`` names the model (``longitudinal``, ``lateral``, ``six_dof``,
    ``longitudinal_linear``, ``lateral_linear``); ``constants`` holds the
    `AircraftConstants` fields (the nonlinear models need it); every other key
    is a keyword of that model's function (``V0``, ``terms``, ``parameters``,
    ``outputs``, ...)::

        aircraft: longitudinal
        V0: 53.6
        constants: {mass: 1247, Ixx: 1421, Iyy: 4067, Izz: 4786, S: 17.09,
                    b: 10.18, cbar: 1.74, altitude: 1500}
        terms: {CL: ["0", alpha, q, delta_e]}
        parameters: {CL_alpha: 4.4, Cm_alpha: -0.7}

    Parameters
    ----------
    spec : mapping of str to Any
        The model's name, constants and keywords, as above.

    Returns
    -------
    AircraftModel

    Raises
    ------
    ModelDefinitionError
        An unknown model or key, or anything the model function rejects; the
        message names it.
    """
    if not isinstance(spec, Mapping):
        raise ModelDefinitionError(f"aircraft model: expected a mapping, got {spec!r}")
    options = dict(spec)
    kind = options.pop("aircraft", None)
    if kind == "decoupled":
        unknown = sorted(set(options) - {"longitudinal", "lateral", "name", "version"})
        if unknown or "longitudinal" not in options or "lateral" not in options:
            raise ModelDefinitionError(
                "aircraft model 'decoupled': expected the keys 'longitudinal' and 'lateral' "
                f"(each an aircraft model mapping), and optionally 'name', 'version'; got {sorted(options)}"
            )
        parts = {k: model_from_config(options.pop(k)) for k in ("longitudinal", "lateral")}
        return decoupled(parts["longitudinal"], parts["lateral"], **options)
    if kind not in _FACTORIES:
        raise ModelDefinitionError(
            f"aircraft: expected one of {sorted([*_FACTORIES, 'decoupled'])}, got {kind!r}"
        )
    factory = _FACTORIES[kind]
    allowed = [
        n
        for n, prm in inspect.signature(factory).parameters.items()
        if prm.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    takes_constants = "constants" in inspect.signature(factory).parameters
    raw = options.pop("constants", None)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ModelDefinitionError(
            f"aircraft model {kind!r}: unknown keys {unknown}; allowed: "
            f"{sorted([*allowed, 'constants'] if takes_constants else allowed)}"
        )
    for key in ("terms", "parameters"):
        if key in options and isinstance(options[key], Mapping):
            options[key] = {
                str(k): ([str(t) for t in v] if isinstance(v, (list, tuple)) else v)
                for k, v in options[key].items()
            }
    if not takes_constants:
        if raw is not None:
            raise ModelDefinitionError(
                f"aircraft model {kind!r}: takes no constants (its derivatives are dimensional)"
            )
        return factory(**options)
    if not isinstance(raw, Mapping):
        raise ModelDefinitionError(
            f"aircraft model {kind!r}: 'constants' must be a mapping of AircraftConstants fields"
        )
    names = {f.name for f in fields(AircraftConstants)}
    bad = sorted(set(raw) - names)
    if bad:
        raise ModelDefinitionError(f"constants: unknown fields {bad}; fields: {sorted(names)}")
    values: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in raw.items()}
    needed = {f.name for f in fields(AircraftConstants) if f.default is MISSING}
    needed |= {"Iyy", "S", "cbar"} | (set() if kind == "longitudinal" else set(_LATERAL_ONLY))
    missing = sorted(needed - set(values))
    if missing:
        raise ModelDefinitionError(f"constants: missing {missing}")
    return factory(AircraftConstants(**values), **options)
