"""SIDPAC demo ``dca_lat_demo``: lateral data compatibility of HARV flight 342l.

``dcmp`` fits beta, phi and psi by output error, estimating ay, p and r
biases and beta, phi and psi scale factors. ``dca_lat_demo_data.mat`` holds
``pc``, ``oe``'s covariance ``crbc`` (white) and the initial state ``x0``.
Ours: ``aeroid.check_compatibility`` with the same six parameters and
SIDPAC's lateral set-up (``dcmp_psel``): outputs beta, phi, psi; u, w and
theta replaced by their measurements; scale factors about the initial value;
initial state held at SIDPAC's ``x0``; one Runge-Kutta step per sample with
the inputs held (``integration="rk4_hold"``: SIDPAC's own ``pc`` through it
gives the saved ``yc`` to rounding) on the uniform time ``k 51/2048 s`` (see
``ref_demo_dca_lon.py`` for how that integration was found, the error bars,
the Monte Carlo and the known-truth study, ``--truth N``).
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S
import ref_demo_dca_lon as LON

CASE = "demo_dca_lat"
FILE = "Demos/dca_lat_demo_data.mat"


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    u, z = np.asarray(d["u"], dtype=float), np.asarray(d["ztot"], dtype=float)
    return LON.compat_rows(
        CASE,
        u[:, :6],
        z,
        S.col(d["t"]),
        ("b_ay", "b_p", "b_r", "k_beta", "k_phi", "k_psi"),
        S.col(d["pc"]),
        np.asarray(d["crbc"], dtype=float),
        S.col(d["x0"]),
        np.asarray(d["yc"], dtype=float),
        outputs=("beta", "phi", "psi"),
        measured_states=("u", "w", "theta"),
        mc=mc,
        seed=seed,
    )


def run_truth(folder: pathlib.Path, n: int) -> None:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    LON.truth_study(
        np.asarray(d["u"], dtype=float)[:, :6],
        np.asarray(d["ztot"], dtype=float),
        S.col(d["t"]),
        ("b_ay", "b_p", "b_r", "k_beta", "k_phi", "k_psi"),
        S.col(d["x0"]),
        outputs=("beta", "phi", "psi"),
        measured_states=("u", "w", "theta"),
        n=n,
    )


if __name__ == "__main__":
    if LON.truth_main(run_truth) < 0:
        raise SystemExit(S.main(CASE, run))
