"""Smoothing and numerical differentiation against closed-form derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import ChannelError, DataFormatError, FlightData
from aeroid.io.smoothing import differentiate, optimal_cutoff, smooth

DT = 0.02
T = np.arange(0.0, 10.0 + DT / 2, DT)
SPAN = T[-1]


def _band_limited() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ramp plus sine terms of the detrended series: the Fourier smoother is exact."""
    w1, w2 = 3 * np.pi / SPAN, 17 * np.pi / SPAN
    x = 1.0 + 0.3 * T + np.sin(w1 * T) + 0.2 * np.sin(w2 * T)
    dx = 0.3 + w1 * np.cos(w1 * T) + 0.2 * w2 * np.cos(w2 * T)
    ddx = -(w1**2) * np.sin(w1 * T) - 0.2 * w2**2 * np.sin(w2 * T)
    return x, dx, ddx


@pytest.mark.filterwarnings("ignore::aeroid.io.smoothing.NoiseFloorWarning")  # clean data
def test_fourier_exact_on_band_limited_signal() -> None:
    x, dx, ddx = _band_limited()
    np.testing.assert_allclose(smooth(x, dt=DT), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(differentiate(x, dt=DT), dx, rtol=0, atol=1e-11)
    # interior exact; the two end samples are extrapolated (documented)
    dd = differentiate(x, dt=DT, order=2)
    np.testing.assert_allclose(dd[1:-1], ddx[1:-1], rtol=0, atol=1e-9)
    assert abs(dd[0] - ddx[0]) < 1e-2 * np.max(np.abs(ddx))


@pytest.mark.filterwarnings("ignore::aeroid.io.smoothing.NoiseFloorWarning")  # clean data
def test_local_polynomial_exact_on_cubic() -> None:
    x = 2.0 + T - 0.5 * T**2 + 0.1 * T**3
    dx = 1.0 - T + 0.3 * T**2
    ddx = -1.0 + 0.6 * T
    for window in (None, 7, 31):
        got = differentiate(x, dt=DT, method="local", window=window)
        np.testing.assert_allclose(got, dx, rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        differentiate(x, dt=DT, method="local", order=2), ddx, rtol=0, atol=1e-7
    )
    np.testing.assert_allclose(smooth(x, dt=DT, method="local"), x, rtol=0, atol=1e-10)


@pytest.mark.filterwarnings("ignore::aeroid.io.smoothing.NoiseFloorWarning")  # clean data
def test_fourier_on_non_periodic_sine_interior() -> None:
    y = np.sin(1.3 * T) + 0.1 * T**2
    dy = 1.3 * np.cos(1.3 * T) + 0.2 * T
    err = np.abs(differentiate(y, dt=DT) - dy)
    assert err[25:-25].max() < 2e-4  # Gibbs-free away from the ends
    assert err.max() < 1e-2


@pytest.mark.parametrize("method", ["fourier", "local"])
@pytest.mark.parametrize("sigma", [0.002, 0.02])
def test_noisy_derivative_beats_finite_difference(method: str, sigma: float) -> None:
    y = np.sin(1.3 * T) + 0.4 * np.sin(3.1 * T + 0.5) + 0.1 * T**2
    dy = 1.3 * np.cos(1.3 * T) + 0.4 * 3.1 * np.cos(3.1 * T + 0.5) + 0.2 * T
    errs_raw, errs = [], []
    for seed in range(5):
        noisy = y + sigma * np.random.default_rng(seed).standard_normal(T.size)
        errs_raw.append(np.sqrt(np.mean((np.gradient(noisy, DT) - dy) ** 2)))
        errs.append(np.sqrt(np.mean((differentiate(noisy, dt=DT, method=method) - dy) ** 2)))
    # central differences have RMS error sigma/(sqrt(2) dt) ~ 35 sigma here
    assert np.mean(errs) < 0.15 * np.mean(errs_raw)
    # and the error is a small multiple of what noise at the cut-off allows
    assert np.mean(errs) < 60 * sigma


def test_smoothing_reduces_noise() -> None:
    y = np.sin(1.3 * T) + 0.1 * T**2
    noisy = y + 0.02 * np.random.default_rng(1).standard_normal(T.size)
    err = np.sqrt(np.mean((smooth(noisy, dt=DT) - y) ** 2))
    assert err < 0.3 * 0.02


def test_cutoff_follows_noise_floor() -> None:
    # not a finite sine series: its spectrum decays smoothly into the noise floor
    y = np.sin(1.3 * T) + 0.1 * T**2
    cuts = []
    for sigma in (1e-5, 1e-3, 1e-1):
        noise = sigma * np.random.default_rng(2).standard_normal(T.size)
        cuts.append(optimal_cutoff(y + noise, dt=DT))
    assert cuts[0] > cuts[1] > cuts[2] >= 0.2  # 1.3 rad/s = 0.21 Hz stays
    # the sine coefficients of this signal fall as 1/m^3 (a kink in the odd extension's
    # second derivative), so the kept band ends where (c/m^3)^2 = 2 sigma^2 * (2/n):
    # a hundredfold more noise divides the cut-off by about 100^(1/3) = 4.6
    assert 2.5 < cuts[0] / cuts[1] < 8.0


def test_explicit_cutoff() -> None:
    x = np.sin(2 * np.pi * 0.5 * T) + np.sin(2 * np.pi * 5.0 * T)
    out = smooth(x, dt=DT, cutoff=2.0)
    # the 5 Hz component goes, the 0.5 Hz one stays (ends aside)
    np.testing.assert_allclose(out[50:-50], np.sin(2 * np.pi * 0.5 * T)[50:-50], atol=0.05)


@pytest.mark.filterwarnings("ignore::aeroid.io.smoothing.NoiseFloorWarning")  # clean data
def test_columns_and_flight_data() -> None:
    x, dx, _ = _band_limited()
    cols = np.column_stack([x, 2 * x])
    np.testing.assert_allclose(
        differentiate(cols, dt=DT), np.column_stack([dx, 2 * dx]), atol=1e-10
    )
    data = FlightData(T, {"q": x, "alpha": 2 * x}, units={"q": "rad/s"})
    out = differentiate(data, "q")
    assert "q_dot" in out and "alpha_dot" not in out
    assert out.units["q_dot"] == "rad/s/s"
    np.testing.assert_allclose(out["q_dot"], dx, atol=1e-10)
    sm = smooth(data, ["alpha"])
    np.testing.assert_allclose(sm["alpha"], 2 * x, atol=1e-11)
    both = differentiate(data, order=2, suffix="_dd")
    assert {"q_dd", "alpha_dd"} <= set(both.names)


def test_bad_input() -> None:
    x, _, _ = _band_limited()
    with pytest.raises(DataFormatError, match="dt"):
        differentiate(x)
    with pytest.raises(DataFormatError, match="method"):
        differentiate(x, dt=DT, method="spline")
    with pytest.raises(
        DataFormatError, match=r"order: expected 1 or 2 \(derivative order\), got 3"
    ):
        differentiate(x, dt=DT, order=3)
    with pytest.raises(DataFormatError, match=r"order: expected 0, 1 or 2 .*got 5"):
        optimal_cutoff(x, dt=DT, order=5)
    with pytest.raises(DataFormatError, match="window"):
        differentiate(x, dt=DT, method="local", window=4)
    with pytest.raises(DataFormatError, match="non-finite"):
        differentiate(np.r_[x[:-1], np.nan], dt=DT)
    with pytest.raises(DataFormatError, match="at least 5"):
        smooth([1.0, 2.0], dt=DT)
    t = np.r_[0.0, 0.1, 0.3, 0.4, 0.5, 0.6]
    with pytest.raises(DataFormatError, match="uniform"):
        smooth(FlightData(t, {"a": np.ones(6)}))
    with pytest.raises(ChannelError, match="nope"):
        differentiate(FlightData(T, {"q": x}), "nope")


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda x, fd: smooth(x + 5j, dt=DT), "x: complex values"),
        (lambda x, fd: differentiate(np.c_[x, x + 1j], dt=DT), "complex values"),
        (lambda x, fd: smooth(x, dt="0.02"), "dt: expected a positive number"),
        (lambda x, fd: smooth(fd, dt="a"), "dt: expected a positive number"),
        (lambda x, fd: smooth(x, dt=DT, cutoff="a"), "cutoff: expected a positive number"),
        (lambda x, fd: smooth(x, dt=DT, method="local", window="a"), "window"),
        (lambda x, fd: smooth(x, dt=DT, method="local", window=21, cutoff=2.0), "cutoff: .*one"),
        (lambda x, fd: smooth(x[:20], dt=DT, method="local", polyorder=30), "polyorder: .* 20"),
        (lambda x, fd: smooth(fd, 5), "channels: expected channel names"),
        (lambda x, fd: differentiate(fd, "q", suffix=5), "suffix: expected a non-empty string"),
        (lambda x, fd: differentiate(fd, "q", suffix=""), "suffix"),
        # the derivative would overwrite a channel the record has (measured, or another)
        (lambda x, fd: differentiate(fd, "q"), "'q_dot'"),
        (lambda x, fd: differentiate(fd, "al", suffix="pha"), "'alpha'"),
    ],
)
def test_bad_options_name_the_culprit(call, match) -> None:
    x, dx, _ = _band_limited()
    fd = FlightData(T, {"q": x, "q_dot": dx, "al": x, "alpha": x})
    with pytest.raises(DataFormatError, match=match):
        call(x, fd)


def test_public_entry_points_limit_blas_threads():
    # wrapped by `small_blas`, as every numerical entry point of the library
    for fn in (smooth, differentiate, optimal_cutoff):
        assert hasattr(fn, "__wrapped__"), fn.__name__


def test_band_limited_data_without_noise_floor_are_named() -> None:
    import warnings

    from aeroid.io.smoothing import NoiseFloorWarning

    # a sine not periodic over the record: its end-point-detrended spectrum falls as
    # 1/m^4 to the top of the band, with no white floor to find
    t = T[:-1]
    clean = np.sin(2 * np.pi * 0.5 * t) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    with pytest.warns(NoiseFloorWarning, match=r"x: no noise floor.*falls.*cutoff="):
        out = smooth(clean, dt=DT)
    assert np.max(np.abs(out - clean)) < 1e-3  # nearly the input, as the warning says
    # sine terms of the series itself: the floor is round-off, the output the input
    exact, _, _ = _band_limited()
    with pytest.warns(NoiseFloorWarning, match="round-off"):
        assert np.allclose(smooth(exact, dt=DT), exact, rtol=0, atol=1e-12)
    data = FlightData(t, {"alpha": clean, "beta": clean})
    with pytest.warns(NoiseFloorWarning, match="channel 'alpha'"):
        smooth(data, "alpha")
    noisy = clean + 1e-2 * np.random.default_rng(1).standard_normal(t.size)
    with pytest.warns(NoiseFloorWarning, match=r"x\[:, 1\]"):
        smooth(np.column_stack([noisy, clean]), dt=DT)
    # white noise on top: a floor, no warning, over many seeds and lengths
    with warnings.catch_warnings():
        warnings.simplefilter("error", NoiseFloorWarning)
        for seed in range(40):
            rng = np.random.default_rng(seed)
            for n in (64, 501, 2001):
                y = np.sin(0.05 * np.arange(n)) + 1e-2 * rng.standard_normal(n)
                smooth(y, dt=DT)
        smooth(clean, dt=DT, cutoff=2.0)  # a given cut-off needs no floor
        smooth(noisy, dt=DT)


def _savgol_window(out: np.ndarray, x: np.ndarray, deriv: int = 0) -> int:
    """The window of the Savitzky–Golay filter (cubic) the local output equals."""
    from scipy.signal import savgol_filter

    for w in range(5, 601, 2):
        ref = savgol_filter(x, w, 3, deriv=deriv, delta=DT, mode="interp")
        if np.max(np.abs(out - ref)) < 1e-9 * max(1.0, float(np.max(np.abs(ref)))):
            return w
    raise AssertionError("no Savitzky-Golay window reproduces the output")


def _minus3db(window: int) -> float:
    from scipy.signal import freqz, savgol_coeffs

    f, h = freqz(savgol_coeffs(window, 3), worN=40000, fs=1.0 / DT)
    return float(f[np.argmax(np.abs(h) < 2**-0.5)])


@pytest.mark.parametrize("sigma", [0.002, 0.02, 0.2])
@pytest.mark.parametrize("order", [0, 1])
def test_local_window_is_near_the_best_window_for_the_record(sigma: float, order: int) -> None:
    # the window minimises the Fourier method's estimated squared error: its actual
    # error against the truth is near the best any window achieves (the oracle)
    from scipy.signal import savgol_filter

    n = 1001
    t = np.arange(n) * DT
    x0 = np.sin(2 * np.pi * 0.7 * t + 0.3) + 0.5 * np.sin(2 * np.pi * 1.3 * t)
    dx0 = 2 * np.pi * (0.7 * np.cos(2 * np.pi * 0.7 * t + 0.3) + 0.65 * np.cos(2 * np.pi * 1.3 * t))
    truth = dx0 if order else x0
    mid = slice(50, -50)  # away from the ends' polynomial extrapolation
    ratios = []
    for seed in range(4):
        x = x0 + sigma * np.random.default_rng(seed).standard_normal(n)
        out = np.asarray(
            differentiate(x, dt=DT, method="local") if order else smooth(x, dt=DT, method="local")
        )
        err = np.sqrt(np.mean((out - truth)[mid] ** 2))
        best = min(
            np.sqrt(np.mean((savgol_filter(x, w, 3, deriv=order, delta=DT) - truth)[mid] ** 2))
            for w in range(5, 400, 2)
        )
        ratios.append(err / best)
    assert np.median(ratios) < 1.3, ratios


def test_local_window_keeps_a_tone_below_the_cutoff() -> None:
    # the -3 dB point at the Fourier cut-off lost 4-13 % of a tone at two thirds of it
    n = 501
    t = np.arange(n) * DT
    ref = np.pi * np.cos(np.pi * t)[25:-25]
    gains = []
    for seed in range(20):
        x = np.sin(2 * np.pi * 0.5 * t) + 0.05 * np.random.default_rng(seed).standard_normal(n)
        d = np.asarray(differentiate(x, dt=DT, method="local"))[25:-25]
        gains.append(float(d @ ref / (ref @ ref)))
    assert abs(np.mean(gains) - 1.0) < 0.015, gains
    assert min(gains) > 0.95, gains


def test_local_window_follows_a_given_cutoff() -> None:
    n = 801
    t = np.arange(n) * DT
    x = np.sin(2 * np.pi * 0.5 * t) + 0.05 * np.random.default_rng(1).standard_normal(n)
    windows = []
    for fc in (0.8, 2.0, 5.0):
        w = _savgol_window(np.asarray(smooth(x, dt=DT, method="local", cutoff=fc)), x)
        assert abs(_minus3db(w) / fc - 1.0) < 0.1, (fc, w)
        windows.append(w)
    assert windows[0] > windows[1] > windows[2]
