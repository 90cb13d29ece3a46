#!/usr/bin/env python
"""How much of the person's body each human-sphere layout leaves out.

The simulated person is a capsule of radius ``Segment.radius`` around every skeleton segment
(``sim/scene.py``). For sampled frames of a dataset, this samples points of those capsules
(half on their surfaces) and prints, per segment and layout
(``HumanSphereMap.from_segments(layout=...)``), how far the worst point lies outside the union
of the spheres, in cm (<= 0: every sampled point is covered).

Usage::

    python scripts/human_sphere_gaps.py [--data datasets/reaching] [--frames 200] [--seed 0]

Uses the noise-free joints of synthetic recordings where the files have them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from _report import fail, main_guard

from iplanner_torch.collision.human_spheres import HumanSphereMap
from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES, SEGMENTS
from iplanner_torch.errors import DataError

ROOT = Path(__file__).resolve().parents[1]


def _frames(data: Path, n: int, gen: torch.Generator) -> torch.Tensor:
    """(n, K, 3) frames drawn from every demonstration under ``data`` (no NaN joints)."""
    demos = load_demonstrations(data, joints=JOINT_NAMES)
    pos = [d.clean_positions if d.clean_positions is not None else d.positions for d in demos]
    frames = torch.as_tensor(np.concatenate(pos), dtype=torch.float64)  # (T, K, 3)
    frames = frames[torch.isfinite(frames).all(-1).all(-1)]
    if frames.shape[0] == 0:
        raise DataError(f"{data}: no frame with every joint tracked")
    idx = torch.randint(frames.shape[0], (n,), generator=gen)
    return frames[idx]


def gaps(frames: torch.Tensor, gen: torch.Generator, points: int = 400) -> dict[str, dict]:
    """{layout: {segment: worst distance outside the spheres [m]}} over frames (F, K, 3)."""
    out: dict[str, dict] = {}
    for layout in ("inner", "cover"):
        smap = HumanSphereMap.from_segments(JOINT_NAMES, layout=layout)
        radii = smap.radii.double()
        worst = {}
        for seg in SEGMENTS:
            a = frames[:, JOINT_INDEX[seg.joint_a]]  # (F, 3)
            b = frames[:, JOINT_INDEX[seg.joint_b]]
            s = torch.rand(frames.shape[0], points, 1, generator=gen, dtype=torch.float64)
            d = torch.randn(frames.shape[0], points, 3, generator=gen, dtype=torch.float64)
            d = d / d.norm(dim=-1, keepdim=True)
            depth = torch.ones(frames.shape[0], points, 1, dtype=torch.float64)
            depth[:, points // 2 :] = torch.rand(
                frames.shape[0], points - points // 2, 1, generator=gen, dtype=torch.float64
            ) ** (1 / 3)
            p = a[:, None] + s * (b - a)[:, None] + seg.radius * depth * d  # (F, P, 3)
            centers = smap.centers(frames)  # (F, S_h, 3)
            dist = (p[:, :, None] - centers[:, None]).norm(dim=-1) - radii  # (F, P, S_h)
            worst[seg.name] = float(dist.min(-1).values.max())
        out[layout] = worst
    return out


@main_guard
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT / "datasets" / "reaching")
    parser.add_argument("--frames", type=int, default=200, help="frames to sample (>= 1)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.frames < 1:
        fail(f"--frames must be >= 1, got {args.frames}")
    if not args.data.exists():
        fail(f"{args.data}: not found (generate it with `iplanner-data generate`)")
    gen = torch.Generator().manual_seed(args.seed)
    frames = _frames(args.data, args.frames, gen)
    result = gaps(frames, gen)
    print(f"{frames.shape[0]} frames of {args.data}; worst point outside the spheres [cm]")
    print(f"{'segment':16s} {'inner':>8s} {'cover':>8s}")
    for seg in SEGMENTS:
        inner, cover = result["inner"][seg.name], result["cover"][seg.name]
        print(f"{seg.name:16s} {100 * inner:8.2f} {100 * cover:8.2f}")
    for layout in ("inner", "cover"):
        n = HumanSphereMap.from_segments(JOINT_NAMES, layout=layout).num_spheres
        print(f"{layout}: {n} spheres, worst {100 * max(result[layout].values()):.2f} cm")


if __name__ == "__main__":
    main()
