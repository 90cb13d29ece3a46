"""The person's collision spheres.

The covering layout against the body's capsules, sampled point by point (a point of a capsule
must lie in some sphere); the inner layout's gaps; the sphere Gaussians against a Monte Carlo
of the joints; bad input."""

from __future__ import annotations

import math

import pytest
import torch

from iplanner_torch.collision.human_spheres import (
    COVER_LENGTH_SCALE,
    COVER_MAX_GAP,
    HumanSphereMap,
)
from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES, SEGMENTS, Segment
from iplanner_torch.errors import ConfigError, DataError, ShapeError

F64 = torch.float64

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


def test_inner_layout_and_names() -> None:
    smap = HumanSphereMap.from_segments(JOINT_NAMES, scale=1.2)
    assert smap.num_spheres == sum(s.n_spheres for s in SEGMENTS) == 22
    assert smap.num_joints == len(JOINT_NAMES)
    assert smap.names[0] == "head_0" and len(set(smap.names)) == smap.num_spheres
    assert abs(float(smap.radii[0]) - 0.11 * 1.2) < 1e-6
    row = dict(zip(smap.names, smap.matrix))
    # forearm spheres at u = 1/6, 1/2, 5/6 from elbow to hand
    u = [float(row[f"left_forearm_{i}"][JOINT_INDEX["left_hand"]]) for i in range(3)]
    assert u == pytest.approx([1 / 6, 1 / 2, 5 / 6])
    assert float(row["head_0"][JOINT_INDEX["head"]]) == 1.0
    cover = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover")
    assert "left_hand" in cover.names and "left_forearm_1" in cover.names
    assert len(set(cover.names)) == cover.num_spheres


@pytest.mark.parametrize("layout", ["inner", "cover"])
def test_sphere_gaussians_match_monte_carlo(layout: str) -> None:
    """Sphere centres interpolated from sampled joints, row by row with the map's weights
    read as (joint a, u) pairs, against the closed-form mean and covariance."""
    gen = torch.Generator().manual_seed(0)
    smap = HumanSphereMap.from_segments(JOINT_NAMES, layout=layout)  # type: ignore[arg-type]
    K = len(JOINT_NAMES)
    mean = torch.randn(K, 3, generator=gen, dtype=F64)
    A = torch.randn(K, 3, 3, generator=gen, dtype=F64) * 0.05
    cov = A @ A.transpose(-1, -2) + 1e-4 * torch.eye(3, dtype=F64)
    m, c = smap.centers_full(mean, cov)
    n = 200_000
    L = torch.linalg.cholesky(cov)
    z = mean + torch.einsum("kij,nkj->nki", L, torch.randn(n, K, 3, generator=gen, dtype=F64))
    samples = []
    for row in smap.matrix.double():
        joints = torch.nonzero(row).squeeze(-1).tolist()
        samples.append(sum(float(row[j]) * z[:, j] for j in joints))
    x = torch.stack(samples, 1)  # (n, S_h, 3)
    torch.testing.assert_close(m, x.mean(0), atol=4e-3, rtol=0)
    xc = x - x.mean(0)
    emp = torch.einsum("nsi,nsj->sij", xc, xc) / (n - 1)
    torch.testing.assert_close(c, emp, atol=3e-4, rtol=0.02)
    torch.testing.assert_close(smap.centers(mean), m)


def test_diag_equals_full_with_diagonal_covariance() -> None:
    gen = torch.Generator().manual_seed(1)
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    mean = torch.randn(2, 4, len(JOINT_NAMES), 3, generator=gen)
    var = torch.rand(2, 4, len(JOINT_NAMES), 3, generator=gen) * 0.01
    m1, v1 = smap.centers_diag(mean, var)
    m2, c2 = smap.centers_full(mean, torch.diag_embed(var))
    torch.testing.assert_close(m1, m2)
    torch.testing.assert_close(torch.diag_embed(v1), c2)


def test_map_errors() -> None:
    with pytest.raises(ConfigError, match="expected scale > 0"):
        HumanSphereMap.from_segments(JOINT_NAMES, scale=0.0)
    with pytest.raises(ConfigError, match="expected scale > 0 and finite"):
        HumanSphereMap.from_segments(JOINT_NAMES, scale=math.inf)
    with pytest.raises(ConfigError, match="needs joint 'neck', not tracked"):
        HumanSphereMap.from_segments(("head",))
    with pytest.raises(ConfigError, match="distinct joint names"):
        HumanSphereMap.from_segments(("head", "head"), SEGMENTS[:1])
    with pytest.raises(ConfigError, match="at least one body segment"):
        HumanSphereMap.from_segments(JOINT_NAMES, ())
    seg = Segment(name="head", joint_a="head", joint_b="head", radius=-0.1, n_spheres=1)
    with pytest.raises(ConfigError, match="expected radius > 0 and finite in segment 'head'"):
        HumanSphereMap.from_segments(JOINT_NAMES, (seg,))
    seg = Segment(name="head", joint_a="head", joint_b="head", radius=0.1, n_spheres=0)
    with pytest.raises(ConfigError, match="n_spheres >= 1 in segment 'head'"):
        HumanSphereMap.from_segments(JOINT_NAMES, (seg,))
    eye = torch.eye(2)
    with pytest.raises(ConfigError, match="sum to 1"):
        HumanSphereMap(2.0 * eye, torch.ones(2))
    with pytest.raises(ConfigError, match="weights >= 0"):
        HumanSphereMap(torch.tensor([[2.0, -1.0]]), torch.ones(1))
    with pytest.raises(ConfigError, match="radii > 0"):
        HumanSphereMap(eye, torch.tensor([0.1, math.nan]))
    with pytest.raises(ShapeError, match="expected radii"):
        HumanSphereMap(eye, torch.ones(3))
    with pytest.raises(ShapeError, match="sphere names"):
        HumanSphereMap(eye, torch.ones(2), names=["a"])


def test_map_without_joints_raises_config_error() -> None:
    """A (S_h, 0) map used to fail with an IndexError."""
    with pytest.raises(ConfigError, match="expected at least one joint in the sphere map"):
        HumanSphereMap(torch.zeros(2, 0), torch.ones(2))


@pytest.mark.parametrize("bad", [math.nan, math.inf])
@pytest.mark.parametrize("name", ["mean", "cov", "var"])
def test_non_finite_input_raises_data_error(name: str, bad: float) -> None:
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    K = len(JOINT_NAMES)
    args = {
        "mean": torch.zeros(2, K, 3, dtype=F64),
        "cov": torch.eye(3, dtype=F64).expand(2, K, 3, 3).clone() * 0.01,
        "var": torch.full((2, K, 3), 0.01, dtype=F64),
    }
    args[name][1, 0, 0] = bad
    with pytest.raises(DataError, match=f"expected finite {name}, got"):
        if name in ("mean", "cov"):
            smap.centers_full(args["mean"], args["cov"])
        else:
            smap.centers_diag(args["mean"], args["var"])
    if name == "mean":
        with pytest.raises(DataError, match="expected finite mean, got"):
            smap.centers_diag(args["mean"], args["var"])
    # validate=False skips the finiteness test (for forecasts already checked)
    out = (
        smap.centers_diag(args["mean"], args["var"], validate=False)
        if name != "cov"
        else smap.centers_full(args["mean"], args["cov"], validate=False)
    )
    assert not all(bool(torch.isfinite(o).all()) for o in out)


def test_bad_shapes_and_dtypes() -> None:
    smap = HumanSphereMap.from_segments(JOINT_NAMES)
    K = len(JOINT_NAMES)
    mean, var = torch.zeros(K, 3), torch.full((K, 3), 0.01)
    with pytest.raises(ShapeError, match="expected mean"):
        smap.centers_diag(torch.zeros(3, 3), torch.zeros(3, 3))
    with pytest.raises(ShapeError, match="expected joints"):
        smap.centers(torch.zeros(K, 2))
    with pytest.raises(DataError, match="expected var >= 0"):
        smap.centers_diag(mean, -var)
    with pytest.raises(ShapeError, match="expected var torch.float32 on cpu \\(as mean\\)"):
        smap.centers_diag(mean, var.double())
    with pytest.raises(ShapeError, match="expected mean of a floating dtype"):
        # integer means would truncate the weights to 0 silently
        smap.centers_diag(mean.long(), var.long())
    with pytest.raises(ShapeError, match="expected joints of a floating dtype"):
        smap.centers(mean.long())
    with pytest.raises(ShapeError, match="expected cov"):
        smap.centers_full(mean, var)


def test_sphere_count_is_capped_before_building() -> None:
    """max_gap = 1e-12 used to build about 2.5e6 spheres (minutes); 1e-40 divided by zero."""
    from iplanner_torch.collision.human_spheres import MAX_HUMAN_SPHERES

    for gap in (1e-12, 1e-40):
        with pytest.raises(ConfigError, match=r"more than MAX_HUMAN_SPHERES = \d+: raise max_gap"):
            HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", max_gap=gap)
    arm = {"name": "arm", "joint_a": "left_shoulder", "joint_b": "left_elbow"}
    many = Segment(**arm, radius=0.05, n_spheres=10**9)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="MAX_HUMAN_SPHERES.*lower n_spheres"):
        HumanSphereMap.from_segments(JOINT_NAMES, (many,))
    fine = HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", max_gap=2e-4)
    assert 42 < fine.num_spheres <= MAX_HUMAN_SPHERES


@pytest.mark.parametrize("dtype", [torch.bool, torch.complex64])
def test_bool_or_complex_maps_raise_shape_error(dtype: torch.dtype) -> None:
    eye = torch.eye(2)
    with pytest.raises(ShapeError, match=f"expected matrix of real numbers, got {dtype}"):
        HumanSphereMap(eye.to(dtype), torch.ones(2))
    with pytest.raises(ShapeError, match=f"expected radii of real numbers, got {dtype}"):
        HumanSphereMap(eye, torch.ones(2).to(dtype))


def test_bad_segments_and_joint_names_raise_config_error() -> None:
    """A float n_spheres, a string radius or length, a non-Segment and joint_names=None
    raised raw TypeError / AttributeError."""
    arm = {"name": "arm", "joint_a": "left_shoulder", "joint_b": "left_elbow"}
    half = Segment(**arm, radius=0.05, n_spheres=2.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="n_spheres >= 1 in segment 'arm' .*got 2.5"):
        HumanSphereMap.from_segments(JOINT_NAMES, (half,))
    text = Segment(**arm, radius="0.05", n_spheres=2)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected radius > 0 and finite in segment 'arm'"):
        HumanSphereMap.from_segments(JOINT_NAMES, (text,))
    text_len = Segment(**arm, radius=0.05, n_spheres=2, length="0.3")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="'arm' needs a length > 0"):
        HumanSphereMap.from_segments(JOINT_NAMES, (text_len,), layout="cover")
    with pytest.raises(ConfigError, match="expected segments of Segment, got tuple"):
        HumanSphereMap.from_segments(JOINT_NAMES, (("arm", "left_shoulder"),))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected segments a sequence of Segment"):
        HumanSphereMap.from_segments(JOINT_NAMES, 3)  # type: ignore[arg-type]
    for names in (None, "head", 3, ["head", 1]):
        with pytest.raises(ConfigError, match="expected joint_names a sequence of joint names"):
            HumanSphereMap.from_segments(names)  # type: ignore[arg-type]
    # iterables other than tuples still work
    assert HumanSphereMap.from_segments(list(JOINT_NAMES), iter(SEGMENTS)).num_spheres == 22


def test_cover_of_a_huge_scale_raises_config_error() -> None:
    """scale=1e300 raised a bare OverflowError from squaring the segment radius; it is now
    the sphere-count ConfigError of any other scale too large for MAX_HUMAN_SPHERES."""
    with pytest.raises(ConfigError, match="'cover' sphere layout would take about"):
        HumanSphereMap.from_segments(JOINT_NAMES, layout="cover", scale=1e300)


@pytest.mark.parametrize(
    ("radius", "length", "max_gap"),
    [(0.05, 0.13, 0.01), (0.02, 0.5, 0.02), (0.08, 0.3, 0.005), (0.04, 0.05, 0.03)],
)
def test_cover_takes_the_fewest_intervals_within_max_gap(
    radius: float, length: float, max_gap: float
) -> None:
    """The docstring's ``m``: the fewest intervals whose radius ``sqrt(r^2 + (L / 2m)^2)``
    stays within ``r + max_gap``, found here by counting up. E.g. r = 0.05, L = 0.13, gap
    0.01: m = 1 gives hypot(0.05, 0.065) = 0.082 > 0.06, m = 2 gives hypot(0.05, 0.0325) =
    0.0596 <= 0.06, so 3 spheres of that radius."""
    seg = Segment(
        name="arm",
        joint_a="left_shoulder",
        joint_b="left_elbow",
        radius=radius,
        n_spheres=1,
        length=length,
    )
    m = 1
    while math.hypot(radius, length / (2 * m)) > radius + max_gap:
        m += 1
    smap = HumanSphereMap.from_segments(
        JOINT_NAMES, [seg], layout="cover", max_gap=max_gap, length_scale=1.0
    )
    assert smap.num_spheres == m + 1
    expected_r = math.hypot(radius, length / (2 * m))
    assert smap.radii.tolist() == pytest.approx([expected_r] * (m + 1), rel=1e-6)
    assert expected_r <= radius + max_gap
