"""Bounding spheres: the union covers each link's surface, with at most 2 cm of excess.

Surface samplers and distance functions below are written independently of the fitter.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import pytorch_kinematics as pk
import torch

from iplanner_torch.errors import ConfigError
from iplanner_torch.robot.description import robot_description
from iplanner_torch.robot.geometry import Box, Capsule, Cylinder
from iplanner_torch.robot.model import RobotModel
from iplanner_torch.robot.spheres import fit_link_spheres

MAX_EXCESS = 0.02


def _orthonormal(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    v /= np.linalg.norm(v)
    return v, np.cross(u, v)


def _unit_vectors(n: int, rng: np.random.Generator) -> np.ndarray:
    x = rng.normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def sample_surface(g, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points on the surface of a primitive, edges and rims included."""
    if isinstance(g, Box):
        c, h = np.asarray(g.center), np.asarray(g.half_extents)
        p = rng.uniform(-h, h, size=(n, 3))
        axis = rng.integers(0, 3, size=n)
        p[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -1.0, 1.0) * h[axis]
        corners = np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T * h
        return np.concatenate([p, corners]) + c
    a, b, r = np.asarray(g.a, float), np.asarray(g.b, float), g.radius
    length = np.linalg.norm(b - a)
    if length < 1e-12:
        return a + r * _unit_vectors(n, rng)
    u = (b - a) / length
    v, w = _orthonormal(u)
    phi = rng.uniform(0, 2 * math.pi, size=(n, 1))
    ring = np.cos(phi) * v + np.sin(phi) * w  # (n, 3)
    t = rng.uniform(0, length, size=(n, 1))
    side = a + t * u + r * ring
    if isinstance(g, Capsule):
        d = _unit_vectors(n, rng)
        caps = np.where((d @ u)[:, None] < 0, a + r * d, b + r * d)
        return np.concatenate([side, caps])
    rho = r * np.sqrt(rng.random((n, 1)))
    ends = np.where(rng.random((n, 1)) < 0.5, a, b) + rho * ring
    rims = np.concatenate([a + r * ring, b + r * ring])
    return np.concatenate([side, ends, rims])


def distance_to(g, p: np.ndarray) -> np.ndarray:
    """(n,) distance of points (n, 3) to the solid primitive (0 inside)."""
    if isinstance(g, Box):
        q = np.abs(p - np.asarray(g.center)) - np.asarray(g.half_extents)
        return np.linalg.norm(np.maximum(q, 0.0), axis=1)
    a, b, r = np.asarray(g.a, float), np.asarray(g.b, float), g.radius
    ab = b - a
    length = np.linalg.norm(ab)
    if isinstance(g, Capsule):
        t = np.clip(((p - a) @ ab) / max(length**2, 1e-300), 0.0, 1.0)
        return np.maximum(np.linalg.norm(p - (a + t[:, None] * ab), axis=1) - r, 0.0)
    u = ab / length
    s = (p - a) @ u
    radial = np.linalg.norm(p - a - s[:, None] * u, axis=1)
    dr = np.maximum(radial - r, 0.0)
    ds = np.maximum(np.maximum(-s, s - length), 0.0)
    return np.hypot(dr, ds)


def _uncovered(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(n,) how far each point lies outside the union of spheres (<= 0: covered)."""
    d = np.linalg.norm(points[:, None, :] - centers[None], axis=-1) - radii[None]
    return d.min(axis=1)


def _excess(geoms, centers: np.ndarray, radii: np.ndarray, rng: np.random.Generator) -> float:
    """Largest distance of a sphere point from the geometry (dense sampling + axis points)."""
    dirs = np.concatenate([_unit_vectors(3000, rng), np.eye(3), -np.eye(3)])
    worst = 0.0
    for c, r in zip(centers, radii):
        pts = c + r * dirs
        d = np.min([distance_to(g, pts) for g in geoms], axis=0)
        worst = max(worst, float(d.max()))
    return worst


PRIMITIVES = [
    Capsule(a=(0.0, 0.0, 0.0), b=(0.0, 0.3, 0.1), radius=0.07),
    Capsule(a=(0.1, 0.0, 0.0), b=(0.1, 0.0, 0.0), radius=0.05),
    Capsule(a=(0.0, 0.0, 0.0), b=(0.01, 0.0, 0.0), radius=0.01),
    Cylinder(a=(0.0, 0.0, 0.0), b=(0.0, 0.0, 0.25), radius=0.04),
    Cylinder(a=(0.0, 0.0, 0.0), b=(0.1, 0.0, 0.0), radius=0.03),
    Box(center=(0.05, 0.0, -0.02), half_extents=(0.1, 0.05, 0.01)),
    Box(center=(0.0, 0.0, 0.0), half_extents=(0.2, 0.2, 0.2)),
]


@pytest.mark.parametrize("geom", PRIMITIVES, ids=lambda g: type(g).__name__)
def test_primitive_surface_covered_with_bounded_excess(geom) -> None:
    rng = np.random.default_rng(1)
    centers, radii = (t.numpy() for t in fit_link_spheres(geom, max_excess=MAX_EXCESS))
    pts = sample_surface(geom, 3000, rng)
    assert _uncovered(pts, centers, radii).max() <= 1e-9
    excess = _excess([geom], centers, radii, rng)
    assert excess <= MAX_EXCESS + 1e-9
    assert excess >= 0.5 * MAX_EXCESS  # the bound is used, the spheres are not needlessly many


def test_tighter_excess_needs_more_spheres() -> None:
    geom = PRIMITIVES[0]
    n = [len(fit_link_spheres(geom, max_excess=e)[1]) for e in (0.04, 0.02, 0.005)]
    assert n[0] < n[1] < n[2]


def test_fit_errors() -> None:
    with pytest.raises(ConfigError, match="max_excess > 0"):
        fit_link_spheres(PRIMITIVES[0], max_excess=0.0)
    with pytest.raises(ConfigError, match="cannot cover a cylinder"):
        fit_link_spheres(Cylinder(a=(0, 0, 0), b=(0, 0, 0.5), radius=0.1), max_excess=0.02)
    # shorter than its diameter (6 cm against 8): one sphere would stick out 3 cm > 2 cm
    with pytest.raises(ConfigError, match=r"length 0\.0600 m .*length >= 2 radius"):
        fit_link_spheres(Cylinder(a=(0, 0, 0), b=(0, 0, 0.06), radius=0.04), max_excess=0.02)
    with pytest.raises(ConfigError, match="at least one"):
        fit_link_spheres([], max_excess=0.02)
    with pytest.raises(ConfigError, match="radius > 0"):
        Capsule(a=(0, 0, 0), b=(0, 0, 1), radius=0.0)


@pytest.mark.parametrize("name", ["kuka_iiwa14", "fetch"])
def test_link_spheres_cover_links_in_link_frame(name: str) -> None:
    rng = np.random.default_rng(2)
    desc = robot_description(name)
    for link in desc.sphere_links:
        geoms = desc.link(link).geometry
        centers, radii = (t.numpy() for t in fit_link_spheres(geoms, max_excess=MAX_EXCESS))
        pts = np.concatenate([sample_surface(g, 2000, rng) for g in geoms])
        assert _uncovered(pts, centers, radii).max() <= 1e-9, link
        assert _excess(geoms, centers, radii, rng) <= MAX_EXCESS + 1e-9, link


@pytest.mark.parametrize("name", ["kuka_iiwa14", "fetch"])
def test_world_spheres_cover_links_after_fk(name: str) -> None:
    """Surface points moved by pytorch-kinematics' link poses lie in our world spheres."""
    rng = np.random.default_rng(3)
    model = RobotModel.load(
        name, dtype=torch.float64, base_position=(0.3, -0.2, 0.1), base_yaw=0.7
    )
    chain = pk.build_serial_chain_from_urdf(model.urdf_xml(), model.tool_link).to(
        dtype=torch.float64
    )
    lo = torch.where(torch.isfinite(model.q_min), model.q_min, torch.full_like(model.q_min, -3.1))
    hi = torch.where(torch.isfinite(model.q_max), model.q_max, torch.full_like(model.q_max, 3.1))
    q = lo + (hi - lo) * torch.rand(8, model.num_joints, dtype=torch.float64)
    frames = chain.forward_kinematics(q, end_only=False)
    c, s = math.cos(0.7), math.sin(0.7)
    t_world_base = np.array(
        [[c, -s, 0, 0.3], [s, c, 0, -0.2], [0, 0, 1, 0.1], [0, 0, 0, 1]], dtype=np.float64
    )
    centers = model.sphere_centers(q).numpy()  # (8, S, 3)
    radii = model.sphere_radii.numpy()
    owner = np.array(model.sphere_link)
    for link in model.description.sphere_links:
        pts_local = np.concatenate(
            [sample_surface(g, 2000, rng) for g in model.description.link(link).geometry]
        )
        pts_h = np.concatenate([pts_local, np.ones((len(pts_local), 1))], axis=1)  # (n, 4)
        mine = owner == link
        for k in range(q.shape[0]):
            t = t_world_base @ frames[link].get_matrix()[k].numpy()
            pts = (pts_h @ t.T)[:, :3]
            assert _uncovered(pts, centers[k, mine], radii[mine]).max() <= 1e-7, (link, k)


def test_sphere_count_is_capped_before_allocating() -> None:
    """max_excess = 1e-5 tried to allocate 1.4 TB for the Fetch gripper's box; 3e-4 built
    2.18 million spheres; a capsule at 1e-19 m divided by zero."""
    from iplanner_torch.robot.spheres import MAX_LINK_SPHERES

    box = Box(center=(0.0, 0.0, 0.0), half_extents=(0.075, 0.065, 0.03))
    capsule = PRIMITIVES[0]
    for geom, excess in ((box, 1e-5), (box, 3e-4), (capsule, 1e-19), (capsule, 1e-9)):
        with pytest.raises(ConfigError, match=r"beyond MAX_LINK_SPHERES = \d+.*raise max_excess"):
            fit_link_spheres(geom, max_excess=excess)
    # the cap counts the link's primitives together
    n_one = len(fit_link_spheres(box, max_excess=0.0022)[1])
    assert n_one <= MAX_LINK_SPHERES < 2 * n_one
    with pytest.raises(ConfigError, match="MAX_LINK_SPHERES"):
        fit_link_spheres([box, box], max_excess=0.0022)
    with pytest.raises(ConfigError, match="link 'gripper_link': .*max_sphere_excess"):
        RobotModel.load("fetch", max_sphere_excess=1e-5)
    assert RobotModel.load("fetch", max_sphere_excess=0.002).num_spheres == 8443


@pytest.mark.parametrize(
    ("geometry", "excess", "match"),
    [
        (PRIMITIVES[0], math.inf, "expected max_excess > 0 and finite, got inf"),
        (PRIMITIVES[0], math.nan, "expected max_excess > 0 and finite, got nan"),
        (PRIMITIVES[0], "0.02", "expected max_excess > 0 and finite"),
        ("a", 0.02, "expected geometry a Capsule, Cylinder or Box or a sequence of them, got str"),
        (None, 0.02, "expected geometry a Capsule, .* got NoneType"),
        (3, 0.02, "expected geometry a Capsule, .* got int"),
    ],
)
def test_bad_fit_arguments_raise_config_error(geometry, excess, match: str) -> None:
    """max_excess = inf gave spheres of infinite radius; a string, None or an int geometry
    raised raw TypeErrors."""
    with pytest.raises(ConfigError, match=match):
        fit_link_spheres(geometry, max_excess=excess)
