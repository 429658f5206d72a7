"""The Zarr result store and the record codec: round trips, atomic commits, integrity."""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pytest

from aeroid.catalog import short_period_flight
from aeroid.errors import StoreError
from aeroid.identification import IdentificationResult
from aeroid.pipeline import ResultStore, open_store, register_record
from aeroid.pipeline.codec import decode, encode
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.stages import CampaignReport


@register_record
@dataclass(frozen=True, eq=False)
class Nested:
    label: str
    values: np.ndarray


@register_record
@dataclass(frozen=True, eq=False)
class Everything:
    text: str
    count: int
    ratio: float
    flag: bool
    nothing: None
    nan: float
    names: tuple[str, ...]
    floats: Mapping[str, float]
    arrays: Mapping[str, np.ndarray]
    complex_: np.ndarray
    ints: np.ndarray
    bools: np.ndarray
    empty: np.ndarray
    strings: np.ndarray
    inner: Nested
    inners: tuple[Nested, ...]
    meta: Mapping[str, object] = field(default_factory=dict)


def _everything() -> Everything:
    return Everything(
        text="é",
        count=3,
        ratio=0.1,
        flag=True,
        nothing=None,
        nan=float("nan"),
        names=("a", "b"),
        floats={"z": 1.0, "a": -np.inf},
        arrays={"x": np.arange(3.0), "y/odd name": np.eye(2)},
        complex_=np.array([1 + 2j, -3j]),
        ints=np.arange(4, dtype=np.int32),
        bools=np.array([True, False]),
        empty=np.zeros((0, 3)),
        strings=np.array(["p", "qq"]),
        inner=Nested("n", np.ones(2)),
        inners=(Nested("a", np.zeros(1)), Nested("b", np.ones(1))),
        meta={"nested": {"k": (1, 2)}, "s": "v"},  # sequences come back as tuples
    )


def _same(x: object, y: object) -> None:
    """Recursive equality: arrays bit for bit, NaN equal to NaN, records field by field."""
    if hasattr(x, "__dataclass_fields__"):
        assert type(x) is type(y)
        for name in x.__dataclass_fields__:  # type: ignore[attr-defined]
            _same(getattr(x, name), getattr(y, name))
    elif isinstance(x, np.ndarray):
        assert isinstance(y, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()
    elif isinstance(x, Mapping):
        assert list(x) == list(y)
        for k in x:
            _same(x[k], y[k])
    elif isinstance(x, (tuple, list)):
        assert isinstance(y, tuple) and len(x) == len(y)
        for u, v in zip(x, y, strict=True):
            _same(u, v)
    elif isinstance(x, float) and np.isnan(x):
        assert np.isnan(y)
    else:
        assert x == y and type(x) is type(y)


def test_codec_round_trips_every_kind_of_field():
    obj = _everything()
    tree, arrays = encode(obj)
    json.dumps(tree, allow_nan=False)  # attributes are plain JSON
    _same(decode(tree, arrays), obj)


def _ident() -> IdentificationResult:
    cov = np.array([[0.01, 0.001], [0.001, 0.04]])
    return IdentificationResult(
        parameters={"M_q": -2.5, "M_alpha": -6.0},
        stderr={"M_q": 0.1, "M_alpha": 0.2},
        covariance=cov,
        parameter_names=("M_q", "M_alpha"),
        fixed={"Z_alpha": -1.2},
        covariance_white=cov / 2,
        error_bars="colored",
        identifiable=True,
        unidentifiable=(),
        success=True,
        message="ok",
        n_iterations=7,
        cost=1.5,
        method="output_error",
        output_names=("alpha", "q"),
        noise_covariance=np.diag([2.5e-5, 1e-4]),
        initial_states=({"alpha": 0.0, "q": 0.0},),
        biases=(),
        extra_stderr={},
        residuals=(np.ones((5, 2)),),
        sigma2=None,
        model_name="short_period",
    )


def test_store_round_trips_library_records(tmp_path):
    store = ResultStore(tmp_path / "s")
    data = short_period_flight(seed=3)
    for stage, rec in (("load", data), ("identify", _ident())):
        key = sha256_hex(canonical_json({"stage": stage}))
        assert store.commit(stage, key, rec, task={"stage": stage})
        back = store.load(key, stage)
        assert type(back) is type(rec)
        _same(back, rec)
        assert not back.__dataclass_fields__ or True
    back = store.load(sha256_hex(canonical_json({"stage": "identify"})))
    assert back.covariance.flags.writeable is False
    assert back.summary() == _ident().summary()


def test_commit_is_never_an_overwrite(tmp_path):
    store = ResultStore(tmp_path / "s")
    task = {"x": 1}
    key = sha256_hex(canonical_json(task))
    rep = CampaignReport("t", "first", ("a",), ("flight",), (("a",),))
    assert store.commit("campaign_report", key, rep, task=task) is True
    other = CampaignReport("t", "second", ("a",), ("flight",), (("a",),))
    assert store.commit("campaign_report", key, other, task=task) is False
    assert store.load(key).markdown == "first"
    assert store.temporaries() == []


def test_task_and_provenance_not_in_plain_json_types_are_normalised(tmp_path):
    # a planned task's document is plain JSON already; one given by hand may hold
    # NumPy scalars, tuples and non-finite floats, and must store and verify the same
    store = ResultStore(tmp_path / "s")
    task = {"n": np.int64(3), "x": np.float64(0.5), "bad": float("inf"), "t": (1, 2)}
    key = sha256_hex(canonical_json(task))
    rep = CampaignReport("t", "text", ("a",), ("flight",), (("a",),))
    assert store.commit(
        "campaign_report", key, rep, task=task, provenance={"s": np.float32(1.5), "v": float("nan")}
    )
    meta = store.metadata(key)
    assert meta["task"] == {"n": 3, "x": 0.5, "bad": {"__float__": "inf"}, "t": [1, 2]}
    assert meta["provenance"] == {"s": 1.5, "v": {"__float__": "nan"}}
    assert store.verify(key) is None
    assert store.load(key).markdown == "text"


def test_a_commit_remakes_folders_removed_under_it(tmp_path):
    import shutil

    store = ResultStore(tmp_path / "s")
    for i in range(3):
        task = {"i": i}
        key = sha256_hex(canonical_json(task))
        rep = CampaignReport("t", f"text {i}", ("a",), ("flight",), (("a",),))
        assert store.commit("campaign_report", key, rep, task=task)
        assert store.load(key).markdown == f"text {i}"
        # e.g. a user clearing the temporaries or a stage's results between two runs
        shutil.rmtree(store.root / (".tmp" if i == 0 else "campaign_report"))
    assert store.temporaries() == []


def test_concurrent_commits_of_one_key_leave_one_intact_entry(tmp_path):
    store = ResultStore(tmp_path / "s")
    task = {"y": 2}
    key = sha256_hex(canonical_json(task))
    results = []

    def commit(i: int) -> None:
        rec = Nested(f"writer {i}", np.full(1000, float(i)))
        results.append(ResultStore(tmp_path / "s").commit("x", key, rec, task=task))

    threads = [threading.Thread(target=commit, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sum(results) == 1
    assert store.verify(key) is None
    assert store.temporaries() == []
    rec = store.load(key)
    assert np.all(rec.values == float(rec.label.split()[1]))


def _committed(tmp_path):
    store = ResultStore(tmp_path / "s")
    task = {"z": 3}
    key = sha256_hex(canonical_json(task))
    store.commit("identify", key, _ident(), task=task)
    return store, key


def test_altered_array_bytes_are_detected_on_read_and_by_verify(tmp_path):
    store, key = _committed(tmp_path)
    chunk = store.path_for("identify", key) / "covariance" / "0.0"
    raw = bytearray(chunk.read_bytes())
    raw[-1] ^= 0xFF
    chunk.write_bytes(bytes(raw))
    with pytest.raises(StoreError, match="corrupt"):
        store.load(key)
    assert key in store.verify_all()
    # removed, it is gone whole (nothing left in the temporaries) and can be committed again
    assert store.remove("identify", key) is True
    assert not store.exists("identify", key) and list(store.entries()) == []
    assert store.temporaries() == [] and store.remove("identify", key) is False
    assert store.commit("identify", key, _ident(), task={"z": 3}) is True
    assert store.verify_all() == {}


def test_a_truncated_chunk_is_reported_as_a_corrupt_entry(tmp_path):
    store, key = _committed(tmp_path)
    chunk = store.path_for("identify", key) / "covariance" / "0.0"
    chunk.write_bytes(chunk.read_bytes()[:-8])
    # the words the command looks for to suggest `aeroid verify --remove`
    with pytest.raises(
        StoreError, match=r"\(identify\) in .* is corrupt: chunk .* holds 3 values, expected 4"
    ):
        store.load(key)
    assert " is corrupt: " in store.verify(key)


def test_altered_attributes_are_detected(tmp_path):
    store, key = _committed(tmp_path)
    meta_path = store.path_for("identify", key) / "zarr.json"
    original = meta_path.read_text()
    doc = json.loads(original)
    doc["attributes"]["aeroid"]["record"]["fields"]["message"] = "tampered"
    meta_path.write_text(json.dumps(doc))
    with pytest.raises(StoreError, match="altered"):
        store.load(key, "identify")
    # a value this store never writes (JSON's NaN, infinity), in the record or the task
    for where in ("record", "task"):
        doc = json.loads(original)
        doc["attributes"]["aeroid"][where]["extra"] = float("nan")
        meta_path.write_text(json.dumps(doc))
        with pytest.raises(StoreError, match="is corrupt"):
            store.load(key, "identify")
    meta_path.write_text(original)
    store.load(key, "identify")  # the original reads
    meta_path.write_text("{ not json")
    assert "unreadable" in store.verify(key, "identify")


def test_reading_never_imports_unregistered_code():
    tree, arrays = encode(_ident())
    tree["__record__"] = "os:system"
    with pytest.raises(StoreError, match="not registered"):
        decode(tree, arrays)
    tree["__record__"] = "aeroid.pipeline.store:ResultStore"
    with pytest.raises(StoreError, match="not a dataclass"):
        decode(tree, arrays)


def test_unstorable_values_name_the_field():
    @dataclass(frozen=True)
    class Bad:
        fn: object

    with pytest.raises(StoreError, match="fn"):
        encode(Bad(print))


def test_gc_removes_temporaries_of_dead_processes_only(tmp_path):
    store = ResultStore(tmp_path / "s")
    tmp = store.root / ".tmp"
    tmp.mkdir()
    host = os.uname().nodename
    dead = tmp / f"{'a' * 64}.{host}.999999999.deadbeef"
    alive = tmp / f"{'b' * 64}.{host}.{os.getppid()}.deadbeef"
    dead.mkdir(), alive.mkdir()
    removed = store.gc()
    assert removed == [dead]
    assert alive.exists() and not dead.exists()


def test_open_store_refuses_non_stores(tmp_path):
    with pytest.raises(StoreError, match="not an aeroid store"):
        open_store(tmp_path)
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(StoreError, match="not empty"):
        ResultStore(tmp_path)
    with pytest.raises(StoreError, match="Protocol not known: nosuch"):
        ResultStore("nosuch://bucket/store")


def test_find_by_prefix(tmp_path):
    store, key = _committed(tmp_path)
    assert store.find(key[:8]).key == key
    with pytest.raises(StoreError, match="no such entry"):
        store.find("0" * 10 if not key.startswith("0") else "f" * 10)
    with pytest.raises(StoreError, match="hexadecimal"):
        store.find("xyz")


def test_entries_are_plain_zarr_v3_that_zarr_python_reads(tmp_path):
    import zarr

    store = ResultStore(tmp_path / "s")
    task = {"w": 1}
    key = sha256_hex(canonical_json(task))
    store.commit("everything", key, _everything(), task=task)
    group = zarr.open_group(store=str(store.path_for("everything", key)), mode="r", zarr_format=3)
    meta = group.attrs["aeroid"]
    assert meta["key"] == key and meta["record_type"].endswith(":Everything")
    ours = store.load_arrays(key)
    assert set(ours) == set(meta["digests"])
    for name, arr in ours.items():
        theirs = group[name][...]
        assert theirs.dtype == arr.dtype and theirs.shape == arr.shape
        assert np.asarray(theirs).tobytes() == arr.tobytes()
