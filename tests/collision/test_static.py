"""Static obstacle distances against brute-force sampling of the box."""

from __future__ import annotations

import math

import pytest
import torch

from iplanner_torch.collision.static import (
    Box,
    Plane,
    StaticScene,
    sphere_box_distance,
    sphere_plane_distance,
)
from iplanner_torch.errors import ConfigError, ShapeError

F64 = torch.float64


def _rot_z(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=F64)


def test_box_distance_matches_brute_force() -> None:
    gen = torch.Generator().manual_seed(0)
    center = torch.tensor([0.5, -0.2, 0.3], dtype=F64)
    half = torch.tensor([0.3, 0.2, 0.1], dtype=F64)
    R = _rot_z(0.4) @ torch.tensor(
        [[1.0, 0, 0], [0, math.cos(0.3), -math.sin(0.3)], [0, math.sin(0.3), math.cos(0.3)]],
        dtype=F64,
    )
    # Dense sampling of the box surface (box frame), then to world.
    g = torch.linspace(-1, 1, 81, dtype=F64)
    a, b = torch.meshgrid(g, g, indexing="ij")
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            pts = torch.zeros(a.numel(), 3, dtype=F64)
            others = [i for i in range(3) if i != axis]
            pts[:, axis] = sign
            pts[:, others[0]] = a.flatten()
            pts[:, others[1]] = b.flatten()
            faces.append(pts)
    surf = (torch.cat(faces) * half) @ R.T + center  # (P, 3) world
    x = center + (torch.rand(400, 3, generator=gen, dtype=F64) - 0.5) * 1.2
    radii = torch.rand(400, generator=gen, dtype=F64) * 0.05
    got = sphere_box_distance(x, radii, center, half, R)
    to_surface = torch.cdist(x, surf).amin(-1)
    local = (x - center) @ R
    inside = (local.abs() <= half).all(-1)
    want = torch.where(inside, -to_surface, to_surface) - radii
    spacing = float(half.max()) * 2 / 80
    assert torch.all((got - want).abs() <= spacing)
    # Samples can only over-estimate the distance to the surface.
    assert torch.all(got[~inside] <= want[~inside] + 1e-12)
    assert torch.all(got[inside] >= want[inside] - 1e-12)
    assert inside.any() and (~inside).any()


def test_plane_and_scene_clearance_and_gradient() -> None:
    scene = StaticScene(
        boxes=(Box(center=(0.6, 0.0, -0.02), half_extents=(0.4, 0.6, 0.02), name="table"),),
        planes=(Plane(normal=(0.0, 0.0, 1.0), offset=-0.75, name="floor"),),
    )
    x = torch.tensor([[[0.6, 0.0, 0.1], [0.6, 0.0, -0.7], [2.0, 0.0, -0.7]]], dtype=F64)
    r = torch.tensor([0.05, 0.01, 0.1], dtype=F64)
    d = scene.clearance(x, r)
    want = torch.tensor([[0.1 - 0.05, 0.05 - 0.01, 0.05 - 0.1]], dtype=F64)
    torch.testing.assert_close(d, want)
    plane = sphere_plane_distance(x, r, torch.tensor([0, 0, 2.0], dtype=F64), -0.75)
    torch.testing.assert_close(plane, x[..., 2] + 0.75 - r)
    xg = torch.tensor([[0.9, 0.1, 0.3], [1.2, 0.8, 0.1]], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p: scene.clearance(p, r[:2]), (xg,))


def test_errors() -> None:
    with pytest.raises(ConfigError, match=r"positive Box\.half_extents"):
        Box(center=(0, 0, 0), half_extents=(0.1, 0.0, 0.1))
    with pytest.raises(ConfigError, match="at least one"):
        StaticScene()
    with pytest.raises(ShapeError, match="expected box_center"):
        sphere_box_distance(torch.zeros(2, 3), torch.zeros(2), torch.zeros(2), torch.ones(3))


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"center": (math.nan, 0.0, 0.0)}, r"Box\.center \('table'\) a sequence of 3 finite"),
        ({"center": "abc"}, r"Box\.center \('table'\) a sequence of 3 finite numbers, got 'abc'"),
        ({"center": (0.0, 0.0)}, r"Box\.center \('table'\)"),
        ({"half_extents": (0.1, math.nan, 0.1)}, r"Box\.half_extents \('table'\)"),
        ({"half_extents": (0.1, math.inf, 0.1)}, r"Box\.half_extents \('table'\)"),
        ({"half_extents": (0.1, -0.1, 0.1)}, r"positive Box\.half_extents \('table'\)"),
        ({"rotation": ((1.0, 0.0, 0.0), (0.0, math.nan, 0.0), (0.0, 0.0, 1.0))}, r"rotation\[1\]"),
        ({"rotation": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))}, r"Box\.rotation \('table'\) a 3x3"),
        ({"rotation": "eye"}, r"Box\.rotation \('table'\) a 3x3"),
        # a scaled or sheared frame: distances in it are not distances
        ({"rotation": ((2.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}, "orthonormal"),
        ({"rotation": ((1.0, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}, "orthonormal"),
    ],
)
def test_box_refuses_non_finite_or_malformed_fields(kwargs: dict, pattern: str) -> None:
    """NaN centres, sizes and rotations used to be accepted (and give NaN distances)."""
    fields = {"center": (0.0, 0.0, 0.0), "half_extents": (0.1, 0.2, 0.3), "name": "table"}
    with pytest.raises(ConfigError, match=pattern):
        Box(**{**fields, **kwargs})


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"normal": (0.0, math.nan, 1.0)}, r"Plane\.normal \('floor'\) a sequence of 3 finite"),
        ({"normal": "xyz"}, r"Plane\.normal \('floor'\) a sequence of 3 finite .* got 'xyz'"),
        ({"normal": (True, False, False)}, r"Plane\.normal \('floor'\)"),
        ({"normal": (0.0, 0.0, 0.0)}, r"non-zero Plane\.normal \('floor'\)"),
        ({"offset": math.nan}, r"Plane\.offset \('floor'\) a finite number, got nan"),
        ({"offset": math.inf}, r"Plane\.offset \('floor'\) a finite number, got inf"),
        ({"offset": "0.1"}, r"Plane\.offset \('floor'\) a finite number, got '0.1'"),
    ],
)
def test_plane_refuses_non_finite_or_malformed_fields(kwargs: dict, pattern: str) -> None:
    """NaN normals and offsets and a string normal used to be accepted."""
    fields = {"normal": (0.0, 0.0, 1.0), "offset": -0.75, "name": "floor"}
    with pytest.raises(ConfigError, match=pattern):
        Plane(**{**fields, **kwargs})


def test_fields_are_stored_as_floats_and_scenes_take_only_obstacles() -> None:
    box = Box(center=[0, 0, 1], half_extents=[1, 2, 3], rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert box.center == (0.0, 0.0, 1.0) and isinstance(box.center[0], float)
    assert box.rotation == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert hash(box) == hash(Box(center=(0.0, 0.0, 1.0), half_extents=(1.0, 2.0, 3.0)))
    plane = Plane(normal=[0, 0, 2], offset=1)
    assert plane.normal == (0.0, 0.0, 2.0) and isinstance(plane.offset, float)
    with pytest.raises(ConfigError, match=r"StaticScene\.boxes a tuple of Box objects"):
        StaticScene(boxes=(plane,))
    with pytest.raises(ConfigError, match=r"StaticScene\.planes a tuple of Plane objects"):
        StaticScene(planes=plane)  # type: ignore[arg-type]


def test_box_takes_rotations_as_written_to_seven_digits() -> None:
    c, s_ = round(math.cos(0.3), 7), round(math.sin(0.3), 7)
    box = Box(
        center=(0.0, 0.0, 0.0),
        half_extents=(0.1, 0.1, 0.1),
        rotation=((c, -s_, 0.0), (s_, c, 0.0), (0.0, 0.0, 1.0)),
    )
    assert box.rotation[0] == (c, -s_, 0.0)


_UP = torch.tensor([[0.0, 0.0, 1.0]])  # one sphere centre 1 m above the origin
_R = torch.tensor([0.1])


def test_integer_centres_are_refused_not_rounded() -> None:
    """Integer centres used to cast the half extents and the normal to integers: 0.9 instead
    of 0.4 for the box, -0.1 instead of 0.7 for the plane."""
    half, normal = torch.full((3,), 0.5), torch.tensor([0.6, 0.0, 0.8])
    assert sphere_box_distance(_UP, _R, torch.zeros(3), half).tolist() == [pytest.approx(0.4)]
    assert sphere_plane_distance(_UP, _R, normal, 0.0).tolist() == [pytest.approx(0.7)]
    up_int = _UP.long()
    with pytest.raises(ShapeError, match="expected centers of a floating dtype, got torch.int64"):
        sphere_box_distance(up_int, _R, torch.zeros(3), half)
    with pytest.raises(ShapeError, match="expected centers of a floating dtype, got torch.int64"):
        sphere_plane_distance(up_int, _R, normal, 0.0)


@pytest.mark.parametrize(
    ("radii", "match"),
    [
        ([0.1], "expected radii to be a torch.Tensor, got list"),
        (
            torch.zeros(2),
            r"expected radii broadcastable to centers\[\.\.\., 0\] \(1,\), got \(2,\)",
        ),
        (torch.zeros(1, 1), r"broadcastable to centers\[\.\.\., 0\] \(1,\), got \(1, 1\)"),
        (torch.tensor([True]), "expected radii of a real dtype, got torch.bool"),
        (torch.ones(1, device="meta"), r"expected radii on cpu \(where centers is\), got meta"),
    ],
)
def test_sphere_distances_refuse_bad_radii(radii: object, match: str) -> None:
    """A list or a wrongly shaped radii tensor used to raise raw Type/RuntimeErrors (or
    broadcast to a larger result)."""
    with pytest.raises(ShapeError, match=match):
        sphere_box_distance(_UP, radii, torch.zeros(3), torch.full((3,), 0.5))  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match=match):
        sphere_plane_distance(_UP, radii, torch.tensor([0.0, 0.0, 1.0]), 0.0)  # type: ignore[arg-type]


def test_sphere_distances_refuse_a_shape_on_another_device() -> None:
    """torch's "Tensor on device meta is not on the expected device cpu!" before."""
    meta = {"device": "meta"}
    with pytest.raises(
        ShapeError, match=r"expected box_center on cpu \(where centers is\), got meta"
    ):
        sphere_box_distance(
            _UP, torch.ones(1), torch.zeros(3, **meta), torch.ones(3), validate=False
        )
    with pytest.raises(ShapeError, match=r"expected normal on cpu \(where centers is\), got meta"):
        sphere_plane_distance(_UP, torch.ones(1), torch.ones(3, **meta), 0.0, validate=False)
    got = sphere_plane_distance(_UP, torch.tensor(0.1), torch.tensor([0.0, 0.0, 1.0]), 0.0)
    assert got.shape == _UP.shape[:-1]  # a 0-d radius goes with centres anywhere


@pytest.mark.parametrize(
    ("offset", "error", "match"),
    [
        ("a", ConfigError, "expected offset a finite number \\[m\\], got 'a'"),
        (math.nan, ConfigError, "expected offset a finite number, got nan"),
        (torch.zeros(3), ShapeError, r"one-element tensor \[m\], got a tensor of shape \(3,\)"),
        (torch.tensor(math.inf), ConfigError, r"Plane\.offset \('plane'\) a finite number"),
    ],
)
def test_plane_distance_refuses_a_bad_offset(
    offset: object, error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        sphere_plane_distance(_UP, _R, torch.tensor([0.0, 0.0, 1.0]), offset)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("normal", "match"),
    [
        # a NaN normal used to be blamed as a zero one, an inf normal gave NaN silently
        ([math.nan, 0.0, 1.0], r"Plane\.normal \('plane'\) a sequence of 3 finite numbers"),
        ([math.inf, 0.0, 1.0], r"Plane\.normal \('plane'\) a sequence of 3 finite numbers"),
        ([0.0, 0.0, 0.0], r"non-zero Plane\.normal"),
    ],
)
def test_plane_distance_checks_the_normal_as_plane_does(normal: list[float], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        sphere_plane_distance(_UP, _R, torch.tensor(normal), 0.0)
    # a one-element tensor offset is taken as the number
    got = sphere_plane_distance(_UP, _R, torch.tensor([0.0, 0.0, 2.0]), torch.tensor(0.5))
    assert got.tolist() == [pytest.approx(0.4)]


@pytest.mark.parametrize(
    ("half", "rotation", "match"),
    [
        (torch.tensor([0.5, -0.5, 0.5]), None, r"positive Box\.half_extents"),
        (torch.tensor([0.5, math.nan, 0.5]), None, r"Box\.half_extents \('box'\) a sequence"),
        (torch.full((3,), 0.5), 2.0 * torch.eye(3), r"Box\.rotation \('box'\) orthonormal"),
        (torch.full((3,), 0.5), torch.full((3, 3), math.nan), r"Box\.rotation\[0\]"),
    ],
)
def test_box_distance_checks_the_box_as_box_does(
    half: torch.Tensor, rotation: torch.Tensor | None, match: str
) -> None:
    """Negative half extents and a scaled rotation used to be accepted silently."""
    with pytest.raises(ConfigError, match=match):
        sphere_box_distance(_UP, _R, torch.zeros(3), half, rotation)
    with pytest.raises(ConfigError, match=r"Box\.center \('box'\) a sequence of 3 finite"):
        sphere_box_distance(_UP, _R, torch.tensor([math.nan, 0.0, 0.0]), torch.full((3,), 0.5))


@pytest.mark.parametrize("dtype", [torch.int64, torch.bool])
def test_scene_distances_refuse_non_floating_centres(dtype: torch.dtype) -> None:
    """Integer and boolean centres used to raise raw RuntimeErrors from vector_norm."""
    scene = StaticScene(
        boxes=(Box(center=(0.0, 0.0, 0.0), half_extents=(0.5, 0.5, 0.5)),),
        planes=(Plane(normal=(0.0, 0.0, 1.0), offset=0.0),),
    )
    got = scene.distances(_UP, _R)
    assert got.tolist() == [[pytest.approx(0.4), pytest.approx(0.9)]]
    with pytest.raises(ShapeError, match=f"expected centers of a floating dtype, got {dtype}"):
        scene.distances(_UP.to(dtype), _R)
    with pytest.raises(ShapeError, match=f"expected centers of a floating dtype, got {dtype}"):
        scene.clearance(_UP.to(dtype), _R)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("scale", [1e-200, 1e-30, 1e30, 1e300])
def test_plane_normal_of_any_magnitude(dtype: torch.dtype, scale: float) -> None:
    """A normal whose norm overflowed gave a zero unit normal, so every sphere read as
    penetrating the plane (-0.6 m instead of 1.52 m), or NaN; one whose norm underflowed gave
    NaN. The normal is scaled before it is normalised."""
    want = (1.0 + 2.0) / math.sqrt(2.0) - 0.5 - 0.1
    centers, radii = torch.tensor([[1.0, 2.0, 3.0]], dtype=dtype), torch.tensor([0.1], dtype=dtype)
    scene = StaticScene(planes=(Plane(normal=(scale, scale, 0.0), offset=0.5),))
    got = scene.distances(centers, radii)
    assert got.item() == pytest.approx(want, rel=1e-6)
    normal = torch.tensor([scale, scale, 0.0], dtype=torch.float64)
    if dtype == torch.float64 or 1e-30 <= scale <= 1e30:  # representable in dtype
        got = sphere_plane_distance(centers, radii, normal.to(dtype), 0.5)
        assert got.item() == pytest.approx(want, rel=1e-6)


def test_plane_integer_normal() -> None:
    """An integer normal raised a bare RuntimeError from linalg.vector_norm."""
    got = sphere_plane_distance(_UP, _R, torch.tensor([0, 0, 2]), 0.0)
    torch.testing.assert_close(got, sphere_plane_distance(_UP, _R, torch.tensor([0, 0, 1.0]), 0.0))


def test_a_scene_box_rotated_about_z_measures_in_the_box_frame() -> None:
    """A box turned 30 degrees about z (long axis along (cos 30, sin 30, 0)): a point on that
    axis is 0.1 m inside, a point on the world y axis 0.5 cos 30 - 0.1 m outside (by hand in
    the box frame, p_box = R^T p). Applying the rotation transposed put the first 0.68 m
    clear."""
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    box = Box(
        center=(0.0, 0.0, 0.0),
        half_extents=(1.0, 0.1, 0.1),
        rotation=((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)),
    )
    points = torch.tensor([[0.9 * c, 0.9 * s, 0.0], [0.0, 0.5, 0.0]], dtype=torch.float64)
    got = StaticScene(boxes=(box,)).distances(points, torch.zeros(2, dtype=torch.float64))
    want = torch.tensor([[-0.1], [0.5 * c - 0.1]], dtype=torch.float64)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
