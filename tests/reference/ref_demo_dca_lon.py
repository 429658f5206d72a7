"""SIDPAC demo ``dca_lon_demo``: longitudinal data compatibility of HARV flight 250h.

``dcmp`` reconstructs the flight path from the accelerometers and rate gyros
(ft/s^2, rad/s) and fits V, alpha and theta by output error, estimating
ax, az and q biases and alpha and theta scale factors, from a held initial
state (saved as ``x0``) with v, phi and psi replaced by their measurements
and the scale factors acting on the change from the initial value. Its saved
outputs are reproduced by forward Euler with the inputs held over each step,
on a constant step equal to the first time-tag interval.
``dca_lon_demo_data.mat`` holds the estimates ``pc`` and ``oe``'s covariance
``crbc`` (white).

Ours: ``aeroid.check_compatibility`` set up the same way (``outputs``,
``measured_states``, ``estimate_x0=False`` with SIDPAC's ``x0``,
``scale_about="initial"``, ``integration="euler"``, ``gravity=32.174``, the
uniform time base). SIDPAC's biases are corrections added to the
measurement; ours, subtracted, are compared negated. ``ours se`` is our
default (coloured, with the input noise's share); the note gives the ratio
of our white bars to SIDPAC's white ones. The Monte Carlo perturbs the fitted
outputs only, not the inertial inputs.
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
    "SIDPAC's set-up (held x0, measured states, scale about the initial value, Euler, "
    "uniform time); SIDPAC bias sign flipped"
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
    outputs: Sequence[str],
    measured: Sequence[str],
    x0: np.ndarray,
    mc: int,
    seed: int,
) -> list[dict[str, Any]]:
    """``u`` = ax, ay, az, p, q, r; ``z`` = V, beta, alpha, phi, theta, psi (ft, rad);
    ``x0`` = SIDPAC's held u, v, w, phi, theta, psi."""
    import aeroid

    inputs = ("ax", "ay", "az", "p", "q", "r")
    outs = ("V", "beta", "alpha", "phi", "theta", "psi")

    def flight(zz: np.ndarray) -> Any:
        ch = {n: u[:, j] for j, n in enumerate(inputs)}
        ch.update({n: zz[:, j] for j, n in enumerate(outs)})
        return aeroid.FlightData(time=t, channels=ch)

    t = np.arange(t.size) * (t[1] - t[0])  # SIDPAC's time base: the first interval
    opts: dict[str, Any] = {
        "estimate": list(names),
        "gravity": 32.174,
        "outputs": list(outputs),
        "measured_states": list(measured),
        "estimate_x0": False,
        "x0": dict(zip(("u", "v", "w", "phi", "theta", "psi"), map(float, x0), strict=True)),
        "scale_about": "initial",
        "integration": "euler",
    }
    with S.Timer() as tm:
        res = aeroid.check_compatibility(flight(z), **opts)
    white = aeroid.check_compatibility(
        flight(z), error_bars="white", input_noise=dict.fromkeys(inputs, 0.0), **opts
    )
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
    ratios = [white.stderr[n] / sw[i] for i, n in enumerate(names)]
    white_note = f"white bars / SIDPAC's {min(ratios):.2f}-{max(ratios):.2f}"
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
                note=NOTE + f"; ours fits {', '.join(res.output_names)}; {white_note}",
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
        outputs=("V", "alpha", "theta"),
        measured=("v", "phi", "psi"),
        x0=S.col(d["x0"]),
        mc=mc,
        seed=seed,
    )


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
