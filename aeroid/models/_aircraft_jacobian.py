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

from ._aircraft_parts import AircraftConstants, _Expansion, _factor_regressor, _gyro_input
from ._batch_function import ClosedForm

FloatArray = NDArray[np.float64]


def _coefficient(
    expansion: _Expansion,
    reg: Mapping[str, Any],
    where: Mapping[str, tuple[int, float]],
    p: Mapping[str, float],
    columns: Mapping[str, int],
    K: int,
    width: int,
) -> FloatArray:
    """d C / d (states, controls, names) (K, width) of C = sum p[name] prod(factors):
    `where` gives each regressor's column and its slope in that column."""
    D = np.zeros((K, width))
    for name, factors in expansion:
        inner = [_factor_regressor(f) for f in factors]
        # |x| is x sign(x) in the model: its slope is sign(x), zero at zero
        signs = [np.sign(reg[r]) if r != f else None for f, r in zip(factors, inner, strict=True)]
        values = [reg[r] if s is None else reg[r] * s for r, s in zip(inner, signs, strict=True)]
        if name in columns:
            D[:, columns[name]] += math.prod(values, start=np.ones(K))
        for i, (r, s) in enumerate(zip(inner, signs, strict=True)):
            col, slope = where[r]
            others = math.prod(values[:i] + values[i + 1 :], start=np.ones(K))
            if s is not None:
                others = others * s
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
    m, S, b = c.mass, c.S, c.b
    qbar_S = 0.5 * c.density() * V0 * V0 * S
    gamma_i = c.Ixx * c.Izz - c.Ixz**2
    Ixx, Izz, Ixz = c.Ixx, c.Izz, c.Ixz
    half_b_V0 = 0.5 * b / V0
    sin_a0, cos_a0 = math.sin(alpha0), math.cos(alpha0)
    g_V0 = c.g * math.cos(theta0) / V0
    tan_t0, sec_t0 = math.tan(theta0), 1.0 / math.cos(theta0)
    xa, ya, za = c.accel_position
    xb, _, zb = c.beta_vane_position
    h_engine = c.engine_momentum
    pitch_rate = _gyro_input(c, surfaces, "q", "lateral")
    known = {name for e in expansions.values() for name, _ in e}
    n_x = 5 if with_heading else 4
    n_u = len(surfaces)
    where = {"beta": (0, 1.0), "p": (1, half_b_V0), "r": (2, half_b_V0)}
    where.update({s: (n_x + i, 1.0) for i, s in enumerate(surfaces)})

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
        reg = {"beta": beta, "p": p_ * half_b_V0, "r": r * half_b_V0}
        reg.update({s: u[i] for i, s in enumerate(surfaces)})
        dCY, dCl, dCn = (
            _coefficient(expansions[k], reg, where, p, columns, K, width)
            for k in ("CY", "Cl", "Cn")
        )
        dL, dN = (qbar_S * b) * dCl, (qbar_S * b) * dCn
        if pitch_rate >= 0:
            dN[:, n_x + pitch_rate] += h_engine
        dp_dot = (Izz * dL + Ixz * dN) / gamma_i
        dr_dot = (Ixz * dL + Ixx * dN) / gamma_i
        sin_phi, cos_phi = np.sin(phi), np.cos(phi)
        rows: dict[str, FloatArray] = {}
        if role == "dynamics":
            d_beta = (qbar_S / (m * V0)) * dCY
            d_beta[:, 1] += sin_a0
            d_beta[:, 2] -= cos_a0
            d_beta[:, 3] += g_V0 * cos_phi
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
            rows["beta"][:, 2] += xb / V0
            rows["beta"][:, 1] -= zb / V0
            rows["p_dot"], rows["r_dot"] = dp_dot, dr_dot
            ay = (qbar_S / m) * dCY + xa * dr_dot - za * dp_dot
            ay[:, 1] -= 2.0 * ya * p_
            ay[:, 2] -= 2.0 * ya * r
            rows["ay"] = accel_scale * ay
            order = [rows[o] for o in outputs]
        J = np.stack(order, axis=1)  # (K, n_out, width)
        return f, J[:, :, :n_x], J[:, :, n_x + n_u :], J[:, :, n_x : n_x + n_u]

    return jacobian
