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

Ours: ``aircraft.longitudinal_linear`` with ``Z`` and ``M`` terms alpha, q,
delta_e and a constant, no ``X`` terms, level trim (``gamma0 = 0``) at the
mean airspeed, outputs alpha, q and ``az`` in g (``accel_units="g"``,
``g = 32.174``) and an output bias on ``az``, fitted by ``aeroid.identify``.
Its alpha equation carries ``q`` itself, so SIDPAC's ``Z_q`` is ours plus
one (``az = V0 ΣZ / g`` then equals SIDPAC's ``(V/g)(... + (Z_q - 1) q ...)``)
and its ``az`` carries ``V0 Z_0 / g``, so SIDPAC's ``b_az`` is compared as our
output bias plus that, without a standard error;
its V and theta states are driven but neither observed nor fed back.
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
    from aeroid.models import aircraft

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

    ours = {  # SIDPAC's name -> ours
        "Z_alpha": "Z_alpha", "Z_q": "Z_q", "Z_delta_e": "Z_delta_e", "b_alpha": "Z_0",
        "M_alpha": "M_alpha", "M_q": "M_q", "M_delta_e": "M_delta_e", "b_q": "M_0",
    }  # fmt: skip
    start = {ours[n]: float(p0[i]) for i, n in enumerate(NAMES) if n in ours}
    start["Z_q"] -= 1.0
    model = aircraft.longitudinal_linear(
        V0=vtg * g,
        g=g,
        terms={"X": [], "Z": ["alpha", "q", "delta_e", "0"], "M": ["alpha", "q", "delta_e", "0"]},
        outputs=list(OUTPUTS),
        accel_units="g",
    )

    def flight(zz: np.ndarray) -> Any:
        ch = {o: zz[:, j] for j, o in enumerate(OUTPUTS)}
        ch["delta_e"] = u[:, 0]
        return aeroid.FlightData(time=t, channels=ch)

    opts: dict[str, Any] = {
        "x0": {"V": 0.0, "alpha": float(x0[0]), "theta": 0.0, "q": float(x0[1])},
        "estimate_bias": {"az": "output"},
    }
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(z), start, **opts)
    mcs = S.identify_monte_carlo(model, flight, z, res, OUTPUTS, mc, seed=seed, **opts)
    note = (
        "SIDPAC saved no result for oe_lon: its oe + m_colores run in numpy here; "
        "ours is longitudinal_linear with az in g (its Z_q + 1 shown; constants Z_0, M_0 "
        "as b_alpha, b_q; b_az = our az output bias + V0 Z_0/g, no se)"
    )
    est = {n: res.parameters[m] for n, m in ours.items()}
    est["Z_q"] += 1.0
    # our az carries V0 Z_0 / g, SIDPAC's does not: its b_az is our sum (no se)
    est["b_az"] = res.biases[0]["az"] + vtg * res.parameters["Z_0"]
    err: dict[str, float | None] = {n: res.stderr[m] for n, m in ours.items()}
    err["b_az"] = None
    mcd = {n: mcs.get(m) for n, m in ours.items()}
    mcd["b_az"] = None
    return [
        S.row(
            CASE,
            n,
            sidpac=ps[i],
            sidpac_se_white=sw[i],
            sidpac_se_corrected=sc[i],
            ours=est[n],
            ours_se=err[n],
            mc_se=mcd[n],
            seconds=tm.seconds,
            note=note,
        )
        for i, n in enumerate(NAMES)
    ]


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
