"""SIDPAC demo ``dca_lon_demo``: longitudinal data compatibility of HARV flight 250h.

``dcmp`` reconstructs the flight path from the accelerometers and rate gyros
(ft/s^2, rad/s) and fits V, alpha and theta by output error, estimating
ax, az and q biases and alpha and theta scale factors, from an initial
state off the smoothed data with v, phi and psi replaced by their
measurements. ``dca_lon_demo_data.mat`` holds the estimates ``pc`` and
``oe``'s covariance ``crbc`` (white).

Ours: ``aeroid.check_compatibility`` with the same five parameters, in
ft/s^2 (``gravity=32.174``), with its defaults otherwise. Differences the
library cannot remove yet: SIDPAC's biases are corrections added to the
measurement (ours, subtracted, are shown negated); its scale factors act on
the change from the initial value (ours on the value); it fixes the initial
state and feeds some states from the measurements, where ours estimates the
initial state and fits phi too (``V, alpha, phi, theta`` are required).
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_dca_lon"
FILE = "Demos/dca_lon_demo_data.mat"
NOTE = (
    "check_compatibility lacks SIDPAC's options: fixed initial state, measured states fed in, "
    "scale factors about the initial value, fitting only SIDPAC's outputs; SIDPAC bias sign flipped"
)


def compat_rows(
    case: str,
    u: np.ndarray,
    z: np.ndarray,
    t: np.ndarray,
    names: Sequence[str],
    pc: np.ndarray,
    crbc: np.ndarray,
    *,
    absent: Sequence[str],
    mc: int,
    seed: int,
) -> list[dict[str, Any]]:
    """``u`` = ax, ay, az, p, q, r; ``z`` = V, beta, alpha, phi, theta, psi (ft, rad)."""
    import aeroid

    inputs = ("ax", "ay", "az", "p", "q", "r")
    outs = ("V", "beta", "alpha", "phi", "theta", "psi")

    def flight(zz: np.ndarray) -> Any:
        ch = {n: u[:, j] for j, n in enumerate(inputs)}
        ch.update({n: zz[:, j] for j, n in enumerate(outs)})
        return aeroid.FlightData(time=t, channels=ch)

    opts: dict[str, Any] = {
        "channels": dict.fromkeys(absent),
        "estimate": list(names),
        "gravity": 32.174,
    }
    with S.Timer() as tm:
        res = aeroid.check_compatibility(flight(z), **opts)
    fitted = [outs.index(o) for o in res.output_names]
    resid = np.asarray(res.measured) - np.asarray(res.reconstructed)
    model_out = z.copy()
    model_out[:, fitted] = np.asarray(res.reconstructed)

    def refit(zz: np.ndarray) -> dict[str, float]:
        full = z.copy()
        full[:, fitted] = zz
        r = aeroid.check_compatibility(flight(full), error_bars="white", **opts)
        return dict(r.parameters)

    mcs = S.monte_carlo(refit, model_out[:, fitted], resid, mc, seed=seed)
    sw = S.se(crbc)
    rows = []
    for i, n in enumerate(names):
        sign = -1.0 if n.startswith("b_") else 1.0
        rows.append(
            S.row(
                case,
                n,
                sidpac=sign * pc[i],
                sidpac_se_white=sw[i],
                sidpac_se_corrected=None,
                ours=res.parameters[n],
                ours_se=res.stderr[n],
                mc_se=mcs.get(n),
                seconds=tm.seconds,
                note=NOTE + f"; ours fits {', '.join(res.output_names)}",
            )
        )
    return rows


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    uc, zc = np.asarray(d["uc"], dtype=float), np.asarray(d["zc"], dtype=float)
    return compat_rows(
        CASE,
        uc[:, :6],
        zc,
        S.col(d["t"]),
        ("b_ax", "b_az", "b_q", "k_alpha", "k_theta"),
        S.col(d["pc"]),
        np.asarray(d["crbc"], dtype=float),
        absent=("beta", "psi"),
        mc=mc,
        seed=seed,
    )


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
