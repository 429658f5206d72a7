"""SIDPAC demo ``totter_tf_demo``: a Twin Otter q/elevator transfer function, then prediction.

The demo fits ``q/δe = (b1 s + b0) / (s² + a1 s + a0)`` to the record of
``totter_demo_data.mat`` (elevator and pitch rate in degrees, each ``zep``'d:
less the straight line through its end points) with ``tfest(u, z, t, 1, 2, w)``
on ``w = 2π (0.3:0.01:1.3)`` rad/s: equation error on the finite Fourier
transforms (``fint``), Levy's regression of ``(jω)² Z`` on ``jω U``, ``U``,
``-jω Z``, ``-Z``, each row divided by ``jω`` (``tfregr``), solved by ``lesq``.
It then flies the model on the ``zep``'d elevator of ``totter_pred_data.mat``
from rest (``tfsim``) and adds a bias fitted by least squares to the
prediction residual (``lesq`` on a column of ones: its mean). SIDPAC saved no
result for this demo, so the ``sidpac`` column is that method run here in
numpy (`_prediction`: fint, tfsim; the regression in a few lines), and its
standard errors are ``lesq``'s, which count each complex residual as one
observation.

Ours: ``aeroid.fit_transfer_function(..., fourier=True, frequencies=w)`` on the
same ``zep``'d record (output error on the transforms, the record's ends
estimated where they matter: the library's defaults), flown on the prediction
input with scipy's exact response and the same least-squares bias. Rows: the
estimates, ω and ζ (SIDPAC's ``damps``), and the prediction against SIDPAC's.
Variant rows: ``ends:`` ours with ``boundary="ignore"`` (no end terms, as
tfest); ``tfsim:`` our model through SIDPAC's simulation.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _prediction as P
import _sidpac as S

CASE = "demo_totter_tf"
FILES = ("Demos/totter_demo_data.mat", "Demos/totter_pred_data.mat")
NAMES = ("b1", "b0", "a1", "a0")


def tfest(u: np.ndarray, z: np.ndarray, t: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, ...]:
    """tfest's estimates [b1, b0, a1, a0] and lesq's standard errors for orders 1 and 2."""
    uf, zf = P.fint(u, t, w), P.fint(z, t, w)
    s = 1j * w
    x = np.column_stack([s * uf, uf, -s * zf, -zf]) / s[:, None]
    y = s * zf  # (jw)^2 Z over jw
    xtx = np.real(x.conj().T @ x)
    p = np.linalg.solve(xtx, np.real(x.conj().T @ y))
    v = y - x @ p
    s2 = float(np.real(v.conj() @ v)) / (w.size - p.size)
    return p, np.sqrt(np.diag(s2 * np.linalg.inv(xtx)))


def _mode(a1: float, a0: float) -> tuple[float, float]:
    omega = float(np.sqrt(a0))
    return omega, a1 / (2.0 * omega)


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    fit_path, pred_path = S.need(folder, *FILES)
    raw, pred = S.loadmat(fit_path), S.loadmat(pred_path)
    t = S.col(raw["t"])
    f = np.asarray(raw["fdata"], dtype=float)
    u, z = P.zep(f[:, 13]), P.zep(f[:, 5])
    w = 2 * np.pi * np.arange(30, 131) / 100.0
    ref, ref_se = tfest(u, z, t, w)
    data = aeroid.FlightData(time=t, channels={"elevator": u, "q": z})
    kw: dict[str, Any] = {"input": "elevator", "output": "q", "delay": False}
    kw.update(numerator_order=1, denominator_order=2, fourier=True, frequencies=w)
    with S.Timer() as tm:
        fit = aeroid.fit_transfer_function(data, **kw)
    ends = aeroid.fit_transfer_function(data, **kw, boundary="ignore")
    # tfest's own method, equation error (our default ends: the trend lines our
    # transforms remove are not zep's end-point lines, and the terms take the difference)
    levy = aeroid.fit_transfer_function(data, **kw, method="equation_error")
    print(f"  our fit estimated the record's ends: {fit.ends_estimated}")
    rows = []
    for label, r in (("", fit), ("ends:", ends), ("ee:", levy)):
        for i, n in enumerate(NAMES):
            rows.append(
                S.row(
                    CASE,
                    label + n,
                    sidpac=ref[i],
                    sidpac_se_white=ref_se[i],
                    sidpac_se_corrected=None,
                    ours=r.parameters[n],
                    ours_se=r.stderr[n],
                    variant=bool(label),
                )
            )
        blank = {"sidpac_se_white": None, "sidpac_se_corrected": None, "ours_se": None}
        sid_mode = _mode(ref[2], ref[3])
        our_mode = _mode(r.parameters["a1"], r.parameters["a0"])
        for j, n in enumerate(("omega", "zeta")):
            rows.append(
                S.row(
                    CASE, label + n, sidpac=sid_mode[j], ours=our_mode[j], variant=bool(label),
                    **blank,
                )
            )  # fmt: skip
    # the prediction manoeuvre, flown from rest with a least-squares bias
    tp = S.col(pred["t"])
    fp = np.asarray(pred["fdata"], dtype=float)
    up, zp = P.zep(fp[:, 13]), P.zep(fp[:, 5])
    num, den = ref[:2], np.concatenate([[1.0], ref[2:]])
    sid = P.tfsim(num, den, 0.0, up, tp)
    sid = sid + np.mean(zp - sid)

    def flown(r: Any, simulate: Any) -> np.ndarray:
        y = simulate(np.asarray(r.numerator, float), np.asarray(r.denominator, float), 0.0, up, tp)
        return np.asarray(y + np.mean(zp - y))

    note = (
        "sidpac column: tfest's method in numpy (SIDPAC saved no result); d/rng: max |ours - "
        "SIDPAC's| prediction over the measured range; rms, R2: each prediction against the "
        "measured q; ends: boundary='ignore'; tfsim: our model, SIDPAC's simulation"
    )
    rows += P.prediction_rows(CASE, ["q"], zp, sid, flown(fit, P.scipy_response), note=note)
    rows += P.prediction_rows(
        CASE, ["q"], zp, sid, flown(ends, P.scipy_response), label="ends:", variant=True
    )
    rows += P.prediction_rows(
        CASE, ["q"], zp, sid, flown(fit, P.tfsim), label="tfsim:", variant=True
    )
    for r in rows:
        r["seconds"] = tm.seconds
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
