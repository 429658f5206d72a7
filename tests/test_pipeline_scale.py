"""Campaigns beyond one machine: reruns that trust the verified index, requests per
stored result on S3, claims left by a kill, a dask.distributed cluster on an S3 store.

The S3 server is moto's, on loopback, in this process; the cluster is a
`dask.distributed.LocalCluster` of processes (scheduler and workers apart from
this one).
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_cli import make_campaign
from test_pipeline_objectstore import _CREDENTIALS, s3_endpoint, s3_url  # noqa: F401 (fixtures)

from aeroid.pipeline import ResultStore, open_store, run
from aeroid.pipeline.storage import verified


def _arrays(store: ResultStore) -> dict[str, dict[str, bytes]]:
    out = {}
    for entry in store.entries():
        arrays = store.load_arrays(entry.key, entry.stage)
        out[entry.key] = {n: a.dtype.str.encode() + a.tobytes() for n, a in arrays.items()}
    return out


def _refuse_reads(monkeypatch: pytest.MonkeyPatch) -> None:
    def opened(*_: object, **__: object) -> None:
        raise AssertionError("an unchanged rerun opened a stored entry")

    monkeypatch.setattr(ResultStore, "_checked_attributes", opened)


def test_an_unchanged_rerun_trusts_the_index_and_keeps_the_warnings(tmp_path, monkeypatch):
    cfg = make_campaign(tmp_path, n=3, stats="{n_boot: 20, warn: true}")
    first = run(cfg, workers=0)
    assert first.count("computed") == 7 and first.failed == 0
    warned = {t.key: first.statuses[t.key].warnings for t in first.plan.tasks}
    assert any(warned.values())
    index = verified.read_index(open_store(tmp_path / "store"))
    assert len(index.files) == 1 and len(index.entries) == 7
    with monkeypatch.context() as m:
        _refuse_reads(m)
        again = run(cfg, workers=0)
    assert again.count("cached") == 7
    assert {k: s.warnings for k, s in again.statuses.items()} == warned


def test_damage_that_changes_an_entry_is_still_caught_and_verify_finds_the_rest(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    a, b = sorted(store.entries("stats"), key=lambda e: e.key)
    # a write (a careless edit, a copy cut short) changes the entry's size or time:
    # not the entry the index holds, so it is read and its CRC-32 fails
    path = Path(a.path)
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 3] ^= 0xFF
    path.write_bytes(bytes(raw))
    # a bit flipped by the disk keeps size and time: trusted until `verify`
    path_b = Path(b.path)
    stat_b = path_b.stat()
    raw_b = bytearray(path_b.read_bytes())
    raw_b[len(raw_b) // 3] ^= 0xFF
    path_b.write_bytes(bytes(raw_b))
    os.utime(path_b, ns=(stat_b.st_atime_ns, stat_b.st_mtime_ns))
    rerun = run(cfg, workers=0)
    status = {s.key: s for s in rerun.statuses.values()}
    assert status[a.key].status == "failed" and "corrupt" in str(status[a.key].error)
    assert status[b.key].status == "cached"
    bad = store.verify_all()
    assert set(bad) == {a.key, b.key}
    index = verified.read_index(store)
    assert len(index.files) == 1 and not {a.key, b.key} & {k for _, k in index.entries}
    after = run(cfg, workers=0)
    assert {after.statuses[k].status for k in (a.key, b.key)} == {"failed"}


def test_index_files_are_merged_and_a_damaged_one_is_ignored(tmp_path):
    cfg = make_campaign(tmp_path, n=1)
    run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    trusted = verified.read_index(store)
    entries = dict(trusted.entries)
    for i in range(verified._MAX_FILES + 2):
        verified.record(store, {("x", f"{i:064x}"): ((1, "t"), ())}, verified.read_index(store))
    merged = verified.read_index(store)
    assert len(merged.files) <= verified._MAX_FILES
    assert entries.items() <= merged.entries.items() and len(merged.entries) == len(entries) + 10
    (Path(store.root) / ".index" / "0-garbled.json").write_bytes(b'{"format": 1, "entr')
    assert verified.read_index(store).entries == merged.entries
    assert run(cfg, workers=0).count("cached") == 3


def test_a_claim_left_empty_by_a_kill_stalls_nothing(tmp_path):
    cfg = make_campaign(tmp_path, n=1)
    plan_keys = run(cfg, workers=0).plan.tasks
    store = open_store(tmp_path / "store")
    stats = next(t for t in plan_keys if t.stage == "stats")
    store.remove("stats", stats.key)
    (Path(store.root) / "stats" / f"{stats.key}.claim").write_bytes(b"")
    t0 = time.monotonic()
    again = run(cfg, workers=0)
    assert again.statuses[stats.key].status == "computed"
    assert time.monotonic() - t0 < 30.0  # not the minute an empty claim used to hold
    assert not list((Path(store.root) / "stats").glob("*.claim"))


# -- an S3 server: requests per stored result ------------------------------------------


@pytest.fixture
def s3_requests(monkeypatch):
    """Every request s3fs sends, by operation."""
    import s3fs

    calls: collections.Counter[str] = collections.Counter()
    original = s3fs.S3FileSystem._call_s3

    async def counting(self, method, *args, **kwargs):
        calls[method if isinstance(method, str) else getattr(method, "__name__", "?")] += 1
        return await original(self, method, *args, **kwargs)

    monkeypatch.setattr(s3fs.S3FileSystem, "_call_s3", counting)
    return calls


@pytest.mark.slow
def test_at_most_two_requests_per_stored_result_on_s3(tmp_path, s3_url, s3_requests):  # noqa: F811
    cfg = make_campaign(tmp_path, n=8)
    open_store(s3_url, create=True)  # the marker, made once per store
    s3_requests.clear()
    cold = run(cfg, store=s3_url, workers=0)
    n = cold.count("computed")
    assert n == 17 and cold.failed == 0
    cold_requests = dict(s3_requests)
    # the entries, one index file and the stored plan (`plan_cache`)
    assert cold_requests.get("put_object") == n + 2, cold_requests
    # two a result, and two a run for the stored plan (a listing and a PUT)
    assert sum(cold_requests.values()) <= 2 * n + 2, cold_requests
    s3_requests.clear()
    again = run(cfg, store=s3_url, workers=0)
    assert again.count("cached") == n
    # a listing per stage and the index: no request per stored result
    assert sum(s3_requests.values()) <= 10, dict(s3_requests)


# -- a dask.distributed cluster of processes on an S3 store ---------------------------


@pytest.mark.slow
def test_a_cluster_on_s3_stores_what_a_local_run_does_and_survives_a_killed_worker(
    tmp_path,
    s3_endpoint,  # noqa: F811
    s3_url,  # noqa: F811
    monkeypatch,
):
    distributed = pytest.importorskip("distributed")
    # the workers are other processes: they find the server through the environment
    for name, value in _CREDENTIALS.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setenv("FSSPEC_S3_ENDPOINT_URL", s3_endpoint)
    n_flights = 24
    cfg = make_campaign(tmp_path, n=n_flights, stats="{n_boot: 20, sleep: 0.15}")
    local = run(cfg, store=tmp_path / "local", workers=0)
    assert local.failed == 0
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        # the workers' pids, from a client closed before the run opens its own (with
        # this one still open, on another event loop, a run once failed when the worker
        # died: "Event ... is bound to a different event loop")
        with distributed.Client(cluster, set_as_default=False) as client:
            pids = list(client.run(os.getpid).values())
        store = open_store(s3_url, create=True)
        killed: list[int] = []
        import s3fs

        # a filesystem of its own, listing afresh each time (fsspec caches listings)
        fresh = s3fs.S3FileSystem(
            endpoint_url=s3_endpoint, skip_instance_cache=True, use_listings_cache=False
        )
        stats_prefix = s3_url.removeprefix("s3://") + "/stats"

        def kill_when_half_done() -> None:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                found = fresh.find(stats_prefix) if fresh.exists(stats_prefix) else []
                if len(found) >= n_flights // 3:
                    os.kill(pids[0], 9)
                    killed.append(pids[0])
                    return
                time.sleep(0.05)

        import threading

        killer = threading.Thread(target=kill_when_half_done, daemon=True)
        killer.start()
        remote = run(cfg, store=s3_url, scheduler=cluster.scheduler_address)
        killer.join(timeout=5)
    assert killed, "the worker was not killed mid-run"
    assert remote.failed == 0, [s.error for s in remote.statuses.values() if s.error]
    assert [t.key for t in remote.plan.tasks] == [t.key for t in local.plan.tasks]
    assert _arrays(store) == _arrays(open_store(tmp_path / "local"))
    assert store.verify_all() == {}
    assert run(cfg, store=s3_url, workers=0).count("cached") == len(local.plan.tasks)


def test_the_signatures_of_a_store_come_from_one_listing(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    summary = run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    listed = store.signatures({t.stage for t in summary.plan.tasks})
    assert set(listed) == {(t.stage, t.key) for t in summary.plan.tasks}
    for (stage, key), (size, _) in listed.items():
        assert size == Path(store.path_for(stage, key)).stat().st_size
    assert np.all([s > 0 for s, _ in listed.values()])
    assert json.loads((Path(store.root) / "aeroid-store.json").read_text())


# -- a streamed run: windows of flights, a ledger of statuses ---------------------------


def _load_fails_on(monkeypatch: pytest.MonkeyPatch, flight: str) -> None:
    from aeroid.pipeline.running import execution
    from aeroid.pipeline.running.execution import TaskStatus

    real = execution.execute_task

    def patched(task, *args, **kwargs):  # type: ignore[no-untyped-def]
        if task.flight == flight and task.step == "load":
            return TaskStatus(task.key, task.step, task.flight, "failed", error="lost in transit")
        return real(task, *args, **kwargs)

    monkeypatch.setattr(execution, "execute_task", patched)


def test_a_run_in_windows_of_flights_stores_and_reports_what_one_window_does(tmp_path, monkeypatch):
    from aeroid.pipeline.running import executors, streaming

    cfg = make_campaign(tmp_path, n=5, stats="{n_boot: 20, warn: true}")
    _load_fails_on(monkeypatch, "f02")
    whole = run(cfg, store=tmp_path / "whole", workers=0)
    sizes: list[int] = []
    real_run = executors.InProcess.run

    def counting(self, tasks, *args, **kwargs):  # type: ignore[no-untyped-def]
        sizes.append(len({t.flight for t in tasks if t.flight is not None}))
        return real_run(self, tasks, *args, **kwargs)

    monkeypatch.setattr(executors.InProcess, "run", counting)
    monkeypatch.setattr(streaming, "WINDOW_FLIGHTS", 2)
    windowed = run(cfg, store=tmp_path / "windowed", workers=0)
    # three windows of at most two flights; the campaign report runs with the last
    assert sizes == [2, 2, 1]
    # the failed flight's statuses reach the campaign report in a later window
    assert whole.failed == windowed.failed == 2  # f02's load and stats
    assert {k: (s.status, s.error, s.warnings) for k, s in whole.statuses.items()} == {
        k: (s.status, s.error, s.warnings) for k, s in windowed.statuses.items()
    }
    assert list(whole.statuses) == [t.key for t in windowed.plan.tasks]
    report = next(s for s in windowed.statuses.values() if s.step == "campaign_report")
    assert report.status == "computed" and not report.cached and "f02" in report.failures
    assert whole.rows == windowed.rows and whole.columns == windowed.columns
    assert whole.report_path is not None and windowed.report_path is not None
    assert whole.report_path.read_text() == windowed.report_path.read_text()
    assert "only 20 bootstrap samples" in windowed.report_path.read_text()
    assert _arrays(open_store(tmp_path / "whole")) == _arrays(open_store(tmp_path / "windowed"))
    assert windowed.to_json()["tasks"] == whole.to_json()["tasks"]
    assert [w for _, w in windowed.warnings()] == [w for _, w in whole.warnings()]
    # the stored plan lists every task of the streamed run
    from aeroid.pipeline.plans import plan_cache

    stored = plan_cache.load(open_store(tmp_path / "windowed"), windowed.plan.inputs or "")
    assert [p.key for p in stored or ()] == [t.key for t in windowed.plan.tasks]


def test_a_ledger_keeps_a_few_bytes_a_task(tmp_path):
    from aeroid.pipeline.plans.planning import plan
    from aeroid.pipeline.running.execution import TaskStatus
    from aeroid.pipeline.running.ledger import Ledger

    p = plan(make_campaign(tmp_path, n=3))
    ledger = Ledger()
    for t in p.tasks:
        i = ledger.add(t)
        warned = ("W",) if t.step == "stats" else ()
        ledger.settle(
            i,
            TaskStatus(
                t.key,
                t.step,
                t.flight,
                "computed",
                cached=True,
                warnings=warned,
                compute_seconds=0.5,
            ),
        )
    assert ledger.flights == p.flights and ledger.count("computed") == len(p.tasks) == 7
    assert ledger.compute_seconds == pytest.approx(3.5)
    # a plain status is rebuilt from its code; one with warnings is kept whole
    load = ledger.statuses[p.tasks[0].key]
    assert (load.key, load.step, load.flight, load.status, load.cached) == (
        p.tasks[0].key,
        "load",
        p.flights[0],
        "computed",
        True,
    )
    assert ledger.statuses[p.tasks[1].key].warnings == ("W",)
    assert len(ledger.statuses) == 7 and list(ledger.statuses) == [t.key for t in p.tasks]
    assert [t.key for t in ledger.planned()] == [t.key for t in p.tasks]


def _outcome(summary) -> dict:  # type: ignore[no-untyped-def]
    report = next(s for s in summary.statuses.values() if s.step == "campaign_report")
    doc = {
        "failed": summary.failed,
        "report": [report.status, sorted(report.failures)],
        "rows": summary.rows,
    }
    return json.loads(json.dumps(doc))


def _windowed_in_a_fresh_process(cfg: Path, store: Path) -> dict:
    script = (
        "import json, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import pytest\n"
        "from test_pipeline_scale import _load_fails_on, _outcome\n"
        "from aeroid.pipeline import run\n"
        "from aeroid.pipeline.running import streaming\n"
        "_load_fails_on(pytest.MonkeyPatch(), 'f00')\n"
        "streaming.WINDOW_FLIGHTS = 1\n"
        f"print(json.dumps(_outcome(run({str(cfg)!r}, store={str(store)!r}, workers=2))))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=300
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("executor", ["local pool", "dask threads"])
def test_a_failed_flight_reaches_a_campaign_task_windows_later_on_every_executor(
    tmp_path, monkeypatch, executor
):
    from aeroid.pipeline.running import streaming

    cfg = make_campaign(tmp_path, n=3)
    _load_fails_on(monkeypatch, "f00")  # forked workers inherit the patch
    whole = run(cfg, store=tmp_path / "whole", workers=0)
    monkeypatch.setattr(streaming, "WINDOW_FLIGHTS", 1)
    if executor == "local pool":
        # in a fresh process: its forked workers inherit the planted failure (a pool
        # spawns its workers instead once an earlier test here has loaded JAX)
        got = _windowed_in_a_fresh_process(cfg, tmp_path / "windowed")
    else:
        distributed = pytest.importorskip("distributed")
        with distributed.LocalCluster(
            n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
        ) as cluster:
            windowed = run(cfg, store=tmp_path / "windowed", scheduler=cluster.scheduler_address)
        got = _outcome(windowed)
    assert got == _outcome(whole)
    assert got["failed"] == 2
    assert got["report"] == ["computed", ["f00"]]
    assert _arrays(open_store(tmp_path / "whole")) == _arrays(open_store(tmp_path / "windowed"))
