"""SIDPAC Text Example 6.1, prediction: the lateral model on another manoeuvre.

After Example 6.1's output error on flight ``totter_f1_017``
(``ref_example_6p1``), SIDPAC's driver predicts beta, p, r, phi and ay of
flight ``totter_f1_014`` (other control inputs), as perturbations from the
first sample, with every derivative held at its 6.1 estimate (``c.pf``) and
the constants of the new flight (``compcss``). Only the five biases (one on
each state equation and on ay) are refitted, from a zero start and a zero
initial state, by ``oe('tnlatss_bias', ...)``; the fitted outputs are the
prediction ``yp``. SIDPAC saved ``yp``, the biases ``pb``, their Cramer-Rao
covariance ``crbb`` and the residual covariance ``rrb`` in
``example_6p1_prediction_results.mat``.

Ours: the 6.1 model of ``ref_example_6p1`` fitted by ``aeroid.identify``,
then the same model with the prediction flight's constants and our
derivatives held (``aeroid.identify(model, flight, [the five biases],
x0=0)``): its fitted outputs are our prediction. Rows: the prediction against
SIDPAC's, the biases against ``pb`` (|d|/sig on SIDPAC's white bounds) and
each output's residual variance against ``rrb``. Variant rows: ``pf:`` our
bias fit with SIDPAC's derivatives held (the method alone); ``sim:`` SIDPAC's
derivatives and biases through our simulation (the integration alone:
``lsims`` is a second-order step with the input averaged over each interval,
ours the exact discretisation with inputs linear between samples); ``val:``
the library's own prediction check, ``aeroid.validate(..., holdout=<the new
flight>, holdout_start="estimated")``: every 6.1 parameter held, its state
biases too, and the initial state and one shift per output fitted instead.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _prediction as P
import _sidpac as S
import ref_example_6p1 as E

CASE = "example_6p1_prediction"
FILES = (
    "Text_Examples/example_6p1_results.mat",
    "Text_Examples/example_6p1_prediction_results.mat",
    "Text_Examples/totter_f1_014_data.mat",
)
BIASES = ("bias_beta", "bias_p", "bias_r", "bias_phi", "bias_ay")
DERIVATIVES = tuple(n for n in E.NAMES if n not in BIASES)


def _record(raw: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, outputs and controls of the prediction flight as the driver forms them."""
    f = np.asarray(raw["fdata"], dtype=float)
    z = np.column_stack([np.radians(f[:, [2, 4, 6, 7]]), f[:, 11]])
    u = np.radians(f[:, 14:16])
    return S.col(raw["t"]), z - z[0], u - u[0]


def _bias_fit(
    constants: dict[str, float], held: dict[str, float], t: Any, z: Any, u: Any
) -> tuple[Any, np.ndarray]:
    """The five biases fitted with `held` derivatives; the fit and its fitted outputs."""
    import aeroid

    model = E.lateral_model(constants, {**held, **dict.fromkeys(BIASES, 0.0)})
    x0 = dict.fromkeys(("beta", "p", "r", "phi"), 0.0)
    res = aeroid.identify(model, E.flight(t, z, u), list(BIASES), x0=x0)
    order = [list(res.output_names).index(o) for o in E.OUTPUTS]
    return res, z - np.asarray(res.residuals[0], dtype=float)[:, order]


def _tnlatss_bias(k: dict[str, float], p: dict[str, float]) -> tuple[np.ndarray, ...]:
    """SIDPAC's tnlatss_bias as matrices: the biases on a constant pseudo-input."""
    k1, k2 = k["qs"] / (k["mass"] * k["vo"]), k["qs"] / (k["mass"] * E.G)
    b2v, qsb = k["b2v"], k["qsb"]
    roll = qsb * np.array([p["Cl_beta"], b2v * p["Cl_p"], b2v * p["Cl_r"], 0.0])
    yaw = qsb * np.array([p["Cn_beta"], b2v * p["Cn_p"], b2v * p["Cn_r"], 0.0])
    roll_u = qsb * np.array([p["Cl_delta_a"], p["Cl_delta_r"]])
    yaw_u = qsb * np.array([p["Cn_delta_a"], p["Cn_delta_r"]])
    a = np.array(
        [
            [k1 * p["CY_beta"], k["sa"], k1 * p["CY_r"] * b2v - k["ca"], k["dgdp"]],
            k["ci3"] * roll + k["ci4"] * yaw,
            k["ci4"] * roll + k["ci9"] * yaw,
            [0.0, 1.0, k["tt"], 0.0],
        ]
    )
    b = np.zeros((4, 3))
    b[0, 1] = k1 * p["CY_delta_r"]
    b[1, :2] = k["ci3"] * roll_u + k["ci4"] * yaw_u
    b[2, :2] = k["ci4"] * roll_u + k["ci9"] * yaw_u
    b[:, 2] = [p[n] for n in BIASES[:4]]
    c = np.vstack([np.eye(4), [k2 * p["CY_beta"], 0.0, k2 * p["CY_r"] * b2v, 0.0]])
    d = np.zeros((5, 3))
    d[4, 1:] = [k2 * p["CY_delta_r"], p["bias_ay"]]
    return a, b, c, d


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    fit_path, pred_path, data_path = S.need(folder, *FILES)
    d6, dp, raw = S.loadmat(fit_path), S.loadmat(pred_path), S.loadmat(data_path)
    t, z, u = _record(raw)
    formed = max(
        np.max(np.abs(z - np.asarray(dp["z"], dtype=float))),
        np.max(np.abs(u - np.asarray(dp["u"], dtype=float)[:, :2])),
    )
    print(f"  prediction record formed as SIDPAC's z, u to {formed:.1e}")
    fit6 = E.fit(d6, mc=0, seed=seed)[0]
    k = E.constants(dp)  # the prediction flight's compcss
    with S.Timer() as tm:
        res, ours = _bias_fit(k, {n: fit6.parameters[n] for n in DERIVATIVES}, t, z, u)
    yp, pb, wb = np.asarray(dp["yp"], dtype=float), S.col(dp["pb"]), S.se(dp["crbb"])
    rrb = np.diag(np.asarray(dp["rrb"], dtype=float))
    note = (
        "d/rng: max |ours - SIDPAC's| prediction over the measured range; rms, R2: each "
        "prediction against the measured output; rr_: residual variance (SIDPAC's rrb); "
        "pf: our bias fit with SIDPAC's derivatives; sim: SIDPAC's parameters, our simulation; "
        "val: aeroid.validate, initial state and output shifts fitted"
    )
    rows = P.prediction_rows(CASE, E.OUTPUTS, z, yp, ours, note=note)

    def bias_rows(r: Any, fitted: np.ndarray, label: str = "") -> list[dict[str, Any]]:
        out = [
            S.row(
                CASE,
                label + n,
                sidpac=pb[i],
                sidpac_se_white=wb[i],
                sidpac_se_corrected=None,
                ours=r.parameters[n],
                ours_se=r.stderr[n],
                variant=bool(label),
            )
            for i, n in enumerate(BIASES)
        ]
        var = np.mean((z - fitted) ** 2, axis=0)
        blank = {"sidpac_se_white": None, "sidpac_se_corrected": None, "ours_se": None}
        out += [
            S.row(CASE, f"{label}rr_{n}", sidpac=rrb[j], ours=var[j], variant=bool(label), **blank)
            for j, n in enumerate(E.OUTPUTS)
        ]
        return out

    rows += bias_rows(res, ours)
    sid = dict(zip(E.NAMES, S.col(d6["p"]), strict=True))
    res_pf, ours_pf = _bias_fit(k, {n: sid[n] for n in DERIVATIVES}, t, z, u)
    rows += P.prediction_rows(CASE, E.OUTPUTS, z, yp, ours_pf, label="pf:", variant=True)
    rows += bias_rows(res_pf, ours_pf, "pf:")
    # SIDPAC's derivatives and biases, our simulation
    whole = {**{n: sid[n] for n in DERIVATIVES}, **dict(zip(BIASES, pb, strict=True))}
    model = E.lateral_model(k, whole)
    sim = model.simulate(t, {"delta_a": u[:, 0], "delta_r": u[:, 1]}, method="exact")
    flown = np.column_stack([sim.output(o) for o in E.OUTPUTS])
    rows += P.prediction_rows(CASE, E.OUTPUTS, z, yp, flown, label="sim:", variant=True)
    # the library's own prediction check: all of 6.1's parameters held (its biases
    # too), the initial state and one shift per output fitted to the new flight
    import aeroid

    check = aeroid.validate(
        E.lateral_model(k, dict(fit6.parameters)),
        E.flight(t, z, u),
        fit6,
        holdout=E.flight(t, z, u),
        holdout_start="estimated",
    ).prediction
    order = [list(check.output_names).index(o) for o in E.OUTPUTS]
    predicted = np.asarray(check.predicted, dtype=float)[:, order]
    rows += P.prediction_rows(CASE, E.OUTPUTS, z, yp, predicted, label="val:", variant=True)
    # and through SIDPAC's own second-order step, in numpy: its yp again
    a, b, c, dd = _tnlatss_bias(k, whole)
    pseudo = np.column_stack([u, np.ones(t.size)])
    again = S.lsims(a, b, c, dd, pseudo, t, np.zeros(4))
    worst = np.max(np.abs(again - yp) / np.ptp(z, axis=0))
    print(f"  SIDPAC's parameters through lsims in numpy give its saved yp to {worst:.1e}")
    for r in rows:
        r["seconds"] = tm.seconds
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
