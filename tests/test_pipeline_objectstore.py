"""Stores at a URL (object stores through fsspec): an entry per object, integrity.

``memory://`` stands in for an object store (no folders, no rename, no
shared process); ``local://`` goes through the same object-store code on a
local disk, so worker processes of an embedded cluster can share it.
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path

import fsspec
import numpy as np
import pytest
from test_cli import invoke, make_campaign
from test_pipeline_store import _ident, flip_in_place, rezip

from aeroid.errors import StoreError
from aeroid.pipeline import ResultStore, open_store, run
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.stages import CampaignReport
from aeroid.pipeline.storage.store import is_store


def _url() -> str:
    return f"memory://aeroid-test-{uuid.uuid4().hex[:12]}/store"


def _commit(store: ResultStore, n: int = 0) -> str:
    task = {"n": n}
    key = sha256_hex(canonical_json(task))
    assert store.commit("identify", key, _ident(), task=task) is True
    return key


def test_a_url_store_round_trips_and_never_overwrites():
    url = _url()
    assert not is_store(url)
    with pytest.raises(StoreError, match="not an aeroid store"):
        open_store(url)
    store = ResultStore(url)
    assert is_store(url) and type(open_store(url)) is type(store) is ResultStore
    assert store.location.kind == "fsspec" and store.location.protocol == "memory"
    key = _commit(store)
    assert store.exists("identify", key)
    back = store.load(key, "identify")
    assert back.summary() == _ident().summary()
    np.testing.assert_array_equal(back.covariance, _ident().covariance)
    assert back.covariance.flags.writeable is False
    task = {"n": 0}
    other = CampaignReport("t", "other", ("a",), ("flight",), (("a",),))
    assert store.commit("identify", key, other, task=task) is False
    assert store.load(key).parameters == _ident().parameters
    # listed and found like the entries of a folder store
    assert [(e.key, e.stage) for e in store.entries()] == [(key, "identify")]
    assert store.find(key[:8]).path == f"{url}/identify/{key}.zarr.zip"
    assert store.verify_all() == {} and store.temporaries() == []


def test_zarr_python_reads_url_entries(tmp_path):
    import zarr

    url = _url()
    store = ResultStore(url)
    key = _commit(store)
    fs, base = fsspec.core.url_to_fs(url)
    fetched = tmp_path / "entry.zarr.zip"  # an object, fetched as it is
    fetched.write_bytes(fs.cat_file(f"{base}/identify/{key}.zarr.zip"))
    zipped = zarr.storage.ZipStore(fetched, mode="r")
    group = zarr.open_group(store=zipped, mode="r", zarr_format=3)
    assert group.attrs["aeroid"]["key"] == key
    np.testing.assert_array_equal(group["covariance"][...], _ident().covariance)


def test_altered_bytes_in_a_url_store_are_detected():
    url = _url()
    store = ResultStore(url)
    key = _commit(store)
    fs, base = fsspec.core.url_to_fs(url)
    obj = f"{base}/identify/{key}.zarr.zip"
    good = fs.cat_file(obj)
    fs.pipe_file(obj, flip_in_place(good, "covariance/")[0])
    with pytest.raises(StoreError, match=r"is corrupt: .*CRC"):
        store.load(key, "identify")
    fs.pipe_file(obj, rezip(good, "covariance/0.0", lambda b: bytes([b[0] ^ 0xFF]) + b[1:])[0])
    with pytest.raises(StoreError, match="does not match its digest"):
        store.load(key, "identify")
    assert key in store.verify_all()
    assert store.remove("identify", key) is True
    assert not store.exists("identify", key) and list(store.entries()) == []
    assert store.temporaries() == [] and not fs.find(f"{base}/identify")
    assert store.remove("identify", key) is False


def test_a_commit_is_one_object_so_an_interrupted_one_leaves_nothing(monkeypatch):
    url = _url()
    store = ResultStore(url)
    fs, base = fsspec.core.url_to_fs(url)
    task = {"n": 7}
    key = sha256_hex(canonical_json(task))
    put = store._backend._put_new  # type: ignore[attr-defined]
    puts = []
    monkeypatch.setattr(
        store._backend, "_put_new", lambda path, data: (puts.append(path), put(path, data))[1]
    )
    assert store.commit("identify", key, _ident(), task=task) is True
    assert puts == [f"{base}/identify/{key}.zarr.zip"]  # the whole entry in one PUT

    def killed(path, data):
        raise KeyboardInterrupt  # the run is killed while its PUT is on the wire

    other = {"n": 8}
    other_key = sha256_hex(canonical_json(other))
    monkeypatch.setattr(store._backend, "_put_new", killed)
    with pytest.raises(KeyboardInterrupt):
        store.commit("identify", other_key, _ident(), task=other)
    monkeypatch.undo()
    assert not store.exists("identify", other_key)
    assert [e.key for e in store.entries()] == [key]
    assert store.temporaries() == [] and store.gc(max_age=0) == []
    # a backend that is a file system may keep a file cut short: reported, removable
    obj = f"{base}/identify/{other_key}.zarr.zip"
    fs.pipe_file(obj, fs.cat_file(f"{base}/identify/{key}.zarr.zip")[:500])
    assert "is corrupt" in store.verify_all()[other_key]
    assert store.remove("identify", other_key) is True
    assert store.commit("identify", other_key, _ident(), task=other) is True
    assert store.verify_all() == {}


def test_unknown_or_uninstalled_backends_name_the_store():
    with pytest.raises(StoreError, match=r"nosuch://b/s.*Protocol not known"):
        ResultStore("nosuch://b/s")


def test_the_aeroid_command_on_a_url_store(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    url = _url()
    code, out, _ = invoke("run", str(cfg), "--store", url, "--json", "--workers", "0")
    doc = json.loads(out)
    assert code == 0 and (doc["computed"], doc["failed"]) == (5, 0)
    # an object store holds results only; the report goes beside the config
    assert Path(doc["report"]) == tmp_path / "reports" / "campaign.md"
    code, out, _ = invoke("run", str(cfg), "--store", url, "--json", "--workers", "0")
    assert code == 0 and json.loads(out)["cached"] == 5
    code, out, _ = invoke("status", str(cfg), "--store", url, "--json")
    assert json.loads(out)["missing"] == 0 and json.loads(out)["store"] == url
    stats = next(t for t in doc["tasks"] if t["stage"] == "stats")
    code, out, _ = invoke("show", stats["key"][:12], "--store", url)
    assert code == 0 and "stats of elevator" in out
    code, out, _ = invoke("rerun", stats["key"], "--store", url)
    assert code == 0 and "bit-identical" in out
    code, out, _ = invoke("verify", "--store", url)
    assert code == 0 and "5 entries checked, 0 corrupt" in out
    fs, base = fsspec.core.url_to_fs(url)
    key = stats["key"]
    obj = f"{base}/stats/{key}.zarr.zip"
    fs.pipe_file(obj, rezip(fs.cat_file(obj), "zarr.json", lambda _: b"{ not json")[0])
    code, out, _ = invoke("verify", "--store", url)
    assert code == 1 and f"CORRUPT {key}" in out


def _arrays(store: ResultStore) -> dict[str, dict[str, bytes]]:
    return {
        e.key: {n: a.tobytes() for n, a in store.load_arrays(e.key, e.stage).items()}
        for e in store.entries()
    }


def test_embedded_cluster_workers_share_a_url_store(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [{simulated: {n_flights: 2, seed: 5}}]\n"
        "stages:\n  identify: {parameters: [M_alpha, M_q]}\n  validate: {}\n"
        "  propagate: {metric: natural_frequency, n_samples: 200}\n"
        "  campaign_report: {figures: false}\n"
    )
    folder = run(cfg, store=tmp_path / "folder", workers=0)
    url = f"local://{tmp_path}/objects"
    shared = run(cfg, store=url, workers=2)
    assert folder.failed == 0 and shared.failed == 0
    assert shared.count("computed") == folder.count("computed")
    same = _arrays(open_store(tmp_path / "folder"))
    assert _arrays(open_store(url)) == same and len(same) == shared.count("computed")


def test_which_tasks_are_stored_takes_one_listing_per_stage_not_a_request_per_key(monkeypatch):
    store = ResultStore(_url())
    keys = [_commit(store, n) for n in range(3)]
    missing = sha256_hex(canonical_json({"n": "missing"}))
    asked = [("identify", k) for k in keys] + [("identify", missing), ("load", keys[0])]
    expected = {("identify", k) for k in keys}
    assert {a for a in asked if store.exists(*a)} == expected

    def no_requests_per_key(*args, **kwargs):
        raise AssertionError("a request per key")

    monkeypatch.setattr(store._backend._fs, "exists", no_requests_per_key)  # type: ignore[attr-defined]
    assert store.stored(asked) == expected


# -- a real S3 server: moto's, over HTTP, reached by s3fs ------------------------------


@pytest.fixture(scope="module")
def s3_endpoint():
    """The URL of an S3-compatible server running in this process (moto's server mode)."""
    pytest.importorskip("s3fs")
    server_mod = pytest.importorskip("moto.server")
    server = server_mod.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()


_CREDENTIALS = {
    "AWS_ACCESS_KEY_ID": "testing",
    "AWS_SECRET_ACCESS_KEY": "testing",
    "AWS_DEFAULT_REGION": "us-east-1",
}


@pytest.fixture
def s3_url(s3_endpoint, monkeypatch):
    """A fresh bucket on the server; stores reach it through fsspec's configuration, as
    ``FSSPEC_S3_ENDPOINT_URL`` in the environment sets it."""
    import fsspec.config
    import s3fs

    for name, value in _CREDENTIALS.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setitem(fsspec.config.conf, "s3", {"endpoint_url": s3_endpoint})
    bucket = f"aeroid-{uuid.uuid4().hex[:12]}"
    s3fs.S3FileSystem(endpoint_url=s3_endpoint).mkdir(bucket)
    return f"s3://{bucket}/store"


@pytest.mark.slow
def test_an_s3_store_round_trips_detects_damage_and_never_overwrites(s3_url):
    assert not is_store(s3_url)
    store = ResultStore(s3_url)
    key = _commit(store)
    assert is_store(s3_url) and store.exists("identify", key)
    assert store.load(key, "identify").summary() == _ident().summary()
    other = CampaignReport("t", "other", ("a",), ("flight",), (("a",),))
    assert store.commit("identify", key, other, task={"n": 0}) is False
    assert [(e.key, e.stage) for e in store.entries()] == [(key, "identify")]
    assert store.find(key[:8]).path == f"{s3_url}/identify/{key}.zarr.zip"
    assert store.check_entry("identify", key) is True and store.verify_all() == {}
    fs, base = fsspec.core.url_to_fs(s3_url)
    obj = f"{base}/identify/{key}.zarr.zip"
    fs.pipe_file(obj, flip_in_place(fs.cat_file(obj), "covariance/")[0])
    assert store.check_entry("identify", key) is False
    assert "CRC" in store.verify_all()[key]
    assert store.remove("identify", key) is True and list(store.entries()) == []


@pytest.mark.slow
def test_claims_on_an_s3_store_are_put_if_absent(s3_url):
    store = ResultStore(s3_url)
    key = sha256_hex(canonical_json({"n": 0}))
    claim = store.claim("identify", key)
    assert claim is not None and store.claim("identify", key) is None
    assert store.wait_for("identify", key, timeout=0.05) is False
    # a run on another host that crashed holding the claim: its lease has run out
    fs, base = fsspec.core.url_to_fs(s3_url)
    crashed = {"pid": 1, "host": "elsewhere", "expires": 0.0, "lease": 60.0, "token": "t"}
    fs.pipe_file(f"{base}/identify/{key}.claim", json.dumps(crashed).encode())
    taken = store.claim("identify", key)
    assert taken is not None and claim.renew() is False
    _commit(store)
    assert store.wait_for("identify", key, timeout=5.0) is True
    taken.release()
    assert not fs.exists(f"{base}/identify/{key}.claim")


@pytest.mark.slow
def test_the_aeroid_command_on_an_s3_store(tmp_path, s3_url):
    cfg = make_campaign(tmp_path, n=2)
    code, out, _ = invoke("run", str(cfg), "--store", s3_url, "--json", "--workers", "0")
    doc = json.loads(out)
    assert code == 0 and (doc["computed"], doc["failed"]) == (5, 0)
    code, out, _ = invoke("run", str(cfg), "--store", s3_url, "--json", "--workers", "0")
    assert code == 0 and json.loads(out)["cached"] == 5
    code, out, _ = invoke("verify", "--store", s3_url)
    assert code == 0 and "5 entries checked, 0 corrupt" in out


@pytest.mark.slow
def test_a_fresh_process_finds_the_s3_endpoint_in_the_environment(s3_endpoint, s3_url):
    import subprocess
    import sys

    store = ResultStore(s3_url)
    key = _commit(store)
    env = {**os.environ, **_CREDENTIALS, "FSSPEC_S3_ENDPOINT_URL": s3_endpoint}
    code = (
        "import sys; from aeroid.pipeline import open_store; "
        "s = open_store(sys.argv[1]); print([e.key for e in s.entries()], s.verify_all())"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, s3_url], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"[{key!r}] {{}}"
