"""FVSysID test case 22: flight path reconstruction of ATTAS over three segments.

Jategaonkar ch. 10 (``chapter04/mDefCase22.m``, ``xdot_TC22_fpr.m``,
``obs_TC22_fpr.m``): the elevator, aileron and rudder manoeuvres
``fAttasElv1``, ``fAttasAil1``, ``fAttasRud1`` analysed together (NZI = 3).
States u, v, w, phi, theta, psi, h driven by the measured specific forces
and rates (the accelerometers 1.0 m behind, 0.9 m right of and 0.1 m above
the CG, so ``pdot, qdot, rdot`` enter, from ``ndiff_pqr``: smoothing and
differentiating p, q, r per segment); outputs V, alpha, beta at the nose
boom (13.08 m ahead: ``atan2`` of the boom's velocity components), phi,
theta, psi, h; g = 9.80. Estimated: the six biases of ax, ay, az, p, q, r,
shared by the segments; the initial states held at the case's values (u,
v, w given, attitudes and height the first samples); alpha and beta
scale factors and offsets fixed at 1 and 0. FVSysID saved no result: its
method runs here in numpy (`_fvsysid.ml_oem`, ``ml_oem2`` with
``ruku4``); the SIDPAC columns hold its estimates and Cramer-Rao standard
deviations (``par_accuracy``; no corrected bar).

Ours: the same equations written as a user ``aeroid.Model`` and fitted by
``aeroid.identify`` to the three records (shared biases, per-record initial
states held), as a user would; rows ``white`` use ``error_bars="white"``.
Rows ``cc<k>`` (variants): ``aeroid.check_compatibility`` on segment k alone
(the six biases, the case's x0 held, g = 9.80, default bars) with the case's
lever arms (``accel_position``, ``alpha_vane_position``,
``beta_vane_position``), ``sideslip="atan"`` and FVSysID's ``pdot, qdot,
rdot`` as the record's ``p_dot, q_dot, r_dot``, next to FVSysID's method on
that segment; rows ``cc123`` the three segments together (shared biases, each
its own x0 held) next to the case's fit.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid as F
import _sidpac as S

CASE = "fvsysid_fpr"
SOURCE = "fvsysid"
FILES = ("fAttasElv1.mat", "fAttasAil1.mat", "fAttasRud1.mat")
DT = 0.04
G = 9.80
D2R = np.pi / 180
FT2M = 0.3048
BIASES = ("b_ax", "b_ay", "b_az", "b_p", "b_q", "b_r")
AIR = ("f_al", "b_al", "f_be", "b_be")
STATES = ("u", "v", "w", "phi", "theta", "psi", "h")
OUTPUTS = ("V", "alpha", "beta", "phi", "theta", "psi", "h")
CONTROLS = ("ax", "ay", "az", "p", "q", "r", "pdot", "qdot", "rdot")
ACC = (-1.010, 0.886, 0.103)  # accelerometer package relative to the CG, m
BOOM = (13.080, -0.010, -0.027)  # nose-boom vane position relative to the CG, m
UVW0 = ((129.4, -0.9, 5.05), (129.4, -0.9, 5.15), (128.7, -0.9, 4.75))


# ------------------------------------------------------------------ FVSysID's data handling


def segments(folder: pathlib.Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(time, Z, U) of each segment in FVSysID's units (SI, rad) and channel order."""
    out = []
    for path in S.need(folder, *FILES, source=SOURCE):
        d = F.read_flight(path)
        z = np.column_stack(
            [d[:, 14], d[:, 12] * D2R, d[:, 13] * D2R, d[:, 9] * D2R, d[:, 10] * D2R,
             d[:, 11] * D2R, d[:, 15] * FT2M]
        )  # fmt: skip
        rates = [d[:, j] for j in (6, 7, 8)]
        dots = [F.differentiate(F.smooth(x), DT) * D2R for x in rates]
        u = np.column_stack([d[:, 1], d[:, 2], d[:, 3], *(x * D2R for x in rates), *dots])
        out.append((np.arange(d.shape[0]) * DT, z, u))
    return out


def initial_states(segs: list[Any]) -> np.ndarray:
    """The case's x0: given u, v, w; attitudes and height from the first samples."""
    return np.array([[*UVW0[k], *z[0, 3:7]] for k, (_, z, _) in enumerate(segs)])


# ------------------------------------------------------------------ the equations, twice


def kinematics(x: Any, c: Any, p: dict[str, Any]) -> list[Any]:
    """``xdot_TC22_fpr`` (Eqs. 10.8, 10.11) for either side: numpy broadcasting."""
    uu, vv, ww, phi, theta = x[0], x[1], x[2], x[3], x[4]
    ax, ay, az = c[0] - p["b_ax"], c[1] - p["b_ay"], c[2] - p["b_az"]
    P, Q, R = c[3] - p["b_p"], c[4] - p["b_q"], c[5] - p["b_r"]
    pd, qd, rd = c[6], c[7], c[8]
    xa, ya, za = ACC
    ax = ax + xa * (Q * Q + R * R) - ya * (P * Q - rd) - za * (P * R + qd)
    ay = ay - xa * (P * Q + rd) + ya * (P * P + R * R) - za * (Q * R - pd)
    az = az - xa * (P * R - qd) - ya * (Q * R + pd) + za * (P * P + Q * Q)
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    turn = Q * sphi + R * cphi
    return [
        ax - G * sth + R * vv - Q * ww,
        ay + G * sphi * cth + P * ww - R * uu,
        az + G * cphi * cth + Q * uu - P * vv,
        P + turn * sth / cth,
        Q * cphi - R * sphi,
        turn / cth,
        uu * sth - vv * sphi * cth - ww * cphi * cth,
    ]


def sensors(x: Any, c: Any, p: dict[str, Any]) -> list[Any]:
    """``obs_TC22_fpr`` (Eqs. 10.12, 10.13): air data at the nose boom."""
    uu, vv, ww = x[0], x[1], x[2]
    P, Q, R = c[3] - p["b_p"], c[4] - p["b_q"], c[5] - p["b_r"]
    xb, yb, zb = BOOM
    unb = uu - R * yb + Q * zb
    vnb = vv - P * zb + R * xb
    wnb = ww - Q * xb + P * yb
    return [
        np.sqrt(uu * uu + vv * vv + ww * ww),
        p["f_al"] * np.arctan2(wnb, unb) + p["b_al"],
        p["f_be"] * np.arctan2(vnb, unb) + p["b_be"],
        x[3],
        x[4],
        x[5],
        x[6],
    ]


NAMES = (*BIASES, *AIR)


def _port_eq(fn: Any) -> F.Fn:
    def eq(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.stack(fn(x, u, dict(zip(NAMES, p, strict=True))))

    return eq


PORT_STATE, PORT_OBS = _port_eq(kinematics), _port_eq(sensors)
# the case's start: biases zero and free, the air-data factors one, offsets zero, held
PORT_P0 = np.array([0.0] * 6 + [1.0, 0.0, 1.0, 0.0])
PORT_FREE = np.array([True] * 6 + [False] * 4)


def port(segs: list[Any], x0: np.ndarray) -> F.OemResult:
    """FVSysID's fit of case 22 on `segs` from their initial states `x0` (held)."""
    us, zs = [u for _, _, u in segs], [z for _, z, _ in segs]
    return F.ml_oem(PORT_STATE, PORT_OBS, x0, us, zs, DT, PORT_P0, free=PORT_FREE, names=NAMES)


def model(start: dict[str, float]) -> Any:
    """The same equations as a user ``aeroid.Model``."""
    import aeroid

    return aeroid.Model(
        states=list(STATES),
        controls=list(CONTROLS),
        parameters=start,
        dynamics=lambda t, x, u, p: np.stack(kinematics(x, u, p)),
        outputs=list(OUTPUTS),
        measurement=lambda t, x, u, p: np.stack(sensors(x, u, p)),
        name="attas_fpr",
    )


def flights(segs: list[Any], zs: list[np.ndarray] | None = None) -> list[Any]:
    import aeroid

    out = []
    for k, (t, z, u) in enumerate(segs):
        zk = z if zs is None else zs[k]
        ch = {o: zk[:, j] for j, o in enumerate(OUTPUTS)}
        ch.update({c: u[:, j] for j, c in enumerate(CONTROLS)})
        out.append(aeroid.FlightData(time=t, channels=ch))
    return out


def _cc_record(t: np.ndarray, z: np.ndarray, u: np.ndarray) -> Any:
    """One segment as `check_compatibility` reads it, FVSysID's p, q, r derivatives
    as ``p_dot, q_dot, r_dot``."""
    import aeroid

    ch = {o: z[:, j] for j, o in enumerate(OUTPUTS)}
    ch.update({c: u[:, j] for j, c in enumerate(CONTROLS[:6])})
    ch.update({f"{c}_dot": u[:, 6 + j] for j, c in enumerate(("p", "q", "r"))})
    return aeroid.FlightData(time=t, channels=ch)


# the case's sensor geometry in check_compatibility's options
CC_OPTIONS = {
    "accel_position": ACC,
    "alpha_vane_position": BOOM,
    "beta_vane_position": BOOM,
    "sideslip": "atan",
}


def compatibility_rows(segs: list[Any], x0: np.ndarray) -> list[dict[str, Any]]:
    """``check_compatibility`` with the case's lever arms and flank-angle beta on each
    segment alone (variant rows ``cc<k>``) next to FVSysID's method on that segment,
    and on the three segments together (``cc123``) next to the case's fit."""
    import aeroid

    rows = []
    common = {"estimate": list(BIASES), "estimate_x0": False, "gravity": G, **CC_OPTIONS}
    for k, (t, z, u) in enumerate(segs):
        fv = port(segs[k : k + 1], x0[k : k + 1])
        with S.Timer() as tm:
            cc = aeroid.check_compatibility(
                _cc_record(t, z, u), x0=dict(zip(STATES, x0[k], strict=True)), **common
            )
        rows += [
            F.row(
                CASE,
                f"cc{k + 1}:{n}",
                fv.p[i],
                fv.se[i],
                cc.parameters[n],
                cc.stderr[n],
                seconds=tm.seconds,
                variant=True,
            )
            for i, n in enumerate(BIASES)
        ]
    fv = port(segs, x0)
    with S.Timer() as tm:
        together = aeroid.check_compatibility(
            [_cc_record(*seg) for seg in segs],
            x0=[dict(zip(STATES, x, strict=True)) for x in x0],
            **common,
        )[0]
    rows += [
        F.row(
            CASE,
            f"cc123:{n}",
            fv.p[i],
            fv.se[i],
            together.parameters[n],
            together.stderr[n],
            seconds=tm.seconds,
            variant=True,
        )
        for i, n in enumerate(BIASES)
    ]
    return rows


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    segs = segments(folder)
    x0 = initial_states(segs)
    fv = port(segs, x0)
    crb = fv.stderr
    start = dict(zip(NAMES, PORT_P0, strict=True))
    m = model(start)
    guess = dict.fromkeys(BIASES, 0.0)
    opts: dict[str, Any] = {"x0": [list(x) for x in x0], "estimate_x0": False}
    data = flights(segs)
    with S.Timer() as tm:
        res = aeroid.identify(m, data, guess, **opts)
    white = aeroid.identify(m, data, guess, error_bars="white", **opts)
    resid = [S.output_residuals(res, OUTPUTS, k) for k in range(len(segs))]
    fitted = [z - r for (_, z, _), r in zip(segs, resid, strict=True)]

    def refit(zs: list[np.ndarray]) -> dict[str, float]:
        r = aeroid.identify(m, flights(segs, zs), dict(res.parameters), error_bars="white", **opts)
        return dict(r.parameters)

    mcs = F.segment_monte_carlo(refit, fitted, resid, mc, seed)
    note = (
        "FVSysID saved no result for case 22: ml_oem2 (ruku4, diagonal R, det(R), "
        f"GN) runs in numpy here ({fv.iterations} iterations); ours: identify on a user Model "
        "of the same equations, three records (check_compatibility with the case's lever "
        "arms and flank-angle beta: rows cc)"
    )
    rows = []
    for i, n in enumerate(BIASES):
        theirs = (fv.p[i], crb[n])
        rows.append(
            F.row(
                CASE,
                n,
                *theirs,
                res.parameters[n],
                res.stderr[n],
                mc_se=mcs.get(n),
                seconds=tm.seconds,
                note=note,
            )
        )
        rows.append(
            F.row(
                CASE,
                f"white:{n}",
                *theirs,
                white.parameters[n],
                white.stderr[n],
                mc_se=mcs.get(n),
                variant=True,
            )
        )
    return rows + compatibility_rows(segs, x0)


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source=SOURCE))
