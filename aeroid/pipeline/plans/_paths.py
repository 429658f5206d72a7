"""Flight-file globs that survive symbolic-link loops, and loopback addresses."""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Collection
from pathlib import Path

__all__ = ["glob_files", "network_refusal"]


def _segment_regex(segment: str) -> str:
    """One path segment of a glob pattern as a regex that never crosses a '/'."""
    out = [r"(?!\.)"] if segment[:1] in "*?[" else []  # like glob: '*' skips hidden names
    i = 0
    while i < len(segment):
        c = segment[i]
        close = segment.find("]", i + 2) if c == "[" else -1
        if c == "*":
            out.append("[^/]*")
        elif c == "?":
            out.append("[^/]")
        elif close > 0:
            body = segment[i + 1 : close]
            body = "^" + body[1:] if body.startswith("!") else body
            out.append("[" + body.replace("\\", "\\\\") + "]")
            i = close
        else:
            out.append(re.escape(c))
        i += 1
    return "".join(out)


def glob_files(pattern: str) -> list[Path]:
    """Files a glob pattern matches, sorted; ``**`` walks each real folder once.

    `glob.glob` with ``**`` follows a symbolic link loop until the path is too
    long, which takes hours; this walk follows links but skips a folder it has
    already seen.
    """
    if "**" not in pattern:
        return sorted(Path(p) for p in glob.glob(pattern))
    parts = Path(pattern).parts
    first = next(i for i, part in enumerate(parts) if glob.has_magic(part))
    root = Path(*parts[:first]) if first else Path(".")
    rest = parts[first:]
    regex = ""
    for part in rest:
        regex += "(?:[^/.][^/]*/)*" if part == "**" else _segment_regex(part) + "/"
    if rest[-1] == "**":
        regex += r"[^/.][^/]*/"
    matcher = re.compile(regex[:-1] + r"\Z", re.DOTALL)
    found: list[Path] = []
    seen: set[str] = set()
    for folder, dirs, files in os.walk(root, followlinks=True):
        real = os.path.realpath(folder)
        if real in seen:
            dirs[:] = []
            continue
        seen.add(real)
        rel = Path(folder).relative_to(root).as_posix()
        prefix = "" if rel == "." else rel + "/"
        found += [Path(folder) / f for f in files if matcher.match(prefix + f)]
    return sorted(found)


def _is_loopback(address: str) -> bool:
    """True for a scheduler on this machine (``tcp://127.0.0.1:8786``, ``localhost``)."""
    import ipaddress
    from urllib.parse import urlsplit

    try:
        host = urlsplit(address).hostname or ""
    except ValueError:
        return False
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def network_refusal(
    scheduler: str | None, store: str, allowed: bool, given: Collection[str]
) -> str | None:
    """Why a config's scheduler or store would send data off this machine without its
    ``allow_network: true``, or None. What the caller passes (`given`: ``--store``,
    ``run(store=...)``) is its own choice; these checks are for what a config asks for."""
    if scheduler is not None and not allowed and "scheduler" not in given:
        if not _is_loopback(scheduler):
            return (
                f"scheduler: {scheduler} is another host; a scheduler receives the "
                "flight data and runs pickled code, so set allow_network: true to use it"
            )
    if "store" in given:
        return None
    protocol = store.split("://", 1)[0].lower() if "://" in store else "file"
    if protocol == "memory":
        return (
            "store: memory:// lives in this process only and keeps nothing after the run; "
            "name a folder or an object-store URL"
        )
    if protocol not in ("file", "local") and not allowed:
        return (
            f"store: {store} sends flight data and results to {protocol}://; "
            "set allow_network: true to use a remote store"
        )
    return None
