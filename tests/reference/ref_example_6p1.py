"""SIDPAC Text Example 6.1: output error for the linear lateral model.

Klein & Morelli Example 6.1, flight ``totter_f1_017`` as perturbations from
the first sample: ``oe('tnlatss', ...)`` fits the linear lateral state-space
model in non-dimensional derivatives (CY, Cl, Cn of beta, p, r, aileron,
rudder, with the inertia coupling), a constant bias on each state equation
and on ``ay``: 18 parameters, outputs beta, p, r, phi, ay (g), starting from
the equation-error estimates of Example 5.1 and from a zero initial state.
SIDPAC saved the estimates and ``oe``'s Cramer-Rao covariance (white
residuals) in ``example_6p1_results.mat``; the corrected bounds are Example
6.2 (``ref_example_6p2.py``).

Ours: the same equations as a user ``aeroid.Model``, fitted by
``aeroid.identify`` with its default error bars. No library model expresses
them: ``aircraft.lateral`` is the nonlinear stability-axis form and
``aircraft.lateral_linear`` takes dimensional derivatives (``L_beta``...),
where ``tnlatss`` estimates the non-dimensional ones (``Cl_beta``...) through
the dynamic pressure and the inertia coupling (``rate_reference`` concerns
``q c/2V`` of the longitudinal model only).
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_6p1"
FILE = "Text_Examples/example_6p1_results.mat"
NAMES = (
    "CY_beta", "CY_r", "CY_delta_r", "bias_beta",
    "Cl_beta", "Cl_p", "Cl_r", "Cl_delta_a", "Cl_delta_r", "bias_p",
    "Cn_beta", "Cn_p", "Cn_r", "Cn_delta_a", "Cn_delta_r", "bias_r",
    "bias_phi", "bias_ay",
)  # fmt: skip
OUTPUTS = ("beta", "p", "r", "phi", "ay")
G = 32.174  # ft/s^2, as tnlatss


def constants(d: dict[str, Any]) -> dict[str, float]:
    """The numbers tnlatss reads from SIDPAC's ``c`` (compcss) record."""
    c = d["c"]
    k = {n: S.field(c, n) for n in ("vo", "qs", "qsb", "b2v", "sa", "ca", "dgdp", "tt", "mass")}
    ci = S.col(S.field(c, "ci"))
    k.update(ci3=ci[2], ci4=ci[3], ci9=ci[8])
    return k


def lateral_model(k: dict[str, float], start: dict[str, float]) -> Any:
    """tnlatss as a user model: linear lateral equations in CY, Cl, Cn derivatives."""
    import aeroid

    k1 = k["qs"] / (k["mass"] * k["vo"])
    k2 = k["qs"] / (k["mass"] * G)
    b2v, qsb = k["b2v"], k["qsb"]

    def dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
        beta, pr, r, phi = x
        da, dr = u
        bdot = (
            k1 * p["CY_beta"] * beta
            + k["sa"] * pr
            + (k1 * p["CY_r"] * b2v - k["ca"]) * r
            + k["dgdp"] * phi
            + k1 * p["CY_delta_r"] * dr
            + p["bias_beta"]
        )
        roll = qsb * (
            p["Cl_beta"] * beta + b2v * (p["Cl_p"] * pr + p["Cl_r"] * r)
            + p["Cl_delta_a"] * da + p["Cl_delta_r"] * dr
        )  # fmt: skip
        yaw = qsb * (
            p["Cn_beta"] * beta + b2v * (p["Cn_p"] * pr + p["Cn_r"] * r)
            + p["Cn_delta_a"] * da + p["Cn_delta_r"] * dr
        )  # fmt: skip
        pdot = k["ci3"] * roll + k["ci4"] * yaw + p["bias_p"]
        rdot = k["ci4"] * roll + k["ci9"] * yaw + p["bias_r"]
        phidot = pr + k["tt"] * r + p["bias_phi"]
        return np.array([bdot, pdot, rdot, phidot])

    def measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
        beta, pr, r, phi = x
        ay = (
            k2 * (p["CY_beta"] * beta + p["CY_r"] * b2v * r + p["CY_delta_r"] * u[1]) + p["bias_ay"]
        )
        return np.array([beta, pr, r, phi, ay])

    return aeroid.Model(
        states=["beta", "p", "r", "phi"],
        controls=["delta_a", "delta_r"],
        parameters=start,
        dynamics=dynamics,
        outputs=list(OUTPUTS),
        measurement=measurement,
        name="tnlatss",
        linear=True,
    )


def flight(t: Any, z: Any, u: Any) -> Any:
    import aeroid

    ch = {n: np.asarray(z[:, j], dtype=float) for j, n in enumerate(OUTPUTS)}
    ch["delta_a"] = np.asarray(u[:, 0], dtype=float)
    ch["delta_r"] = np.asarray(u[:, 1], dtype=float)
    return aeroid.FlightData(time=np.asarray(t, dtype=float).ravel(), channels=ch)


def fit(d: dict[str, Any], *, mc: int, seed: int) -> tuple[Any, dict[str, float], float]:
    """Our fit of 6.1's record, its Monte Carlo standard errors and its time."""
    import aeroid

    start = dict(zip(NAMES, S.col(d["p0"]), strict=True))
    model = lateral_model(constants(d), start)
    t, z, u = S.col(d["t"]), np.asarray(d["z"], dtype=float), np.asarray(d["u"], dtype=float)
    x0 = dict.fromkeys(("beta", "p", "r", "phi"), 0.0)
    with S.Timer() as tm:
        res = aeroid.identify(model, flight(t, z, u), start, x0=x0)
    # residuals come in the order of result.output_names
    order = [list(res.output_names).index(o) for o in OUTPUTS]
    resid = np.asarray(res.residuals[0], dtype=float)[:, order]
    fitted = z - resid

    def refit(zz: np.ndarray) -> dict[str, float]:
        r = aeroid.identify(
            model, flight(t, zz, u), dict(res.parameters), x0=x0, error_bars="white"
        )
        return dict(r.parameters)

    mcs = S.monte_carlo(refit, fitted, resid, mc, seed=seed)
    return res, mcs, tm.seconds


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    res, mcs, secs = fit(d, mc=mc, seed=seed)
    p, w = S.col(d["p"]), S.se(d["crb"])
    return [
        S.row(
            CASE,
            n,
            sidpac=p[i],
            sidpac_se_white=w[i],
            sidpac_se_corrected=None,
            ours=res.parameters[n],
            ours_se=res.stderr[n],
            mc_se=mcs.get(n),
            seconds=secs,
            note="SIDPAC saved oe's white Cramer-Rao bounds only (corrected: example_6p2)",
        )
        for i, n in enumerate(NAMES)
    ]


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
