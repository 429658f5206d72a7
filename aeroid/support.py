"""What aeroid's own subpackages (`aeroid.pipeline`, `aeroid.adapters`) take from the
library's private helpers, named once here.

Not part of the user API (`aeroid` does not export it): the subpackages import
these names from here rather than reach into the library's private modules, so
that what crosses a package boundary is listed in one place.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._aliases import legacy_name
from ._conditions import CONDITION_KEYS, CONDITION_NAMES
from ._records import ReadOnlyDict, fmt, markdown_table
from ._threads import quiet_warnings, record_warnings, replay_warnings
from ._units import guessed_units, parameter_units
from .reports import html as _html
from .reports.html import figure_png, markdown_to_html
from .uncertainty.database_export import replace_aerodynamics
from .uncertainty.design_options import optimizer_settings
from .uncertainty.prediction import holdout_record

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = [
    "CONDITION_KEYS",
    "CONDITION_NAMES",
    "ReadOnlyDict",
    "atomic_write",
    "figure",
    "figure_png",
    "fmt",
    "guessed_units",
    "holdout_record",
    "legacy_name",
    "markdown_table",
    "markdown_to_html",
    "optimizer_settings",
    "parameter_units",
    "quiet_warnings",
    "record_warnings",
    "replace_aerodynamics",
    "replay_warnings",
]


def atomic_write(path: Path, data: bytes) -> None:
    """Write `data` to `path` whole or not at all (looked up at each call, so that a
    test that replaces the library's writer replaces this one too)."""
    _html._atomic_write(path, data)


def figure(rows: int, cols: int = 1, *, height: float | None = None) -> tuple[Figure, Any]:
    """A report figure with `rows` x `cols` axes in the library's layout (matplotlib
    is imported on first use)."""
    from .reports.plotting import figure

    return figure(rows, cols) if height is None else figure(rows, cols, height=height)
