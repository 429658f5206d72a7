"""Frequency-response summaries: the mean coherence runs over the frequencies judged."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog
from aeroid.models.catalog import frequency_sweep


@pytest.fixture(scope="module")
def sweep() -> aeroid.FlightData:
    """A 60 s 0.1–3 Hz elevator sweep of the catalog short period (seeded)."""
    t = np.linspace(0.0, 60.0, 3001)
    elevator = frequency_sweep(t, start=1.0, f0=0.1, f1=3.0, amplitude=0.03)
    return catalog.short_period_flight(duration=60.0, elevator=elevator, seed=3)


def _rows(text: str) -> list[dict[str, str]]:
    lines = [ln for ln in text.splitlines() if ln.startswith("|")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    return [
        dict(zip(head, (c.strip() for c in ln.strip("|").split("|")), strict=True))
        for ln in lines[2:]
    ]


def test_frequency_response_mean_coherence_is_over_the_coherent_band(sweep):
    model = catalog.short_period()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = aeroid.identify(model, sweep, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
        fr = aeroid.frequency_response(model, sweep, result)
    rows = {r["output"]: r for r in _rows(fr.summary())}
    for output in ("alpha", "q"):
        c = fr.channel("elevator", output)
        gamma2 = np.asarray(c.coherence)
        coherent = float(np.mean(gamma2[np.asarray(c.coherent)]))
        # the grid runs to 25 Hz, far past the 3 Hz sweep: its mean is much lower
        assert float(np.mean(gamma2)) < 0.5 * coherent
        assert rows[output]["mean γ² (coherent freqs)"] == f"{coherent:.3g}"
    # q: 0.933 over its 181 coherent frequencies (0.294 over the whole grid before)
    assert rows["q"]["mean γ² (coherent freqs)"] == "0.933"


def test_composite_response_mean_coherence_is_over_its_coherent_band(sweep):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        composite = aeroid.composite_response(sweep, "elevator", "q")
    c = composite.channel("elevator", "q")
    gamma2 = np.asarray(c.coherence)
    ok = gamma2 >= 0.6
    assert float(np.mean(gamma2)) < float(np.mean(gamma2[ok])) - 0.1
    (row,) = _rows(composite.summary())
    assert row["mean γ² (γ² ≥ 0.6)"] == f"{float(np.mean(gamma2[ok])):.3g}"
