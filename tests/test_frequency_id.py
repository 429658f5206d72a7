"""Composite frequency responses and transfer-function fits against known systems."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.signal
import scipy.stats
from _sidpac_files import sidpac_mat

from aeroid import (
    ChannelError,
    CompositeResponse,
    DataFormatError,
    FlightData,
    IdentificationError,
    Model,
    TransferFunctionFit,
    composite_response,
    fit_transfer_function,
)
from aeroid._czt import fourier

WN, ZETA, GAIN, TAU = 4.0, 0.5, 2.0, 0.05


def log_sweep(t: np.ndarray, w0: float, w1: float) -> np.ndarray:
    """Exponential sweep from w0 to w1 rad/s over the record."""
    span = t[-1]
    return np.sin(w0 * span / np.log(w1 / w0) * (np.exp(np.log(w1 / w0) * t / span) - 1.0))


def discrete_response(b, a, omega, fs, delay_samples=0):
    """Exact response of the simulated discrete filter at ω (rad/s)."""
    z = np.exp(1j * omega / fs)
    return np.polyval(b, z) / np.polyval(a, z) * z ** (-len(a) + len(b)) * z ** (-delay_samples)


def second_order(fs):
    return scipy.signal.bilinear([GAIN * WN**2], [1.0, 2 * ZETA * WN, WN**2], fs)


# -- chirp-z Fourier transform ---------------------------------------------------------------


@pytest.mark.parametrize("chunk", [2_000_000, 50])
def test_fourier_matches_direct_sum_on_even_and_uneven_grids(
    chunk: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    import aeroid._czt as czt

    monkeypatch.setattr(czt, "_CHUNK", chunk)  # 50: the block sum in chunks of frequencies
    rng = np.random.default_rng(1)
    x = rng.standard_normal((300, 2))
    dt = 0.02
    t = np.arange(300) * dt
    # few evenly spaced frequencies (block sum), many (chirp-z), uneven ones (block sum)
    grids = (np.linspace(0.1, 12.0, 37), np.linspace(0.1, 24.0, 400), np.geomspace(0.1, 12.0, 37))
    for f in grids:
        ref = dt * np.exp(-2j * np.pi * np.outer(f, t)) @ x
        np.testing.assert_allclose(fourier(x, dt, f), ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fourier(x[:, 0], dt, f), ref[:, 0], rtol=0, atol=1e-12)
    assert 400 > czt._CZT_FROM * np.log2(700) > 37  # the grids take both paths


def test_end_correction_converges_at_second_order():
    # ∫_0^1 e^{-2t} e^{-jωt} dt = (1 - e^{-(2+jω)}) / (2 + jω)
    f = np.array([0.3, 1.1])
    s = 2.0 + 2j * np.pi * f
    exact = (1.0 - np.exp(-s)) / s
    errs = {}
    for corr in (False, True):
        errs[corr] = []
        for n in (101, 201):
            dt = 1.0 / (n - 1)
            x = np.exp(-2.0 * np.arange(n) * dt)
            errs[corr].append(np.max(np.abs(fourier(x, dt, f, end_correction=corr) - exact)))
    assert errs[False][0] / errs[False][1] == pytest.approx(2.0, rel=0.05)  # Euler: O(Δt)
    assert errs[True][0] / errs[True][1] == pytest.approx(4.0, rel=0.05)  # trapezoid: O(Δt²)


def test_fourier_rejects_bad_input():
    with pytest.raises(DataFormatError, match="dt"):
        fourier(np.ones(10), 0.0, [1.0])
    with pytest.raises(DataFormatError, match="non-finite"):
        fourier(np.array([1.0, np.nan]), 0.1, [1.0])


# -- composite response ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def clean_sweep():
    """180 s exponential sweep 0.3-20 rad/s at 50 Hz through the second-order system."""
    fs = 50.0
    t = np.arange(int(180 * fs) + 1) / fs
    u = log_sweep(t, 0.3, 20.0)
    b, a = second_order(fs)
    y = scipy.signal.lfilter(b, a, u)
    return FlightData(t, {"u": u, "y": y}), (b, a), fs


def test_composite_recovers_noise_free_transfer_function(clean_sweep):
    data, (b, a), fs = clean_sweep
    res = composite_response(data, "u", "y", windows=(60, 30, 15), frequency_range=(0.6, 8.0))
    ch = res.channel("u", "y")
    good = ch.coherence > 0.9
    assert good.sum() >= 90
    truth = discrete_response(b, a, ch.frequency, fs)
    ratio = ch.response[good] / truth[good]
    assert np.max(np.abs(np.abs(ratio) - 1.0)) < 0.01
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 1.0
    # magnitude in dB, unwrapped phase in degrees, on the same truth
    np.testing.assert_allclose(ch.magnitude[good], 20 * np.log10(np.abs(truth[good])), atol=0.087)
    assert np.all(np.diff(ch.phase) < 5.0) and ch.phase[-1] < -90.0
    assert isinstance(res, CompositeResponse) and len(res.n_averages) == 3
    assert "Composite frequency response" in res.summary()


def test_two_correlated_inputs_are_conditioned():
    fs = 50.0
    t = np.arange(int(180 * fs) + 1) / fs
    half = t.size // 2
    sweep = log_sweep(t[:half], 0.3, 20.0)
    # one axis swept after the other; the second input also follows the first (a crossfeed)
    u1 = np.concatenate([sweep, np.zeros(t.size - half)])
    u2 = 0.6 * u1 + np.concatenate([np.zeros(t.size - half), sweep])
    b1, a1 = second_order(fs)
    b2, a2 = scipy.signal.bilinear([3.0], [1.0, 1.5], fs)
    y = scipy.signal.lfilter(b1, a1, u1) + scipy.signal.lfilter(b2, a2, u2)
    data = FlightData(t, {"u1": u1, "u2": u2, "y": y})
    res = composite_response(data, ["u1", "u2"], "y", windows=(30, 15), frequency_range=(0.8, 6.0))
    for name, (b, a) in (("u1", (b1, a1)), ("u2", (b2, a2))):
        ch = res.channel(name, "y")
        good = ch.coherence > 0.9
        assert good.sum() >= 60
        ratio = ch.response[good] / discrete_response(b, a, ch.frequency[good], fs)
        assert np.max(np.abs(np.abs(ratio) - 1.0)) < 0.02
        assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 2.0
    # the inputs explain the output: multiple coherence near one
    assert np.median(res.multiple_coherence["y"]) > 0.99
    # without conditioning the correlated input biases the single-input estimate
    single = composite_response(data, "u1", "y", windows=(30, 15), frequency_range=(0.8, 6.0))
    h1 = discrete_response(b1, a1, single.frequency, fs)
    assert np.median(np.abs(single.channels[0].response / h1 - 1.0)) > 0.1


def test_random_error_predicts_the_scatter():
    """εr from the coherence matches the spread of |Ĥ| over noise seeds (within 15 %)."""
    fs = 50.0
    t = np.arange(int(60 * fs) + 1) / fs
    u = log_sweep(t, 0.3, 20.0)
    om = np.arange(1.0, 8.0, 2 * 2 * np.pi / 15)
    mags, errs = [], []
    for seed in range(120):
        y = u + 0.5 * np.random.default_rng(seed).standard_normal(t.size)
        ch = composite_response(
            FlightData(t, {"u": u, "y": y}), "u", "y", windows=(15,), frequencies=om
        ).channels[0]
        mags.append(np.abs(ch.response))
        errs.append(ch.random_error)
    actual = np.std(mags, axis=0)
    predicted = np.sqrt(np.mean(np.square(errs), axis=0))
    # 120 seeds: the sample std is within ±13 % (2σ) of the truth
    np.testing.assert_allclose(np.mean(actual / predicted), 1.0, atol=0.1)
    assert np.all(np.abs(actual / predicted - 1.0) < 0.3)


def test_composite_errors_name_the_problem(clean_sweep):
    data, _, _ = clean_sweep
    with pytest.raises(ChannelError, match="nope"):
        composite_response(data, "nope", "y")
    with pytest.raises(DataFormatError, match="window"):
        composite_response(data, "u", "y", windows=(1000.0,))
    with pytest.raises(IdentificationError, match="overlap"):
        composite_response(data, "u", "y", overlap=1.2)
    with pytest.raises(IdentificationError, match="frequencies"):
        composite_response(data, "u", "y", frequencies=[0.0, 1.0])
    with pytest.raises(ChannelError, match="both"):
        composite_response(data, "u", "u")


def test_composite_refuses_bad_windows_frequencies_and_names(clean_sweep):
    data, _, _ = clean_sweep
    with pytest.raises(ChannelError, match="inputs: expected one or more channel names, got 5"):
        composite_response(data, 5, "y")
    with pytest.raises(DataFormatError, match="windows: a window length must be finite, got nan"):
        composite_response(data, "u", "y", windows=[np.nan])
    with pytest.raises(IdentificationError, match="windows: expected one or more lengths"):
        composite_response(data, "u", "y", windows=[])
    with pytest.raises(IdentificationError, match="frequencies: expected numbers in rad/s"):
        composite_response(data, "u", "y", frequencies="abc")
    with pytest.raises(IdentificationError, match="frequencies: 1 rad/s is given more than once"):
        composite_response(data, "u", "y", frequencies=[1.0, 1.0, 2.0])
    # text and bools are not numbers, though float() would read them as such
    for bad in ({"windows": (True,)}, {"windows": ("10",)}, {"windows": [[5.0, 10.0]]}):
        with pytest.raises(IdentificationError, match="windows: expected one or more lengths"):
            composite_response(data, "u", "y", **bad)
    for bad_overlap in ("0.5", True):
        with pytest.raises(IdentificationError, match="overlap: expected a number"):
            composite_response(data, "u", "y", overlap=bad_overlap)
    with pytest.raises(IdentificationError, match=r"frequency_range: expected \(low, high\)"):
        composite_response(data, "u", "y", frequency_range=("1", "10"))


@pytest.mark.parametrize("level", [0.0, 1.5])
def test_composite_refuses_an_input_without_excitation(clean_sweep, level):
    data, _, _ = clean_sweep
    flat = data.with_channels({"u": np.full(data.n_samples, level)})
    with pytest.raises(IdentificationError, match=r"input 'u' is constant .*no excitation"):
        composite_response(flat, "u", "y")


def test_composite_refuses_linearly_dependent_inputs(clean_sweep):
    data, _, _ = clean_sweep
    twin = data.with_channels({"u2": 2.0 * data["u"] + 0.3})
    with pytest.raises(IdentificationError, match=r"inputs \['u', 'u2'\] are linearly dependent"):
        composite_response(twin, ["u", "u2"], "y")
    # a third, independent input: the dependent pair is still named, and only it
    noise = np.random.default_rng(0).standard_normal(data.n_samples)
    three = twin.with_channels({"w": noise})
    with pytest.raises(IdentificationError, match=r"\['u', 'u2'\] are linearly"):
        composite_response(three, ["u", "w", "u2"], "y")


def test_response_channel_validates_what_it_is_given():
    from aeroid import ResponseChannel

    w = np.geomspace(0.3, 20.0, 10)
    h = 1.0 / (1j * w + 1.0)
    ok = ResponseChannel("x", "y", w, h, coherence=np.ones(w.size), random_error=None)
    assert np.all(np.isnan(ok.random_error)) and ok.coherence.shape == (10,)
    bad_h = h.copy()
    bad_h[4] = np.nan
    cases = [
        ({"response": bad_h}, r"'x' -> 'y': response: non-finite value .* at index 4"),
        ({"frequency": -w}, "frequency: expected positive frequencies"),
        ({"frequency": w[::-1]}, "frequency: not strictly increasing at index 1"),
        ({"frequency": w[:5]}, r"response has shape \(10,\), frequency \(5,\)"),
        ({"coherence": [0.9]}, r"coherence has shape \(1,\), frequency \(10,\)"),
        ({"coherence": np.full(10, 1.5)}, r"coherence: expected values in \[0, 1\], got 1.5"),
        ({"random_error": np.full(10, -0.1)}, "random_error: expected values non-negative"),
        ({"frequency": np.full((2, 5), 1.0)}, "frequency: expected a non-empty 1-D array"),
        ({"input_name": 1}, "input_name: expected a channel name"),
    ]
    for change, message in cases:
        kwargs = {"input_name": "x", "output_name": "y", "frequency": w, "response": h}
        kwargs.update(change)
        with pytest.raises(DataFormatError, match=message):
            ResponseChannel(**kwargs)


# -- transfer-function fit --------------------------------------------------------------------


def noisy_sweep(seed: int, noise: float = 0.5):
    """120 s sweep at 100 Hz through the delayed second-order system, output noise."""
    fs = 100.0
    t = np.arange(int(120 * fs) + 1) / fs
    u = log_sweep(t, 0.3, 25.0)
    b, a = second_order(fs)
    y = scipy.signal.lfilter(b, a, u)
    y = np.concatenate([np.zeros(5), y[:-5]])  # 0.05 s delay
    y = y + noise * np.random.default_rng(seed).standard_normal(t.size)
    return FlightData(t, {"u": u, "y": y})


TRUTH = {"b0": GAIN * WN**2, "a0": WN**2, "a1": 2 * ZETA * WN, "tau": TAU}
# Frequencies two resolution cells of the 20 s window apart: about independent errors.
FIT_FREQS = np.arange(1.0, 9.0, 2 * 2 * np.pi / 20)


def test_fit_recovers_second_order_with_delay_within_3_sigma():
    for seed in range(3):
        res = composite_response(noisy_sweep(seed), "u", "y", windows=(20,), frequencies=FIT_FREQS)
        for weighting in ("cifer", "random_error"):
            fit = fit_transfer_function(
                res, numerator_order=0, denominator_order=2, weighting=weighting
            )
            for k, v in TRUTH.items():
                se = fit.standard_errors[k]
                assert abs(fit.parameters[k] - v) < 3 * se
            if weighting == "random_error":
                assert abs(fit.parameters["tau"] - TAU) < 3 * fit.standard_errors["tau"]
    assert set(fit.parameters) == {"b0", "a0", "a1", "tau"}
    poles = np.sort_complex(fit.poles)
    exact = np.sort_complex(np.roots([1.0, 2 * ZETA * WN, WN**2]))
    np.testing.assert_allclose(poles, exact, rtol=0.1)
    np.testing.assert_allclose(fit.evaluate([2.0]), fit.transfer_function([2j]))
    assert "Transfer-function fit" in fit.summary()


def test_fit_is_exact_on_an_exact_response():
    w = np.geomspace(0.3, 20.0, 60)
    s = 1j * w
    h = (2.0 * s + 3.0) / (s**3 + 4.0 * s**2 + 9.0 * s + 5.0) * np.exp(-0.08 * s)
    from aeroid import ResponseChannel

    ch = ResponseChannel("x", "y", w, h, coherence=np.ones(w.size))
    fit = fit_transfer_function(ch, numerator_order=1, denominator_order=3)
    expect = {"b0": 3.0, "b1": 2.0, "a0": 5.0, "a1": 9.0, "a2": 4.0, "tau": 0.08}
    for k, v in expect.items():
        assert fit.parameters[k] == pytest.approx(v, rel=1e-6)
    assert fit.cost < 1e-10
    fit0 = fit_transfer_function(ch, numerator_order=1, denominator_order=3, delay=False)
    assert "tau" not in fit0.parameters and fit0.cost > 1.0


def test_numerator_of_higher_order_than_the_denominator():
    # Klein & Morelli Example 7.2's form: (p1 s^2 + p2 s + p3)/(s + p4), exact data
    w = np.geomspace(0.5, 12.0, 40)
    s = 1j * w
    h = (0.3 * s**2 + 2.0 * s + 5.0) / (s + 4.0) * np.exp(-0.05 * s)
    from aeroid import ResponseChannel

    ch = ResponseChannel("x", "y", w, h, coherence=np.ones(w.size))
    fit = fit_transfer_function(ch, numerator_order=2, denominator_order=1)
    expect = {"b0": 5.0, "b1": 2.0, "b2": 0.3, "a0": 4.0, "tau": 0.05}
    for k, v in expect.items():
        assert fit.parameters[k] == pytest.approx(v, rel=1e-6), k
    np.testing.assert_allclose(fit.numerator, [0.3, 2.0, 5.0], rtol=1e-6)


def test_fixed_parameters_are_held_and_the_rest_fitted():
    w = np.geomspace(0.3, 20.0, 60)
    s = 1j * w
    h = (2.0 * s + 3.0) / (s**2 + 1.5 * s + 9.0) * np.exp(-0.08 * s)
    from aeroid import ResponseChannel

    ch = ResponseChannel("x", "y", w, h, coherence=np.ones(w.size))
    fit = fit_transfer_function(ch, numerator_order=1, denominator_order=2, fixed={"tau": 0.08})
    assert fit.parameters["tau"] == 0.08 and fit.standard_errors["tau"] == 0.0
    for k, v in {"b0": 3.0, "b1": 2.0, "a0": 9.0, "a1": 1.5}.items():
        assert fit.parameters[k] == pytest.approx(v, rel=1e-6), k
    # a wrong fixed value: the others move to absorb it, the held one stays put
    off = fit_transfer_function(ch, numerator_order=1, denominator_order=2, fixed={"a0": 8.0})
    assert off.parameters["a0"] == 8.0 and off.cost > 1e-3
    i = list(off.parameters).index("a0")
    assert np.all(np.asarray(off.covariance)[i, :] == 0.0)


def test_fit_rejects_bad_options():
    w = np.geomspace(0.3, 20.0, 10)
    from aeroid import ResponseChannel

    ch = ResponseChannel("x", "y", w, 1.0 / (1j * w + 1.0), coherence=np.ones(w.size))
    with pytest.raises(IdentificationError, match="numerator_order"):
        fit_transfer_function(ch, numerator_order=-1, denominator_order=2)
    with pytest.raises(IdentificationError, match="fixed: unknown"):
        fit_transfer_function(ch, numerator_order=0, denominator_order=1, fixed={"zz": 1.0})
    with pytest.raises(IdentificationError, match="every parameter is fixed"):
        fit_transfer_function(
            ch, numerator_order=0, denominator_order=1, delay=False, fixed={"a0": 1, "b0": 1}
        )
    with pytest.raises(IdentificationError, match="weighting"):
        fit_transfer_function(ch, numerator_order=0, denominator_order=1, weighting="x")
    with pytest.raises(IdentificationError, match="cannot fit"):
        fit_transfer_function(
            ch, numerator_order=0, denominator_order=1, frequency_range=(0.3, 0.35)
        )
    with pytest.raises(IdentificationError, match="unknown"):
        fit_transfer_function(ch, numerator_order=0, denominator_order=1, start={"zz": 1.0})
    with pytest.raises(IdentificationError, match="min_coherence"):
        fit_transfer_function(ch, numerator_order=0, denominator_order=1, min_coherence=2.0)
    for value in (np.nan, "x", True):
        with pytest.raises(IdentificationError, match=r"start\['a0'\]: expected a finite number"):
            fit_transfer_function(ch, numerator_order=0, denominator_order=1, start={"a0": value})
    with pytest.raises(IdentificationError, match="delay: expected True or False, got 'no'"):
        fit_transfer_function(ch, numerator_order=0, denominator_order=1, delay="no")  # type: ignore[arg-type]


def test_fit_straight_from_flight_data_needs_the_pair():
    data = noisy_sweep(0, noise=0.05)
    with pytest.raises(ChannelError, match="input= and output="):
        fit_transfer_function(data, numerator_order=0, denominator_order=2)
    fit = fit_transfer_function(
        data,
        numerator_order=0,
        denominator_order=2,
        input="u",
        output="y",
        frequency_range=(1.0, 10.0),
    )
    for k, v in TRUTH.items():
        assert fit.parameters[k] == pytest.approx(v, rel=0.05)
    assert fit.input_name == "u" and fit.output_name == "y"


@pytest.mark.slow
def test_random_error_standard_errors_cover_over_200_seeds():
    """95 % t-intervals from weighting="random_error" cover the truth 93-97 % of the time.

    Pooled over the 4 parameters and 200 seeds (800 intervals): the binomial
    standard error of a 95 % coverage is 0.8 %, and 93-97 % is ±2.6 of it.
    """
    inside = []
    for seed in range(200):
        res = composite_response(noisy_sweep(seed), "u", "y", windows=(20,), frequencies=FIT_FREQS)
        fit = fit_transfer_function(
            res, numerator_order=0, denominator_order=2, weighting="random_error"
        )
        q = scipy.stats.t.ppf(0.975, 2 * fit.frequency.size - len(fit.parameters))
        half = fit.margin(0.95)  # the fit's own t interval
        assert all(h == pytest.approx(q * fit.standard_errors[k]) for k, h in half.items())
        inside.extend(abs(fit.parameters[k] - v) <= half[k] for k, v in TRUTH.items())
    coverage = float(np.mean(inside))
    assert 0.93 <= coverage <= 0.97, coverage


def test_a_short_window_biases_the_composite_near_the_mode():
    """What the README says the random-error bars leave out: with windows (20, 10, 5)
    the 5 s window carries the composite from 2.5 rad/s and, on noise-free data,
    reads the resonance's |H| about 3 % low and its phase about 2.4 deg off (Bendat
    & Piersol's resolution bias); one 20 s window stays within 1 %."""
    data = noisy_sweep(0, noise=0.0)
    freqs = FIT_FREQS[(FIT_FREQS > 2.5) & (FIT_FREQS < 3.2)]
    s = 1j * freqs
    exact = GAIN * WN**2 / (s**2 + 2 * ZETA * WN * s + WN**2) * np.exp(-TAU * s)
    one = composite_response(data, "u", "y", windows=(20,), frequencies=freqs).channels[0]
    three = composite_response(data, "u", "y", windows=(20, 10, 5), frequencies=freqs)
    mixed = three.channels[0]
    assert np.max(np.abs(np.abs(one.response / exact) - 1.0)) < 0.01
    low = np.abs(mixed.response / exact) - 1.0
    assert np.all((low > -0.045) & (low < -0.015)), low
    phase = np.degrees(np.angle(mixed.response / exact))
    assert np.all((np.abs(phase) > 1.0) & (np.abs(phase) < 4.0)), phase
    # about one random error of its own at each point
    assert np.all(np.abs(low) > 0.5 * mixed.random_error), (low, mixed.random_error)


def test_plots_have_labelled_axes(clean_sweep):
    data, _, _ = clean_sweep
    res = composite_response(data, "u", "y", windows=(60,), frequency_range=(0.6, 8.0))
    fig = res.plot()
    labels = {ax.get_ylabel() for ax in fig.axes} | {ax.get_xlabel() for ax in fig.axes}
    assert {"magnitude [dB]", "phase [deg]", "frequency [rad/s]"} <= labels
    fit = fit_transfer_function(res, numerator_order=0, denominator_order=2, delay=False)
    assert len(fit.plot().axes) == 3


# -- numpy replacements for scipy.signal on the first-call path --------------------------------


@pytest.mark.parametrize(("n", "m"), [(1, 5), (2, 3), (50, 400), (1501, 1501), (6001, 100)])
def test_chirp_z_matches_scipy_and_the_direct_sum(n: int, m: int) -> None:
    from aeroid._czt import _chirp_z

    rng = np.random.default_rng(n + m)
    x = rng.standard_normal((n, 3))
    dt, f0, df = 0.01, 0.05, 0.37
    ref = scipy.signal.czt(
        x, m=m, w=np.exp(-2j * np.pi * df * dt), a=np.exp(2j * np.pi * f0 * dt), axis=0
    )
    direct = np.exp(-2j * np.pi * np.outer(f0 + df * np.arange(m), np.arange(n) * dt)) @ x
    got = _chirp_z(x, m, f0, df, dt)
    scale = np.abs(direct).max()
    assert np.abs(got - direct).max() <= 1e-10 * scale
    assert np.abs(got - ref).max() <= 1e-10 * scale


def test_fast_length_is_the_smallest_five_smooth_number() -> None:
    from aeroid._czt import fast_length

    def smooth(k: int) -> bool:
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        return k == 1

    for n in (1, 2, 7, 11, 97, 1000, 1025, 6001, 12345):
        got = fast_length(n)
        assert got >= n and smooth(got)
        assert not any(smooth(k) for k in range(n, got))


@pytest.mark.parametrize("n", [0, 1, 2, 3, 10, 101, 1000])
def test_hann_is_scipys_periodic_window(n: int) -> None:
    from aeroid._czt import hann

    assert np.array_equal(hann(n), scipy.signal.get_window("hann", n) if n else np.ones(0))


def test_frequency_paths_do_not_import_scipy_signal() -> None:
    """A fresh process runs the frequency-domain entry points without `scipy.signal`."""
    import subprocess
    import sys

    code = """
import sys
import numpy as np
import aeroid
from aeroid.models.aircraft import lateral_linear
fs = 100.0
t = np.arange(3001) / fs
u = np.sin(0.3 * 30.0 / np.log(80.0) * (np.exp(np.log(80.0) * t / 30.0) - 1.0))
y = np.zeros_like(u)
for i in range(1, u.size):
    y[i] = 0.9 * y[i - 1] + 0.1 * u[i - 1]
data = aeroid.FlightData(t, {"u": u, "y": y})
aeroid.composite_response(data, "u", "y", windows=(10.0, 5.0))
t4 = np.arange(0, 10, 1 / 400)
aeroid.resample({"x": (t4, np.sin(t4))}, ["x"], rate=50)
truth = dict(Y_beta=-0.15, Y_delta_r=0.03, L_beta=-8.0, L_p=-2.5, L_r=0.8, L_delta_a=12.0,
             L_delta_r=1.0, N_beta=3.5, N_p=-0.1, N_r=-0.4, N_delta_a=-0.3, N_delta_r=-2.5)
model = lateral_linear(V0=60.0, parameters=truth)
tt = np.arange(0.0, 20.0, 0.02)
sim = model.simulate(tt, {"delta_a": np.sin(2.0 * tt) * np.sin(np.pi * tt / 20) ** 2,
                          "delta_r": np.sin(3.1 * tt) * np.sin(np.pi * tt / 20) ** 2},
                     method="exact")
fd = sim.to_flight_data()
import warnings
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    aeroid.frequency_response(model, fd, truth)
    aeroid.identify_frequency_domain(model, fd, truth, method="output_error")
print(sorted(m for m in sys.modules if m.startswith("scipy.signal")))
"""
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_composite_coherence_is_at_most_one_by_construction():
    # Two windows whose spectra a per-element weighting combined into γ² = 1.16:
    # G1 = [[1, 1], [1, 1]] (γ² = 1), G2 = [[100, 0.1], [0.1, 0.01]] (γ² = 0.01).
    from aeroid.frequency.frequency_id import _combine, _condition

    g1 = np.array([[1.0, 1.0], [1.0, 1.0]], dtype=complex)
    g2 = np.array([[100.0, 0.1], [0.1, 0.01]], dtype=complex)
    spectra = np.array([g1, g2])[:, None]  # (n_w, m, c, c)
    old = sum((1 / np.abs(g) ** 2) * g for g in (g1, g2)) / sum(
        1 / np.abs(g) ** 2 for g in (g1, g2)
    )
    assert abs(old[0, 1]) ** 2 / (old[0, 0].real * old[1, 1].real) > 1.1
    for w in ([0.5, 0.5], [0.9, 0.1], [1e-6, 1.0 - 1e-6]):
        gc = _combine(spectra, np.array(w)[:, None], 1)
        assert abs(gc[0, 0, 1]) ** 2 <= gc[0, 0, 0].real * gc[0, 1, 1].real * (1 + 1e-12)
    # random Hermitian positive semi-definite windows and weights, three channels
    rng = np.random.default_rng(0)
    for _ in range(200):
        z = rng.standard_normal((4, 5, 3, 2)) + 1j * rng.standard_normal((4, 5, 3, 2))
        spectra = np.einsum("wmak,wmbk->wmab", np.conj(z), z)  # rank 2: γ² < 1
        gc = _combine(spectra, rng.random((4, 5)), 1)
        g = np.abs(gc[:, 0, 1:]) ** 2 / (
            gc[:, 0, 0].real[:, None] * np.diagonal(gc, axis1=1, axis2=2)[:, 1:].real
        )
        assert np.all(g <= 1 + 1e-12)
        _, coh, _ = _condition(gc, 1)
        assert np.all(coh <= 1.0)


def test_random_error_floor_keeps_a_noise_free_point_from_deciding_a_fit(clean_sweep):
    data, _, _ = clean_sweep
    res = composite_response(data, "u", "y", windows=(60, 30, 15), frequency_range=(0.6, 8.0))
    ch = res.channel("u", "y")
    assert np.all(ch.coherence <= 1.0)
    # noise-free: γ² near 1 everywhere, yet no error below 1 %, so no point weighs more
    # than (εr_max / εr_min)² <= 1e4 times another
    assert np.min(ch.random_error) == pytest.approx(0.01)
    assert np.all(ch.random_error >= 0.01)


def test_a_window_of_one_segment_is_refused(clean_sweep):
    data, _, _ = clean_sweep
    with pytest.raises(DataFormatError, match="coherence 1 by construction"):
        composite_response(data, "u", "y", windows=(data.duration,))
    # at 80 % overlap a window of 90 % of the record still fits once
    with pytest.raises(DataFormatError, match="windows"):
        composite_response(data, "u", "y", windows=(0.9 * data.duration,))


def test_frequencies_below_two_periods_of_the_longest_window_are_dropped_and_said(clean_sweep):
    data, _, _ = clean_sweep
    limit = 4 * np.pi / 30.0  # two periods of the 30 s window, rad/s
    with pytest.warns(UserWarning, match="two periods of the longest"):
        res = composite_response(data, "u", "y", windows=(30, 15), frequency_range=(0.1, 8.0))
    assert res.frequency[0] >= limit * (1 - 1e-12)
    assert res.notes and "dropped" in res.notes[0]
    with pytest.raises(IdentificationError, match="two periods"):
        composite_response(data, "u", "y", windows=(30, 15), frequencies=[0.1, 0.2])
    # the default range starts at the limit: nothing dropped, nothing said
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert composite_response(data, "u", "y", windows=(30, 15)).notes == ()


def test_tfest_demo_composite_keeps_coherence_below_one_and_the_fit_honest():
    # SIDPAC's tfest demo (simulated aileron -> roll rate, 15 s at 40 Hz): the composite
    # read γ² = 1.0074 there, was clipped to 1, and its 1e-9 random error decided the
    # random-error fit (a0 = 4.77 +- 4e-8 for SIDPAC's 3.40 +- 0.11).
    mat = sidpac_mat("Demos", "tfest_demo_data.mat")
    t = mat["t"][:, 0] - mat["t"][0, 0]
    data = FlightData(t, {"aileron": mat["fdata"][:, 14], "p": np.radians(mat["fdata"][:, 4])})
    with pytest.warns(UserWarning, match="two periods"):  # SIDPAC's band starts at 0.1 Hz
        res = composite_response(
            data, "aileron", "p", frequency_range=(2 * np.pi * 0.1, 2 * np.pi * 1.5)
        )
    ch = res.channel("aileron", "p")
    assert np.max(ch.coherence) < 1.0 and np.min(ch.random_error) >= 0.01
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        fit = fit_transfer_function(
            ch, numerator_order=0, denominator_order=1, delay=False, weighting="random_error"
        )
    assert fit.standard_errors["a0"] > 1e-3
    assert abs(fit.parameters["a0"] - 3.40) < 3 * max(fit.standard_errors["a0"], 0.11)


def _first_order_record(seed: int, noise: float, window: bool = True) -> FlightData:
    """y = 3/(s + 2) u, u a multisine 0.2-1 Hz (k/T components), white noise on y.

    Windowed, the record starts and ends at rest, so its transforms hold no
    transient of the ends (which the direct fit does not model, as SIDPAC's).
    """
    from aeroid import Model

    model = Model(
        ["x"],
        ["u"],
        {"a0": 2.0, "b0": 3.0},
        lambda t, x, u, p: np.array([-p["a0"] * x[0] + u[0]]),
        outputs=["y"],
        measurement=lambda t, x, u, p: np.array([p["b0"] * x[0]]),
        name="first_order",
    )
    dt, T = 0.02, 40.0
    t = np.arange(0.0, T + dt / 2, dt)
    rng = np.random.default_rng(100 + seed)
    u = sum(np.sin(2 * np.pi * k / T * t + rng.uniform(0, 2 * np.pi)) for k in range(8, 41)) * 0.1
    if window:
        u = u * np.sin(np.pi * t / T) ** 2
    sim = model.simulate(t, {"u": u}, method="exact").to_flight_data()
    y = sim["y"] + noise * np.random.default_rng(seed).standard_normal(t.size)
    return FlightData(t, {"u": u, "y": y})


def test_excited_band_follows_the_input():
    from aeroid.frequency.frequency_id import _excited_band

    lo, hi = _excited_band(_first_order_record(0, 0.0, window=False), "u")
    assert lo == pytest.approx(2 * np.pi * 8 / 40.0, rel=1e-9)
    assert hi == pytest.approx(2 * np.pi * 40 / 40.0, rel=1e-9)


def test_direct_fourier_fit_recovers_the_truth_with_calibrated_errors():
    exact = fit_transfer_function(
        _first_order_record(0, 0.0),
        input="u",
        output="y",
        numerator_order=0,
        denominator_order=1,
        delay=False,
        fourier=True,
    )
    assert exact.parameters["a0"] == pytest.approx(2.0, rel=1e-4)
    assert exact.parameters["b0"] == pytest.approx(3.0, rel=1e-4)
    assert exact.frequency.min() < 2 * np.pi * 8 / 40.0 < exact.frequency.max()
    # 40 seeds: the scatter of the estimates matches the reported standard errors
    z = []
    for seed in range(40):
        fit = fit_transfer_function(
            _first_order_record(seed, 0.05),
            input="u",
            output="y",
            numerator_order=0,
            denominator_order=1,
            delay=False,
            fourier=True,
        )
        z.append((fit.parameters["a0"] - 2.0) / fit.standard_errors["a0"])
    # the sample sd of 40 unit normals lies within 0.75-1.25 with probability > 99 %
    assert 0.75 < float(np.std(z)) < 1.25, np.std(z)
    assert abs(float(np.mean(z))) < 3 / np.sqrt(40)
    from aeroid import ResponseChannel

    with pytest.raises(IdentificationError, match="fourier"):
        fit_transfer_function(
            ResponseChannel("u", "y", exact.frequency, exact.response, coherence=exact.coherence),
            numerator_order=0,
            denominator_order=1,
            fourier=True,
        )


def test_fourier_fit_refuses_a_band_above_nyquist():
    # as equivalent_system and identify_frequency_domain do: a band is not cut in silence
    data = _first_order_record(0, 0.0)
    nyquist = np.pi / float(np.median(np.diff(data.time)))
    with pytest.raises(IdentificationError, match=r"frequency_range: its top 400 rad/s .*Nyquist"):
        fit_transfer_function(
            data,
            input="u",
            output="y",
            numerator_order=0,
            denominator_order=1,
            fourier=True,
            frequency_range=(1.0, 400.0),
        )
    assert nyquist < 400.0


def test_fourier_fit_keeps_two_periods_of_the_record():
    # the whole record is the window: the default grid starts at k = 2 (4π/T), and
    # explicit frequencies below it are kept with a warning
    data = _first_order_record(0, 0.0, window=False)
    T = float(data.time[-1] - data.time[0])
    fit = fit_transfer_function(
        data,
        input="u",
        output="y",
        numerator_order=0,
        denominator_order=1,
        delay=False,
        fourier=True,
        frequency_range=(0.01, 10.0),
    )
    assert fit.frequency.min() == pytest.approx(4 * np.pi / T, rel=1e-9)
    w = 2 * np.pi * np.arange(1, 30) / T
    with pytest.warns(UserWarning, match="two periods of the record"):
        low = fit_transfer_function(
            data,
            input="u",
            output="y",
            numerator_order=0,
            denominator_order=1,
            delay=False,
            fourier=True,
            frequencies=w,
        )
    assert low.frequency.min() == pytest.approx(w[0], rel=1e-9)


# -- a record's Fourier fit: the record's ends and the frequency sandwich ------------------

_SECOND = {"b1": 2.0, "b0": 8.0, "a1": 1.4, "a0": 9.0}


def _second_order_record(seed: int, noise: float, phi: float = 0.0) -> FlightData:
    """(b1 s + b0)/(s^2 + a1 s + a0) driven by a multisine that neither starts nor ends
    at rest, from rest at t = 0 (so the ends carry both the input's and the state's
    jumps), plus AR(1) noise."""
    model = Model(
        ["x1", "x2"],
        ["u"],
        dict(_SECOND),
        lambda t, x, u, p: np.array([x[1], -p["a0"] * x[0] - p["a1"] * x[1] + u[0]]),
        outputs=["y"],
        measurement=lambda t, x, u, p: np.array([p["b0"] * x[0] + p["b1"] * x[1]]),
        name="second_order",
    )
    dt, T = 0.02, 20.0
    t = np.arange(0.0, T + dt / 2, dt)
    rng = np.random.default_rng(1)
    f = np.arange(0.1, 2.0, 0.05)
    u = sum(np.cos(2 * np.pi * fk * t + rng.uniform(0, 2 * np.pi)) for fk in f) / np.sqrt(f.size)
    y = model.simulate(t, {"u": u}, method="exact").to_flight_data()["y"]
    white = np.random.default_rng(100 + seed).standard_normal(t.size)
    e = scipy.signal.lfilter([np.sqrt(1 - phi**2)], [1, -phi], white) * noise
    return FlightData(t, {"u": u, "y": y + e})


def _second_order_fit(data: FlightData, **kw: object) -> TransferFunctionFit:
    return fit_transfer_function(
        data,
        input="u",
        output="y",
        numerator_order=1,
        denominator_order=2,
        delay=False,
        fourier=True,
        frequency_range=(0.5, 13.0),
        **kw,  # type: ignore[arg-type]
    )


def test_fourier_fit_estimates_the_record_ends_on_and_off_the_grid() -> None:
    data = _second_order_record(0, 0.0)
    T = float(data.time[-1])
    off = 2 * np.pi * np.arange(2.0, 41.0, 0.4) / T  # 0.4 of 2π/T apart, as SIDPAC's
    for kw in ({}, {"frequencies": off}):
        fit = _second_order_fit(data, **kw)
        assert fit.ends_estimated
        for k, v in _SECOND.items():
            assert fit.parameters[k] == pytest.approx(v, rel=2e-3), (kw, k)
        # without them the record's ends are read as dynamics
        bare = _second_order_fit(data, boundary="ignore", **kw)
        assert not bare.ends_estimated
        assert max(abs(bare.parameters[k] / v - 1) for k, v in _SECOND.items()) > 0.02


@pytest.mark.parametrize(("phi", "low"), [(0.0, 0.91), (0.9, 0.90)])
def test_fourier_fit_default_bars_cover_on_a_record_not_at_rest(phi: float, low: float) -> None:
    # 200 records: binomial SD 1.5 % at 0.95; white noise or AR(1) 0.9 (coloured in the
    # band, which the frequency sandwich counts where it lies)
    hits = []
    for seed in range(200):
        fit = _second_order_fit(_second_order_record(seed, 0.05, phi))
        half = fit.margin()
        hits.append([abs(fit.parameters[k] - v) < half[k] for k, v in _SECOND.items()])
    cover = np.mean(hits, axis=0)
    assert np.all(cover >= low) and np.all(cover <= 0.99), cover


@pytest.mark.slow
def test_fourier_fit_bars_cover_noise_peaked_at_a_lightly_damped_mode() -> None:
    # Process noise through the plant puts the noise where a mode (zeta 0.1) puts the
    # information, the case smoothing the spectrum over neighbouring frequencies might
    # bias. The mode spans about six bins of a 60 s record, so the neighbours share its
    # level: 200 records cover 0.925-0.96 (each frequency alone gave 0.835 on a0)
    dt, wn, zeta = 0.02, 3.0, 0.1
    truth = {"b0": wn**2, "a1": 2 * zeta * wn, "a0": wn**2}
    t = np.arange(0.0, 60.0 + dt / 2, dt)
    rng = np.random.default_rng(1)
    f = np.arange(0.05, 2.0, 0.05)
    u = sum(np.cos(2 * np.pi * fk * t + rng.uniform(0, 2 * np.pi)) for fk in f) / np.sqrt(f.size)
    plant = ([wn**2], [1.0, 2 * zeta * wn, wn**2])
    y = scipy.signal.lsim(plant, u, t)[1]
    bd, ad, _ = scipy.signal.cont2discrete(plant, dt)
    hits = []
    for seed in range(200):
        noise = np.random.default_rng(500 + seed)
        shaped = scipy.signal.lfilter(np.ravel(bd), np.ravel(ad), noise.standard_normal(t.size))
        e = 0.05 * shaped / shaped.std() + 0.005 * noise.standard_normal(t.size)
        fit = fit_transfer_function(
            FlightData(t, {"u": u, "y": y + e}),
            input="u",
            output="y",
            numerator_order=0,
            denominator_order=2,
            delay=False,
            fourier=True,
            frequency_range=(0.5, 12.0),
        )
        half = fit.margin()
        hits.append([abs(fit.parameters[k] - v) < half[k] for k, v in truth.items()])
    cover = np.mean(hits, axis=0)
    # binomial SD 1.5 % at 0.95: 0.90 is 3.3 SD below
    assert np.all(cover >= 0.90) and np.all(cover <= 0.99), cover


def test_fourier_fit_options_are_checked() -> None:
    data = _second_order_record(0, 0.0)
    with pytest.raises(IdentificationError, match="boundary"):
        _second_order_fit(data, boundary="guess")
    with pytest.raises(IdentificationError, match="error_bars"):
        _second_order_fit(data, error_bars="reml")
    response = composite_response(data, ["u"], ["y"])
    for kw in ({"error_bars": "white"}, {"boundary": "estimate"}):
        with pytest.raises(IdentificationError, match="fourier=True only"):
            fit_transfer_function(response, numerator_order=1, denominator_order=2, **kw)


def test_fourier_fit_summary_says_what_was_fitted() -> None:
    text = _second_order_fit(_second_order_record(0, 0.05)).summary()
    assert "output error on the record's Fourier transforms" in text
    assert "The record's ends estimated with it." in text
    assert "CIFER cost" not in text and "Reduced χ²" not in text


def test_a_response_without_coherence_is_fitted_and_named_options_are_checked():
    """An independent suite: a ResponseChannel given without coherence (NaN: unknown)
    lost every frequency to the coherence filter ("0 frequencies with γ² >= 0.6"), the
    Fourier fit's frequency_range went unchecked (bare ValueError), True was an order,
    and a bad `fixed` value was blamed on `start`."""
    import aeroid

    w = np.geomspace(0.1, 10.0, 100)
    s = 1j * w
    rc = aeroid.ResponseChannel("da", "p", w, 10.0 * np.exp(-0.08 * s) / (s + 2.0))
    loes = aeroid.equivalent_system(rc, kind="roll")
    assert loes.parameters["1/T_R"] == pytest.approx(2.0, rel=1e-6)
    assert loes.parameters["tau"] == pytest.approx(0.08, rel=1e-6)
    fit = aeroid.fit_transfer_function(rc, numerator_order=0, denominator_order=1)
    assert fit.parameters["a0"] == pytest.approx(2.0, rel=1e-6)
    t = np.arange(0.0, 20.0, 0.01)
    u = np.sin(2 * np.pi * np.cumsum(0.05 + 2.95 * t / 20.0) * 0.01)
    model = aeroid.Model(
        ["p"], ["da"], {"a": 2.0}, lambda t, x, u, p: np.array([-p["a"] * x[0] + 10 * u[0]])
    )
    data = model.simulate(t, u, [0.0]).to_flight_data()
    kw = {
        "numerator_order": 0,
        "denominator_order": 1,
        "input": "da",
        "output": "p",
        "fourier": True,
    }
    for band in ((np.nan, 5.0), (1.0, np.inf), ("a", 1.0)):
        with pytest.raises(IdentificationError, match="frequency_range"):
            aeroid.fit_transfer_function(data, **kw, frequency_range=band)
    with pytest.raises(IdentificationError, match="numerator_order"):
        aeroid.fit_transfer_function(data, **{**kw, "numerator_order": True})
    with pytest.raises(IdentificationError, match=r"fixed\['tau'\]"):
        aeroid.fit_transfer_function(data, **kw, delay=True, fixed={"tau": "x"})


def test_a_singular_covariance_gives_infinite_bars_and_a_warning():
    import aeroid
    from aeroid.frequency._rational_fit import undetermined_bars

    cov = np.diag([4.0, -5e29, np.nan, 0.0])
    free = np.array([True, True, True, False])
    with pytest.warns(aeroid.IdentifiabilityWarning, match=r"\['a1', 'a2'\]"):
        se = undetermined_bars(cov, free, ["a0", "a1", "a2", "tau"], "da -> p", 1)
    assert se[0] == 2.0 and np.isinf(se[1]) and np.isinf(se[2]) and se[3] == 0.0
