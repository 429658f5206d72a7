"""SIDPAC demo ``oe_lat_demo``: output error for the lateral linear model.

Flight ``372e`` (F-18 HARV class data, 961 samples at 40 Hz): ``oe`` fits
``tlatssd``, the linear lateral model in dimensional derivatives (Y_beta,
Y_delta_r; L_beta, L_p, L_r, L_delta_r, L_delta_a; N_beta, N_r, N_delta_r,
N_delta_a) with a constant on each state equation and on ``ay``, outputs
beta, p, r, phi, ay (g), from an initial state taken off the smoothed data.
``oe_lat_demo_data.mat`` holds the estimates with ``oe``'s white
(``serro``) and corrected (``serr``, ``m_colores``) standard errors.

Ours: ``aircraft.lateral_linear`` with the same terms (constants ``Y_0``,
``L_0``, ``N_0``), ``estimate_bias={"phi": "state", "ay": "output"}``,
trim from SIDPAC's constants, ``ay`` in g (``accel_units="g"``), SIDPAC's
initial state and SIDPAC's time base: ``tlatssd`` discretises with a
first-order hold at the recorder's first time-tag interval (51/2048 s, not
the rounded 0.025 s of ``t``), so ours runs ``method="exact"``
(piecewise-linear inputs) on ``t = k 51/2048 s``. Our model puts
``V0 Y_0 / g`` into ``ay`` where ``tlatssd`` does not, so the ``ay`` bias is
compared as ``V0 Y_0 / g + b_ay`` without a standard error.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_oe_lat"
FILE = "Demos/oe_lat_demo_data.mat"
G = 32.174
OUTPUTS = ("beta", "p", "r", "phi", "ay")
# SIDPAC's p(1..14) in our names; p(15) is the phi state bias, p(16) the ay bias
NAMES = (
    "Y_beta", "Y_delta_r", "Y_0",
    "L_beta", "L_p", "L_r", "L_delta_r", "L_delta_a", "L_0",
    "N_beta", "N_r", "N_delta_r", "N_delta_a", "N_0",
)  # fmt: skip


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid
    from aeroid.models import aircraft

    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    c = S.col(d["c"])  # vtg, sin(alpha0), cos(alpha0), g cos(theta0)/V0, tan(theta0)
    theta0 = float(np.arctan(c[4]))
    alpha0 = float(np.arctan2(c[1], c[2]))
    V0 = float(c[0] * G)
    model = aircraft.lateral_linear(
        V0=V0,
        alpha0=alpha0,
        theta0=theta0,
        g=G,
        terms={
            "Y": ["beta", "delta_r", "0"],
            "L": ["beta", "p", "r", "delta_r", "delta_a", "0"],
            "N": ["beta", "r", "delta_r", "delta_a", "0"],
        },
        outputs=list(OUTPUTS),
        accel_units="g",
    )
    z, u = np.asarray(d["z"], dtype=float), np.asarray(d["u"], dtype=float)
    tags = np.asarray(d["fdata_372e"], dtype=float)[:, 0]
    t = np.arange(z.shape[0]) * (tags[1] - tags[0])  # SIDPAC's step, 51/2048 s

    def flight(zz: np.ndarray) -> Any:
        ch = {o: zz[:, j] for j, o in enumerate(OUTPUTS)}
        ch["delta_r"], ch["delta_a"] = u[:, 0], u[:, 1]
        return aeroid.FlightData(time=t, channels=ch)

    p0 = S.col(d["p0"])
    start = {n: float(p0[i]) for i, n in enumerate(NAMES)}
    options: dict[str, Any] = {
        "x0": dict(zip(("beta", "p", "r", "phi"), S.col(d["x0"]).tolist(), strict=True)),
        "estimate_bias": {"phi": "state", "ay": "output"},
        "simulate_options": {"method": "exact"},
    }
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(z), start, **options)
    mcs = S.identify_monte_carlo(model, flight, z, res, OUTPUTS, mc, seed=seed, **options)
    p, sc, sw = S.col(d["p"]), S.col(d["serr"]), S.col(d["serro"])
    rows = [
        S.row(
            CASE,
            n,
            sidpac=p[i],
            sidpac_se_white=sw[i],
            sidpac_se_corrected=sc[i],
            ours=res.parameters[n],
            ours_se=res.stderr[n],
            mc_se=mcs.get(n),
            seconds=tm.seconds,
        )
        for i, n in enumerate(NAMES)
    ]
    b = res.biases[0]
    rows.append(
        S.row(
            CASE,
            "bias_phi_state",
            sidpac=p[14],
            sidpac_se_white=sw[14],
            sidpac_se_corrected=sc[14],
            ours=b["state.phi"],
            ours_se=res.extra_stderr.get("bias[0].state.phi"),
            mc_se=mcs.get("bias.state.phi"),
            seconds=tm.seconds,
        )
    )
    ay_bias = V0 * res.parameters["Y_0"] / G + b["ay"]
    rows.append(
        S.row(
            CASE,
            "bias_ay (g)",
            sidpac=p[15],
            sidpac_se_white=sw[15],
            sidpac_se_corrected=sc[15],
            ours=ay_bias,
            ours_se=None,
            mc_se=None,
            seconds=tm.seconds,
            note=(
                "ay bias: ours is V0 Y_0/g + b_ay (lateral_linear puts Y_0 into ay); no se; "
                "time k*51/2048 s (SIDPAC's step), method='exact', ay in g"
            ),
        )
    )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
