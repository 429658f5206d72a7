"""Closed-form Jacobians of `aircraft.lateral`'s equations (issue 47).

Newton's method over the record (`aeroid.models.shooting`) linearises every RK4 step
and the measurement at every sample; by central differences each state and
coefficient costs two more evaluations of the equations. The lateral model is
linear in its coefficients and nearly so in its states: its partial derivatives are
written out here once per point, the values taken from the model's own function (the
same bits). `None` (a name that is not one of the model's coefficients) sends the
caller back to central differences.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._aircraft_parts import (
    AircraftConstants,
    _expand,
    _Expansion,
    _factor_regressor,
    _gyro_input,
    _lateral_speed,
    _speed_at,
)
from ._batch_function import ClosedForm

FloatArray = NDArray[np.float64]


def _coefficient(
    expansion: _Expansion,
    reg: Mapping[str, Any],
    where: Mapping[str, list[tuple[int, Any]]],
    p: Mapping[str, float],
    columns: Mapping[str, int],
    K: int,
    width: int,
) -> FloatArray:
    """d C / d (states, controls, names) (K, width) of C = sum p[name] prod(factors):
    `where` gives each regressor's columns and its slope in each (a number or per point)."""
    D = np.zeros((K, width))
    for name, factors in expansion:
        inner = [_factor_regressor(f) for f in factors]
        # |x| is x sign(x) in the model: its slope is sign(x), zero at zero
        signs = [np.sign(reg[r]) if r != f else None for f, r in zip(factors, inner, strict=True)]
        values = [reg[r] if s is None else reg[r] * s for r, s in zip(inner, signs, strict=True)]
        if name in columns:
            D[:, columns[name]] += math.prod(values, start=np.ones(K))
        for i, (r, s) in enumerate(zip(inner, signs, strict=True)):
            others = math.prod(values[:i] + values[i + 1 :], start=np.ones(K))
            if s is not None:
                others = others * s
            for col, slope in where[r]:
                D[:, col] += (float(p[name]) * slope) * others
    return D


def lateral_jacobian(
    equations: Callable[[Any, Any, Any, Any], Any],
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
) -> ClosedForm:
    """The closed form of `equations` (`_lateral_function` with the same arguments)."""
    m, b = c.mass, c.b
    airspeed, half_rho_S, qbar_S0, half_b_V0 = _lateral_speed(c, V0, surfaces)
    col_V = (5 if with_heading else 4) + airspeed
    gamma_i = c.Ixx * c.Izz - c.Ixz**2
    Ixx, Izz, Ixz = c.Ixx, c.Izz, c.Ixz
    sin_a0, cos_a0 = math.sin(alpha0), math.cos(alpha0)
    g_cos_t0 = c.g * math.cos(theta0)
    tan_t0, sec_t0 = math.tan(theta0), 1.0 / math.cos(theta0)
    xa, ya, za = c.accel_position
    xb, _, zb = c.beta_vane_position
    h_engine = c.engine_momentum
    pitch_rate = _gyro_input(c, surfaces, "q", "lateral")
    known = {name for e in expansions.values() for name, _ in e}
    n_x = 5 if with_heading else 4
    n_u = len(surfaces)

    def jacobian(
        t: FloatArray,
        x: FloatArray,
        u: FloatArray,
        p: Mapping[str, float],
        names: tuple[str, ...],
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
        if any(n not in known for n in names):
            return None
        f = np.asarray(equations(t, x, u, p), dtype=np.float64)
        K = x.shape[1]
        width = n_x + n_u + len(names)
        columns = {n: n_x + n_u + j for j, n in enumerate(names)}
        beta, p_, r, phi = x[0], x[1], x[2], x[3]
        V, qbar_S, half_b_V = _speed_at(u, airspeed, V0, half_rho_S, b, qbar_S0, half_b_V0)
        reg = {"beta": beta, "p": p_ * half_b_V, "r": r * half_b_V}
        reg.update({s: u[i] for i, s in enumerate(surfaces)})
        where: dict[str, list[tuple[int, Any]]] = {
            "beta": [(0, 1.0)],
            "p": [(1, half_b_V)],
            "r": [(2, half_b_V)],
        }
        where.update({s: [(n_x + i, 1.0)] for i, s in enumerate(surfaces)})
        if airspeed >= 0:
            # p b/2V and r b/2V fall with the airspeed; its own regressor is V/V0 - 1
            reg["V"] = V / V0 - 1.0
            where["p"].append((col_V, -reg["p"] / V))
            where["r"].append((col_V, -reg["r"] / V))
            where["V"] = [(col_V, 1.0 / V0)]
        dCY, dCl, dCn = (
            _coefficient(expansions[k], reg, where, p, columns, K, width)
            for k in ("CY", "Cl", "Cn")
        )
        # the dynamic pressure's own slope in V, the coefficients' values times 2 q̄ S / V
        dqbar_S: Any = None
        CY: Any = 0.0
        if airspeed >= 0:
            dqbar_S, CY = 2.0 * qbar_S / V, _expand(expansions["CY"], reg, p)
        scale = qbar_S if airspeed < 0 else qbar_S[:, None]  # a row of slopes per point
        dL, dN = (scale * b) * dCl, (scale * b) * dCn
        if dqbar_S is not None:
            dL[:, col_V] += dqbar_S * b * _expand(expansions["Cl"], reg, p)
            dN[:, col_V] += dqbar_S * b * _expand(expansions["Cn"], reg, p)
        if pitch_rate >= 0:
            dN[:, n_x + pitch_rate] += h_engine
        dp_dot = (Izz * dL + Ixz * dN) / gamma_i
        dr_dot = (Ixz * dL + Ixx * dN) / gamma_i
        sin_phi, cos_phi = np.sin(phi), np.cos(phi)
        rows: dict[str, FloatArray] = {}
        if role == "dynamics":
            d_beta = (scale / (m * V if airspeed < 0 else m * V[:, None])) * dCY
            d_beta[:, 1] += sin_a0
            d_beta[:, 2] -= cos_a0
            d_beta[:, 3] += g_cos_t0 / V * cos_phi
            if dqbar_S is not None:
                # q̄ S CY / (m V) is ρ S V CY / 2m, and g cos θ0 sin φ / V
                d_beta[:, col_V] += half_rho_S * CY / m - g_cos_t0 * sin_phi / (V * V)
            d_phi = np.zeros((K, width))
            d_phi[:, 1] = 1.0
            d_phi[:, 2] = tan_t0 * cos_phi
            d_phi[:, 3] = -tan_t0 * r * sin_phi
            order = [d_beta, dp_dot, dr_dot, d_phi]
            if with_heading:
                d_psi = np.zeros((K, width))
                d_psi[:, 2] = cos_phi * sec_t0
                d_psi[:, 3] = -r * sin_phi * sec_t0
                order.append(d_psi)
        else:
            for i, s in enumerate(("beta", "p", "r", "phi", "psi")[:n_x]):
                rows[s] = np.zeros((K, width))
                rows[s][:, i] = 1.0
            rows["beta"][:, 2] += xb / V
            rows["beta"][:, 1] -= zb / V
            rows["p_dot"], rows["r_dot"] = dp_dot, dr_dot
            ay = (scale / m) * dCY + xa * dr_dot - za * dp_dot
            if dqbar_S is not None:
                rows["beta"][:, col_V] -= (r * xb - p_ * zb) / (V * V)
                ay[:, col_V] += dqbar_S * CY / m
            ay[:, 1] -= 2.0 * ya * p_
            ay[:, 2] -= 2.0 * ya * r
            rows["ay"] = accel_scale * ay
            order = [rows[o] for o in outputs]
        J = np.stack(order, axis=1)  # (K, n_out, width)
        return f, J[:, :, :n_x], J[:, :, n_x + n_u :], J[:, :, n_x : n_x + n_u]

    return jacobian
