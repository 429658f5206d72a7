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
do); the initial values are removed with a local quadratic fit over the
first second (xsmep's role), which moves only the biases. The output-error
step (SIDPAC's nonlinear ``nldyn`` with measured states fed in) is not
reproduced: its rows are listed with SIDPAC's values only.
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


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    data_path, res_path = S.need(folder, *FILES)
    d, r = S.loadmat(data_path), S.loadmat(res_path)
    f = np.asarray(d["fdata"], dtype=float)
    t = S.col(d["t"])
    cz, cm = coefficients(f)
    X = np.column_stack([f[:, 3] * DTR, f[:, 71], f[:, 13] * DTR])
    m = round(1.0 / (t[1] - t[0])) + 1
    tt = t[:m] - t[0]
    X = X - np.array([np.polyval(np.polyfit(tt, X[:m, j], 2), 0.0) for j in range(3)])
    reg = {"alpha": X[:, 0], "q_hat": X[:, 1], "delta_e": X[:, 2]}
    pZ, sZ = S.col(r["pZ"]), S.col(r["serrZ"])
    rows = S.regression_rows(
        CASE,
        {"alpha": reg["alpha"], "delta_e": reg["delta_e"]},
        cz,
        {k: (pZ[i], None, sZ[i]) for i, k in enumerate(("alpha", "delta_e", "const"))},
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
    sid_m = dict(zip(("alpha", "q_hat", "delta_e", "const"), zip(pm, sm, strict=True), strict=True))
    note = (
        f"Cm terms: SIDPAC alpha, q_hat, delta_e, const; ours {', '.join(sw.selected)}, const; "
        "SIDPAC saved corrected (r_colores) errors only; the biases differ because xsmep's smoothed "
        "initial values are approximated here by a local quadratic fit"
    )
    for k in (*cands, "const"):
        sp, ss = sid_m.get(k, (0.0, None))
        rows.append(
            S.row(
                CASE,
                f"Cm_{k}",
                sidpac=sp,
                sidpac_se_white=None,
                sidpac_se_corrected=ss,
                ours=fit.parameters.get(k, 0.0),
                ours_se=fit.stderr.get(k),
                mc_se=mcs.get(k),
                seconds=tm.seconds,
                note=note,
            )
        )
    p, serr = S.col(r["p"]), S.col(r["serr"])
    oe_names = (
        "CZ_alpha",
        "CZ_delta_e",
        "CZ_0",
        "Cm_alpha",
        "Cm_q",
        "Cm_delta_e",
        "Cm_0",
        "az_bias",
    )
    for i, n in enumerate(oe_names):
        rows.append(
            S.row(
                CASE,
                f"oe:{n}",
                sidpac=p[i],
                sidpac_se_white=None,
                sidpac_se_corrected=serr[i],
                ours=None,
                ours_se=None,
                note="oe: rows are SIDPAC's nonlinear output error (nldyn), not reproduced here",
            )
        )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
