"""FVSysID chapter 5, test case 2: filter error on simulated lateral data in turbulence.

``mDefCase02`` (chapter05) fits ``xdot_TC02_dhc2_lat`` / ``obs_TC02_dhc2_lat``
to ``y13aus_da1.asc`` (16 s at 20 Hz, simulated with process noise): states
p, r; inputs aileron, rudder and the lateral gust velocity v; outputs pdot,
rdot, ay, p, r; the linear model's 15 derivatives (L, N, Y of p, r, da, dr,
v), two state biases, five output biases and the diagonal of the process-noise
matrix F free (24 parameters), the initial state held at zero. The SIDPAC
columns hold FVSysID's ``ml_fem2`` run in numpy here (`_fvsysid_fem.ml_fem`):
its estimate and Cramer-Rao standard deviation. FVSysID states no true values
for this simulation, but the file's simulated pdot, rdot and ay (the columns
the case fits) are exact linear functions of its simulated p, r and the
inputs (least-squares residual 1e-7, the file's rounding: no measurement
noise on any output): their coefficients are the simulation's derivatives
(`data_truth`), and ``truth <who>:`` rows give each method's recovery of the
15 derivatives in its own standard errors.

Ours: the same equations as a user ``aeroid.Model`` (the biases are model
parameters, as FVSysID writes them; ``estimate_bias`` now does this too), by
``aeroid.identify(method="filter_error", estimate_process_noise=True)`` from
the case's start, process noise at F0^2, measurement noise estimated, ``x0``
held; ``F_p``, ``F_r`` rows compare sqrt of our intensity. ``white:`` rows
are ``error_bars="white"``; ``oem:`` rows ``method="output_error"`` against
the same predictor's output error in numpy, and ``fvsysid oem-fem:`` rows the
book's two methods against each other: the bias output error takes from the
process noise, which is this case's reason to exist.

With no measurement noise in the record our maximum likelihood drives every
measurement variance to its floor and recovers the output equations'
coefficients to the file's rounding, with standard errors to match (1e-7);
the book's method, its innovation covariance standing in for the
measurement noise, cannot. With the filter started at the given start
exactly (no prior: it is held), the information on this noise-free record
is singular to working precision along combinations of Lp, Np, BX2 and the
noise levels, which the fit reports inseparable (those bars read 0). The Monte Carlo (the port's fitted predictor
driven by its own innovations on every output) makes records with
measurement noise the flight does not have: its spread is no judge of our
bars here.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid_fem as P
import _sidpac as S
from _fvsysid import read_flight

CASE = "fvsysid_dhc2_fem"
SOURCE = "fvsysid"
FILE = "y13aus_da1.asc"
NAMES = (
    "Lp", "Lr", "Lda", "Ldr", "Lv", "Np", "Nr", "Nda", "Ndr", "Nv",
    "Yp", "Yr", "Yda", "Ydr", "Yv", "BX1", "BX2", "BY1", "BY2", "BY3", "BY4", "BY5",
)  # fmt: skip
P0 = (-6.7, 1.83, -18.3, 0.43, -0.114, -0.906, -0.665, -0.66, -2.82, 0.0069,
      -0.64, 1.30, -1.40, 2.79, -0.193, 0.08, -0.089,
      0.08, -0.089, 0.044, -0.0034, -0.0015)  # fmt: skip
F0 = (0.02, 0.02)
STATES = ("p", "r")
OUTPUTS = ("p_dot", "r_dot", "ay", "p_meas", "r_meas")
DT = 0.05


def _rows(x: Any, u: Any, c: Any) -> tuple[Any, Any, Any]:
    """The L, N and Y sums of the linear model (no biases)."""
    p, r = x[0], x[1]
    da, dr, v = u[0], u[1], u[2]
    lsum = c[0] * p + c[1] * r + c[2] * da + c[3] * dr + c[4] * v
    nsum = c[5] * p + c[6] * r + c[7] * da + c[8] * dr + c[9] * v
    ysum = c[10] * p + c[11] * r + c[12] * da + c[13] * dr + c[14] * v
    return lsum, nsum, ysum


def _rates(x: Any, u: Any, c: Any) -> list[Any]:
    lsum, nsum, _ = _rows(x, u, c)
    return [lsum + c[15], nsum + c[16]]


def _outputs(x: Any, u: Any, c: Any) -> list[Any]:
    lsum, nsum, ysum = _rows(x, u, c)
    return [lsum + c[17], nsum + c[18], ysum + c[19], x[0] + c[20], x[1] + c[21]]


def port_case(d: np.ndarray) -> P.FemCase:
    """mDefCase02 for the numpy port (batched model functions)."""

    def f(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.stack(_rates(x.T, u.T, p.T), axis=-1)

    def h(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.stack(_outputs(x.T, u.T, p.T), axis=-1)

    return P.FemCase(f, h, 2, d[:, 11:16], d[:, 16:19], DT, np.zeros(2), np.array(P0 + F0))


def user_model() -> Any:
    """The case's equations as a user writes them for aeroid."""
    import aeroid

    def dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array(_rates(x, u, [p[n] for n in NAMES]))

    def measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
        return np.array(_outputs(x, u, [p[n] for n in NAMES]))

    return aeroid.Model(
        states=list(STATES),
        controls=["delta_a", "delta_r", "v"],
        parameters=dict(zip(NAMES, P0, strict=True)),
        dynamics=dynamics,
        outputs=list(OUTPUTS),
        measurement=measurement,
        name="dhc2_lat",
        linear=True,
    )


def data_truth(d: np.ndarray) -> dict[str, float]:
    """The derivatives the simulated outputs obey: pdot, rdot and ay regressed on the
    simulated states (columns 20, 21), the inputs and a constant."""
    x = np.column_stack([d[:, 19], d[:, 20], d[:, 16:19], np.ones(d.shape[0])])
    out: dict[str, float] = {}
    for k, col in enumerate((11, 12, 13)):
        coef = np.linalg.lstsq(x, d[:, col], rcond=None)[0]
        out.update(zip(NAMES[5 * k : 5 * k + 5], map(float, coef[:5]), strict=True))
    return out


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    (path,) = S.need(folder, FILE, source="fvsysid")
    d = read_flight(path)
    t = np.arange(d.shape[0]) * DT

    def flight(z: np.ndarray) -> Any:
        ch = {o: z[:, j] for j, o in enumerate(OUTPUTS)}
        ch.update(delta_a=d[:, 16], delta_r=d[:, 17], v=d[:, 18])
        return aeroid.FlightData(time=t, channels=ch)

    return P.compare(
        CASE,
        port_case(d),
        NAMES,
        STATES,
        user_model(),
        flight,
        dict.fromkeys(STATES, 0.0),
        mc=mc,
        seed=seed,
        truth=data_truth(d),
    )


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
