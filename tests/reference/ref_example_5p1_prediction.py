"""SIDPAC Text Example 5.1, prediction: the Cn model on another manoeuvre.

After Example 5.1's equation error for Cn on flight ``totter_f1_017``
(``ref_example_5p1``), SIDPAC's driver predicts Cn of flight
``totter_f1_014`` (other control inputs) with the same regressors, beta,
p_hat, r_hat, aileron, rudder (rad) and a bias: ``ynp = Xp*pn``, with nothing
refitted. The figure's 95 % band is ``2*mean(syn)``, ``syn`` the standard
error of a predicted output on the modelling data from ``confin``,
``sqrt(s² (1 + x_i (X'X)^-1 x_i'))``. SIDPAC saved ``Xp``, ``Cnp``, ``ynp`` and
``syn`` in ``example_5p1_prediction_results.mat``.

Ours: ``aeroid.equation_error`` on the modelling record, its estimates times
the prediction record's regressors (formed from ``totter_f1_014_data.mat`` as
the driver forms them, which the case checks against SIDPAC's ``Xp``), and
the band's standard error from the result's ``fit_error`` and
``covariance_white``. Rows: the prediction against SIDPAC's; ``band`` the
mean of ``syn`` and the share of prediction residuals inside ``±2 mean(syn)``;
``PRESS`` the predicted residual sum of squares on the modelling data, ours
(``RegressionResult.press``) against SIDPAC's ``press.m`` (refits without each
sample) written in numpy.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _prediction as P
import _sidpac as S

CASE = "example_5p1_prediction"
FILES = ("Text_Examples/example_5p1_prediction_results.mat", "Text_Examples/totter_f1_014_data.mat")
_X = ("beta", "p_hat", "r_hat", "delta_a", "delta_r")
DTR = np.pi / 180.0


def press(x: np.ndarray, z: np.ndarray) -> float:
    """SIDPAC's press.m: each sample predicted by the least squares without it."""
    xtx, xtz = x.T @ x, x.T @ z
    total = 0.0
    for i in range(z.size):
        p = np.linalg.solve(xtx - np.outer(x[i], x[i]), xtz - x[i] * z[i])
        total += float(z[i] - x[i] @ p) ** 2
    return total


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    res_path, data_path = S.need(folder, *FILES)
    d, raw = S.loadmat(res_path), S.loadmat(data_path)
    x = np.asarray(d["X"], dtype=float)  # modelling regressors, ones last
    cn = S.col(d["Cn"])
    modelling = {n: x[:, j] for j, n in enumerate(_X)} | {"Cn": cn}
    with S.Timer() as tm:
        fit = aeroid.equation_error(modelling, "Cn", list(_X))
    f = np.asarray(raw["fdata"], dtype=float)
    xp = np.column_stack([f[:, 2] * DTR, f[:, 70], f[:, 72], f[:, 14:16] * DTR])
    formed = np.max(np.abs(xp - np.asarray(d["Xp"], dtype=float)[:, :5]))
    print(f"  prediction regressors formed as SIDPAC's Xp to {formed:.1e}")
    cnp, ynp = f[:, 65], S.col(d["ynp"])
    theta = np.array([fit.parameters[n] for n in _X])
    ours = fit.parameters["const"] + xp @ theta
    rows = P.prediction_rows(
        CASE,
        ["Cn"],
        cnp,
        ynp,
        ours,
        note="d/rng: max |ours - SIDPAC's| prediction over the measured range; rms, R2: "
        "each prediction against the measured Cn; band: 2 mean(syn) of confin",
    )
    # confin's predicted-output standard error on the modelling data, from our record
    names = list(fit.parameter_names)
    xm = np.column_stack([modelling[n] if n != "const" else np.ones(cn.size) for n in names])
    syn = np.sqrt(fit.fit_error**2 + np.einsum("ij,jk,ik->i", xm, fit.covariance_white, xm))
    syn_sid = S.col(d["syn"])
    inside = [
        float(np.mean(np.abs(cnp - y) <= 2 * np.mean(s))) for y, s in ((ynp, syn_sid), (ours, syn))
    ]
    blank = {"sidpac_se_white": None, "sidpac_se_corrected": None, "ours_se": None}
    rows.append(S.row(CASE, "band mean(syn)", sidpac=np.mean(syn_sid), ours=np.mean(syn), **blank))
    rows.append(S.row(CASE, "band inside", sidpac=inside[0], ours=inside[1], **blank))
    xs = np.column_stack([np.ones(cn.size), x[:, :5]])
    sid_press = press(xs, cn)
    print(
        f"  PRESS: ours {fit.press:.12e}, press.m {sid_press:.12e} (relative {fit.press / sid_press - 1:.1e})"
    )
    rows.append(S.row(CASE, "PRESS", sidpac=sid_press, ours=fit.press, **blank))
    for r in rows:
        r["seconds"] = tm.seconds
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
