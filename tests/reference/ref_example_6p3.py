"""SIDPAC Text Example 6.3: equation error for the short-period Z and M equations.

Klein & Morelli Example 6.3, flight ``totter_9752ed20``: ``az`` (g) on
``alpha*V/g`` and ``elevator*V/g`` plus a bias, and pitch acceleration
``q_dot`` (rad/s^2) on ``alpha``, ``q`` and the elevator plus a bias, both by
``lesq``. SIDPAC saved white (``crboZ``, ``crbom``) and corrected
(``crbZ``, ``crbm``, ``r_colores``) covariances in ``example_6p3_results.mat``.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_6p3"
FILE = "Text_Examples/example_6p3_results.mat"


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    XZ, Xm, z = d["XZ"], d["Xm"], d["z"]
    pZ, wZ, cZ = S.col(d["pZ"]), S.se(d["crboZ"]), S.se(d["crbZ"])
    namesZ = ("alpha", "delta_e", "const")
    rows = S.regression_rows(
        CASE,
        {"alpha": XZ[:, 0], "delta_e": XZ[:, 1]},
        z[:, 0],
        {k: (pZ[i], wZ[i], cZ[i]) for i, k in enumerate(namesZ)},
        label="Z_",
        mc=mc,
        seed=seed,
    )
    pm, wm, cm = S.col(d["pm"]), S.se(d["crbom"]), S.se(d["crbm"])
    namesm = ("alpha", "q", "delta_e", "const")
    rows += S.regression_rows(
        CASE,
        {"alpha": Xm[:, 0], "q": Xm[:, 1], "delta_e": Xm[:, 2]},
        z[:, 1],
        {k: (pm[i], wm[i], cm[i]) for i, k in enumerate(namesm)},
        label="M_",
        mc=mc,
        seed=seed + 1,
    )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
