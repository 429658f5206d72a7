"""A store in a folder: safe file-system access that follows no symbolic link below
the store's root (``O_NOFOLLOW``), and entries published by an atomic rename."""

from __future__ import annotations

import contextlib
import errno
import functools
import itertools
import os
import re
import shutil
import socket
import stat
import time
import uuid
import zipfile
from collections.abc import Iterator
from pathlib import Path

from ...errors import StoreError
from ._backend import (
    _CHECKED,
    _INDEX,
    _MARKER,
    _MARKER_DOC,
    _PLANS,
    _SUFFIX,
    _TMP,
    StoreLocation,
    _Archive,
    _check_marker,
    _os_error,
    _pid_alive,
)
from ._rename import _place
from ._zipentry import (
    Entry,
)


@functools.lru_cache(maxsize=1)
def _hostname() -> str:
    return socket.gethostname()


# Below the root every folder is opened without following a link and every file
# is reached through such a folder's descriptor: no path in the store resolves
# outside it, whatever was planted in it.
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | _NOFOLLOW | _CLOEXEC
_LINK_ERRNOS = {errno.ELOOP, errno.EMLINK}  # what O_NOFOLLOW gives on a link (Linux, BSD)
# past this many keys of a stage, `stored` lists the stage's folder instead of looking
# for each key (a listing costs about what 50 looks do, for any number of names)
_LOOKS = 256


def _link_refused(path: str) -> StoreError:
    return StoreError(
        f"{path} is a symbolic link; a store follows no link below its root (remove the link)"
    )


_ENTRY_FILE = re.compile(r"[0-9a-f]{64}(?:\.zarr\.zip|\.claim(?:\.[0-9a-f]{8})?)")
_STAGE_DIR = re.compile(r"[a-z_]+")


def _only_store_content(folder: Path) -> bool:
    """True when `folder` holds what a store holds and at least one entry, but no
    marker: a store emptied while a run still wrote, which that run's entries refill.
    Anything else (a link, a file of the user's) keeps the folder refused."""
    entries = 0
    for top in folder.iterdir():
        if top.name.startswith(f".{_MARKER}.") and top.is_file():
            continue  # a marker being written
        if top.is_symlink() or not top.is_dir():
            return False
        inner = list(top.iterdir())
        if any(p.is_symlink() or not p.is_file() for p in inner if top.name != "reports"):
            return False
        if top.name in (_TMP, "reports", _INDEX, _PLANS):
            continue
        if not _STAGE_DIR.fullmatch(top.name):
            return False
        if not all(_ENTRY_FILE.fullmatch(p.name) for p in inner):
            return False
        entries += sum(p.name.endswith(_SUFFIX) for p in inner)
    return entries > 0


class _LocalBackend:
    """A store in a folder of a local or shared file system."""

    look_first = False  # the final rename refuses an existing entry: no look first
    claims_per_task = True  # a claim is a file made and removed in a folder: cheap

    def __init__(
        self, location: StoreLocation, given: str, *, create: bool, repair: bool = False
    ) -> None:
        self.root: Path | str = Path(os.path.expanduser(given.removeprefix("file://")))
        self._folder = location.root
        self.ident = location.root
        marker = os.path.join(self._folder, _MARKER)
        if not (self.ident in _CHECKED and os.path.isfile(marker)):
            self._open_marker(marker, create=create, repair=repair)
            _CHECKED.add(self.ident)
        # every path below is made from the real root: a link above it was the user's choice
        self._real = os.path.realpath(self._folder)

    def _open_marker(self, marker: str, *, create: bool, repair: bool = False) -> None:
        folder, shown = Path(self._folder), self.root
        if repair and not create and not os.path.isfile(marker):
            # verify --remove: a store that lost its marker gets it back, nothing new is made
            create = folder.is_dir() and _only_store_content(folder)
        if os.path.isfile(marker):
            try:
                raw = Path(marker).read_bytes()
            except OSError as exc:
                raise StoreError(f"store {shown}: unreadable marker {marker} ({exc})") from None
            _check_marker(raw, shown)
        elif create:
            if folder.exists() and not folder.is_dir():
                raise StoreError(f"store {shown}: is a file, not a folder")
            # another run may be creating the same store: its marker's temporary file,
            # or by now its marker and first folders, are what the folder holds
            busy = f".{_MARKER}."
            if folder.exists() and any(not p.name.startswith(busy) for p in folder.iterdir()):
                if os.path.isfile(marker):
                    self._open_marker(marker, create=False)
                    return
                if not _only_store_content(folder):
                    raise StoreError(
                        f"store {shown}: the directory exists, is not empty and is not an "
                        "aeroid store"
                    )
            try:
                folder.mkdir(parents=True, exist_ok=True)
                tmp = folder / f".{_MARKER}.{uuid.uuid4().hex}"
                tmp.write_bytes(_MARKER_DOC)
                os.replace(tmp, marker)
            except OSError as exc:
                raise StoreError(
                    f"store {shown}: cannot create it ({exc.strerror or exc})"
                ) from None
        elif folder.is_dir() and _only_store_content(folder):
            raise StoreError(
                f"store {shown}: holds store entries but lost its {_MARKER} (emptied while a "
                "run wrote?); `aeroid verify --remove` or the next run gives it back"
            )
        else:
            raise StoreError(f"store {shown}: not an aeroid store (no {_MARKER})")

    # -- folders, never through a link ----------------------------------------
    def _shown(self, *parts: str) -> Path:
        return Path(self.root, *parts)

    def _dir(self, name: str, *, make: bool = False) -> int:
        """A descriptor of the folder `name` under the root, opened without following
        a link (FileNotFoundError when it is missing and `make` is false)."""
        path = os.path.join(self._real, name)
        try:
            return os.open(path, _DIR_FLAGS)
        except FileNotFoundError:
            if not make:
                raise
        except OSError as exc:
            raise self._dir_error(name, exc) from None
        try:
            os.makedirs(path, exist_ok=True)
            return os.open(path, _DIR_FLAGS)
        except OSError as exc:
            raise self._dir_error(name, exc) from None

    def _dir_error(self, name: str, exc: OSError) -> StoreError:
        if exc.errno in _LINK_ERRNOS or os.path.islink(os.path.join(self._real, name)):
            return _link_refused(str(self._shown(name)))
        if exc.errno == errno.ENOTDIR:
            return StoreError(f"{self._shown(name)} is not a folder")
        return _os_error("open", self._shown(name), exc)

    @contextlib.contextmanager
    def _folder_fd(self, name: str, *, make: bool = False) -> Iterator[int]:
        fd = self._dir(name, make=make)
        try:
            yield fd
        finally:
            os.close(fd)

    # -- entries ----------------------------------------------------------------
    def path_for(self, stage: str, key: str) -> Path:
        return self._shown(stage, key + _SUFFIX)

    def exists(self, stage: str, key: str) -> bool:
        return self._stage_present(stage) and os.path.lexists(
            os.path.join(self._real, stage, key + _SUFFIX)
        )

    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]:
        by_stage: dict[str, list[str]] = {}
        for stage, key in tasks:
            by_stage.setdefault(stage, []).append(key)
        out: set[tuple[str, str]] = set()
        for stage, keys in by_stage.items():
            # a stage with no folder yet (a new store, a new stage) has none: one look for all
            if not self._stage_present(stage):
                continue
            if len(keys) > _LOOKS:
                # one listing of the folder instead of a look per key
                with self._folder_fd(stage) as fd:
                    listed = {n[: -len(_SUFFIX)] for n in os.listdir(fd) if n.endswith(_SUFFIX)}
                out.update(zip(itertools.repeat(stage), listed.intersection(keys)))
                continue
            folder = os.path.join(self._real, stage)
            out |= {(stage, k) for k in keys if os.path.lexists(os.path.join(folder, k + _SUFFIX))}
        return out

    def _stage_present(self, stage: str) -> bool:
        """True when the stage has a folder; a link in its place is refused."""
        try:
            st = os.lstat(os.path.join(self._real, stage))
        except FileNotFoundError:
            return False
        if stat.S_ISLNK(st.st_mode):
            raise _link_refused(str(self._shown(stage)))
        return stat.S_ISDIR(st.st_mode)

    @contextlib.contextmanager
    def open_entry(self, stage: str, key: str) -> Iterator[_Archive]:
        name = key + _SUFFIX
        with self._folder_fd(stage) as folder:
            try:
                fd = os.open(name, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
            except OSError as exc:
                if exc.errno in _LINK_ERRNOS:
                    raise _link_refused(str(self._shown(stage, name))) from None
                raise
        with os.fdopen(fd, "rb") as file:
            info = os.fstat(file.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise StoreError(f"{self._shown(stage, name)} is not a file")
            with zipfile.ZipFile(file) as archive:
                yield _Archive(archive, info.st_size, str(self._shown(stage, name)))

    def listing(self, stage: str | None, prefix: str) -> list[Entry]:
        if stage is None:
            stages = self._stages()
        else:
            stages = [stage]
        out: list[Entry] = []
        for s in stages:
            try:
                fd = self._dir(s)
            except FileNotFoundError:
                continue
            except StoreError as exc:
                if stage is not None and str(exc).endswith("is not a folder"):
                    continue
                raise
            try:
                with os.scandir(fd) as it:
                    names = sorted(e.name for e in it if not e.is_dir(follow_symlinks=False))
            finally:
                os.close(fd)
            for name in names:
                key = name.removesuffix(_SUFFIX)
                if name.endswith(_SUFFIX) and len(key) == 64 and key.startswith(prefix):
                    out.append(Entry(key, s, self._shown(s, name)))
        return out

    def _stages(self) -> list[str]:
        """The stage folders; a link to a folder among them is refused, not followed."""
        try:
            it = os.scandir(self._real)
        except FileNotFoundError:
            return []
        stages = []
        with it:
            for e in it:
                if e.name.startswith("."):
                    continue
                if e.is_symlink():
                    if e.is_dir():
                        raise _link_refused(str(self._shown(e.name)))
                elif e.is_dir(follow_symlinks=False):
                    stages.append(e.name)
        return sorted(stages)

    def publish(self, stage: str, key: str, data: bytes) -> bool:
        """Write the entry's zip under a temporary name, then move it into place."""
        # host and pid in the name let `gc` keep the temporaries of live processes
        tmp = f"{key}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(_TMP, make=True) as tmp_dir:
                fd = self._create(tmp_dir, tmp)
                try:
                    self._fill(fd, data)
                    with self._folder_fd(stage, make=True) as folder:
                        placed = _place(tmp_dir, tmp, folder, key + _SUFFIX)
                except BaseException:
                    with contextlib.suppress(OSError):
                        os.unlink(tmp, dir_fd=tmp_dir)
                    raise
                if not placed:
                    os.unlink(tmp, dir_fd=tmp_dir)  # another run committed the same key first
                return placed
        except OSError as exc:
            raise _os_error("write", self._shown(stage, key + _SUFFIX), exc) from None

    def remove(self, stage: str, key: str) -> bool:
        name = key + _SUFFIX
        try:
            with self._folder_fd(stage) as folder:
                os.unlink(name, dir_fd=folder)  # a link planted as an entry: the link goes
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("remove", self._shown(stage, name), exc) from None
        return True

    # -- temporaries ------------------------------------------------------------
    def _partial(self) -> tuple[int, list[str]] | None:
        try:
            fd = self._dir(_TMP)
        except FileNotFoundError:
            return None
        try:
            return fd, sorted(os.listdir(fd))
        except OSError as exc:
            os.close(fd)
            raise _os_error("list", self._shown(_TMP), exc) from None

    def temporaries(self) -> list[Path | str]:
        found = self._partial()
        if found is None:
            return []
        os.close(found[0])
        return [self._shown(_TMP, name) for name in found[1]]

    def gc(self, max_age: float) -> list[Path | str]:
        found = self._partial()
        if found is None:
            return []
        fd, names = found
        removed: list[Path | str] = []
        host, now = _hostname(), time.time()
        try:
            for name in names:
                parts = name.split(".")
                alive = False
                if len(parts) >= 4:
                    t_host, t_pid = ".".join(parts[1:-2]), parts[-2]
                    if t_host == host and t_pid.isdigit():
                        alive = _pid_alive(int(t_pid)) and int(t_pid) != os.getpid()
                    else:
                        try:
                            age = now - os.stat(name, dir_fd=fd, follow_symlinks=False).st_mtime
                            alive = age < max_age
                        except OSError:
                            alive = False
                if alive:
                    continue
                try:
                    info = os.stat(name, dir_fd=fd, follow_symlinks=False)
                    if stat.S_ISDIR(info.st_mode):
                        shutil.rmtree(name, dir_fd=fd)  # descriptor-based: follows no link
                    else:
                        os.unlink(name, dir_fd=fd)
                except FileNotFoundError:
                    continue
                except OSError as exc:
                    raise _os_error("remove", self._shown(_TMP, name), exc) from None
                removed.append(self._shown(_TMP, name))
        finally:
            os.close(fd)
        return removed

    # -- claims -------------------------------------------------------------------
    def create(self, stage: str, name: str, data: bytes) -> bool:
        """Put a small file (a claim) in place unless one exists: written whole under
        ``.tmp`` and moved in, so no reader ever sees it empty or half-written."""
        tmp = f"{name}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(_TMP, make=True) as tmp_dir:
                self._write_new(tmp_dir, tmp, data)
                try:
                    with self._folder_fd(stage, make=True) as folder:
                        placed = _place(tmp_dir, tmp, folder, name)
                finally:
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(tmp, dir_fd=tmp_dir)
        except OSError as exc:
            raise _os_error("write", self._shown(stage, name), exc) from None
        return placed

    @staticmethod
    def _create(folder: int, name: str) -> int:
        """A new file `name` in `folder`, opened to write (never an existing one, nor
        through a link)."""
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC
        return os.open(name, flags, 0o644, dir_fd=folder)

    @staticmethod
    def _fill(fd: int, data: bytes) -> None:
        """Write `data` whole to `fd` and close it."""
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
        finally:
            os.close(fd)

    @classmethod
    def _write_new(cls, folder: int, name: str, data: bytes) -> None:
        cls._fill(cls._create(folder, name), data)

    def _open_to_read(self, folder_name: str, name: str) -> int | None:
        """A file of `folder_name` opened for reading, never through a link; None where
        there is none."""
        try:
            with self._folder_fd(folder_name) as folder:
                return os.open(name, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno in _LINK_ERRNOS:
                raise _link_refused(str(self._shown(folder_name, name))) from None
            raise _os_error("read", self._shown(folder_name, name), exc) from None

    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None:
        fd = self._open_to_read(stage, name)
        if fd is None:
            return None
        try:
            age = time.time() - os.fstat(fd).st_mtime
            return os.read(fd, 4096), age
        finally:
            os.close(fd)

    def overwrite(self, stage: str, name: str, data: bytes) -> None:
        # a new file renamed over the old one: a reader sees the old claim or the new
        tmp = f"{name}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(_TMP, make=True) as tmp_dir, self._folder_fd(stage) as folder:
                self._write_new(tmp_dir, tmp, data)
                try:
                    os.rename(tmp, name, src_dir_fd=tmp_dir, dst_dir_fd=folder)
                except BaseException:
                    with contextlib.suppress(OSError):
                        os.unlink(tmp, dir_fd=tmp_dir)
                    raise
        except OSError as exc:
            raise _os_error("write", self._shown(stage, name), exc) from None

    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool:
        aside = f"{name}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(stage) as folder:
                try:
                    # of runs taking over one stale claim, one renames it away
                    os.rename(name, aside, src_dir_fd=folder, dst_dir_fd=folder)
                except FileNotFoundError:
                    return False
                fd = os.open(aside, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=folder)
                try:
                    moved = os.read(fd, 4096)
                finally:
                    os.close(fd)
                if moved != old:  # a fresh claim made since it was read: put it back
                    with contextlib.suppress(OSError):
                        _place(folder, aside, folder, name)
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(aside, dir_fd=folder)
                    return False
                os.unlink(aside, dir_fd=folder)
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise _os_error("take over", self._shown(stage, name), exc) from None
        return self.create(stage, name, new)

    def delete(self, stage: str, name: str) -> None:
        try:
            with self._folder_fd(stage) as folder:
                os.unlink(name, dir_fd=folder)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise _os_error("remove", self._shown(stage, name), exc) from None

    # -- the index of entries checked whole (`verified`) ---------------------------
    def signatures(self, stages: set[str]) -> dict[tuple[str, str], tuple[int, str]]:
        """(stage, key) -> (size, mtime in ns) of every entry of `stages`, one folder
        listing each; a link planted as an entry gets no signature (never trusted)."""
        out: dict[tuple[str, str], tuple[int, str]] = {}
        for stage in stages:
            if not self._stage_present(stage):
                continue
            with self._folder_fd(stage) as fd, os.scandir(fd) as it:
                for e in it:
                    key = e.name.removesuffix(_SUFFIX)
                    if len(key) != 64 or not e.name.endswith(_SUFFIX):
                        continue
                    info = e.stat(follow_symlinks=False)
                    size = info.st_size if stat.S_ISREG(info.st_mode) else -1
                    out[(stage, key)] = (size, str(info.st_mtime_ns))
        return out

    def index_files(self) -> list[tuple[str, bytes]]:
        try:
            fd = self._dir(_INDEX)
        except FileNotFoundError:
            return []
        out = []
        try:
            for name in sorted(os.listdir(fd)):
                with contextlib.suppress(OSError):
                    f = os.open(name, os.O_RDONLY | _NOFOLLOW | _CLOEXEC, dir_fd=fd)
                    with os.fdopen(f, "rb") as file:
                        out.append((name, file.read()))
        finally:
            os.close(fd)
        return out

    def write_index(self, name: str, data: bytes) -> None:
        self._write_whole(_INDEX, name, data)

    def _write_whole(self, folder_name: str, name: str, data: bytes) -> None:
        """Write a file whole under ``.tmp`` and move it into `folder_name`."""
        tmp = f"{name}.{_hostname()}.{os.getpid()}.{os.urandom(4).hex()}"
        try:
            with self._folder_fd(_TMP, make=True) as tmp_dir:
                self._write_new(tmp_dir, tmp, data)
                with self._folder_fd(folder_name, make=True) as folder:
                    os.rename(tmp, name, src_dir_fd=tmp_dir, dst_dir_fd=folder)
        except OSError as exc:
            raise _os_error("write", self._shown(folder_name, name), exc) from None

    def remove_index(self, name: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.delete(_INDEX, name)

    # -- stored plans (`plan_cache`) ---------------------------------------------------
    def plan_names(self) -> list[str]:
        try:
            fd = self._dir(_PLANS)
        except FileNotFoundError:
            return []
        try:
            return sorted(os.listdir(fd))
        finally:
            os.close(fd)

    def read_plan(self, name: str) -> bytes | None:
        fd = self._open_to_read(_PLANS, name)
        if fd is None:
            return None
        with os.fdopen(fd, "rb") as file:
            return file.read()

    def write_plan(self, name: str, data: bytes) -> None:
        self._write_whole(_PLANS, name, data)

    def remove_plan(self, name: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.delete(_PLANS, name)
