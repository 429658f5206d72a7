"""Records as real logs leave them: a dropout, an epoch clock, float32 stamps, a
record that never moves, one too short for spectra. Each is named where it is, or
met with a warning that says what the fit can and cannot tell."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid.errors import DataFormatError, IdentifiabilityWarning
from aeroid.models import catalog


def test_a_dropout_is_named_with_its_time_and_run():
    t = 1.7e9 + np.arange(0.0, 10.0, 0.02)
    alpha = np.sin(t - t[0])
    alpha[200:210] = np.nan
    alpha[400] = np.inf
    with pytest.raises(DataFormatError) as err:
        aeroid.FlightData(t, {"alpha": alpha})
    message = str(err.value)
    assert "index 200 (t = 1700000004 s, a run of 10 samples; 11 in all)" in message


def test_resample_says_where_on_an_epoch_clock():
    t = 1.7e9 + np.arange(0.0, 20.0, 0.0025)
    values = np.sin(t - t[0])
    dropped = values.copy()
    dropped[2000:2010] = np.nan
    with pytest.raises(DataFormatError, match=r"nan value at t = 1700000005 s \(sample 2000\)"):
        aeroid.resample({"a": (t, dropped)}, ["a"], rate=50.0)
    keep = np.r_[0:2000, 2400 : t.size]
    with pytest.raises(
        DataFormatError, match=r"starting at t = 1700000004\.997 s \(after sample 1999"
    ):
        aeroid.resample({"a": (t[keep], values[keep])}, ["a"], rate=50.0)


def test_float32_stamps_too_coarse_for_their_clock_are_refused():
    t = (1.0e5 + np.arange(0.0, 10.0, 0.02)).astype(np.float32)
    with pytest.raises(DataFormatError, match=r"float32 stamps near t = 1000(09|10)"):
        aeroid.FlightData(t, {"a": np.zeros(t.size)})
    t = (1.7e9 + np.arange(0.0, 10.0, 0.02)).astype(np.float32)  # one value per 128 s
    with pytest.raises(DataFormatError, match="float64"):
        aeroid.FlightData(t, {"a": np.zeros(t.size)})
    # a float32 record on its own clock is fine: 50 minutes at 100 Hz round to 2 % of a step
    t = np.arange(0.0, 3000.0, 0.01).astype(np.float32)
    assert aeroid.FlightData(t, {"a": np.zeros(t.size)}).n_samples == t.size


def test_a_record_that_never_moves_is_called_unexcited_without_numpy_noise():
    t = np.arange(501) * 0.02
    zero = np.zeros(t.size)
    data = aeroid.FlightData(t, {"elevator": zero, "alpha": zero, "q": zero})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = aeroid.identify(
            catalog.short_period(), data, ["Z_alpha", "M_alpha", "M_q", "M_delta"]
        )
    assert not any(issubclass(w.category, RuntimeWarning) for w in caught)
    assert any(
        issubclass(w.category, IdentifiabilityWarning) and "not excited" in str(w.message)
        for w in caught
    )
    assert res.response_to_noise == {"alpha": 0.0, "q": 0.0}


def test_frequency_response_names_a_record_too_short_for_spectra():
    t = np.arange(3) * 0.02
    data = aeroid.FlightData(t, {"elevator": [0.0, 1.0, 0.0], "alpha": [0.0] * 3, "q": [0.0] * 3})
    with pytest.raises(DataFormatError, match="3 samples are too few for a frequency response"):
        aeroid.frequency_response(catalog.short_period(), data)
