"""Degenerate records and responses in the frequency-domain tools: a stuck or dead
channel, a control that never moves, a zero transfer function, an exact zero delay,
a multisine asked for lines it cannot hold. Each gets a clear error (or no false
flag), never numbers that look like a result or a bare numpy exception."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid
from aeroid.errors import IdentificationError, ModelDefinitionError
from aeroid.models import catalog


def _white_record(output: np.ndarray | None = None, input_: np.ndarray | None = None):
    t = np.arange(0.0, 30.0, 0.02)
    u = np.random.default_rng(0).standard_normal(t.size) if input_ is None else input_
    y = np.convolve(u, np.exp(-np.arange(50) * 0.1), mode="full")[: t.size] * 0.1
    return aeroid.FlightData(t, {"u": u, "y": y if output is None else output})


@pytest.mark.parametrize("level", [3.0, 0.0])
def test_a_stuck_or_dead_output_is_refused_not_called_coherent(level: float) -> None:
    # once the segments' means are removed a stuck output's rounding residue read as
    # coherent with the input (gamma^2 up to 0.85) and was fitted without a word
    d = _white_record(output=np.full(1500, level))
    with pytest.raises(IdentificationError, match="output 'y' is constant"):
        aeroid.composite_response(d, "u", "y")
    with pytest.raises(IdentificationError, match="output 'y' is constant"):
        aeroid.fit_transfer_function(
            d, numerator_order=0, denominator_order=1, fourier=True, input="u", output="y"
        )
    with pytest.raises(IdentificationError, match="output 'y' is constant"):
        aeroid.equivalent_system(d, input="u", output="y", kind="roll")


@pytest.mark.parametrize("level", [0.0, 1.0])
def test_an_equivalent_system_needs_an_input_that_moves(level: float) -> None:
    d = _white_record(input_=np.full(1500, level))
    with pytest.raises(IdentificationError, match="input 'u' is constant"):
        aeroid.equivalent_system(d, input="u", output="y", kind="roll")


def test_frequency_domain_identification_refuses_a_control_that_never_moves() -> None:
    d = catalog.short_period_flight(seed=42)
    t = np.asarray(d.time)
    data = aeroid.FlightData(
        t, {"alpha": np.asarray(d["alpha"]), "q": np.asarray(d["q"]), "elevator": np.zeros(t.size)}
    )
    with pytest.raises(IdentificationError, match="every control is constant"):
        aeroid.identify_frequency_domain(
            catalog.short_period(), data, ["Z_alpha", "M_alpha", "M_q", "M_delta"]
        )


def test_a_zero_transfer_function_has_no_bandwidth_or_crossover() -> None:
    with pytest.raises(IdentificationError, match="zero at every frequency"):
        aeroid.bandwidth(([0.0], [1.0, 1.0, 0.0]))
    with pytest.raises(IdentificationError, match="zero at every frequency"):
        aeroid.stability_margins(([0.0], [1.0, 1.0, 0.0]))


@pytest.mark.parametrize(
    ("num", "den", "kind"),
    [([-2.0], [1.0, 4.0], "roll"), ([-5.0, -4.0], [1.0, 3.6, 9.0], "short_period")],
)
def test_an_exact_zero_delay_is_not_flagged_negative(num, den, kind) -> None:
    fit = aeroid.equivalent_system((num, den, 0.0), kind=kind)
    assert abs(fit.parameters["tau"]) < 1e-12
    assert not any("negative" in f for f in fit.flags)
    # a real negative delay still is
    late = aeroid.equivalent_system((num, den, -0.05), kind=kind)
    assert "negative time delay" in late.flags


def test_a_multisine_refuses_a_band_above_nyquist_and_a_wrong_amplitude_count() -> None:
    with pytest.raises(ModelDefinitionError, match="Nyquist"):
        aeroid.orthogonal_multisine(["a"], duration=10, sample_rate=10, band=(0.1, 8.0))
    # up to Nyquist itself is a band it can fill (lines below it)
    ms = aeroid.orthogonal_multisine(["a"], duration=10, sample_rate=10, band=(0.1, 5.0))
    assert ms.frequencies("a").max() < 5.0
    with pytest.raises(ModelDefinitionError, match="amplitudes"):
        aeroid.orthogonal_multisine(
            ["a", "b"], duration=10, sample_rate=10, band=(0.1, 3.0), amplitudes=[1, 2, 3]
        )
