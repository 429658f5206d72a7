"""Hostile files and configs: no reading outside the file, no network without opt-in,
no file contents in errors, sizes bounded before reading (issue 49)."""

from __future__ import annotations

import numpy as np
import pytest

from aeroid import read_log
from aeroid.errors import ConfigError, DataFormatError
from aeroid.pipeline.plans.config import load_config

h5py = pytest.importorskip("h5py")

_SECRET = b"TOP-SECRET-VALUES-" * 8


def _log_with_external(tmp_path, *, virtual: bool = False):
    secret = tmp_path / "secret.bin"
    secret.write_bytes(_SECRET)
    n = len(_SECRET) // 8
    path = tmp_path / "hostile.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(n) * 0.1
        f["q"] = np.ones(n)
        if virtual:
            src = tmp_path / "other.h5"
            with h5py.File(src, "w") as g:
                g["data"] = np.frombuffer(_SECRET, dtype="<f8")
            layout = h5py.VirtualLayout(shape=(n,), dtype="<f8")
            layout[:] = h5py.VirtualSource(str(src), "data", shape=(n,))
            f.create_virtual_dataset("leak", layout)
        else:
            f.create_dataset("leak", (n,), dtype="<f8", external=[(str(secret), 0, n * 8)])
    return path, n


@pytest.mark.parametrize("virtual", [False, True])
def test_external_and_virtual_hdf5_datasets_are_refused_unless_allowed(tmp_path, virtual):
    path, n = _log_with_external(tmp_path, virtual=virtual)
    with pytest.warns(UserWarning, match="allow_external_data"):
        log = read_log(path)
    assert "leak" not in log and "q" in log
    assert "leak" in log.metadata["skipped"]
    allowed = read_log(path, allow_external_data=True)
    assert allowed.channels["leak"].values.tobytes() == _SECRET[: n * 8]


def test_an_external_time_dataset_is_refused_with_its_name(tmp_path):
    secret = tmp_path / "secret.bin"
    secret.write_bytes(np.arange(16, dtype="<f8").tobytes())
    path = tmp_path / "t.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("time", (16,), dtype="<f8", external=[(str(secret), 0, 128)])
        f["q"] = np.ones(16)
    with pytest.raises(DataFormatError, match="time dataset 'time' is stored in an external"):
        read_log(path)


def test_a_dataset_declaring_gigabytes_is_skipped_before_reading(tmp_path):
    path = tmp_path / "bomb.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(50) * 0.1
        f["q"] = np.sin(np.arange(50))
        # 2 GiB declared, nothing written: the file stays a few kB
        f.create_dataset("huge", (1 << 28,), dtype="<f8", chunks=(1 << 16,), compression="gzip")
    assert path.stat().st_size < 100_000
    log = read_log(path)
    assert "q" in log and "huge" not in log
    assert "GiB" in log.metadata["skipped"]["huge"]
    bomb_time = tmp_path / "bomb_time.h5"
    with h5py.File(bomb_time, "w") as f:
        f.create_dataset("time", (1 << 28,), dtype="<f8", chunks=(1 << 16,), compression="gzip")
    with pytest.raises(DataFormatError, match=r"time dataset 'time' declares 2\.0 GiB"):
        read_log(bomb_time)


def _config(tmp_path, extra: str):
    (tmp_path / "a.csv").write_text("time,q\n0,1\n0.1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: [a.csv]\n" + extra)
    return cfg


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("scheduler: tcp://10.1.2.3:8786\n", "scheduler: tcp://10.1.2.3:8786 is another host"),
        ("store: s3://bucket/campaign\n", "store: s3://bucket/campaign sends flight data"),
        ("store: gcs://bucket/x\n", "allow_network: true"),
        ("store: memory://x/store\n", "keeps nothing"),
        ("store: $STORE_DIR\n", "environment variable"),
        ("store: '${HOME}/s'\n", "environment variable"),
        ("store: " + "a" * 5000 + "\n", "at most 1024 characters"),
    ],
)
def test_network_and_odd_stores_are_refused_by_the_config(tmp_path, extra, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_config(tmp_path, extra))


def test_network_is_allowed_by_opt_in_and_loopback_needs_none(tmp_path):
    for address in ("tcp://127.0.0.1:8786", "tcp://localhost:8786", "tcp://[::1]:8786"):
        assert load_config(_config(tmp_path, f"scheduler: {address}\n")).scheduler == address
    cfg = load_config(
        _config(tmp_path, "scheduler: tcp://10.1.2.3:8786\nstore: s3://b/c\nallow_network: true\n")
    )
    assert cfg.allow_network and cfg.store == "s3://b/c"
    assert load_config(_config(tmp_path, f"store: file://{tmp_path}/s\n")).store_is_url is False


def test_pre_flight_errors_quote_no_file_contents(tmp_path):
    from aeroid.pipeline.plans.checks import preflight

    secret = tmp_path / "creds.csv"
    secret.write_text("AWS_SECRET=abc123xyz,other\n1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [{path: creds.csv, time_column: t}]\n"
        "stages:\n  identify: {parameters: [M_alpha]}\n"
    )
    with pytest.raises(ConfigError) as err:
        preflight(cfg)
    text = str(err.value)
    assert "creds.csv" in text and "time column 't' not found" in text
    assert "abc123xyz" not in text and "AWS_SECRET" not in text


def test_flights_sharing_a_stem_are_named_by_their_relative_path(tmp_path):
    from aeroid.pipeline.plans.planning import _flight_sources

    for folder in ("x", "y"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "a.csv").write_text("time,q\n0,1\n0.1,2\n")
    (tmp_path / "b.csv").write_text("time,q\n0,1\n0.1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: ['x/a.csv', 'y/a.csv', 'b.csv']\n")
    names = [f.name for f in _flight_sources(load_config(cfg))]
    assert names == ["x/a.csv", "y/a.csv", "b"]


def test_workers_beyond_four_per_core_are_refused(tmp_path):
    import os

    limit = 4 * (os.cpu_count() or 1)
    assert load_config(_config(tmp_path, f"workers: {limit}\n")).workers == limit
    with pytest.raises(ConfigError, match=f"workers: .*at most {limit}"):
        load_config(_config(tmp_path, f"workers: {limit + 1}\n"))


def test_a_recursive_glob_through_a_symlink_loop_ends(tmp_path):
    (tmp_path / "loop" / "a").mkdir(parents=True)
    (tmp_path / "loop" / "a" / "f.csv").write_text("time,q\n0,1\n0.1,2\n")
    (tmp_path / "loop" / ".hidden.csv").write_text("time,q\n0,1\n0.1,2\n")
    (tmp_path / "loop" / "a" / "up").symlink_to("..", target_is_directory=True)
    (tmp_path / "loop" / "a" / "again").symlink_to("..", target_is_directory=True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: ['loop/**/*.csv']\n")
    paths = [p for _, p, _ in load_config(cfg).expand_files()]
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == ["loop/a/f.csv"]


@pytest.mark.parametrize(
    ("stage", "match"),
    [
        ("propagate: {n_samples: true}", r"n_samples: .*expected a number, got the boolean true"),
        ("propagate: {n_samples: 1.0e+9, n_batches: 1.0e+9}", r"n_samples: .*less than or equal"),
        ("propagate: {n_batches: 1.0e+9}", r"n_batches: .*less than or equal"),
        ("infer: {parameters: {M_q: {normal: [0, 1]}}, n_ensembles: 1000000}", r"n_ensembles"),
    ],
)
def test_counts_that_would_hang_a_run_are_refused_before_it(tmp_path, stage, match):
    from aeroid.pipeline.plans.planning import plan

    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [{simulated: {n_flights: 1}}]\n"
        f"stages:\n  identify: {{parameters: [M_alpha, M_q]}}\n  {stage}\n"
    )
    with pytest.raises(ConfigError, match=match):
        plan(cfg)


@pytest.mark.slow  # botocore's randomised back-off: about 2 s
def test_an_s3_server_that_stops_answering_fails_the_request(tmp_path, monkeypatch):
    import socket
    import threading
    import time

    pytest.importorskip("s3fs")
    import fsspec.config

    from aeroid.errors import StoreError
    from aeroid.pipeline import ResultStore

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept_and_stay_silent() -> None:
        server.settimeout(0.1)
        while not stop.is_set():
            with contextlib.suppress(OSError):
                held.append(server.accept()[0])

    import contextlib

    thread = threading.Thread(target=accept_and_stay_silent, daemon=True)
    thread.start()
    for name in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.setenv(name, "testing")
    monkeypatch.setenv("AWS_DEFAULT_REGION", "us-east-1")
    monkeypatch.setenv("AEROID_REMOTE_TIMEOUT", "0.05")
    endpoint = f"http://127.0.0.1:{server.getsockname()[1]}"
    monkeypatch.setitem(fsspec.config.conf, "s3", {"endpoint_url": endpoint})
    start = time.monotonic()
    try:
        with pytest.raises(StoreError, match="store s3://silent/store") as err:
            ResultStore("s3://silent/store", create=True)
    finally:
        stop.set()
        thread.join()
        for conn in held:
            conn.close()
        server.close()
    assert "timeout" in str(err.value).lower()
    assert time.monotonic() - start < 30  # bounded by the timeout, not minutes


def test_a_store_or_scheduler_the_caller_names_needs_no_opt_in(tmp_path):
    cfg = _config(tmp_path, "")
    assert load_config(cfg, store="memory://x/s").store == "memory://x/s"
    assert load_config(cfg, scheduler="tcp://10.1.2.3:8786").scheduler == "tcp://10.1.2.3:8786"


def test_a_url_store_that_lost_its_marker_mid_run_is_made_whole_by_the_next(tmp_path):
    import uuid

    import fsspec

    from aeroid.pipeline import ResultStore
    from aeroid.pipeline.keys import canonical_json, sha256_hex
    from aeroid.pipeline.stages import CampaignReport
    from aeroid.pipeline.storage._backend import _CHECKED

    url = f"memory://aeroid-test-{uuid.uuid4().hex[:12]}/store"
    store = ResultStore(url)
    key = sha256_hex(canonical_json({"n": 1}))
    report = CampaignReport("t", "x", ("a",), ("flight",), (("a",),))
    assert store.commit("campaign_report", key, report, task={"n": 1})
    fs, base = fsspec.core.url_to_fs(url)
    fs.rm(f"{base}/aeroid-store.json")  # the prefix emptied while the run still wrote
    _CHECKED.discard(url)
    again = ResultStore(url)
    assert fs.exists(f"{base}/aeroid-store.json")
    assert [e.key for e in again.entries()] == [key]
    # anything else under the prefix is still not taken over
    other = f"memory://aeroid-test-{uuid.uuid4().hex[:12]}/store"
    fs.pipe_file(fsspec.core.url_to_fs(other)[1] + "/notes.txt", b"mine")
    from aeroid.errors import StoreError

    with pytest.raises(StoreError, match="is not empty and is not an aeroid store"):
        ResultStore(other)


@pytest.mark.parametrize("name", ['"a\\0b"', "x" * 5000, "a/../../b", "''"])
def test_a_campaign_name_that_cannot_name_a_file_is_refused(tmp_path, name):
    with pytest.raises(ConfigError, match=r"name: .*printable characters"):
        load_config(_config(tmp_path, f"name: {name}\n"))


def test_an_unknown_simulate_options_key_is_refused_before_any_load(tmp_path):
    from aeroid.pipeline.plans.planning import plan

    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [missing.csv]\n"
        "stages:\n  identify: {parameters: [M_q], simulate_options: {rtoll: 1.0e-6}}\n"
    )
    with pytest.raises(ConfigError, match=r"simulate_options: .*unknown keys \['rtoll'\]"):
        plan(cfg)


def test_a_csv_with_many_columns_reports_its_duplicates(tmp_path):
    from aeroid import load_flight_test

    names = ["time", *(f"c{i}" for i in range(20_000)), "c7", "c7", "c19999"]
    path = tmp_path / "wide.csv"
    path.write_text(",".join(names) + "\n" + "\n".join(",".join(["0"] * len(names)) for _ in "ab"))
    with pytest.raises(DataFormatError, match=r"duplicate column names \['c19999', 'c7'\]"):
        load_flight_test(path)


def test_a_map_unit_that_contradicts_the_files_own_is_refused():
    from aeroid import FlightData
    from aeroid.io.channel_map import apply_channel_map

    t = np.arange(10) * 0.1
    data = FlightData(t, {"gyro_y": np.sin(t)}, {"gyro_y": "rad/s"}, {"source": "log.ulg"})
    with pytest.raises(DataFormatError, match=r"log.ulg: channel map 'q': unit 'deg/s' contra"):
        apply_channel_map(data, {"q": {"channel": "gyro_y", "unit": "deg/s"}})
    same = apply_channel_map(data, {"q": {"channel": "gyro_y", "unit": "rad/s"}})
    np.testing.assert_array_equal(same.channels["q"], np.sin(t))
    unstated = FlightData(t, {"gyro_y": np.sin(t)})
    converted = apply_channel_map(unstated, {"q": {"channel": "gyro_y", "unit": "deg/s"}})
    np.testing.assert_allclose(converted.channels["q"], np.deg2rad(np.sin(t)))


def test_load_mapped_and_the_config_pass_the_external_data_opt_in(tmp_path):
    from aeroid.errors import ChannelError
    from aeroid.io.channel_map import load_mapped

    path, n = _log_with_external(tmp_path)
    with pytest.warns(UserWarning, match="allow_external_data"), pytest.raises(ChannelError):
        load_mapped(path, {"alpha": "leak"})
    data = load_mapped(path, {"alpha": "leak"}, allow_external_data=True)
    assert data.channels["alpha"].tobytes() == _SECRET[: n * 8]
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [{path: hostile.h5, allow_external_data: true}]\n"
    )
    ((_, _, spec),) = load_config(cfg).expand_files()
    assert spec.loader_options()["allow_external_data"] is True
    cfg.write_text("model: short_period\nflights: [{path: hostile.h5}]\n")
    ((_, _, spec),) = load_config(cfg).expand_files()
    assert "allow_external_data" not in spec.loader_options()  # keys of old runs unchanged
