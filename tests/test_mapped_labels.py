"""load_mapped's unit labels and channel maps: contradictions are refused by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import DataFormatError
from aeroid.io.channel_map import load_mapped
from aeroid.io.data import FlightData

T = np.arange(0.0, 2.0, 0.02)
X = np.sin(T)


def _csv(tmp_path: Path, units: dict[str, str] | None = None) -> Path:
    data = FlightData(T, {"alpha": X, "q": 2 * X, "elevator": -X}, units or {})
    return data.to_csv(tmp_path / "f.csv")


def test_units_label_contradicting_conversion_refused(tmp_path: Path) -> None:
    p = _csv(tmp_path)
    cmap = {"a": {"channel": "alpha", "unit": "deg"}}
    with pytest.raises(DataFormatError, match=r"units\['a'\] = 'deg' contradicts.*'rad'"):
        load_mapped(p, cmap, units={"a": "deg"})
    # a label that says what the values are in is kept
    d = load_mapped(p, cmap, units={"a": "rad"})
    assert d.units["a"] == "rad"
    np.testing.assert_allclose(d["a"], np.deg2rad(X), rtol=1e-12)


def test_units_label_contradicting_stated_unit_refused(tmp_path: Path) -> None:
    p = _csv(tmp_path, {"alpha": "rad"})
    with pytest.raises(DataFormatError, match=r"units\['a'\] = 'deg'.*the file states 'rad'"):
        load_mapped(p, {"a": {"channel": "alpha"}}, units={"a": "deg"})
