"""SIDPAC Text Example 7.1: frequency-domain output error, lateral model.

Klein & Morelli Example 7.1, flight ``totter_f1_017``: ``fdoe('fnlatss', ...)``
fits the linear lateral state-space model in 13 non-dimensional derivatives
(CY, Cl, Cn of beta, p, r, aileron, rudder, with the inertia coupling) to the
Fourier transforms of beta, p, r, phi, ay (g) at SIDPAC's 71 frequencies,
with the full Hermitian output noise covariance re-estimated from the
residuals, starting from the equation-error estimates. SIDPAC saved the
estimates and the Cramer-Rao covariance in ``example_7p1_oe_results.mat``.

Ours: the same equations as a user ``aeroid.Model`` fitted by
``aeroid.identify_frequency_domain`` on the same frequencies, with SIDPAC's
record ends (``boundary="ignore"``, the signals detrended to zero end
points as SIDPAC's ``zep``) and the white Cramer-Rao error bars that SIDPAC
reports. Two rows per derivative:

- plain name: the library's default weighting, ``weighting="sidpac"``:
  fdoe's ``estsvv`` forms ``v'*v`` on the frequency-by-output residual
  array, the *conjugate* of ``S = (1/M) Σ v vᴴ``; with it our fit reproduces
  fdoe's estimates (0.18 sigma).
- ``*_ml``: ``weighting="hermitian"``, ``S`` itself, the maximum-likelihood
  weighting for circular complex residuals. With complex cross-spectra (phi
  against p, a quarter turn apart) the two differ, here by up to 6 SIDPAC
  sigma; on simulated records with process noise through this very model
  the Hermitian ``S`` gives the smaller errors (the unit test
  ``test_hermitian_covariance_beats_its_real_part_on_phase_correlated_noise``
  pins it on a smaller model).
- ``*_default``: the default weighting with our default error bars (the
  frequency sandwich), against a Monte Carlo of the flight's own residuals
  (``--mc``): the fitted model simulated in time from the measured first
  states, plus phase-randomised copies of the time-domain residuals, each
  refitted as the case is. SIDPAC's 71 frequencies are 0.4 of ``2π/T``
  apart, so neighbouring transforms share their noise; the sandwich counts
  that, and the Monte Carlo checks it.
"""

from __future__ import annotations

import pathlib
import sys
import time
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "example_7p1"
FILE = "Text_Examples/example_7p1_oe_results.mat"
NAMES = (
    "CY_beta", "CY_r", "CY_delta_r",
    "Cl_beta", "Cl_p", "Cl_r", "Cl_delta_a", "Cl_delta_r",
    "Cn_beta", "Cn_p", "Cn_r", "Cn_delta_a", "Cn_delta_r",
)  # fmt: skip
OUTPUTS = ("beta", "p", "r", "phi", "ay")
G = 32.174  # ft/s^2, as fnlatss


def _load(path: pathlib.Path) -> dict[str, Any]:
    import scipy.io

    return dict(scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False))


def _col(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=float).ravel()


def constants(d: dict[str, Any]) -> dict[str, float]:
    """The numbers fnlatss reads from SIDPAC's ``c`` (compcss) record."""
    c = d["c"]
    k = {n: float(getattr(c, n)) for n in ("vo", "qs", "qsb", "b2v", "sa", "ca", "dgdp", "tt")}
    k["mass"] = float(c.mass)
    ci = _col(c.ci)
    k.update(ci3=ci[2], ci4=ci[3], ci9=ci[8])
    return k


def lateral_model(k: dict[str, float], start: dict[str, float]) -> Any:
    """fnlatss as a user model: linear lateral equations in CY, Cl, Cn derivatives."""
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
        )
        roll = qsb * (
            p["Cl_beta"] * beta + b2v * (p["Cl_p"] * pr + p["Cl_r"] * r)
            + p["Cl_delta_a"] * da + p["Cl_delta_r"] * dr
        )  # fmt: skip
        yaw = qsb * (
            p["Cn_beta"] * beta + b2v * (p["Cn_p"] * pr + p["Cn_r"] * r)
            + p["Cn_delta_a"] * da + p["Cn_delta_r"] * dr
        )  # fmt: skip
        pdot = k["ci3"] * roll + k["ci4"] * yaw
        rdot = k["ci4"] * roll + k["ci9"] * yaw
        phidot = pr + k["tt"] * r
        return np.array([bdot, pdot, rdot, phidot])

    def measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
        beta, pr, r, phi = x
        ay = k2 * (p["CY_beta"] * beta + p["CY_r"] * b2v * r + p["CY_delta_r"] * u[1])
        return np.array([beta, pr, r, phi, ay])

    return aeroid.Model(
        states=["beta", "p", "r", "phi"],
        controls=["delta_a", "delta_r"],
        parameters=start,
        dynamics=dynamics,
        outputs=list(OUTPUTS),
        measurement=measurement,
        name="fnlatss",
        linear=True,
    )


def run(
    folder: pathlib.Path, *, mc: int = 100, seed: int = 0, weighting: str = "sidpac"
) -> list[dict[str, Any]]:
    """One row per derivative: ours with the library's `weighting` (default) against fdoe."""
    import aeroid

    path = pathlib.Path(folder) / FILE
    if not path.exists():
        return []
    d = _load(path)
    start = dict(zip(NAMES, _col(d["p0"]), strict=True))
    model = lateral_model(constants(d), start)
    t = _col(d["t"])
    t = np.round(t / 0.02) * 0.02  # (uniform already; rounding guards float jitter)
    z, u = np.asarray(d["z"], dtype=float), np.asarray(d["u"], dtype=float)
    ch = {n: z[:, j] for j, n in enumerate(OUTPUTS)}
    ch.update(delta_a=u[:, 0], delta_r=u[:, 1])
    data = aeroid.FlightData(time=t, channels=ch)
    import warnings

    fits, secs = {}, 0.0
    for suffix, how in (("", weighting), ("_ml", "hermitian")):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            # SIDPAC's 71 frequencies are 0.4 of 2π/T apart: the library says so
            warnings.filterwarnings("ignore", "frequencies: spacing")
            fits[suffix] = aeroid.identify_frequency_domain(
                model,
                data,
                start,
                frequencies=_col(d["w"]),
                boundary="ignore",
                error_bars="white",
                weighting=how,
            )
        if not suffix:
            secs = time.perf_counter() - t0
    p, w = _col(d["p"]), np.sqrt(np.diag(np.asarray(d["crb"], dtype=float)))
    default, mc_se = _default_with_monte_carlo(d, model, data, start, weighting, mc, seed)
    rows = []
    for suffix, res in fits.items():
        for i, n in enumerate(NAMES):
            ours, se = res.parameters[n], res.stderr[n]
            rows.append(
                S.row(
                    case=CASE,
                    parameter=n + suffix,
                    sidpac=float(p[i]),
                    sidpac_se_white=float(w[i]),
                    sidpac_se_corrected=None,
                    ours=float(ours),
                    ours_se=float(se),
                    mc_se=None,
                    seconds=secs,
                    variant=bool(suffix),
                )
            )
    for n in NAMES:
        rows.append(
            S.row(
                case=CASE,
                parameter=n + "_default",
                sidpac=float(p[NAMES.index(n)]),
                sidpac_se_white=float(w[NAMES.index(n)]),
                sidpac_se_corrected=None,
                ours=float(default.parameters[n]),
                ours_se=float(default.stderr[n]),
                mc_se=mc_se.get(n),
                variant=True,
            )
        )
    return rows


def _default_with_monte_carlo(
    d: dict[str, Any],
    model: Any,
    data: Any,
    start: dict[str, float],
    weighting: str,
    mc: int,
    seed: int,
) -> tuple[Any, dict[str, float]]:
    """Our default error bars (the frequency sandwich) on the same fit, and the Monte
    Carlo of the case's own residuals: the fitted model simulated in time from the
    measured first states (the signals end at zero, SIDPAC's zep), plus
    phase-randomised copies of the time-domain residuals, refitted as the case is."""
    import warnings

    import aeroid

    options = dict(frequencies=_col(d["w"]), boundary="ignore", weighting=weighting)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "frequencies: spacing")
        res = aeroid.identify_frequency_domain(model, data, start, **options)
    if mc < 2:
        return res, {}
    z = np.column_stack([np.asarray(data[o], dtype=float) for o in OUTPUTS])
    controls = {c: np.asarray(data[c], dtype=float) for c in ("delta_a", "delta_r")}
    sim = model.simulate(
        data.time, controls, x0=z[0, :4], parameters=dict(res.parameters), method="exact"
    )
    fitted = np.column_stack([np.asarray(sim.output(o), dtype=float) for o in OUTPUTS])
    fitted_start = dict(res.parameters)

    def refit(znew: np.ndarray) -> dict[str, float]:
        ch = {o: znew[:, j] for j, o in enumerate(OUTPUTS)} | controls
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = aeroid.identify_frequency_domain(
                model, aeroid.FlightData(time=data.time, channels=ch), fitted_start,
                error_bars="white", **options,
            )  # fmt: skip
        return dict(r.parameters)

    return res, S.monte_carlo(refit, fitted, z - fitted, mc, seed=seed)


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run))
