"""SIDPAC Text Example 7.1, first half: equation error in the frequency domain.

Klein & Morelli Example 7.1, flight ``totter_f1_017`` (the lateral record of
Example 5.1, 20 s at 50 Hz): each coefficient CY, Cl, Cn is regressed on the
finite Fourier transforms of beta, p_hat, r_hat, aileron and rudder at
SIDPAC's 71 frequencies 0.1:0.02:1.5 Hz (``fint`` of ``zep``'d signals, then
``lesq`` on the complex values, with a column of ones in the frequency
domain). SIDPAC saved the estimates and its white covariances (``crbn``,
``crbY``, ``crb1``) in ``example_7p1_ee_results.mat``.

Ours: ``aeroid.equation_error(..., domain="frequency")`` on the same
``zep``'d signals and frequencies. SIDPAC's ones column is the transform of
a unit impulse at t = 0 (a sample of height 1/dt, whose Euler transform is 1
at every frequency), given here as a regressor ``const_impulse`` with
``intercept=False``. SIDPAC's ``lesq`` counts each complex residual as one
observation of the full variance, so its white standard errors are about
sqrt(2 (2M - p) / (M - p)) = 1.45 times the classical ones per real
component. The frequencies are 0.4 of ``1/T`` apart, so the transforms of
neighbouring frequencies share their noise; our default bars (the
frequency sandwich) count that, and the Monte Carlo (the fitted time
response plus phase-randomised copies of the time-domain residual, each
refitted as the case is) checks them.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_7p1_ee"
FILE = "Text_Examples/example_7p1_ee_results.mat"
_X = ("beta", "p_hat", "r_hat", "delta_a", "delta_r", "const_impulse")
DTR = np.pi / 180.0


def _zep(x: np.ndarray) -> np.ndarray:
    """SIDPAC's zep: each column less the straight line through its end points."""
    ramp = np.linspace(0.0, 1.0, x.shape[0])[:, None]
    return np.asarray(x - (x[:1] + ramp * (x[-1:] - x[:1])), dtype=float)


def _coefficient(
    label: str,
    names: tuple[str, ...],
    regressors: dict[str, np.ndarray],
    z: np.ndarray,
    sidpac: tuple[np.ndarray, np.ndarray],
    freq: np.ndarray,
    dt: float,
    mc: int,
    seed: int,
) -> list[dict[str, Any]]:
    import aeroid

    data = {**{n: regressors[n] for n in names}, "__z": z}
    kw: dict[str, Any] = {
        "intercept": False,
        "domain": "frequency",
        "frequencies": freq,
        "dt": dt,
    }
    with S.Timer() as tm:
        res = aeroid.equation_error(data, "__z", list(names), **kw)
    white = aeroid.equation_error(data, "__z", list(names), error_bars="white", **kw)
    theta = np.array([res.parameters[n] for n in names])
    fitted = np.column_stack([regressors[n] for n in names]) @ theta

    def refit(zz: np.ndarray) -> dict[str, float]:
        out = aeroid.equation_error({**data, "__z": zz}, "__z", list(names), **kw)
        return dict(out.parameters)

    mcs = S.monte_carlo(refit, fitted, z - fitted, mc, seed=seed)
    p, sw = sidpac
    rows = []
    for i, n in enumerate(names):
        for suffix, fit in (("", res), ("_white", white)):
            rows.append(
                S.row(
                    CASE,
                    f"{label}{n}{suffix}",
                    sidpac=p[i],
                    sidpac_se_white=sw[i],
                    sidpac_se_corrected=None,
                    ours=fit.parameters[n],
                    ours_se=fit.stderr[n],
                    mc_se=mcs.get(n),
                    seconds=tm.seconds if fit is res else None,
                    variant=fit is white,
                )
            )
    return rows


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    fdata = np.asarray(d["fdata"], dtype=float)
    t = S.col(d["t"])
    dt = float(t[1] - t[0])
    freq = S.col(d["f"])
    x = _zep(
        np.column_stack(
            [fdata[:, 2] * DTR, fdata[:, 70], fdata[:, 72], fdata[:, 14] * DTR, fdata[:, 15] * DTR]
        )
    )
    reg = {n: x[:, j] for j, n in enumerate(_X[:5])}
    impulse = np.zeros(t.size)
    impulse[0] = 1.0 / dt  # its Euler transform is 1 at every frequency: SIDPAC's ones
    reg["const_impulse"] = impulse
    rows: list[dict[str, Any]] = []
    cases = (
        ("CY_", ("beta", "r_hat", "delta_r", "const_impulse"), 61, "pY", "serrY"),
        ("Cl_", _X, 63, "p1", "serr1"),
        ("Cn_", _X, 65, "pn", "serrn"),
    )
    for k, (label, names, column, pk, sk) in enumerate(cases):
        z = _zep(fdata[:, [column]])[:, 0]
        sidpac = (S.col(d[pk]), S.col(d[sk]))
        rows += _coefficient(label, names, reg, z, sidpac, freq, dt, mc, seed + k)
    rows[0]["note"] = (
        "SIDPAC's lesq white se = sqrt(2(2M-p)/(M-p)) x the classical per real component "
        "(*_white rows); its frequencies are 0.4 of 1/T apart, which the default bars count"
    )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
