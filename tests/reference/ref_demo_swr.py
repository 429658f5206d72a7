"""SIDPAC demo ``swr_demo``: stepwise regression on simulated data.

SIDPAC's demo draws 500 samples of four regressors, forms
``z = -x1 + 2 x2 + 3 x4 - 0.5`` (x3 absent) plus 5 % white noise (``buzz``)
and selects terms with ``swr``. ``swr_demo_data.mat`` holds the data, the
selected terms, the estimates and ``swr``'s covariance (classical, white
residuals; the noise is white here, so there is no corrected one), and the
truth.

Ours: ``aeroid.stepwise_regression`` with its defaults (F-to-enter and
F-to-remove 4). A candidate not selected counts as 0 in the Monte Carlo,
which reselects terms on every refit.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_swr"
FILE = "Demos/swr_demo_data.mat"
NAMES = ("x1", "x2", "x3", "x4", "const")


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    x, z = np.asarray(d["x"], dtype=float), S.col(d["z"])
    with S.Timer() as tm:
        res = aeroid.stepwise_regression(x, z)
    reg = res.regression

    def estimates(r: Any) -> dict[str, float]:
        return {n: float(r.parameters.get(n, 0.0)) for n in NAMES}

    def refit(zz: np.ndarray) -> dict[str, float]:
        return estimates(aeroid.stepwise_regression(x, zz, error_bars="white").regression)

    fitted = np.asarray(reg.fitted, dtype=float)
    mcs = S.monte_carlo(refit, fitted, z - fitted, mc, seed=seed)
    p = S.col(d["p"])
    sel = [int(i) - 1 for i in S.col(d["pindx"])]  # SIDPAC's selected columns, const = 4
    w = dict.fromkeys(range(5), None) | {j: s for j, s in zip(sel, S.se(d["cvar"]), strict=True)}
    truth = S.col(d["p_true"])
    ours = estimates(reg)
    rows = []
    for j, n in enumerate(NAMES):
        chosen = n in reg.parameters
        rows.append(
            S.row(
                CASE,
                n,
                sidpac=p[j],
                sidpac_se_white=w[j],
                sidpac_se_corrected=None,
                ours=ours[n],
                ours_se=reg.stderr[n] if chosen else None,
                mc_se=mcs.get(n),
                seconds=tm.seconds,
                note=(
                    f"truth {', '.join(f'{a}={b:g}' for a, b in zip(NAMES, truth, strict=True))}; "
                    f"SIDPAC selected {', '.join(NAMES[j] for j in sel)}; "
                    f"ours {', '.join(res.selected)}; SIDPAC's bars are swr's white ones (white noise here)"
                ),
            )
        )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
