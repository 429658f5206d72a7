"""Stored plans (issue 49): ``aeroid status`` on an unchanged campaign reads the keys a
run or an earlier status stored instead of planning, any change to what the keys
depend on plans afresh, and planning streamed a flight at a time holds little a flight.
"""

from __future__ import annotations

import json
import os
import tracemalloc
from pathlib import Path

import pytest
from test_cli import invoke, make_campaign, write_flight
from test_pipeline_objectstore import _CREDENTIALS, s3_endpoint, s3_url  # noqa: F401 (fixtures)

from aeroid.cli import _status_json
from aeroid.errors import PipelineError, StoreError
from aeroid.pipeline import open_store, run
from aeroid.pipeline.plans import plan_cache, planning
from aeroid.pipeline.plans.config import load_config
from aeroid.pipeline.plans.planning import plan, plan_stream, stored_plan
from aeroid.pipeline.storage.store import ResultStore


def _status(cfg: Path, *extra: str) -> tuple[dict, str]:
    code, out, err = invoke("status", str(cfg), "--json", *extra)
    assert code == 0, err
    return json.loads(out), out


def _expected(cfg: Path, store: ResultStore) -> list[tuple[str, str | None, str, str]]:
    """(step, flight, key, status) of every task, from a fresh plan."""
    fresh = plan(cfg)
    return [
        (t.step, t.flight, t.key, "stored" if store.exists(t.stage, t.key) else "missing")
        for t in fresh.tasks
    ]


def _shown(doc: dict) -> list[tuple[str, str | None, str, str]]:
    return [(t["stage"], t["flight"], t["key"], t["status"]) for t in doc["tasks"]]


def _refuse_planning(monkeypatch: pytest.MonkeyPatch) -> None:
    def planned(*_: object, **__: object) -> None:
        raise AssertionError("status planned the campaign's flights")

    monkeypatch.setattr(planning, "_tasks", planned)


def test_status_reads_the_plan_a_run_stored_and_it_is_the_fresh_plan(tmp_path, monkeypatch):
    cfg = make_campaign(tmp_path, n=3)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    fresh = plan(cfg)
    stored = plan_cache.load(store, fresh.inputs)
    assert stored == list(plan_cache.rows(fresh.tasks))
    assert len(stored) == 7 and stored[-1].flight is None  # the campaign report
    with monkeypatch.context() as m:
        _refuse_planning(m)
        doc, text = _status(cfg)
    assert _shown(doc) == _expected(cfg, store) and doc["missing"] == 0
    # the same text as planning gives, without the stored plan
    for name in os.listdir(tmp_path / "store" / ".plans"):
        os.remove(tmp_path / "store" / ".plans" / name)
    assert _status(cfg)[1] == text
    assert plan_cache.load(store, fresh.inputs) == stored  # that status stored it again


def _rewrite_keeping_size_and_time(path: Path) -> None:
    info = path.stat()
    raw = path.read_bytes()
    at = raw.index(b"\n") + 3  # a digit of the first row's time
    digit = raw[at : at + 1]
    assert digit.isdigit()
    path.write_bytes(raw[:at] + (b"1" if digit != b"1" else b"2") + raw[at + 1 :])
    os.utime(path, ns=(info.st_atime_ns, info.st_mtime_ns))
    assert path.stat().st_size == info.st_size and path.stat().st_mtime_ns == info.st_mtime_ns


def _change(what: str, tmp_path: Path, cfg: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if what == "flight file":
        write_flight(tmp_path / "flights" / "f01.csv", 17)
    elif what == "flight file, same size and time":
        _rewrite_keeping_size_and_time(tmp_path / "flights" / "f01.csv")
    elif what == "new flight file":
        write_flight(tmp_path / "flights" / "f09.csv", 9)
    elif what == "config":
        cfg.write_text(cfg.read_text().replace("n_boot: 50", "n_boot: 60"))
    elif what == "stage version":
        module = tmp_path / "user_pipeline.py"
        module.write_text(module.read_text().replace('Stage("stats", "1"', 'Stage("stats", "2"'))
    elif what == "aeroid code":
        monkeypatch.setattr(plan_cache, "_code_digest", lambda: "0" * 64)
    else:
        raise AssertionError(what)


@pytest.mark.parametrize(
    "what",
    [
        "flight file",
        "flight file, same size and time",
        "new flight file",
        "config",
        "stage version",
        "aeroid code",
    ],
)
def test_any_change_the_keys_depend_on_plans_afresh(tmp_path, monkeypatch, what):
    cfg = make_campaign(tmp_path, n=3)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    before = plan(cfg)
    assert stored_plan(store, load_config(cfg)) == list(plan_cache.rows(before.tasks))
    _change(what, tmp_path, cfg, monkeypatch)
    after = plan(cfg)
    assert after.inputs != before.inputs
    assert stored_plan(store, load_config(cfg)) is None
    doc, _ = _status(cfg)
    assert _shown(doc) == _expected(cfg, store)
    # what changed is not stored yet (new code may plan the same keys: all stored)
    assert doc["missing"] >= (what != "aeroid code")
    # that status stored the new plan: the next one reads it
    assert stored_plan(store, load_config(cfg)) == list(plan_cache.rows(after.tasks))
    with monkeypatch.context() as m:
        _refuse_planning(m)
        assert _status(cfg)[0] == doc


def test_a_plan_is_kept_for_the_store_it_is_in_and_old_ones_go(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    store = open_store(tmp_path / "store", create=True)
    fresh = plan(cfg)
    rows = list(plan_cache.rows(fresh.tasks))
    assert plan_cache.save(store, fresh.inputs, rows)
    assert not plan_cache.save(store, fresh.inputs, rows)  # one a set of inputs
    others = [f"{i:064x}" for i in range(1, 7)]
    for inputs in others:
        assert plan_cache.save(store, inputs, rows)
    names = sorted(os.listdir(tmp_path / "store" / ".plans"))
    assert len(names) == plan_cache._MAX_PLANS
    assert [n.split("-")[1] for n in names] == [f"{o}.plan" for o in others[-4:]]
    assert plan_cache.load(store, fresh.inputs) is None
    assert plan_cache.load(store, others[-1]) == rows  # the rows, under any inputs


@pytest.mark.parametrize("damage", ["cut short", "bytes flipped", "another plan's inputs"])
def test_a_damaged_stored_plan_is_ignored_and_replaced(tmp_path, monkeypatch, damage):
    cfg = make_campaign(tmp_path, n=2)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    fresh = plan(cfg)
    (path,) = (tmp_path / "store" / ".plans").iterdir()
    raw = path.read_bytes()
    if damage == "cut short":
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "bytes flipped":
        path.write_bytes(raw[:20] + bytes(b ^ 0x5A for b in raw[20:40]) + raw[40:])
    else:
        other = plan_cache._document("f" * 64, plan_cache.rows(fresh.tasks))
        path.write_bytes(other)
    assert plan_cache.load(store, fresh.inputs) is None
    doc, _ = _status(cfg)  # planned afresh, and the plan stored again
    assert _shown(doc) == _expected(cfg, store) and doc["missing"] == 0
    assert plan_cache.load(store, fresh.inputs) == list(plan_cache.rows(fresh.tasks))


def test_a_read_only_store_keeps_no_plan_and_status_still_answers(tmp_path, monkeypatch):
    cfg = make_campaign(tmp_path, n=2)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    fresh = plan(cfg)

    def refused(*_: object, **__: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(type(store._backend), "write_plan", refused)
    assert not plan_cache.save(store, "e" * 64, plan_cache.rows(fresh.tasks))
    doc, _ = _status(cfg)
    assert _shown(doc) == _expected(cfg, store)


def test_status_before_any_run_plans_and_makes_no_store(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    doc, _ = _status(cfg)
    assert doc["stored"] == 0 and doc["missing"] == 5
    assert not (tmp_path / "store").exists()


def test_the_stream_gives_the_plan_a_flight_at_a_time(tmp_path):
    cfg = make_campaign(tmp_path, n=3)
    whole = plan(cfg)
    stream = plan_stream(cfg)
    assert stream.inputs == whole.inputs and stream.flights == []
    batches = list(stream.batches(2))
    assert [len(b) for b in batches] == [2, 2, 2, 1]
    streamed = [t for b in batches for t in b]
    assert [(t.key, t.canonical, t.options, t.upstream) for t in streamed] == [
        (t.key, t.canonical, t.options, t.upstream) for t in whole.tasks
    ]
    assert stream.flights == whole.flights == ["f00", "f01", "f02"]
    with pytest.raises(PipelineError, match="iterated once"):
        list(stream)


def _simulated(tmp_path: Path, n: int) -> Path:
    cfg = tmp_path / f"sim{n}.yaml"
    cfg.write_text(
        "model: short_period\nseed: 1\nstore: store\nflights:\n"
        f"  - simulated: {{n_flights: {n}, seed: 3, duration: 2.0, sample_rate: 10.0}}\n"
        "stages:\n  identify: {}\n"
    )
    return cfg


def _held_streaming(cfg: Path) -> tuple[int, int]:
    """(bytes traced once every flight's tasks came and went, flights)."""
    stream = plan_stream(cfg)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tasks = iter(stream)
        while next(tasks).flight is not None:  # up to the first campaign task
            pass
        return tracemalloc.get_traced_memory()[0] - base, len(stream.flights)
    finally:
        tracemalloc.stop()


def test_a_streamed_plan_holds_a_few_hundred_bytes_a_flight(tmp_path):
    # what a plan holds for every flight at once, a stream holds for one: of a flight
    # it keeps the name, the load key (a flight listed twice is refused) and the keys
    # the campaign steps take; a whole plan holds several kB a flight
    small, n_small = _held_streaming(_simulated(tmp_path, 300))
    large, n_large = _held_streaming(_simulated(tmp_path, 3000))
    assert (n_small, n_large) == (300, 3000)
    per_flight = (large - small) / (n_large - n_small)
    tracemalloc.start()
    try:
        whole = plan(_simulated(tmp_path, 3000))
        held = tracemalloc.get_traced_memory()[0] / len(whole.flights)
    finally:
        tracemalloc.stop()
    # its name (60 B), its load key and the keys of the two steps the campaign steps
    # take (113 B each), and their places in lists, a set and a dict
    assert per_flight < 1200, per_flight
    assert held > 4 * per_flight, (held, per_flight)


def test_stored_looks_up_many_keys_with_one_listing_and_agrees_with_exists(tmp_path):
    store = open_store(tmp_path / "store", create=True)
    keys = [f"{i:064x}" for i in range(600)]
    (tmp_path / "store" / "identify").mkdir()
    for k in keys[::3]:
        (tmp_path / "store" / "identify" / f"{k}.zarr.zip").write_bytes(b"")
    asked = [("identify", k) for k in keys] + [("validate", keys[0])]
    expected = {(s, k) for s, k in asked if store.exists(s, k)}
    assert len(expected) == 200
    assert store.stored(asked) == expected
    assert store.stored(asked[:10]) == expected & set(asked[:10])  # a look per key
    with pytest.raises(StoreError, match=r"key '\.\./x' is not a valid name"):
        store.stored([*asked, ("identify", "../x")])


def test_the_status_document_is_what_json_dumps_writes():
    from aeroid.pipeline.plans.plan_cache import PlannedTask

    tasks = [
        PlannedTask("load", "load", 'odd "name" é\n', "a" * 64),
        PlannedTask("report", "campaign_report", None, "b" * 64),
    ]
    for shown, ok in ((tasks, [True, False]), ([], [])):
        doc = {
            "stored": sum(ok),
            "missing": len(ok) - sum(ok),
            "store": "/somewhere/ü",
            "tasks": [
                {
                    "stage": t.step,
                    "flight": t.flight,
                    "key": t.key,
                    "status": "stored" if s else "missing",
                }
                for t, s in zip(shown, ok, strict=True)
            ],
        }
        assert _status_json(sum(ok), "/somewhere/ü", shown, ok) == json.dumps(doc, indent=2)


@pytest.mark.slow
def test_a_plan_is_stored_in_an_object_store_too(tmp_path, s3_url, monkeypatch):  # noqa: F811
    cfg = make_campaign(tmp_path, n=2)
    run(cfg, store=s3_url, workers=0)
    store = open_store(s3_url)
    fresh = plan(cfg)
    assert plan_cache.load(store, fresh.inputs) == list(plan_cache.rows(fresh.tasks))
    with monkeypatch.context() as m:
        _refuse_planning(m)
        doc, _ = _status(cfg, "--store", s3_url)
    assert doc["missing"] == 0 and [t["key"] for t in doc["tasks"]] == [t.key for t in fresh.tasks]


def test_a_store_that_lost_its_marker_with_a_stored_plan_is_still_repaired(tmp_path):
    from aeroid.pipeline.storage._backend import _CHECKED

    cfg = make_campaign(tmp_path, n=2)
    run(cfg, workers=0)
    root = tmp_path / "store"
    assert list((root / ".plans").iterdir())
    (root / "aeroid-store.json").unlink()  # emptied mid-run: the run's entries came back
    _CHECKED.clear()  # as a fresh process would
    code, out, _ = invoke("verify", "--remove", "--store", str(root))
    assert code == 0, out
    assert (root / "aeroid-store.json").is_file()
    doc, _ = _status(cfg)
    assert doc["missing"] == 0
