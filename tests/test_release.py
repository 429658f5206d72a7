"""Releases are numbered: the newest CHANGELOG section is the package's version."""

from __future__ import annotations

import re
from pathlib import Path

import aeroid

CHANGELOG = Path(__file__).resolve().parents[1] / "CHANGELOG.md"


def _sections() -> list[tuple[str, str]]:
    text = CHANGELOG.read_text(encoding="utf-8")
    parts = re.split(r"^## \[([^\]]+)\][^\n]*\n", text, flags=re.M)
    return list(zip(parts[1::2], parts[2::2], strict=True))


def test_the_newest_release_section_is_the_package_version() -> None:
    released = [(v, body) for v, body in _sections() if v != "Unreleased"]
    assert released, "no release section in CHANGELOG.md"
    assert released[0][0] == aeroid.__version__
    heading = re.search(
        rf"^## \[{re.escape(aeroid.__version__)}\] - (\d{{4}}-\d\d-\d\d)$",
        CHANGELOG.read_text(encoding="utf-8"),
        flags=re.M,
    )
    assert heading is not None, "the release heading carries its date"


def test_no_unreleased_section_grows_unnumbered() -> None:
    # work lands in a numbered release; an Unreleased heading, if any, holds no entries
    for version, body in _sections():
        if version == "Unreleased":
            assert not re.search(r"^- ", body, flags=re.M), "entries under [Unreleased]"


def test_versions_only_go_up() -> None:
    def key(v: str) -> tuple[int, ...]:
        return tuple(int(x) for x in v.split("."))

    versions = [key(v) for v, _ in _sections() if v != "Unreleased"]
    assert versions == sorted(versions, reverse=True) and len(set(versions)) == len(versions)
