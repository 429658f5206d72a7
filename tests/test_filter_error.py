"""Filter-error identification: seeded recovery of known truths, with and without turbulence."""

from __future__ import annotations

import math
import warnings
from typing import ClassVar

import numpy as np
import pytest
import scipy.linalg

import aeroid
from aeroid import FlightData, IdentificationError
from aeroid.estimation._filter_error import identify_filter_error
from aeroid.models import catalog

NOISE = {"alpha": 0.005**2, "q": 0.01**2}
NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = catalog.SHORT_PERIOD_TRUTH


def _fe(model, datas, **kw):
    args = dict(
        outputs=None,
        process_noise=None,
        measurement_noise=None,
        filter_options=None,
        estimate_process_noise=False,
        x0=None,
        max_iterations=50,
        tolerance=1e-6,
    )
    args.update(kw)
    return identify_filter_error(model, datas, NAMES, dict(model.parameters), **args)


def _turbulent_flight(seed: int, s_q: float, duration: float = 10.0) -> FlightData:
    """Truth-case flight with white process noise (PSD s_q) on q, sampled exactly
    (superposition of the noise-free response and the discretised stochastic part)."""
    clean = catalog.short_period_flight(noise={}, duration=duration)
    t = clean.time
    A = np.array([[TRUTH["Z_alpha"], 1.0], [TRUTH["M_alpha"], TRUTH["M_q"]]])
    M = np.zeros((4, 4))
    M[:2, :2] = -A
    M[:2, 2:] = np.diag([0.0, s_q])
    M[2:, 2:] = A.T
    E = scipy.linalg.expm(M * (t[1] - t[0]))
    phi = E[2:, 2:].T
    qd = phi @ E[:2, 2:]
    lq = np.linalg.cholesky(0.5 * (qd + qd.T))
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((t.size, 2)) @ lq.T
    xs = np.zeros((t.size, 2))
    for k in range(1, t.size):
        xs[k] = phi @ xs[k - 1] + w[k]
    y = np.column_stack([clean["alpha"], clean["q"]]) + xs
    y = y + rng.standard_normal((t.size, 2)) * np.array([0.005, 0.01])
    return FlightData(t, {"elevator": clean["elevator"], "alpha": y[:, 0], "q": y[:, 1]})


def test_truth_case_recovered_with_unit_sigma2(sp_model, sp_noisy):
    res = _fe(
        sp_model, [sp_noisy], process_noise={"alpha": 1e-8, "q": 1e-8}, measurement_noise=NOISE
    )
    assert res.success and res.method == "filter_error" and res.error_bars == "white"
    for n in NAMES:
        assert res.parameters[n] == pytest.approx(TRUTH[n], rel=0.05)
        assert abs(res.parameters[n] - TRUTH[n]) < 3 * res.stderr[n]
    # sigma2 = mean of chi2_2 / 2 over n = 500 samples: standard deviation sqrt(1/n)
    n = sp_noisy.time.size - 1
    assert abs(res.sigma2 - 1) < 4 * math.sqrt(1 / n)
    np.testing.assert_array_equal(res.covariance, res.covariance_white)
    assert res.residuals[0].shape == (sp_noisy.time.size, 2)
    assert res.noise_covariance == pytest.approx(np.diag([0.005**2, 0.01**2]))
    assert dict(res.process_noise) == {"alpha": 1e-8, "q": 1e-8}
    assert res.initial_states[0]["alpha"] == sp_noisy["alpha"][0]
    assert res.fixed == {} and res.identifiable and res.model_name == "short_period"
    assert res.covariance.shape == (4, 4) and np.all(np.linalg.eigvalsh(res.covariance) > 0)
    assert "filter error" in res.summary() and "sigma2" in res.summary()


def test_fixed_parameters_and_noise_estimated_from_innovations(sp_model, sp_noisy):
    names = ["M_q", "M_delta"]
    res = identify_filter_error(
        sp_model,
        [sp_noisy],
        names,
        {**TRUTH, "M_q": -1.5, "M_delta": -6.0},
        outputs=None,
        process_noise=None,
        measurement_noise=None,
        filter_options=None,
        estimate_process_noise=False,
        x0=None,
        max_iterations=50,
        tolerance=1e-8,
    )
    assert res.parameter_names == tuple(names)
    assert res.fixed == {"Z_alpha": TRUTH["Z_alpha"], "M_alpha": TRUTH["M_alpha"]}
    for n in names:
        assert abs(res.parameters[n] - TRUTH[n]) < 3 * res.stderr[n]
    # ML variances: relative standard error sqrt(2/n) with n = 500
    var = np.diag(res.noise_covariance)
    assert var == pytest.approx([0.005**2, 0.01**2], rel=4 * math.sqrt(2 / 500))
    assert res.sigma2 == pytest.approx(1.0, abs=1e-3)  # ML noise makes it 1 by construction
    assert set(res.extra_stderr) == {"measurement_noise.alpha", "measurement_noise.q"}


def test_several_manoeuvres_share_the_parameters(sp_model):
    datas = [catalog.short_period_flight(seed=s) for s in (10, 11)]
    one = _fe(sp_model, datas[:1], process_noise={"q": 1e-8}, measurement_noise=NOISE)
    two = _fe(sp_model, datas, process_noise={"q": 1e-8}, measurement_noise=NOISE)
    assert len(two.residuals) == 2 and len(two.initial_states) == 2
    ratio = np.array([two.stderr[n] / one.stderr[n] for n in NAMES])
    assert np.all((ratio > 0.6) & (ratio < 0.8))  # twice the data: about 1/sqrt(2)


def test_ukf_option_matches_ekf_on_a_linear_model(sp_model, sp_noisy):
    kw = dict(process_noise={"q": 1e-4}, measurement_noise=NOISE)
    a = _fe(sp_model, [sp_noisy], **kw)
    # alpha = 1 keeps the sigma-point weights O(1); the default alpha = 1e-3 weights
    # of order 1e6 amplify rounding in the finite-difference derivatives (rel ~1e-6).
    b = _fe(sp_model, [sp_noisy], filter_options={"method": "ukf", "ukf_alpha": 1.0}, **kw)
    c = _fe(sp_model, [sp_noisy], filter_options={"method": "ukf"}, **kw)
    for n in NAMES:
        assert b.parameters[n] == pytest.approx(a.parameters[n], rel=1e-6)
        assert b.stderr[n] == pytest.approx(a.stderr[n], rel=1e-6)
        assert c.parameters[n] == pytest.approx(a.parameters[n], rel=1e-4)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_turbulence_biases_output_error_but_not_filter_error(sp_model, seed):
    s_q = 3e-3  # PSD of the turbulence on q (rad^2/s^3)
    data = _turbulent_flight(seed, s_q)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", aeroid.IdentifiabilityWarning)
        if hasattr(aeroid, "identify"):
            oe = aeroid.identify(sp_model, data, NAMES)
            oe_se = oe.stderr_white
        else:  # output error as the filter with neither process noise nor initial uncertainty
            oe = _fe(sp_model, [data], filter_options={"P0": np.zeros((2, 2))})
            oe_se = oe.stderr
    fe = _fe(sp_model, [data], process_noise={"q": s_q}, measurement_noise=NOISE)
    z_oe = max(abs(oe.parameters[n] - TRUTH[n]) / oe_se[n] for n in NAMES)
    z_fe = max(abs(fe.parameters[n] - TRUTH[n]) / fe.stderr[n] for n in NAMES)
    assert z_oe > 3.0  # output error: off by more than 3 of its (white-residual) error bars
    assert z_fe < 3.0  # filter error: truth within 3 error bars for every parameter
    assert abs(fe.sigma2 - 1) < 4 * math.sqrt(1 / 500)


def test_process_noise_intensity_estimated(sp_model):
    s_q = 3e-3
    data = _turbulent_flight(5, s_q)
    res = _fe(sp_model, [data], measurement_noise=NOISE, estimate_process_noise=["q"])
    q_hat, q_se = res.process_noise["q"], res.extra_stderr["process_noise.q"]
    assert abs(q_hat - s_q) < 3 * q_se and q_se < 0.3 * s_q
    assert res.process_noise["alpha"] == 0.0
    for n in NAMES:
        assert abs(res.parameters[n] - TRUTH[n]) < 3 * res.stderr[n]


def test_errors(sp_model, sp_noisy):
    class Stepped:
        name = "box"
        controls = ("elevator",)
        outputs = ("q",)
        parameters: ClassVar[dict[str, float]] = {"k": 1.0}

    with pytest.raises(IdentificationError, match="continuous dynamics"):
        _fe(Stepped(), [sp_noisy])
    with pytest.raises(IdentificationError, match=r"valid options are \['method'"):
        _fe(sp_model, [sp_noisy], filter_options={"smoother": True})
    with pytest.raises(IdentificationError, match="not parameters"):
        identify_filter_error(sp_model, [sp_noisy], ["k"], None)
    with pytest.raises(IdentificationError, match="one initial state per manoeuvre"):
        _fe(sp_model, [sp_noisy], x0=[{}, {}])
    with pytest.raises(IdentificationError, match="not states"):
        _fe(sp_model, [sp_noisy], estimate_process_noise=["beta"])
    with pytest.raises(IdentificationError, match="method"):
        _fe(sp_model, [sp_noisy], filter_options={"method": "pf"})
    with pytest.raises(IdentificationError, match="measurement_noise"):
        _fe(sp_model, [sp_noisy], measurement_noise={"alpha": 1e-4})
    # a start the model cannot simulate: the cause, not only "the filter fails"
    with pytest.raises(IdentificationError, match=r"fails at .*: .*state 'alpha' is not finite"):
        aeroid.identify(
            sp_model,
            sp_noisy,
            {"M_alpha": 1e6, "M_q": 1e6},
            method="filter_error",
            process_noise={"alpha": 1e-4, "q": 1e-4},
        )


def test_derivatives_step_back_where_the_forward_member_fails() -> None:
    # a Gaussian innovation model with nu_k = y_k - a t_k, S = exp(s): the forward
    # differences of the one batched pass give the exact gradient to O(h), and an
    # unknown whose forward member fails (a > 0.9999 here) takes the backward one
    from aeroid.estimation._filter_error import _derivatives, _Layout

    t = np.linspace(0.0, 1.0, 50)
    y = 0.8 * t + 0.1 * np.sin(7.0 * t)

    def obj(Z):
        a, s = Z[:, 0], Z[:, 1]
        nu = (y[None] - a[:, None] * t[None])[:, :, None]
        S = np.broadcast_to(np.exp(s)[:, None, None, None], (Z.shape[0], t.size, 1, 1)).copy()
        quad = np.sum(nu[:, 1:, 0] ** 2, axis=1) / np.exp(s)
        cost = 0.5 * (quad + (t.size - 1) * s)
        cost[a > 0.9999] = np.inf
        return cost, quad, [(nu, S, None)]

    layout = _Layout(names=("a",), q_states=(), r_outputs=(0,))
    tt = t[1:]
    for a0 in (0.5, 0.9999):
        z = np.array([a0, math.log(0.02)])
        f, g, fisher, _, _ = _derivatives(obj, z, layout)
        r = y[1:] - a0 * tt
        exact = np.array([-np.sum(r * tt) / 0.02, 0.5 * (tt.size - np.sum(r**2) / 0.02)])
        np.testing.assert_allclose(g, exact, rtol=2e-3, atol=1e-6)
        # Fisher: sum t^2 / S for a, n/2 for the log-variance, no cross term
        np.testing.assert_allclose(
            fisher, np.diag([np.sum(tt**2) / 0.02, 0.5 * tt.size]), rtol=1e-3, atol=1e-6
        )
        assert np.isfinite(f)


def test_a_vanished_process_noise_costs_no_rejected_steps(sp_model, monkeypatch):
    """Turbulence on q only, both states' intensities estimated: alpha's falls towards
    zero, where the likelihood is flat in its logarithm. Held out of the steps once an
    e-fold moves the cost by less than the stopping rule's decrease, every evaluation
    is an accepted step (without the hold, seeds 2 and 3 spend 10 and 5 more on steps
    dozens of e-folds long); the estimates and error bars are those of the fit that
    leaves alpha's noise at zero, and q's intensity is recovered. Started from the
    state equations' residuals, alpha's noise stops where the hold catches it (1e-9
    to 5e-11) rather than at its bound 30 e-folds under the start, and its correlation
    with the parameters does not fade with it (the information's cross terms fall with
    the intensity, its own with the square): seed 4's error bars move by 1.2 %."""
    from aeroid.estimation import _filter_error

    calls = []
    derivatives = _filter_error._derivatives
    monkeypatch.setattr(
        _filter_error, "_derivatives", lambda *a: calls.append(1) or derivatives(*a)
    )
    s_q = 3e-3
    for seed in range(1, 5):
        data = _turbulent_flight(seed, s_q)
        calls.clear()
        both = _fe(sp_model, [data], measurement_noise=NOISE, estimate_process_noise=True)
        assert both.success
        assert len(calls) == both.n_iterations + 1  # the start, then one per step
        assert both.process_noise["alpha"] < 1e-6 * s_q  # six decades under q's
        q_only = _fe(sp_model, [data], measurement_noise=NOISE, estimate_process_noise=["q"])
        for n in NAMES:
            assert abs(both.parameters[n] - q_only.parameters[n]) < 0.01 * q_only.stderr[n]
            assert both.stderr[n] == pytest.approx(q_only.stderr[n], rel=0.02)
        q_hat, q_se = both.process_noise["q"], both.extra_stderr["process_noise.q"]
        assert abs(q_hat - s_q) < 3 * q_se


def test_a_flat_noise_takes_no_step():
    """The held intensity's step is zero, the others' the plain Gauss-Newton step, and
    the whole information rides along for the error bars."""
    from aeroid.estimation._filter_error import _flat_noises_held
    from aeroid.estimation.least_squares import Linearisation, damped_step

    F = np.array([[4.0, 1.0, 1e-5], [1.0, 3.0, 0.0], [1e-5, 0.0, 1e-12]])
    g = np.array([1.0, -2.0, 3e-9])
    point = _flat_noises_held(Linearisation(-1e4, g, F, ("q", "p")), 1, 1e-4)
    assert point.payload[:2] == ("q", "p") and point.payload[2] is F
    # parameter 0 is no noise; noise 1 is well determined (3 >> 2e-3 of 1e4): both move
    delta, _ = damped_step(point, 0.0, np.zeros(3), np.full(3, -np.inf), np.full(3, np.inf))
    assert delta[2] == 0.0
    np.testing.assert_allclose(delta[:2], -np.linalg.solve(F[:2, :2], g[:2]), rtol=1e-12)


def test_information_summed_in_blocks_is_the_whole_record_sum(sp_model, monkeypatch):
    """The information's trace term summed a block of samples at a time (blocks of 7
    leave a remainder) is the sum over the whole record at once, to rounding: the same
    estimates and error bars, the process noise's included (the remainder's samples
    left out move the estimates by 3e-6 of a standard error: it fails)."""
    from aeroid.estimation import _filter_error

    data = _turbulent_flight(2, 1e-3)

    def fit() -> aeroid.IdentificationResult:
        return aeroid.identify(
            sp_model,
            data,
            NAMES,
            method="filter_error",
            measurement_noise=NOISE,
            process_noise={"q": 1e-4},
            estimate_process_noise=["q"],
        )

    monkeypatch.setattr(_filter_error, "_TRACE_BLOCK", 7)
    small = fit()
    monkeypatch.setattr(_filter_error, "_TRACE_BLOCK", 10**6)
    whole = fit()
    for k in NAMES:
        assert abs(small.parameters[k] - whole.parameters[k]) < 1e-6 * whole.stderr[k]
        assert small.stderr[k] == pytest.approx(whole.stderr[k], rel=1e-7)
    assert small.extra_stderr["process_noise.q"] == pytest.approx(
        whole.extra_stderr["process_noise.q"], rel=1e-7
    )


@pytest.mark.parametrize("duration", [10.0, 60.0])
def test_process_noise_start_recovers_a_known_intensity(sp_model, duration):
    """The start of an estimated intensity (what the state equations leave unexplained
    in the measured states, the measurement noise's share removed) lies within the
    factor its record allows: q's white turbulence of known intensity, at the true
    parameters, within three of the window slope's relative standard errors,
    ``2 sqrt(2 L / n) L / (L - 1)`` at the best window ``L = 2 R / (Qc dt)``; alpha,
    free of turbulence, starts far below q (at what the record could just detect)."""
    from aeroid.estimation._identification_start import process_noise_start

    s_q, r_q, dt = 3e-3, NOISE["q"], 0.02
    n = round(duration / dt) + 1
    window = 2 * r_q / (s_q * dt)
    rel = 2 * math.sqrt(2 * window / n) * window / (window - 1)
    for seed in range(1, 6):
        data = _turbulent_flight(seed, s_q, duration)
        start = process_noise_start(sp_model, [data], dict(TRUTH), NOISE, [0, 1])
        assert abs(math.log(start[1] / s_q)) < 3 * rel
        assert start[0] < 0.05 * s_q
    # records pooled: the intensity they share, at least as close as the worse alone
    pair = [_turbulent_flight(seed, s_q, duration) for seed in (7, 8)]
    alone = [process_noise_start(sp_model, [d], dict(TRUTH), NOISE, [1])[1] for d in pair]
    both = process_noise_start(sp_model, pair, dict(TRUTH), NOISE, [1])[1]
    assert min(alone) <= both <= max(alone)


def test_process_noise_start_leaves_out_unmeasured_states(sp_model):
    """A state with no channel of its own gets no start from the residuals (the fit then
    starts it from the simulated states), and the fit still recovers q's intensity."""
    from aeroid.estimation._identification_start import process_noise_start

    data = _turbulent_flight(3, 3e-3)
    only_q = FlightData(data.time, {k: data[k] for k in ("elevator", "q")})
    assert process_noise_start(sp_model, [only_q], dict(TRUTH), NOISE, [0, 1]) == {}
    res = _fe(
        sp_model,
        [only_q],
        outputs=["q"],
        measurement_noise={"q": NOISE["q"]},
        estimate_process_noise=True,
    )
    assert res.success
    assert abs(res.process_noise["q"] - 3e-3) < 3 * res.extra_stderr["process_noise.q"]


@pytest.mark.parametrize("scale", [1.0, 0.01])
def test_without_process_noise_it_lands_on_output_errors_minimum(scale: float) -> None:
    # No process noise and a known start: the Kalman gain is zero, the innovations are
    # the output-error residuals and both likelihoods are one (Jategaonkar ch. 5). The
    # minimum must not move with the sensors' precision (a forward-differenced cost
    # gradient moved it by half a difference step: 7 standard errors at scale 0.01).
    from aeroid.models.aircraft import lateral_linear

    truth = {
        "Y_beta": -0.15,
        "Y_delta_r": 0.03,
        "L_beta": -8.0,
        "L_p": -3.0,
        "L_r": 1.0,
        "L_delta_a": 15.0,
        "L_delta_r": 1.5,
        "N_beta": 3.0,
        "N_p": -0.1,
        "N_r": -0.6,
        "N_delta_a": -0.5,
        "N_delta_r": -2.5,
    }
    outputs = ["beta", "p", "r", "phi"]
    model = lateral_linear(V0=50.0, outputs=outputs)
    t = np.arange(0.0, 20.0 + 0.01, 0.02)
    da = catalog.multisine(t, [0.1, 0.25, 0.45, 0.7, 1.0, 1.4, 1.9], 0.02)
    dr = np.roll(catalog.multisine(t, [0.15, 0.35, 0.55, 0.85, 1.2, 1.65], 0.02), 37)
    sim = model.simulate(t, {"delta_a": da, "delta_r": dr}, parameters=truth)
    rng = np.random.default_rng(22)
    sd = {"beta": 5e-4 * scale, "p": 2e-3 * scale, "r": 1e-3 * scale, "phi": 1e-3 * scale}
    channels = {o: sim.output(o) + sd[o] * rng.standard_normal(t.size) for o in outputs}
    data = FlightData(t, {**channels, "delta_a": da, "delta_r": dr})
    R = {o: s**2 for o, s in sd.items()}
    start = {k: 0.8 * v for k, v in truth.items()}
    none = dict.fromkeys(model.states, 0.0)
    fe = aeroid.identify(
        model,
        data,
        start,
        method="filter_error",
        process_noise=none,
        measurement_noise=R,
        filter_options={"P0": none},
        tolerance=1e-10,
    )
    oe = aeroid.identify(
        model,
        data,
        start,
        estimate_x0=False,
        tolerance=1e-10,
        weights={o: 1.0 / v for o, v in R.items()},
    )
    for k in truth:
        assert abs(fe.parameters[k] - oe.parameters[k]) < 1e-3 * oe.stderr_white[k], k
