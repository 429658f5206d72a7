"""AeroSandbox airplanes as longitudinal 3-DOF AeroID models (``pip install "aeroid[aerosandbox]"``).

`aerosandbox_model` runs AeroSandbox's AeroBuildup once over a grid of angle
of attack and elevator deflection, and returns a genuine `aeroid.Model`
whose dynamics interpolate those tables. Because the result is an ordinary
`Model`, identification, filtering, inference and every other path apply
(except ``gradient="jax"``: the table lookups are numpy code).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AdapterError
from ..models.model import Model
from . import require

__all__ = ["aerosandbox_model"]

FloatArray = NDArray[np.float64]
G0 = 9.80665


class LongitudinalDynamics:
    """Wind-axis longitudinal equations of motion driven by tabulated coefficients.

    States ``V`` (m/s), ``alpha`` (rad), ``q`` (rad/s), ``theta`` (rad);
    control ``elevator`` (rad). With q̄ = ½ρV², L = q̄S·CL, D = q̄S·CD and
    a thrust T along the body x axis::

        V'     = (T cos α − D)/m − g sin(θ − α)
        α'     = q − (L + T sin α)/(m V) + g cos(θ − α)/V
        q'     = q̄ S c̄ Cm / Iyy
        θ'     = q

    with CL = CL_scale·CL(α, δe) + CL_q·q c̄/(2V), CD = CD_scale·CD(α, δe),
    Cm = Cm_scale·Cm(α, δe) + Cm_q·q c̄/(2V). The tables are interpolated
    bilinearly (extrapolated linearly outside the grid). Works on single
    points and on batches (arrays of shape (n, batch)).

    Attributes
    ----------
    alpha_deg, elevator_deg : ndarray
        Grid of the tables in degrees.
    CL, CD, Cm : ndarray, shape (n_alpha, n_elevator)
        AeroBuildup coefficients about the airplane's ``xyz_ref``.
    trim : mapping of str to float
        Level-flight trim at the reference velocity with the nominal
        parameters: ``V``, ``alpha``, ``q``, ``theta``, ``elevator``, ``thrust``.
    """

    def __init__(
        self,
        alpha_deg: FloatArray,
        elevator_deg: FloatArray,
        CL: FloatArray,
        CD: FloatArray,
        Cm: FloatArray,
        *,
        mass: float,
        Iyy: float,
        rho: float,
        S: float,
        cbar: float,
    ) -> None:
        self.alpha_deg = alpha_deg
        self.elevator_deg = elevator_deg
        self.CL, self.CD, self.Cm = CL, CD, Cm
        self.mass, self.Iyy, self.rho, self.S, self.cbar = mass, Iyy, rho, S, cbar
        self._a = np.radians(alpha_deg)
        self._d = np.radians(elevator_deg)
        self._tables = np.stack([CL, CD, Cm], axis=-1)  # one lookup for all three
        self.trim: Mapping[str, float] = {}

    def coefficients(self, alpha: Any, de: Any) -> tuple[Any, Any, Any]:
        """Unscaled CL, CD, Cm at angle of attack and elevator deflection (rad)."""
        a, d, tab = self._a, self._d, self._tables
        i = np.clip(np.searchsorted(a, alpha) - 1, 0, a.size - 2)
        j = np.clip(np.searchsorted(d, de) - 1, 0, d.size - 2)
        wa = np.expand_dims((alpha - a[i]) / (a[i + 1] - a[i]), -1)
        wd = np.expand_dims((de - d[j]) / (d[j + 1] - d[j]), -1)
        lo = tab[i, j] + wd * (tab[i, j + 1] - tab[i, j])
        hi = tab[i + 1, j] + wd * (tab[i + 1, j + 1] - tab[i + 1, j])
        c = lo + wa * (hi - lo)
        return c[..., 0], c[..., 1], c[..., 2]

    def __call__(self, t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        V, alpha, q, theta = x[0], x[1], x[2], x[3]
        de = u[0]
        cl, cd, cm = self.coefficients(alpha, de)
        qhat = q * self.cbar / (2.0 * V)
        qbar_s = 0.5 * self.rho * V * V * self.S
        lift = qbar_s * (p["CL_scale"] * cl + p["CL_q"] * qhat)
        drag = qbar_s * p["CD_scale"] * cd
        moment = qbar_s * self.cbar * (p["Cm_scale"] * cm + p["Cm_q"] * qhat)
        thrust = p["thrust"]
        gamma = theta - alpha
        m = self.mass
        return np.array(
            [
                (thrust * np.cos(alpha) - drag) / m - G0 * np.sin(gamma),
                q - (lift + thrust * np.sin(alpha)) / (m * V) + G0 * np.cos(gamma) / V,
                moment / self.Iyy,
                q,
            ]
        )


def aerosandbox_model(
    airplane: Any,
    *,
    mass: float,
    Iyy: float,
    velocity: float,
    altitude: float = 0.0,
    alpha_range: tuple[float, float] = (-6.0, 14.0),
    n_alpha: int = 11,
    elevator: str = "elevator",
    elevator_range: tuple[float, float] = (-15.0, 15.0),
    n_elevator: int = 7,
    name: str | None = None,
) -> Model:
    """Build a longitudinal 3-DOF `aeroid.Model` from AeroSandbox AeroBuildup tables.

    Parameters
    ----------
    airplane : aerosandbox.Airplane
        The airplane; moments are taken about its ``xyz_ref``, which should be
        the centre of gravity. Its reference area, chord and the control
        surface named `elevator` are used.
    mass : float
        Mass in kg.
    Iyy : float
        Pitch moment of inertia about the CG in kg m².
    velocity : float
        Reference airspeed in m/s: the AeroBuildup evaluations and the trim
        use it (coefficients are assumed independent of airspeed otherwise).
    altitude : float
        Altitude in m; sets the (constant) air density of the ISA atmosphere.
    alpha_range : (float, float)
        Angle-of-attack range of the tables in degrees.
    n_alpha : int
        Number of angle-of-attack grid points.
    elevator : str
        Name of the airplane's symmetric pitch control surface.
    elevator_range : (float, float)
        Deflection range of the tables in degrees (AeroSandbox's sign).
    n_elevator : int
        Number of deflection grid points.
    name : str, optional
        Model name (default ``"aerosandbox:<airplane.name>"``).

    Returns
    -------
    Model
        States ``V`` (m/s), ``alpha``, ``q``, ``theta`` (rad, rad/s), control
        ``elevator`` (rad); parameters ``CL_scale``, ``CD_scale``,
        ``Cm_scale`` (nominal 1), ``CL_q``, ``Cm_q`` (AeroBuildup's pitch-rate
        derivatives at trim, per unit q c̄/(2V)) and ``thrust`` (N, nominal:
        the level-flight trim thrust). ``model.dynamics`` is a
        `LongitudinalDynamics` whose ``trim`` holds the trimmed state,
        elevator and thrust, a natural ``x0`` and control offset.

    Raises
    ------
    AdapterError
        AeroSandbox is not installed, the airplane has no such control
        surface, an argument is out of range, or no level-flight trim exists
        inside the tables.
    """
    asb = require("aerosandbox", "aerosandbox")
    for what, value in (("mass", mass), ("Iyy", Iyy), ("velocity", velocity)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise AdapterError(f"{what}: expected a positive number, got {value!r}")
    if not isinstance(altitude, int | float) or not math.isfinite(altitude):
        raise AdapterError(f"altitude: expected a number in m, got {altitude!r}")
    a_grid = _grid(alpha_range, n_alpha, "alpha_range", "n_alpha")
    d_grid = _grid(elevator_range, n_elevator, "elevator_range", "n_elevator")
    if not isinstance(airplane, asb.Airplane):
        raise AdapterError(
            f"airplane: expected an aerosandbox.Airplane, got {type(airplane).__name__}"
        )
    surfaces = {
        cs.name for wing in airplane.wings for xsec in wing.xsecs for cs in xsec.control_surfaces
    }
    if elevator not in surfaces:
        raise AdapterError(
            f"elevator: airplane {airplane.name!r} has no control surface {elevator!r}; "
            f"its control surfaces: {sorted(surfaces)}"
        )

    atmosphere = asb.Atmosphere(altitude=float(altitude))
    CL = np.empty((a_grid.size, d_grid.size))
    CD = np.empty_like(CL)
    Cm = np.empty_like(CL)
    for j, deflection in enumerate(d_grid):
        deflected = airplane.with_control_deflections({elevator: float(deflection)})
        op = asb.OperatingPoint(atmosphere=atmosphere, velocity=float(velocity), alpha=a_grid)
        aero = asb.AeroBuildup(airplane=deflected, op_point=op).run()
        CL[:, j] = np.asarray(aero["CL"], dtype=np.float64).reshape(-1)
        CD[:, j] = np.asarray(aero["CD"], dtype=np.float64).reshape(-1)
        Cm[:, j] = np.asarray(aero["Cm"], dtype=np.float64).reshape(-1)
    if not (np.all(np.isfinite(CL)) and np.all(np.isfinite(CD)) and np.all(np.isfinite(Cm))):
        raise AdapterError("AeroBuildup returned non-finite coefficients; narrow alpha_range")

    dyn = LongitudinalDynamics(
        a_grid,
        d_grid,
        CL,
        CD,
        Cm,
        mass=float(mass),
        Iyy=float(Iyy),
        rho=float(np.asarray(atmosphere.density())),
        S=float(airplane.s_ref),
        cbar=float(airplane.c_ref),
    )
    alpha_t, de_t, thrust_t = _trim(dyn, float(velocity), airplane.name)
    stab = asb.AeroBuildup(
        airplane=airplane.with_control_deflections({elevator: math.degrees(de_t)}),
        op_point=asb.OperatingPoint(
            atmosphere=atmosphere, velocity=float(velocity), alpha=math.degrees(alpha_t)
        ),
    ).run_with_stability_derivatives(alpha=False, beta=False, p=False, q=True, r=False)
    dyn.trim = {
        "V": float(velocity),
        "alpha": alpha_t,
        "q": 0.0,
        "theta": alpha_t,
        "elevator": de_t,
        "thrust": thrust_t,
    }
    return Model(
        states=["V", "alpha", "q", "theta"],
        controls=["elevator"],
        parameters={
            "CL_scale": 1.0,
            "CD_scale": 1.0,
            "Cm_scale": 1.0,
            "CL_q": float(np.asarray(stab["CLq"]).reshape(-1)[0]),
            "Cm_q": float(np.asarray(stab["Cmq"]).reshape(-1)[0]),
            "thrust": thrust_t,
        },
        dynamics=dyn,
        name=name or f"aerosandbox:{airplane.name}",
    )


def _grid(rng: tuple[float, float], n: int, what: str, count: str) -> FloatArray:
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise AdapterError(f"{what}: expected (low, high) in degrees, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise AdapterError(f"{what}: expected finite low < high in degrees, got {rng!r}")
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise AdapterError(f"{count}: expected an integer >= 2, got {n!r}")
    return np.linspace(lo, hi, n)


def _trim(dyn: LongitudinalDynamics, V: float, airplane: str) -> tuple[float, float, float]:
    """Level flight at V: thrust balances drag, lift (plus thrust) weight, zero moment."""
    from scipy.optimize import least_squares

    qbar_s = 0.5 * dyn.rho * V * V * dyn.S
    weight = dyn.mass * G0

    def residual(z: FloatArray) -> FloatArray:
        alpha, de, thrust = z
        cl, cd, cm = dyn.coefficients(alpha, de)
        return np.array(
            [
                (thrust * np.cos(alpha) - qbar_s * cd) / weight,
                (qbar_s * cl + thrust * np.sin(alpha) - weight) / weight,
                cm,
            ]
        )

    lo = [dyn._a[0], dyn._d[0], 0.0]
    hi = [dyn._a[-1], dyn._d[-1], 10.0 * weight]
    sol = least_squares(
        residual,
        [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.1 * weight],
        bounds=(lo, hi),
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
    )
    if not np.all(np.abs(sol.fun) < 1e-8):
        raise AdapterError(
            f"airplane {airplane!r}: no level-flight trim at {V} m/s inside the tables "
            f"(alpha {np.degrees(dyn._a[[0, -1]]).round(2).tolist()} deg, elevator "
            f"{np.degrees(dyn._d[[0, -1]]).round(2).tolist()} deg); widen alpha_range or "
            "elevator_range, or change mass or velocity"
        )
    alpha, de, thrust = (float(v) for v in sol.x)
    return alpha, de, thrust
