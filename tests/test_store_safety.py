"""The store stays inside itself: planted links, crafted zips and failing disks are refused
with a `StoreError` naming what is at fault, and nothing outside the store is touched."""

from __future__ import annotations

import errno
import os
import socket
import struct
import zipfile
from pathlib import Path

import pytest
from test_pipeline_store import _ident, flip_a_bit, rezip

from aeroid.errors import StoreError
from aeroid.pipeline import ResultStore
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.storage import store as store_mod
from aeroid.pipeline.storage.store import StoreLocation, is_url, parse


def _store(tmp_path: Path, name: str = "s") -> tuple[ResultStore, str]:
    store = ResultStore(tmp_path / name)
    task = {"z": 3}
    key = sha256_hex(canonical_json(task))
    assert store.commit("identify", key, _ident(), task=task)
    return store, key


def _outside(tmp_path: Path) -> tuple[Path, dict[str, bytes]]:
    """A folder outside the store with files that must survive."""
    folder = tmp_path / "precious"
    folder.mkdir()
    files = {f"{'a' * 64}.{socket.gethostname()}.999999999.dead": b"a", "thesis.tex": b"b"}
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return folder, files


def _untouched(folder: Path, files: dict[str, bytes]) -> None:
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == files


# -- links planted in the store ---------------------------------------------------


def test_gc_refuses_a_tmp_folder_that_is_a_link(tmp_path):
    store, key = _store(tmp_path)
    folder, files = _outside(tmp_path)
    tmp = store.root / ".tmp"
    tmp.rmdir()
    tmp.symlink_to(folder)
    with pytest.raises(StoreError, match=r"\.tmp is a symbolic link"):
        store.gc(max_age=0)
    with pytest.raises(StoreError, match=r"\.tmp is a symbolic link"):
        store.temporaries()
    # a commit writes nothing through it either
    other = {"z": 4}
    with pytest.raises(StoreError, match=r"\.tmp is a symbolic link"):
        store.commit("identify", sha256_hex(canonical_json(other)), _ident(), task=other)
    _untouched(folder, files)
    assert store.load(key, "identify").parameters == _ident().parameters


def test_verify_remove_refuses_a_stage_folder_that_is_a_link(tmp_path):
    store, key = _store(tmp_path)
    folder, files = _outside(tmp_path)
    planted = "b" * 64 + ".zarr.zip"  # looks like a corrupt entry: verify --remove would delete it
    (folder / planted).write_bytes(b"not a zip")
    files[planted] = b"not a zip"
    (store.root / "validate").symlink_to(folder)
    for call in (
        store.verify_all,
        lambda: list(store.entries()),
        lambda: store.remove("validate", "b" * 64),
        lambda: store.exists("validate", "b" * 64),
        lambda: store.load("b" * 64, "validate"),
        lambda: store.find("bbbbbbbb"),
        lambda: store.stored([("validate", "b" * 64)]),
    ):
        with pytest.raises(StoreError, match=r"validate is a symbolic link"):
            call()
    _untouched(folder, files)
    assert store.verify(key, "identify") is None  # the rest of the store still reads


def test_an_entry_that_is_a_link_is_refused_and_removing_it_removes_the_link(tmp_path):
    store, key = _store(tmp_path)
    elsewhere, _ = _store(tmp_path, "elsewhere")
    target = elsewhere.path_for("identify", key)
    original = target.read_bytes()
    entry = store.path_for("identify", key)
    entry.unlink()
    entry.symlink_to(target)
    with pytest.raises(StoreError, match=r"identify/.*\.zarr\.zip is a symbolic link"):
        store.load(key, "identify")
    assert "is a symbolic link" in store.verify_all()[key]
    assert store.check_entry("identify", key) is False
    assert store.remove("identify", key) is True
    assert not os.path.lexists(entry) and target.read_bytes() == original


def test_stage_and_key_names_cannot_leave_the_store(tmp_path):
    store, key = _store(tmp_path)
    for stage in ("..", "../identify", "a/b", ".tmp", ""):
        with pytest.raises(StoreError, match="not a valid name"):
            store.exists(stage, key)
    with pytest.raises(StoreError, match="not a valid name"):
        store.load("../" + key, "identify")
    with pytest.raises(StoreError, match="not a valid name"):
        store.commit("../outside", key, _ident(), task={"z": 3})
    assert not (tmp_path / "outside").exists()


def test_a_store_reached_through_a_link_to_its_folder_works(tmp_path):
    # the root itself may be a link (the user's choice); only what is below it is checked
    store, key = _store(tmp_path)
    (tmp_path / "alias").symlink_to(store.root)
    alias = ResultStore(tmp_path / "alias", create=False)
    assert alias.verify_all() == {} and alias.load(key, "identify").success


# -- crafted zips -------------------------------------------------------------------


def _spy_reads(monkeypatch) -> list[str]:
    """Names of the members zipfile opens from now on."""
    opened: list[str] = []
    real = zipfile.ZipFile.open

    def spy(self, name, *args, **kwargs):
        opened.append(name if isinstance(name, str) else name.filename)
        return real(self, name, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "open", spy)
    return opened


def test_a_compressed_member_is_refused_before_a_byte_is_read(tmp_path, monkeypatch):
    store, key = _store(tmp_path)
    entry = store.path_for("identify", key)
    with zipfile.ZipFile(entry) as z:
        members = {i.filename: z.read(i) for i in z.infolist()}
    # a few kilobytes on disk that inflate to 64 MiB (a zip bomb, scaled down)
    with zipfile.ZipFile(entry, "w") as z:
        for name, data in members.items():
            if name == "covariance/0.0":
                z.writestr(name, bytes(64 * 2**20), compress_type=zipfile.ZIP_DEFLATED)
            else:
                z.writestr(name, data)
    assert entry.stat().st_size < 2**20
    opened = _spy_reads(monkeypatch)
    with pytest.raises(StoreError, match=r"is corrupt: member 'covariance/0.0' is compressed"):
        store.load(key, "identify")
    assert "is compressed" in store.verify(key, "identify")
    assert store.check_entry("identify", key) is False
    assert opened == []  # refused from the directory alone


def test_a_chunk_of_another_size_than_its_shape_implies_is_never_read(tmp_path, monkeypatch):
    store, key = _store(tmp_path)
    entry = store.path_for("identify", key)
    # a stored chunk far larger than the 2 x 2 float64 array its metadata declares
    entry.write_bytes(rezip(entry.read_bytes(), "covariance/0.0", lambda b: bytes(8 * 10**6))[0])
    opened = _spy_reads(monkeypatch)
    with pytest.raises(StoreError, match=r"chunk covariance/0.0 holds 1000000 values, expected 4"):
        store.load(key, "identify")
    assert "covariance/0.0" not in opened


def test_a_member_declaring_more_bytes_than_the_file_holds_is_refused(tmp_path):
    store, key = _store(tmp_path)
    entry = store.path_for("identify", key)
    raw = bytearray(entry.read_bytes())
    name = b"covariance/0.0"
    # the central directory header of the member: sizes at offsets 20 and 24
    at = next(
        i
        for i in range(len(raw))
        if raw[i : i + 4] == b"PK\x01\x02" and raw[i + 46 : i + 46 + len(name)] == name
    )
    raw[at + 20 : at + 28] = struct.pack("<II", 2**31 - 1, 2**31 - 1)
    entry.write_bytes(bytes(raw))
    with pytest.raises(
        StoreError, match=r"is corrupt: member 'covariance/0.0' declares 2147483647"
    ):
        store.load(key, "identify")
    assert store.check_entry("identify", key) is False


def test_memory_errors_while_reading_make_the_entry_corrupt(tmp_path, monkeypatch):
    store, key = _store(tmp_path)

    def exhausted(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(store_mod, "_read_array", exhausted)
    with pytest.raises(StoreError, match=r"is corrupt: MemoryError"):
        store.load(key, "identify")
    assert "is corrupt" in store.verify(key, "identify")
    monkeypatch.undo()
    monkeypatch.setattr(zipfile.ZipFile, "read", exhausted)
    assert "is corrupt: unreadable metadata" in store.verify(key, "identify")
    monkeypatch.setattr(zipfile.ZipFile, "_RealGetContents", exhausted)
    assert "is corrupt: unreadable (MemoryError" in store.verify(key, "identify")
    assert store.check_entry("identify", key) is False


# -- a store that cannot be written ---------------------------------------------------


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES])
def test_removing_from_a_store_that_cannot_be_written_names_the_entry(tmp_path, monkeypatch, code):
    store, key = _store(tmp_path)
    tmp = store.root / ".tmp"
    dead = tmp / f"{'c' * 64}.{socket.gethostname()}.999999999.dead"
    dead.write_bytes(b"x")

    def refused(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "unlink", refused)  # a read-only mount (root ignores chmod)
    with pytest.raises(StoreError, match=rf"cannot remove .*identify/{key}\.zarr\.zip"):
        store.remove("identify", key)
    with pytest.raises(StoreError, match=r"cannot remove .*\.tmp/c+\..*\.dead"):
        store.gc()
    monkeypatch.undo()
    assert store.exists("identify", key) and dead.exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes through file modes")
def test_verify_remove_on_a_read_only_folder_raises_store_error(tmp_path):
    store, key = _store(tmp_path)
    stage = store.root / "identify"
    stage.chmod(0o555)
    try:
        with pytest.raises(StoreError, match="cannot remove"):
            store.remove("identify", key)
    finally:
        stage.chmod(0o755)


# -- the cheap check for a cache hit -----------------------------------------------------


def test_check_entry_checks_every_member_crc_without_decoding(tmp_path):
    store, key = _store(tmp_path)
    assert store.check_entry("identify", key) is True
    assert store.check_entry("identify", "0" * 64) is False
    flip_a_bit(store.path_for("identify", key), "covariance/")
    assert store.check_entry("identify", key) is False
    store.path_for("identify", key).write_bytes(b"PK\x03\x04 cut short")
    assert store.check_entry("identify", key) is False


# -- where a store lives ---------------------------------------------------------------


def test_a_location_is_parsed_once_into_kind_root_and_protocol(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert parse("~/store") == StoreLocation("local", str(tmp_path / "store"), "file")
    assert parse(f"file://{tmp_path}/s") == StoreLocation("local", str(tmp_path / "s"), "file")
    monkeypatch.chdir(tmp_path)
    assert parse(Path("rel")).root == str(tmp_path / "rel")
    s3 = parse("s3://bucket/campaign/")
    assert s3 == StoreLocation("fsspec", "s3://bucket/campaign", "s3") and s3.is_url
    assert parse(s3) is s3 and str(s3) == "s3://bucket/campaign"
    assert is_url("memory://x") and not is_url("file:///x") and not is_url(tmp_path)
    with pytest.raises(StoreError, match="empty"):
        parse(" ")
    store = ResultStore(parse(tmp_path / "via-location"))
    assert (
        store.location == parse(tmp_path / "via-location")
        and store.root == tmp_path / "via-location"
    )
