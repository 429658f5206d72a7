"""SIDPAC Text Example 5.1: equation error for the lateral coefficients.

Klein & Morelli Example 5.1, flight ``totter_f1_017``: ordinary least squares
of CY, Cl and Cn on beta, p_hat, r_hat, aileron and rudder plus a bias
(``lesq``). SIDPAC saved, in ``example_5p1_results.mat``, white (``lesq``) and
coloured-residual corrected (``r_colores``) covariances for CY and Cl, and
only the white one for Cn (its corrected one is Example 5.2; here SIDPAC's
``r_colores`` is run in numpy for it, which ``ref_example_5p2`` checks
against the saved one).
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_5p1"
FILE = "Text_Examples/example_5p1_results.mat"
_X = ("beta", "p_hat", "r_hat", "delta_a", "delta_r", "const")


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    X = d["X"]  # beta, phat, rhat, ail, rdr (rad), ones
    reg = {n: X[:, j] for j, n in enumerate(_X[:5])}
    rows: list[dict[str, Any]] = []
    # CY on beta, r_hat, rudder (SIDPAC X(:,[1,3,5,6]))
    pY, wY, cY = S.col(d["pY"]), S.se(d["crboY"]), S.se(d["crbY"])
    namesY = ("beta", "r_hat", "delta_r", "const")
    rows += S.regression_rows(
        CASE,
        {k: reg[k] for k in namesY[:3]},
        d["CY"],
        {k: (pY[i], wY[i], cY[i]) for i, k in enumerate(namesY)},
        label="CY_",
        mc=mc,
        seed=seed,
    )
    p1, w1, c1 = S.col(d["p1"]), S.se(d["crbo1"]), S.se(d["crb1"])
    rows += S.regression_rows(
        CASE,
        reg,
        d["C1"],
        {k: (p1[i], w1[i], c1[i]) for i, k in enumerate(_X)},
        label="Cl_",
        mc=mc,
        seed=seed + 1,
    )
    pn, wn = S.col(d["pn"]), S.se(d["crbn"])
    cn_corr = S.se(S.r_colores(X, d["Cn"])[0])  # SIDPAC's r_colores in numpy (saved in 5.2)
    rows += S.regression_rows(
        CASE,
        reg,
        d["Cn"],
        {k: (pn[i], wn[i], cn_corr[i]) for i, k in enumerate(_X)},
        label="Cn_",
        mc=mc,
        seed=seed + 2,
        note="Cn: SIDPAC saved only the white (lesq) error here; its r_colores run in numpy gives the corrected",
    )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
