"""Timing shared by the ``scripts/bench_*.py`` benchmarks."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_seconds(
    fn: Callable[[], object],
    repeats: int,
    *,
    warmup: int = 1,
    sync: Callable[[], object] | None = None,
) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` untimed calls.

    Args:
        fn: the work to time.
        repeats: timed calls.
        warmup: untimed calls first (caches, lazy compilation).
        sync: called after each call before the clock stops (e.g. ``torch.cuda.synchronize``).
    """
    for _ in range(warmup):
        fn()
    if sync is not None:
        sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        if sync is not None:
            sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)
