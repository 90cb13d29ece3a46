"""Automatic bounding spheres of robot links (paper sec. 3.2, "bounding spheres ... generated
using the medial axis of robot links").

Each primitive is covered by a finite set of spheres ``B_ij`` with ``R_i`` inside their union and
a bounded *excess*, the largest distance of a sphere point from the primitive:

* capsule of radius ``r`` around segment ``a -> b`` (its medial axis is the segment): spheres of
  radius ``R = r + e`` centred on the segment, with spacing ``s <= 2 sqrt(R^2 - r^2)``, so that
  the point of the surface midway between two centres, at distance ``sqrt(r^2 + (s/2)^2)``,
  is covered; the end caps are covered by the end spheres. Excess ``e`` exactly.
* cylinder (flat ends): the same axis spheres, the end ones moved inwards by
  ``h = sqrt(R^2 - r^2)`` so the end rims stay covered; excess ``max(e, R - h)``. Possible only
  when ``r <= (1 + sqrt 2) e`` and the cylinder is at least ``2 r`` long; otherwise a
  :class:`ConfigError` says to use a capsule or a box.
* box: a grid of ``n_x n_y n_z`` cells, one sphere circumscribing each cell. A sphere of
  radius ``R`` centred ``delta`` inside the nearest face exceeds the box by ``R - delta``; the
  grid is refined along its longest cell side until ``R - min(cell half sizes) <= e``.

The union covers the whole solid (not only its surface). Sphere counts grow as the excess
shrinks (a box's as ``1 / e^3``): one link gets at most :data:`MAX_LINK_SPHERES`, counted
before any is built.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from iplanner_torch.checks import positive
from iplanner_torch.errors import ConfigError
from iplanner_torch.robot.geometry import Box, Capsule, Cylinder, Geometry

#: the most spheres for one link (the iiwa takes 2 to 11 per link and the Fetch gripper's box
#: 8400 at ``max_excess = 0.002`` m, 44 at the default 0.02 m in all): the planner's cost
#: scales with the robot's sphere count
MAX_LINK_SPHERES = 10_000


def fit_link_spheres(
    geometry: Geometry | Sequence[Geometry], max_excess: float = 0.02
) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounding spheres covering one link's collision geometry.

    Args:
        geometry: one primitive or a sequence of them, in the link frame [m].
        max_excess: the largest allowed distance of any sphere point from the geometry [m].

    Returns:
        ``(centers_local, radii)``: (S, 3) sphere centres in the link frame [m] and (S,) radii
        [m], float64 on the CPU, primitives in the given order.

    Raises:
        ConfigError: for ``max_excess`` not a finite number > 0, a geometry that is not a
            primitive or a sequence of them, an empty geometry list, a cylinder that axis
            spheres cannot cover within ``max_excess``, or more than
            :data:`MAX_LINK_SPHERES` spheres (raise ``max_excess``).
    """
    max_excess = positive("max_excess", max_excess)
    bad = ConfigError(
        "expected geometry a Capsule, Cylinder or Box or a sequence of them, got "
        f"{type(geometry).__name__} {geometry!r}"
    )
    if isinstance(geometry, Capsule | Cylinder | Box):
        prims: list[object] = [geometry]
    elif isinstance(geometry, str | bytes):
        raise bad
    else:
        try:
            prims = list(geometry)
        except TypeError:
            raise bad from None
    if not prims:
        raise ConfigError("expected at least one geometry primitive, got none")
    centers: list[torch.Tensor] = []
    radii: list[torch.Tensor] = []
    room = MAX_LINK_SPHERES  # spheres the remaining primitives may take
    for g in prims:
        if isinstance(g, Capsule):
            c, r = _capsule_spheres(g, max_excess, room)
        elif isinstance(g, Cylinder):
            c, r = _cylinder_spheres(g, max_excess, room)
        elif isinstance(g, Box):
            c, r = _box_spheres(g, max_excess, room)
        else:
            raise ConfigError(f"unsupported geometry {type(g).__name__}")
        centers.append(c)
        radii.append(r)
        room -= len(r)
    return torch.cat(centers), torch.cat(radii)


def _too_many(g: Geometry, count: float, e: float) -> ConfigError:
    """The error for a primitive that needs ``count`` spheres, beyond what is left."""
    return ConfigError(
        f"covering {g} within max_excess = {e:g} m takes about "
        f"{count:.4g} spheres, beyond MAX_LINK_SPHERES = {MAX_LINK_SPHERES} for the link: "
        "raise max_excess (RobotModel / RobotCfg: max_sphere_excess)"
    )


def _axis_count(length: float, half_spacing: float, g: Geometry, e: float, room: int) -> int:
    """Intervals between axis spheres, ``ceil(length / (2 half_spacing))``; ConfigError when
    their spheres would exceed ``room``."""
    intervals = length / (2.0 * half_spacing) - 1e-12 if half_spacing > 0 else math.inf
    if not intervals + 1 <= room:
        raise _too_many(g, intervals + 1, e)
    return math.ceil(intervals)


def _axis_points(a: torch.Tensor, b: torch.Tensor, count: int) -> torch.Tensor:
    """``count`` evenly spaced points from ``a`` to ``b`` inclusive: (count, 3)."""
    if count == 1:
        return (0.5 * (a + b)).unsqueeze(0)
    t = torch.linspace(0.0, 1.0, count, dtype=torch.float64).unsqueeze(1)  # (count, 1)
    return a + t * (b - a)


def _capsule_spheres(g: Capsule, e: float, room: int) -> tuple[torch.Tensor, torch.Tensor]:
    a = torch.tensor(g.a, dtype=torch.float64)
    b = torch.tensor(g.b, dtype=torch.float64)
    big_r = g.radius + e
    half_gap = math.sqrt(big_r**2 - g.radius**2)
    length = g.length
    if length <= 1e-12:
        return a.unsqueeze(0), torch.tensor([big_r], dtype=torch.float64)
    intervals = max(1, _axis_count(length, half_gap, g, e, room))
    centers = _axis_points(a, b, intervals + 1)
    return centers, torch.full((intervals + 1,), big_r, dtype=torch.float64)


def _cylinder_spheres(g: Cylinder, e: float, room: int) -> tuple[torch.Tensor, torch.Tensor]:
    r = g.radius
    big_r = r + e
    inset = math.sqrt(big_r**2 - r**2)  # end spheres sit this far inside the end faces
    length = g.length
    if big_r - inset > e + 1e-12 or length < 2.0 * r:
        raise ConfigError(
            f"cannot cover a cylinder of radius {r} m and length {length:.4f} m by axis spheres "
            f"within {e} m (needs radius <= {(1 + math.sqrt(2)) * e:.4f} m and length >= 2 "
            "radius): use a Capsule or a Box"
        )
    a = torch.tensor(g.a, dtype=torch.float64)
    b = torch.tensor(g.b, dtype=torch.float64)
    u = (b - a) / length
    # Any inset in [r, h] keeps the excess <= e; stay as far in as allowed, within the middle.
    d = min(inset, 0.5 * length)
    inner = length - 2.0 * d
    intervals = _axis_count(inner, inset, g, e, room) if inner > 1e-12 else 0
    centers = _axis_points(a + d * u, b - d * u, intervals + 1)
    return centers, torch.full((intervals + 1,), big_r, dtype=torch.float64)


def _box_spheres(g: Box, e: float, room: int) -> tuple[torch.Tensor, torch.Tensor]:
    half = [float(h) for h in g.half_extents]
    counts = [1, 1, 1]
    while True:
        cell = [h / n for h, n in zip(half, counts)]
        big_r = math.sqrt(sum(c * c for c in cell))
        if big_r - min(cell) <= e:
            break
        if math.prod(counts) > room:  # the count only grows from here
            raise _too_many(g, _box_count_estimate(half, e), e)
        counts[max(range(3), key=lambda i: cell[i])] += 1
    if math.prod(counts) > room:
        raise _too_many(g, math.prod(counts), e)
    axes = []
    for k in range(3):
        n, h, c0 = counts[k], half[k], float(g.center[k])
        # Cell centres: c0 - h + (2 i + 1) h / n for i = 0 .. n - 1.
        idx = torch.arange(n, dtype=torch.float64)
        axes.append(c0 - h + (2.0 * idx + 1.0) * h / n)
    gx, gy, gz = torch.meshgrid(*axes, indexing="ij")
    centers = torch.stack([gx, gy, gz], dim=-1).reshape(-1, 3)  # (n_x n_y n_z, 3)
    return centers, torch.full((centers.shape[0],), big_r, dtype=torch.float64)


def _box_count_estimate(half: list[float], e: float) -> float:
    """About how many cells the box grid needs: cubic cells of half size ``e / (sqrt 3 - 1)``
    (where ``R - min(cell) = e``), at least one per axis."""
    c = e / (math.sqrt(3.0) - 1.0)
    return math.prod(max(1.0, h / c) for h in half)
