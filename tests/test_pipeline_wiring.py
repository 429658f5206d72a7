"""The engine's wiring of the store and the planner: cache hits checked, runs sharing a store
claiming tasks, per-flight models, segments as flights."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from aeroid.cli import main
from aeroid.errors import ConfigError
from aeroid.pipeline import open_store, plan, run
from aeroid.pipeline.keys import model_fingerprint
from aeroid.pipeline.plans.planning import resolve_model


def _sim_config(tmp: Path, n: int = 2) -> Path:
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        f"flights: [{{simulated: {{n_flights: {n}, seed: 1, duration: 4.0}}}}]\n"
        "stages:\n  identify: {parameters: [M_q, M_delta]}\n  validate: {}\n"
        "  campaign_report: {figures: false}\n"
    )
    return cfg


# -- cache hits are checked -------------------------------------------------------------


def test_a_damaged_cache_hit_is_reported_corrupt_not_cached(tmp_path):
    cfg = _sim_config(tmp_path)
    first = run(cfg, workers=0)
    assert first.failed == 0
    t = next(t for t in first.plan.tasks if t.step == "identify")
    path = Path(open_store(tmp_path / "store").path_for(t.stage, t.key))
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 3] ^= 0xFF  # a flipped bit inside a member: its CRC-32 fails
    os.chmod(path, 0o644)
    path.write_bytes(bytes(raw))
    again = run(cfg, workers=0)
    status = again.statuses[t.key]
    assert status.status == "failed" and " is corrupt: " in status.error
    others = [s for k, s in again.statuses.items() if s.flight != t.flight and s.flight]
    assert others and all(s.status == "cached" for s in others)


# -- runs sharing a store ---------------------------------------------------------------


@pytest.mark.slow
def test_two_runs_on_one_store_compute_each_task_once(tmp_path):
    cfg = _sim_config(tmp_path, n=4)
    cmd = [sys.executable, "-m", "aeroid.cli", "run", str(cfg), "--workers", "0", "--json", "-q"]
    procs = [
        subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    docs = []
    for p in procs:
        out, err = p.communicate(timeout=240)
        assert p.returncode == 0, err
        docs.append(json.loads(out))
    n_tasks = len(plan(cfg).tasks)
    for doc in docs:
        assert len(doc["tasks"]) == n_tasks
        assert doc["computed"] + doc["cached"] + doc["by_another_run"] == n_tasks, doc
        assert doc["failed"] == 0
        assert {t["status"] for t in doc["tasks"]} <= {"computed", "cached", "by_another_run"}
    # every task computed exactly once across both runs
    computed = [t["key"] for doc in docs for t in doc["tasks"] if t["status"] == "computed"]
    assert sorted(computed) == sorted({t["key"] for t in docs[0]["tasks"]})
    store = open_store(tmp_path / "store")
    assert store.verify_all() == {}
    assert not list((tmp_path / "store").rglob("*.claim"))


# -- verify and gc say what is wrong --------------------------------------------------------


def test_verify_and_gc_refuse_a_linked_folder_with_a_message(tmp_path):
    cfg = _sim_config(tmp_path)
    assert run(cfg, workers=0).failed == 0
    outside = tmp_path / "outside"
    outside.mkdir()
    store = tmp_path / "store"
    (store / ".tmp").rename(tmp_path / "old-tmp") if (store / ".tmp").exists() else None
    (store / ".tmp").symlink_to(outside)
    (store / "validate").rename(tmp_path / "validate-moved")
    (store / "validate").symlink_to(outside)
    for args in (["verify", "--store", str(store)], ["gc", "--store", str(store)]):
        out = CliRunner().invoke(main, args)
        assert out.exit_code == 1, (args, out.output)
        assert "symbolic link" in out.output and "Traceback" not in out.output
        assert out.exception is None or isinstance(out.exception, SystemExit)


# -- per-flight models -------------------------------------------------------------------


_LON = (
    "model:\n  aircraft: longitudinal_linear\n  V0: 50.0\n"
    "  parameters: {Z_alpha: -1.2, M_alpha: -4.0, M_q: -2.0}\n"
)


def _csv(path: Path, scale: float) -> None:
    t = np.arange(0.0, 4.0, 0.02)
    rng = np.random.default_rng(int(scale * 10))
    cols = {
        "time": t,
        "delta_e": 0.02 * np.sin(2 * t),
        "V": 50.0 + scale * rng.standard_normal(t.size),
        "alpha": 0.05 * np.sin(t),
        "theta": 0.04 * np.cos(t),
        "q": 0.01 * np.sin(3 * t),
    }
    header = ",".join(cols)
    np.savetxt(
        path, np.column_stack(list(cols.values())), delimiter=",", header=header, comments=""
    )


def _lon_config(tmp: Path, flights: str) -> Path:
    for name, scale in (("a", 1.0), ("b", 2.0)):
        _csv(tmp / f"{name}.csv", scale)
    cfg = tmp / "lon.yaml"
    cfg.write_text(_LON + "store: store\n" + flights + "stages:\n  identify: {parameters: [M_q]}\n")
    return cfg


def test_a_flight_model_override_gives_its_tasks_their_own_model(tmp_path):
    plain = plan(_lon_config(tmp_path, "flights: [a.csv, b.csv]\n"))
    own = plan(
        _lon_config(
            tmp_path,
            "flights:\n  - a.csv\n  - path: b.csv\n    model: {V0: 45.0}\n"
            "    condition: {airspeed: 45.0, altitude: 500.0}\n",
        )
    )
    keys = {(t.step, t.flight): t for t in plain.tasks}
    by = {(t.step, t.flight): t for t in own.tasks}
    # a flight without an override keeps exactly the keys it had
    for step in ("load", "identify"):
        assert by[(step, "a")].key == keys[(step, "a")].key
    # the overridden flight: its model in the keys of the tasks that use one, and resolved
    ident = by[("identify", "b")]
    assert ident.key != keys[("identify", "b")].key
    assert ident.model_ref["spec"]["V0"] == 45.0
    assert ident.model_ref["spec"]["parameters"]["M_q"] == -2.0  # deep-merged, kept
    campaign_model = resolve_model(own.config.model, own.config.base_dir)
    flight_model = resolve_model(ident.model_ref["spec"], ident.model_ref["base_dir"])
    assert model_fingerprint(flight_model) != model_fingerprint(campaign_model)
    assert ident.document["model"] == model_fingerprint(flight_model)
    # the model is no loader option; the condition travels as the engine-only option
    load = by[("load", "b")]
    assert "model" not in load.options
    assert load.options["condition"] == {"airspeed": 45.0, "altitude": 500.0}
    assert "condition" not in by[("load", "a")].options


def test_a_flight_model_override_needs_a_model_mapping(tmp_path):
    for name, scale in (("a", 1.0),):
        _csv(tmp_path / f"{name}.csv", scale)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nstore: store\nflights:\n  - path: a.csv\n    model: {V0: 45.0}\n"
    )
    with pytest.raises(ConfigError, match=r"flights\[0\]\.model"):
        plan(cfg)


def test_a_flight_model_override_is_checked_against_its_own_model(tmp_path):
    cfg = _lon_config(
        tmp_path, "flights:\n  - path: b.csv\n    model: {aircraft: no_such_aircraft}\n"
    )
    with pytest.raises(ConfigError, match="no_such_aircraft"):
        plan(cfg)


# -- segments as flights ------------------------------------------------------------------

PULSES = ((5.0, 2.0), (15.0, 2.0))  # (start, length) of each one-cycle sine, s


def _write_log(path: Path) -> None:
    """An HDF5 log of a first-order response to two aileron pulses (seeded noise)."""
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 24.0, 0.01)
    u = np.zeros_like(t)
    for t0, length in PULSES:
        inside = (t >= t0) & (t <= t0 + length)
        u += np.where(inside, 0.05 * np.sin(2 * np.pi * (t - t0) / length), 0.0)
    y = np.zeros_like(t)
    for i in range(1, t.size):  # y' = (K u - y) / tau, K = 2, tau = 0.5, explicit Euler
        y[i] = y[i - 1] + 0.01 * (2.0 * u[i - 1] - y[i - 1]) / 0.5
    with h5py.File(path, "w") as f:
        g = f.create_group("imu")
        g["time"] = t
        g["p"] = y + 1e-4 * rng.standard_normal(t.size)
        g["u"] = u + 1e-4 * rng.standard_normal(t.size)


_SEGMENTED = (
    "model: first_order\nstore: store\nflights:\n  - path: roll.h5\n"
    "    channels: {y: imu.p, u: imu.u}\n    sample_rate: 50.0\n"
    "    segments: {inputs: [u]}\n"
    "stages:\n  identify: {parameters: [K, tau]}\n"
)


def test_segments_of_a_log_become_flights_with_their_windows_keyed(tmp_path):
    _write_log(tmp_path / "roll.h5")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(_SEGMENTED)
    p = plan(cfg)
    assert p.flights == ["roll-seg1", "roll-seg2"]
    loads = [t for t in p.tasks if t.step == "load"]
    windows = [t.options["window"] for t in loads]
    for (t0, t1), (start, length) in zip(windows, PULSES, strict=True):
        assert t0 < start + 0.05 and t1 > start + length - 0.05
        assert start - 1.5 < t0 and t1 < start + length + 1.5
    assert "segments" not in loads[0].options
    assert loads[0].key != loads[1].key
    assert loads[0].document["options"]["window"] == windows[0]


@pytest.mark.slow
def test_segments_of_a_log_are_each_fitted_as_a_flight(tmp_path):
    _write_log(tmp_path / "roll.h5")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(_SEGMENTED)
    p = plan(cfg)
    s = run(cfg, workers=0)
    assert s.failed == 0, [st.error for st in s.statuses.values() if st.error]
    store = open_store(tmp_path / "store")
    for t in (t for t in p.tasks if t.step == "identify"):
        fit = store.load(t.key, t.stage)
        assert fit.parameters["K"] == pytest.approx(2.0, rel=0.1)
        assert fit.parameters["tau"] == pytest.approx(0.5, rel=0.1)


def test_segments_that_find_nothing_say_so(tmp_path):
    _write_log(tmp_path / "roll.h5")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: first_order\nstore: store\nflights:\n  - path: roll.h5\n"
        "    channels: {y: imu.p, u: imu.u}\n    segments: {inputs: [nope]}\n"
    )
    with pytest.raises(ConfigError, match=r"flights\[0\]"):
        plan(cfg)
