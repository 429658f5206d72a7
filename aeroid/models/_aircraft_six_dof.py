"""The six-degree-of-freedom aircraft model in body axes (see `aeroid.models.aircraft`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ModelDefinitionError
from ._aircraft_parts import (
    AircraftConstants,
    AircraftModel,
    _accel_scale,
    _accel_text,
    _aircraft_model,
    _check_constants,
    _check_speed,
    _expand,
    _Expansion,
    _expansion_text,
    _expansion_units,
    _outputs,
    _parameter_values,
    _parse_expansions,
    _surfaces,
)

FloatArray = NDArray[np.float64]

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
    d, h_engine = c.thrust_offset, c.engine_momentum
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
        # the engine's gyroscopic moment -ω × (h, 0, 0): pitch -h r, yaw h q
        yawing = (
            qbar_S * b * _expand(cn, reg, p) + (Ixx - Iyy) * p_ * q - Ixz * q * r + h_engine * q
        )
        pitching = qbar_S * cbar * _expand(cm, reg, p) + T * d - h_engine * r
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
        Iyy q̇ = q̄ S c̄ Cm + T dT + (Izz - Ixx) p r + Ixz (r² - p²) - hE r
        Izz ṙ - Ixz ṗ = q̄ S b Cn + (Ixx - Iyy) p q - Ixz q r + hE q
        φ̇ = p + (q sin φ + r cos φ) tan θ
        θ̇ = q cos φ - r sin φ
        ψ̇ = (q sin φ + r cos φ) / cos θ

    with hE the engine's angular momentum (`AircraftConstants.engine_momentum`),
    ``X = q̄ S CX + T cos σT``, ``Y = q̄ S CY``, ``Z = q̄ S CZ - T sin σT``,
    ``V = √(u² + v² + w²)``, ``α = atan2(w, u)``, ``β = asin(v / V)``. With
    ``force_axes="stability"`` the force coefficients are CD, CY, CL
    (``CX = -CD cos α + CL sin α``, ``CZ = -CD sin α - CL cos α``); with
    ``"body"`` they are CX, CY, CZ. Every coefficient is a linear-in-parameters
    expansion in ``alpha``, ``beta``, ``V`` (``V/V0 - 1``), ``p``, ``q``,
    ``r`` (``p b/2V``, ``q c̄/2V``, ``r b/2V``), the surfaces, their products,
    absolute values (``"abs(beta)"``, as for `longitudinal`) and the constant
    ``"0"``.

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
            "  Iyy q̇ = q̄ S c̄ Cm + T dT + (Izz - Ixx) p r + Ixz (r² - p²)"
            + (" - hE r" if c.engine_momentum else ""),
            "  Izz ṙ - Ixz ṗ = q̄ S b Cn + (Ixx - Iyy) p q - Ixz q r"
            + (" + hE q" if c.engine_momentum else ""),
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
            + (f", hE = {c.engine_momentum:.6g} kg m²/s" if c.engine_momentum else "")
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
        parameter_units=_expansion_units(expansions, None, linear=False, g=c.g),
    )
