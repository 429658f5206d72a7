"""FVSysID chapter 4, test case 4: output error on the HFB-320's longitudinal flight.

``mDefCase04`` fits ``xdot_TC04_hfb_lon`` / ``obs_TC04_hfb_lon`` to
``hfb320_1_10.asc`` (60 s at 10 Hz, elevator 3-2-1-1 then a pulse): states V,
alpha, theta, q; inputs elevator and thrust; outputs V, alpha, theta, q, qdot,
ax, az; the 11 non-dimensional coefficients (drag, lift and pitching moment in
V/V0 and alpha, with Cm_q and Cm_de) free, the initial state held at the
case's values, no biases. FVSysID saved no converged estimates for it: its
output-error method (``ml_oem2``) runs here in numpy (`_fvsysid.ml_oem`) and
the SIDPAC columns hold that port's estimates and Cramer-Rao standard
deviations (FVSysID gives no corrected bars).

Ours: the same equations written as a user ``aeroid.Model``, fitted by
``aeroid.identify`` from the case's starting values with the initial state
held (``x0=``, ``estimate_x0=False``), with its default (coloured) error bars
and, as ``white:`` variant rows, ``error_bars="white"``.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid as F
import _sidpac as S

CASE = "fvsysid_hfb320_oem"
SOURCE = "fvsysid"
FILE = "hfb320_1_10.asc"
NAMES = ("CD0", "CDV", "CDAL", "CL0", "CLV", "CLAL", "CM0", "CMV", "CMAL", "CMQ", "CMDE")
P0 = (5.67516e-03, 7.72612e-03, 6.74256e-01, -3.18267e-01, 2.60317e-01, 5.37576e00,
      4.98218e-02, 1.89182e-02, -4.98586e-01, -2.58439e01, -9.90687e-01)  # fmt: skip
STATES = ("V", "alpha", "theta", "q")
X0 = (1.06023e02, 1.11685e-01, 1.04887e-01, -3.32659e-03)
OUTPUTS = ("V", "alpha", "theta", "q", "qdot", "ax", "az")
DT = 0.1
# the case's geometry, mass and flight-condition constants
G0, SBYM, SCBYIY, FEIYLT = 9.80665, 4.028e-3, 8.0027e-4, -7.0153e-6
V0, RM, SIGMAT, RHO, CBAR = 104.67, 7472.0, 0.0524, 0.792, 1.215


def _aero(x: Any, u: Any, c: Any) -> tuple[Any, Any, Any, Any]:
    """Dynamic pressure, CD, CL and the pitching-moment coefficient."""
    v, alpha, _, q = x[0], x[1], x[2], x[3]
    qbar = 0.5 * RHO * v**2
    cd = c[0] + c[1] * v / V0 + c[2] * alpha
    cl = c[3] + c[4] * v / V0 + c[5] * alpha
    cm = c[6] + c[7] * v / V0 + c[8] * alpha + CBAR * c[9] * q / V0 + c[10] * u[0]
    return qbar, cd, cl, cm


def state_eq(x: Any, u: Any, c: Any) -> Any:
    """The case's state equations (book eqs. 5.86-5.87); c: the 11 coefficients."""
    v, alpha, theta, q = x[0], x[1], x[2], x[3]
    qbar, cd, cl, cm = _aero(x, u, c)
    thrust = u[1]
    return np.stack(
        [
            -SBYM * qbar * cd + thrust * np.cos(alpha + SIGMAT) / RM + G0 * np.sin(alpha - theta),
            -SBYM * qbar / v * cl
            - thrust * np.sin(alpha + SIGMAT) / (RM * v)
            + q
            + G0 * np.cos(alpha - theta) / v,
            q,
            SCBYIY * qbar * cm + FEIYLT * thrust,
        ]
    )


def obs_eq(x: Any, u: Any, c: Any) -> Any:
    """The case's outputs: the states, qdot and the body-axis accelerations."""
    alpha = x[1]
    qbar, cd, cl, cm = _aero(x, u, c)
    thrust = u[1]
    cx = cl * np.sin(alpha) - cd * np.cos(alpha)
    cz = -cl * np.cos(alpha) - cd * np.sin(alpha)
    return np.stack(
        [
            x[0],
            alpha,
            x[2],
            x[3],
            SCBYIY * qbar * cm + FEIYLT * thrust,
            qbar * SBYM * cx + thrust * np.cos(SIGMAT) / RM,
            qbar * SBYM * cz - thrust * np.sin(SIGMAT) / RM,
        ]
    )


def model() -> Any:
    """The case as a user writes it for aeroid."""
    return F.user_model(
        state_eq,
        obs_eq,
        NAMES,
        P0,
        states=STATES,
        controls=("delta_e", "thrust"),
        outputs=OUTPUTS,
        name="hfb320_lon",
    )


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    (path,) = S.need(folder, FILE, source="fvsysid")
    d = F.read_flight(path)
    z, u = d[:, 4:11], d[:, [1, 3]]
    t = np.asarray(np.arange(len(z)) * DT, dtype=np.float64)
    fv = F.ml_oem(state_eq, obs_eq, np.array(X0), u, z, DT, np.array(P0))

    def flight(zz: np.ndarray) -> Any:
        ch = {o: zz[:, j] for j, o in enumerate(OUTPUTS)}
        ch.update(delta_e=u[:, 0], thrust=u[:, 1])
        return aeroid.FlightData(time=t, channels=ch)

    m = model()
    start = dict(zip(NAMES, P0, strict=True))
    opts: dict[str, Any] = {"x0": dict(zip(STATES, X0, strict=True)), "estimate_x0": False}
    with S.Timer() as tm:
        res = aeroid.identify(m, flight(z), start, **opts)
    white = aeroid.identify(m, flight(z), start, error_bars="white", **opts)
    mcs = S.identify_monte_carlo(m, flight, z, res, OUTPUTS, mc, seed=seed, **opts)
    note = (
        f"FVSysID ml_oem2 in numpy ({fv.iterations} iterations, stop at 1e-4 relative "
        "change of det R): its estimate and Cramer-Rao sd"
    )
    rows = []
    for label, fit, variant in (("", res, False), ("white:", white, True)):
        rows += [
            F.row(
                CASE,
                f"{label}{n}",
                fv.p[i],
                fv.se[i],
                fit.parameters[n],
                fit.stderr[n],
                mc_se=mcs.get(n),
                seconds=tm.seconds,
                note=note,
                variant=variant,
            )
            for i, n in enumerate(NAMES)
        ]
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
