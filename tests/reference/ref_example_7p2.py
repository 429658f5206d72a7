"""SIDPAC Text Example 7.2: a transfer function fitted to Fourier transforms.

Klein & Morelli Example 7.2, F-16XL wind-tunnel forced-oscillation run
``f16xl_r1263e``: the normal-force coefficient's response to angle of attack,
``CN = (p1 s^2 + p2 s + p3)/(s + p4) alpha`` (a numerator of higher order than
the denominator: unsteady aerodynamics), fitted by ``fdoe('fusatf', ...)``
(output error on the finite Fourier transforms of the detrended signals, 97
frequencies 0.008-0.2 Hz). SIDPAC saved its estimates and Cramer-Rao
covariance in ``example_7p2_results.mat``.

Ours: ``aeroid.fit_transfer_function(..., fourier=True)`` with the library's
defaults otherwise (the band the input excited, on the record's k/T grid).
The time stamps carry ~1e-4 relative jitter; this script rounds them to the
nominal 0.1 s grid before building ``FlightData``. The Monte Carlo
(``_sidpac.transfer_monte_carlo``) refits the fitted transfer function's time
response plus phase-randomised copies of the residual.
"""

from __future__ import annotations

import pathlib
import sys
import time
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_7p2"
FILE = "Text_Examples/example_7p2_results.mat"
NAMES = ("b2", "b1", "b0", "a0")  # SIDPAC's p1..p4


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import scipy.io

    import aeroid

    path = pathlib.Path(folder) / FILE
    if not path.exists():
        return []
    d = scipy.io.loadmat(str(path), squeeze_me=True)
    t = np.asarray(d["t"], dtype=float)
    dt = round(float(np.median(np.diff(t))), 6)
    t = t[0] + dt * np.arange(t.size)  # rounded: the stored stamps jitter by ~2e-5 s
    data = aeroid.FlightData(
        time=t, channels={"alpha": np.radians(d["alf"]), "CN": np.asarray(d["CN"], dtype=float)}
    )
    t0 = time.perf_counter()
    fit = aeroid.fit_transfer_function(
        data,
        input="alpha",
        output="CN",
        numerator_order=2,
        denominator_order=1,
        delay=False,
        fourier=True,
    )
    secs = time.perf_counter() - t0

    def refit(u: np.ndarray, z: np.ndarray) -> dict[str, float]:
        rec = aeroid.FlightData(time=t, channels={"alpha": u, "CN": z})
        return dict(
            aeroid.fit_transfer_function(
                rec, input="alpha", output="CN", numerator_order=2, denominator_order=1,
                delay=False, fourier=True, start=fit.parameters,
            ).parameters
        )  # fmt: skip

    mcs = S.transfer_monte_carlo(refit, fit, t, data["alpha"], data["CN"], mc, seed=seed)
    p = np.asarray(d["p"], dtype=float).ravel()
    w = np.sqrt(np.diag(np.asarray(d["crb"], dtype=float)))
    rows = []
    for i, n in enumerate(NAMES):
        ours, se = fit.parameters[n], fit.standard_errors[n]
        rows.append(
            S.row(
                case=CASE,
                parameter=n,
                sidpac=float(p[i]),
                sidpac_se_white=float(w[i]),
                sidpac_se_corrected=None,
                ours=float(ours),
                ours_se=float(se),
                mc_se=mcs.get(n),
                seconds=secs,
            )
        )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
