"""What a fractional time delay is: the control's samples delayed on the data grid
(``u(t_k - tau)``) joined by straight lines, not the exact ``u(t - tau)``.

Noise-free known truths of a roll model ``p' = Lp p + Lda da(t - tau)`` at 100 Hz,
integrated exactly (closed form per linear segment of the input, no aeroid), pin
both sides of the documented behaviour (`aeroid.identify`, ``time_delays``)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from aeroid import FlightData, Model, identify

DT, LP, LDA = 0.01, -2.0, -6.5


def _respond(knots: np.ndarray, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """p at the times t (a subset of the knots) for an input linear between knots."""
    p = np.zeros(t.size)
    x, k = 0.0, 1
    for s in range(knots.size - 1):
        h = knots[s + 1] - knots[s]
        e, slope = np.exp(LP * h), (u[s + 1] - u[s]) / h
        x = e * x + LDA * (u[s] * (e - 1.0) / LP + slope * (e - 1.0 - LP * h) / LP**2)
        if k < t.size and abs(knots[s + 1] - t[k]) < 1e-9:
            p[k] = x
            k += 1
    return p


def _record(tau: float, exact: bool) -> FlightData:
    """A 3-2-1-1 aileron and its doublet; the record carries the undelayed aileron.
    `exact`: the response to the continuous ``da(t - tau)``, corners at t_j + tau;
    else to the delayed samples joined on the grid (aeroid's model)."""
    t = np.arange(800) * DT
    da = np.zeros(t.size)
    for a, b, s in [(100, 160, 1), (160, 200, -1), (200, 220, 1), (220, 240, -1)]:
        da[a:b] = 0.02 * s
    da[400:440], da[440:480] = 0.02, -0.02
    moved = np.interp(t - tau, t, da)
    if exact:
        knots = np.union1d(t, t[:-1] + tau)
        knots = knots[knots <= t[-1]]
        u = np.interp(knots - tau, t, da)
    else:
        knots, u = t, moved
    p = _respond(knots, u, t)
    return FlightData(time=t, channels={"p": p, "p_dot": LP * p + LDA * moved, "da": da})


def _fit(data: FlightData) -> float:
    def dynamics(t, x, u, p):  # type: ignore[no-untyped-def]
        return np.array([p["Lp"] * x[0] + p["Lda"] * u[0]])

    def measurement(t, x, u, p):  # type: ignore[no-untyped-def]
        return np.array([x[0], p["Lp"] * x[0] + p["Lda"] * u[0]])

    model = Model(
        states=["p"],
        controls=["da"],
        parameters={"Lp": -1.5, "Lda": -5.0},
        dynamics=dynamics,
        outputs=["p", "p_dot"],
        measurement=measurement,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # noise-free: the residual is zero
        r = identify(
            model,
            data,
            ["Lp", "Lda"],
            x0={"p": 0.0},
            estimate_x0=False,
            time_delays={"da": 0.012},
            error_bars="white",
        )
    assert r.success
    return float(r.time_delays["da"])


@pytest.mark.parametrize("tau", [0.0025, 0.015, 0.0275])
def test_a_fractional_delay_is_the_delayed_samples_joined_on_the_grid(tau: float) -> None:
    # the documented model: recovered to rounding
    assert _fit(_record(tau, exact=False)) == pytest.approx(tau, abs=1e-8 * DT)


@pytest.mark.parametrize("tau", [0.01, 0.02, 0.03])
def test_a_whole_sample_delay_is_exactly_u_of_t_minus_tau(tau: float) -> None:
    # corners on the grid: the exact u(t - tau) is the model, recovered to 1e-6 sample
    assert _fit(_record(tau, exact=True)) == pytest.approx(tau, abs=1e-6 * DT)


@pytest.mark.parametrize("tau", [0.0025, 0.015, 0.0275])
def test_a_fractional_delay_of_the_exact_u_of_t_minus_tau_is_within_1_percent(
    tau: float,
) -> None:
    # the chord cuts the delayed control's corners at t_j + tau: a small bias, not
    # zero (0.25 % of a sample for half a sample here), within the documented 1 %
    bias = (_fit(_record(tau, exact=True)) - tau) / DT
    assert 1e-4 < abs(bias) < 0.01
