"""Biases estimated by the filter error (`identify(method="filter_error", estimate_bias=...)`):
a seeded short-period flight in turbulence whose alpha sensor reads 0.02 rad high and
whose pitch equation carries an unmodelled constant moment (Jategaonkar's BY and BX).

Truth: the model with those biases simulated exactly, plus the exactly discretised
response to white process noise on q, plus white measurement noise. The estimates are
the same as writing the biases as model parameters by hand, they hold the truth within
their bars, and two manoeuvres keep their own.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

import aeroid
from aeroid import FlightData, IdentificationError, identify
from aeroid.models import catalog

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = dict(catalog.SHORT_PERIOD_TRUTH)
NOISE = {"alpha": 0.005**2, "q": 0.01**2}
S_Q = 1e-3  # PSD of the turbulence on q (rad^2/s^3)
START = {"alpha": 0.0, "q": 0.0}
BIASES = {"alpha": "output", "q": "state"}


def _dynamics(t, x, u, p):
    return np.array(
        [
            p["Z_alpha"] * x[0] + x[1],
            p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0] + p["bx_q"],
        ]
    )


def _measurement(t, x, u, p):
    return np.array([x[0] + p["by_alpha"], x[1]])


def _by_hand(parameters) -> aeroid.Model:
    """The short-period model with the biases written as its own parameters."""
    return aeroid.Model(
        states=["alpha", "q"],
        controls=["elevator"],
        parameters=dict(parameters),
        dynamics=_dynamics,
        measurement=_measurement,
        outputs=["alpha", "q"],
        name="short_period",
    )


def _flight(seed: int, by: float, bx: float) -> FlightData:
    t = np.arange(751) / 50.0
    u = catalog.doublet(t, amplitude=0.05) - catalog.doublet(t, start=8.0, amplitude=0.04)
    clean = _by_hand({**TRUTH, "by_alpha": by, "bx_q": bx}).simulate(t, u, method="exact")
    A = np.array([[TRUTH["Z_alpha"], 1.0], [TRUTH["M_alpha"], TRUTH["M_q"]]])
    M = np.zeros((4, 4))
    M[:2, :2] = -A
    M[:2, 2:] = np.diag([0.0, S_Q])
    M[2:, 2:] = A.T
    E = scipy.linalg.expm(M * (t[1] - t[0]))
    phi = E[2:, 2:].T
    qd = phi @ E[:2, 2:]
    lower = np.linalg.cholesky(0.5 * (qd + qd.T))
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((t.size, 2)) @ lower.T
    xs = np.zeros((t.size, 2))
    for k in range(1, t.size):
        xs[k] = phi @ xs[k - 1] + w[k]
    y = np.column_stack([clean.output("alpha"), clean.output("q")]) + xs
    y = y + rng.standard_normal((t.size, 2)) * np.sqrt([NOISE["alpha"], NOISE["q"]])
    return FlightData(t, {"elevator": u, "alpha": y[:, 0], "q": y[:, 1]})


def _fit(model, datas, names, **kw):
    kw.setdefault("estimate_bias", BIASES)
    return identify(
        model,
        datas,
        names,
        method="filter_error",
        process_noise={"q": S_Q},
        measurement_noise=NOISE,
        x0=[START] * (len(datas) if isinstance(datas, list) else 1),
        tolerance=1e-10,
        **kw,
    )


@pytest.fixture(scope="module")
def flight() -> FlightData:
    return _flight(3, by=0.02, bx=0.3)


@pytest.fixture(scope="module")
def fitted(flight):
    return _fit(catalog.short_period(), flight, NAMES)


def test_output_and_state_biases_recovered_within_their_bars(fitted):
    r = fitted
    assert r.success and r.method == "filter_error"
    assert set(r.biases[0]) == {"alpha", "state.q"}
    for key, truth in (("alpha", 0.02), ("state.q", 0.3)):
        name = f"bias[0].{key}"
        # 3 bars: a seeded draw fails this 0.3 % of the time; the bar is a few % of the bias
        assert abs(r.biases[0][key] - truth) < 3 * r.extra_stderr[name]
        assert r.extra_stderr[name] < 0.2 * abs(truth)
    for n in NAMES:
        assert abs(r.parameters[n] - TRUTH[n]) < 3 * r.stderr[n]
    # the result's layout is output error's: parameters, then state and output biases
    assert r.parameter_names == tuple(NAMES) and r.covariance.shape == (4, 4)
    assert r.full_names == (*NAMES, "bias[0].state.q", "bias[0].alpha")
    bars = np.sqrt(np.diag(r.full_covariance))
    expected = [r.stderr[n] for n in NAMES] + [r.extra_stderr[k] for k in r.full_names[4:]]
    np.testing.assert_allclose(bars, expected, rtol=1e-12)
    np.testing.assert_array_equal(r.full_covariance[:4, :4], r.covariance)


def test_bias_bars_cover_at_the_rate_their_sampling_allows():
    # 30 seeded flights: each bias's standardised error has unit variance if its bar is
    # right, so the pooled mean square of the 60 is chi2_60 / 60 (99.9 % band of its root
    # 0.71-1.31), each bias's own chi2_30 / 30 (0.60-1.44), a mean within 3.3 / sqrt(30)
    z = []
    for seed in range(100, 130):
        r = _fit(catalog.short_period(), _flight(seed, by=0.02, bx=0.3), NAMES)
        z.append(
            [
                (r.biases[0]["alpha"] - 0.02) / r.extra_stderr["bias[0].alpha"],
                (r.biases[0]["state.q"] - 0.3) / r.extra_stderr["bias[0].state.q"],
            ]
        )
    z = np.array(z)
    assert 0.71 < math.sqrt(np.mean(z**2)) < 1.31
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((rms > 0.60) & (rms < 1.44))
    assert np.all(np.abs(z.mean(axis=0)) < 3.3 / math.sqrt(30))


def test_same_estimates_as_the_biases_written_as_parameters(flight, fitted):
    start = {**catalog.SHORT_PERIOD_GUESS, "by_alpha": 0.0, "bx_q": 0.0}
    hand = _fit(_by_hand(start), flight, [*NAMES, "by_alpha", "bx_q"], estimate_bias=False)
    pairs = [(n, n) for n in NAMES] + [("by_alpha", "alpha"), ("bx_q", "state.q")]
    for h, b in pairs:
        mine = fitted.parameters[b] if b in NAMES else fitted.biases[0][b]
        bar = fitted.stderr[b] if b in NAMES else fitted.extra_stderr[f"bias[0].{b}"]
        assert mine == pytest.approx(hand.parameters[h], rel=1e-8, abs=1e-8 * bar)
        assert bar == pytest.approx(hand.stderr[h], rel=1e-6)
    assert fitted.cost == pytest.approx(hand.cost, rel=1e-10)


def test_two_manoeuvres_keep_their_own_biases():
    truths = [(0.02, 0.3), (-0.01, -0.2)]
    datas = [_flight(10 + i, by=by, bx=bx) for i, (by, bx) in enumerate(truths)]
    r = _fit(catalog.short_period(), datas, NAMES)
    assert len(r.biases) == 2
    for i, (by, bx) in enumerate(truths):
        for key, truth in (("alpha", by), ("state.q", bx)):
            bar = r.extra_stderr[f"bias[{i}].{key}"]
            assert abs(r.biases[i][key] - truth) < 3 * bar
    assert r.full_names[4:] == (
        "bias[0].state.q",
        "bias[1].state.q",
        "bias[0].alpha",
        "bias[1].alpha",
    )
    for n in NAMES:
        assert abs(r.parameters[n] - TRUTH[n]) < 3 * r.stderr[n]


def test_biases_alone_and_estimate_bias_true():
    # no parameters named: the biases are the only unknowns; True means every output
    flight = _flight(4, by=0.02, bx=0.0)
    r = _fit(catalog.short_period(TRUTH), flight, [], estimate_bias=True)
    assert r.parameter_names == () and set(r.biases[0]) == {"alpha", "q"}
    for key, truth in (("alpha", 0.02), ("q", 0.0)):
        bar = r.extra_stderr[f"bias[0].{key}"]
        assert abs(r.biases[0][key] - truth) < 3 * bar and math.isfinite(bar)
    assert "bias[0].alpha" in r.summary()  # the table shows what was fitted


def test_refusals_unchanged(flight):
    model = catalog.short_period()
    with pytest.raises(IdentificationError, match=r"estimate_x0 applies to method='output_error'"):
        _fit(model, flight, NAMES, estimate_x0=True)
    with pytest.raises(IdentificationError, match=r"estimate_bias\['q'\]: expected 'output'"):
        _fit(model, flight, NAMES, estimate_bias={"q": "bogus"})
    with pytest.raises(IdentificationError, match=r"estimate_bias: 'theta' is not a state"):
        _fit(model, flight, NAMES, estimate_bias={"theta": "state"})
    with pytest.raises(IdentificationError, match="name at least one parameter"):
        _fit(model, flight, [], estimate_bias=[])


@pytest.mark.parametrize("outputs", [["alpha"], []])
def test_the_bias_wrapper_compiles_where_the_model_does(outputs):
    # the nonlinear filters' compiled propagation traces the wrapper with jax.numpy
    pytest.importorskip("jax")
    from aeroid.estimation._state_biases import _with_bias_parameters
    from aeroid.models import compiled

    sp = catalog.short_period()
    model = aeroid.Model(
        states=sp.states,
        controls=sp.controls,
        parameters=dict(sp.parameters),
        dynamics=sp.dynamics,
        name="sp",
        linear=False,
    )
    datas = [catalog.short_period_flight(seed=s) for s in (1, 2)]
    wrapped, marked, _, _ = _with_bias_parameters(model, datas, outputs, ["q"])
    u = marked[1].array(list(wrapped.controls))
    np.testing.assert_array_equal(u[:, 1:], np.tile([0.0, 1.0], (u.shape[0], 1)))
    p = np.array(list(wrapped.parameters.values())) + 0.1
    assert compiled.available(wrapped, datas[1].time, np.array([0.01, 0.02]), u, p)


def test_an_offset_on_a_directly_measured_state_moves_only_its_bias():
    """The filter starts a state read from its own channel where the measurement, with
    the bias, reads that channel: an offset of 0.03 rad added to alpha moves its bias
    by 0.03 and leaves the parameters and the start where they were. (The start read
    the raw channel: a 30-sigma error in the first innovations that moved Z_alpha by
    5 standard errors and M_alpha by 6.)"""
    p0 = {"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -6.0}
    model = catalog.short_period(p0)
    d = catalog.short_period_flight(seed=16, colored=0.9, duration=20.0)
    moved = FlightData(time=d.time, channels={**d.channels, "alpha": d.channels["alpha"] + 0.03})
    kw = dict(
        method="filter_error",
        estimate_bias=["alpha"],
        process_noise={"alpha": 1e-4, "q": 1e-3},
        estimate_process_noise=True,
        tolerance=1e-10,
    )
    a = identify(model, d, list(p0), **kw)
    b = identify(model, moved, list(p0), **kw)
    assert b.biases[0]["alpha"] - a.biases[0]["alpha"] == pytest.approx(0.03, abs=1e-6)
    for k in p0:
        assert b.parameters[k] == pytest.approx(a.parameters[k], abs=1e-3 * a.stderr[k])
    assert b.initial_states[0]["alpha"] == pytest.approx(a.initial_states[0]["alpha"], abs=1e-6)
    # the start is the channel's first value less the bias
    first = float(d.channels["alpha"][0])
    assert a.initial_states[0]["alpha"] == pytest.approx(first - a.biases[0]["alpha"], abs=1e-12)
