"""Benchmark: batched DTW Gram versus tslearn's ``cdist_dtw`` on the same windows.

Also times :func:`~iplanner_torch.types.all_finite`, the finiteness check of every kernel
call, against ``torch.isfinite(x).all()`` (``checks.all_finite_200x15x90_us``).

Run: ``python scripts/bench_dtw.py [--quick]``. Both sides run on one CPU thread (tslearn's
``cdist_dtw`` with ``n_jobs=None`` is single-threaded), timings are medians of repeats after a
warm-up; the values of both Grams are compared (tslearn's DTW is the square root of the sum of
squared local costs, our ``squared=True``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable

import numpy as np
import torch
from _timing import median_seconds

from iplanner_torch.prediction.dtw import dtw_distance
from iplanner_torch.types import all_finite, torch_threads


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    # one warm-up call (and numba compilation on the tslearn side)
    return median_seconds(fn, repeats, warmup=1)


def run(quick: bool) -> dict[str, dict]:
    """Time our Gram and tslearn's on the same windows; return the figures."""
    from tslearn.metrics import cdist_dtw

    n, t, d = (60, 15, 30) if quick else (200, 15, 30)
    repeats = 3 if quick else 5
    g = torch.Generator().manual_seed(0)
    x = torch.randn(n, t, d, generator=g, dtype=torch.float64)
    x_np = x.numpy()
    with torch_threads(1):
        ours = dtw_distance(x, x, squared=True)
        ref = torch.from_numpy(np.asarray(cdist_dtw(x_np)))
        err = float((ours - ref).abs().max())
        assert err < 1e-4, f"DTW Gram differs from tslearn by {err}"
        t_ours = _median_time(lambda: dtw_distance(x, x, squared=True), repeats)
        t_ref = _median_time(lambda: cdist_dtw(x_np), repeats)
        x32 = x.float()
        t_ours32 = _median_time(lambda: dtw_distance(x32, x32), repeats)
        # the finiteness check every DTW/GAK/RBF call makes, on a training-sized batch
        xc = torch.randn(200, 15, 90, generator=g)
        assert all_finite(xc) and bool(torch.isfinite(xc).all())
        reps = 20 if quick else 200
        t_check = _median_time(lambda: all_finite(xc), reps)
        t_check_ref = _median_time(lambda: bool(torch.isfinite(xc).all()), reps)
    pairs = n * n
    return {
        "dtw.gram_speedup_vs_tslearn": {
            "value": t_ref / t_ours,
            "unit": "x",
            "ours_s": t_ours,
            "reference_s": t_ref,
            "reference": "tslearn.metrics.cdist_dtw",
            "windows": [n, t, d],
            "dtype": "float64",
            "threads": 1,
            "max_abs_diff": err,
        },
        "dtw.gram_pairs_per_s": {
            "value": pairs / t_ours32,
            "unit": "pairs/s",
            "seconds": t_ours32,
            "reference_pairs_per_s": pairs / t_ref,
            "reference_name": "tslearn.metrics.cdist_dtw, float64",
            "ratio": t_ref / t_ours32,
            "windows": [n, t, d],
            "dtype": "float32",
            "threads": 1,
        },
        "checks.all_finite_200x15x90_us": {
            "value": 1e6 * t_check,
            "unit": "us",
            "reference": "bool(torch.isfinite(x).all())",
            "reference_us": 1e6 * t_check_ref,
            "ratio": t_check / t_check_ref,
            "dtype": "float32",
            "threads": 1,
        },
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    print(json.dumps(run(parser.parse_args().quick), indent=2))
