"""Frequency-domain work: frequency responses, transfer-function fits, frequency-domain
estimation, handling qualities."""

from __future__ import annotations

from typing import Any


# `aeroid.frequency` was the frequency-response module before it became this
# package: its names stay reachable here (flat layout: ``aeroid.frequency.frequency_response``).
def __getattr__(name: str) -> Any:
    from importlib import import_module
    from pathlib import Path

    if (Path(__file__).parent / f"{name}.py").is_file():
        # a module of this package not imported yet: the import system loads it
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    response = import_module(".response", __name__)
    try:
        return getattr(response, name)
    except AttributeError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
