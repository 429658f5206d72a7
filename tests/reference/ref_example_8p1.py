"""SIDPAC Text Example 8.1: recursive least squares of the Cn model.

Klein & Morelli Example 8.1 runs the Cn regression of Example 5.1 (flight
``totter_f1_017``: beta, p_hat, r_hat, aileron, rudder and a bias) through
``rlesq``, recursive least squares with no forgetting, starting from zero with
``1e6`` times the identity as covariance. SIDPAC saved the history of the
estimates (``ph``), of the gains (``kh``), the final estimate ``p`` and its
covariance ``crb`` (the classical one, the last covariance matrix scaled by its
fit-error variance ``s2``), in ``example_8p1_results.mat``.

``rlesq``'s loop starts at the record's second sample (the first sets nothing
but its residual), so this script gives `aeroid.recursive_least_squares` the
record from the second sample on, with the same start.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_8p1"
FILE = "Text_Examples/example_8p1_results.mat"
_X = ("beta", "p_hat", "r_hat", "delta_a", "delta_r", "const")


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    X, z = np.asarray(d["X"], dtype=float)[1:], S.col(d["Cn"])[1:]
    with S.Timer() as t:
        res = aeroid.recursive_least_squares(X, z, list(_X), intercept=False)
    white = aeroid.recursive_least_squares(X, z, list(_X), intercept=False, error_bars="white")
    ph, kh = np.asarray(d["ph"], dtype=float)[1:], np.asarray(d["kh"], dtype=float)[1:]
    hist = float(np.max(np.abs(res.history - ph)) / np.max(np.abs(ph)))
    gain = float(np.max(np.abs(res.gain_history - kh)) / np.max(np.abs(kh)))
    batch = float(S.col(d["s2n"])[0])
    fitted = X @ np.array([res.parameters[k] for k in _X])

    def refit(zz: np.ndarray) -> dict[str, float]:
        fit = aeroid.recursive_least_squares(X, zz, list(_X), intercept=False, error_bars="white")
        return dict(fit.parameters)

    mcs = S.monte_carlo(refit, fitted, z - fitted, mc, seed=seed)
    p, sw = S.col(d["p"]), S.se(d["crb"])
    note = (
        f"our recursion reproduces SIDPAC's estimate history to {hist:.1e} and its gain "
        f"history to {gain:.1e} (relative to their largest values); the final fit-error "
        f"variance is {float(S.col(d['s2'])[0]) / batch:.3f} of the batch one in SIDPAC "
        f"(a posteriori residuals summed), {white.fit_error_history[-1] ** 2 / batch:.4f} "
        f"in ours (the weighted cost, exact), so our white bars are "
        f"{white.stderr['beta'] / sw[0]:.3f} of SIDPAC's; ours (default) are coloured"
    )
    sidpac = {name: (p[i], sw[i], None) for i, name in enumerate(_X)}
    return S.fit_rows(CASE, sidpac, res, mcs, t.seconds, label="Cn_", note=note)


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
