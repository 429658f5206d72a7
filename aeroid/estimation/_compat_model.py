"""The kinematic and sensor model of data compatibility, its closed-form Jacobians and
its channel names.

Split out of `aeroid.estimation.compatibility` (which re-exports the model's names):
rigid-body kinematics driven by measured rates and specific forces, the sensor model
with biases, scale factors, time shifts and wind, and the channel tuples.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

INPUT_CHANNELS = ("p", "q", "r", "ax", "ay", "az")
"""The inputs: body-axis rates (rad/s) and specific forces (m/s^2)."""
OUTPUT_CHANNELS = ("V", "alpha", "beta", "phi", "theta", "psi", "h", "vn", "ve")
"""The outputs: airspeed (m/s), angles (rad), altitude (m), north and east ground speed (m/s)."""
STATES = ("u", "v", "w", "phi", "theta", "psi", "h")
_MEASURED = tuple(f"{s}_measured" for s in STATES)  # controls that stand in for states
_REQUIRED_OUTPUTS = ("V", "alpha", "theta")
_WIND = ("w_n", "w_e", "w_d")
SENSOR_PARAMETERS = (
    *(f"b_{c}" for c in INPUT_CHANNELS),
    *(f"k_{c}" for c in INPUT_CHANNELS),
    *(f"b_{c}" for c in OUTPUT_CHANNELS),
    *(f"k_{c}" for c in OUTPUT_CHANNELS),
    *(f"tau_{c}" for c in OUTPUT_CHANNELS),
    *_WIND,
)
"""Every parameter `check_compatibility` can estimate or hold at a given value."""
DEFAULT_ESTIMATE = (
    *(f"b_{c}" for c in INPUT_CHANNELS),
    "b_V",
    "b_alpha",
    "b_beta",
    "k_alpha",
)
"""Estimated when `estimate` is not given (those of absent channels dropped)."""


# -- the model: numpy broadcasting, module-level np calls, no branches on values --------
#
# Except one kind: the numpy batches pass a parameter that is the same at every point
# as a broadcast view of one number (`_one`), and a term multiplied by such a zero is
# left out (`_is_zero`). That changes no finite value and halves the arithmetic of a
# batch of kinematics; a traced (JAX) or perturbed parameter takes the general formula.
# (The types are held by name: the JAX translation of these functions rebinds `np`.)
_NDARRAY = np.ndarray
_NUMBER = (float, np.floating)


def _one(v: Any) -> Any:
    """A parameter the same at every point (a stride-0 view) as one number, so that
    an operation with it costs what one with a scalar does; anything else unchanged."""
    if isinstance(v, _NDARRAY) and v.ndim == 1 and v.size and v.strides == (0,):
        return v[0]
    return v


def _is_zero(v: Any) -> bool:
    """Whether `v` is a plain number equal to zero (never a traced value or an array)."""
    return isinstance(v, _NUMBER) and float(v) == 0.0


# Nominal parameters of sensors off the centre of gravity (body axes, m), present only
# where a position is given, so that a record measured at the c.g. runs the same model.
ACCEL_POSITION = ("acc_x", "acc_y", "acc_z")
ALPHA_POSITION = ("alpha_x", "alpha_y", "alpha_z")
BETA_POSITION = ("beta_x", "beta_y", "beta_z")
_SIDESLIP_ATAN = "sideslip_atan"  # present: the beta vane reads atan(v / u)


def _rates(c: Any, p: Any) -> tuple[Any, Any, Any, Any, Any, Any]:
    """Rates and specific forces (at the c.g.) with the gyro and accelerometer errors removed."""
    out = []
    for j, ch in enumerate(INPUT_CHANNELS):
        b, k = _one(p[f"b_{ch}"]), _one(p[f"k_{ch}"])
        out.append((c[j] - b) / (1.0 + k))
    P, Q, R, AX, AY, AZ = out
    if ACCEL_POSITION[0] in p:
        # the accelerometers at r read the c.g.'s specific force plus w' x r (taken off
        # the record beforehand: it needs no gyro error) plus w x (w x r), removed here
        rx, ry, rz = (_one(p[k]) for k in ACCEL_POSITION)
        along = P * rx + Q * ry + R * rz
        spin = P * P + Q * Q + R * R
        AX = AX - (P * along - rx * spin)
        AY = AY - (Q * along - ry * spin)
        AZ = AZ - (R * along - rz * spin)
    return P, Q, R, AX, AY, AZ


def _effective(x: Any, c: Any, p: Any) -> list[Any]:
    """The states with those marked measured (``m_<state>`` = 1) replaced by the record."""
    out = []
    for i, s in enumerate(STATES):
        m = _one(p[f"m_{s}"])
        out.append(x[i] if _is_zero(m) else x[i] + m * (c[6 + i] - x[i]))
    return out


def _derivatives(x: Any, c: Any, p: Any) -> list[Any]:
    uu, vv, ww, phi, theta, _psi, _h = x
    P, Q, R, AX, AY, AZ = _rates(c, p)
    g = _one(p["g"])
    sphi = np.sin(phi)
    cphi = np.cos(phi)
    sth = np.sin(theta)
    cth = np.cos(theta)
    turn = Q * sphi + R * cphi
    return [
        R * vv - Q * ww - g * sth + AX,
        P * ww - R * uu + g * cth * sphi + AY,
        Q * uu - P * vv + g * cth * cphi + AZ,
        P + sth / cth * turn,
        Q * cphi - R * sphi,
        turn / cth,
        uu * sth - (vv * sphi + ww * cphi) * cth,
    ]


def _kinematics(t: Any, x: Any, c: Any, p: Any) -> Any:
    """Rigid-body translational and rotational kinematics (states `STATES`).

    A state replaced by its measurement is held still (its derivative zeroed):
    the measurement stands in for it wherever it is used.
    """
    rates = _derivatives(_effective(x, c, p), c, p)
    out = []
    for d, s in zip(rates, STATES, strict=True):
        m = _one(p[f"m_{s}"])
        out.append(d if _is_zero(m) else d * (1.0 - m))
    return np.stack(out)


def _sensors(t: Any, x: Any, c: Any, p: Any) -> Any:
    """What the air-data, attitude and altitude sensors read (outputs `OUTPUT_CHANNELS`)."""
    xe = _effective(x, c, p)
    uu, vv, ww, phi, theta, psi, h = xe
    P, Q, R, AX, AY, AZ = _rates(c, p)
    du, dv, dw, dphi, dtheta, dpsi, dh = _derivatives(xe, c, p)
    sphi = np.sin(phi)
    cphi = np.cos(phi)
    sth = np.sin(theta)
    cth = np.cos(theta)
    spsi = np.sin(psi)
    cpsi = np.cos(psi)
    w_n, w_e, w_d = (_one(p[w]) for w in _WIND)
    if _is_zero(w_n) and _is_zero(w_e) and _is_zero(w_d):
        # no wind: air and ground velocities are one
        ua, va, wa, dua, dva, dwa = uu, vv, ww, du, dv, dw
    else:
        # the wind (north-east-down) in body axes
        along = cpsi * w_n + spsi * w_e
        across = cpsi * w_e - spsi * w_n
        wx = cth * along - sth * w_d
        wy = sphi * sth * along + cphi * across + sphi * cth * w_d
        wz = cphi * sth * along - sphi * across + cphi * cth * w_d
        ua = uu - wx
        va = vv - wy
        wa = ww - wz
        # an earth-fixed wind turns in body axes: d(w_b)/dt = -omega x w_b
        dua = du + Q * wz - R * wy
        dva = dv + R * wx - P * wz
        dwa = dw + P * wy - Q * wx
    plane = ua * ua + wa * wa
    V = np.sqrt(plane + va * va)
    dV = (ua * dua + va * dva + wa * dwa) / V
    alpha = np.arctan2(wa, ua)
    if ALPHA_POSITION[0] in p:
        # a vane at r sees the air velocity plus w x r (Klein & Morelli, ch. 10)
        rx, ry, rz = (_one(p[k]) for k in ALPHA_POSITION)
        alpha = np.arctan2(wa + P * ry - Q * rx, ua + Q * rz - R * ry)
    dalpha = (ua * dwa - wa * dua) / plane
    ub, vb, wb = ua, va, wa
    if BETA_POSITION[0] in p:
        rx, ry, rz = (_one(p[k]) for k in BETA_POSITION)
        ub, vb, wb = ua + Q * rz - R * ry, va + R * rx - P * rz, wa + P * ry - Q * rx
    if _SIDESLIP_ATAN in p:
        # a flank-angle vane: the angle of the air velocity in the body x-y plane
        beta = np.arctan2(vb, ub)
        dbeta = (ua * dva - va * dua) / (ua * ua + va * va)
    else:
        beta = (
            np.arcsin(va / V) if vb is va else np.arcsin(vb / np.sqrt(ub * ub + vb * vb + wb * wb))
        )
        dbeta = (dva * V - va * dV) / (V * np.sqrt(plane))
    # ground velocity north and east: the body-to-earth rotation of (u, v, w); its rate
    # is the same rotation of the specific force (gravity acts along "down" only)
    n_x = cth * cpsi
    n_y = sphi * sth * cpsi - cphi * spsi
    n_z = cphi * sth * cpsi + sphi * spsi
    e_x = cth * spsi
    e_y = sphi * sth * spsi + cphi * cpsi
    e_z = cphi * sth * spsi - sphi * cpsi
    vn = n_x * uu + n_y * vv + n_z * ww
    ve = e_x * uu + e_y * vv + e_z * ww
    dvn = n_x * AX + n_y * AY + n_z * AZ
    dve = e_x * AX + e_y * AY + e_z * AZ
    true = {
        "V": (V, dV),
        "alpha": (alpha, dalpha),
        "beta": (beta, dbeta),
        "phi": (phi, dphi),
        "theta": (theta, dtheta),
        "psi": (psi, dpsi),
        "h": (h, dh),
        "vn": (vn, dvn),
        "ve": (ve, dve),
    }
    # a scale factor acts on the change from the pivot y0_<o> (zero, or the start value)
    out = []
    for o, (y, dy) in true.items():
        k, tau, y0, b = (_one(p[f"{e}_{o}"]) for e in ("k", "tau", "y0", "b"))
        shifted = y if _is_zero(tau) else y - tau * dy
        out.append((1.0 + k) * (shifted - y0) + y0 + b)
    return np.stack(out)


# -- closed-form Jacobians ----------------------------------------------------------------
#
# Newton's method over the record (`aeroid.models.shooting`) linearises every RK4 step
# and the measurement at every sample. By central differences that takes two extra
# evaluations per state and parameter, each dominated by its sines and cosines; here the
# partial derivatives of `_kinematics` and `_sensors` are written out once per point.
# The values come from those two functions (the same bits); the derivatives are exact
# where the differences carried an error of about a millionth of a step. The sensors are
# covered without time shifts (every ``tau_*`` zero and none estimated): a shift reads
# the kinematics' derivatives, whose state derivatives are of second order. Elsewhere
# None sends the caller back to central differences.

Jacobians = tuple[FloatArray, FloatArray, FloatArray, FloatArray]

_N_X = len(STATES)
_N_U = len(INPUT_CHANNELS) + _N_X
# parameters the kinematics never read: their columns are zero
_NOT_IN_KINEMATICS = frozenset(
    [f"{e}_{o}" for e in ("b", "k", "tau", "y0") for o in OUTPUT_CHANNELS] + list(_WIND)
)
_INPUT_ERRORS = frozenset(f"{e}_{c}" for e in ("b", "k") for c in INPUT_CHANNELS)
_OUTPUT_ERRORS = frozenset(f"{e}_{o}" for e in ("b", "k") for o in OUTPUT_CHANNELS)


def _held(x: FloatArray, u: FloatArray, masks: list[float]) -> list[FloatArray]:
    """The states with those marked measured replaced by the record (`_effective`)."""
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
    uu, vv, ww, phi, theta, _, _ = _held(x, u, masks)
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
    if ACCEL_POSITION[0] in p:
        # the c.g.'s specific force is the reading less w x (w x r) = w (w.r) - r |w|^2
        lever = [float(p[k]) for k in ACCEL_POSITION]
        w = (P, Q, R)
        along = P * lever[0] + Q * lever[1] + R * lever[2]
        for i in range(3):
            for j in range(3):
                d = w[i] * lever[j] - 2.0 * lever[i] * w[j]
                Dr[:, i, j] -= d + along if i == j else d
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
    if ALPHA_POSITION[0] in p or BETA_POSITION[0] in p or _SIDESLIP_ATAN in p:
        return None  # vanes off the c.g. or a flank angle: central differences
    if any(
        n not in _INPUT_ERRORS and n not in _OUTPUT_ERRORS and n not in _WIND and n != "g"
        for n in names
    ):
        return None
    y = np.asarray(_sensors(t, x, u, p), dtype=np.float64)
    K = x.shape[1]
    masks = [float(p[f"m_{s}"]) for s in STATES]
    uu, vv, ww, phi, theta, psi, h = _held(x, u, masks)
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


@functools.lru_cache(maxsize=8)
def _model(nominal: tuple[tuple[str, float], ...]) -> Any:
    """The kinematics-and-sensors `Model` with these nominal values.

    Cached so that repeated analyses with the same fixed values reuse one
    model (and whatever the simulation machinery learnt about it).
    """
    from ..models.model import Model

    model = Model(
        states=list(STATES),
        controls=[*INPUT_CHANNELS, *_MEASURED],
        parameters=dict(nominal),
        dynamics=_kinematics,
        outputs=list(OUTPUT_CHANNELS),
        measurement=_sensors,
        name="flight_path_reconstruction",
    )
    # Newton's method over the record linearises with these instead of differences
    model._dynamics_batch.jacobian = _kinematics_jacobian
    assert model._measurement_batch is not None
    model._measurement_batch.jacobian = _sensors_jacobian
    return model


def _zero_sensor_errors(values: Mapping[str, float]) -> dict[str, float]:
    """The same parameters with every output error zeroed: the outputs are then the truth."""
    out = dict(values)
    for c in OUTPUT_CHANNELS:
        out[f"b_{c}"] = out[f"k_{c}"] = out[f"tau_{c}"] = 0.0
    return out
