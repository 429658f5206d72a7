"""SIDPAC Text Example 5.2: coloured-residual error bars of the Cn regression.

Klein & Morelli Example 5.2 takes the Cn model of Example 5.1 (flight
``totter_f1_017``, regressors beta, p_hat, r_hat, aileron, rudder, bias) and
corrects its covariance for coloured residuals with ``r_colores``. SIDPAC
saved both, in ``example_5p2_results.mat``: ``crbon`` (white) and ``crbn``
(corrected).
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_5p2"
FILE = "Text_Examples/example_5p2_results.mat"
_X = ("beta", "p_hat", "r_hat", "delta_a", "delta_r", "const")


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    X = d["X"]
    reg = {n: X[:, j] for j, n in enumerate(_X[:5])}
    p, w, c = S.col(d["p"]), S.se(d["crbon"]), S.se(d["crbn"])
    mine_c, mine_w = S.r_colores(X, d["Cn"])
    gap = max(
        float(np.max(np.abs(S.se(mine_c) / c - 1))), float(np.max(np.abs(S.se(mine_w) / w - 1)))
    )
    return S.regression_rows(
        CASE,
        reg,
        d["Cn"],
        {k: (p[i], w[i], c[i]) for i, k in enumerate(_X)},
        label="Cn_",
        mc=mc,
        seed=seed,
        note=f"the numpy r_colores of this suite reproduces SIDPAC's saved errors to {gap:.1e} (relative)",
    )


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
