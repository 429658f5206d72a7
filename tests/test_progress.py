"""Progress bars: on stderr when it is a terminal, silent otherwise or when asked."""

from __future__ import annotations

import io

import pytest

from aeroid._progress import progress_bar


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_shows_on_a_terminal_and_hides_otherwise(monkeypatch):
    tty = _Tty()
    monkeypatch.setattr("sys.stderr", tty)
    bar = progress_bar(3, desc="work")
    assert bar is not None
    bar.update(3)
    bar.close()
    assert "work" in tty.getvalue()
    monkeypatch.setattr("sys.stderr", io.StringIO())  # not a terminal
    quiet = progress_bar(3, desc="hidden")
    if quiet is not None:
        quiet.update(3)
        quiet.close()
    assert progress_bar(3, desc="off", enabled=False) is None


@pytest.mark.parametrize("value", ["0"])
def test_environment_switch_disables_bars(monkeypatch, value):
    monkeypatch.setenv("AEROID_PROGRESS", value)
    assert progress_bar(3, desc="x") is None
