"""The ``aeroid`` command driven as a user would: run, rerun, change, kill, corrupt, break.

The campaign uses a small user-defined pipeline (load -> a seeded "stats"
stage -> campaign report) written next to the config, exactly as a user
would define one, so these tests exercise the engine independently of the
numerical stages.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_pipeline_store import flip_a_bit, member_bytes

from aeroid.cli import main
from aeroid.models.catalog import short_period_flight
from aeroid.pipeline import open_store

USER_PIPELINE = textwrap.dedent(
    '''
    """A user pipeline: per flight, bootstrap means of every channel."""
    import time
    from dataclasses import dataclass

    import numpy as np

    from aeroid.pipeline import Pipeline, Stage, Step, register_record, register_stage
    from aeroid.pipeline.plans.config import Options


    @register_record
    @dataclass(frozen=True, eq=False)
    class ChannelStats:
        names: tuple
        mean: np.ndarray
        boot: np.ndarray

        def summary(self):
            return "stats of " + ", ".join(self.names)


    class StatsOptions(Options):
        n_boot: int = 50
        sleep: float = 0.0
        warn: bool = False


    def run_stats(ctx):
        data = ctx.inputs["data"]
        rng = np.random.default_rng(ctx.seed_int())
        x = data.array(list(data.names))
        idx = rng.integers(0, x.shape[0], size=(ctx.options.n_boot, x.shape[0]))
        time.sleep(ctx.options.sleep)
        if ctx.options.warn:
            import warnings
            warnings.warn(f"only {ctx.options.n_boot} bootstrap samples")
        return ChannelStats(tuple(data.names), x.mean(axis=0), x[idx].mean(axis=1))


    register_stage(Stage("stats", "1", StatsOptions, "user_pipeline:ChannelStats", run_stats,
                         uses_model=False, seeded=True))

    pipeline = Pipeline(
        "user",
        flight_steps=(Step("load"), Step("stats", inputs={"data": "load"})),
        campaign_steps=(Step("campaign_report", inputs={"data": "load"}),),
    )
    '''
)


def write_flight(path: Path, seed: int) -> None:
    d = short_period_flight(seed=seed)
    rows = np.column_stack([d.time, *(d[n] for n in d.names)])
    body = "\n".join(",".join(repr(float(v)) for v in r) for r in rows)
    path.write_text(",".join(["time", *d.names]) + "\n" + body + "\n")


def make_campaign(tmp: Path, n: int = 4, stats: str = "{n_boot: 50}") -> Path:
    (tmp / "flights").mkdir(exist_ok=True)
    for i in range(n):
        write_flight(tmp / "flights" / f"f{i:02d}.csv", i)
    (tmp / "user_pipeline.py").write_text(USER_PIPELINE)
    cfg = tmp / "campaign.yaml"
    cfg.write_text(
        "model: short_period\npipeline: user_pipeline:pipeline\nseed: 11\n"
        f"flights: ['flights/*.csv']\nstore: store\nstages:\n  stats: {stats}\n"
    )
    return cfg


def invoke(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(main, list(args))
    if result.exception and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.stdout, result.stderr


def run_json(cfg: Path, *extra: str) -> tuple[int, dict]:
    code, out, _ = invoke("run", str(cfg), "--json", "--workers", "0", *extra)
    return code, json.loads(out)


def by_status(doc: dict) -> dict[str, list[tuple[str, str]]]:
    out: dict[str, list[tuple[str, str]]] = {}
    for t in doc["tasks"]:
        out.setdefault(t["status"], []).append((t["stage"], t["flight"]))
    return out


def test_fresh_run_then_unchanged_rerun_computes_nothing(tmp_path):
    cfg = make_campaign(tmp_path)
    code, doc = run_json(cfg)
    assert code == 0
    assert (doc["computed"], doc["cached"], doc["failed"]) == (9, 0, 0)
    assert set(doc) == {
        "computed",
        "cached",
        "by_another_run",
        "failed",
        "report",
        "report_html",
        "tasks",
    }
    assert set(doc["tasks"][0]) == {"stage", "flight", "key", "status", "error"}
    report = Path(doc["report"])
    assert report.is_file() and "f03" in report.read_text()
    code, doc2 = run_json(cfg)
    assert code == 0 and (doc2["computed"], doc2["cached"]) == (0, 9)
    assert [t["key"] for t in doc2["tasks"]] == [t["key"] for t in doc["tasks"]]
    # human output: per-flight table, counts, report location
    code, out, _ = invoke("run", str(cfg), "--workers", "0")
    assert code == 0 and "| f00" in out and "0 computed, 9 cached, 0 failed" in out
    assert f"report: {report}" in out
    if doc["report_html"]:
        assert f"report (HTML, with the figures): {doc['report_html']}" in out


def test_changed_flight_recomputes_exactly_its_chain_and_the_report(tmp_path):
    cfg = make_campaign(tmp_path)
    run_json(cfg)
    write_flight(tmp_path / "flights" / "f02.csv", 99)
    code, doc = run_json(cfg)
    assert code == 0
    assert sorted(by_status(doc)["computed"], key=str) == sorted(
        [("load", "f02"), ("stats", "f02"), ("campaign_report", None)], key=str
    )
    # a changed stage option recomputes that stage everywhere and nothing else (this
    # pipeline's report reads only the loads)
    cfg.write_text(cfg.read_text().replace("n_boot: 50", "n_boot: 60"))
    code, doc = run_json(cfg)
    computed = by_status(doc)["computed"]
    assert {s for s, _ in computed} == {"stats"} and len(computed) == 4


def test_bad_flight_file_is_reported_and_others_succeed(tmp_path):
    cfg = make_campaign(tmp_path)
    bad = tmp_path / "flights" / "f01.csv"
    lines = bad.read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[2], "oops", 1)
    bad.write_text("\n".join(lines))
    code, doc = run_json(cfg)
    assert code == 1
    failed = {
        (t["stage"], t["flight"]): t["error"] for t in doc["tasks"] if t["status"] == "failed"
    }
    assert set(failed) == {("load", "f01"), ("stats", "f01")}
    assert "f01.csv" in failed[("load", "f01")] and "oops" in failed[("load", "f01")]
    assert "upstream load failed" in failed[("stats", "f01")]
    # the step that could not run carries the first failure's own reason
    assert "oops" in failed[("stats", "f01")]
    assert doc["computed"] == 7  # three flights x 2 + the report
    text = Path(doc["report"]).read_text()
    assert "1 failed" in text and "f01" in text
    # failures are never stored; the report over them is (the file fails again, by its
    # key), so an unchanged rerun recomputes nothing but the failed flight's retries
    code, st_out, _ = invoke("status", str(cfg), "--json")
    st = json.loads(st_out)
    assert st["missing"] == 2 and st["stored"] == 7
    code, out, _ = invoke("run", str(cfg), "--workers", "0", "--json")
    again = json.loads(out)
    assert code == 1 and again["computed"] == 0 and again["cached"] == 7
    assert "1 failed" in Path(again["report"]).read_text()
    # and `aeroid rerun` recomputes it from the failures its provenance records
    code, out, _ = invoke("rerun", "--all", "--config", str(cfg), "--workers", "0")
    assert code == 0 and "7 of 7 entries bit-identical" in out, out


def test_bad_config_names_file_and_key_path(tmp_path):
    cfg = make_campaign(tmp_path)
    cfg.write_text(cfg.read_text() + "stores: elsewhere\n")
    code, out, err = invoke("run", str(cfg))
    assert code == 2 and out == ""
    assert f"{cfg}: stores: unknown key" in err
    cfg.write_text(
        cfg.read_text().replace("stores: elsewhere\n", "").replace("n_boot: 50", "n_bot: 5")
    )
    code, _, err = invoke("run", str(cfg))
    assert code == 2 and "stages.stats.n_bot: unknown key; allowed keys: n_boot, sleep" in err


def test_a_scheduler_nobody_listens_at_is_reported_at_once(tmp_path, monkeypatch):
    cfg = make_campaign(tmp_path)
    with socket.socket() as s:  # a port that was free a moment ago: refused
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # Dask's client alone would retry the refused port for its 30 s timeout: the probe
    # must answer before any client is made
    import dask.distributed

    def no_client(*args, **kwargs):
        raise AssertionError("a dask Client was made for an unreachable scheduler")

    monkeypatch.setattr(dask.distributed, "Client", no_client)
    code, out, err = invoke("run", str(cfg), "--scheduler", f"tcp://127.0.0.1:{port}")
    assert code == 2 and out == ""
    assert f"cannot reach the dask scheduler tcp://127.0.0.1:{port}" in err
    assert not list((tmp_path / "store").glob("load/*"))  # nothing half-written


def _flip_a_bit(store: Path, task: dict, array: str) -> tuple[Path, str, bytes]:
    """Alter one bit of a stored array's chunk: (entry file, chunk member, original bytes)."""
    entry = store / task["stage"] / f"{task['key']}.zarr.zip"
    member, original = flip_a_bit(entry, f"{array}/")
    return entry, member, original


def test_corrupted_entry_is_detected_by_verify_and_on_read(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    _, doc = run_json(cfg)
    stats = next(t for t in doc["tasks"] if t["stage"] == "stats")
    entry, chunk, original = _flip_a_bit(tmp_path / "store", stats, "boot")
    code, out, _ = invoke("verify", "--config", str(cfg))
    assert code == 1 and f"CORRUPT {stats['key']}" in out and "1 corrupt" in out
    assert "verify --remove" in out  # the way out is named
    code, _, err = invoke("show", stats["key"][:10], "--store", str(tmp_path / "store"))
    assert code == 1 and "corrupt" in err
    code, _, err = invoke("rerun", stats["key"], "--store", str(tmp_path / "store"))
    assert code == 1 and "corrupt" in err
    # removed, the next run recomputes exactly that entry, with the original bytes
    code, out, _ = invoke("verify", "--config", str(cfg), "--remove", "--json")
    assert code == 1 and json.loads(out)["removed"] == [stats["key"]]
    assert not entry.exists()
    assert invoke("verify", "--config", str(cfg))[0] == 0
    _, doc = run_json(cfg)
    assert by_status(doc)["computed"] == [("stats", stats["flight"])] and doc["failed"] == 0
    assert member_bytes(entry, chunk) == original


def test_a_run_reading_a_corrupt_entry_fails_that_flight_and_names_the_way_out(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    _, doc = run_json(cfg)
    load = next(t for t in doc["tasks"] if t["stage"] == "load")
    _flip_a_bit(tmp_path / "store", load, "time")
    # a changed stats option recomputes stats, which reads both flights' load entries
    cfg.write_text(cfg.read_text().replace("n_boot: 50", "n_boot: 60"))
    code, out, _ = invoke("run", str(cfg), "--workers", "0")
    assert code == 1
    assert f"FAILED stats {load['flight']}" in out and "is corrupt" in out
    # the cache hit itself fails its checksum: the load is not counted as cached
    assert f"FAILED load {load['flight']}" in out
    assert "2 failed" in out and "`aeroid verify --remove` removes them" in out
    assert invoke("verify", "--config", str(cfg), "--remove")[0] == 1
    code, doc = run_json(cfg)
    assert code == 0 and doc["failed"] == 0
    assert sorted(by_status(doc)["computed"]) == [
        ("load", load["flight"]),
        ("stats", load["flight"]),
    ]


def test_show_status_rerun_and_gc(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    code, out, _ = invoke("status", str(cfg))
    assert code == 0 and "0 stored, 5 missing" in out
    _, doc = run_json(cfg)
    code, out, _ = invoke("status", str(cfg), "--json")
    assert json.loads(out)["missing"] == 0
    stats = next(t for t in doc["tasks"] if t["stage"] == "stats")
    code, out, _ = invoke("show", stats["key"][:12], "--config", str(cfg))
    assert code == 0 and "stats of elevator" in out and "spawn_key" in out and "numpy" in out
    code, out, _ = invoke("rerun", stats["key"], "--config", str(cfg))
    assert code == 0 and "bit-identical" in out
    # gc removes a temporary a crashed run left behind
    tmp = tmp_path / "store" / ".tmp" / f"{'c' * 64}.{os.uname().nodename}.999999999.00000000"
    tmp.parent.mkdir(parents=True, exist_ok=True)
    tmp.write_bytes(b"PK\x03\x04")  # the start of a zip, cut short
    code, out, _ = invoke("gc", "--store", str(tmp_path / "store"))
    assert code == 0 and "1 temporaries removed" in out and not tmp.exists()
    code, _, err = invoke("verify")
    assert code == 2 and "--config" in err


def test_status_refuses_a_store_that_is_a_file(tmp_path):
    # as `run` and `status --store` do: not read as an empty store
    cfg = make_campaign(tmp_path, n=1)
    (tmp_path / "flat").write_text("not a store\n")
    cfg.write_text(cfg.read_text().replace("store: store", "store: flat"))
    code, out, err = invoke("status", str(cfg))
    assert code != 0 and "flat: is a file, not a folder" in err and not out


def test_status_of_a_large_campaign_is_a_summary_per_step(tmp_path, monkeypatch):
    from aeroid import cli

    cfg = make_campaign(tmp_path, n=3)  # 7 tasks: 3 loads, 3 stats, the campaign step
    run_json(cfg)
    (tmp_path / "flights" / "f00.csv").write_text(
        (tmp_path / "flights" / "f01.csv").read_text().replace("0.", "1.", 3)
    )
    monkeypatch.setattr(cli, "_STATUS_ROWS", 4)
    monkeypatch.setattr(cli, "_MISSING_SHOWN", 1)
    code, out, _ = invoke("status", str(cfg))
    assert code == 0
    # one row per step with its counts, then the first missing task, then the totals
    assert "| stage " in out and "| stored | missing |" in out
    assert "first 1 of 3 missing tasks:" in out and "f00" in out
    assert "7 tasks; `aeroid status --all` lists every one" in out
    assert "4 stored, 3 missing" in out
    code, every, _ = invoke("status", str(cfg), "--all")
    assert code == 0 and every.count("| missing |") == 3 and every.count("| stored  |") == 4


def test_rerun_reports_the_largest_difference(tmp_path):
    cfg = make_campaign(tmp_path, n=1)
    _, doc = run_json(cfg)
    stats = next(t for t in doc["tasks"] if t["stage"] == "stats")
    code, out, _ = invoke("rerun", "--all", "--config", str(cfg))
    assert code == 0 and "3 of 3 entries bit-identical" in out
    assert f"bit-identical stats {stats['key']}" in out
    assert invoke("rerun", "--config", str(cfg))[0] == 2  # neither a key nor --all
    assert invoke("rerun", "--all", "--stage", "nosuch", "--config", str(cfg))[0] == 2
    # the user changes the stage's code without bumping its version
    src = tmp_path / "user_pipeline.py"
    src.write_text(
        src.read_text().replace("x.mean(axis=0), x[idx]", "x.mean(axis=0) + 1e-3, x[idx]")
    )
    sys.modules.pop("user_pipeline", None)
    try:
        code, out, _ = invoke("rerun", stats["key"], "--config", str(cfg))
        code_all, out_all, _ = invoke("rerun", "--all", "--stage", "stats", "--config", str(cfg))
    finally:  # later tests import their own, unchanged user_pipeline
        sys.modules.pop("user_pipeline", None)
    assert code == 1 and "largest difference: 0.001" in out
    assert code_all == 1 and f"DIFFERS stats {stats['key']}" in out_all
    assert "largest difference: 0.001" in out_all and "0 of 1 entries bit-identical" in out_all


def _cli(*args: str, **kw):
    exe = [sys.executable, "-c", "from aeroid.cli import main; main()"]
    return subprocess.run([*exe, *args], capture_output=True, text=True, timeout=120, **kw)


def _run_until_stored(cfg: Path, store: Path, n: int, *, workers: int) -> subprocess.Popen:
    """`aeroid run` in the background, returned once `n` stats results are stored."""
    exe = [sys.executable, "-c", "from aeroid.cli import main; main()"]
    proc = subprocess.Popen(
        [*exe, "run", str(cfg), "--workers", str(workers), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    deadline = time.time() + 60
    while time.time() < deadline and len(list((store / "stats").glob("*.zarr.zip"))) < n:
        time.sleep(0.05)
    return proc


@pytest.mark.slow
def test_the_workers_of_a_killed_run_stop_with_it(tmp_path):
    import psutil

    cfg = make_campaign(tmp_path, n=12, stats="{n_boot: 50, sleep: 0.3}")
    proc = _run_until_stored(cfg, tmp_path / "store", 2, workers=2)
    workers = psutil.Process(proc.pid).children(recursive=True)
    assert len(workers) == 2
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    _, alive = psutil.wait_procs(workers, timeout=20)
    assert alive == []
    assert _cli("verify", "--store", str(tmp_path / "store")).returncode == 0


@pytest.mark.slow
def test_killed_run_leaves_a_store_that_verifies_and_the_next_run_completes(tmp_path):
    cfg = make_campaign(tmp_path, n=12, stats="{n_boot: 50, sleep: 0.15}")
    store = tmp_path / "store"
    proc = _run_until_stored(cfg, store, 3, workers=0)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    done_before = len(list((store / "stats").glob("*.zarr.zip")))
    assert 3 <= done_before < 12
    res = _cli("verify", "--store", str(store))
    assert res.returncode == 0, res.stdout + res.stderr
    res = _cli("run", str(cfg), "--workers", "0", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert (
        doc["failed"] == 0
        and doc["cached"] >= done_before
        and doc["computed"] + doc["cached"] == 25
    )
    assert _cli("verify", "--store", str(store)).returncode == 0
    _cli("gc", "--store", str(store))
    assert not any((store / ".tmp").iterdir()) if (store / ".tmp").exists() else True


@pytest.mark.slow
def test_two_runs_at_once_on_one_store_leave_it_intact(tmp_path):
    # the runs overlap: each task is claimed by one of them, the other waits for its
    # entry (computed by another run), so every task is computed once across both
    cfg = make_campaign(tmp_path, n=6, stats="{n_boot: 50, sleep: 0.1}")
    exe = [sys.executable, "-c", "from aeroid.cli import main; main()"]
    procs = [
        subprocess.Popen(
            [*exe, "run", str(cfg), "--workers", "0", "--json"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    docs = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        docs.append(json.loads(out))
    assert all(d["failed"] == 0 for d in docs)
    assert all(d["computed"] + d["cached"] + d["by_another_run"] == 13 for d in docs), docs
    assert sum(d["computed"] for d in docs) == 13
    store = tmp_path / "store"
    assert _cli("verify", "--store", str(store)).returncode == 0
    assert len(list((store / "stats").glob("*.zarr.zip"))) == 6
    assert not any((store / ".tmp").glob("*"))
    code, doc = run_json(cfg)
    assert code == 0 and doc["computed"] == 0 and doc["cached"] == 13
    # the entries are those of one run alone
    code, alone = run_json(cfg, "--store", str(tmp_path / "alone"))
    assert code == 0 and alone["computed"] == 13
    shared, single = open_store(store), open_store(tmp_path / "alone")
    for t in alone["tasks"]:
        x, y = shared.load_arrays(t["key"]), single.load_arrays(t["key"])
        assert x.keys() == y.keys()
        differ = [k for k in x if x[k].tobytes() != y[k].tobytes()]
        assert not differ, (t["stage"], t["flight"], differ, {k: (x[k], y[k]) for k in differ})


@pytest.mark.slow
@pytest.mark.parametrize("workers", ["0", "1"])
def test_ctrl_c_stops_a_run_cleanly_and_the_next_run_goes_on(tmp_path, workers):
    cfg = make_campaign(tmp_path, n=12, stats="{n_boot: 50, sleep: 0.15}")
    exe = [sys.executable, "-c", "from aeroid.cli import main; main()"]
    proc = subprocess.Popen(
        [*exe, "run", str(cfg), "--workers", workers, "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # as in a terminal: SIGINT raises KeyboardInterrupt (a test runner may ignore it)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    store = tmp_path / "store"
    deadline = time.time() + 60
    while time.time() < deadline and len(list((store / "stats").glob("*.zarr.zip"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted: the results stored so far are kept" in err and "Traceback" not in err
    done = len(list((store / "stats").glob("*.zarr.zip")))
    assert 2 <= done < 12
    assert _cli("verify", "--store", str(store)).returncode == 0
    res = _cli("run", str(cfg), "--workers", "0", "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["failed"] == 0 and doc["cached"] >= done and doc["computed"] + doc["cached"] == 25


@pytest.mark.slow
def test_warnings_are_kept_with_their_task_and_shown(tmp_path):
    cfg = make_campaign(tmp_path, n=2, stats="{n_boot: 40, warn: true}")
    code, out, err = invoke("run", str(cfg), "--workers", "0")
    assert code == 0 and "bootstrap" not in err  # not printed by the warnings module
    lines = [line for line in out.splitlines() if line.startswith("WARNING stats")]
    assert len(lines) == 2 and all("UserWarning: only 40 bootstrap samples" in x for x in lines)
    key = lines[0].split("(")[1].split(")")[0]
    code, out, _ = invoke("show", key, "--config", str(cfg))
    assert code == 0 and "- warning: UserWarning: only 40 bootstrap samples" in out
    code, again, _ = invoke("run", str(cfg), "--workers", "0")
    # a cached rerun shows the warnings stored with the results, marked cached
    cached = [line for line in again.splitlines() if line.startswith("WARNING stats")]
    assert len(cached) == 2 and f"({key}, cached)" in cached[0]
    assert [c.split("): ", 1)[1] for c in cached] == [x.split("): ", 1)[1] for x in lines]
    # with --json they go to stderr: stdout is the document alone
    other = tmp_path / "json"
    other.mkdir()
    cfg = make_campaign(other, n=2, stats="{n_boot: 40, warn: true}")
    code, out, err = invoke("run", str(cfg), "--workers", "0", "--json")
    assert code == 0 and json.loads(out)["computed"] > 0
    warned = [x for x in err.splitlines() if x.startswith("WARNING stats")]
    assert len(warned) == 2 and all("only 40 bootstrap samples" in x for x in warned)


def test_console_script_on_the_embedded_cluster(tmp_path, monkeypatch):
    # the stage warns: the warning goes with the task, not onto a worker's stderr
    cfg = make_campaign(tmp_path, n=3, stats="{n_boot: 50, warn: true}")
    # Dask's usual HTTP port held by someone else (a user's own cluster): no warning either
    holder = socket.socket()
    with contextlib.suppress(OSError):  # already held: the same situation
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    try:
        res = subprocess.run(
            ["aeroid", "run", str(cfg), "--workers", "2", "--json"],
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        holder.close()
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["computed"] == 7
    # on stderr the tasks' warnings, announced by the command; nothing from the workers,
    # no progress bar off a terminal
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 3, res.stderr
    assert all(x.startswith("WARNING stats f0") and "only 50 bootstrap" in x for x in lines)
    # no cluster is started when nothing is to compute
    import concurrent.futures

    def no_pool(*args, **kwargs):
        raise AssertionError("worker processes started for a cached rerun")

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", no_pool)
    code, out, _ = invoke("run", str(cfg), "--json")
    assert code == 0 and json.loads(out)["cached"] == 7


def test_python_m_aeroid_is_the_command(tmp_path):
    # for an environment whose scripts folder is not on the PATH
    import aeroid

    root = str(Path(aeroid.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=root)
    run = [sys.executable, "-m", "aeroid"]
    out = subprocess.run([*run, "--version"], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == f"aeroid, version {aeroid.__version__}"
    missing = str(tmp_path / "none.yaml")
    out = subprocess.run(
        [*run, "run", missing], capture_output=True, text=True, env=env, timeout=60
    )
    assert out.returncode == 2 and "none.yaml" in out.stderr and "Traceback" not in out.stderr


def test_a_moved_campaign_reruns_from_its_own_files(tmp_path):
    # found by an independent suite: rerun read the flight files at the paths of the
    # first run, so a moved campaign failed every rerun, and a copy whose flight was
    # edited was "bit-identical" against the original folder's file
    import shutil

    (tmp_path / "orig").mkdir()
    cfg = make_campaign(tmp_path / "orig", n=2)
    code, doc = run_json(cfg)
    assert code == 0
    load = next(t["key"] for t in doc["tasks"] if t["stage"] == "load")
    shutil.move(str(tmp_path / "orig"), str(tmp_path / "moved"))
    moved = tmp_path / "moved" / "campaign.yaml"
    sys.modules.pop("user_pipeline", None)
    try:
        code, out, _ = invoke("rerun", "--all", "--config", str(moved), "--workers", "0")
        assert code == 0 and f"{doc['computed']} of {doc['computed']} entries bit-identical" in out
        shutil.copytree(tmp_path / "moved", tmp_path / "copy")
        edited = sorted((tmp_path / "copy" / "flights").glob("*.csv"))[0]
        edited.write_text(edited.read_text().replace("\n0.0,", "\n0.0,1", 1))
        code, out, err = invoke("rerun", load, "--config", str(tmp_path / "copy" / "campaign.yaml"))
    finally:
        sys.modules.pop("user_pipeline", None)
    # the entry is no task of the edited copy's config: it is recomputed from what it
    # recorded, the first run's folder, gone, and says so (never the copy's edited file)
    assert code == 1 and "/orig/" in err and "cannot read it" in err
