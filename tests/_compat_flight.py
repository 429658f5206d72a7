"""A simulated flight for the data-compatibility tests and benchmark.

The true airspeed, angles of attack and sideslip and Euler angles are sums of
sines (no wind: air and ground velocity agree), so the body-axis velocity, its
derivative and the Euler-angle rates are known in closed form; the rates and
specific forces follow from the inverse kinematics, the altitude from a
tight-tolerance quadrature of its rate. Sensor errors follow the convention of
`aeroid.estimation.compatibility`: ``x_m = (1 + k_x) x + b_x`` for the inertial
sensors, ``y_m(t) = (1 + k_y) y(t - tau_y) + b_y`` for the others.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.integrate import solve_ivp

from aeroid import FlightData

G = 9.80665
INPUTS = ("p", "q", "r", "ax", "ay", "az")
OUTPUTS = ("V", "alpha", "beta", "phi", "theta", "psi", "h")
NOISE = {
    "p": 5e-4,
    "q": 5e-4,
    "r": 5e-4,
    "ax": 0.02,
    "ay": 0.02,
    "az": 0.02,
    "V": 0.2,
    "alpha": 1.5e-3,
    "beta": 1.5e-3,
    "phi": 1e-3,
    "theta": 1e-3,
    "psi": 1e-3,
    "h": 0.5,
    "vn": 0.05,
    "ve": 0.05,
}
# Sensor biases injected by the tests and the benchmark (units of each channel).
BIASES = {
    "b_p": 0.003,
    "b_q": -0.002,
    "b_r": 0.0025,
    "b_ax": 0.15,
    "b_ay": -0.1,
    "b_az": 0.2,
    "b_V": 1.0,
    "b_alpha": 0.02,
    "b_beta": -0.01,
}
# constant, slope, then (amplitude, frequency in Hz, phase) per sine
_SIGNALS = {
    "V": (45.0, 0.0, [(4.0, 0.04, 0.0), (1.5, 0.21, 1.0), (0.5, 0.6, 2.0)]),
    "alpha": (0.06, 0.0, [(0.04, 0.33, 0.0), (0.02, 0.85, 1.0), (0.008, 1.6, 0.3)]),
    "beta": (0.0, 0.0, [(0.03, 0.41, 0.5), (0.015, 1.05, 2.0)]),
    "phi": (0.0, 0.0, [(0.4, 0.11, 0.0), (0.15, 0.47, 1.2)]),
    "theta": (0.05, 0.0, [(0.08, 0.19, 0.3), (0.03, 0.71, 0.0)]),
    "psi": (0.2, 0.01, [(0.3, 0.06, 0.0), (0.05, 0.37, 2.5)]),
}


def _signal(name: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    const, slope, sines = _SIGNALS[name]
    value = const + slope * t
    rate = np.full_like(t, slope)
    for amp, freq, phase in sines:
        w = 2 * np.pi * freq
        value = value + amp * np.sin(w * t + phase)
        rate = rate + amp * w * np.cos(w * t + phase)
    return value, rate


def truth(
    t: np.ndarray, wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> dict[str, np.ndarray]:
    """Every true channel (inputs and outputs but h) at times `t`, in a constant wind
    (north, east, down; V, alpha and beta are air-relative)."""
    (V, dV), (a, da), (b, db) = _signal("V", t), _signal("alpha", t), _signal("beta", t)
    (phi, dphi), (th, dth), (psi, dpsi) = (
        _signal("phi", t),
        _signal("theta", t),
        _signal("psi", t),
    )
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    u, v, w = V * ca * cb, V * sb, V * sa * cb
    du = dV * ca * cb - V * sa * da * cb - V * ca * sb * db
    dv = dV * sb + V * cb * db
    dw = dV * sa * cb + V * ca * da * cb - V * sa * sb * db
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    p = dphi - dpsi * sth
    q = dth * cphi + dpsi * cth * sphi
    r = dpsi * cth * cphi - dth * sphi
    # ground velocity = air velocity + the wind in body axes, which turns as -omega x w
    wn, we, wd = wind
    spsi, cpsi = np.sin(psi), np.cos(psi)
    along, across = cpsi * wn + spsi * we, cpsi * we - spsi * wn
    wx = cth * along - sth * wd
    wy = sphi * sth * along + cphi * across + sphi * cth * wd
    wz = cphi * sth * along - sphi * across + cphi * cth * wd
    u, v, w = u + wx, v + wy, w + wz
    du, dv, dw = du - (q * wz - r * wy), dv - (r * wx - p * wz), dw - (p * wy - q * wx)
    return {
        "p": p,
        "q": q,
        "r": r,
        "ax": du - r * v + q * w + G * sth,
        "ay": dv - p * w + r * u - G * cth * sphi,
        "az": dw - q * u + p * v - G * cth * cphi,
        "V": V,
        "alpha": a,
        "beta": b,
        "phi": phi,
        "theta": th,
        "psi": psi,
        "hdot": u * sth - v * sphi * cth - w * cphi * cth,
        "vn": cth * cpsi * u
        + (sphi * sth * cpsi - cphi * spsi) * v
        + (cphi * sth * cpsi + sphi * spsi) * w,
        "ve": cth * spsi * u
        + (sphi * sth * spsi + cphi * cpsi) * v
        + (cphi * sth * spsi - sphi * cpsi) * w,
    }


def _off_centre(
    t: np.ndarray,
    wind: tuple[float, float, float],
    accel: tuple[float, float, float],
    alpha_vane: tuple[float, float, float],
    beta_vane: tuple[float, float, float],
    sideslip: str,
) -> dict[str, np.ndarray]:
    """The true channels as sensors off the c.g. read them: the specific force at
    `accel` adds w' x r + w x (w x r), a vane at r sees the air velocity plus w x r;
    also p_dot, q_dot, r_dot (central differences of a 1e-4 s step: errors ~1e-9)."""
    now = truth(t, wind)
    step = 1e-4
    ahead, behind = truth(t + step, wind), truth(t - step, wind)
    w = np.column_stack([now[c] for c in ("p", "q", "r")])
    wdot = np.column_stack([(ahead[c] - behind[c]) / (2 * step) for c in ("p", "q", "r")])
    r_acc = np.asarray(accel, dtype=float)
    extra = np.cross(wdot, r_acc) + np.cross(w, np.cross(w, r_acc))
    out = dict(now)
    for j, c in enumerate(("ax", "ay", "az")):
        out[c] = now[c] + extra[:, j]
    V, a, b = now["V"], now["alpha"], now["beta"]
    air = np.column_stack([V * np.cos(a) * np.cos(b), V * np.sin(b), V * np.sin(a) * np.cos(b)])
    at_alpha = air + np.cross(w, np.asarray(alpha_vane, dtype=float))
    at_beta = air + np.cross(w, np.asarray(beta_vane, dtype=float))
    out["alpha"] = np.arctan2(at_alpha[:, 2], at_alpha[:, 0])
    if sideslip == "atan":
        out["beta"] = np.arctan2(at_beta[:, 1], at_beta[:, 0])
    else:
        out["beta"] = np.arcsin(at_beta[:, 1] / np.linalg.norm(at_beta, axis=1))
    out["p_dot"], out["q_dot"], out["r_dot"] = wdot.T
    return out


def simulated_flight(
    duration: float = 30.0,
    rate: float = 50.0,
    *,
    errors: Mapping[str, float] | None = None,
    noise: Mapping[str, float] | None = None,
    seed: int = 0,
    h0: float = 1500.0,
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0),
    gps: bool = False,
    accel_position: tuple[float, float, float] = (0.0, 0.0, 0.0),
    alpha_vane_position: tuple[float, float, float] = (0.0, 0.0, 0.0),
    beta_vane_position: tuple[float, float, float] = (0.0, 0.0, 0.0),
    sideslip: str = "asin",
    rate_derivatives: bool = False,
) -> FlightData:
    """Sensor records of the flight with the given `errors` and white `noise` (std per channel);
    `gps` adds the ground speed north and east; the sensors sit at the given positions
    (m, body axes from the c.g.), the sideslip vane reads `sideslip` (``asin(v / V)``
    or ``atan(v / u)``); `rate_derivatives` adds exact ``p_dot, q_dot, r_dot``."""
    geometry = (accel_position, alpha_vane_position, beta_vane_position)
    plain = sideslip == "asin" and not rate_derivatives and not np.any(np.asarray(geometry))

    def sensed(at: np.ndarray) -> dict[str, np.ndarray]:
        if plain:
            return truth(at, wind)
        return _off_centre(at, wind, *geometry, sideslip)

    errors = dict(errors or {})
    noise = NOISE if noise is None else noise
    t = np.arange(round(duration * rate) + 1) / rate
    height = solve_ivp(
        lambda s, y: truth(np.atleast_1d(s), wind)["hdot"],
        (-1.0, duration + 1.0),
        [h0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-9,
        dense_output=True,
    ).sol
    rng = np.random.default_rng(seed)
    now = sensed(t)
    channels: dict[str, np.ndarray] = {}
    for c in INPUTS:
        channels[c] = (1 + errors.get(f"k_{c}", 0.0)) * now[c] + errors.get(f"b_{c}", 0.0)
    outputs = (*OUTPUTS, "vn", "ve") if gps else OUTPUTS
    for o in outputs:
        tt = t - errors.get(f"tau_{o}", 0.0)
        value = height(tt)[0] if o == "h" else sensed(tt)[o]
        channels[o] = (1 + errors.get(f"k_{o}", 0.0)) * value + errors.get(f"b_{o}", 0.0)
    for c in (*INPUTS, *outputs):  # fixed order: a reproducible stream
        channels[c] = channels[c] + noise.get(c, 0.0) * rng.standard_normal(t.size)
    if rate_derivatives:  # after the noise draws: the same stream either way
        channels.update({c: now[c] for c in ("p_dot", "q_dot", "r_dot")})
    return FlightData(t, channels)
