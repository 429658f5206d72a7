"""Frozen records survive pickling and copying as they were: read-only arrays stay
read-only, mapping proxies stay proxies, values equal (a process pool, joblib or
``copy.deepcopy`` sees the same immutable record)."""

from __future__ import annotations

import copy
import math
import pickle
import warnings
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog


def _records() -> dict[str, Any]:
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=42)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = aeroid.identify(model, data, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
        return {
            "FlightData": data,
            "IdentificationResult": fit,
            "ValidationResult": aeroid.validate(model, data, fit),
            "PropagationResult": aeroid.propagate(
                fit, lambda p: math.sqrt(-p["M_alpha"]), n_samples=100, seed=0
            ),
            "FrequencyResponseResult": aeroid.frequency_response(model, data, fit),
            "SensitivityResult": aeroid.sensitivities(model, data, ["M_q", "M_delta"]),
        }


RECORDS = _records()


def _same(a: Any, b: Any, where: str) -> None:
    assert type(a) is type(b), where
    if isinstance(a, np.ndarray):
        assert a.flags.writeable == b.flags.writeable, f"{where}: writeable flag"
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, (dict, MappingProxyType)):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif hasattr(a, "__dict__") and type(a).__module__.startswith("aeroid"):
        _same(vars(a), vars(b), where)
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    elif not callable(a):
        assert a == b, where


@pytest.mark.parametrize("copier", ["pickle", "deepcopy", "copy"])
@pytest.mark.parametrize("name", list(RECORDS))
def test_a_frozen_record_comes_back_as_it_was(name, copier):
    record = RECORDS[name]
    if copier == "pickle":
        back = pickle.loads(pickle.dumps(record))
    else:
        back = getattr(copy, copier)(record)
    _same(vars(record), vars(back), name)
    assert back.summary() == record.summary()


def test_an_unpickled_result_refuses_changes_like_the_original():
    fit = pickle.loads(pickle.dumps(RECORDS["IdentificationResult"]))
    with pytest.raises(ValueError, match="read-only"):
        fit.covariance[0, 0] = 1e9
    data = copy.deepcopy(RECORDS["FlightData"])
    with pytest.raises(ValueError, match="read-only"):
        data["alpha"][0] = 1.0
    with pytest.raises(TypeError):
        data.channels["alpha"] = np.zeros(3)  # type: ignore[index]
