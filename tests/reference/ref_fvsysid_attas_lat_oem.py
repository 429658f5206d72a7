"""FVSysID chapter 4, test case 1: output error on the ATTAS lateral-directional flight.

``mDefCase01`` fits ``xdot_TC01_attas_lat`` / ``obs_TC01_attas_lat`` to
``fAttasAilRud1`` (60 s at 25 Hz, aileron then rudder): states p, r; inputs
aileron (half the right-left difference), rudder and the measured sideslip
(beta as a pseudo-control); outputs p_dot, r_dot, ay (m/s^2), p, r. The 22
parameters are all free: L and N of p, r, aileron, rudder and beta, the ay
derivatives Y of the same five, state biases BX1, BX2 and one bias per
output BY1..BY5 (the p_dot and r_dot outputs leave BX out); the initial state
is held at zero (the lumped biases take its place). The SIDPAC columns hold
FVSysID's output-error method run in numpy (`_fvsysid.ml_oem`): its
estimates and Cramer-Rao standard deviations (FVSysID saved none for it).

Ours: ``aircraft.lateral_linear`` with the measured sideslip as a third
surface, ``beta_m`` (``"beta"`` is refused as a surface name: it is the
model's own state, here driven but neither observed nor fed back, like phi),
``L`` and ``N`` terms p, r, the three surfaces and a constant (BX1, BX2),
``Y`` terms p, r and the surfaces, outputs p_dot, r_dot, ay, p, r with an
output bias on each; zero initial state held. Our ``ay`` is ``V0 sum Y``,
so FVSysID's ``Y*`` are ours times V0 (the mean airspeed), and our p_dot
and r_dot carry the constant, so FVSysID's BY1, BY2 are our output bias
plus ``L_0``, ``N_0`` (no standard error: the result keeps no covariance
between parameters and biases). Default and ``white:`` error bars; ``user:``
rows fit the case word for word as a user ``aeroid.Model`` (beta an input,
every bias a parameter), default bars.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid as F
import _sidpac as S

CASE = "fvsysid_attas_lat_oem"
SOURCE = "fvsysid"
FILE = "fAttasAilRud1.mat"
NAMES = (
    "Lp", "Lr", "Lda", "Ldr", "Lbeta", "Np", "Nr", "Nda", "Ndr", "Nbeta",
    "Yp", "Yr", "Yda", "Ydr", "Ybeta", "BX1", "BX2", "BY1", "BY2", "BY3", "BY4", "BY5",
)  # fmt: skip
P0 = (-3.53744e00, 4.75534e-01, -4.93279e00, 0.73334e00, -4.34076e00,
      -0.86939e-01, -1.69526e-01, -1.92049e-01, -0.74855e00, 1.55155e00,
      0.0364, 2.130, 0.740, 2.279, -5.193) + (0.02,) * 7  # fmt: skip
SURFACES = ("delta_a", "delta_r", "beta_m")
TERMS = ("p", "r", *SURFACES)
# FVSysID's derivative names -> ours (the Y ones scaled by V0)
SHORT = ("p", "r", "da", "dr", "beta")
OURS = {f"{e}{s}": f"{e}_{t}" for e in "LNY" for s, t in zip(SHORT, TERMS, strict=True)}
OURS.update(BX1="L_0", BX2="N_0")
OUTPUTS = ("p_dot", "r_dot", "ay", "p", "r")
DT = 0.04


def _derivatives(x: Any, u: Any, p: Any) -> tuple[Any, Any, Any]:
    """p_dot, r_dot and ay without biases; u holds aileron, rudder, beta."""
    v = [x[0], x[1], u[0], u[1], u[2]]
    return tuple(sum(p[5 * k + j] * v[j] for j in range(5)) for k in range(3))


def state_eq(x: Any, u: Any, p: Any) -> Any:
    """xdot_TC01_attas_lat: roll and yaw accelerations plus the state biases."""
    pd, rd, _ = _derivatives(x, u, p)
    return np.stack([pd + p[15], rd + p[16]])


def obs_eq(x: Any, u: Any, p: Any) -> Any:
    """obs_TC01_attas_lat: p_dot, r_dot, ay, p, r, each with its own bias."""
    pd, rd, ay = _derivatives(x, u, p)
    return np.stack([pd + p[17], rd + p[18], ay + p[19], x[0] + p[20], x[1] + p[21]])


def user_model() -> Any:
    """mDefCase01 as a user ``aeroid.Model``: states p, r; beta an input; FVSysID's names."""
    return F.user_model(
        state_eq,
        obs_eq,
        NAMES,
        P0,
        states=("p", "r"),
        controls=SURFACES,
        outputs=OUTPUTS,
        name="attas_lat_tc01",
    )


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid
    from aeroid.models import aircraft

    (path,) = S.need(folder, FILE, source="fvsysid")
    d = F.read_flight(path)
    z = np.column_stack(
        [d[:, 16] * F.D2R, d[:, 18] * F.D2R, d[:, 2], d[:, 6] * F.D2R, d[:, 8] * F.D2R]
    )
    u = np.column_stack([(d[:, 28] - d[:, 27]) * 0.5 * F.D2R, d[:, 29] * F.D2R, d[:, 13] * F.D2R])
    fv = F.ml_oem(state_eq, obs_eq, np.zeros(2), u, z, DT, np.array(P0))

    v0 = float(np.mean(d[:, 14]))
    scale = {n: (v0 if n.startswith("Y") else 1.0) for n in OURS}
    model = aircraft.lateral_linear(
        V0=v0,
        surfaces=SURFACES,
        terms={"Y": list(TERMS), "L": [*TERMS, "0"], "N": [*TERMS, "0"]},
        outputs=list(OUTPUTS),
    )

    def flight(zz: np.ndarray) -> Any:
        ch = {o: zz[:, j] for j, o in enumerate(OUTPUTS)}
        ch.update({s: u[:, j] for j, s in enumerate(SURFACES)})
        return aeroid.FlightData(
            time=np.asarray(np.arange(len(zz)) * DT, dtype=np.float64), channels=ch
        )

    start = {OURS[n]: P0[i] / scale[n] for i, n in enumerate(NAMES) if n in OURS}
    opts: dict[str, Any] = {
        "x0": dict.fromkeys(("beta", "p", "r", "phi"), 0.0),
        "estimate_x0": False,
        "estimate_bias": list(OUTPUTS),
    }
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(z), start, **opts)
    white = aeroid.identify(model, flight(z), start, error_bars="white", **opts)
    mcs = S.identify_monte_carlo(model, flight, z, res, OUTPUTS, mc, seed=seed, **opts)
    # the case word for word as a user Model: every bias a parameter, BY1, BY2 with bars
    user = aeroid.identify(
        user_model(), flight(z), dict(zip(NAMES, P0, strict=True)), x0=[0.0, 0.0]
    )

    def ours(fit: Any, n: str) -> tuple[float, float | None, float | None]:
        """Our estimate, se and Monte Carlo se of FVSysID's parameter n."""
        if fit is user:
            return fit.parameters[n], fit.stderr[n], None
        if n in OURS:
            k, c = OURS[n], scale[n]
            m = mcs.get(k)
            return fit.parameters[k] * c, fit.stderr[k] * c, None if m is None else m * c
        out = OUTPUTS[int(n[2]) - 1]
        b = fit.biases[0][out]
        if out in ("p_dot", "r_dot"):  # FVSysID's p_dot, r_dot leave the state bias out
            return b + fit.parameters["L_0" if out == "p_dot" else "N_0"], None, None
        return b, fit.extra_stderr[f"bias[0].{out}"], mcs.get(f"bias.{out}")

    note = (
        f"FVSysID ml_oem2 in numpy ({fv.iterations} iterations): estimate and Cramer-Rao sd; "
        "ours lateral_linear (beta as surface beta_m; Y* x V0; BY1, BY2 = bias + L_0, N_0)"
    )
    rows = []
    for label, fit, variant in (("", res, False), ("white:", white, True), ("user:", user, True)):
        for i, n in enumerate(NAMES):
            est, err, mce = ours(fit, n)
            rows.append(
                F.row(
                    CASE,
                    f"{label}{n}",
                    fv.p[i],
                    fv.se[i],
                    est,
                    err,
                    mc_se=mce,
                    seconds=tm.seconds,
                    note=note,
                    variant=variant,
                )
            )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
