"""FVSysID test case 33: ATTAS flight path reconstruction with output time delays.

``chapter04/mDefCase33.m`` with ``obs_TC33_fpr.m`` and ``timeDelay.m``: case
22's three segments and equations (`ref_fvsysid_fpr`), now estimating the
six input biases, the scale factors and offsets of alpha and beta, all 21
initial states and time delays in alpha, beta and psi (the file's comments
say phi, theta, psi; its observation function delays alpha, beta, psi).
``timeDelay.m`` interpolates linearly between the current and the previous
sample, ``y(k) - (tau / dt) (y(k) - y(k-1))`` (its sample offset comes from
``isinteger`` of a double, always false, so a delay beyond one sample is
extrapolated from those two), and the first sample of each segment is not
delayed. FVSysID saved no result: its method runs here in numpy
(`_fvsysid.ml_oem` with that delay); the SIDPAC columns hold its
estimates and Cramer-Rao standard deviations. Scale factors are shown as
``k = f - 1``.

Ours: ``identify(time_delays=...)`` delays controls only, and
``check_compatibility``'s ``tau_alpha``, ``tau_beta``, ``tau_psi`` are these
delays (rows ``cc123``); the main rows use a user
``aeroid.Model`` carries the delays to first order, ``y - tau y'`` with
``y'`` from the kinematics, fitted by ``aeroid.identify`` to the three
records with every initial state estimated. Rows ``fo`` (variants): FVSysID's
method with the delays to first order as ours, against our white fit. Rows
``cc123`` (variants): ``check_compatibility`` on the three records together
(shared sensor errors and delays, each record's initial state estimated) with
the case's lever arms and flank-angle beta (`ref_fvsysid_fpr.CC_OPTIONS`).
"""

from __future__ import annotations

import pathlib
import sys
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid as F
import _sidpac as S
import ref_fvsysid_fpr as C

CASE = "fvsysid_fpr_delay"
SOURCE = "fvsysid"
NAMES = (*C.BIASES, "k_alpha", "b_alpha", "k_beta", "b_beta", "tau_alpha", "tau_beta", "tau_psi")
DELAYED = {"tau_alpha": 1, "tau_beta": 2, "tau_psi": 5}  # output columns


def _air(p: dict[str, Any]) -> dict[str, Any]:
    """Case 22's air-data parameter names from ours (``f = 1 + k``)."""
    return {
        **p,
        "f_al": 1.0 + p["k_alpha"],
        "b_al": p["b_alpha"],
        "f_be": 1.0 + p["k_beta"],
        "b_be": p["b_beta"],
    }


def interpolated(y: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``timeDelay.m`` on one segment's outputs (n, Ny, K) for K parameter columns."""
    out = y.copy()
    for name, j in DELAYED.items():
        a = p[NAMES.index(name)][None, :] / C.DT
        out[1:, j] = (1.0 - a) * y[1:, j] + a * y[:-1, j]
    return out


def first_order(x: Any, c: Any, p: dict[str, Any]) -> list[Any]:
    """Case 22's outputs with alpha, beta, psi delayed to first order, ``y - tau y'``."""
    q = _air(p)
    y = C.sensors(x, c, q)
    du, dv, dw, _, _, dpsi, _ = C.kinematics(x, c, q)
    P, Q, R = c[3] - q["b_p"], c[4] - q["b_q"], c[5] - q["b_r"]
    pd, qd, rd = c[6], c[7], c[8]
    xb, yb, zb = C.BOOM
    unb, vnb, wnb = x[0] - R * yb + Q * zb, x[1] - P * zb + R * xb, x[2] - Q * xb + P * yb
    dun, dvn, dwn = du - rd * yb + qd * zb, dv - pd * zb + rd * xb, dw - qd * xb + pd * yb
    dal = (unb * dwn - wnb * dun) / (unb * unb + wnb * wnb)
    dbe = (unb * dvn - vnb * dun) / (unb * unb + vnb * vnb)
    y[1] = y[1] - p["tau_alpha"] * q["f_al"] * dal
    y[2] = y[2] - p["tau_beta"] * q["f_be"] * dbe
    y[5] = y[5] - p["tau_psi"] * dpsi
    return y


def _eq(fn: Any) -> F.Fn:
    def eq(x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.stack(fn(x, u, dict(zip(NAMES, p, strict=True))))

    return eq


def port(segs: list[Any], x0: np.ndarray, obs: Any, post: Any) -> F.OemResult:
    """FVSysID's fit of case 33 (every parameter and initial state free)."""
    return F.ml_oem(
        _eq(lambda x, c, p: C.kinematics(x, c, _air(p))),
        _eq(obs),
        x0,
        [u for _, _, u in segs],
        [z for _, z, _ in segs],
        C.DT,
        np.zeros(len(NAMES)),
        free_x0=np.ones(x0.shape, bool),
        post=post,
        names=NAMES,
    )


def model(start: dict[str, float]) -> Any:
    import aeroid

    return aeroid.Model(
        states=list(C.STATES),
        controls=list(C.CONTROLS),
        parameters=start,
        dynamics=lambda t, x, u, p: np.stack(C.kinematics(x, u, _air(p))),
        outputs=list(C.OUTPUTS),
        measurement=lambda t, x, u, p: np.stack(first_order(x, u, p)),
        name="attas_fpr_delay",
    )


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    segs = C.segments(folder)
    x0 = C.initial_states(segs)
    fv = port(segs, x0, lambda x, c, p: C.sensors(x, c, _air(p)), interpolated)
    # the same method with the delays to first order, as ours carries them
    fo = port(segs, x0, first_order, None)
    crb = fv.stderr
    start = dict.fromkeys(NAMES, 0.0)
    m = model(start)
    opts: dict[str, Any] = {
        "x0": [dict(zip(C.STATES, x, strict=True)) for x in x0],
        "estimate_x0": True,
    }
    data = C.flights(segs)
    with S.Timer() as tm:
        res = aeroid.identify(m, data, start, **opts)
    white = aeroid.identify(m, data, start, error_bars="white", **opts)
    resid = [S.output_residuals(res, C.OUTPUTS, k) for k in range(len(segs))]
    fitted = [z - r for (_, z, _), r in zip(segs, resid, strict=True)]
    x0_names = [f"x0[{k}].{s}" for k in range(len(segs)) for s in C.STATES]

    def estimates(r: Any) -> dict[str, float]:
        out = dict(r.parameters)
        out.update(
            {f"x0[{k}].{s}": v for k, m0 in enumerate(r.initial_states) for s, v in m0.items()}
        )
        return out

    def refit(zs: list[np.ndarray]) -> dict[str, float]:
        o = {**opts, "x0": [dict(m0) for m0 in res.initial_states]}
        r = aeroid.identify(m, C.flights(segs, zs), dict(res.parameters), error_bars="white", **o)
        return estimates(r)

    mcs = F.segment_monte_carlo(refit, fitted, resid, mc, seed)
    ours, ours_w = estimates(res), estimates(white)
    se = {**res.stderr, **res.extra_stderr}
    se_w = {**white.stderr, **white.extra_stderr}
    theirs = dict(zip(NAMES, fv.p, strict=True))
    theirs.update({n: float(v) for n, v in zip(x0_names, fv.x0.ravel(), strict=True)})
    fv_names = {f"x0[{k}].{j}": f"x0[{k}].{s}" for k in range(3) for j, s in enumerate(C.STATES)}
    crb = {fv_names.get(n, n): v for n, v in crb.items()}
    note = (
        "FVSysID saved no result for case 33: ml_oem2 with timeDelay's interpolation runs "
        f"in numpy here ({fv.iterations} iterations); ours: identify on a user Model, "
        "delays to first order in the measurement (identify delays controls only; "
        "check_compatibility on the three records: rows cc123)"
    )
    rows = []
    for n in (*NAMES, *x0_names):
        fig = (theirs[n], crb[n])
        rows.append(
            F.row(CASE, n, *fig, ours[n], se[n], mc_se=mcs.get(n), seconds=tm.seconds, note=note)
        )
        rows.append(
            F.row(CASE, f"white:{n}", *fig, ours_w[n], se_w[n], mc_se=mcs.get(n), variant=True)
        )
    rows += [
        F.row(CASE, f"fo:{n}", fo.p[i], fo.se[i], ours_w[n], se_w[n], variant=True)
        for i, n in enumerate(NAMES)
    ]
    # check_compatibility on the three records together: the case's lever arms,
    # flank-angle beta and delays (shifted until the remaining shift is under a
    # twentieth of a sample, not interpolated linearly), every initial state estimated
    with S.Timer() as tm_cc:
        cc = aeroid.check_compatibility(
            [C._cc_record(*seg) for seg in segs],
            estimate=list(NAMES),
            x0=[dict(zip(C.STATES, x, strict=True)) for x in x0],
            gravity=C.G,
            **C.CC_OPTIONS,
        )
    cc_est = dict(cc[0].parameters)
    cc_se = dict(cc[0].stderr)
    for k, r in enumerate(cc):
        cc_est.update({f"x0[{k}].{s}": v for s, v in r.initial_states.items()})
        cc_se.update({f"x0[{k}].{s}": v for s, v in r.initial_state_stderr.items()})
    rows += [
        F.row(
            CASE,
            f"cc123:{n}",
            theirs[n],
            crb[n],
            cc_est[n],
            cc_se[n],
            seconds=tm_cc.seconds,
            variant=True,
        )
        for n in (*NAMES, *x0_names)
        if n in cc_est
    ]
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source=SOURCE))
