"""The Zarr result store and the record codec: round trips, atomic commits, integrity."""

from __future__ import annotations

import io
import json
import os
import struct
import threading
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import StoreError
from aeroid.estimation.identification import IdentificationResult
from aeroid.models.catalog import short_period_flight
from aeroid.pipeline import ResultStore, open_store, register_record
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.stages import CampaignReport
from aeroid.pipeline.storage.codec import decode, encode

# -- altering entries as a failing disk or a careless hand would --------------------


def rezip(raw: bytes, member: str, change: Callable[[bytes], bytes]) -> tuple[bytes, bytes]:
    """An entry's zip with one member's bytes changed, still a valid zip: (new zip, old bytes)."""
    with zipfile.ZipFile(io.BytesIO(raw)) as z:
        members = {i.filename: z.read(i) for i in z.infolist()}
    original = members[member]
    members[member] = change(original)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return out.getvalue(), original


def flip_in_place(raw: bytes, prefix: str) -> tuple[bytes, str, bytes]:
    """An entry's zip with one bit flipped in the stored bytes of the first chunk whose
    member name starts with `prefix`: (new zip, member, its original bytes)."""
    with zipfile.ZipFile(io.BytesIO(raw)) as z:
        info = next(
            i
            for i in z.infolist()
            if i.filename.startswith(prefix) and not i.filename.endswith("zarr.json")
        )
        original = z.read(info)
    name_len, extra_len = struct.unpack(
        "<HH", raw[info.header_offset + 26 : info.header_offset + 30]
    )
    at = info.header_offset + 30 + name_len + extra_len + info.file_size // 2
    out = bytearray(raw)
    out[at] ^= 0x01
    return bytes(out), info.filename, original


def rewrite_member(entry: Path, member: str, change: Callable[[bytes], bytes]) -> bytes:
    """Change one member of the entry file `entry`; returns its original bytes."""
    raw, original = rezip(entry.read_bytes(), member, change)
    entry.write_bytes(raw)
    return original


def flip_a_bit(entry: Path, prefix: str = "") -> tuple[str, bytes]:
    """Flip a bit of a chunk in the entry file `entry`: (member, its original bytes)."""
    raw, member, original = flip_in_place(entry.read_bytes(), prefix)
    entry.write_bytes(raw)
    return member, original


def member_bytes(entry: Path, member: str) -> bytes:
    with zipfile.ZipFile(entry) as z:
        return z.read(member)


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


@pytest.mark.parametrize("system", ["renameat2", "refused", "link", "no links"])
def test_every_way_of_committing_never_overwrites(tmp_path, monkeypatch, system):
    """A commit never replaces an entry, by Linux's no-replace rename; on a file system
    refusing it (NFS) or with a C library without it, by a hard link; on a file system
    without hard links either, by a look and then a rename."""
    import ctypes
    import errno

    from aeroid.pipeline.storage import _rename as store_mod

    def refused(*args: object) -> int:
        ctypes.set_errno(errno.EINVAL)
        return -1

    def no_links(*args: object, **kwargs: object) -> None:
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(store_mod, "_NOREPLACE_UNSUPPORTED", set())
    if system == "refused":
        monkeypatch.setattr(store_mod, "_renameat2", lambda: refused)
    elif system != "renameat2":
        monkeypatch.setattr(store_mod, "_renameat2", lambda: None)
    if system == "no links":
        monkeypatch.setattr(os, "link", no_links)
    store = ResultStore(tmp_path / "s")
    for n in range(2):  # the stage's first entry makes its folder; the second finds it
        task = {"x": n}
        key = sha256_hex(canonical_json(task))
        rep = CampaignReport("t", "first", ("a",), ("flight",), (("a",),))
        assert store.commit("campaign_report", key, rep, task=task) is True
        other = CampaignReport("t", "second", ("a",), ("flight",), (("a",),))
        assert store.commit("campaign_report", key, other, task=task) is False
        assert store.load(key).markdown == "first"
    assert store.temporaries() == [] and store.verify_all() == {}
    assert os.stat(store.path_for("campaign_report", key)).st_nlink == 1
    if system == "refused":  # asked once, then known for this file system
        assert len(store_mod._NOREPLACE_UNSUPPORTED) == 1


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
    entry = store.path_for("identify", key)
    good = entry.read_bytes()
    # a bit flipped on disk: the zip's own checksum of the member catches it
    flip_a_bit(entry, "covariance/")
    with pytest.raises(StoreError, match=r"\(identify\) in .* is corrupt: .*CRC"):
        store.load(key)
    # bytes changed and the zip made whole again: the array's SHA-256 catches it
    entry.write_bytes(good)
    rewrite_member(entry, "covariance/0.0", lambda b: b[:-1] + bytes([b[-1] ^ 0xFF]))
    with pytest.raises(StoreError, match="array 'covariance' does not match its digest"):
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
    rewrite_member(store.path_for("identify", key), "covariance/0.0", lambda b: b[:-8])
    # the words the command looks for to suggest `aeroid verify --remove`
    with pytest.raises(
        StoreError, match=r"\(identify\) in .* is corrupt: chunk .* holds 3 values, expected 4"
    ):
        store.load(key)
    assert " is corrupt: " in store.verify(key)


def test_altered_attributes_are_detected(tmp_path):
    store, key = _committed(tmp_path)
    entry = store.path_for("identify", key)
    original = member_bytes(entry, "zarr.json").decode()

    def write(text: str) -> None:
        rewrite_member(entry, "zarr.json", lambda _: text.encode())

    doc = json.loads(original)
    doc["attributes"]["aeroid"]["record"]["fields"]["message"] = "tampered"
    write(json.dumps(doc))
    with pytest.raises(StoreError, match="altered"):
        store.load(key, "identify")
    # a value this store never writes (JSON's NaN, infinity), in the record or the task
    for where in ("record", "task"):
        doc = json.loads(original)
        doc["attributes"]["aeroid"][where]["extra"] = float("nan")
        write(json.dumps(doc))
        with pytest.raises(StoreError, match="is corrupt"):
            store.load(key, "identify")
    write(original)
    store.load(key, "identify")  # the original reads
    write("{ not json")
    assert "unreadable" in store.verify(key, "identify")
    # not a zip at all (a file cut short by a failing disk)
    entry.write_bytes(entry.read_bytes()[:100])
    assert "is corrupt: unreadable" in store.verify(key, "identify")


def test_a_store_of_the_earlier_folder_layout_is_refused_with_the_way_out(tmp_path):
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "aeroid-store.json").write_text('{"format": 1}')
    with pytest.raises(StoreError, match=r"layout version 1 .*run the campaign into a new store"):
        open_store(tmp_path / "old")


def test_reading_never_imports_unregistered_code():
    tree, arrays = encode(_ident())
    tree["__record__"] = "os:system"
    with pytest.raises(StoreError, match="not registered"):
        decode(tree, arrays)
    tree["__record__"] = "aeroid.pipeline.storage.store:ResultStore"
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


def test_two_runs_creating_one_store_at_once_both_open_it(tmp_path, monkeypatch):
    # A second run finds the first one's marker being written (its temporary file), or
    # already written with the first folders beside it: neither is a foreign folder.
    from aeroid.pipeline.storage import _store_paths

    busy = tmp_path / "a"
    busy.mkdir()
    (busy / ".aeroid-store.json.0123abcd").write_bytes(b"{")
    ResultStore(busy)
    assert (busy / "aeroid-store.json").is_file()

    made = tmp_path / "b"
    ResultStore(made)
    (made / "identify").mkdir()
    real = os.path.isfile
    seen: list[str] = []

    def late(path: str) -> bool:  # the marker appears just after this run first looked
        if str(path).endswith("aeroid-store.json") and not seen:
            seen.append(path)
            return False
        return real(path)

    monkeypatch.setattr(_store_paths.os.path, "isfile", late)
    _store_paths._CHECKED.clear()
    ResultStore(made)
    assert seen


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
    entry = store.path_for("everything", key)
    assert entry.name == f"{key}.zarr.zip" and entry.parent.name == "everything"
    zipped = zarr.storage.ZipStore(entry, mode="r")
    group = zarr.open_group(store=zipped, mode="r", zarr_format=3)
    meta = group.attrs["aeroid"]
    assert meta["key"] == key and meta["record_type"].endswith(":Everything")
    ours = store.load_arrays(key)
    assert set(ours) == set(meta["digests"])
    for name, arr in ours.items():
        theirs = group[name][...]
        assert theirs.dtype == arr.dtype and theirs.shape == arr.shape
        assert np.asarray(theirs).tobytes() == arr.tobytes()


def test_an_entry_is_a_valid_zip_whichever_writer_made_it(tmp_path, monkeypatch):
    """The store's own zip writer and zipfile's (used past 2 GiB, for Zip64) make entries
    that zipfile reads member for member, checksums included, and that load the same."""
    from aeroid.pipeline.storage import _zipentry as store_mod

    record = Everything(
        **{**_everything().__dict__, "arrays": {"x": np.arange(3.0), "é": np.eye(2)}}
    )
    task = {"w": 2}
    key = sha256_hex(canonical_json(task))
    contents = []
    for limit in (store_mod._ZIP32_LIMIT, 0):
        monkeypatch.setattr(store_mod, "_ZIP32_LIMIT", limit)
        store = ResultStore(tmp_path / f"s{limit}")
        store.commit("everything", key, record, task=task)
        entry = store.path_for("everything", key)
        with zipfile.ZipFile(entry) as z:
            assert z.testzip() is None  # every member's CRC-32 checks
            infos = z.infolist()
            assert all(i.compress_type == zipfile.ZIP_STORED for i in infos)
            assert all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in infos)
            assert infos[-1].filename == "zarr.json"  # the group's metadata last
            contents.append({i.filename: z.read(i) for i in infos if i.filename != "zarr.json"})
        _same(store.load(key), record)
    assert contents[0] == contents[1] and "inners.1.values/0" in contents[0]
    # a name beyond ASCII is marked UTF-8, as zipfile expects
    with zipfile.ZipFile(io.BytesIO(store_mod._stored_zip([("α/0", b"x"), ("b", b"")]))) as z:
        assert z.testzip() is None and z.namelist() == ["α/0", "b"] and z.read("α/0") == b"x"


def test_record_types_are_stored_under_stable_names_and_old_names_still_read(tmp_path, monkeypatch):
    from aeroid.pipeline.storage import codec

    store = ResultStore(tmp_path / "s")
    tree, _ = encode(_ident())
    assert tree["__record__"] == "IdentificationResult"  # no module: moving one breaks nothing
    assert encode(CampaignReport("t", "m", (), (), ()))[0]["__record__"] == "CampaignReport"
    # entries written before stable names carry module:qualname; and a class that has
    # since moved to another module is found by its public name
    for old in (
        "aeroid.estimation.identification:IdentificationResult",
        "aeroid.gone:IdentificationResult",
    ):
        task = {"old": old}
        key = sha256_hex(canonical_json(task))
        monkeypatch.setitem(codec._NAMES, IdentificationResult, old)
        assert store.commit("identify", key, _ident(), task=task)
        monkeypatch.undo()
        assert store.metadata(key)["record_type"] == old
        assert store.verify(key) is None
        assert store.load(key).summary() == _ident().summary()
    tree["__record__"] = "NoSuchResult"
    with pytest.raises(codec.UnknownRecordType, match="exports no such type"):
        decode(tree, encode(_ident())[1])
    tree["__record__"] = "aeroid.gone:NoSuchResult"
    with pytest.raises(codec.UnknownRecordType, match="does not exist in this aeroid version"):
        decode(tree, encode(_ident())[1])


def test_registered_types_may_take_a_stable_name(monkeypatch):
    from aeroid.pipeline.storage import codec

    monkeypatch.setattr(codec, "_REGISTRY", dict(codec._REGISTRY))
    monkeypatch.setattr(codec, "_NAMES", dict(codec._NAMES))

    @register_record(name="Thing")
    @dataclass(frozen=True)
    class Thing:
        x: np.ndarray

    tree, arrays = encode(Thing(np.arange(2.0)))
    assert tree["__record__"] == "Thing"
    assert decode(tree, arrays).x.tolist() == [0.0, 1.0]
    tree["__record__"] = f"{Thing.__module__}:{Thing.__qualname__}"  # its qualified name too
    assert type(decode(tree, arrays)) is Thing

    @dataclass(frozen=True)
    class Other:
        y: int

    with pytest.raises(StoreError, match="'Thing' is taken"):
        register_record(Other, name="Thing")


def test_reading_a_record_imports_its_type_only(tmp_path):
    # aeroid exports its types lazily: a record read in a fresh process (an unchanged
    # rerun reads the campaign report's) resolves its one type, not every export
    import subprocess
    import sys

    store = ResultStore(tmp_path / "s")
    key = sha256_hex(canonical_json({"x": 1}))
    rep = CampaignReport("t", "text", ("a",), ("flight",), (("a",),))
    assert store.commit("campaign_report", key, rep, task={"x": 1})
    code = (
        "import sys\n"
        "from aeroid.pipeline import ResultStore\n"
        f"rec = ResultStore({str(tmp_path / 's')!r}).load({key!r}, 'campaign_report')\n"
        "print(type(rec).__name__, rec.markdown, 'scipy.optimize' in sys.modules)\n"
    )
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": root}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=root
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["CampaignReport", "text", "False"]
