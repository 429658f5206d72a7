"""Built-in models and synthetic manoeuvres (the truth cases of the test suite and demo)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._value_checks import check_seed
from ..errors import SimulationError
from ..io.data import FlightData
from .model import Model

__all__ = [
    "SHORT_PERIOD_GUESS",
    "SHORT_PERIOD_TRUTH",
    "doublet",
    "first_order",
    "frequency_sweep",
    "multisine",
    "short_period",
    "short_period_flight",
]

SHORT_PERIOD_TRUTH: Mapping[str, float] = {
    "Z_alpha": -1.2,
    "M_alpha": -6.0,
    "M_q": -2.5,
    "M_delta": -9.0,
}
SHORT_PERIOD_GUESS: Mapping[str, float] = {
    "Z_alpha": -0.8,
    "M_alpha": -4.0,
    "M_q": -1.5,
    "M_delta": -6.0,
}


def _short_period_dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    alpha, q = x[0], x[1]
    return np.array(
        [
            p["Z_alpha"] * alpha + q,
            p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0],
        ]
    )


def short_period(parameters: Mapping[str, float] | None = None) -> Model:
    """Linear short-period model: states alpha (rad), q (rad/s); control elevator (rad)."""
    return Model(
        states=["alpha", "q"],
        controls=["elevator"],
        parameters=dict(parameters or SHORT_PERIOD_GUESS),
        dynamics=_short_period_dynamics,
        name="short_period",
    )


def _first_order_dynamics(t: Any, x: Any, u: Any, p: Any) -> Any:
    return np.array([(p["K"] * u[0] - x[0]) / p["tau"]])


def first_order(K: float = 2.0, tau: float = 0.5) -> Model:
    """First-order lag ``tau y' = K u - y`` (state and output ``y``, control ``u``)."""
    return Model(
        states=["y"],
        controls=["u"],
        parameters={"K": K, "tau": tau},
        dynamics=_first_order_dynamics,
        name="first_order",
    )


def doublet(
    time: NDArray[np.float64], *, start: float = 1.0, width: float = 1.0, amplitude: float = 0.05
) -> NDArray[np.float64]:
    """A doublet: +amplitude for `width` s from `start`, then -amplitude for `width` s."""
    t = np.asarray(time, dtype=np.float64)
    up = (t >= start) & (t < start + width)
    down = (t >= start + width) & (t < start + 2 * width)
    return amplitude * (up.astype(float) - down.astype(float))


def multisine(
    time: NDArray[np.float64],
    frequencies: NDArray[np.float64] | list[float],
    amplitude: float,
) -> NDArray[np.float64]:
    """Sum of sines with Schroeder phases (low peak factor), one amplitude each."""
    f = np.asarray(frequencies, dtype=np.float64)
    k = np.arange(1, f.size + 1)
    phases = -np.pi * k * (k - 1) / f.size
    t = np.asarray(time, dtype=np.float64)
    return amplitude * np.sin(2 * np.pi * f[None, :] * t[:, None] + phases[None, :]).sum(axis=1)


def frequency_sweep(
    time: NDArray[np.float64],
    *,
    start: float,
    f0: float,
    f1: float,
    amplitude: float,
) -> NDArray[np.float64]:
    """A linear frequency sweep from `f0` to `f1` Hz between `start` and the end of `time`.

    ``amplitude * sin(2π (f0 τ + (f1 - f0) τ² / 2T))`` with ``τ = t - start``
    over the ``T`` seconds left; zero before `start`.
    """
    t = np.asarray(time, dtype=np.float64)
    span = float(t[-1]) - start
    if not span > 0:
        raise ValueError(f"frequency_sweep: start {start} s is not before the end {t[-1]} s")
    tau = np.clip(t - start, 0.0, None)
    phase = 2.0 * np.pi * (f0 * tau + (f1 - f0) * tau**2 / (2.0 * span))
    return np.where(t >= start, amplitude * np.sin(phase), 0.0)


def short_period_flight(
    *,
    parameters: Mapping[str, float] | None = None,
    duration: float = 10.0,
    sample_rate: float = 50.0,
    noise: Mapping[str, float] | None = None,
    seed: int | None = 0,
    elevator: NDArray[np.float64] | None = None,
    colored: float = 0.0,
) -> FlightData:
    """Synthetic short-period flight test: the truth case of the test suite.

    Defaults: truth parameters, a ±0.05 rad elevator doublet with 1 s lobes
    from t = 1 s, 10 s at 50 Hz, noise σ 0.005 rad on alpha and 0.01 rad/s
    on q. ``colored`` (AR(1) coefficient φ) makes the noise coloured with the
    same variance. ``noise={}`` gives noise-free data.
    """
    model = short_period(parameters or SHORT_PERIOD_TRUTH)
    n = round(duration * sample_rate) + 1
    t = np.arange(n) / sample_rate
    u = doublet(t) if elevator is None else np.asarray(elevator, dtype=np.float64)
    sim = model.simulate(t, u, method="exact")
    sig = {"alpha": 0.005, "q": 0.01} if noise is None else dict(noise)
    channels = {"elevator": u, "alpha": sim.output("alpha").copy(), "q": sim.output("q").copy()}
    if sig:
        if check_seed(seed, SimulationError, "short_period_flight: seed") is None:
            raise SimulationError("short_period_flight: noisy data needs a seed")
        rng = np.random.default_rng(seed)
        for name in ("alpha", "q"):
            if name not in sig:
                continue
            e = rng.standard_normal(n)
            if colored:
                # AR(1) with unit stationary variance, started in its stationary state
                w = e * np.sqrt(1.0 - colored**2)
                from scipy.signal import lfilter

                e = lfilter([1.0], [1.0, -colored], w, zi=[colored * e[0]])[0]
            channels[name] = channels[name] + sig[name] * e
    return FlightData(t, channels, {"alpha": "rad", "q": "rad/s", "elevator": "rad"})
