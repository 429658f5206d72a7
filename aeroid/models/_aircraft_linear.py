"""The linear small-perturbation aircraft models, and the two halves joined (see
`aeroid.models.aircraft`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .. import _units
from ..errors import ModelDefinitionError
from ._aircraft_parts import (
    AircraftModel,
    _accel_scale,
    _aircraft_model,
    _check_speed,
    _check_trim_angles,
    _content_version,
    _expand,
    _Expansion,
    _expansion_text,
    _expansion_units,
    _finite,
    _outputs,
    _parameter_values,
    _parse_expansions,
    _positive_g,
    _surfaces,
    _us_system,
)

FloatArray = NDArray[np.float64]

# -- linear small-perturbation models with dimensional derivatives -------------------------------


def _speed(g: float) -> str:
    """The speed unit of constants with this g (the equations' text states it)."""
    return "ft/s" if _us_system(g) else "m/s"


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
            *(f"  Σ{_expansion_text(k, e, linear=True)}" for k, e in expansions.items()),
            "  az = V0 ΣZ" + (" / g (in g)" if accel_units == "g" else ""),
            f"  V0 = {V0:.6g} {_speed(g)}, γ0 = {gamma0:.6g} rad, g = {g:.6g} {_speed(g)}²",
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
        gravity=g,
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
            g=g,
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
            *(f"  Σ{_expansion_text(k, e, linear=True)}" for k, e in expansions.items()),
            "  ay = V0 ΣY" + (" / g (in g)" if accel_units == "g" else ""),
            f"  V0 = {V0:.6g} {_speed(g)}, α0 = {alpha0:.6g} rad, θ0 = {theta0:.6g} rad, "
            f"g = {g:.6g} {_speed(g)}²",
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
        gravity=g,
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
            g=g,
        ),
    )


# -- longitudinal and lateral-directional together -------------------------------------------


def _decoupled_function(
    parts: tuple[Callable[[Any, Any, Any, Any], Any], Callable[[Any, Any, Any, Any], Any]],
    n_states: int,
    sources: tuple[list[tuple[bool, int]], list[tuple[bool, int]]],
) -> Callable[[Any, Any, Any, Any], Any]:
    longitudinal_f, lateral_f = parts
    lon_u, lat_u = sources

    def inputs(x: Any, u: Any, picks: list[tuple[bool, int]]) -> Any:
        # each part's inputs row by row (JAX, which compiles the model, indexes with no
        # list): a control, or the other part's state where the part names one
        return np.stack([x[i] if from_state else u[i] for from_state, i in picks])

    def decoupled_equations(t: Any, x: Any, u: Any, p: Any) -> Any:
        # Stacked, the two sets of equations are one model.
        first = longitudinal_f(t, x[:n_states], inputs(x, u, lon_u), p)
        second = lateral_f(t, x[n_states:], inputs(x, u, lat_u), p)
        return np.concatenate([first, second])

    return decoupled_equations


def _input_sources(
    part: AircraftModel, other: AircraftModel, offset: int, controls: list[str]
) -> list[tuple[bool, int]]:
    """Where each of `part`'s inputs comes from: (True, the full state's index) for a
    state of `other` (which starts at `offset`), else (False, the control's index)."""
    return [
        (True, offset + other.states.index(c)) if c in other.states else (False, controls.index(c))
        for c in part.controls
    ]


def decoupled(
    longitudinal: AircraftModel,
    lateral: AircraftModel,
    *,
    name: str = "decoupled",
    version: str | None = None,
) -> AircraftModel:
    """A longitudinal and a lateral-directional model flown as one.

    For small perturbations about wings-level flight the two sets of equations
    share no state (Klein & Morelli ch. 3; Jategaonkar ch. 3), so one
    identification of the stacked model gives the same estimates as two
    separate ones (each output keeps its own noise variance) while a
    campaign handles one model per flight. States, outputs and parameters
    are the longitudinal model's then the lateral model's; controls are the
    union in that order (a control both use is one input).

    A part may take the other part's state as an input: an input named after
    one of its states (the lateral model's ``surfaces=("delta_a", "delta_r",
    "alpha")`` with a ``Cl: alpha`` term) is fed that state, not a control.
    This is the textbooks' longitudinal variable in the lateral-directional
    equations (Jategaonkar ch. 3, Klein & Morelli ch. 3, there measured and
    fed as an input), here the model's own: an aircraft whose lift rolls it
    (a centre of gravity off its plane of symmetry, asymmetric stores) gives
    ``Cl_alpha``, and the parts are coupled through that state. A lateral model
    with ``"V"`` among its surfaces flies the longitudinal airspeed so fed.

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
    n = len(longitudinal.states)
    fed = set(longitudinal.controls) & set(lateral.states)
    fed |= set(lateral.controls) & set(longitudinal.states)
    controls = [c for c in longitudinal.controls if c not in fed] + [
        c for c in lateral.controls if c not in longitudinal.controls and c not in fed
    ]
    index = (
        _input_sources(longitudinal, lateral, n, controls),
        _input_sources(lateral, longitudinal, 0, controls),
    )
    measurement_parts = (longitudinal.measurement, lateral.measurement)
    if measurement_parts[0] is None or measurement_parts[1] is None:
        raise ModelDefinitionError("decoupled: both parts must have a measurement function")
    linear = True if longitudinal.linear and lateral.linear else None
    return AircraftModel(
        states=[*longitudinal.states, *lateral.states],
        controls=controls,
        parameters={**longitudinal.parameters, **lateral.parameters},
        dynamics=_decoupled_function(
            (longitudinal._dynamics_batch.fun, lateral._dynamics_batch.fun), n, index
        ),
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
        + lateral.equations
        + "".join(f"\n(input {c}: the other part's state)" for c in sorted(fed)),
        parameter_units={**longitudinal.parameter_units, **lateral.parameter_units},
        channel_units={**longitudinal.channel_units, **lateral.channel_units},
    )
