"""SIDPAC Text Example 7.3, prediction: the TU-144 LOES flown on another 2-1-1.

After fitting ``q/η = (b1 s + b0) e^{−τ s} / (s² + a1 s + a0)`` to flight
``f20_4d`` (``ref_example_7p3``), SIDPAC's driver predicts the pitch rate of
flight ``f20_4f`` (opposite input polarity) with its frequency-domain
output-error model: ``yp = tfsim(numo, deno, tauo, up, tp)``, the ``zep``'d
stick (mm / 25.4) and pitch rate of ``tu144_f20_4f_pred_data.mat``, from rest.
No bias or initial state is fitted. SIDPAC saved ``yp`` in
``example_7p3_prediction_results.mat``.

Ours: the library's default LOES (``aeroid.equivalent_system`` on the record
as ``ref_example_7p3`` fits it), simulated as a user would, with scipy's
exact response to the linearly interpolated, delayed input (``num``,
``den`` and ``delay`` of the fit). Two variant rows split the difference:
``sidsim:`` SIDPAC's model through that same simulation (the simulation
alone: tfsim's second-order step with the input averaged over each
interval, and ulag's delay), ``tfsim:`` our model through SIDPAC's
simulation written in numpy (the estimates alone). SIDPAC's tfsim in numpy
gives its saved ``yp`` back to rounding, which the case checks.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _prediction as P
import _sidpac as S

CASE = "example_7p3_prediction"
FILES = (
    "Text_Examples/example_7p3_prediction_results.mat",
    "Text_Examples/tu144_f20_4d_data.mat",
    "Text_Examples/tu144_f20_4f_pred_data.mat",
)


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    res_path, fit_path, pred_path = S.need(folder, *FILES)
    res, raw, pred = S.loadmat(res_path), S.loadmat(fit_path), S.loadmat(pred_path)
    fd, t = np.asarray(raw["fdata"], dtype=float), S.col(raw["t"])
    stick, q = fd[:, 30] / 25.4, fd[:, 5]
    data = aeroid.FlightData(time=t, channels={"stick": stick - stick[0], "q": q - q[0]})
    with S.Timer() as tm:
        fit = aeroid.equivalent_system(data, input="stick", output="q").fit
    # the prediction record as the driver forms it
    fp, tp = np.asarray(pred["fdata_f20_4f"], dtype=float), S.col(pred["t_f20_4f"])
    up, zp = P.zep(fp[:, 30] / 25.4), P.zep(fp[:, 5])
    formed = max(np.max(np.abs(up - S.col(pred["up"]))), np.max(np.abs(zp - S.col(pred["zp"]))))
    yp = S.col(res["yp"])
    num, den, tau = S.col(res["numo"]), S.col(res["deno"]), float(S.col(res["tauo"])[0])
    again = np.max(np.abs(P.tfsim(num, den, tau, up, tp) - yp)) / np.ptp(zp)
    print(f"  input and output formed as SIDPAC's up, zp to {formed:.1e}")
    print(f"  SIDPAC's tfsim in numpy gives its saved yp to {again:.1e} of the range")
    ours_num, ours_den = np.asarray(fit.numerator, float), np.asarray(fit.denominator, float)
    ours = P.scipy_response(ours_num, ours_den, float(fit.delay), up, tp)
    note = (
        "d/rng: max |ours - SIDPAC's| prediction over the measured range; rms, R2: each "
        "prediction against the measured q; sidsim: SIDPAC's model, our simulation; "
        "tfsim: our model, SIDPAC's simulation"
    )
    rows = P.prediction_rows(CASE, ["q"], zp, yp, ours, note=note)
    rows += P.prediction_rows(
        CASE, ["q"], zp, yp, P.scipy_response(num, den, tau, up, tp), label="sidsim:",
        variant=True,
    )  # fmt: skip
    rows += P.prediction_rows(
        CASE, ["q"], zp, yp, P.tfsim(ours_num, ours_den, float(fit.delay), up, tp),
        label="tfsim:", variant=True,
    )  # fmt: skip
    for r in rows:
        r["seconds"] = tm.seconds
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
