"""The person's collision spheres: the covering layout against the body's capsules, sampled
point by point (a point of a capsule must lie in some sphere), and the inner layout's gaps."""

from __future__ import annotations

import math

import pytest
import torch

from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES, SEGMENTS, Segment
from iplanner_torch.errors import ConfigError
from iplanner_torch.planning.human_model import (
    COVER_LENGTH_SCALE,
    COVER_MAX_GAP,
    HumanSphereMap,
)
from iplanner_torch.planning.optimizer import OptimizerCfg, TrajectoryOptimizer

#: a joint's parent in the tree the random bodies are grown along (waist is the root)
PARENT = {
    "torso": "waist",
    "neck": "torso",
    "head": "neck",
    "left_shoulder": "neck",
    "right_shoulder": "neck",
    "left_elbow": "left_shoulder",
    "right_elbow": "right_shoulder",
    "left_hand": "left_elbow",
    "right_hand": "right_elbow",
}
SEGMENT_OF = {frozenset((s.joint_a, s.joint_b)): s for s in SEGMENTS if s.joint_a != s.joint_b}


def _unit(gen: torch.Generator, n: int) -> torch.Tensor:
    v = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    return v / v.norm(dim=-1, keepdim=True)


def _random_body(gen: torch.Generator, fraction: float) -> torch.Tensor:
    """(K, 3) joints in random directions, each segment ``fraction`` of its design length
    (with fraction 1: exactly the length the covering layout is made for)."""
    joints = torch.zeros(len(JOINT_NAMES), 3, dtype=torch.float64)
    for child, parent in PARENT.items():  # parents come first in PARENT's order
        seg = SEGMENT_OF[frozenset((child, parent))]
        length = fraction * COVER_LENGTH_SCALE * seg.length
        joints[JOINT_INDEX[child]] = joints[JOINT_INDEX[parent]] + length * _unit(gen, 1)[0]
    return joints


def _capsule_points(
    gen: torch.Generator, a: torch.Tensor, b: torch.Tensor, radius: float, n: int
) -> torch.Tensor:
    """(n, 3) points of the capsule of ``radius`` around a-b: half on its surface (the
    farthest from the axis), half inside."""
    s = torch.rand(n, 1, generator=gen, dtype=torch.float64)
    depth = torch.ones(n, 1, dtype=torch.float64)
    depth[n // 2 :] = torch.rand(n - n // 2, 1, generator=gen, dtype=torch.float64) ** (1 / 3)
    return a + s * (b - a) + radius * depth * _unit(gen, n)


def _outside(smap: HumanSphereMap, joints: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(n,) how far each point lies outside the union of the spheres [m] (<= 0: inside; the
    radii are float32, so up to about 1e-7 m for points on the surface)."""
    centers = smap.centers(joints)  # (S_h, 3)
    dist = (points[:, None, :] - centers[None]).norm(dim=-1) - smap.radii.double()
    return dist.min(dim=-1).values


def _worst(smap: HumanSphereMap, joints: torch.Tensor, gen: torch.Generator) -> dict[str, float]:
    out = {}
    for seg in SEGMENTS:
        a, b = joints[JOINT_INDEX[seg.joint_a]], joints[JOINT_INDEX[seg.joint_b]]
        pts = _capsule_points(gen, a, b, seg.radius, 3000)
        out[seg.name] = float(_outside(smap, joints, pts).max())
    return out


@pytest.mark.parametrize("fraction", [1.0, 0.8, 0.45])
def test_cover_contains_every_capsule(fraction: float) -> None:
    smap = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover")
    gen = torch.Generator().manual_seed(3)
    for _ in range(4):
        worst = _worst(smap, _random_body(gen, fraction), gen)
        assert max(worst.values()) <= 1e-6, worst


def test_cover_is_tight_and_shares_joint_spheres() -> None:
    smap = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover")
    assert torch.allclose(smap.matrix.sum(-1), torch.ones(smap.num_spheres))
    # every sphere at most COVER_MAX_GAP larger than the largest segment radius at its place
    one_joint = (smap.matrix == 1.0).any(-1)
    biggest = max(s.radius for s in SEGMENTS)
    assert float(smap.radii.max()) <= biggest + COVER_MAX_GAP + 1e-6
    # one sphere per joint, the largest one needed there
    per_joint = (smap.matrix[one_joint] == 1.0).sum(0)
    assert int(per_joint.max()) == 1
    neck = smap.matrix[:, JOINT_INDEX["neck"]] == 1.0
    torso_r = next(s.radius for s in SEGMENTS if s.name == "upper_torso")
    assert float(smap.radii[neck]) > torso_r
    # forearm: 0.35 m at the design length, 1 cm gap -> 6 intervals, radius below 5.5 cm
    seg = next(s for s in SEGMENTS if s.name == "left_forearm")
    inside = (smap.matrix[:, JOINT_INDEX["left_elbow"]] > 0) & (
        smap.matrix[:, JOINT_INDEX["left_hand"]] > 0
    )
    length = COVER_LENGTH_SCALE * seg.length
    m = math.ceil(length / (2 * math.sqrt((seg.radius + COVER_MAX_GAP) ** 2 - seg.radius**2)))
    assert int(inside.sum()) == m - 1
    r = math.sqrt(seg.radius**2 + (length / (2 * m)) ** 2)
    assert torch.allclose(smap.radii[inside], torch.full((m - 1,), r, dtype=torch.float32))


def test_inner_layout_leaves_parts_of_the_arms_out() -> None:
    """The paper's spheres on the skeleton (the default) lie inside the capsules but leave
    centimetres of them out: the reason for the covering layout."""
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    gen = torch.Generator().manual_seed(3)
    worst = _worst(smap, _random_body(gen, 1.0 / COVER_LENGTH_SCALE), gen)
    assert worst["left_forearm"] > 0.02 and worst["right_upper_arm"] > 0.03
    assert worst["head"] <= 1e-6  # a single joint is its own sphere


def test_cover_scales_with_the_body() -> None:
    small = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", scale=0.9)
    big = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", scale=1.2)
    assert float(big.radii.max()) > float(small.radii.max())
    gen = torch.Generator().manual_seed(5)
    joints = _random_body(gen, 1.2)  # 1.2 times the reference design length
    pts = []
    for seg in SEGMENTS:
        a, b = joints[JOINT_INDEX[seg.joint_a]], joints[JOINT_INDEX[seg.joint_b]]
        pts.append(_capsule_points(gen, a, b, 1.2 * seg.radius, 2000))
    assert float(_outside(big, joints, torch.cat(pts)).max()) <= 1e-6


def test_layout_errors() -> None:
    with pytest.raises(ConfigError, match="layout"):
        HumanSphereMap.from_segments(JOINT_NAMES, layout="outer")  # type: ignore[arg-type]
    for key in ("max_gap", "length_scale", "scale"):
        with pytest.raises(ConfigError, match=key):
            HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", **{key: 0.0})
    no_length = Segment(
        name="arm", joint_a="left_shoulder", joint_b="left_elbow", radius=0.05, n_spheres=2
    )
    assert HumanSphereMap.from_segments(JOINT_NAMES, [no_length]).num_spheres == 2
    with pytest.raises(ConfigError, match="'arm' needs a length"):
        HumanSphereMap.from_segments(JOINT_NAMES, [no_length], layout="cover")
    with pytest.raises(ConfigError, match="human_spheres"):
        OptimizerCfg(human_spheres="outer")  # type: ignore[arg-type]


def test_optimizer_uses_the_configured_layout(point_robot) -> None:
    for layout, n in (("inner", 22), ("cover", None)):
        opt = TrajectoryOptimizer(point_robot, OptimizerCfg(human_spheres=layout))
        got = opt._spheres_for(JOINT_NAMES)
        want = HumanSphereMap.from_segments(JOINT_NAMES, layout=layout)
        assert torch.equal(got.matrix, want.matrix) and torch.equal(got.radii, want.radii)
        assert n is None or got.num_spheres == n
