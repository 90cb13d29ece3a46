#!/usr/bin/env python
"""Benchmark of the probabilistic collision bound (iplanner_torch.collision.gaussian).

Figures: pair bounds per second on a planner-sized batch (diagonal and full covariances),
Newton versus the paper's bisection on the same pairs, the tightness of the bounds
against the exact probability (Ruben's series), the optimiser's isotropic pair screen
(``planning.costs``) on a closed-loop-sized batch against its straightforward formulation, and
the optimiser's bound with its gradient on the kept (waypoint, pair, action) entries of a
person with 9 actions against the same on every entry of the kept pairs, and Boole's sum over
the pairs (``bound_reduce="sum"``) against the paper's maximum, in an optimiser iteration
(with the gradient) and in the acceptance check (exact, without it).

Usage::

    python scripts/bench_collision.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np
import torch
from _timing import median_seconds

from iplanner_torch.collision import gaussian as G
from iplanner_torch.collision.exact import ruben_series
from iplanner_torch.planning import costs as C


def _median_time(fn, repeats: int, warmup: int = 1) -> float:
    return median_seconds(fn, repeats, warmup=warmup)


def _scene(B: int, seed: int, *, W=20, S_r=40, A=10, S_h=20):
    """A robot arm reaching around a seated human: robot spheres spread over the workspace,
    human spheres around the torso and arms, predictive std 1-6 cm."""
    gen = torch.Generator().manual_seed(seed)
    rc = torch.rand(B, W, S_r, 3, generator=gen) * torch.tensor([1.2, 1.0, 0.8])
    rr = 0.04 + 0.04 * torch.rand(S_r, generator=gen)
    hm = torch.tensor([0.0, 0.3, 0.2]) + torch.rand(W, A, S_h, 3, generator=gen) * 0.5
    hv = (0.01 + 0.05 * torch.rand(W, A, S_h, 3, generator=gen)) ** 2
    hr = 0.04 + 0.08 * torch.rand(S_h, generator=gen)
    w = torch.softmax(torch.randn(A, generator=gen), 0)
    Q = torch.linalg.qr(torch.randn(W, A, S_h, 3, 3, generator=gen))[0]
    cov = Q @ torch.diag_embed(hv) @ Q.transpose(-1, -2)
    return rc, rr, hm, hv, cov, hr, w


def _tightness(n: int, seed: int) -> tuple[float, float, int]:
    rng = np.random.default_rng(seed)
    R = rng.uniform(0.05, 0.4, n)
    # Std 0.25 R to 4 R, anisotropy up to 2 in std (where a 120-term Ruben series is exact).
    sig = R[:, None] * np.exp(
        rng.uniform(np.log(0.25), np.log(4.0), (n, 1)) + rng.uniform(0, np.log(2.0), (n, 3))
    )
    s = sig**2
    far = R + sig.max(1) * rng.uniform(0, 6, n)
    dist = np.where(rng.random(n) < 0.25, R * rng.uniform(0, 1, n), far)
    d2 = (rng.dirichlet(np.ones(3), n)) * dist[:, None] ** 2
    lower, exact = ruben_series(s, d2, R * R, max_terms=120)
    assert np.all(exact - lower <= 1e-9 * exact + 1e-300), "Ruben series did not converge"
    t = torch.from_numpy
    zeros = torch.zeros(n, 3, dtype=torch.float64)
    mean = t(np.sqrt(d2))
    out = {}
    for method in ("min", "volume"):
        b = G.sphere_collision_bound_diag(zeros, t(R / 2), mean, t(s), t(R / 2), method=method)
        keep = exact >= 1e-6
        out[method] = float(np.median(b.numpy()[keep] / exact[keep]))
    return out["min"], out["volume"], int(keep.sum())


def _screen_inputs(seed: int, B=8, W=29, P=300, A=9):
    """Robot sphere centres (B, W, P, 3) and the human side of P sphere pairs, as in a
    look-ahead solve of the blocking scenario: most pairs many standard deviations apart."""
    gen = torch.Generator().manual_seed(seed)
    c = torch.rand(B, W, P, 3, generator=gen) * torch.tensor([1.2, 1.0, 0.8])
    mu = torch.tensor([0.0, 0.3, 0.2]) + torch.rand(1, W, P, A, 3, generator=gen) * 0.5
    var = (0.005 + 0.03 * torch.rand(W, P, A, 3, generator=gen)) ** 2
    inv_s = var.amax(-1).rsqrt()
    rad = 0.1 + 0.1 * torch.rand(P, 1, generator=gen)
    return c, mu, var, inv_s, rad


def _screen_reference(c, mu, var, inv_s, rad):
    """The isotropic screen written plainly: (mu - c).norm() and erfc of the unclamped gap."""
    d = mu - c.unsqueeze(-2)
    dist = d.norm(dim=-1)
    gap = (dist - rad) * inv_s
    bound = 0.5 * torch.erfc(gap * (1.0 / math.sqrt(2.0)))
    return torch.where(gap > 0.0, bound, torch.ones_like(bound)), dist


def _many_action_scene(seed: int, B=8, W=29, S_r=20, A=9, S_h=22):
    """The blocking scene's sizes: a robot arm crossing in front of a seated person whose A
    actions put the arm's spheres at A different targets (as the reaching predictor's 9
    weighted actions; std 0.25-10 cm, growing over the window): (B, W, S_r, 3) centres, (S_r,)
    radii and the obstacle."""
    gen = torch.Generator().manual_seed(seed)
    t = torch.linspace(0.0, 1.0, W).view(1, W, 1, 1)
    start = torch.tensor([0.3, 0.3, 0.2]) + 0.4 * torch.rand(B, 1, S_r, 3, generator=gen)
    goal = torch.tensor([0.3, -0.4, 0.2]) + 0.4 * torch.rand(B, 1, S_r, 3, generator=gen)
    rc = start + t * (goal - start)  # (B, W, S_r, 3)
    rr = 0.04 + 0.04 * torch.rand(S_r, generator=gen)
    body = torch.tensor([-0.4, -0.2, 0.0]) + torch.rand(1, 1, S_h, 3, generator=gen) * 0.4
    target = torch.tensor([-0.2, -0.3, 0.0]) + torch.rand(1, A, 1, 3, generator=gen) * 0.6
    reach = torch.linspace(0.0, 1.0, S_h).view(1, 1, S_h, 1)  # share of the reach per sphere
    hm = body + t.view(W, 1, 1, 1) * reach * (target - body)  # (W, A, S_h, 3)
    std = (0.005 + 0.06 * t.view(W, 1, 1, 1)) * (0.5 + torch.rand(W, A, S_h, 3, generator=gen))
    human = C.HumanObstacle(
        mean=hm,
        var=std.square(),
        radii=0.04 + 0.04 * torch.rand(S_h, generator=gen),
        weights=torch.softmax(torch.randn(A, generator=gen), 0),
    )
    return rc, rr, human


def _bound_step(rc, rr, human, pairs, entries=None, reduce="max") -> None:
    """One optimiser iteration's use of the bound: value and gradient."""
    x = rc.clone().requires_grad_(True)
    bound, pen = C.human_collision_bound(
        x, rr, human, pairs, exact=False, entries=entries, reduce=reduce
    )
    (bound.sum() + pen.sum()).backward()


def _acceptance(rc, rr, human, pairs, entries, reduce="max") -> None:
    """The acceptance check's use of the bound: exact, without a gradient."""
    with torch.no_grad():
        C.human_collision_bound(rc, rr, human, pairs, exact=True, entries=entries, reduce=reduce)


def run(quick: bool) -> dict[str, dict]:
    """Run the collision benchmark; ``quick`` uses smaller batches (well under 20 s)."""
    B = 4 if quick else 64
    repeats = 3 if quick else 7
    rc, rr, hm, hv, cov, hr, w = _scene(B, 0)
    n_pairs = rc.shape[0] * rc.shape[1] * rc.shape[2] * hm.shape[1] * hm.shape[2]
    t_diag = _median_time(lambda: G.trajectory_collision_bound(rc, rr, hm, hv, hr, w), repeats)
    t_full = _median_time(lambda: G.trajectory_collision_bound(rc, rr, hm, cov, hr, w), repeats)
    # Dense worst case: no pruning, every pair through the solver.
    t_dense = _median_time(
        lambda: G.trajectory_collision_bound(rc, rr, hm, hv, hr, w, prune_sigma=None), repeats
    )
    # Newton versus bisection on the same pairs (all of them, no pruning).
    n_solver = 50_000 if quick else 1_000_000
    gen = torch.Generator().manual_seed(1)
    c = torch.rand(n_solver, 3, generator=gen)
    mu = torch.rand(n_solver, 3, generator=gen)
    var = (0.01 + 0.1 * torch.rand(n_solver, 3, generator=gen)) ** 2
    r = torch.full((n_solver,), 0.06)
    t_newton = _median_time(lambda: G.sphere_collision_bound_diag(c, r, mu, var, r), repeats)
    t_bisect = _median_time(
        lambda: G.sphere_collision_bound_diag(c, r, mu, var, r, solver="bisection"), repeats
    )
    tight_min, tight_vol, n_tight = _tightness(2000 if quick else 10_000, 2)
    screen = _screen_inputs(3, P=60 if quick else 300)
    with torch.no_grad():
        fast_b, fast_d = C._pair_bounds(*screen, exact=False)
        ref_b, ref_d = _screen_reference(*screen)
        t_screen = _median_time(lambda: C._pair_bounds(*screen, exact=False), repeats)
        t_screen_ref = _median_time(lambda: _screen_reference(*screen), repeats)
    screen_err = float((fast_b - ref_b).abs().max())
    rc_m, rr_m, human_m = _many_action_scene(4)
    pairs_m, entries_m = C.candidate_entries(rc_m, rr_m, human_m, 0.15)
    with torch.no_grad():
        b_entries, _ = C.human_collision_bound(rc_m, rr_m, human_m, pairs_m, entries=entries_m)
        b_dense, _ = C.human_collision_bound(rc_m, rr_m, human_m, pairs_m)
    t_entries = _median_time(lambda: _bound_step(rc_m, rr_m, human_m, pairs_m, entries_m), repeats)
    t_pairs = _median_time(lambda: _bound_step(rc_m, rr_m, human_m, pairs_m), repeats)
    n_dense = pairs_m.shape[0] * human_m.weights.shape[0] * rc_m.shape[1]
    t_sum_step = _median_time(
        lambda: _bound_step(rc_m, rr_m, human_m, pairs_m, entries_m, "sum"), repeats
    )
    pairs_a, entries_a = C.candidate_entries(rc_m, rr_m, human_m, 0.0)
    t_accept = _median_time(lambda: _acceptance(rc_m, rr_m, human_m, pairs_a, entries_a), repeats)
    t_accept_sum = _median_time(
        lambda: _acceptance(rc_m, rr_m, human_m, pairs_a, entries_a, "sum"), repeats
    )
    with torch.no_grad():
        b_max, _ = C.human_collision_bound(rc_m, rr_m, human_m, pairs_a, entries=entries_a)
        b_sum, _ = C.human_collision_bound(
            rc_m, rr_m, human_m, pairs_a, entries=entries_a, reduce="sum"
        )
    threads = torch.get_num_threads()
    return {
        "collision.pairs_per_s": {
            "value": n_pairs / t_diag,
            "unit": "pairs/s",
            "covariance": "diagonal",
            "pairs": n_pairs,
            "dense_no_pruning_pairs_per_s": n_pairs / t_dense,
            "reference_pairs_per_s": n_pairs / t_dense,
            "reference_name": "the same bound, dense, without pruning",
            "ratio": t_dense / t_diag,
            "goal": 1e7,
            "threads": threads,
        },
        "collision.pairs_per_s_full_cov": {
            "value": n_pairs / t_full,
            "unit": "pairs/s",
            "covariance": "full",
            "pairs": n_pairs,
            "goal": 1e7,
            "threads": threads,
        },
        "collision.newton_vs_bisection_speedup": {
            "value": t_bisect / t_newton,
            "unit": "x",
            "newton_s": t_newton,
            "reference": t_bisect,
            "reference_name": "bisection (60 halvings) on the same pairs [s]",
            "pairs": n_solver,
            "goal": 5.0,
        },
        "collision.planner_screen_ms": {
            "value": 1e3 * t_screen,
            "unit": "ms",
            "reference": 1e3 * t_screen_ref,
            "reference_name": "the same screen with (mu - c).norm() and unclamped erfc [ms]",
            "ratio": t_screen / t_screen_ref,
            "entries": int(fast_b.numel()),
            "max_abs_difference": screen_err,
            "max_distance_difference_m": float((fast_d - ref_d).abs().max()),
        },
        "collision.planner_bound_entries_ms": {
            "value": 1e3 * t_entries,
            "unit": "ms",
            "reference": 1e3 * t_pairs,
            "reference_name": "the same bound and gradient on every entry of the pairs [ms]",
            "ratio": t_entries / t_pairs,
            "scene": "B 8, W_x 29, 20 robot spheres, 9 actions x 22 human spheres",
            "pairs": int(pairs_m.shape[0]),
            "entries_kept_fraction": entries_m.shape[0] / n_dense,
            "max_bound": float(b_dense.max()),
            "max_abs_difference": float((b_dense - b_entries).abs().max()),
        },
        "collision.planner_bound_sum_ms": {
            "value": 1e3 * t_sum_step,
            "unit": "ms",
            "reference": 1e3 * t_entries,
            "reference_name": "the paper's maximum, the same entries, value and gradient [ms]",
            "ratio": t_sum_step / t_entries,
            "scene": "B 8, W_x 29, 20 robot spheres, 9 actions x 22 human spheres",
        },
        "collision.acceptance_bound_sum_ms": {
            "value": 1e3 * t_accept_sum,
            "unit": "ms",
            "reference": 1e3 * t_accept,
            "reference_name": "the paper's maximum, exact, refined only where it can change [ms]",
            "ratio": t_accept_sum / t_accept,
            "scene": "B 8, W_x 29, 20 robot spheres, 9 actions x 22 human spheres",
            "largest_bound_max": float(b_max.max()),
            "largest_bound_sum": float(b_sum.max()),
        },
        "collision.tightness_median": {
            "value": tight_min,
            "unit": "bound/exact",
            "method": "min",
            "cases": n_tight,
            "goal": 3.0,
        },
        "collision.tightness_median_volume_only": {
            "value": tight_vol,
            "unit": "bound/exact",
            "method": "volume",
            "cases": n_tight,
            "reference": tight_min,
            "ratio": tight_vol / tight_min,
        },
    }


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    t0 = time.perf_counter()
    print(json.dumps(run(args.quick), indent=2))
    print(f"# {time.perf_counter() - t0:.1f} s", flush=True)
