"""A Navion-like light aircraft shared by the aircraft-model tests and benchmark.

Nelson's data in SI units: mass, inertias and reference geometry (`BASE`, the
`AircraftConstants` fields without product of inertia, density or sensor
positions) and non-dimensional derivatives (`LONG`, `LAT`).
"""

from __future__ import annotations

from typing import Any

BASE = dict(mass=1247.0, Ixx=1421.0, Iyy=4067.0, Izz=4786.0, S=17.09, b=10.18, cbar=1.74)
LONG = {
    "CD_0": 0.03,
    "CD_alpha": 0.3,
    "CD_delta_e": 0.02,
    "CL_0": 0.25,
    "CL_alpha": 4.44,
    "CL_q": 3.8,
    "CL_delta_e": 0.355,
    "Cm_0": 0.05,
    "Cm_alpha": -0.683,
    "Cm_q": -9.96,
    "Cm_delta_e": -0.923,
}
LAT = {
    "CY_beta": -0.564,
    "CY_p": -0.05,
    "CY_r": 0.2,
    "CY_delta_a": 0.0,
    "CY_delta_r": 0.157,
    "Cl_beta": -0.074,
    "Cl_p": -0.410,
    "Cl_r": 0.107,
    "Cl_delta_a": -0.134,
    "Cl_delta_r": 0.0107,
    "Cn_beta": 0.071,
    "Cn_p": -0.0575,
    "Cn_r": -0.125,
    "Cn_delta_a": -0.0035,
    "Cn_delta_r": -0.072,
}

# dimensional derivatives of `aircraft.lateral_linear` (per second: Y_ per rad, L_ and N_
# per rad/s^2), a lateral-directional truth for the linear-model tests, and its states
LATERAL_LINEAR = {
    "Y_beta": -0.15,
    "Y_delta_r": 0.03,
    "L_beta": -4.0,
    "L_p": -2.5,
    "L_r": 0.8,
    "L_delta_a": 12.0,
    "L_delta_r": 0.5,
    "N_beta": 3.0,
    "N_p": -0.1,
    "N_r": -0.6,
    "N_delta_a": -0.4,
    "N_delta_r": -3.0,
}
LATERAL_STATES = ["beta", "p", "r", "phi"]


def coupled_inputs(controls: dict[str, float], t: Any) -> Any:
    """The coupled tests' manoeuvre about a trim's `controls` on the time grid `t`
    (s): an elevator 3-2-1-1 from 1.6 s (0.04 rad), then aileron and rudder doublets
    (0.03 rad) from 8 s and 11 s; columns delta_e, thrust, delta_a, delta_r."""
    import numpy as np

    de = np.full(t.size, controls["delta_e"])
    for start, end, sign in ((1, 4, 1), (4, 6, -1), (6, 7, 1), (7, 8, -1)):
        de[(t >= 1.0 + start * 0.6) & (t < 1.0 + end * 0.6)] += 0.04 * sign
    da = 0.03 * (((t >= 8.0) & (t < 9.0)) * 1.0 - ((t >= 9.0) & (t < 10.0)))
    dr = 0.03 * (((t >= 11.0) & (t < 12.0)) * 1.0 - ((t >= 12.0) & (t < 13.0)))
    return np.column_stack([de, np.full(t.size, controls["thrust"]), da, dr])


def noisy_interval(
    f: Any, t0: float, x: Any, u: tuple[Any, Any], sub: int, h: float, noise: Any
) -> Any:
    """The state `x` carried over one sample interval from `t0` by `sub` RK4 steps of
    `h`, the controls linear from ``u[0]`` to ``u[1]`` across it, and ``noise()`` (a
    step's process noise) added after each step (Euler-Maruyama); ``f(t, x, u)`` is
    the dynamics."""
    u0, u1 = u
    for j in range(sub):
        ua, ub, uc = (u0 + a * (u1 - u0) for a in (j / sub, (j + 0.5) / sub, (j + 1) / sub))
        tt = t0 + j * h
        k1 = f(tt, x, ua)
        k2 = f(tt + h / 2, x + h / 2 * k1, ub)
        k3 = f(tt + h / 2, x + h / 2 * k2, ub)
        k4 = f(tt + h, x + h * k3, uc)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4) + noise()
    return x
