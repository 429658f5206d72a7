"""The held-out flights flown again with the exported database (issue 51, the report's replay)."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from aeroid.pipeline.stages._database_report import REPLAY_OUTPUTS, r_squared, replay_section


def test_r_squared_closed_form() -> None:
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert r_squared(y, y) == 1.0
    assert r_squared(y, np.full(4, 2.5)) == 0.0
    assert r_squared(y, y + 1.0) == pytest.approx(1.0 - 4.0 / 5.0)


def _own_section() -> str:
    jsbsim = pytest.importorskip("jsbsim")
    xml = (Path(jsbsim.get_default_root_dir()) / "aircraft" / "c172x" / "c172x.xml").read_text()
    return xml[xml.find("<aerodynamics") : xml.find("</aerodynamics>") + len("</aerodynamics>")]


def test_a_calm_record_replayed_with_its_own_aerodynamics_is_the_record() -> None:
    # in calm air and without noise the recorded surfaces (pilot's corrections included)
    # fly the same aircraft along the same path: only the integration's round-off differs
    pytest.importorskip("jsbsim")
    from aeroid.adapters.jsbsim_flights import FlightCondition, fly_c172x, replay_c172x

    cond = FlightCondition(28.0, 500.0)  # the slow end: alpha 9 deg
    record = fly_c172x(cond, turbulence=0.0, noise=False, seed=1)
    flown = replay_c172x(record, cond)
    for ch in (*REPLAY_OUTPUTS, "V", "theta", "phi"):
        assert r_squared(record[ch], flown[ch]) > 0.999, ch
    assert np.max(np.abs(record["alpha"] - flown["alpha"])) < 5e-4
    # the section in the aircraft's own file, read back from text: the same flight
    again = replay_c172x(record, cond, aerodynamics=_own_section())
    assert np.max(np.abs(again["alpha"] - flown["alpha"])) < 1e-9


def _fake(tmp_path: Path, record: object, replay: str | None) -> tuple[object, object, object]:
    task = SimpleNamespace(
        flights=("flight_a", "flight_b"),
        upstream={"data": ["key-a", "key-b"]},
        upstream_stages={"data": "load"},
        options={"replay": replay, "held_out": ["flight_b"]},
    )
    store = SimpleNamespace(load=lambda key, stage: record if key == "key-b" else None)
    return SimpleNamespace(), store, task


def test_the_section_flies_each_held_out_flight_and_plots_it(tmp_path: Path) -> None:
    pytest.importorskip("jsbsim")
    from aeroid.adapters.jsbsim_flights import FlightCondition, fly_c172x

    record = fly_c172x(FlightCondition(40.0, 1000.0), turbulence=0.0, noise=False, seed=2)
    (tmp_path / "aerodynamics.xml").write_text(_own_section())
    plan, store, task = _fake(tmp_path, record, "c172x")
    text, files = replay_section(plan, store, task, ["flight_b"], tmp_path)  # type: ignore[arg-type]
    assert "| flight_b |" in text and "alpha" in text
    row = next(line for line in text.splitlines() if line.startswith("| flight_b"))
    values = [float(c.split("(")[0]) for c in row.split("|")[2:-1]]
    assert len(values) == 5 and min(values) > 0.99  # the own section, a calm record
    assert files == {"flight_b replay": "replay_flight_b.png"}
    assert (tmp_path / "replay_flight_b.png").read_bytes()[:4] == b"\x89PNG"


def test_the_section_says_why_it_does_not_fly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    record = SimpleNamespace(metadata={"airspeed": 40.0}, names=())
    plan, store, task = _fake(tmp_path, record, None)
    text, files = replay_section(plan, store, task, ["flight_b"], tmp_path)  # type: ignore[arg-type]
    assert "names no simulator" in text and "c172x" in text and files == {}
    assert replay_section(plan, store, task, [], tmp_path) == ("", {})  # type: ignore[arg-type]
    plan, store, task = _fake(tmp_path, record, "c172x")
    monkeypatch.setitem(sys.modules, "jsbsim", None)  # not installed
    text, _ = replay_section(plan, store, task, ["flight_b"], tmp_path)  # type: ignore[arg-type]
    assert "jsbsim is not installed" in text
    monkeypatch.undo()
    if "jsbsim" not in sys.modules:
        pytest.importorskip("jsbsim")
    text, _ = replay_section(plan, store, task, ["flight_b"], tmp_path)  # type: ignore[arg-type]
    assert "no JSBSim section" in text
    (tmp_path / "aerodynamics.xml").write_text("<aerodynamics/>")
    text, _ = replay_section(plan, store, task, ["flight_b"], tmp_path)  # type: ignore[arg-type]
    assert "flight_b: not flown, its condition lacks altitude" in text
