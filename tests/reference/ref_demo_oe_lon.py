"""SIDPAC demo ``oe_lon_demo``: output error for the short-period model with ``az``.

The demo fits ``tlonssd``: states alpha, q; inputs elevator and a constant;
``alpha' = Z_alpha alpha + Z_q q + Z_delta_e de + b_alpha``,
``q' = M_alpha alpha + M_q q + M_delta_e de + b_q``, outputs alpha, q and
``az = (V/g) (Z_alpha alpha + (Z_q - 1) q + Z_delta_e de) + b_az`` (g), from
an initial state off the smoothed data and a start from a regression of the
differentiated states; ``oe`` then ``m_colores`` for the corrected bounds.
``oe_lon_demo_data.mat`` holds only the data: SIDPAC saved no result, so this
script runs SIDPAC's method itself in plain numpy (``_sidpac.np_output_error``
and ``_sidpac.m_colores``, following oe.m, lsims.m and m_colores.m) for the
SIDPAC columns.

Ours: the same equations as a user ``aeroid.Model`` (``aircraft.longitudinal_linear``
has no ``az`` output and no free ``Z_q``), fitted by ``aeroid.identify``.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_oe_lon"
FILE = "Demos/oe_lon_demo_data.mat"
NAMES = ("Z_alpha", "Z_q", "Z_delta_e", "b_alpha", "M_alpha", "M_q", "M_delta_e", "b_q", "b_az")
OUTPUTS = ("alpha", "q", "az")
DTR = np.pi / 180


def matrices(p: Any, vtg: float) -> tuple[np.ndarray, ...]:
    A = np.array([[p[0], p[1]], [p[4], p[5]]])
    B = np.array([[p[2], p[3]], [p[6], p[7]]])
    C = np.array([[1.0, 0.0], [0.0, 1.0], [p[0] * vtg, (p[1] - 1.0) * vtg]])
    D = np.array([[0.0, 0.0], [0.0, 0.0], [p[2] * vtg, p[8]]])
    return A, B, C, D


def initial_state(z: np.ndarray, t: np.ndarray, m: int = 21) -> np.ndarray:
    """The first sample of a local quadratic fit over the first m samples (xsmep's role)."""
    tt = t[:m] - t[0]
    return np.array([np.polyval(np.polyfit(tt, z[:m, j], 2), 0.0) for j in range(z.shape[1])])


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    f = np.asarray(d["fdata"], dtype=float)
    t = S.col(d["t"])
    g = float(S.col(d["g"])[0])
    z = np.column_stack([f[:, 3] * DTR, f[:, 5] * DTR, f[:, 12]])
    u = np.column_stack([f[:, 13] * DTR, np.ones(len(t))])
    vtg = float(np.mean(f[:, 1]) / g)
    x0 = initial_state(z[:, :2], t)
    # start: regression of the differentiated states on [alpha, q, de, 1]
    zd = np.gradient(z[:, :2], t, axis=0)
    reg = np.linalg.lstsq(np.column_stack([z[:, :2], u]), zd, rcond=None)[0]
    p0 = np.concatenate([reg[:, 0], reg[:, 1], [-1.0]])

    # SIDPAC's method in numpy
    def sim(p: np.ndarray) -> np.ndarray:
        return S.lsims(*matrices(p, vtg), u, t, x0)

    ps, ys, _, rr = S.np_output_error(sim, p0, z)
    crb, crbo = S.m_colores(S._sensitivities(sim, ps), z - ys, rr)
    sw, sc = S.se(crbo), S.se(crb)

    def dynamics(tt: Any, x: Any, uu: Any, p: Any) -> Any:
        a, q = x
        return np.array(
            [
                p["Z_alpha"] * a + p["Z_q"] * q + p["Z_delta_e"] * uu[0] + p["b_alpha"],
                p["M_alpha"] * a + p["M_q"] * q + p["M_delta_e"] * uu[0] + p["b_q"],
            ]
        )

    def measurement(tt: Any, x: Any, uu: Any, p: Any) -> Any:
        a, q = x
        az = vtg * (p["Z_alpha"] * a + (p["Z_q"] - 1.0) * q + p["Z_delta_e"] * uu[0]) + p["b_az"]
        return np.array([a, q, az])

    start = dict(zip(NAMES, p0.tolist(), strict=True))
    model = aeroid.Model(
        states=["alpha", "q"],
        controls=["delta_e"],
        parameters=start,
        dynamics=dynamics,
        outputs=list(OUTPUTS),
        measurement=measurement,
        name="tlonssd",
        linear=True,
    )

    def flight(zz: np.ndarray) -> Any:
        ch = {o: zz[:, j] for j, o in enumerate(OUTPUTS)}
        ch["delta_e"] = u[:, 0]
        return aeroid.FlightData(time=t, channels=ch)

    opts = {"x0": {"alpha": float(x0[0]), "q": float(x0[1])}}
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(z), start, **opts)
    mcs = S.identify_monte_carlo(model, flight, z, res, OUTPUTS, mc, seed=seed, **opts)
    note = (
        "SIDPAC saved no result for oe_lon: its oe + m_colores run in numpy here; "
        "ours is a user Model (longitudinal_linear has no az output)"
    )
    return [
        S.row(
            CASE,
            n,
            sidpac=ps[i],
            sidpac_se_white=sw[i],
            sidpac_se_corrected=sc[i],
            ours=res.parameters[n],
            ours_se=res.stderr[n],
            mc_se=mcs.get(n),
            seconds=tm.seconds,
            note=note,
        )
        for i, n in enumerate(NAMES)
    ]


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
