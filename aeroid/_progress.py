"""Progress bars on stderr for long work, silent when stderr is not a terminal."""

from __future__ import annotations

import os
import sys
from typing import Any


def progress_bar(total: int, *, desc: str, enabled: bool = True, unit: str = "it") -> Any:
    """A tqdm bar on stderr, or None when disabled.

    Disabled when `enabled` is false, when ``AEROID_PROGRESS=0`` is set, or
    when stderr is not a terminal (tqdm's ``disable=None``), so logs and CI
    output stay clean.
    """
    if not enabled or os.environ.get("AEROID_PROGRESS", "1") == "0":
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # progress is cosmetic
        return None
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=None, leave=False)
