"""Where a store lives (`parse`), its layout version, and what `ResultStore` needs of
the place its entries live in (`_Backend`)."""

from __future__ import annotations

import contextlib
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

from ...errors import StoreError
from ._zipentry import (
    FORMAT,
    Entry,
)

_MARKER = "aeroid-store.json"
_TMP = ".tmp"
_SUFFIX = ".zarr.zip"
_CLAIM = ".claim"
_INDEX = ".index"  # files listing entries checked whole (see `verified`)
_PLANS = ".plans"  # the keys of planned campaigns (see `plan_cache`)


@dataclass(frozen=True)
class StoreLocation:
    """Where a store lives, parsed once from the text a user gave.

    Attributes
    ----------
    kind : {"local", "fsspec"}
        A folder on a (possibly shared) file system, or a URL for fsspec.
    root : str
        The absolute folder (``~`` expanded, ``file://`` removed), or the URL
        without a trailing slash.
    protocol : str
        ``"file"`` for a folder, else the URL's protocol (``"s3"``, ``"memory"``).
    """

    kind: Literal["local", "fsspec"]
    root: str
    protocol: str

    @property
    def is_url(self) -> bool:
        """True for a store reached through fsspec."""
        return self.kind == "fsspec"

    def __str__(self) -> str:
        return self.root


def parse(location: str | os.PathLike[str] | StoreLocation) -> StoreLocation:
    """Parse a store location: a folder (``file://`` allowed) or a URL fsspec understands.

    Parameters
    ----------
    location : str, path or StoreLocation
        ``"results/store"``, ``"~/store"``, ``"file:///data/store"``,
        ``"s3://bucket/campaign"``...

    Returns
    -------
    StoreLocation
        Touches no disk and no network.
    """
    if isinstance(location, StoreLocation):
        return location
    text = os.fspath(location)
    if not text.strip():
        raise StoreError("store location is empty")
    if "://" in text and not text.startswith("file://"):
        protocol = text.split("://", 1)[0]
        return StoreLocation("fsspec", text.rstrip("/"), protocol)
    path = text.removeprefix("file://")
    expanded = os.path.expanduser(path)
    if path.startswith("~") and expanded == path:
        user = path[1:].split("/", 1)[0] or "the current user"
        raise StoreError(f"store location {text!r}: no home folder for {user!r}")
    return StoreLocation("local", os.path.abspath(expanded), "file")


def is_url(location: str | os.PathLike[str] | StoreLocation) -> bool:
    """True when a store location is a URL for fsspec (``s3://...``), not a folder."""
    return parse(location).kind == "fsspec"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


_CHECKED: set[str] = set()  # store roots whose marker this process has read

_MARKER_DOC = json.dumps({"format": FORMAT, "kind": "aeroid result store"}).encode("utf-8")


def _check_marker(raw: bytes, store: Path | str) -> None:
    """Raise unless `raw` is a store marker of the layout version this aeroid reads."""
    try:
        info = json.loads(raw)
    except ValueError as exc:
        raise StoreError(f"store {store}: unreadable marker {_MARKER} ({exc})") from None
    got = info.get("format") if isinstance(info, dict) else info
    if got == 1:
        raise StoreError(
            f"store {store}: layout version 1 (a folder per entry, as aeroid wrote before "
            f"zipped entries); this aeroid reads version {FORMAT}: run the campaign into a "
            "new store (the keys are the same)"
        )
    if got != FORMAT:
        raise StoreError(
            f"store {store}: layout version {got!r}, this aeroid reads version {FORMAT}"
        )


class _Backend(Protocol):
    """What `ResultStore` needs of the place its entries live in."""

    root: Path | str  # as shown to users
    ident: str  # one name per store in this process (caches, markers read)
    look_first: bool  # a commit must look before writing (a PUT overwrites)
    claims_per_task: bool  # a run claims each task before computing it (cheap here)

    def path_for(self, stage: str, key: str) -> Path | str: ...
    def exists(self, stage: str, key: str) -> bool: ...
    def stored(self, tasks: set[tuple[str, str]]) -> set[tuple[str, str]]: ...
    def open_entry(self, stage: str, key: str) -> contextlib.AbstractContextManager[_Archive]: ...
    def listing(self, stage: str | None, prefix: str) -> list[Entry]: ...
    def publish(self, stage: str, key: str, data: bytes) -> bool: ...
    def remove(self, stage: str, key: str) -> bool: ...
    def temporaries(self) -> list[Path | str]: ...
    def gc(self, max_age: float) -> list[Path | str]: ...
    def create(self, stage: str, name: str, data: bytes) -> bool: ...
    def read_small(self, stage: str, name: str) -> tuple[bytes, float] | None: ...
    def overwrite(self, stage: str, name: str, data: bytes) -> None: ...
    def take_over(self, stage: str, name: str, old: bytes, new: bytes) -> bool: ...
    def delete(self, stage: str, name: str) -> None: ...
    def signatures(self, stages: set[str]) -> dict[tuple[str, str], tuple[int, str]]: ...
    def index_files(self) -> list[tuple[str, bytes]]: ...
    def write_index(self, name: str, data: bytes) -> None: ...
    def remove_index(self, name: str) -> None: ...
    def plan_names(self) -> list[str]: ...
    def read_plan(self, name: str) -> bytes | None: ...
    def write_plan(self, name: str, data: bytes) -> None: ...
    def remove_plan(self, name: str) -> None: ...


@dataclass(frozen=True)
class _Archive:
    """An entry's zip opened for reading, and the size of its file."""

    zip: zipfile.ZipFile
    size: int
    where: str


def _os_error(action: str, path: object, exc: OSError) -> StoreError:
    return StoreError(f"cannot {action} {path} ({exc.strerror or exc})")
