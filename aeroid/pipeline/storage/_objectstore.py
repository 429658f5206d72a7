"""A store in an object store, through fsspec: an entry is one object in one PUT."""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ...errors import StoreError
from ._backend import (
    _CHECKED,
    _INDEX,
    _MARKER,
    _MARKER_DOC,
    _PLANS,
    _SUFFIX,
    StoreLocation,
    _Archive,
    _check_marker,
    _os_error,
)
from ._zipentry import (
    Entry,
)


def remote_timeout() -> float:
    """Seconds a remote store may take to connect or answer one request
    (``AEROID_REMOTE_TIMEOUT``, default 30): a server that stops answering
    fails the request instead of hanging the run."""
    text = os.environ.get("AEROID_REMOTE_TIMEOUT", "30")
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise StoreError(f"AEROID_REMOTE_TIMEOUT={text!r}: expected a positive number of seconds")
    return value


def url_to_fs(url: str) -> tuple[Any, str]:
    """`fsspec.core.url_to_fs` with timeouts and few retries for the protocols that
    take them, unless fsspec's own configuration already sets them."""
    import fsspec
    import fsspec.config

    protocol = url.split("://", 1)[0].lower()
    t = remote_timeout()
    kwargs: dict[str, Any] = {}
    conf = fsspec.config.conf.get(protocol, {})
    if protocol in ("s3", "s3a") and "config_kwargs" not in conf:
        kwargs["config_kwargs"] = {
            "connect_timeout": t,
            "read_timeout": t,
            "retries": {"max_attempts": 2, "mode": "standard"},
        }
    elif protocol in ("gs", "gcs") and "timeout" not in conf:
        kwargs["timeout"] = t
    elif protocol in ("az", "abfs", "abfss") and "read_timeout" not in conf:
        # adlfs: seconds to connect and between reads (whole seconds)
        kwargs["connection_timeout"] = kwargs["read_timeout"] = max(1, math.ceil(t))
    elif protocol in ("http", "https") and "client_kwargs" not in conf:
        with contextlib.suppress(ImportError):  # fsspec's HTTP needs aiohttp and says so
            import aiohttp

            kwargs["client_kwargs"] = {"timeout": aiohttp.ClientTimeout(total=t)}
    fs, base = fsspec.core.url_to_fs(url, **kwargs)
    if "config_kwargs" in kwargs and getattr(fs, "retries", 0) > 1:
        # s3fs's own retries (five, nested in reads) multiply botocore's: leave one layer
        fs.retries = 1
    return fs, str(base)


_ENTRY_NAME = re.compile(
    r"[a-z_]+/[0-9a-f]{64}(?:\.zarr\.zip|\.claim)|\.index/[0-9a-z_.-]+\.json"
    r"|\.plans/[0-9]+-[0-9a-f]{64}\.plan"
)


def _only_entries(fs: Any, base: str) -> bool:
    """True when a prefix holds nothing but store entries and claims: a store whose
    marker went (the prefix emptied while a run still wrote), made whole again."""
    names = [str(n)[len(base) + 1 :] for n in fs.find(base)]
    return all(_ENTRY_NAME.fullmatch(n) for n in names)


class _ObjectBackend:
    """A store at a URL that fsspec understands (``s3://``, ``gs://``, ``az://``, ``memory://`` ...).

    Object stores have no rename, and need none: an entry is one object,
    written in one PUT, and an object store shows an object whole or not at
    all. So there are no temporaries. Two runs that commit the same key at once
    write the same result (results are deterministic); were they to differ,
    the digests say so on every read. A backend that is a file system reached
    through fsspec (``local://``, ``sftp://``) may leave a partial file when a
    run is killed mid-write: the next read reports it corrupt, as `verify`
    does, and ``verify --remove`` takes it out. Claims are written with the
    backend's put-if-absent where it has one (S3's ``If-None-Match``) and read
    back, so two runs rarely both win one; were they to, each computes the
    same result and the second commit is refused.
    """

    look_first = False  # the commit is a put-if-absent: it refuses a committed key itself
    # a claim costs requests around every PUT (create, read back, delete): a run on an
    # object store commits with put-if-absent instead, and two runs sharing the store
    # at once may compute a task twice but store it once
    claims_per_task = False

    def __init__(self, location: StoreLocation, *, create: bool, repair: bool = False) -> None:
        text = location.root
        try:
            fs, base = url_to_fs(text)
        except (ImportError, ValueError) as exc:  # unknown protocol, backend not installed
            raise StoreError(f"store {text!r}: {exc}") from None
        self.root: Path | str = text
        self.ident = text
        self._fs = fs
        self._base = str(base).rstrip("/")
        if text in _CHECKED:
            return
        marker = f"{self._base}/{_MARKER}"
        try:
            raw: bytes | None = fs.cat_file(marker)
        except FileNotFoundError:
            raw = None
        except Exception as exc:
            raise StoreError(f"store {text}: cannot read {_MARKER} ({exc})") from None
        if raw is not None:
            _check_marker(raw, text)
        elif create or (repair and fs.exists(self._base) and _only_entries(fs, self._base)):
            # (repair: verify --remove gives a prefix of entries its marker back)
            try:
                if fs.exists(self._base) and not _only_entries(fs, self._base):
                    raise StoreError(
                        f"store {text}: the location exists, is not empty and is not an aeroid "
                        "store"
                    )
                self._put({marker: _MARKER_DOC})
            except StoreError:
                raise
            except Exception as exc:
                raise StoreError(f"store {text}: cannot create it ({exc})") from None
        else:
            raise StoreError(f"store {text}: not an aeroid store (no {_MARKER})")
        _CHECKED.add(text)

    def _object(self, stage: str, name: str) -> str:
        return f"{self._base}/{stage}/{name}"

    def _url(self, path: str) -> str:
        return str(self.root) + path[len(self._base) :]

    def path_for(self, stage: str, key: str) -> str:
        return f"{self.root}/{stage}/{key}{_SUFFIX}"

    def exists(self, stage: str, key: str) -> bool:
        return bool(self._fs.exists(self._object(stage, key + _SUFFIX)))

    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]:
        # one listing per stage instead of a request per key
        found = set()
        for stage in {stage for stage, _ in tasks}:
            found |= {(e.stage, e.key) for e in self.listing(stage, "")}
        return tasks & found

    @contextlib.contextmanager
    def open_entry(self, stage: str, key: str) -> Iterator[_Archive]:
        raw = self._fs.cat_file(self._object(stage, key + _SUFFIX))
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            yield _Archive(archive, len(raw), self.path_for(stage, key))

    def listing(self, stage: str | None, prefix: str) -> list[Entry]:
        out = []
        pattern = f"{self._base}/{stage or '*'}/{prefix}*{_SUFFIX}"
        for found in sorted(self._fs.glob(pattern)):
            st, _, name = str(found)[len(self._base) + 1 :].rpartition("/")
            name = name.removesuffix(_SUFFIX)
            if "/" not in st and not st.startswith(".") and len(name) == 64:
                out.append(Entry(name, st, self._url(str(found))))
        return out

    def publish(self, stage: str, key: str, data: bytes) -> bool:
        """The commit: one PUT that refuses an existing object (S3's ``If-None-Match``);
        False when the key was committed already."""
        return self._put_new(self._object(stage, key + _SUFFIX), data)

    def _put_new(self, path: str, data: bytes) -> bool:
        """Write one object unless it exists (False then), in one request where the
        backend has put-if-absent."""
        try:
            self._fs.pipe_file(path, data, mode="create")
        except FileExistsError:
            return False
        except FileNotFoundError:  # a filesystem with real folders: make them once
            self._fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
            return self._put_new(path, data)
        except (NotImplementedError, TypeError, ValueError):
            # a backend without put-if-absent: a look, then a PUT
            if self._fs.exists(path):
                return False
            self._put({path: data})
        return True

    def remove(self, stage: str, key: str) -> bool:
        try:
            self._fs.rm_file(self._object(stage, key + _SUFFIX))
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("remove", self.path_for(stage, key), exc) from None
        return True

    def _put(self, files: dict[str, bytes]) -> None:
        """Write objects (concurrently, where the backend can)."""
        try:
            self._fs.pipe(files)
        except FileNotFoundError:
            # a filesystem with real folders (``local://``, ``sftp://``): make them once
            for folder in sorted({f.rsplit("/", 1)[0] for f in files}):
                self._fs.makedirs(folder, exist_ok=True)
            self._fs.pipe(files)

    def temporaries(self) -> list[Path | str]:
        return []  # an entry is written in one PUT: no commit leaves a part behind

    def gc(self, max_age: float) -> list[Path | str]:
        return []

    def create(self, stage: str, name: str, data: bytes) -> bool:
        path = self._object(stage, name)
        try:
            self._fs.pipe_file(path, data, mode="create")
        except FileExistsError:
            return False
        except FileNotFoundError:
            self._fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
            return self.create(stage, name, data)
        except OSError as exc:
            raise _os_error("write", f"{self.root}/{stage}/{name}", exc) from None
        # where put-if-absent is only a look and a PUT, the last writer won: read back
        return self._fs.cat_file(path) == data

    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None:
        try:
            raw = self._fs.cat_file(self._object(stage, name))
        except FileNotFoundError:
            return None
        return raw, 0.0  # object ages are not compared across clocks: the lease decides

    def overwrite(self, stage: str, name: str, data: bytes) -> None:
        self._fs.pipe_file(self._object(stage, name), data)

    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool:
        path = self._object(stage, name)
        try:
            if self._fs.cat_file(path) != old:
                return False
        except FileNotFoundError:
            return self.create(stage, name, new)
        self._fs.pipe_file(path, new)
        return self._fs.cat_file(path) == new

    def delete(self, stage: str, name: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._fs.rm_file(self._object(stage, name))

    # -- the index of entries checked whole (`verified`) ---------------------------
    def signatures(self, stages: set[str]) -> dict[tuple[str, str], tuple[int, str]]:
        """(stage, key) -> (size, ETag or modification time) of every entry of
        `stages`: one listing each (a request per thousand entries on S3)."""
        out: dict[tuple[str, str], tuple[int, str]] = {}
        for stage in stages:
            try:
                found = self._fs.find(f"{self._base}/{stage}", detail=True)
            except FileNotFoundError:
                continue
            for path, info in found.items():
                name = str(path).rpartition("/")[2]
                key = name.removesuffix(_SUFFIX)
                if len(key) == 64 and name.endswith(_SUFFIX):
                    tag = next((info[k] for k in _TAGS if info.get(k) is not None), "")
                    out[(stage, key)] = (int(info.get("size") or 0), str(tag))
        return out

    def index_files(self) -> list[tuple[str, bytes]]:
        try:
            names = sorted(self._fs.find(f"{self._base}/{_INDEX}"))
        except FileNotFoundError:
            return []
        out = []
        for path in names:
            with contextlib.suppress(FileNotFoundError):
                out.append((str(path).rpartition("/")[2], self._fs.cat_file(path)))
        return out

    def write_index(self, name: str, data: bytes) -> None:
        self._put({f"{self._base}/{_INDEX}/{name}": data})

    def remove_index(self, name: str) -> None:
        self.delete(_INDEX, name)

    # -- stored plans (`plan_cache`) ---------------------------------------------------
    def plan_names(self) -> list[str]:
        try:
            found = self._fs.ls(f"{self._base}/{_PLANS}", detail=False)
        except FileNotFoundError:
            return []
        return sorted(str(p).rpartition("/")[2] for p in found)

    def read_plan(self, name: str) -> bytes | None:
        try:
            return bytes(self._fs.cat_file(f"{self._base}/{_PLANS}/{name}"))
        except FileNotFoundError:
            return None

    def write_plan(self, name: str, data: bytes) -> None:
        self._put({f"{self._base}/{_PLANS}/{name}": data})

    def remove_plan(self, name: str) -> None:
        self.delete(_PLANS, name)


# what tells one object's bytes from another's write of the same name, per backend
_TAGS = ("ETag", "etag", "md5Hash", "mtime", "LastModified", "last_modified", "created")
