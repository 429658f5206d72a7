"""SIDPAC demo ``tfest_demo``: a first-order roll transfer function.

The demo fits ``p/delta_a = Lda/(s - Lp)`` to a flight record (roll rate in
rad/s, aileron in degrees as stored) with ``tfest(u, z, t, 0, 1, w)``:
equation error on the finite Fourier transforms at 0.1-1.5 Hz (Levy's
regression of ``jw Z`` on ``U`` and ``-Z``, ``lesq``). ``tfest_demo_data.mat``
keeps the record but not the estimates, so the ``sidpac`` column is that
regression recomputed here in a few lines, following ``tfest.m``/``tfregr.m``/
``lesq.m`` (SIDPAC's ``fint`` transforms are the cubic transforms used below to
1e-13); its standard errors are ``lesq``'s, which count each complex
residual as one observation.

Ours: ``aeroid.fit_transfer_function(..., fourier=True)`` (output error on
the transforms; a variant row gives ``method="equation_error"``, tfest's own
method, on its frequencies) with library defaults: the band the aileron excited, on the
record's k/T grid, the record's ends estimated where they matter, and the
frequency sandwich's error bars), set against a Monte Carlo of the fitted
time response plus phase-randomised copies of the residual
(``_sidpac.transfer_monte_carlo``).
"""

from __future__ import annotations

import pathlib
import sys
import time
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_tfest"
FILE = "Demos/tfest_demo_data.mat"
NAMES = ("Lda", "Lp")


def _tfest_like(t: np.ndarray, u: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tfest's equation-error estimates and standard errors for nord=0, dord=1."""
    from aeroid.frequency.frequency_domain import _transform

    dt = float(t[1] - t[0])
    w = 2 * np.pi * np.arange(0.1, 1.5 + 1e-9, 0.05)
    U = _transform(u[:, None], dt, w, cubic=True)[:, 0]
    Z = _transform(z[:, None], dt, w, cubic=True)[:, 0]
    X = np.stack([U, -Z], axis=1)
    y = 1j * w * Z
    xtx = np.real(X.conj().T @ X)
    p = np.linalg.solve(xtx, np.real(X.conj().T @ y))
    v = y - X @ p
    s2 = float(np.real(v.conj() @ v)) / (w.size - p.size)
    se = np.sqrt(np.diag(s2 * np.linalg.inv(xtx)))
    # b0 = Lda, a0 = -Lp
    return np.array([p[0], -p[1]]), se


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import scipy.io

    import aeroid

    path = pathlib.Path(folder) / FILE
    if not path.exists():
        return []
    d = scipy.io.loadmat(str(path), squeeze_me=True)
    t = np.asarray(d["t"], dtype=float).ravel()
    fd = np.asarray(d["fdata"], dtype=float)
    u, z = fd[:, 14], np.radians(fd[:, 4])
    ref, ref_se = _tfest_like(t, u, z)
    data = aeroid.FlightData(time=t, channels={"delta_a": u, "p": z})
    t0 = time.perf_counter()
    fit = aeroid.fit_transfer_function(
        data,
        input="delta_a",
        output="p",
        numerator_order=0,
        denominator_order=1,
        delay=False,
        fourier=True,
    )
    secs = time.perf_counter() - t0

    def refit(uu: np.ndarray, zz: np.ndarray) -> dict[str, float]:
        rec = aeroid.FlightData(time=t, channels={"delta_a": uu, "p": zz})
        out = aeroid.fit_transfer_function(
            rec, input="delta_a", output="p", numerator_order=0, denominator_order=1,
            delay=False, fourier=True, start=fit.parameters,
        ).parameters  # fmt: skip
        return {"Lda": out["b0"], "Lp": -out["a0"]}

    mcs = S.transfer_monte_carlo(refit, fit, t, u, z, mc, seed=seed)
    ours = {"Lda": fit.parameters["b0"], "Lp": -fit.parameters["a0"]}
    ours_se = {"Lda": fit.standard_errors["b0"], "Lp": fit.standard_errors["a0"]}
    # SIDPAC's own method on its frequencies: equation error (our transforms remove
    # the trends and interpolate the input linearly, SIDPAC's fint cubically)
    levy = aeroid.fit_transfer_function(
        data, input="delta_a", output="p", numerator_order=0, denominator_order=1,
        delay=False, fourier=True, method="equation_error",
        frequencies=2 * np.pi * np.arange(0.1, 1.5 + 1e-9, 0.05),
    )  # fmt: skip
    rows = []
    for i, n in enumerate(NAMES):
        key, sign = ("b0", 1.0) if n == "Lda" else ("a0", -1.0)
        rows.append(
            S.row(
                case=CASE,
                parameter="ee:" + n,
                sidpac=float(ref[i]),
                sidpac_se_white=float(ref_se[i]),
                sidpac_se_corrected=None,
                ours=sign * levy.parameters[key],
                ours_se=levy.standard_errors[key],
                variant=True,
            )
        )
    for i, n in enumerate(NAMES):
        rows.append(
            S.row(
                case=CASE,
                parameter=n,
                sidpac=float(ref[i]),
                sidpac_se_white=float(ref_se[i]),
                sidpac_se_corrected=None,
                ours=float(ours[n]),
                ours_se=float(ours_se[n]),
                mc_se=mcs.get(n),
                seconds=secs,
            )
        )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
