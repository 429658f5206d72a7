"""SIDPAC demo ``totter_demo``: Twin Otter short-period modelling, equation error.

The demo computes CZ and Cm from the measured accelerations (``compfc``,
``compmc``), removes the smoothed initial values from alpha, q_hat and the
elevator, fits CZ on alpha, elevator and a bias (``lesq`` with ``r_colores``
bounds) and selects the Cm model from alpha, q_hat, elevator and
alpha*elevator by stepwise regression (``swr``, then ``r_colores``).
``Demos/totter_results.mat`` holds the estimates with corrected standard
errors only (``serrZ``, ``serrm``), and the output-error refinement ``p``,
``serr`` (nonlinear ``nldyn`` through ``oe`` and ``m_colores``).

Ours: ``aeroid.equation_error`` for CZ and ``aeroid.stepwise_regression``
for Cm on the same coefficients (computed here in numpy as compfc/compmc
do); the smoothed initial values are removed as xsmep does (reproduced in
numpy here), which moves only the biases. The output-error
step is SIDPAC's ``nldyn`` with its ``totter_results`` settings: states
alpha and q integrated, V, beta, p, r, phi, theta, q_hat, dynamic pressure,
thrust and the measured CX fed in from the data; CZ and Cm modelled; outputs
alpha, q and az with an az bias. Ours writes those equations as a user
``aeroid.Model`` (the fed-in signals as controls) fitted by
``aeroid.identify``; rows ``oe:...``. ``aircraft.longitudinal`` cannot
express it: it integrates V and theta (here fed from the data) and has no
fed-in measured CX; ``rate_reference="V0"`` would only change q_hat, which
``nldyn`` takes from the data too.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_totter"
FILES = ("Demos/totter_demo_data.mat", "Demos/totter_results.mat")
DTR = np.pi / 180
G = 32.174


def coefficients(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CZ and Cm as compfc.m and compmc.m form them (angular accelerations measured)."""
    qs = f[0, 76] * f[:, 26]
    cz = G * f[:, 47] * f[:, 12] / qs
    p, r = f[:, 4] * DTR, f[:, 6] * DTR
    qd = f[:, 42] * DTR
    ixx, iyy, izz, ixz = f[:, 48], f[:, 49], f[:, 50], f[:, 51]
    cm = (iyy * qd + ixz * (p**2 - r**2) + (ixx - izz) * p * r) / (f[0, 78] * qs)
    return cz, cm


def smoothed_start(z: np.ndarray, cutoff: float, dt: float) -> np.ndarray:
    """The smoothed value of each column at the first sample, as xsmep.m finds it.

    Samples 2-4 are low-pass filtered with a one-sided window (an ideal filter
    at `cutoff` Hz with a sine taper of width pi/(half the record) in
    frequency, normalised to unit gain); a straight line through those three
    filtered values, extrapolated back to the first sample's time, is the
    start value.
    """
    n = z.shape[0]
    half = round(n / 2.0 - 0.1)
    w = 2.0 * np.pi * cutoff
    wt = 2.0 * np.pi * (cutoff + np.pi / (half * dt))
    k = np.arange(1, half + 1)
    h = (np.pi / (2.0 * k * dt)) * (
        (np.sin(wt * k * dt) + np.sin(w * k * dt)) / (np.pi**2 - ((wt - w) * k * dt) ** 2)
    )
    h0 = cutoff + (cutoff + np.pi / (half * dt))
    norm = h0 + 2.0 * h.sum()
    h0, h = h0 / norm, h / norm
    rows = []
    for i in (1, 2, 3):  # samples 2-4 (0-based 1-3)
        rows.append(h0 * z[i] + 2.0 * (h[:, None] * z[i + 1 : i + 1 + half]).sum(axis=0))
    x = np.column_stack([np.ones(3), dt * np.arange(1, 4)])
    coef = np.linalg.lstsq(x, np.asarray(rows), rcond=None)[0]
    return np.asarray(coef[0], dtype=float)


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    data_path, res_path = S.need(folder, *FILES)
    d, r = S.loadmat(data_path), S.loadmat(res_path)
    f = np.asarray(d["fdata"], dtype=float)
    t = S.col(d["t"])
    cz, cm = coefficients(f)
    X = np.column_stack([f[:, 3] * DTR, f[:, 71], f[:, 13] * DTR])
    X = X - smoothed_start(X, 1.0, float(t[1] - t[0]))
    reg = {"alpha": X[:, 0], "q_hat": X[:, 1], "delta_e": X[:, 2]}
    pZ, sZ = S.col(r["pZ"]), S.col(r["serrZ"])
    one = np.ones(len(t))
    # SIDPAC saved corrected errors only: its lesq white ones computed here in numpy
    wZ = S.se(S.r_colores(np.column_stack([reg["alpha"], reg["delta_e"], one]), cz)[1])
    wm = S.se(
        S.r_colores(np.column_stack([reg["alpha"], reg["q_hat"], reg["delta_e"], one]), cm)[1]
    )
    rows = S.regression_rows(
        CASE,
        {"alpha": reg["alpha"], "delta_e": reg["delta_e"]},
        cz,
        {k: (pZ[i], wZ[i], sZ[i]) for i, k in enumerate(("alpha", "delta_e", "const"))},
        label="CZ_",
        mc=mc,
        seed=seed,
    )
    cands = dict(reg, alpha_delta_e=X[:, 0] * X[:, 2])
    pool = list(cands)
    data = dict(cands, Cm=cm)
    with S.Timer() as tm:
        sw = aeroid.stepwise_regression(data, "Cm", pool)
    fit = sw.regression
    fitted = np.asarray(fit.fitted, dtype=float)

    def refit(zz: np.ndarray) -> dict[str, float]:
        res = aeroid.stepwise_regression(
            dict(cands, Cm=zz), "Cm", pool, error_bars="white"
        ).regression
        return {k: float(res.parameters.get(k, 0.0)) for k in (*cands, "const")}

    mcs = S.monte_carlo(refit, fitted, cm - fitted, mc, seed=seed + 1)
    pm, sm = S.col(r["pm"]), S.col(r["serrm"])
    sid_m = dict(
        zip(("alpha", "q_hat", "delta_e", "const"), zip(pm, wm, sm, strict=True), strict=True)
    )
    note = (
        f"Cm terms: SIDPAC alpha, q_hat, delta_e, const; ours {', '.join(sw.selected)}, const; "
        "SIDPAC saved corrected (r_colores) errors only, white ones computed in numpy; "
        "xsmep's smoothed initial values reproduced in numpy"
    )
    for k in (*cands, "const"):
        sp, sw_, ss = sid_m.get(k, (0.0, None, None))
        rows.append(
            S.row(
                CASE,
                f"Cm_{k}",
                sidpac=sp,
                sidpac_se_white=sw_,
                sidpac_se_corrected=ss,
                ours=fit.parameters.get(k, 0.0),
                ours_se=fit.stderr.get(k),
                mc_se=mcs.get(k),
                seconds=tm.seconds,
                note=note,
            )
        )
    rows += oe_rows(d, r, mc=mc, seed=seed + 2)
    return rows


OE_NAMES = ("CZ_alpha", "CZ_delta_e", "CZ_0", "Cm_alpha", "Cm_q_hat", "Cm_delta_e", "Cm_0", "b_az")
FED = ("V", "beta", "p", "r", "phi", "theta", "q_hat", "qbar", "thrust", "CX")


def oe_rows(d: dict[str, Any], r: dict[str, Any], *, mc: int, seed: int) -> list[dict[str, Any]]:
    """nldyn's alpha/q equations (measured states fed in) as a user model, fitted by identify."""
    import aeroid

    f = np.asarray(d["fdata"], dtype=float)
    t = S.col(d["t"])
    coe = r["coe"]
    x0c, u0c = S.col(S.field(coe, "x0")), S.col(S.field(coe, "u0"))
    alpha0, de0 = float(x0c[2]), float(u0c[0])
    mass, ixx, iyy, izz, ixz = (float(np.mean(f[:, j])) for j in (47, 48, 49, 50, 51))
    sarea, cbar = float(f[0, 76]), float(f[0, 78])
    c5, c6, c7 = (izz - ixx) / iyy, ixz / iyy, 1.0 / iyy

    def dynamics(tt: Any, x: Any, u: Any, p: Any) -> Any:
        alpha, q = x
        de, vt, beta, pr, rr, phi, the, qhat, qbar, thrust, cx = u
        qs = qbar * sarea
        cz = p["CZ_alpha"] * (alpha - alpha0) + p["CZ_delta_e"] * (de - de0) + p["CZ_0"]
        cm = (
            p["Cm_alpha"] * (alpha - alpha0) + p["Cm_q_hat"] * qhat
            + p["Cm_delta_e"] * (de - de0) + p["Cm_0"]
        )  # fmt: skip
        cb = np.cos(beta)
        ub, vb, wb = vt * np.cos(alpha) * cb, vt * np.sin(beta), vt * np.sin(alpha) * cb
        udot = rr * vb - q * wb - G * np.sin(the) + (qs * cx + thrust) / mass
        wdot = q * ub - pr * vb + G * np.cos(the) * np.cos(phi) + qs * cz / mass
        adot = (wdot * ub - wb * udot) / (ub * ub + wb * wb)
        qdot = c5 * pr * rr + c6 * (rr * rr - pr * pr) + qs * cbar * c7 * cm
        return np.array([adot, qdot])

    def measurement(tt: Any, x: Any, u: Any, p: Any) -> Any:
        alpha, q = x
        cz = p["CZ_alpha"] * (alpha - alpha0) + p["CZ_delta_e"] * (u[0] - de0) + p["CZ_0"]
        return np.array([alpha, q, u[8] * sarea * cz / (mass * G) + p["b_az"]])

    pr0 = S.col(r["p0"])
    start = dict(zip(OE_NAMES, pr0.tolist(), strict=True))
    model = aeroid.Model(
        states=["alpha", "q"],
        controls=["delta_e", *FED],
        parameters=start,
        dynamics=dynamics,
        outputs=["alpha", "q", "az"],
        measurement=measurement,
        name="nldyn_short_period",
    )
    fed = {
        "delta_e": f[:, 13] * DTR,
        "V": f[:, 1],
        "beta": f[:, 2] * DTR,
        "p": f[:, 4] * DTR,
        "r": f[:, 6] * DTR,
        "phi": f[:, 7] * DTR,
        "theta": f[:, 8] * DTR,
        "q_hat": f[:, 71],
        "qbar": f[:, 26],
        "thrust": f[:, 37:41].sum(axis=1),
        "CX": f[:, 60],
    }
    z = np.column_stack([f[:, 3] * DTR, f[:, 5] * DTR, f[:, 12]])
    outs = ("alpha", "q", "az")

    def flight(zz: np.ndarray) -> Any:
        return aeroid.FlightData(
            time=t, channels=dict(fed, **{o: zz[:, j] for j, o in enumerate(outs)})
        )

    opts = {"x0": {"alpha": alpha0, "q": float(x0c[4])}}
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(z), start, **opts)
    mcs = S.identify_monte_carlo(model, flight, z, res, outs, mc, seed=seed, **opts)
    p, serr = S.col(r["p"]), S.col(r["serr"])
    return [
        S.row(
            CASE,
            f"oe:{n}",
            sidpac=p[i],
            sidpac_se_white=None,
            sidpac_se_corrected=serr[i],
            ours=res.parameters[n],
            ours_se=res.stderr[n],
            mc_se=mcs.get(n),
            seconds=tm.seconds,
            note="oe: SIDPAC's nldyn (Adams-Bashforth) as a user Model (RK4); SIDPAC saved m_colores errors only",
        )
        for i, n in enumerate(OE_NAMES)
    ]


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
