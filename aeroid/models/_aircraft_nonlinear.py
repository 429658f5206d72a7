"""The nonlinear longitudinal and lateral-directional aircraft models (see `aeroid.models.aircraft`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._aircraft_jacobian import lateral_jacobian
from ._aircraft_parts import (
    AircraftConstants,
    AircraftModel,
    _accel_scale,
    _accel_text,
    _aircraft_model,
    _alpha_dot_alone,
    _check_constants,
    _check_rate_reference,
    _check_speed,
    _check_trim_angles,
    _expand,
    _Expansion,
    _expansion_text,
    _expansion_units,
    _gyro_input,
    _lateral_speed,
    _outputs,
    _parameter_values,
    _parse_expansions,
    _speed_at,
    _surfaces,
)

FloatArray = NDArray[np.float64]

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
    h_engine = c.engine_momentum
    yaw_rate = _gyro_input(c, surfaces, "r", "longitudinal")

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
        pitching = qbar_S * cbar * Cm + T * d
        if yaw_rate >= 0:
            pitching = pitching - h_engine * u[yaw_rate]  # the engine's gyroscopic moment
        q_dot = pitching / Iyy
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
        q̇ = (q̄ S c̄ Cm + T dT - hE r) / Iyy
        ḣ = V sin(θ - α)

    with ``q̄ = ρ V² / 2`` (ρ constant), σT and dT the thrust line's angle and
    offset (`AircraftConstants.thrust_angle`, `thrust_offset`), hE the engine's
    angular momentum (`AircraftConstants.engine_momentum`; when nonzero the yaw
    rate ``r`` must be among the `surfaces`: measured, or fed by `decoupled`
    from the lateral model), and each of
    CD, CL, Cm a linear-in-parameters expansion whose terms are chosen with
    `terms`: regressors ``alpha``, ``V`` (``V/V0 - 1``), ``q`` (``q c̄ / 2V``),
    each surface, their products (``"alpha*delta_e"``), absolute values
    (``"abs(beta)"``, ``"abs(beta)*alpha"``: for a coefficient even in a
    regressor with a corner at zero, such as a fuselage's sideslip drag
    ``k |β|``, which no polynomial follows; Klein & Morelli ch. 5) and the
    constant ``"0"``; the parameters are named ``CL_alpha``, ``Cm_q``,
    ``CD_0``, ``CL_alpha_delta_e``, ``CD_abs_beta``.

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
    _gyro_input(c, surf, "r", "longitudinal")
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
            "  q̇ = (q̄ S c̄ Cm + T dT)/Iyy"
            + (
                f" - {c.engine_momentum:.6g} r/Iyy (engine gyroscopic)" if c.engine_momentum else ""
            ),
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
        parameter_units=_expansion_units(expansions, None, linear=False, g=c.g),
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
    m, b, g = c.mass, c.b, c.g
    airspeed, half_rho_S, qbar_S0, half_b_V0 = _lateral_speed(c, V0, surfaces)
    gamma_i = c.Ixx * c.Izz - c.Ixz**2
    Ixx, Izz, Ixz = c.Ixx, c.Izz, c.Ixz
    sin_a0, cos_a0 = math.sin(alpha0), math.cos(alpha0)
    g_cos_t0 = g * math.cos(theta0)
    g_V0 = g_cos_t0 / V0
    tan_t0, sec_t0 = math.tan(theta0), 1.0 / math.cos(theta0)
    xa, ya, za = c.accel_position
    xb, _, zb = c.beta_vane_position
    cy, cl, cn = expansions["CY"], expansions["Cl"], expansions["Cn"]
    n_surf = len(surfaces)
    dynamics = role == "dynamics"
    h_engine = c.engine_momentum
    pitch_rate = _gyro_input(c, surfaces, "q", "lateral")

    def lateral_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # Klein & Morelli ch. 3 small-perturbation lateral equations about (V0, α0, θ0),
        # body-axis rates, q = 0.
        beta, p_, r, phi = x[0], x[1], x[2], x[3]
        # the flown airspeed where the model takes it as an input, else the trim's
        V, qbar_S, half_b_V = _speed_at(u, airspeed, V0, half_rho_S, b, qbar_S0, half_b_V0)
        reg = {"beta": beta, "p": p_ * half_b_V, "r": r * half_b_V}
        for i in range(n_surf):
            reg[surfaces[i]] = u[i]
        g_V = g_V0
        if airspeed >= 0:
            reg["V"], g_V = V / V0 - 1.0, g_cos_t0 / V
        CY = _expand(cy, reg, p) + 0.0 * beta
        Cl = _expand(cl, reg, p)
        Cn = _expand(cn, reg, p)
        rolling = qbar_S * b * Cl
        yawing = qbar_S * b * Cn
        if pitch_rate >= 0:
            yawing = yawing + h_engine * u[pitch_rate]  # the engine's gyroscopic moment
        p_dot = (Izz * rolling + Ixz * yawing) / gamma_i
        r_dot = (Ixz * rolling + Ixx * yawing) / gamma_i
        cos_phi = np.cos(phi)
        if dynamics:
            beta_dot = qbar_S * CY / (m * V) + p_ * sin_a0 - r * cos_a0 + g_V * np.sin(phi)
            rates = [beta_dot, p_dot, r_dot, p_ + tan_t0 * r * cos_phi]
            if with_heading:
                rates.append(r * cos_phi * sec_t0)
            return np.stack(np.broadcast_arrays(*rates))
        # accelerometer: F_y/m + (ω̇ × r + ω × (ω × r))_y with q = 0
        ay = qbar_S * CY / m + r_dot * xa - (p_ * p_ + r * r) * ya - p_dot * za
        values = {
            "beta": beta + (r * xb - p_ * zb) / V,
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
        Izz ṙ - Ixz ṗ = q̄ S b Cn + hE q
        φ̇ = p + tan θ0 r cos φ
        ψ̇ = r cos φ / cos θ0

    with ``q̄ = ρ V0² / 2``, hE the engine's angular momentum
    (`AircraftConstants.engine_momentum`; when nonzero the pitch rate ``q`` must be
    among the `surfaces`, measured or fed by `decoupled`), and CY, Cl, Cn linear-in-parameters expansions in
    ``beta``, ``p`` (``p b / 2V0``), ``r`` (``r b / 2V0``), the surfaces,
    their products, absolute values (``"abs(beta)"``, as for `longitudinal`)
    and the constant ``"0"``; parameters named ``Cl_p``, ``Cn_beta``,
    ``Cn_delta_r``, ``CY_0``, ``Cn_abs_beta``.

    With ``"V"`` among the `surfaces` the model flies the airspeed it is given
    (measured, or the longitudinal part's state fed by `decoupled`) in place of
    V0 everywhere above: ``q̄ = ρ V² / 2``, ``p b / 2V``, ``r b / 2V``, the
    ``1/V`` of the β̇ equation and of the vane's offset (Klein & Morelli ch. 6
    and Jategaonkar ch. 3 take the measured airspeed); a term ``"V"`` is then
    ``V/V0 - 1``, as for `longitudinal`. Without it the equations are the
    small-perturbation form about V0.

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
    _gyro_input(c, surf, "q", "lateral")
    expansions = _parse_expansions(terms, _LAT_DEFAULT_TERMS, ("beta", "p", "r", *surf), "lateral")
    values = _parameter_values(expansions, parameters)
    allowed = [o for o in _LAT_OUTPUTS if with_heading or o != "psi"]
    outs = _outputs(outputs, _LAT_DEFAULT_OUTPUTS, allowed)
    scale = _accel_scale(accel_units, c.g)
    states = ["beta", "p", "r", "phi"] + (["psi"] if with_heading else [])
    args = (c, V0, alpha0, theta0, expansions, surf, bool(with_heading), outs, scale)
    flown = "V" in surf
    equations = "\n".join(
        [
            "Klein & Morelli ch. 3, small perturbations about (V0, α0, θ0), body-axis rates,"
            " q̄ = ρ V0²/2:",
            *(
                ["  with V, the input (the airspeed flown), for V0 in q̄, b/2V0 and 1/V0"]
                if flown
                else []
            ),
            "  β̇ = q̄ S CY/(m V0) + p sin α0 - r cos α0 + (g/V0) cos θ0 sin φ",
            "  Ixx ṗ - Ixz ṙ = q̄ S b Cl",
            "  Izz ṙ - Ixz ṗ = q̄ S b Cn"
            + (f" + {c.engine_momentum:.6g} q (engine gyroscopic)" if c.engine_momentum else ""),
            "  φ̇ = p + tan θ0 r cos φ",
            *(["  ψ̇ = r cos φ / cos θ0"] if with_heading else []),
            *(f"  {_expansion_text(k, e).replace('(2V)', '(2V0)')}" for k, e in expansions.items()),
            "outputs:",
            "  β (vane at xβ, zβ) = β + (r xβ - p zβ)/V0",
            "  ay = q̄ S CY/m + ṙ xa - (p² + r²) ya - ṗ za",
            "  " + _accel_text("body axes", accel_units),
        ]
    )
    model = _aircraft_model(
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
        parameter_units=_expansion_units(expansions, None, linear=False, g=c.g),
    )
    # Newton's method over the record linearises with these instead of differences
    model._dynamics_batch.jacobian = lateral_jacobian(model._dynamics_batch.fun, *args, "dynamics")
    assert model._measurement_batch is not None and model.measurement is not None
    model._measurement_batch.jacobian = lateral_jacobian(model.measurement, *args, "measurement")
    return model
