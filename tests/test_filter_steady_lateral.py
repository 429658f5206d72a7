"""The fixed-gain filter error on the nonlinear lateral-directional aircraft model:
seeded flights in turbulence with a pilot's loop closed, known truth.

The wing leveller and yaw damper feed the gust response back into the controls,
so the recorded inputs correlate with the process noise: output error, which
takes the inputs as the only cause of the motion, is then biased in the control
derivatives; the filter error, whose Kalman gain absorbs the gusts, is not.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from _aircraft_data import BASE, LAT, noisy_interval

import aeroid
from aeroid import FlightData
from aeroid.models import catalog
from aeroid.models.aircraft import AircraftConstants, lateral

V0 = 53.6
TERMS = {
    "CY": ("beta", "delta_r"),
    "Cl": ("beta", "p", "r", "delta_a"),
    "Cn": ("beta", "r", "delta_r"),
}
NAMES = ["CY_beta", "Cl_beta", "Cl_p", "Cl_r", "Cl_delta_a", "Cn_beta", "Cn_r", "Cn_delta_r"]
TRUTH = {k: LAT[k] for k in (*NAMES, "CY_delta_r")}
# gusts: continuous white noise on the state derivatives (PSD, state^2/s)
PROCESS = {"beta": 6e-5, "p": 6e-3, "r": 6e-4}
NOISE = {"beta": 0.002**2, "p": 0.005**2, "r": 0.003**2, "phi": 0.003**2}
SEEDS = range(8)


def _model() -> aeroid.Model:
    constants = AircraftConstants(**BASE, Ixz=80.0, rho=1.225)
    return lateral(constants, V0=V0, terms=TERMS, parameters=TRUTH, outputs=list(NOISE))


def _flights(model: aeroid.Model, dt: float = 0.02, duration: float = 15.0) -> list[FlightData]:
    """One flight per seed, simulated together: RK4 on a grid ten times finer with the
    white process noise added per fine step (Euler-Maruyama), a wing leveller and a
    yaw damper acting one sample late (so the recorded controls are linear between
    samples, as the models take them), and white measurement noise."""
    t = np.arange(0.0, duration + dt / 2, dt)
    ref = {
        "delta_a": catalog.doublet(t, start=1.0, width=1.0, amplitude=0.08),
        "delta_r": catalog.doublet(t, start=7.0, width=1.5, amplitude=0.08),
    }
    B = len(SEEDS)
    rngs = [np.random.default_rng(s) for s in SEEDS]
    st = {s: model.states.index(s) for s in model.states}
    ia, ir = model.controls.index("delta_a"), model.controls.index("delta_r")
    u = np.repeat(np.stack([ref[c] for c in model.controls])[:, :, None], B, axis=2)
    q = np.array([PROCESS.get(s, 0.0) for s in model.states])
    sub = 10
    h = dt / sub
    p = dict(model.parameters)
    x = np.zeros((model.n_states, B))
    X = np.empty((t.size, model.n_states, B))
    X[0] = x

    def f(tt: float, xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return np.asarray(model.dynamics(tt, xx, uu, p))

    def noise() -> np.ndarray:
        w = np.stack([r.standard_normal(model.n_states) for r in rngs], axis=1)
        return np.sqrt(q * h)[:, None] * w

    for k in range(t.size - 1):
        # the controls pushed against the Cl_delta_a < 0, Cn_delta_r < 0 moments
        u[ia, k + 1] += x[st["phi"]] + 0.5 * x[st["p"]]
        u[ir, k + 1] += x[st["r"]]
        x = noisy_interval(f, t[k], x, (u[:, k], u[:, k + 1]), sub, h, noise)
        X[k + 1] = x
    out = []
    for i, r in enumerate(rngs):
        channels = {c: u[j, :, i] for j, c in enumerate(model.controls)}
        for s in model.states:
            channels[s] = X[:, st[s], i] + math.sqrt(NOISE[s]) * r.standard_normal(t.size)
        out.append(FlightData(t, channels))
    return out


@pytest.mark.slow
def test_steady_filter_error_recovers_the_lateral_truth_where_output_error_is_biased():
    model = _model()
    start = {k: 0.8 * TRUTH[k] for k in NAMES}
    fe_z, fe_err, oe_err = [], [], []
    for data in _flights(model):
        fe = aeroid.identify(
            model,
            data,
            start,
            method="filter_error",
            process_noise=PROCESS,
            measurement_noise=NOISE,
            filter_options={"gain": "steady"},
        )
        assert fe.success
        fe_z.append([(fe.parameters[k] - TRUTH[k]) / fe.stderr[k] for k in NAMES])
        fe_err.append([fe.parameters[k] / TRUTH[k] - 1 for k in NAMES])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its drift warning: the point of the test
            oe = aeroid.identify(model, data, start, method="output_error")
        oe_err.append([oe.parameters[k] / TRUTH[k] - 1 for k in NAMES])
    z = np.array(fe_z)
    n = z.size  # 64 standardised errors
    # within their error bars: |z| < 1.96 for 95 %, binomial sd sqrt(.95 .05 / 64) = 0.027
    assert np.mean(np.abs(z) < 1.96) >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / n)
    # mean square z is chi2_n / n: sd sqrt(2 / n) = 0.18
    assert np.mean(z**2) < 1 + 3 * math.sqrt(2 / n)
    # no term biased: mean z over 8 seeds has sd 1/sqrt(8) per term
    assert np.all(np.abs(z.mean(axis=0)) < 3.5 / math.sqrt(len(SEEDS)))
    # output error: the aileron's power biased (its mean error against its own
    # scatter over the seeds), the filter error's not
    j = NAMES.index("Cl_delta_a")
    for errs, biased in ((np.array(oe_err)[:, j], True), (np.array(fe_err)[:, j], False)):
        t_stat = errs.mean() / (errs.std(ddof=1) / math.sqrt(errs.size))
        assert bool(abs(t_stat) > 4.0) is biased, (t_stat, errs)


@pytest.mark.slow
def test_the_steady_gain_is_the_default_and_agrees_with_the_time_varying_filter():
    model = _model()
    data = _flights(model)[0]
    start = {k: 0.8 * TRUTH[k] for k in NAMES}
    kw = dict(method="filter_error", process_noise=PROCESS, measurement_noise=NOISE)
    default = aeroid.identify(model, data, start, **kw)
    steady = aeroid.identify(model, data, start, filter_options={"gain": "steady"}, **kw)
    ekf = aeroid.identify(model, data, start, filter_options={"gain": "time_varying"}, **kw)
    # (the same predictor, in numpy or compiled once the model has run enough)
    assert default.parameters == pytest.approx(steady.parameters, rel=1e-6)
    # near the trim the relinearised filter's gain is the steady one after its
    # transient: the estimates differ by a small fraction of their error bars
    for k in NAMES:
        assert abs(steady.parameters[k] - ekf.parameters[k]) < 0.1 * ekf.stderr[k]
        assert steady.stderr[k] == pytest.approx(ekf.stderr[k], rel=0.05)
