"""Closed-form Jacobians of the data-compatibility kinematics and sensors.

Newton's method over the record (`aeroid.models.shooting`) linearises every RK4
step and the measurement at every sample. By central differences that takes two
extra evaluations per state and parameter, each evaluation dominated by its sines
and cosines; here the partial derivatives of `_kinematics` and `_sensors` are
written out once per point instead. The values themselves come from those two
functions (the same bits); the derivatives are exact where the differences carried
a truncation and rounding error of about a millionth of a step.

The sensors are covered without time shifts (every ``tau_*`` zero and none
estimated): a time shift reads the kinematics' derivatives, whose state
derivatives are of second order. Elsewhere `None` sends the caller back to
central differences.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from ._compat_model import _WIND, INPUT_CHANNELS, OUTPUT_CHANNELS, STATES, _kinematics, _sensors

FloatArray = NDArray[np.float64]
Jacobians = tuple[FloatArray, FloatArray, FloatArray, FloatArray]

_N_X = len(STATES)
_N_U = len(INPUT_CHANNELS) + _N_X
# parameters the kinematics never read: their columns are zero
_NOT_IN_KINEMATICS = frozenset(
    [f"{e}_{o}" for e in ("b", "k", "tau", "y0") for o in OUTPUT_CHANNELS] + list(_WIND)
)
_INPUT_ERRORS = frozenset(f"{e}_{c}" for e in ("b", "k") for c in INPUT_CHANNELS)
_OUTPUT_ERRORS = frozenset(f"{e}_{o}" for e in ("b", "k") for o in OUTPUT_CHANNELS)


def _effective(x: FloatArray, u: FloatArray, masks: list[float]) -> list[FloatArray]:
    return [x[i] if m == 0.0 else x[i] + m * (u[6 + i] - x[i]) for i, m in enumerate(masks)]


def _masked(D: FloatArray, masks: list[float], rows: bool) -> FloatArray:
    """D (K, n, n_x) with its rows (a state held still has no derivative) or its
    columns (a held state's effective value follows the record) times 1 - m."""
    keep = np.array([1.0 - m for m in masks])
    if not np.any(keep != 1.0):
        return D
    return D * (keep[None, :, None] if rows else keep[None, None, :])


def _kinematics_jacobian(
    t: FloatArray,
    x: FloatArray,
    u: FloatArray,
    p: Mapping[str, float],
    names: tuple[str, ...],
) -> Jacobians | None:
    """`_kinematics` at points (t (K,), x (7, K), u (13, K)) and its Jacobians in the
    states (K, 7, 7), `names` (K, 7, n_p) and the controls (K, 7, 13)."""
    if any(n not in _INPUT_ERRORS and n not in _NOT_IN_KINEMATICS and n != "g" for n in names):
        return None
    f = np.asarray(_kinematics(t, x, u, p), dtype=np.float64)
    K = x.shape[1]
    masks = [float(p[f"m_{s}"]) for s in STATES]
    uu, vv, ww, phi, theta, _, _ = _effective(x, u, masks)
    scale = [1.0 + float(p[f"k_{c}"]) for c in INPUT_CHANNELS]
    rates = [(u[j] - float(p[f"b_{c}"])) / scale[j] for j, c in enumerate(INPUT_CHANNELS)]
    P, Q, R = rates[:3]
    g = float(p["g"])
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    tth = sth / cth
    turn = Q * sphi + R * cphi
    side = Q * cphi - R * sphi
    # in the effective states u, v, w, phi, theta (psi and h are read by none)
    Dx = np.zeros((K, _N_X, _N_X))
    Dx[:, 0, 1], Dx[:, 0, 2], Dx[:, 0, 4] = R, -Q, -g * cth
    Dx[:, 1, 0], Dx[:, 1, 2] = -R, P
    Dx[:, 1, 3], Dx[:, 1, 4] = g * cth * cphi, -g * sth * sphi
    Dx[:, 2, 0], Dx[:, 2, 1] = Q, -P
    Dx[:, 2, 3], Dx[:, 2, 4] = -g * cth * sphi, -g * sth * cphi
    Dx[:, 3, 3], Dx[:, 3, 4] = tth * side, turn / (cth * cth)
    Dx[:, 4, 3] = -turn
    Dx[:, 5, 3], Dx[:, 5, 4] = side / cth, turn * sth / (cth * cth)
    Dx[:, 6, 0], Dx[:, 6, 1], Dx[:, 6, 2] = sth, -sphi * cth, -cphi * cth
    Dx[:, 6, 3] = -(vv * cphi - ww * sphi) * cth
    Dx[:, 6, 4] = uu * cth + (vv * sphi + ww * cphi) * sth
    # in the corrected rates and specific forces P, Q, R, AX, AY, AZ
    Dr = np.zeros((K, _N_X, 6))
    Dr[:, 0, 1], Dr[:, 0, 2], Dr[:, 0, 3] = -ww, vv, 1.0
    Dr[:, 1, 0], Dr[:, 1, 2], Dr[:, 1, 4] = ww, -uu, 1.0
    Dr[:, 2, 0], Dr[:, 2, 1], Dr[:, 2, 5] = -vv, uu, 1.0
    Dr[:, 3, 0], Dr[:, 3, 1], Dr[:, 3, 2] = 1.0, tth * sphi, tth * cphi
    Dr[:, 4, 1], Dr[:, 4, 2] = cphi, -sphi
    Dr[:, 5, 1], Dr[:, 5, 2] = sphi / cth, cphi / cth
    Dx = _masked(Dx, masks, True)
    Dr = _masked(Dr, masks, True)
    fx = _masked(Dx, masks, False)
    fu = np.zeros((K, _N_X, _N_U))
    fu[:, :, :6] = Dr / np.array(scale)[None, None, :]
    fu[:, :, 6:] = Dx * np.array(masks)[None, None, :]
    fp = np.zeros((K, _N_X, len(names)))
    for c, name in enumerate(names):
        if name == "g":
            fp[:, 0, c], fp[:, 1, c], fp[:, 2, c] = -sth, cth * sphi, cth * cphi
            fp[:, :, c] *= np.array([1.0 - m for m in masks])[None, :]
        elif name in _INPUT_ERRORS:
            kind, _, channel = name.partition("_")
            j = INPUT_CHANNELS.index(channel)
            # (c - b) / (1 + k): d/db = -1 / (1 + k), d/dk = -rate / (1 + k)
            fp[:, :, c] = -fu[:, :, j] if kind == "b" else -fu[:, :, j] * rates[j][:, None]
    return f, fx, fp, fu


def _sensors_jacobian(
    t: FloatArray,
    x: FloatArray,
    u: FloatArray,
    p: Mapping[str, float],
    names: tuple[str, ...],
) -> Jacobians | None:
    """`_sensors` at points (t (K,), x (7, K), u (13, K)) and its Jacobians in the
    states (K, 9, 7), `names` (K, 9, n_p) and the controls (K, 9, 13), where no time
    shift is at work (else None)."""
    if any(float(p[f"tau_{o}"]) != 0.0 for o in OUTPUT_CHANNELS):
        return None
    if any(
        n not in _INPUT_ERRORS and n not in _OUTPUT_ERRORS and n not in _WIND and n != "g"
        for n in names
    ):
        return None
    y = np.asarray(_sensors(t, x, u, p), dtype=np.float64)
    K = x.shape[1]
    masks = [float(p[f"m_{s}"]) for s in STATES]
    uu, vv, ww, phi, theta, psi, h = _effective(x, u, masks)
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    spsi, cpsi = np.sin(psi), np.cos(psi)
    # the rows of the body-to-earth rotation: north, east, down in body axes
    north = (cth * cpsi, sphi * sth * cpsi - cphi * spsi, cphi * sth * cpsi + sphi * spsi)
    east = (cth * spsi, sphi * sth * spsi + cphi * cpsi, cphi * sth * spsi - sphi * cpsi)
    down = (-sth, sphi * cth, cphi * cth)
    w_n, w_e, w_d = (float(p[w]) for w in _WIND)
    # the air velocity: the ground velocity less the wind in body axes
    ua, va, wa = (
        g - (n * w_n + e * w_e + d * w_d)
        for g, n, e, d in zip((uu, vv, ww), north, east, down, strict=True)
    )
    plane = ua * ua + wa * wa
    V2 = plane + va * va
    V = np.sqrt(V2)
    root = np.sqrt(plane)
    vn = north[0] * uu + north[1] * vv + north[2] * ww
    ve = east[0] * uu + east[1] * vv + east[2] * ww
    true = [V, np.arctan2(wa, ua), np.arcsin(va / V), phi, theta, psi, h, vn, ve]
    # V, alpha, beta in the air velocity
    Ga = np.zeros((K, 3, 3))
    Ga[:, 0, 0], Ga[:, 0, 1], Ga[:, 0, 2] = ua / V, va / V, wa / V
    Ga[:, 1, 0], Ga[:, 1, 2] = -wa / plane, ua / plane
    across = va / (V2 * root)
    Ga[:, 2, 0], Ga[:, 2, 1], Ga[:, 2, 2] = -across * ua, root / V2, -across * wa
    # the error-free outputs in the effective states
    G = np.zeros((K, len(OUTPUT_CHANNELS), _N_X))
    G[:, :3, :3] = Ga
    if w_n or w_e or w_d:
        # the wind in body axes turns with the attitude: d/d(phi, theta, psi)
        turn = np.zeros((K, 3, 3))
        turn[:, 1, 0] = north[2] * w_n + east[2] * w_e + down[2] * w_d
        turn[:, 2, 0] = -(north[1] * w_n + east[1] * w_e + down[1] * w_d)
        turn[:, 0, 1] = -sth * (cpsi * w_n + spsi * w_e) - cth * w_d
        level = cth * (cpsi * w_n + spsi * w_e) - sth * w_d
        turn[:, 1, 1], turn[:, 2, 1] = sphi * level, cphi * level
        for i in range(3):
            turn[:, i, 2] = -east[i] * w_n + north[i] * w_e
        G[:, :3, 3:6] = -np.matmul(Ga, turn)
    G[:, 3, 3] = G[:, 4, 4] = G[:, 5, 5] = G[:, 6, 6] = 1.0
    G[:, 7, 0], G[:, 7, 1], G[:, 7, 2] = north
    G[:, 7, 3] = north[2] * vv - north[1] * ww
    G[:, 7, 4] = cpsi * (-sth * uu + cth * (sphi * vv + cphi * ww))
    G[:, 7, 5] = -ve
    G[:, 8, 0], G[:, 8, 1], G[:, 8, 2] = east
    G[:, 8, 3] = east[2] * vv - east[1] * ww
    G[:, 8, 4] = spsi * (-sth * uu + cth * (sphi * vv + cphi * ww))
    G[:, 8, 5] = vn
    gain = np.array([1.0 + float(p[f"k_{o}"]) for o in OUTPUT_CHANNELS])
    G = G * gain[None, :, None]
    gx = _masked(G, masks, False)
    gu = np.zeros((K, len(OUTPUT_CHANNELS), _N_U))
    gu[:, :, 6:] = G * np.array(masks)[None, None, :]
    gp = np.zeros((K, len(OUTPUT_CHANNELS), len(names)))
    for c, name in enumerate(names):
        kind, _, channel = name.partition("_")
        if name in _OUTPUT_ERRORS:
            o = OUTPUT_CHANNELS.index(channel)
            # (1 + k)(y - y0) + y0 + b
            gp[:, o, c] = 1.0 if kind == "b" else true[o] - float(p[f"y0_{channel}"])
        elif name in _WIND:
            axis = (north, east, down)[_WIND.index(name)]
            gp[:, :3, c] = -np.einsum("kij,jk->ki", Ga, np.array(axis)) * gain[None, :3]
    return y, gx, gp, gu
