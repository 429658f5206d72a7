"""Non-dimensional aerodynamic coefficients computed from measured motion.

Equation-error regression models the aerodynamic force and moment
coefficients directly, so they are first computed from the flight data with
the aircraft's constants (Klein & Morelli, *Aircraft System
Identification*, ch. 3 and 5). With the dynamic pressure ``q̄ = ½ ρ V²`` and
the specific forces ``a_x, a_y, a_z`` at the centre of gravity (what body-axis
accelerometers measure, gravity excluded)::

    CX = (m a_x − T cos σ) / (q̄ S)   CY = m a_y / (q̄ S)   CZ = (m a_z + T sin σ) / (q̄ S)
    CL = −CZ cos α + CX sin α     CD = −CX cos α − CZ sin α
    Cl = [Ixx ṗ − Ixz (ṙ + p q) + (Izz − Iyy) q r] / (q̄ S b)
    Cm = [Iyy q̇ + (Ixx − Izz) p r + Ixz (p² − r²) − T d + h r] / (q̄ S c̄)
    Cn = [Izz ṙ − Ixz (ṗ − q r) + (Iyy − Ixx) p q − h q] / (q̄ S b)

where T is the thrust, along a line tilted up by σ from the body x axis and
passing d below the centre of gravity (`AircraftConstants.thrust_angle` and
`thrust_offset`, the convention of `aeroid.models.aircraft`'s models), and h
the engine's angular momentum (`AircraftConstants.engine_momentum`), whose
gyroscopic moment is no aerodynamic one. The
moments may be referred to another point than the centre of gravity, such as
the fixed moment reference point of a wind-tunnel database, at ``r`` from it:
``M_r = M_cg − r × F`` with ``F`` the aerodynamic force, so for instance
``Cm_r = Cm − (z CX − x CZ)/c̄`` (Jategaonkar's ATTAS regressions refer
their moments so). Accelerometers away from the
centre of gravity also sense ``ω̇ × r + ω × (ω × r)``, which is removed using
`AircraftConstants.accel_position`. Angular accelerations are taken from the
data when present (``p_dot``, ``q_dot``, ``r_dot``) and otherwise computed
with `aeroid.io.smoothing.differentiate`.

A record with neither ``p`` nor ``r`` is longitudinal (wings level): its roll
and yaw rates and their derivatives are taken as zero, so ``Cm = (Iyy q̇ − T
d) / (q̄ S c̄)`` needs only ``q`` and constants without ``Ixx``, ``Izz`` or ``b``
(a longitudinal `AircraftConstants`). With ``p`` and ``r`` the inertial coupling
of ``Cm`` needs ``Ixx`` and ``Izz``, and ``Cl`` and ``Cn`` need them and ``b``:
asked for without them, the constants lacking are named.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._threads import small_blas
from .._value_checks import body_position
from ..errors import ChannelError, DataFormatError, ModelDefinitionError
from ..io.data import FlightData, real_array
from ..io.smoothing import differentiate
from .aircraft import AircraftConstants

__all__ = ["coefficients_from_data"]

FloatArray = NDArray[np.float64]

_ROLES = ("V", "alpha", "p", "q", "r", "p_dot", "q_dot", "r_dot", "ax", "ay", "az")
_OUTPUTS = ("CX", "CY", "CZ", "CL", "CD", "Cl", "Cm", "Cn")
# What each coefficient needs besides V (angular accelerations can be derived from rates).
_NEEDS: dict[str, tuple[str, ...]] = {
    "CX": ("ax",),
    "CY": ("ay",),
    "CZ": ("az",),
    "CL": ("ax", "az", "alpha"),
    "CD": ("ax", "az", "alpha"),
    "Cl": ("p", "q", "r"),
    "Cm": ("q",),  # and p, r unless the record is longitudinal (module notes)
    "Cn": ("p", "q", "r"),
}


def _series(data: FlightData, value: Any, what: str) -> FloatArray:
    if isinstance(value, str):
        data.require([value], role=what)
        return np.asarray(data.channels[value], dtype=np.float64)
    expected = f"{what}: expected a channel name, a number or {data.n_samples} samples"
    if value is None:
        raise DataFormatError(f"{expected}, got None")
    arr = real_array(value, what)
    try:
        arr = np.broadcast_to(arr, data.time.shape)
    except ValueError:
        raise DataFormatError(f"{expected}, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(f"{what}: non-finite value")
    return np.array(arr)


def _lacking(constants: AircraftConstants, wanted: Sequence[str], lateral: bool) -> str:
    """What the constants lack for `wanted` (module notes), or ''."""
    need = {"Ixx", "Izz", "b"} if {"Cl", "Cn"} & set(wanted) else set()
    if "Cm" in wanted and lateral:
        need |= {"Ixx", "Izz"}
    missing = [n for n in ("Ixx", "Izz", "b") if n in need and np.isnan(getattr(constants, n))]
    return ", ".join(missing)


def _reference_point(value: Any) -> tuple[float, float, float] | None:
    """The moment reference point as three finite floats, None for the centre of gravity."""
    if value is None:
        return None
    point = body_position(value, "moment_reference", DataFormatError)
    return point if any(point) else None


@small_blas
def coefficients_from_data(
    data: FlightData,
    constants: AircraftConstants,
    *,
    outputs: Sequence[str] | None = None,
    channels: Mapping[str, str] | None = None,
    thrust: float | str | Any = 0.0,
    accel_in_g: bool = False,
    method: str = "fourier",
    density: float | str | Any = None,
    moment_reference: Sequence[float] | None = None,
) -> FlightData:
    """Force and moment coefficients from measured accelerations and rates.

    Parameters
    ----------
    data : FlightData
        Uniformly sampled record in SI units: airspeed ``V`` (m/s), angle of
        attack ``alpha`` (rad), body rates ``p, q, r`` (rad/s), specific forces
        ``ax, ay, az`` (m/s², or g with `accel_in_g`), optionally angular
        accelerations ``p_dot, q_dot, r_dot`` (rad/s²).
    constants : AircraftConstants
        Mass, inertias, reference geometry, air density and accelerometer
        position (relative to the centre of gravity).
    outputs : sequence of str, optional
        Which of ``CX, CY, CZ, CL, CD, Cl, Cm, Cn`` to compute; default every
        one the channels allow.
    channels : mapping of str to str, optional
        Channel names for the roles above where they differ from the
        defaults, e.g. ``{"V": "airspeed", "ax": "nx"}``.
    thrust : float, str or array_like
        Thrust in N along the constants' thrust line (`thrust_angle`,
        `thrust_offset`; the body x axis through the centre of gravity by
        default): a constant, a channel name or samples. Default 0 (glider,
        or thrust included in the coefficients).
    accel_in_g : bool
        The specific-force channels are in units of g (``constants.g``).
    method : {"fourier", "local"}
        Smoother for angular accelerations not in the data (see
        `aeroid.io.smoothing.differentiate`).
    density : float, str or array_like, optional
        Air density in kg/m³ for the dynamic pressure: a constant, a channel
        name (a measured or computed density, which varies over a climb or a
        stall manoeuvre) or samples. Default: the constants' (`rho`, or the
        standard atmosphere at their `altitude`).
    moment_reference : sequence of 3 float, optional
        The point, in m in body axes from the centre of gravity (x forward,
        y right, z down), about which ``Cl``, ``Cm`` and ``Cn`` are taken.
        Default the centre of gravity. The transfer needs the force
        coefficients, so the specific-force channels too.

    Returns
    -------
    FlightData
        `data` with the coefficients added as channels, plus ``qbar`` (Pa)
        and any angular accelerations it derived (``p_dot`` ...).

    Raises
    ------
    ChannelError
        A channel an asked-for coefficient needs is missing.
    ModelDefinitionError
        An asked-for coefficient needs constants the record lacks (``Ixx``, ``Izz``,
        ``b``; module notes), named.
    DataFormatError
        Bad option, non-positive airspeed, or an unknown output name.
    """
    if not isinstance(data, FlightData):
        raise DataFormatError(f"data: expected FlightData, got {type(data).__name__}")
    if not isinstance(constants, AircraftConstants):
        raise DataFormatError(
            f"constants: expected AircraftConstants, got {type(constants).__name__}"
        )
    names = {role: role for role in _ROLES}
    if channels is not None and not isinstance(channels, Mapping):
        raise DataFormatError(
            f"channels: expected a mapping of role to channel name, e.g. {{'V': 'airspeed'}}, "
            f"got {channels!r}"
        )
    for role, name in dict(channels or {}).items():
        if role not in _ROLES:
            raise DataFormatError(f"channels: unknown role {role!r}; roles are {list(_ROLES)}")
        names[role] = str(name)
    # a record without the roll and yaw rates is longitudinal: p = r = 0 (module notes)
    lateral = names["p"] in data or names["r"] in data
    if outputs is None:
        wanted = [c for c in _OUTPUTS if all(names[r] in data for r in _NEEDS[c])]
        wanted = [c for c in wanted if not _lacking(constants, [c], lateral)]
        if not wanted:
            raise ChannelError(
                "no coefficient can be computed: need ax/ay/az or p, q, r in the data "
                f"(channels present: {sorted(data.names)})"
            )
    else:
        if isinstance(outputs, str):
            outputs = [outputs]
        if not isinstance(outputs, Sequence):
            raise DataFormatError(f"outputs: expected coefficient names, got {outputs!r}")
        wanted = [str(c) for c in outputs]
        for c in wanted:
            if c not in _NEEDS:
                raise DataFormatError(f"outputs: unknown coefficient {c!r}; choose from {_OUTPUTS}")
            data.require([names[r] for r in _NEEDS[c]], role=f"channel for {c}")
        lacking = _lacking(constants, wanted, lateral)
        if lacking:
            which = [c for c in wanted if _lacking(constants, [c], lateral)]
            raise ModelDefinitionError(
                f"constants: {lacking} not given, and {', '.join(which)} "
                f"{'needs' if len(which) == 1 else 'need'} them with the roll and yaw rates "
                "p and r (a longitudinal record, without p and r, gives Cm from Iyy alone)"
            )
    if method not in ("fourier", "local"):  # refused even where no rate is differentiated
        raise DataFormatError(f"method: expected 'fourier' or 'local', got {method!r}")
    data.require([names["V"]], role="airspeed channel")
    speed = np.asarray(data.channels[names["V"]], dtype=np.float64)
    if np.any(speed <= 0):
        raise DataFormatError(f"channel {names['V']!r}: airspeed must be positive")
    rho = constants.density() if density is None else _series(data, density, "density")
    if np.any(np.asarray(rho) <= 0):
        raise DataFormatError("density: air density must be positive")
    reference = _reference_point(moment_reference)
    moments_wanted = any(c in wanted for c in ("Cl", "Cm", "Cn"))
    if reference is not None and moments_wanted:
        data.require(
            [names[r] for r in ("ax", "ay", "az")],
            role="specific-force channel (moment_reference needs the aerodynamic force)",
        )
    qbar = 0.5 * rho * speed**2
    qs = qbar * constants.S
    added: dict[str, FloatArray] = {"qbar": qbar}
    units: dict[str, str] = {"qbar": "Pa"}

    need_forces = any(c in wanted for c in ("CX", "CY", "CZ", "CL", "CD")) or (
        reference is not None and moments_wanted
    )
    lever = np.asarray(constants.accel_position, dtype=np.float64)
    need_rates = moments_wanted or (need_forces and bool(np.any(lever != 0)))
    omega = omega_dot = None
    if need_rates:
        rates = ("p", "q", "r") if lateral else ("q",)
        data.require([names[r] for r in rates], role="body rate channel")
        derived = [names[r] for r in rates if names[r + "_dot"] not in data]
        if derived:
            deriv = differentiate(data, derived, method=method, suffix="_dot")
            for r in rates:
                if names[r + "_dot"] not in data:
                    added[names[r + "_dot"]] = np.asarray(deriv.channels[names[r] + "_dot"])
                    units[names[r + "_dot"]] = "rad/s^2"
        zero = np.zeros(data.n_samples)
        omega = np.column_stack(
            [data.channels[names[r]] if r in rates else zero for r in ("p", "q", "r")]
        )
        omega_dot = np.column_stack(
            [
                zero
                if r not in rates
                else added[names[r + "_dot"]]
                if names[r + "_dot"] in added
                else data.channels[names[r + "_dot"]]
                for r in ("p", "q", "r")
            ]
        )

    m = constants.mass
    thrust_samples: FloatArray | None = None
    forces: dict[str, FloatArray] = {}
    if need_forces:
        scale = constants.g if accel_in_g else 1.0
        acc = np.zeros((data.n_samples, 3))
        for k, role in enumerate(("ax", "ay", "az")):
            if names[role] in data:
                acc[:, k] = scale * np.asarray(data.channels[names[role]])
        if np.any(lever != 0):
            assert omega is not None and omega_dot is not None
            # specific force at r = at CG + ω̇ × r + ω × (ω × r)
            acc = acc - np.cross(omega_dot, lever) - np.cross(omega, np.cross(omega, lever))
        force = m * acc
        if thrust_samples is None:
            thrust_samples = _series(data, thrust, "thrust")
        force[:, 0] -= thrust_samples * np.cos(constants.thrust_angle)
        force[:, 2] += thrust_samples * np.sin(constants.thrust_angle)
        coef = force / qs[:, None]
        block = dict(zip(("CX", "CY", "CZ"), coef.T, strict=True))
        forces = block.copy()
        if "CL" in wanted or "CD" in wanted:
            alpha = np.asarray(data.channels[names["alpha"]])
            ca, sa = np.cos(alpha), np.sin(alpha)
            block["CL"] = -block["CZ"] * ca + block["CX"] * sa
            block["CD"] = -block["CX"] * ca - block["CZ"] * sa
        for c in ("CX", "CY", "CZ", "CL", "CD"):
            if c in wanted:
                added[c] = block[c]
    if omega is not None and omega_dot is not None:
        p, q, r = omega.T
        pd, qd, rd = omega_dot.T
        ac = constants
        pitching: Any = 0.0  # the thrust's own pitching moment, T d
        if "Cm" in wanted and ac.thrust_offset != 0:
            if thrust_samples is None:
                thrust_samples = _series(data, thrust, "thrust")
            pitching = thrust_samples * ac.thrust_offset
        # the inertial coupling of pitch, absent from a longitudinal record (whose
        # constants may lack Ixx and Izz: NaN times a zero rate is no zero)
        coupling = (ac.Ixx - ac.Izz) * p * r + ac.Ixz * (p**2 - r**2) if lateral else 0.0
        h = ac.engine_momentum  # the engine's gyroscopic moment, -omega x h
        moments = {
            "Cl": (ac.Ixx * pd - ac.Ixz * (rd + p * q) + (ac.Izz - ac.Iyy) * q * r) / (qs * ac.b),
            "Cm": (ac.Iyy * qd + coupling - pitching + h * r) / (qs * ac.cbar),
            "Cn": (ac.Izz * rd - ac.Ixz * (pd - q * r) + (ac.Iyy - ac.Ixx) * p * q - h * q)
            / (qs * ac.b),
        }
        if reference is not None:
            # M_r = M_cg - r x F, each component over its reference length
            x, y, z = reference
            fx, fy, fz = forces["CX"], forces["CY"], forces["CZ"]
            moments["Cl"] = moments["Cl"] - (y * fz - z * fy) / ac.b
            moments["Cm"] = moments["Cm"] - (z * fx - x * fz) / ac.cbar
            moments["Cn"] = moments["Cn"] - (x * fy - y * fx) / ac.b
        for name, value in moments.items():
            if name in wanted:
                added[name] = value
    for cname in wanted:
        units[cname] = "1"
    return data.with_channels(added, units)
