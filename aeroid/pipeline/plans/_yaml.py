"""Reading a campaign config's YAML safely: a size limit, no tags that build objects,
a depth and node limit, and a file that must be a plain file."""

from __future__ import annotations

import functools
import os
import re
import stat
from pathlib import Path
from typing import Any

from ...errors import ConfigError

_MAX_CONFIG_BYTES = 256 * 1024
_MAX_DEPTH = 100
_MAX_NODES = 5_000


@functools.lru_cache(maxsize=1)
def _config_loader() -> tuple[type, type[Exception]]:
    """The YAML loader for configs and the error it raises for a refused construct."""
    import yaml

    class Refused(yaml.YAMLError):
        """A construct a campaign config may not use, at a place in the file."""

        def __init__(self, message: str, mark: Any) -> None:
            super().__init__(message)
            self.message = message
            self.mark = mark

    class Loader(yaml.SafeLoader):
        """YAML's safe loader for configs: a key given twice in one mapping (the last
        would otherwise win without a word), anchors and aliases (an alias chain
        expands exponentially: a few lines can hold a billion values) and nesting
        deeper than `_MAX_DEPTH` are refused, each at its line."""

        _depth = 0
        _nodes = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            event = self.peek_event()
            if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
                raise Refused(
                    "YAML anchors and aliases (&name, *name) are not accepted in a campaign "
                    "config; write the values out",
                    event.start_mark,
                )
            self._nodes += 1
            if self._nodes > _MAX_NODES:
                raise Refused(
                    f"more than {_MAX_NODES} values; a campaign config names its data "
                    "files, it does not hold the data",
                    event.start_mark,
                )
            self._depth += 1
            try:
                if self._depth > _MAX_DEPTH:
                    raise Refused(
                        f"nested deeper than {_MAX_DEPTH} levels; a campaign config is "
                        "never this deep",
                        event.start_mark,
                    )
                return super().compose_node(parent, index)
            finally:
                self._depth -= 1

        def construct_object(self, node: Any, deep: bool = False) -> Any:
            try:
                return super().construct_object(node, deep=deep)
            except (ValueError, OverflowError, TypeError) as exc:
                # an impossible date (2024-13-45), an integer of 5,000 digits, ...
                raise Refused(f"cannot read the value ({exc})", node.start_mark) from None

        def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
            seen: set[Any] = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                try:
                    repeated = key in seen
                except TypeError:
                    raise Refused(
                        "a key must be a single value, not a list or mapping",
                        key_node.start_mark,
                    ) from None
                if repeated:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"the key {key!r} is given twice", key_node.start_mark
                    )
                seen.add(key)
            return super().construct_mapping(node, deep=deep)

    # YAML 1.2's floats: PyYAML (YAML 1.1) reads `1e-6` and `1e9` (no dot, or no sign in
    # the exponent) as strings, which the options refuse where a number is meant
    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
        list("-+0123456789"),
    )
    return Loader, Refused


def _read_config_text(path: Path, source: str) -> str:
    """The config file's text: a regular file of at most `_MAX_CONFIG_BYTES`, UTF-8."""
    # stat first and open without blocking: a FIFO or a device must never be read
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read the config file ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{source}: is {_file_kind(st.st_mode)}, not a config file")
    if st.st_size > _MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{source}: {st.st_size} bytes; a config file is at most "
            f"{_MAX_CONFIG_BYTES // 1024} KiB (is it the right file?)"
        )
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read the config file ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "rb") as fh:
            # the file may have been replaced since the stat: check what was opened
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise ConfigError(f"{source}: is not a regular file, not a config file")
            data = fh.read(_MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read the config file ({exc.strerror})") from None
    if len(data) > _MAX_CONFIG_BYTES:
        raise ConfigError(f"{source}: a config file is at most {_MAX_CONFIG_BYTES // 1024} KiB")
    return _decode_config(data, source)


def _decode_config(data: bytes, source: str) -> str:
    hint = ""
    # UTF-16 (with a byte-order mark, or ASCII text with every other byte zero)
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or (
        len(data) > 1 and (data[0] == 0) != (data[1] == 0)
    ):
        hint = "; it looks like UTF-16: save it as UTF-8"
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{source}: not UTF-8 text (undecodable byte at line {line}){hint or '; is it a binary file?'}"
        ) from None
    if "\x00" in text:
        line = text[: text.index("\x00")].count("\n") + 1
        raise ConfigError(
            f"{source}: not UTF-8 text (a NUL byte at line {line}){hint or '; is it a binary file?'}"
        )
    return text


def _file_kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def read_yaml(p: Path, source: str) -> dict[str, Any]:
    """The top-level mapping of the config file `p` (`source`: its name in messages)."""
    import yaml

    loader, refused = _config_loader()
    text = _read_config_text(p, source)
    try:
        raw = yaml.load(text, Loader=loader)
    except refused as exc:
        mark = exc.mark  # type: ignore[attr-defined]
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ConfigError(f"{source}: {where}{exc.message}") from None  # type: ignore[attr-defined]
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(
            f"{source}: {where}not valid YAML ({' '.join(problem.split())})"
        ) from None
    except RecursionError:  # the depth limit stops nesting first; this is a backstop
        raise ConfigError(f"{source}: nested too deeply to read") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level")
    for key in ("source", "base_dir"):
        if key in raw:
            raise ConfigError(f"{source}: {key}: unknown key")
    return raw
