"""The kinematic and sensor model of data compatibility, and its channel names.

Split out of `aeroid.estimation.compatibility` (which re-exports every name): rigid-body
kinematics driven by measured rates and specific forces, the sensor model with
biases, scale factors, time shifts and wind, and the channel tuples.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

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


def _rates(c: Any, p: Any) -> tuple[Any, Any, Any, Any, Any, Any]:
    """Rates and specific forces with the gyro and accelerometer errors removed."""
    out = []
    for j, ch in enumerate(INPUT_CHANNELS):
        b, k = _one(p[f"b_{ch}"]), _one(p[f"k_{ch}"])
        out.append((c[j] - b) / (1.0 + k))
    return out[0], out[1], out[2], out[3], out[4], out[5]


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
    dalpha = (ua * dwa - wa * dua) / plane
    beta = np.arcsin(va / V)
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


@functools.lru_cache(maxsize=8)
def _model(nominal: tuple[tuple[str, float], ...]) -> Any:
    """The kinematics-and-sensors `Model` with these nominal values.

    Cached so that repeated analyses with the same fixed values reuse one
    model (and whatever the simulation machinery learnt about it).
    """
    from ..models.model import Model
    from ._compat_jacobian import _kinematics_jacobian, _sensors_jacobian

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
