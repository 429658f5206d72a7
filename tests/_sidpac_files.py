"""SIDPAC's data files for reference tests: read from $AEROID_SIDPAC_DIR, skipped without it."""

from __future__ import annotations

import os
from typing import Any

import pytest


def sidpac_mat(*parts: str) -> dict[str, Any]:
    """The .mat file at `parts` under $AEROID_SIDPAC_DIR, loaded; skips the test when absent."""
    root = os.environ.get("AEROID_SIDPAC_DIR")
    if not root:
        pytest.skip("AEROID_SIDPAC_DIR not set")
    path = os.path.join(root, *parts)
    if not os.path.exists(path):
        pytest.skip(f"{path} not found")
    scipy_io = pytest.importorskip("scipy.io")
    return dict(scipy_io.loadmat(path))
