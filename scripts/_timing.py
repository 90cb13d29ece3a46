"""Timing shared by the ``scripts/bench_*.py`` benchmarks."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import torch


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


def reference_ms() -> float:
    """Wall time [ms] of a fixed workload of small-tensor torch operations.

    The machine's speed drifts between runs (and within one) by up to 2x on the development
    machine; timed right beside a measurement, this workload moves with it, so the ratio of
    the two compares code across runs better than either time. The work is dispatch-bound,
    like a replanning cycle: 600 operations on (8, 20, 7) tensors, with the caller's torch
    thread setting.
    """
    g = torch.Generator().manual_seed(0)
    a = torch.randn(8, 20, 7, generator=g)
    m = 0.1 * torch.randn(7, 7, generator=g)
    t0 = time.perf_counter()
    x = a
    for _ in range(200):
        x = torch.tanh(x @ m + a)
    float(x.sum())
    return 1e3 * (time.perf_counter() - t0)
