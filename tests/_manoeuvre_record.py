"""A synthetic flight record with five known manoeuvres, for segmentation tests and benchmarks."""

from __future__ import annotations

import numpy as np

from aeroid import FlightData

NOISE = {"elevator": 0.002, "aileron": 0.003, "rudder": 0.002}
AMPLITUDE = {"elevator": 0.05, "aileron": 0.08, "rudder": 0.06}


def _sweep(tau: np.ndarray, length: float, f0: float, f1: float) -> np.ndarray:
    phase = 2 * np.pi * (f0 * tau + (f1 - f0) * tau**2 / (2 * length))
    return np.where((tau >= 0) & (tau < length), np.sin(phase), 0.0)


def _pulses(tau: np.ndarray, widths: list[float], signs: list[int]) -> np.ndarray:
    out = np.zeros_like(tau)
    edge = 0.0
    for w, s in zip(widths, signs, strict=True):
        out[(tau >= edge) & (tau < edge + w)] = s
        edge += w
    return out


def manoeuvre_record(
    seed: int, *, rate: float = 50.0, duration: float = 200.0
) -> tuple[FlightData, list[tuple[float, float]]]:
    """Inputs with noise and drifting trim, and the true (start, end) of each excitation.

    1. elevator doublet, 2. elevator 3-2-1-1, 3. aileron sweep 0.2 to 2 Hz,
    4. rudder doublet with an aileron doublet 1 s later, 5. elevator sweep 0.5 to 3 Hz
    with a rudder sweep 0.3 to 2 Hz.
    Starts move by up to 3 s, widths, lengths and amplitudes by up to 30 %.
    """
    rng = np.random.default_rng(seed)
    time = np.arange(round(duration * rate) + 1) / rate
    amp = {k: v * rng.uniform(0.7, 1.3) for k, v in AMPLITUDE.items()}
    excitation = {k: np.zeros_like(time) for k in AMPLITUDE}
    truth = []
    s = 20 + rng.uniform(-3, 3)
    w = rng.uniform(0.7, 1.3)
    excitation["elevator"] += amp["elevator"] * _pulses(time - s, [w, w], [1, -1])
    truth.append((s, s + 2 * w))
    s = 55 + rng.uniform(-3, 3)
    w = rng.uniform(0.35, 0.65)
    excitation["elevator"] += amp["elevator"] * _pulses(
        time - s, [3 * w, 2 * w, w, w], [1, -1, 1, -1]
    )
    truth.append((s, s + 7 * w))
    s = 90 + rng.uniform(-3, 3)
    length = rng.uniform(8, 12)
    excitation["aileron"] += amp["aileron"] * _sweep(time - s, length, 0.2, 2.0)
    truth.append((s, s + length))
    s = 125 + rng.uniform(-3, 3)
    w = rng.uniform(0.7, 1.3)
    excitation["rudder"] += amp["rudder"] * _pulses(time - s, [w, w], [1, -1])
    excitation["aileron"] += amp["aileron"] * _pulses(time - s - 1.0, [w, w], [-1, 1])
    truth.append((s, s + 1.0 + 2 * w))
    s = 160 + rng.uniform(-3, 3)
    length = rng.uniform(4, 7)
    excitation["elevator"] += amp["elevator"] * _sweep(time - s, length, 0.5, 3.0)
    excitation["rudder"] -= amp["rudder"] * _sweep(time - s, length, 0.3, 2.0)
    truth.append((s, s + length))
    channels = {}
    for name in AMPLITUDE:
        # trim drifts slowly: a few noise levels over the record
        period, phase = rng.uniform(150, 400), rng.uniform(0, 2 * np.pi)
        trim = rng.uniform(-0.05, 0.05) + 0.01 * np.sin(2 * np.pi * time / period + phase)
        trim = trim + rng.uniform(-1, 1) * 0.01 * time / duration
        noise = NOISE[name] * rng.standard_normal(time.size)
        channels[name] = trim + excitation[name] + noise
    data = FlightData(time, channels, dict.fromkeys(channels, "rad"), {"source": f"seed {seed}"})
    return data, truth
