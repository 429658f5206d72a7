"""Are our filter-error error bars calibrated on the HFB-320 model? A known-truth study.

On the flight (`ref_fvsysid_hfb320_fem.py`) our filter-error standard errors
of CD_alpha, CL_alpha, Cm_alpha and Cm_q read 0.15-0.2 of FVSysID's
Cramer-Rao bounds and of the case's Monte Carlo while the filter started from a
unit variance on the held start: the first innovations' covariance, a radian
of alpha's prior seen through the outputs, then dominated the information's
innovation-covariance term (on one record 99.9 % of CL_alpha's), and neither
the likelihood's curvature nor the scores' spread agreed with it. The prior is
now the start's error (none for a given start). Here each seed simulates the
case's model at FVSysID's estimates, finely (20 RK4 steps a sample, the
process noise F F' as a continuous white noise, the inputs straight lines
between samples), plus white measurement noise at our fit's levels, so the
record is what our filter-error model assumes. Each record is fitted by
``identify(method="filter_error")`` with the default steady gain and with
``gain="time_varying"``, and by the numpy port of FVSysID (`_fvsysid_fem`),
all from the truth. Printed per parameter: the root mean square of
(estimate - truth) / standard error over the seeds (1 for calibrated bars)
and the median of our standard error over the port's.

``--no-trace`` re-evaluates each of our fits at its estimate (one step,
measurement noise held as the book holds R) with the innovation covariance's
term ``1/2 tr(S^-1 dS_i S^-1 dS_j)`` dropped from the parameters' rows of the
Fisher information (monkeypatched into the library's private `_derivatives`;
a diagnosis, not an option): the port's information has no such term. With
the start's prior right the term is small on this model and the switch moves
the bars by a few per cent.

``--case dhc2`` runs the same study on the lateral case's linear model (its
data's derivatives, biases and F of our choosing, white measurement noise on
every output): there our derivatives' bars are calibrated and tighter than
the port's (the full likelihood is more efficient); the biases', which only
the transient from the given start separates (BX1 from BY1), read 20-36
times too wide under the unit prior and are calibrated now.

``AEROID_FVSYSID_DIR=... python tests/reference/study_fvsysid_fem.py [--seeds 8]
[--no-trace] [--case hfb320|dhc2]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import pathlib
import sys
import warnings
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid_fem as P
import _sidpac as S
import ref_fvsysid_dhc2_fem as D
import ref_fvsysid_hfb320_fem as H
from _fvsysid import read_flight

F_TRUE = (0.36, 0.0024, 0.00045, 0.0017)  # about FVSysID's F on the flight
NOISE_SD = np.sqrt([3e-3, 1e-6, 1.3e-7, 1e-7, 3.5e-5, 1.3e-4, 7e-3])  # about ours
# the lateral case: the data's derivatives, biases and F of our choosing, some noise
LAT_BIASES = (0.05, -0.05, 0.02, -0.03, 0.04, 0.01, -0.01)
LAT_F = (0.2, 0.2)
LAT_SD = np.array([0.05, 0.02, 0.05, 0.005, 0.005])


def setting(d: np.ndarray, which: str) -> dict[str, Any]:
    """Module, port case at the truth, truth, noise sd, x0 and control channels."""
    if which == "hfb320":
        truth = np.r_[H.SAVED, F_TRUE]
        controls = {"delta_e": d[:, 1], "thrust": d[:, 3]}
        x0 = dict(zip(H.STATES, H.X0, strict=True))
        return {"mod": H, "case": H.port_case(d), "truth": truth, "sd": NOISE_SD, "x0": x0,
                "controls": controls}  # fmt: skip
    lat = D.data_truth(d)
    truth = np.r_[[lat[n] for n in D.NAMES[:15]], LAT_BIASES, LAT_F]
    controls = {"delta_a": d[:, 16], "delta_r": d[:, 17], "v": d[:, 18]}
    return {"mod": D, "case": D.port_case(d), "truth": truth, "sd": LAT_SD,
            "x0": dict.fromkeys(D.STATES, 0.0), "controls": controls}  # fmt: skip


def record(
    case: P.FemCase, p: np.ndarray, sd: np.ndarray, rng: np.random.Generator, fine: int = 20
) -> np.ndarray:
    """Outputs of the model with continuous process noise and white measurement noise."""
    n = case.z.shape[0]
    x = case.x0.astype(float)[None]
    z = np.empty_like(case.z)
    h = case.dt / fine
    f = np.asarray(p[-case.nx :])
    for k in range(n):
        z[k] = case.h(x, case.u[k][None], p[None])[0] + sd * rng.standard_normal(z.shape[1])
        if k + 1 < n:
            du = (case.u[k + 1] - case.u[k]) / fine
            for j in range(fine):
                u1, u2 = case.u[k] + j * du, case.u[k] + (j + 1) * du
                x = P.rk4_step(case.f, x, u1[None], u2[None], p[None], h)
                x = x + np.sqrt(h) * f * rng.standard_normal(case.nx)
    return z


def without_trace_term() -> None:
    """Drop the innovation covariance's term from the parameters' rows and columns of
    our filter-error Fisher information (the noise intensities keep theirs)."""
    import aeroid.estimation._filter_error as fe

    src = inspect.getsource(fe._derivatives)
    for old in ("fisher += 0.5 * (trace / np.outer(h, h))", "fisher += 0.5 * (K - k0) * np.einsum"):
        assert old in src, old
    src = src.replace(
        "fisher += 0.5 * (trace / np.outer(h, h))",
        "fisher += 0.5 * (trace / np.outer(h, h)) * _noise_only(layout, n)",
    ).replace(
        'fisher += 0.5 * (K - k0) * np.einsum("iab,jba->ij", SdS1, SdS1)',
        'fisher += 0.5 * (K - k0) * np.einsum("iab,jba->ij", SdS1, SdS1) * _noise_only(layout, n)',
    )

    def noise_only(layout: Any, n: int) -> np.ndarray:
        keep = np.zeros((n, n))
        keep[layout.n_e :, layout.n_e :] = 1.0
        return keep

    space: dict[str, Any] = {**vars(fe), "_noise_only": noise_only}
    exec(src, space)
    fe._derivatives = space["_derivatives"]  # type: ignore[attr-defined]


def rebar(model: Any, data: Any, r: Any) -> Any:
    """`r` re-evaluated at its estimate (one step from it, noise intensities free,
    measurement noise held) with `without_trace_term`'s information."""
    import aeroid
    import aeroid.estimation._filter_error as fe

    saved = fe._derivatives
    without_trace_term()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return aeroid.identify(
                model, data, dict(r.parameters), method="filter_error",
                x0=dict(r.initial_states[0]), estimate_process_noise=True,
                process_noise=dict(r.process_noise),
                measurement_noise={o: r.noise_covariance[j, j] for j, o in enumerate(r.output_names)},
                max_iterations=1,
            )  # fmt: skip
    finally:
        fe._derivatives = saved


def main(argv: list[str] | None = None) -> int:
    import aeroid

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--no-trace", action="store_true")
    ap.add_argument("--case", choices=("hfb320", "dhc2"), default="hfb320")
    args = ap.parse_args(argv)
    folder = S.data_folder("fvsysid")
    if folder is None:
        print(f"skipped: set {S.FVSYSID_ENV}")
        return 0
    st = setting(read_flight(S.need(folder, (H if args.case == "hfb320" else D).FILE,
                                    source="fvsysid")[0]), args.case)  # fmt: skip
    mod, truth = st["mod"], st["truth"]
    names = list(mod.NAMES)
    npar = len(names)
    case = dataclasses.replace(st["case"], p0=truth)
    model = mod.user_model()
    t = np.arange(case.z.shape[0]) * mod.DT
    start = dict(zip(names, truth[:npar], strict=True))
    q0 = {s: f * f for s, f in zip(mod.STATES, truth[npar:], strict=True)}
    devs: dict[str, list[np.ndarray]] = {"steady": [], "time_varying": [], "fvsysid": []}
    ratios: dict[str, list[np.ndarray]] = {"steady": [], "time_varying": []}
    unconverged = dict.fromkeys(ratios, 0)
    for seed in range(args.seeds):
        z = record(case, truth, st["sd"], np.random.default_rng(seed))
        book = P.ml_fem(dataclasses.replace(case, z=z))
        devs["fvsysid"].append((book.p[:npar] - truth[:npar]) / book.se[:npar])
        ch = {o: z[:, j] for j, o in enumerate(mod.OUTPUTS)}
        ch.update(st["controls"])
        data = aeroid.FlightData(time=t, channels=ch)
        for gain in ratios:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = aeroid.identify(
                    model, data, start, method="filter_error", x0=st["x0"],
                    estimate_process_noise=True, process_noise=q0,
                    filter_options={"gain": gain},
                )  # fmt: skip
            unconverged[gain] += not r.success
            if args.no_trace:  # the same fit's bars, the parameters' trace term dropped
                r = rebar(model, data, r)
            est = np.array([r.parameters[n] for n in names])
            se = np.array([r.stderr[n] for n in names])
            devs[gain].append((est - truth[:npar]) / se)
            ratios[gain].append(se / book.se[:npar])
    print(f"{'':24}" + "".join(f"{n:>7}" for n in names))
    for who, v in devs.items():
        rms = np.sqrt(np.mean(np.square(v), axis=0))
        print(f"rms d/se {who:15}" + "".join(f"{x:7.2f}" for x in rms))
    for who, v in ratios.items():
        med = np.median(v, axis=0)
        print(f"se/fvsysid {who:13}" + "".join(f"{x:7.2f}" for x in med))
    print(f"not converged of {args.seeds}: {unconverged}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
