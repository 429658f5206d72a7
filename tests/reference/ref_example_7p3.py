"""SIDPAC Text Example 7.3: a short-period LOES of the TU-144 fitted to Fourier transforms.

Klein & Morelli Example 7.3, TU-144 flight ``f20_4d`` (a longitudinal 2-1-1 at
Mach 0.88): pitch rate over longitudinal stick,
``q/η = (b1 s + b0) e^{−τ s} / (s² + a1 s + a0)``, fitted by ``fdoe`` on the
finite Fourier transforms of the record over 0.6–10 rad/s (95 frequencies,
0.1 rad/s apart): an equation-error stage, then output error (``poe``,
``crboe``), saved in ``example_7p3_results.mat``. SIDPAC's stick is the
column in mm over 25.4 and both signals have their first value removed
(``zep``). Compared: ω = √a0, ζ = a1/(2ω), T_θ2 = b1/b0 and τ, SIDPAC's
standard errors by the delta method from ``crboe``.

Ours: ``aeroid.equivalent_system(data, input=, output=)`` with the library's
defaults (the fit on the record's Fourier transforms at the ``k/T`` frequencies
of 0.1–10 rad/s, the global start, delta-method standard errors). The rows
``*_comp`` are the same LOES fitted to ``aeroid.composite_response`` of the
record (CIFER's mismatch cost), the other way a user may go; the rows
``*_grid`` give ``frequencies=`` SIDPAC's 95 frequencies. The Monte Carlo
(``_sidpac.transfer_monte_carlo``) refits the default fit's time response
(from the initial state that fits the record, as the fit estimated the
record's ends) plus phase-randomised copies of its time-domain residual;
the ``*_grid`` and ``*_comp`` rows are set against the same scatter.
"""

from __future__ import annotations

import pathlib
import sys
import time
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_7p3"
FILE = "Text_Examples/example_7p3_results.mat"
DATA = "Text_Examples/tu144_f20_4d_data.mat"
NAMES = ("omega", "zeta", "T_theta2", "tau")


def _derived(p: Any) -> dict[str, float]:
    b1, b0, a1, a0, tau = (float(v) for v in p)
    om = float(np.sqrt(a0))
    return {"omega": om, "zeta": a1 / (2.0 * om), "T_theta2": b1 / b0, "tau": tau}


def _sidpac_se(p: Any, cov: Any) -> dict[str, float]:
    """Delta method on SIDPAC's parameters [b1, b0, a1, a0, tau] and covariance."""
    p = np.asarray(p, dtype=float)
    g = np.zeros((len(NAMES), p.size))
    for j in range(p.size):
        step = 1e-6 * max(abs(p[j]), 1e-3)
        hi, lo = p.copy(), p.copy()
        hi[j] += step
        lo[j] -= step
        up, down = _derived(hi), _derived(lo)
        g[:, j] = [(up[k] - down[k]) / (2 * step) for k in NAMES]
    var = np.einsum("ij,jk,ik->i", g, np.asarray(cov, dtype=float), g)
    return dict(zip(NAMES, np.sqrt(var).tolist(), strict=True))


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import scipy.io

    import aeroid

    res_path = pathlib.Path(folder) / FILE
    data_path = pathlib.Path(folder) / DATA
    if not (res_path.exists() and data_path.exists()):
        return []
    res = scipy.io.loadmat(str(res_path), squeeze_me=True)
    raw = scipy.io.loadmat(str(data_path), squeeze_me=True)
    fdata = np.asarray(raw["fdata"], dtype=float)
    t = np.asarray(raw["t"], dtype=float)
    stick = fdata[:, 30] / 25.4
    q = fdata[:, 5]
    data = aeroid.FlightData(time=t, channels={"stick": stick - stick[0], "q": q - q[0]})
    t0 = time.perf_counter()
    fits = {"": aeroid.equivalent_system(data, input="stick", output="q")}
    secs = time.perf_counter() - t0
    # SIDPAC's own frequencies (0.6:0.1:10 rad/s, finer than 2π/T: the library warns)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        fits["_grid"] = aeroid.equivalent_system(
            data, input="stick", output="q", frequencies=np.asarray(res["w"], dtype=float)
        )
    fits["_comp"] = aeroid.equivalent_system(aeroid.composite_response(data, "stick", "q"))
    default = fits[""]

    def refit(u: np.ndarray, z: np.ndarray) -> dict[str, float]:
        rec = aeroid.FlightData(time=t, channels={"stick": u, "q": z})
        out = aeroid.equivalent_system(rec, input="stick", output="q", start=default.fit.parameters)
        p = dict(out.parameters)
        p["T_theta2"] = 1.0 / p["1/T_theta2"]
        return {n: p[n] for n in NAMES}

    mcs = S.transfer_monte_carlo(refit, default.fit, t, data["stick"], data["q"], mc, seed=seed)
    poe = np.asarray(res["poe"], dtype=float)
    ref = _derived(poe)
    ref_se = _sidpac_se(poe, res["crboe"])
    rows = []
    for suffix, fit in fits.items():
        p = dict(fit.parameters)
        inv = p["1/T_theta2"]
        p["T_theta2"] = 1.0 / inv if inv != 0 else float("inf")
        for n in NAMES:
            ours, se = p[n], fit.standard_errors[n]
            rows.append(
                S.row(
                    case=CASE,
                    parameter=n + suffix,
                    sidpac=ref[n],
                    sidpac_se_white=ref_se[n],
                    sidpac_se_corrected=None,
                    ours=float(ours),
                    ours_se=float(se),
                    mc_se=mcs.get(n),
                    seconds=secs,
                    variant=bool(suffix),
                )
            )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
