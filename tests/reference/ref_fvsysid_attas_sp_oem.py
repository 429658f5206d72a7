"""FVSysID chapter 4, test case 11: output error on the ATTAS short-period motion.

``mDefCase11`` fits ``xdot_TC11_lon_sp`` / ``obs_TC11_lon_sp`` to two elevator
manoeuvres together, ``fAttasElv1`` and ``fAttasElv2`` (25 s at 25 Hz each):
states and outputs alpha, q (rad); input the elevator; eight parameters
``alpha' = Z0 + Za alpha + (Zq + 1) q + Zde de``, ``q' = M0 + Ma alpha + Mq q +
Mde de``, all free; both manoeuvres start, held, from the first sample of
``fAttasElv1`` (the case sets both initial states from ``Z(1,:)`` of the
concatenated record, so the second manoeuvre does not start from its own
first sample). The SIDPAC columns hold FVSysID's output-error method run in
numpy (`_fvsysid.ml_oem`): its estimates and Cramer-Rao standard deviations.
FVSysID also saved the converged estimates of this case
(``chapter07/mDefCase11.m``, ``parOEM``, no standard deviations): the
``saved:`` rows compare ours with them, with the numpy port's bars.

Ours: ``aircraft.longitudinal_linear`` with ``Z`` and ``M`` terms alpha, q,
delta_e and a constant and no ``X`` terms, level trim (its alpha equation
carries ``q`` itself, so FVSysID's ``Zq`` is our ``Z_q``); V and theta are
driven but neither observed nor fed back. Both records are fitted together
from the case's starting values with the same held initial state, default and
``white:`` error bars; ``own_x0:`` rows start each record from its own first
sample instead (against FVSysID's saved answer). The Monte Carlo refits
surrogates of the two records' residuals, concatenated.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid as F
import _sidpac as S

CASE = "fvsysid_attas_sp_oem"
SOURCE = "fvsysid"
FILES = ("fAttasElv1.mat", "fAttasElv2.mat")
NAMES = ("Z_0", "Z_alpha", "Z_q", "Z_delta_e", "M_0", "M_alpha", "M_q", "M_delta_e")
P0 = (-2.52504e-03, -2.13832e-01, 2.78189e-02, 1.66147e-01,
      2.71618e-01, -2.73646e00, -1.08034e00, -3.18940e00)  # fmt: skip
# chapter07/mDefCase11.m: parOEM, "estimates from OEM" of chapter 4's test case 11
SAVED = (-8.98779e-03, -4.83362e-01, 1.04198e-01, 6.76322e-01,
         4.75234e-01, -4.92651e00, -2.00573e00, -7.20806e00)  # fmt: skip
OUTPUTS = ("alpha", "q")
DT = 0.04


def state_eq(x: Any, u: Any, p: Any) -> Any:
    """xdot_TC11_lon_sp: the short-period equations with constants."""
    alpha, q = x[0], x[1]
    return np.stack(
        [
            p[0] + p[1] * alpha + (p[2] + 1.0) * q + p[3] * u[0],
            p[4] + p[5] * alpha + p[6] * q + p[7] * u[0],
        ]
    )


def obs_eq(x: Any, u: Any, p: Any) -> Any:
    """obs_TC11_lon_sp: the two states."""
    return np.stack([x[0], x[1]])


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid
    from aeroid.models import aircraft

    records = [F.read_flight(p) for p in S.need(folder, *FILES, source="fvsysid")]
    zs = [r[:, [12, 7]] * F.D2R for r in records]  # ALCG, QRGY
    us = [r[:, [21]] * F.D2R for r in records]  # DELV
    x0 = zs[0][0]
    fv = F.ml_oem(state_eq, obs_eq, [x0, x0], us, zs, DT, np.array(P0))

    model = aircraft.longitudinal_linear(
        V0=float(np.mean(records[0][:, 14])),
        terms={"X": [], "Z": ["alpha", "q", "delta_e", "0"], "M": ["alpha", "q", "delta_e", "0"]},
        outputs=list(OUTPUTS),
    )

    def flights(z: np.ndarray) -> list[Any]:
        out, k = [], 0
        for u in us:
            zz = z[k : k + len(u)]
            k += len(u)
            ch = {"alpha": zz[:, 0], "q": zz[:, 1], "delta_e": u[:, 0]}
            out.append(
                aeroid.FlightData(
                    time=np.asarray(np.arange(len(u)) * DT, dtype=np.float64), channels=ch
                )
            )
        return out

    def state(z0: np.ndarray) -> dict[str, float]:
        return {"V": 0.0, "alpha": float(z0[0]), "theta": 0.0, "q": float(z0[1])}

    z = np.concatenate(zs)
    start = dict(zip(NAMES, P0, strict=True))
    opts: dict[str, Any] = {"x0": state(x0), "estimate_x0": False}
    with S.Timer() as tm:
        res = aeroid.identify(model, flights(z), start, **opts)
    white = aeroid.identify(model, flights(z), start, error_bars="white", **opts)
    own = aeroid.identify(
        model, flights(z), start, x0=[state(zz[0]) for zz in zs], estimate_x0=False
    )
    resid = np.concatenate([S.output_residuals(res, OUTPUTS, k) for k in range(len(zs))])

    def refit(zz: np.ndarray) -> dict[str, float]:
        r = aeroid.identify(model, flights(zz), dict(res.parameters), error_bars="white", **opts)
        return dict(r.parameters)

    mcs = S.monte_carlo(refit, z - resid, resid, mc, seed=seed)
    note = (
        f"FVSysID ml_oem2 in numpy ({fv.iterations} iterations): estimate and Cramer-Rao sd; "
        "saved: FVSysID's parOEM (chapter07/mDefCase11.m) with the port's sd"
    )
    rows = []
    sets = (
        ("", res, fv.p, False),
        ("white:", white, fv.p, True),
        ("saved:", res, SAVED, True),
        ("own_x0:", own, SAVED, True),
    )
    for label, fit, ref, variant in sets:
        rows += [
            F.row(
                CASE,
                f"{label}{n}",
                ref[i],
                fv.se[i],
                fit.parameters[n],
                fit.stderr[n],
                mc_se=None if label == "own_x0:" else mcs.get(n),
                seconds=tm.seconds,
                note=note,
                variant=variant,
            )
            for i, n in enumerate(NAMES)
        ]
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
