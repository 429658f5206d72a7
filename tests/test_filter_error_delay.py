"""Input time delays estimated by the filter error (`identify(method="filter_error",
time_delays=...)`): seeded flights in turbulence whose surfaces act 0.6 and 1.7
samples after their record, on a linear and a nonlinear lateral model.

Truth: each record carries the undelayed surfaces while the vehicle flew
``u(t - tau)`` (interpolated between samples, the models' contract), with white
process noise on the state derivatives and white measurement noise. Over the
seeds the delays' 95 % intervals hold the truth at the rate a binomial count
allows, and their mean standardised error is within its sampling spread.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg
from _aircraft_data import LATERAL_LINEAR as LATERAL
from _aircraft_data import LATERAL_STATES as STATES
from _aircraft_data import noisy_interval
from test_filter_steady_lateral import NAMES, PROCESS, TRUTH
from test_filter_steady_lateral import _model as _steady_lateral_model

import aeroid
from aeroid import FlightData, IdentificationError, identify
from aeroid.estimation import _filter_error as fe
from aeroid.estimation._output_error import shifted_controls
from aeroid.models import catalog
from aeroid.models.aircraft import lateral_linear

DT = 0.02
TAU = {"delta_a": 0.6 * DT, "delta_r": 1.7 * DT}
NOISE = {"beta": 0.002**2, "p": 0.005**2, "r": 0.003**2, "phi": 0.003**2}


def _surfaces(t: np.ndarray) -> np.ndarray:
    da = catalog.multisine(t, [0.2, 0.5, 0.9, 1.4, 2.1], 0.02)
    dr = catalog.doublet(t, start=4.0, width=1.0, amplitude=0.06)
    return np.column_stack([da, dr])


def _record(t: np.ndarray, u: np.ndarray, states: np.ndarray, names, rng) -> FlightData:
    channels = {"delta_a": u[:, 0], "delta_r": u[:, 1]}
    for i, s in enumerate(names):
        channels[s] = states[:, i] + math.sqrt(NOISE[s]) * rng.standard_normal(t.size)
    return FlightData(t, channels)


# -- a linear lateral model: the stochastic part sampled exactly -----------------------

LINEAR_PROCESS = {"beta": 1e-6, "p": 1e-4, "r": 1e-5, "phi": 0.0}


def _linear_flights(seeds: range) -> tuple[aeroid.Model, list[FlightData]]:
    """The deterministic response to the delayed surfaces plus the discretised
    (Van Loan) response to the process noise: both exact at the samples."""
    model = lateral_linear(V0=60.0, parameters=LATERAL, outputs=list(STATES))
    t = np.arange(751) * DT
    u = _surfaces(t)
    late = shifted_controls(t, u, [0, 1], [TAU["delta_a"], TAU["delta_r"]])
    clean = model.simulate(t, late, method="exact")
    p = dict(model.parameters)
    n = model.n_states
    A = np.column_stack([np.asarray(model.dynamics(0.0, e, np.zeros(2), p)) for e in np.eye(n)])
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = np.diag([LINEAR_PROCESS[s] for s in model.states])
    M[n:, n:] = A.T
    E = scipy.linalg.expm(M * DT)
    phi = E[n:, n:].T
    qd = phi @ E[:n, n:]
    lower = np.linalg.cholesky(0.5 * (qd + qd.T))
    flights = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        w = rng.standard_normal((t.size, n)) @ lower.T
        xs = np.zeros((t.size, n))
        for k in range(1, t.size):
            xs[k] = phi @ xs[k - 1] + w[k]
        states = np.column_stack([clean.output(s) for s in STATES]) + xs
        flights.append(_record(t, u, states, STATES, rng))
    return model, flights


def _standardised(results: list[aeroid.IdentificationResult]) -> np.ndarray:
    return np.array(
        [[(r.parameters[f"tau_{c}"] - TAU[c]) / r.stderr[f"tau_{c}"] for c in TAU] for r in results]
    )


def _check_coverage(z: np.ndarray) -> None:
    n = z.size
    # misses of a 95 % interval: binomial(n, 0.05); P(more than 3 of 16) is 0.007
    allowed = 3 if n <= 16 else int(0.05 * n + 3 * math.sqrt(0.05 * 0.95 * n))
    assert np.sum(np.abs(z) > 1.96) <= allowed, z
    # each delay's mean standardised error over the seeds: sd 1/sqrt(seeds)
    assert np.all(np.abs(z.mean(axis=0)) < 3.5 / math.sqrt(z.shape[0])), z


def test_linear_lateral_delays_of_fractional_samples_recovered_over_seeds():
    model, flights = _linear_flights(range(8))
    results = [
        identify(
            model,
            d,
            list(LATERAL),
            method="filter_error",
            process_noise=LINEAR_PROCESS,
            measurement_noise=NOISE,
            x0=np.zeros(4),
            time_delays=list(TAU),
        )
        for d in flights
    ]
    assert all(r.success for r in results)
    for r in results:
        assert r.parameter_names[-2:] == ("tau_delta_a", "tau_delta_r")
        assert r.covariance.shape == (len(LATERAL) + 2,) * 2
        assert set(r.time_delays) == set(TAU)
        assert r.time_delays["delta_a"] == r.parameters["tau_delta_a"]
        assert r.parameter_units["tau_delta_a"] == "s"
        # a delay is no model parameter: the model's merged values leave it out
        assert "tau_delta_a" not in r.all_parameters
        # the error bars resolve a fraction of a sample
        assert 0 < r.stderr["tau_delta_a"] < 0.2 * DT
    _check_coverage(_standardised(results))
    # the model parameters stay unbiased with the delays estimated
    zp = np.array(
        [[(r.parameters[k] - LATERAL[k]) / r.stderr[k] for k in LATERAL] for r in results]
    )
    assert np.mean(np.abs(zp) < 1.96) >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / zp.size)


def test_the_delay_is_what_moves_the_fit():
    # without the delays the aileron's power moves by many of its standard errors
    model, flights = _linear_flights(range(1))
    kw = dict(
        method="filter_error",
        process_noise=LINEAR_PROCESS,
        measurement_noise=NOISE,
        x0=np.zeros(4),
    )
    plain = identify(model, flights[0], list(LATERAL), **kw)
    delayed = identify(model, flights[0], list(LATERAL), time_delays=list(TAU), **kw)
    truth = LATERAL["L_delta_a"]
    assert abs(plain.parameters["L_delta_a"] - truth) > 3 * plain.stderr["L_delta_a"]
    assert abs(delayed.parameters["L_delta_a"] - truth) < 3 * delayed.stderr["L_delta_a"]
    # the likelihood gains what the delays explain
    assert delayed.cost < plain.cost - 10.0


# -- a nonlinear lateral model (the steady-gain tests'): RK4, process noise per fine step


def _nonlinear_flights(seeds: range) -> tuple[aeroid.Model, list[FlightData]]:
    """RK4 on a grid ten times finer, the delayed surfaces linear between their
    samples, the white process noise added per fine step (Euler-Maruyama)."""
    model = _steady_lateral_model()
    t = np.arange(0.0, 15.0 + DT / 2, DT)
    u = 4.0 * _surfaces(t)  # the nonlinear model's surfaces in rad: a few degrees
    cols = [model.controls.index(c) for c in ("delta_a", "delta_r")]
    order = np.zeros((t.size, model.n_controls))
    order[:, cols] = u
    late = shifted_controls(t, order, cols, [TAU["delta_a"], TAU["delta_r"]])
    B = len(seeds)
    rngs = [np.random.default_rng(s) for s in seeds]
    q = np.array([PROCESS.get(s, 0.0) for s in model.states])
    p = dict(model.parameters)
    sub = 10
    h = DT / sub
    x = np.zeros((model.n_states, B))
    X = np.empty((t.size, model.n_states, B))
    X[0] = x

    def f(tt: float, xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return np.asarray(model.dynamics(tt, xx, np.repeat(uu[:, None], B, axis=1), p))

    def noise() -> np.ndarray:
        w = np.stack([r.standard_normal(model.n_states) for r in rngs], axis=1)
        return np.sqrt(q * h)[:, None] * w

    for k in range(t.size - 1):
        X[k + 1] = x = noisy_interval(f, t[k], x, (late[k], late[k + 1]), sub, h, noise)
    names = list(NOISE)
    flights = []
    for i, r in enumerate(rngs):
        states = np.column_stack([X[:, model.states.index(s), i] for s in names])
        flights.append(_record(t, u, states, names, r))
    return model, flights


@pytest.mark.slow
def test_nonlinear_lateral_delays_recovered_over_seeds():
    model, flights = _nonlinear_flights(range(8))
    start = {k: 0.8 * TRUTH[k] for k in NAMES}
    results = [
        identify(
            model,
            d,
            start,
            method="filter_error",
            process_noise=PROCESS,
            measurement_noise=NOISE,
            time_delays=list(TAU),
        )
        for d in flights
    ]
    assert all(r.success for r in results)
    assert all(0 < r.stderr["tau_delta_r"] < DT for r in results)
    _check_coverage(_standardised(results))


def test_nonlinear_lateral_delay_with_estimated_noise():
    # one seed, the process-noise intensities estimated too: the delays sit between the
    # parameters and the noise log-intensities, each reported under its own name
    model, flights = _nonlinear_flights(range(1))
    start = {k: 0.8 * TRUTH[k] for k in NAMES}
    r = identify(
        model,
        flights[0],
        start,
        method="filter_error",
        measurement_noise=NOISE,
        estimate_process_noise=["p", "r"],
        time_delays={"delta_a": 0.0},
    )
    assert r.success and r.parameter_names == (*NAMES, "tau_delta_a")
    est, se = r.parameters["tau_delta_a"], r.stderr["tau_delta_a"]
    assert 0 < se < 0.5 * DT and abs(est - TAU["delta_a"]) < 3.5 * se
    assert set(r.extra_stderr) == {"process_noise.p", "process_noise.r"}
    assert r.process_noise["p"] == pytest.approx(PROCESS["p"], rel=0.5)


# -- the path without delays, and bad input ------------------------------------------


def test_zero_delays_give_the_plain_objective_bit_for_bit():
    # the grouped passes over shifted controls reduce, at zero delay, to the plain pass
    model, flights = _linear_flights(range(1))
    prob, R = fe.build_problem(
        model,
        flights[0],
        outputs=None,
        measurement_noise=NOISE,
        x0=np.zeros(4),
        P0=None,
        substeps=None,
        method="ekf",
        ukf=(1e-3, 2.0, 0.0),
        error=IdentificationError,
    )
    Qc = np.diag([LINEAR_PROCESS[s] for s in model.states])
    names = tuple(LATERAL)
    plain = fe._Layout(names, (), ())
    delayed = replace(plain, delayed=(0, 1), dt=DT)
    z = np.array([LATERAL[k] for k in names])
    Z = np.repeat(z[None], 3, axis=0)
    Z[1, 0] *= 1.01
    Zd = np.column_stack([Z, np.zeros((3, 2))])
    Zd[2, -1] = 0.5 * DT  # a member of its own: two passes, reassembled
    Z[2] = Z[0]
    out = []
    for layout, zz in ((plain, Z), (delayed, Zd)):
        obj = fe._Objective(model, [prob], dict(model.parameters), layout, Qc, R, False, "ekf")
        obj.gain = "steady"
        out.append(obj(zz))
    (c0, q0, per0), (c1, q1, per1) = out
    np.testing.assert_array_equal(c0[:2], c1[:2])
    np.testing.assert_array_equal(q0[:2], q1[:2])
    np.testing.assert_array_equal(per0[0][0][:2], per1[0][0][:2])
    assert c1[2] != c0[2]  # the delayed member's own pass differs


def test_filter_error_delay_errors():
    model, flights = _linear_flights(range(1))
    kw = dict(method="filter_error", process_noise=LINEAR_PROCESS, measurement_noise=NOISE)
    with pytest.raises(IdentificationError, match="not a control"):
        identify(model, flights[0], list(LATERAL), time_delays=["elevator"], **kw)
    with pytest.raises(IdentificationError, match="finite number"):
        identify(model, flights[0], list(LATERAL), time_delays={"delta_a": math.inf}, **kw)
    with pytest.raises(IdentificationError, match="not controls of model"):
        fe.identify_filter_error(
            model,
            flights[0],
            ["L_p"],
            None,
            process_noise=LINEAR_PROCESS,
            measurement_noise=NOISE,
            time_delays={"aileron": 0.0},
        )
    short = FlightData(flights[0].time[:3], {k: v[:3] for k, v in flights[0].channels.items()})
    with pytest.raises(IdentificationError, match="time delays 2"):
        identify(model, short, list(LATERAL), time_delays=list(TAU), **kw)
