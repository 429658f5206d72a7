"""Benchmark: a textbook nonlinear longitudinal model (run as a script).

    python tests/benchmarks/bench_nonlinear.py

The model (stability axes): states V, alpha, theta, q; controls elevator and
thrust; outputs V, alpha, theta, q, q_dot, ax, az with the accelerations from
the aerodynamic coefficients

    CD = CD0 + CD_alpha alpha + CD_alpha2 alpha^2
    CL = CL0 + CL_alpha alpha + CL_q q cbar/2V + CL_de de
    Cm = Cm0 + Cm_alpha alpha + Cm_q q cbar/2V + Cm_de de

(11 non-dimensional coefficients), simulated at 10 Hz for 60 s (601 samples)
with measurement noise and biases on ax and az (estimated).

Each case runs in a fresh process with the default environment (no BLAS
pinning); the first call and the median of the warm calls are printed:

* ``aeroid.identify`` (output error, compiled RK4 with exact forward-mode
  sensitivities); target <= 0.3 s warm and >= 15x a plain numpy Gauss-Newton
  (one RK4 step per sample, finite-difference Jacobian by re-simulating per
  parameter) timed in the same process;
* one nonlinear filter pass (`filter_states`, EKF) on the same model with
  process noise; target <= 0.1 s.

The machine may be shared: the figures are medians and still noisy.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

RHO, S, CBAR, MASS, IYY, G = 1.225, 16.2, 1.5, 1100.0, 1800.0, 9.81
TRUTH = {
    "CD0": 0.03,
    "CD_alpha": 0.25,
    "CD_alpha2": 1.2,
    "CL0": 0.25,
    "CL_alpha": 4.8,
    "CL_q": 7.0,
    "CL_de": 0.4,
    "Cm0": 0.02,
    "Cm_alpha": -0.7,
    "Cm_q": -12.0,
    "Cm_de": -1.1,
}
NAMES = list(TRUTH)
OUTPUTS = ["V", "alpha", "theta", "q", "qdot", "ax", "az"]
SIGMA = np.array([0.2, 0.002, 0.002, 0.003, 0.01, 0.05, 0.1])
BIAS = {"ax": 0.1, "az": -0.2}
X0 = np.array([40.0, 0.06, 0.06, 0.0])
REPEATS = 5
WARM_UP_PASSES = 6


def _coefficients(x: Any, u: Any, p: Any) -> Any:
    V, alpha, _theta, q = x
    de = u[0]
    qbar = 0.5 * RHO * V**2
    qh = q * CBAR / (2.0 * V)
    CD = p["CD0"] + p["CD_alpha"] * alpha + p["CD_alpha2"] * alpha**2
    CL = p["CL0"] + p["CL_alpha"] * alpha + p["CL_q"] * qh + p["CL_de"] * de
    Cm = p["Cm0"] + p["Cm_alpha"] * alpha + p["Cm_q"] * qh + p["Cm_de"] * de
    return qbar, CD, CL, Cm


def dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    V, alpha, theta, q = x
    qbar, CD, CL, Cm = _coefficients(x, u, p)
    thrust = u[1]
    v_dot = (thrust * np.cos(alpha) - qbar * S * CD) / MASS - G * np.sin(theta - alpha)
    a_dot = (
        q + (-thrust * np.sin(alpha) - qbar * S * CL) / (MASS * V) + G * np.cos(theta - alpha) / V
    )
    return np.array([v_dot, a_dot, q, qbar * S * CBAR * Cm / IYY])


def measurement(t: Any, x: Any, u: Any, p: Any) -> Any:
    V, alpha, theta, q = x
    qbar, CD, CL, Cm = _coefficients(x, u, p)
    ax = (qbar * S * (CL * np.sin(alpha) - CD * np.cos(alpha)) + u[1]) / MASS
    az = qbar * S * (-CL * np.cos(alpha) - CD * np.sin(alpha)) / MASS
    return np.array([V, alpha, theta, q, qbar * S * CBAR * Cm / IYY, ax, az])


def controls(t: np.ndarray) -> np.ndarray:
    de = (
        -0.05
        + 0.02 * np.sign(np.sin(2 * np.pi * t / 3.0)) * ((t > 2.0) & (t < 14.0))
        + 0.02 * np.sign(np.sin(2 * np.pi * t / 1.5)) * ((t > 30.0) & (t < 40.0))
    )
    thrust = 2200.0 + 300.0 * ((t > 20.0) & (t < 26.0))
    return np.stack([de, thrust], axis=1)


def make_model() -> Any:
    import aeroid

    return aeroid.Model(
        ["V", "alpha", "theta", "q"],
        ["de", "thrust"],
        dict(TRUTH),
        dynamics,
        outputs=OUTPUTS,
        measurement=measurement,
        name="longitudinal",
    )


def make_data(model: Any, seed: int = 0) -> Any:
    import aeroid

    t = np.arange(601) * 0.1
    u = controls(t)
    sim = model.simulate(t, {"de": u[:, 0], "thrust": u[:, 1]}, X0)
    rng = np.random.default_rng(seed)
    y = sim.outputs + rng.standard_normal(sim.outputs.shape) * SIGMA
    for k, b in BIAS.items():
        y[:, OUTPUTS.index(k)] += b
    channels = {n: y[:, j] for j, n in enumerate(OUTPUTS)}
    channels.update(de=u[:, 0], thrust=u[:, 1])
    return aeroid.FlightData(time=t, channels=channels)


GUESS = {k: 1.2 * v for k, v in TRUTH.items()}


# -- the plain numpy reference --------------------------------------------------------------


def plain_gauss_newton(data: Any, max_iterations: int = 30) -> tuple[np.ndarray, int]:
    """Output error the straightforward way: one RK4 step per sample, a forward-difference
    Jacobian by re-simulating once per parameter, Gauss-Newton with the noise covariance
    estimated from the residuals. Returns (parameters + biases, iterations)."""
    t = data.time
    u = data.array(["de", "thrust"])
    z = data.array(OUTPUTS)
    x0 = np.array([z[0, 0], z[0, 1], z[0, 2], z[0, 3]])
    n_p = len(NAMES)
    ib = [OUTPUTS.index(k) for k in BIAS]

    def simulate(theta: np.ndarray) -> np.ndarray:
        p = dict(zip(NAMES, theta[:n_p], strict=True))
        xs = np.empty((t.size, 4))
        x = x0.copy()
        xs[0] = x
        for k in range(t.size - 1):
            h = t[k + 1] - t[k]
            um = 0.5 * (u[k] + u[k + 1])
            k1 = dynamics(t[k], x, u[k], p)
            k2 = dynamics(t[k] + h / 2, x + h / 2 * k1, um, p)
            k3 = dynamics(t[k] + h / 2, x + h / 2 * k2, um, p)
            k4 = dynamics(t[k + 1], x + h * k3, u[k + 1], p)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            xs[k + 1] = x
        y = measurement(t, xs.T, u.T, p).T
        y[:, ib] += theta[n_p:]
        return np.asarray(y)

    theta = np.concatenate([[GUESS[k] for k in NAMES], np.zeros(len(ib))])
    y = simulate(theta)
    cost = np.inf
    iterations = 0
    for _ in range(max_iterations):
        iterations += 1
        v = z - y
        r = np.mean(v**2, axis=0)
        new_cost = 0.5 * t.size * float(np.sum(np.log(r)))
        if abs(cost - new_cost) < 1e-8 * abs(new_cost):
            break
        cost = new_cost
        jac = np.empty((t.size, len(OUTPUTS), theta.size))
        for j in range(theta.size):
            d = 1e-6 * max(abs(theta[j]), 1e-3)
            th = theta.copy()
            th[j] += d
            jac[:, :, j] = (simulate(th) - y) / d
        w = jac / np.sqrt(r)[None, :, None]
        a = w.reshape(-1, theta.size)
        b = (v / np.sqrt(r)).reshape(-1)
        theta = theta + np.linalg.lstsq(a, b, rcond=None)[0]
        y = simulate(theta)
    return theta, iterations


# -- cases (each in its own process) -------------------------------------------------------------


def _identify(model: Any, data: Any, **options: Any) -> Any:
    import aeroid

    return aeroid.identify(model, data, GUESS, estimate_bias=list(BIAS), **options)


def case_identify() -> None:
    t0 = time.perf_counter()
    import aeroid  # noqa: F401

    model = make_model()
    data = make_data(model)
    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = _identify(model, data)
    first = time.perf_counter() - t0
    warm = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        res = _identify(model, data)
        warm.append(time.perf_counter() - t0)
    # Like for like: the same one RK4 step per sample as the plain reference (the
    # default substeps follow the dynamics' stiffness: 8 per sample here).
    one_step = {"simulate_options": {"substeps": 1}}
    _identify(model, data, **one_step)
    warm1 = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        _identify(model, data, **one_step)
        warm1.append(time.perf_counter() - t0)
    plain = []
    for _ in range(3):
        t0 = time.perf_counter()
        theta, iters = plain_gauss_newton(data)
        plain.append(time.perf_counter() - t0)
    w, pl = float(np.median(warm)), float(np.median(plain))
    worst = max(abs(res.parameters[k] - TRUTH[k]) / res.stderr[k] for k in NAMES)
    agree = max(abs(res.parameters[k] - theta[j]) / res.stderr[k] for j, k in enumerate(NAMES))
    print(f"  import aeroid + model + data          {t_import:8.3f} s")
    print(
        f"  identify, first call                  {first:8.3f} s   ({res.n_iterations} iterations)"
    )
    print(f"  identify, warm (median of {REPEATS})         {w:8.3f} s   target <= 0.300 s")
    print(f"  plain numpy Gauss-Newton (median of 3) {pl:8.3f} s   ({iters} iterations)")
    print(f"  speed-up over plain numpy              {pl / w:8.1f} x   target >= 15 x")
    w1 = float(np.median(warm1))
    print(f"  identify, 1 RK4 step/sample, warm      {w1:8.3f} s")
    print(f"  speed-up, same integration as plain GN {pl / w1:8.1f} x   target >= 15 x")
    print(f"  largest |estimate - truth| / stderr    {worst:8.2f}")
    print(f"  largest |aeroid - plain GN| / stderr   {agree:8.2g}  (plain GN: 1 RK4 step/sample)")


def case_filter() -> None:
    t0 = time.perf_counter()
    import aeroid

    model = make_model()
    data = make_data(model, seed=1)
    t_import = time.perf_counter() - t0
    process = {"V": 1e-4, "alpha": 1e-6, "theta": 1e-8, "q": 1e-6}
    meas = {k: float(s**2) for k, s in zip(OUTPUTS, SIGMA, strict=True)}
    fit_outputs = ["V", "alpha", "theta", "q", "qdot"]

    def run() -> Any:
        return aeroid.filter_states(
            model,
            data,
            TRUTH,
            process_noise=process,
            measurement_noise={k: meas[k] for k in fit_outputs},
            outputs=fit_outputs,
            x0=dict(zip(model.states, X0, strict=True)),
        )

    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0
    # A model compiles once it has spent about a compilation's worth of numpy passes:
    # the passes until then are timed apart from the warm (compiled) ones.
    ramp = []
    for _ in range(WARM_UP_PASSES):
        t0 = time.perf_counter()
        run()
        ramp.append(time.perf_counter() - t0)
    warm = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        run()
        warm.append(time.perf_counter() - t0)
    print(f"  import aeroid + model + data          {t_import:8.3f} s")
    print(f"  filter_states (EKF + smoother), first {first:8.3f} s")
    print("  next passes (numpy, then the compile) " + " ".join(f"{x:.3f}" for x in ramp) + " s")
    print(
        f"  filter_states, warm (median of {REPEATS})    {float(np.median(warm)):8.3f} s   "
        "target <= 0.100 s"
    )


CASES = {"identify": case_identify, "filter": case_filter}


def main() -> None:
    if len(sys.argv) > 1:
        CASES[sys.argv[1]]()
        return
    here = Path(__file__).resolve()
    for name in CASES:
        print(f"{name} (fresh process)")
        sys.stdout.flush()
        subprocess.run([sys.executable, str(here), name], check=True)


if __name__ == "__main__":
    main()
