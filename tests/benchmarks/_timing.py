"""Timing shared by the benchmarks: the median of several runs, never one."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any


def timed(fn: Callable[[], Any], repeats: int = 7, *, warm_up: bool = False) -> tuple[float, Any]:
    """Median wall time of `repeats` calls of `fn` and the last call's result.

    `warm_up` makes one untimed call first (imports, caches, LTI detection).
    """
    if warm_up:
        fn()
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def median_time(fn: Callable[[], Any], repeats: int = 7, *, warm_up: bool = False) -> float:
    """Median wall time of `repeats` calls of `fn`."""
    return timed(fn, repeats, warm_up=warm_up)[0]
