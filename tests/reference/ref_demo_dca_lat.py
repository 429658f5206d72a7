"""SIDPAC demo ``dca_lat_demo``: lateral data compatibility of HARV flight 342l.

``dcmp`` fits beta, phi and psi by output error, estimating ay, p and r
biases and beta, phi and psi scale factors, with u, w and theta replaced by
their measurements. ``dca_lat_demo_data.mat`` holds ``pc`` and ``oe``'s
covariance ``crbc`` (white). Ours: ``aeroid.check_compatibility`` set up as
``ref_demo_dca_lon.py`` describes (the stored time tags alternate 0.0249 and
0.0251 s; SIDPAC's constant step is the first interval).
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
        outputs=("beta", "phi", "psi"),
        measured=("u", "w", "theta"),
        x0=S.col(d["x0"]),
        mc=mc,
        seed=seed,
    )


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
