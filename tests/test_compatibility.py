"""Data compatibility: seeded recovery of injected sensor errors on a simulated flight."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _compat_flight import BIASES, NOISE, G, simulated_flight, truth
from matplotlib.figure import Figure

import aeroid
from aeroid.errors import ChannelError, DataFormatError, IdentificationError
from aeroid.estimation import compatibility as compat
from aeroid.estimation.compatibility import DEFAULT_ESTIMATE, SENSOR_PARAMETERS, check_compatibility

DURATION, RATE = 12.0, 25.0
INJECTED = {**BIASES, "k_alpha": 0.08, "tau_alpha": 0.05}
ESTIMATE = [*DEFAULT_ESTIMATE, "tau_alpha"]


@pytest.fixture(autouse=True, scope="module")
def _numpy_simulation():
    # The compiled simulation path is checked once, in its own test; here the
    # numpy path keeps the fits free of compilation time.
    try:
        from aeroid.models import compiled as _compiled
    except ImportError:
        yield
        return
    before = _compiled.ENABLED
    _compiled.ENABLED = False
    yield
    _compiled.ENABLED = before


@pytest.fixture(scope="module")
def injected():
    data = simulated_flight(DURATION, RATE, errors=INJECTED, seed=3)
    return data, check_compatibility(data, estimate=ESTIMATE)


@pytest.fixture(scope="module")
def clean():
    data = simulated_flight(DURATION, RATE, seed=4)
    return data, check_compatibility(data, estimate=ESTIMATE)


def test_recovers_injected_biases_scale_factor_and_time_shift(injected):
    _, r = injected
    assert r.success and r.identifiable
    assert r.n_passes >= 2  # the time shift re-interpolates the channel
    assert set(r.parameter_names) == set(INJECTED)
    for name, value in INJECTED.items():
        assert abs(r.parameters[name] - value) < 3 * r.stderr[name], name
        # and the error bars are error bars, not a blanket: each well below the value
        assert r.stderr[name] < 0.2 * abs(value), name


def test_corrected_data_match_the_truth_within_noise(injected):
    data, r = injected
    true = truth(data.time)
    for c in ("p", "q", "r", "ax", "ay", "az", "V", "alpha", "beta"):
        err = r.corrected[c] - true[c]
        raw = data[c] - true[c]
        # the raw channels are off by many noise levels, the corrected ones by one
        assert np.sqrt(np.mean(err**2)) < 1.2 * NOISE[c], c
        assert np.sqrt(np.mean(raw**2)) > 2.5 * NOISE[c] or c in ("phi", "theta"), c
    for c in compat.INPUT_CHANNELS:  # the noise level behind the error bars
        assert abs(r.input_noise[c] / NOISE[c] - 1) < 0.2, c
    # the reconstruction explains the measurements down to their noise
    rms = np.sqrt(np.mean(r.residuals**2, axis=0))
    for j, o in enumerate(r.output_names):
        assert rms[j] < 1.15 * NOISE[o], o


def test_clean_data_are_left_unchanged(clean):
    data, r = clean
    assert r.success
    for name in r.parameter_names:
        assert abs(r.parameters[name]) < 3 * r.stderr[name], name
    for c in data.names:
        change = np.sqrt(np.mean((r.corrected[c] - data[c]) ** 2))
        assert change < 0.3 * NOISE[c], c


# Noisy gyros and accelerometers: their noise, integrated by the kinematics, then
# dominates the gyro-bias uncertainty.
NOISY_INPUTS = {**NOISE, "p": 2e-3, "q": 2e-3, "r": 2e-3, "ax": 0.05, "ay": 0.05, "az": 0.05}
UNSHIFTED = {k: v for k, v in INJECTED.items() if k != "tau_alpha"}


def test_estimates_within_three_sigma_over_seeds():
    # Three seeds with noisy inputs, 30 estimates in all: none beyond 3.5 sigma and at
    # most two beyond 2.5 sigma (0.37 expected for unit-normal z-scores).
    z = []
    for seed in (11, 12, 13):
        data = simulated_flight(10.0, 25.0, errors=UNSHIFTED, noise=NOISY_INPUTS, seed=seed)
        r = check_compatibility(data)
        z += [(r.parameters[n] - INJECTED[n]) / r.stderr[n] for n in r.parameter_names]
    z = np.abs(np.array(z))
    assert z.size == 30
    assert np.all(z < 3.5) and np.sum(z > 2.5) <= 2, z


def test_input_noise_share_makes_the_gyro_error_bars_cover():
    # Output error alone treats the inputs as exact: its gyro-bias error bars are
    # several times too small (this seed: b_r off by 13 of them).
    data = simulated_flight(10.0, 25.0, errors=UNSHIFTED, noise=NOISY_INPUTS, seed=1)
    full = check_compatibility(data)
    bare = check_compatibility(data, input_noise=dict.fromkeys(compat.INPUT_CHANNELS, 0.0))
    names = full.parameter_names
    assert full.parameters == bare.parameters  # only the error bars differ
    z_bare = [abs(bare.parameters[n] - INJECTED[n]) / bare.stderr[n] for n in names]
    z_full = [abs(full.parameters[n] - INJECTED[n]) / full.stderr[n] for n in names]
    assert max(z_bare) > 5.0 and max(z_full) < 3.0, (z_bare, z_full)
    for n in ("b_p", "b_q", "b_r"):
        assert full.stderr[n] > 3.0 * bare.stderr[n], n


def test_input_noise_estimate_from_fourth_differences():
    data = simulated_flight(20.0, 50.0, seed=5)
    sigma = compat._input_noise({c: data[c] for c in compat.INPUT_CHANNELS}, None)
    for c, s in sigma.items():
        # 1000 samples: the robust scale estimate is good to a few per cent
        assert abs(s / NOISE[c] - 1) < 0.12, c


def test_absent_optional_channels_are_not_fitted():
    full = simulated_flight(10.0, 25.0, errors=UNSHIFTED, seed=6)
    data = aeroid.FlightData(full.time, {c: full[c] for c in full.names if c not in ("beta", "h")})
    r = check_compatibility(data)
    assert r.output_names == ("V", "alpha", "phi", "theta", "psi")
    assert "b_beta" not in r.parameter_names  # dropped from the defaults
    for n in r.parameter_names:
        assert abs(r.parameters[n] - INJECTED[n]) < 3 * r.stderr[n], n
    with pytest.raises(ChannelError, match="beta"):
        check_compatibility(data, estimate=["b_p", "b_beta"])


def test_renamed_channels_and_a_known_fixed_error():
    full = simulated_flight(10.0, 25.0, errors={"b_V": 2.0, "b_q": 0.002}, seed=7)
    chans = {("aoa" if c == "alpha" else c): full[c] for c in full.names}
    data = aeroid.FlightData(full.time, chans)
    r = check_compatibility(
        data, channels={"alpha": "aoa", "h": None}, estimate=["b_q"], fixed={"b_V": 2.0}
    )
    assert r.channels["alpha"] == "aoa" and "h" not in r.output_names
    assert abs(r.parameters["b_q"] - 0.002) < 3 * r.stderr["b_q"]
    assert r.fixed["b_V"] == 2.0
    assert np.allclose(r.corrected["V"], data["V"] - 2.0)
    assert "aoa" in r.corrected and "alpha" not in r.corrected


@pytest.mark.filterwarnings("ignore:identify.*:UserWarning")  # the blind fit may not converge
def test_wind_needs_ground_speed_and_is_recovered_with_it():
    wind = (6.0, -4.0, 0.5)
    errors = {"b_p": 0.003, "b_V": 1.0, "b_alpha": 0.02}
    names = ["b_p", "b_q", "b_r", "b_V", "b_alpha", "b_beta", "w_n", "w_e", "w_d"]
    truth_values = {**dict.fromkeys(names, 0.0), **errors, "w_n": 6.0, "w_e": -4.0, "w_d": 0.5}
    data = simulated_flight(12.0, 25.0, errors=errors, wind=wind, gps=True, seed=14)
    r = check_compatibility(data, estimate=names)
    assert r.identifiable and r.output_names[-2:] == ("vn", "ve")
    for n in names:
        assert abs(r.parameters[n] - truth_values[n]) < 3 * r.stderr[n], n
    # a constant wind moves the air velocity as the kinematics move the ground velocity:
    # without ground speed only its vertical part (through the altitude) is seen
    air_only = aeroid.FlightData(
        data.time, {c: data[c] for c in data.names if c[0] != "v"} | {"V": data["V"]}
    )
    with pytest.warns(aeroid.IdentifiabilityWarning, match="w_n"):
        blind = check_compatibility(
            air_only, estimate=["b_p", "w_n", "w_e", "w_d"], max_iterations=5
        )
    assert not blind.identifiable


def test_summary_and_plot(clean):
    _, r = clean
    text = r.summary()
    for name in (*r.parameter_names, "u", "theta", "RMS residual"):
        assert name in text
    fig = r.plot()
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2 * len(r.output_names)
    measured, recon = r.channel("V")
    assert measured.shape == recon.shape == r.time.shape
    with pytest.raises(ChannelError):
        r.channel("nope")
    with pytest.raises((TypeError, ValueError)):
        r.parameters["b_p"] = 1.0  # frozen record
    with pytest.raises(ValueError):
        r.measured[0, 0] = 1.0


# -- the model itself ------------------------------------------------------------------


def _params(batch: int, **values: float) -> dict[str, np.ndarray]:
    p = {n: np.zeros(batch) for n in SENSOR_PARAMETERS}
    p["g"] = np.full(batch, G)
    for name in compat.STATES:  # no state replaced by its measurement
        p[f"m_{name}"] = np.zeros(batch)
    for name in compat.OUTPUT_CHANNELS:  # scale factors about zero
        p[f"y0_{name}"] = np.zeros(batch)
    for k, v in values.items():
        p[k] = np.full(batch, v)
    return p


def test_kinematics_match_the_closed_form_flight():
    t = np.linspace(0.0, 10.0, 7)
    tr = truth(t)
    a, b, V = tr["alpha"], tr["beta"], tr["V"]
    x = np.stack(
        [
            V * np.cos(a) * np.cos(b),
            V * np.sin(b),
            V * np.sin(a) * np.cos(b),
            tr["phi"],
            tr["theta"],
            tr["psi"],
            np.zeros_like(t),
        ]
    )
    c = np.stack([tr[k] for k in compat.INPUT_CHANNELS] + [np.zeros_like(t)] * 7)
    p = _params(t.size)
    xd = compat._kinematics(t, x, c, p)
    eps = 1e-6
    ahead = truth(t + eps)
    behind = truth(t - eps)
    for j, k in ((3, "phi"), (4, "theta"), (5, "psi")):
        assert np.allclose(xd[j], (ahead[k] - behind[k]) / (2 * eps), atol=1e-7)
    assert np.allclose(xd[6], tr["hdot"], atol=1e-10)
    y = compat._sensors(t, x, c, p)
    for j, k in enumerate(("V", "alpha", "beta", "phi", "theta", "psi")):
        assert np.allclose(y[j], tr[k], atol=1e-12)
    # a time shift is the first-order term of y(t - tau)
    tau = 1e-4
    shifted = compat._sensors(t, x, c, _params(t.size, tau_alpha=tau, tau_beta=tau, tau_V=tau))
    back = truth(t - tau)
    for j, k in enumerate(("V", "alpha", "beta")):
        assert np.allclose(shifted[j], back[k], rtol=0, atol=1e-8 * max(1.0, abs(tr[k]).max()))


def test_wind_enters_the_air_data_as_in_earth_axes():
    # level, wings level, heading east, flying at 50 m/s over ground into a 10 m/s east wind
    # with 2 m/s of updraft: 40 m/s airspeed and a small positive alpha
    x = np.array([[50.0], [0.0], [0.0], [0.0], [0.0], [np.pi / 2], [100.0]])
    c = np.zeros((13, 1))
    y = compat._sensors(0.0, x, c, _params(1, w_e=10.0, w_d=-2.0))
    assert np.allclose(y[0], np.hypot(40.0, 2.0))
    assert np.allclose(y[1], np.arctan2(2.0, 40.0))
    assert np.allclose(y[2], 0.0, atol=1e-15)


def test_model_broadcasts_over_a_batch():
    rng = np.random.default_rng(0)
    batch = 5
    x = np.array([45.0, 1.0, 3.0, 0.1, 0.05, 0.2, 1500.0])[:, None] + 0.1 * rng.standard_normal(
        (7, batch)
    )
    c = 0.1 * rng.standard_normal((13, batch))
    p = _params(batch)
    for n in SENSOR_PARAMETERS:
        p[n] = 1e-2 * rng.standard_normal(batch)
    for fun in (compat._kinematics, compat._sensors):
        whole = fun(0.0, x, c, p)
        for b in range(batch):
            one = fun(0.0, x[:, b], c[:, b], {k: float(v[b]) for k, v in p.items()})
            assert np.allclose(whole[:, b], one, rtol=1e-14, atol=0)


@pytest.mark.slow
def test_compiled_simulation_agrees_with_numpy():
    _compiled = pytest.importorskip("aeroid.models.compiled")
    data = simulated_flight(8.0, 25.0, errors=UNSHIFTED, seed=8)
    names = ["b_p", "b_q", "b_az", "b_alpha"]
    # many draws: the numpy path's Monte Carlo input-noise share, good to a few per cent
    plain = check_compatibility(data, estimate=names, n_draws=1000)
    _compiled.ENABLED = True
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a failed compilation must not pass unseen
            # the errors left unestimated drift the residuals: said, and not the point here
            warnings.simplefilter("ignore", aeroid.ResidualDriftWarning)
            fast = check_compatibility(data, estimate=names)
    finally:
        _compiled.ENABLED = False
    for n in names:
        assert abs(fast.parameters[n] - plain.parameters[n]) < 1e-3 * plain.stderr[n], n
        # The input-noise share: exact to first order there, 1000 simulated draws here.
        # It is two thirds of b_p's variance on this record, its estimate scatters by
        # sqrt(2/1000) = 4.5 %, so b_p's error bar by 1.5 %: 6 % is four sigma.
        assert abs(fast.stderr[n] - plain.stderr[n]) < 0.06 * plain.stderr[n], n


# -- bad input -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small():
    return simulated_flight(2.0, 10.0, seed=9)


def test_a_state_measured_or_fitted_needs_its_channel(small):
    no_psi = aeroid.FlightData(small.time, {c: small[c] for c in small.names if c != "psi"})
    with pytest.raises(ChannelError, match="'psi'"):
        check_compatibility(no_psi, measured_states=["psi"])
    with pytest.raises(ChannelError, match="'psi'"):
        check_compatibility(no_psi, outputs=["V", "psi"])
    with pytest.raises(ChannelError, match="b_phi"):
        check_compatibility(small, outputs=["V", "alpha", "theta"], estimate=["b_phi"])


def test_missing_required_channel_is_named(small):
    data = aeroid.FlightData(small.time, {c: small[c] for c in small.names if c != "q"})
    with pytest.raises(ChannelError, match="'q'"):
        check_compatibility(data)
    with pytest.raises(ChannelError, match="'gyro_x'"):
        check_compatibility(small, channels={"p": "gyro_x"})
    with pytest.raises(ChannelError, match="theta"):
        check_compatibility(small, channels={"theta": None})


def test_bad_values_are_named(small):
    degrees = small.with_channels({"alpha": np.degrees(small["alpha"]) + 5.0})
    with pytest.raises(DataFormatError, match=r"'alpha'.*radians"):
        check_compatibility(degrees)
    stopped = small.with_channels({"V": np.zeros(small.n_samples)})
    with pytest.raises(DataFormatError, match="'V'"):
        check_compatibility(stopped)
    with pytest.raises(DataFormatError, match="FlightData"):
        check_compatibility({"p": [0.0]})  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match="'beta'"):
        aeroid.FlightData(small.time, {"beta": np.full(small.n_samples, np.nan)})


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"estimate": ["b_x"]}, "b_x"),
        ({"estimate": ["b_p", "b_p"]}, "twice"),
        ({"estimate": []}, "at least one"),
        ({"estimate": ["b_p"], "fixed": {"b_p": 0.1}}, "both"),
        ({"fixed": {"k_beta": -1.5}}, "exceed -1"),
        ({"fixed": {"w_n": float("nan")}}, "finite"),
        ({"channels": {"rudder": "r"}}, "rudder"),
        ({"gravity": -9.8}, "gravity"),
        ({"x0": {"speed": 1.0}}, "speed"),
        ({"input_noise": {"p": -1.0}}, "input_noise"),
        ({"seed": 1.5}, "seed"),
        ({"outputs": ["V", "speed"]}, "speed"),
        ({"outputs": []}, "at least one"),
        ({"measured_states": ["q"]}, "measured_states"),
        ({"estimate_x0": ["u", "x"]}, "estimate_x0"),
        ({"scale_about": "mean"}, "scale_about"),
        ({"integration": "rk2"}, "integration"),
    ],
)
def test_bad_options_are_named(small, kwargs, match):
    with pytest.raises(IdentificationError, match=match):
        check_compatibility(small, **kwargs)


def test_public_names():
    assert aeroid.check_compatibility is check_compatibility
    assert aeroid.CompatibilityResult is compat.CompatibilityResult


def test_correlation_is_the_normalised_covariance(injected):
    _, r = injected
    sd = np.array([r.stderr[n] for n in r.parameter_names])
    assert np.allclose(r.correlation, r.covariance / np.outer(sd, sd), rtol=1e-12, atol=0)
    assert np.array_equal(np.diag(r.correlation), np.ones(sd.size))
    assert not r.correlation.flags.writeable


def test_check_compatibility_limits_blas_threads():
    # wrapped by `small_blas`, as every numerical entry point of the library
    assert hasattr(check_compatibility, "__wrapped__")


def test_a_drifting_unestimated_offset_is_named_in_this_functions_terms():
    # alpha carries an offset that is not estimated: its residual drifts, and the warning
    # names the offset to estimate rather than identify's output bias
    data = simulated_flight(8.0, 25.0, errors=UNSHIFTED, seed=8)
    with pytest.warns(aeroid.ResidualDriftWarning, match="check_compatibility") as caught:
        check_compatibility(data, estimate=["b_p", "b_q", "b_az"])
    drift = [w.message for w in caught if isinstance(w.message, aeroid.ResidualDriftWarning)]
    assert drift and "b_alpha" in str(drift[0]) and "estimate_bias" not in str(drift[0])
    assert caught[0].filename == __file__


# -- SIDPAC's set-up: held initial state, measured states, scale factors about the start --

SIDPAC_LON = {"b_ax": 0.15, "b_az": -0.2, "b_q": 0.002, "k_alpha": 0.08, "k_theta": 0.04}
SIDPAC_LAT = {
    "b_ay": -0.1,
    "b_p": 0.003,
    "b_r": 0.0025,
    "k_beta": 0.09,
    "k_phi": 0.07,
    "k_psi": 0.06,
}
SETUPS = {
    "lon": (SIDPAC_LON, ["V", "alpha", "theta"], ["v", "phi", "psi"]),
    "lat": (SIDPAC_LAT, ["beta", "phi", "psi"], ["u", "w", "theta"]),
}


def _true_start(data: aeroid.FlightData) -> dict[str, float]:
    tr = truth(data.time[:1])
    a, b, V = tr["alpha"][0], tr["beta"][0], tr["V"][0]
    return {
        "u": V * np.cos(a) * np.cos(b),
        "v": V * np.sin(b),
        "w": V * np.sin(a) * np.cos(b),
        "phi": tr["phi"][0],
        "theta": tr["theta"][0],
        "psi": tr["psi"][0],
        "h": 1500.0,
    }


@pytest.mark.parametrize("axis", ["lon", "lat"])
def test_sidpac_setup_recovers_its_sensor_errors(axis):
    truths, fitted, fed = SETUPS[axis]
    # scale factors about the start value: (1 + k)(y - y0) + y0 = (1 + k) y - k y0
    t0 = truth(np.zeros(1))
    errors = dict(truths)
    for o in fitted:
        if f"k_{o}" in truths:
            errors[f"b_{o}"] = -truths[f"k_{o}"] * t0[o][0]
    data = simulated_flight(DURATION, RATE, errors=errors, seed=21)
    res = check_compatibility(
        data,
        estimate=list(truths),
        outputs=fitted,
        measured_states=fed,
        estimate_x0=False,
        x0=_true_start(data),
        scale_about="initial",
        error_bars="white",
    )
    assert res.output_names == tuple(fitted)
    assert res.measured_states == tuple(s for s in compat.STATES if s in fed)
    assert res.initial_state_stderr == {}
    o = fitted[1]
    assert res.scale_pivots[o] == pytest.approx(t0[o][0], abs=1e-9)
    assert "taken from their measurements" in res.summary()
    for n, v in truths.items():
        assert abs(res.parameters[n] - v) < 4.0 * res.stderr[n], n
    # the corrected channel undoes the pivoted scale factor
    fixed = res.corrected[o]
    clean = truth(data.time)[o]
    assert np.sqrt(np.mean((fixed - clean) ** 2)) < 1.5 * NOISE[o]


def test_a_measured_state_stands_in_for_the_integrated_one():
    # phi taken from the data: a roll-gyro bias then cannot move the bank angle, and the
    # reconstructed phi state is the measured one (the model never integrates it)
    data = simulated_flight(DURATION, RATE, errors={"b_p": 0.01}, seed=22)
    res = check_compatibility(
        data,
        estimate=["b_q", "b_az"],
        outputs=["V", "alpha", "theta"],
        measured_states=["phi"],
        error_bars="white",
    )
    k = compat.STATES.index("phi")
    assert np.all(res.states[:, k] == res.states[0, k])  # held, not integrated
    assert "phi" not in res.initial_states or "phi" not in res.initial_state_stderr


def test_a_longitudinal_record_without_phi(monkeypatch):
    import _compat_flight as flight

    # wings level, no sideslip, constant heading: a purely longitudinal flight
    monkeypatch.setitem(flight._SIGNALS, "phi", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "beta", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "psi", (0.3, 0.0, []))
    data = simulated_flight(DURATION, RATE, errors={"b_q": -0.002, "b_ax": 0.15}, seed=23)
    lon = aeroid.FlightData(
        data.time, {c: data[c] for c in ("p", "q", "r", "ax", "ay", "az", "V", "alpha", "theta")}
    )
    res = check_compatibility(lon, estimate=["b_q", "b_ax", "b_az"], error_bars="white")
    assert res.output_names == ("V", "alpha", "theta")
    assert "phi" not in res.initial_state_stderr
    assert abs(res.parameters["b_q"] + 0.002) < 4.0 * res.stderr["b_q"]
    assert abs(res.parameters["b_ax"] - 0.15) < 4.0 * res.stderr["b_ax"]
    assert abs(res.parameters["b_az"]) < 4.0 * res.stderr["b_az"]


def test_a_longitudinal_record_leaves_the_unseen_side_velocity_alone(monkeypatch):
    """Without beta (or the ground speed) the airspeed holds v only squared: asked for its
    start by default, the fit stalled at its start values ("no step decreases the
    cost"), 41 of 50 noisy records too."""
    import _compat_flight as flight

    monkeypatch.setitem(flight._SIGNALS, "phi", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "beta", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "psi", (0.3, 0.0, []))
    truth = {"b_q": -0.002, "b_ax": 0.15, "b_az": -0.05}
    data = simulated_flight(DURATION, RATE, errors=truth, noise={})
    lon = aeroid.FlightData(
        data.time, {c: data[c] for c in ("p", "q", "r", "ax", "ay", "az", "V", "alpha", "theta")}
    )
    res = check_compatibility(lon, estimate=list(truth))
    assert res.success and res.identifiable
    assert set(res.initial_state_stderr) == {"u", "w", "theta"}
    for name, value in truth.items():
        assert res.parameters[name] == pytest.approx(value, rel=5e-3)


def test_a_longitudinal_record_by_default_fits_the_longitudinal_errors(monkeypatch):
    """The lateral gyros and accelerometer reach no fitted output of a wings-level record
    without phi, beta, psi or a ground speed but through second-order terms: estimated by
    default, they left the fit stalled at its start (or, listed in another order, at a
    wrong answer flagged converged). They are left out by default and refused when asked."""
    import _compat_flight as flight

    monkeypatch.setitem(flight._SIGNALS, "phi", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "beta", (0.0, 0.0, []))
    monkeypatch.setitem(flight._SIGNALS, "psi", (0.3, 0.0, []))
    truth = {"b_q": -0.002, "b_ax": 0.15, "b_az": -0.05, "b_V": 1.5, "b_alpha": 0.02}
    data = simulated_flight(DURATION, RATE, errors=truth, noise={})
    channels = ("p", "q", "r", "ax", "ay", "az", "V", "alpha", "theta")
    lon = aeroid.FlightData(data.time, {c: data[c] for c in channels})
    res = check_compatibility(lon)
    assert res.success and set(res.parameters) == {*truth, "k_alpha"}
    for name, value in truth.items():
        assert res.parameters[name] == pytest.approx(value, rel=5e-3, abs=1e-6), name
    with pytest.raises(IdentificationError, match=r"estimate: \['b_p'\]: a wings-level record"):
        check_compatibility(lon, estimate=["b_q", "b_ax", "b_p"])


def test_what_cannot_be_separated_keeps_infinite_bars_with_input_noise():
    """Level flight at a constant angle of attack, no ground speed: an airspeed offset
    and the initial forward speed are one direction. The warning said their bars are
    infinite, but the coloured bars with the input-noise share gave b_V +-0.07."""
    from scipy.signal import lfilter

    g = 9.80665
    t = np.arange(0.0, 15.0, 0.02)
    a0, th = 0.06, 0.05
    speed = 50.0 + 2.0 * np.sin(0.3 * t) + np.sin(0.9 * t + 1.0)
    accel = 0.6 * np.cos(0.3 * t) + 0.9 * np.cos(0.9 * t + 1.0)
    rng = np.random.default_rng(0)
    drift = lfilter([1.0], [1.0, -0.97], 0.05 * rng.standard_normal(t.size))

    def noise(s: float) -> np.ndarray:
        return s * rng.standard_normal(t.size)

    data = aeroid.FlightData(
        t,
        {
            "p": noise(1e-4),
            "q": noise(1e-4),
            "r": noise(1e-4),
            "ay": noise(0.01),
            "ax": accel * np.cos(a0) + g * np.sin(th) + noise(0.01),
            "az": accel * np.sin(a0) - g * np.cos(th) + noise(0.01),
            "V": speed + drift,
            "alpha": a0 + noise(0.002),
            "theta": th + noise(0.002),
        },
    )
    with pytest.warns(aeroid.IdentifiabilityWarning, match="b_V"):
        res = check_compatibility(data, estimate=["b_V", "b_q", "b_ax", "b_az"])
    assert res.error_bars == "colored" and not res.identifiable
    assert any("b_V" in combo for combo in res.unidentifiable)
    assert res.stderr["b_V"] == np.inf
    assert np.isfinite(res.stderr["b_q"]) and np.isfinite(res.stderr["b_az"])


def test_scale_about_initial_is_a_reparametrisation():
    # (1 + k)(y - y0) + y0 + b == (1 + k) y + (b - k y0): same k, offset moved by k y0
    data = simulated_flight(DURATION, RATE, errors={"k_alpha": 0.08, "b_alpha": 0.01}, seed=24)
    names = ["k_alpha", "b_alpha", "b_q"]
    zero = check_compatibility(data, estimate=names, error_bars="white")
    pivot = check_compatibility(data, estimate=names, error_bars="white", scale_about="initial")
    y0 = pivot.scale_pivots["alpha"]
    assert pivot.parameters["k_alpha"] == pytest.approx(zero.parameters["k_alpha"], abs=1e-6)
    shifted = pivot.parameters["b_alpha"] - pivot.parameters["k_alpha"] * y0
    assert shifted == pytest.approx(zero.parameters["b_alpha"], abs=1e-6)
    assert zero.scale_pivots["alpha"] == 0.0


@pytest.mark.filterwarnings("ignore::aeroid.errors.ResidualDriftWarning")
def test_euler_integration_is_first_order():
    # one Euler step per sample: the reconstruction error halves with the step
    errors = []
    for rate in (25.0, 50.0):
        data = simulated_flight(4.0, rate, noise={}, seed=25)
        res = check_compatibility(
            data, estimate=["b_q"], estimate_x0=False, x0=_true_start(data), integration="euler"
        )
        theta = res.true_outputs[:, compat.OUTPUT_CHANNELS.index("theta")]
        errors.append(float(np.max(np.abs(theta - truth(data.time)["theta"]))))
    assert 1.6 < errors[0] / errors[1] < 2.5


# -- integrated input noise: counted once, at the level the inputs and residuals allow --

DRIFTING_INPUTS = {
    **NOISE,
    **dict.fromkeys(("p", "q", "r"), 4e-3),
    **dict.fromkeys(("ax", "ay", "az"), 0.1),
    **dict.fromkeys(("phi", "theta", "psi"), 3e-4),
    "alpha": 5e-4,
    "beta": 5e-4,
    "V": 0.05,
}


@pytest.mark.slow
def test_integrated_input_noise_is_counted_once():
    # Gyro and accelerometer noise integrated into attitude and velocity random walks
    # dominate the residuals: the coloured bars of the residuals plus the input-noise
    # share counted that wander twice (z-scores of sd 0.84 over six seeds; now 1.00).
    # Four seeds, 40 estimates: the sd of unit-normal z-scores is known to 11 %.
    z = []
    for seed in range(4):
        data = simulated_flight(20.0, 25.0, errors=BIASES, noise=DRIFTING_INPUTS, seed=100 + seed)
        r = check_compatibility(data)
        assert r.error_bars == "colored"
        z += [(r.parameters[n] - BIASES.get(n, 0.0)) / r.stderr[n] for n in r.parameter_names]
    z = np.array(z)
    assert z.size == 40
    assert 0.7 < float(np.std(z)) < 1.35 and np.all(np.abs(z) < 3.5), z


def test_input_noise_level_is_bounded_by_the_quietest_band():
    # White noise of sd 0.01 plus a strong vibration at 0.4 of the sampling rate: the
    # fourth differences see the vibration (sd 0.05 at that frequency amplified by
    # (2 sin(0.4 pi))^4 = 13.1, against 70 for white noise), the quietest band does not.
    rng = np.random.default_rng(0)
    n = 2000
    k = np.arange(n)
    vibration = 0.05 * np.sqrt(2) * np.sin(2 * np.pi * 0.4 * k)
    signal = np.sin(2 * np.pi * 0.002 * k)
    inputs = {c: signal + 0.01 * rng.standard_normal(n) for c in compat.INPUT_CHANNELS}
    inputs["p"] = inputs["p"] + vibration
    sigma = compat._input_noise(inputs, None)
    d4 = np.diff(inputs["p"], 4)
    assert np.std(d4) / np.sqrt(70) > 2.0 * 0.01  # what the differences alone would say
    assert 0.95 < sigma["p"] / 0.01 < 1.3, sigma
    # white noise alone: the band bound never undercuts the fourth differences by much
    for c in ("q", "r", "ax"):
        assert 0.9 < sigma[c] / 0.01 < 1.1, (c, sigma)


def test_residuals_lower_the_input_noise_only_beyond_chance():
    from aeroid.estimation._compat_input_noise import _allowed_scale

    rng = np.random.default_rng(0)
    # two outputs whose input-noise sums of squares are 100 chi2_4 / 4 and 10 chi2_50 / 50
    drawn = np.column_stack([100 * rng.chisquare(4, 400) / 4, 10 * rng.chisquare(50, 400) / 50])
    # residuals at half the mean of a four-degree-of-freedom sum: well within chance
    assert _allowed_scale(drawn, np.array([50.0, 10.0])) == 1.0
    # far below: the factor puts the residual at the 2.5 % quantile (Bonferroni, two
    # outputs) of the fitted scaled chi-square, here close to chi2_4's
    from scipy.stats import chi2

    c = _allowed_scale(drawn, np.array([5.0, 10.0]))
    assert c == pytest.approx(5.0 / (100 * chi2.ppf(0.025, 4) / 4), rel=0.2)
    # exact draws (no spread): the mean itself is the bound
    assert _allowed_scale(np.full((3, 1), 8.0), np.array([4.0])) == pytest.approx(0.5, rel=5e-3)


@pytest.mark.filterwarnings("ignore::aeroid.errors.ResidualDriftWarning")
def test_rk4_hold_holds_the_inputs_and_measured_states_over_each_step():
    # SIDPAC's saved dca results: one RK4 step per sample, the rates and the measured
    # states held at the step's first sample in every stage. With phi from the data,
    # theta's rate depends on held values only, so theta is in closed form the left
    # Riemann sum of (q - b_q) cos(phi) - r sin(phi) over the samples.
    data = simulated_flight(4.0, 25.0, noise={}, seed=26)
    opts = {
        "estimate": ["b_q"],
        "outputs": ["V", "alpha", "theta"],
        "measured_states": ["phi"],
        "estimate_x0": False,
        "x0": _true_start(data),
        "error_bars": "white",
    }
    res = check_compatibility(data, integration="rk4_hold", **opts)
    q = data["q"] - res.parameters["b_q"]
    rate = q * np.cos(data["phi"]) - data["r"] * np.sin(data["phi"])
    steps = np.diff(data.time) * rate[:-1]
    want = _true_start(data)["theta"] + np.concatenate([[0.0], np.cumsum(steps)])
    theta = res.states[:, compat.STATES.index("theta")]
    np.testing.assert_allclose(theta, want, rtol=0, atol=1e-12)
    # The held rate lags the sampled one by half a step, and on this error-free record
    # the gyro bias absorbs what the lag leaves (b_q 2.4e-3 rad/s at 25 Hz); inputs
    # interpolated between the samples recover b_q = 0 (3e-6).
    smooth = check_compatibility(data, integration="rk4", **opts)
    assert abs(smooth.parameters["b_q"]) < 5e-5
    assert abs(res.parameters["b_q"]) > 1e-3
    moved = smooth.states[:, compat.STATES.index("theta")] - want
    assert np.max(np.abs(moved)) > 1e-3
