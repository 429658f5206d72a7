"""SIDPAC demo ``dca_lon_demo``: longitudinal data compatibility of HARV flight 250h.

``dcmp`` (set up by ``dcmp_psel`` for a longitudinal run) reconstructs the
flight path from the accelerometers and rate gyros (ft/s^2, rad/s) and fits
V, alpha and theta by output error, estimating ax, az and q biases and alpha
and theta scale factors about the initial value, from an initial state held
at the smoothed data, with v, phi and psi replaced by their measurements.
``dca_lon_demo_data.mat`` holds the estimates ``pc``, ``oe``'s covariance
``crbc`` (white: ``oe`` applies no residual-colour correction, and the demo
prints ``sqrt(diag(crbc))``), its fitted outputs ``yc`` and the initial
state ``x0``.

How the saved results were integrated: not by the Adams-Bashforth code
(``adamb3``, RK2 start) that ``dcmp`` calls in V2.0, nor by forward Euler
(with ``pc`` they miss ``yc`` by 0.15 / 0.14 ft/s in V), but by one classical
Runge-Kutta step per sample with the inputs and the measured states held at
the step's first sample, at the constant step ``t1 - t0``. A plain-numpy
transcription of that (`sidpac_outputs`) with SIDPAC's own ``pc`` gives
``dca_lat_demo``'s ``yc`` to rounding (1e-16), and ``dca_lon_demo``'s to
1e-10 over the first 2.8 s, then within 1.2e-3 ft/s in V and 5e-6 rad in
theta. That drift is a defect of the kinematics the lon results were computed
with, not a method: their pitch-attitude rate was ``cos(phi) (q - r sin(phi))``
(a misplaced parenthesis; V2.0's ``dcmp_eqs`` has the textbook ``q cos(phi) -
r sin(phi)``); with that rate the transcription gives ``yc`` to rounding
(1e-13 ft/s).
Output error on that transcription (`sidpac_refit`) returns ``pc`` within
2e-4 SIDPAC sigma, so what is left between ours and SIDPAC's estimates
(the textbook rate) is that defect alone. The lat demo takes theta from its
measurement, so the rate does not enter there. The table's note prints these
figures.

Ours: ``aeroid.check_compatibility`` with that set-up (`SETUP`,
``integration="rk4_hold"``), in ft/s^2 (``gravity=32.174``), on the uniform
time ``k (t1 - t0)``. SIDPAC's biases are
corrections added to the measurement (ours, subtracted, are shown negated).
Both our default error bars (coloured residuals plus the integrated
input-noise share) and our white ones are reported. The Monte Carlo
perturbs the fitted outputs only, as SIDPAC's output-error noise model
does (inputs exact); the measured states come from channels not fitted, so
they stay as flown.

That Monte Carlo cannot see integrated input noise: the biases absorb the
ramp-like share of the random walk it leaves, and the residuals keep no
trace of it. ``--truth N`` (this script or ``ref_demo_dca_lat.py`` run by
itself) runs a known-truth study instead: the fitted model is the truth,
the inputs get white noise at the level our error bars use and the fitted
outputs white noise of 0.3 of their residual rms; N refits give the true
scatter, against which it prints our default bars, the coloured bars of the
residuals alone, the 95 % coverage and what the surrogate Monte Carlo of one
such record claims.
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

CASE = "demo_dca_lon"
FILE = "Demos/dca_lon_demo_data.mat"
INPUTS = ("ax", "ay", "az", "p", "q", "r")
OUTPUTS = ("V", "beta", "alpha", "phi", "theta", "psi")
STATES = ("u", "v", "w", "phi", "theta", "psi")
SETUP = (
    "scale_about='initial', integration='rk4_hold', estimate_x0=False with SIDPAC's x0, uniform t"
)


def uniform_time(t: np.ndarray) -> np.ndarray:
    """SIDPAC's time base: a constant step equal to the first time-tag interval."""
    return np.arange(t.size) * (t[1] - t[0])


def sidpac_outputs(
    u: np.ndarray,
    z: np.ndarray,
    dt: float,
    x0: np.ndarray,
    values: dict[str, float],
    outputs: Sequence[str],
    measured_states: Sequence[str],
    *,
    saved_theta_rate: bool = False,
    gravity: float = 32.174,
    scheme: str = "rk4_hold",
) -> np.ndarray:
    """SIDPAC's ``dcmp`` as its saved results were computed, in plain numpy.

    ``u`` = ax, ay, az, p, q, r; ``z`` = V, beta, alpha, phi, theta, psi;
    ``values`` in our convention (biases subtracted from the measurement,
    output scale factors about the start value). One Runge-Kutta step per
    sample, with the inputs and the measured states held at the step's first
    sample in all four stages; returns the `outputs` columns.
    ``saved_theta_rate``: the pitch-attitude rate as the saved results had it,
    ``cos(phi) (q - r sin(phi))``, instead of ``q cos(phi) - r sin(phi)``.
    ``scheme="adamb3"``: V2.0's ``dcmp`` integration instead (third-order
    Adams-Bashforth on the samples, two midpoint steps with the inputs and
    measured states averaged over the interval to start it).
    """
    V, beta, alpha = z[:, 0], z[:, 1], z[:, 2]
    stand_in = np.column_stack(
        [
            V * np.cos(alpha) * np.cos(beta),
            V * np.sin(beta),
            V * np.sin(alpha) * np.cos(beta),
            z[:, 3],
            z[:, 4],
            z[:, 5],
        ]
    )
    held = [STATES.index(s) for s in measured_states]
    bias = np.array([values.get(f"b_{c}", 0.0) for c in INPUTS])
    rates = u - bias

    def slope_at(x: np.ndarray, uk: np.ndarray, sk: np.ndarray) -> np.ndarray:
        x = x.copy()
        x[held] = sk[held]
        ax, ay, az, p, q, r = uk
        uu, vv, ww, phi, theta, _ = x
        turn = (q * np.sin(phi) + r * np.cos(phi)) / np.cos(theta)
        pitch = q * np.cos(phi) - r * np.sin(phi)
        return np.array(
            [
                r * vv - q * ww - gravity * np.sin(theta) + ax,
                p * ww - r * uu + gravity * np.cos(theta) * np.sin(phi) + ay,
                q * uu - p * vv + gravity * np.cos(theta) * np.cos(phi) + az,
                p + np.sin(theta) * turn,
                np.cos(phi) * (q - r * np.sin(phi)) if saved_theta_rate else pitch,
                turn,
            ]
        )

    def slope(x: np.ndarray, k: int) -> np.ndarray:
        return slope_at(x, rates[k], stand_in[k])

    x = np.empty((u.shape[0], 6))
    x[0] = x0
    if scheme == "adamb3":
        past: list[np.ndarray] = []
        for k in range(u.shape[0] - 1):
            f = slope(x[k], k)
            past = [f, *(past or [f, f])][:3]
            if k < 2:
                mid = x[k] + 0.5 * dt * f
                um, sm = 0.5 * (rates[k] + rates[k + 1]), 0.5 * (stand_in[k] + stand_in[k + 1])
                x[k + 1] = x[k] + dt * slope_at(mid, um, sm)
            else:
                x[k + 1] = x[k] + dt * (23.0 * past[0] - 16.0 * past[1] + 5.0 * past[2]) / 12.0
    elif scheme == "rk4_hold":
        for k in range(u.shape[0] - 1):
            k1 = slope(x[k], k)
            k2 = slope(x[k] + 0.5 * dt * k1, k)
            k3 = slope(x[k] + 0.5 * dt * k2, k)
            k4 = slope(x[k] + dt * k3, k)
            x[k + 1] = x[k] + dt / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)
    else:
        raise ValueError(f"scheme: expected 'rk4_hold' or 'adamb3', got {scheme!r}")
    x[:, held] = stand_in[:, held]
    speed = np.sqrt(np.sum(x[:, :3] ** 2, axis=1))
    true = {
        "V": speed,
        "beta": np.arcsin(x[:, 1] / speed),
        "alpha": np.arctan2(x[:, 2], x[:, 0]),
        "phi": x[:, 3],
        "theta": x[:, 4],
        "psi": x[:, 5],
    }
    cols = []
    for o in outputs:
        y = true[o]
        cols.append((1.0 + values.get(f"k_{o}", 0.0)) * (y - y[0]) + y[0])
    return np.column_stack(cols)


def sidpac_refit(
    u: np.ndarray,
    z: np.ndarray,
    dt: float,
    x0: np.ndarray,
    start: dict[str, float],
    scale: Sequence[float],
    outputs: Sequence[str],
    measured_states: Sequence[str],
    weights: np.ndarray,
) -> dict[str, float]:
    """Output error on `sidpac_outputs` (the saved theta rate): the fitted
    outputs' columns of `z` weighted by `weights` (SIDPAC's final noise
    variances), from `start`, each parameter stepped on its `scale`."""
    from scipy.optimize import least_squares

    names = list(start)
    zf = np.column_stack(
        [z[:, ["V", "beta", "alpha", "phi", "theta", "psi"].index(o)] for o in outputs]
    )

    def residuals(v: np.ndarray) -> np.ndarray:
        y = sidpac_outputs(
            u,
            z,
            dt,
            x0,
            dict(zip(names, v, strict=True)),
            outputs,
            measured_states,
            saved_theta_rate=True,
        )
        return ((y - zf) / np.sqrt(weights)).ravel()

    first = np.array([start[n] for n in names])
    fit = least_squares(residuals, first, x_scale=np.asarray(scale), xtol=1e-12, ftol=1e-14)
    return dict(zip(names, fit.x, strict=True))


def _setup(
    u: np.ndarray,
    z: np.ndarray,
    t: np.ndarray,
    names: Sequence[str],
    x0: np.ndarray,
    outputs: Sequence[str],
    measured_states: Sequence[str],
) -> tuple[Any, dict[str, Any]]:
    import aeroid

    time = uniform_time(t)

    def flight(uu: np.ndarray, zz: np.ndarray) -> Any:
        ch = {n: uu[:, j] for j, n in enumerate(INPUTS)}
        ch.update({n: zz[:, j] for j, n in enumerate(OUTPUTS)})
        return aeroid.FlightData(time=time, channels=ch)

    opts: dict[str, Any] = {
        "estimate": list(names),
        "gravity": 32.174,
        "outputs": list(outputs),
        "measured_states": list(measured_states),
        "estimate_x0": False,
        "x0": {s: float(v) for s, v in zip(STATES, x0, strict=True)},
        "scale_about": "initial",
        "integration": "rk4_hold",
    }
    return flight, opts


def truth_study(
    u: np.ndarray,
    z: np.ndarray,
    t: np.ndarray,
    names: Sequence[str],
    x0: np.ndarray,
    *,
    outputs: Sequence[str],
    measured_states: Sequence[str],
    n: int,
    seed: int = 123,
) -> None:
    """Print the known-truth study described in the module notes (`n` records)."""
    import aeroid
    from aeroid._stats import t_quantile

    flight, opts = _setup(u, z, t, names, x0, outputs, measured_states)
    fit = aeroid.check_compatibility(flight(u, z), **opts)
    level = np.array([fit.input_noise[c] for c in INPUTS])
    fitted = [OUTPUTS.index(o) for o in fit.output_names]
    true_z = z.copy()
    true_z[:, fitted] = fit.reconstructed
    out_sd = 0.3 * np.sqrt(np.mean(np.asarray(fit.residuals) ** 2, axis=0))
    quiet = dict.fromkeys(INPUTS, 0.0)
    rng = np.random.default_rng(seed)
    est, ours, resid_only, hit = [], [], [], []
    record: tuple[np.ndarray, np.ndarray] | None = None
    for _ in range(n):
        uu = u + rng.standard_normal(u.shape) * level
        zz = true_z.copy()
        zz[:, fitted] += rng.standard_normal((t.size, len(fitted))) * out_sd
        record = record or (uu, zz)
        a = aeroid.check_compatibility(flight(uu, zz), input_noise=fit.input_noise, **opts)
        b = aeroid.check_compatibility(flight(uu, zz), input_noise=quiet, **opts)
        q = t_quantile(np.array([a.degrees_of_freedom[k] for k in names]))
        est.append([a.parameters[k] for k in names])
        ours.append([a.stderr[k] for k in names])
        resid_only.append([b.stderr[k] for k in names])
        hit.append(
            [
                abs(a.parameters[k] - fit.parameters[k]) <= q[j] * a.stderr[k]
                for j, k in enumerate(names)
            ]
        )
    assert record is not None
    uu, zz = record
    first = aeroid.check_compatibility(
        flight(uu, zz), input_noise=quiet, error_bars="white", **opts
    )
    model_z = zz.copy()
    model_z[:, fitted] = first.reconstructed

    def refit(zn: np.ndarray) -> dict[str, float]:
        full = zz.copy()
        full[:, fitted] = zn
        r = aeroid.check_compatibility(
            flight(uu, full), input_noise=quiet, error_bars="white", **opts
        )
        return dict(r.parameters)

    resid = np.asarray(first.measured) - np.asarray(first.reconstructed)
    mcs = S.monte_carlo(refit, model_z[:, fitted], resid, 40, seed=0)
    sd = np.std(np.array(est), axis=0, ddof=1)
    print(
        f"known truth: {n} records; input noise {', '.join(f'{c} {v:.3g}' for c, v in fit.input_noise.items())}"
    )
    print(
        f"{'parameter':10s} {'true sd':>10s} {'ours/true':>10s} {'resid/true':>10s} {'cover95':>8s} {'MC/true':>8s}"
    )
    for j, k in enumerate(names):
        print(
            f"{k:10s} {sd[j]:10.3g} {np.mean(np.array(ours)[:, j]) / sd[j]:10.3g} "
            f"{np.mean(np.array(resid_only)[:, j]) / sd[j]:10.3g} {np.mean(np.array(hit)[:, j]):8.2f} "
            f"{mcs.get(k, float('nan')) / sd[j]:8.3g}"
        )


def truth_main(run_truth: Any) -> int:
    """``--truth N``: the known-truth study of a dca case (see the module notes)."""
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--truth", type=int, default=0)
    args = ap.parse_known_args()[0]
    folder = S.data_folder()
    if args.truth <= 0 or folder is None:
        return -1
    run_truth(folder, args.truth)
    return 0


def compat_rows(
    case: str,
    u: np.ndarray,
    z: np.ndarray,
    t: np.ndarray,
    names: Sequence[str],
    pc: np.ndarray,
    crbc: np.ndarray,
    x0: np.ndarray,
    yc: np.ndarray,
    *,
    outputs: Sequence[str],
    measured_states: Sequence[str],
    mc: int,
    seed: int,
) -> list[dict[str, Any]]:
    """``u`` = ax, ay, az, p, q, r; ``z`` = V, beta, alpha, phi, theta, psi (ft,
    rad); ``x0`` = u, v, w, phi, theta, psi and ``yc`` the fitted outputs as
    SIDPAC saved them."""
    import aeroid

    time = uniform_time(t)
    flight_of, opts = _setup(u, z, t, names, x0, outputs, measured_states)

    def flight(zz: np.ndarray) -> Any:
        return flight_of(u, zz)

    with S.Timer() as tm:
        res = aeroid.check_compatibility(flight(z), **opts)
    # SIDPAC's white bars: white residuals, inputs exact (no input-noise share)
    quiet = dict.fromkeys(INPUTS, 0.0)
    white = aeroid.check_compatibility(flight(z), error_bars="white", input_noise=quiet, **opts)
    # the share the Monte Carlo below can see: coloured residuals, inputs exact
    coloured = aeroid.check_compatibility(flight(z), input_noise=quiet, **opts)
    fitted = [OUTPUTS.index(o) for o in res.output_names]
    resid = np.asarray(res.measured) - np.asarray(res.reconstructed)
    model_out = z.copy()
    model_out[:, fitted] = np.asarray(res.reconstructed)

    def refit(zz: np.ndarray) -> dict[str, float]:
        full = z.copy()
        full[:, fitted] = zz
        r = aeroid.check_compatibility(flight(full), error_bars="white", input_noise=quiet, **opts)
        return dict(r.parameters)

    mcs = S.monte_carlo(refit, model_out[:, fitted], resid, mc, seed=seed)
    sw = S.se(crbc)
    theirs = {n: (-1.0 if n.startswith("b_") else 1.0) * float(pc[i]) for i, n in enumerate(names)}
    dt = float(time[1])
    misses = [
        np.max(
            np.abs(
                sidpac_outputs(u, z, dt, x0, theirs, outputs, measured_states, saved_theta_rate=b)
                - yc
            ),
            axis=0,
        )
        for b in (False, True)
    ]
    ours_miss = np.max(np.abs(np.asarray(res.reconstructed) - yc), axis=0)
    rms = np.sqrt(np.mean(resid**2, axis=0))
    weights = np.mean((z[:, [OUTPUTS.index(o) for o in outputs]] - yc) ** 2, axis=0)
    refit = sidpac_refit(u, z, dt, x0, theirs, sw, outputs, measured_states, weights)

    def listed(values: Any, fmt: str = ".2g") -> str:
        return ", ".join(f"{o} {m:{fmt}}" for o, m in zip(outputs, values, strict=True))

    repro = (
        f"SIDPAC's pc through its integration (RK4, inputs held) misses its yc by {listed(misses[0])} "
        f"(with the saved theta rate cos(phi) (q - r sin(phi)): {listed(misses[1])}); "
        f"our fit's reconstruction misses it by {listed(ours_miss / rms)} residual rms; "
        "that method refitted in plain numpy lands within "
        + ", ".join(f"{n} {abs(refit[n] - theirs[n]) / sw[i]:.2g}" for i, n in enumerate(names))
        + " SIDPAC sigma of pc"
    )
    bars = ", ".join(f"{n} {white.stderr[n] / sw[i]:.3g}" for i, n in enumerate(names))
    vs_mc = ", ".join(f"{n} {coloured.stderr[n] / mcs[n]:.3g}" for n in names if mcs.get(n))
    note = (
        f"SIDPAC's set-up: fits {', '.join(res.output_names)}; measured states "
        f"{', '.join(measured_states)}; {SETUP} (dt {time[1]:.6g} s), gravity 32.174; "
        f"{repro}; "
        "SIDPAC bias sign flipped; ours se = default bars (coloured + input noise); "
        f"our white se (inputs exact) / SIDPAC white: {bars}; MC perturbs the fitted outputs only "
        "(SIDPAC's output-error noise model: inputs exact), so it lacks our input-noise share "
        "(a known-truth study, --truth N, shows the share is needed)"
        + (f"; our coloured se (inputs exact) / MC: {vs_mc}" if vs_mc else "")
    )
    rows = []
    for i, n in enumerate(names):
        sign = -1.0 if n.startswith("b_") else 1.0
        r = S.row(
            case,
            n,
            sidpac=sign * pc[i],
            sidpac_se_white=sw[i],
            sidpac_se_corrected=None,
            ours=res.parameters[n],
            ours_se=res.stderr[n],
            mc_se=mcs.get(n),
            seconds=tm.seconds,
            note=note,
        )
        r["ours_se_white"] = float(white.stderr[n])
        r["ours_se_coloured_inputs_exact"] = float(coloured.stderr[n])
        rows.append(r)
    return rows


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    uc, zc = np.asarray(d["uc"], dtype=float), np.asarray(d["zc"], dtype=float)
    return compat_rows(
        CASE,
        uc[:, :6],
        zc,
        S.col(d["t"]),
        ("b_ax", "b_az", "b_q", "k_alpha", "k_theta"),
        S.col(d["pc"]),
        np.asarray(d["crbc"], dtype=float),
        S.col(d["x0"]),
        np.asarray(d["yc"], dtype=float),
        outputs=("V", "alpha", "theta"),
        measured_states=("v", "phi", "psi"),
        mc=mc,
        seed=seed,
    )


def run_truth(folder: pathlib.Path, n: int) -> None:
    (path,) = S.need(folder, FILE)
    d = S.loadmat(path)
    truth_study(
        np.asarray(d["uc"], dtype=float)[:, :6],
        np.asarray(d["zc"], dtype=float),
        S.col(d["t"]),
        ("b_ax", "b_az", "b_q", "k_alpha", "k_theta"),
        S.col(d["x0"]),
        outputs=("V", "alpha", "theta"),
        measured_states=("v", "phi", "psi"),
        n=n,
    )


if __name__ == "__main__":
    if truth_main(run_truth) < 0:
        raise SystemExit(S.main(CASE, run))
