"""Primitive collision geometry of robot links: capsules, cylinders and boxes.

Every primitive is expressed in its link's frame, in metres. The same objects are written into
the URDF and MJCF assets (``description.py``), covered by bounding spheres (``spheres.py``) and
sampled in the tests, so the three can never disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from iplanner_torch.errors import ConfigError

Vec3 = tuple[float, float, float]


def _check_vec3(name: str, v: Vec3) -> None:
    if len(v) != 3 or not all(math.isfinite(float(x)) for x in v):
        raise ConfigError(f"expected {name} to be 3 finite numbers, got {v!r}")


def _segment_length(a: Vec3, b: Vec3) -> float:
    return math.sqrt(sum((float(x) - float(y)) ** 2 for x, y in zip(a, b)))


@dataclass(frozen=True, kw_only=True)
class Capsule:
    """All points within ``radius`` of the segment from ``a`` to ``b`` (link frame)."""

    a: Vec3  # first end point of the axis segment [m]
    b: Vec3  # second end point of the axis segment [m] (may equal ``a``: a sphere)
    radius: float  # distance of the surface from the axis [m], > 0

    def __post_init__(self) -> None:
        _check_vec3("Capsule.a", self.a)
        _check_vec3("Capsule.b", self.b)
        if not self.radius > 0:
            raise ConfigError(f"expected Capsule.radius > 0, got {self.radius}")

    @property
    def length(self) -> float:
        """Length of the axis segment [m]."""
        return _segment_length(self.a, self.b)


@dataclass(frozen=True, kw_only=True)
class Cylinder:
    """A solid cylinder with flat ends at ``a`` and ``b`` (link frame)."""

    a: Vec3  # centre of the first end face [m]
    b: Vec3  # centre of the second end face [m], different from ``a``
    radius: float  # radius of the cylinder [m], > 0

    def __post_init__(self) -> None:
        _check_vec3("Cylinder.a", self.a)
        _check_vec3("Cylinder.b", self.b)
        if not self.radius > 0:
            raise ConfigError(f"expected Cylinder.radius > 0, got {self.radius}")
        if not self.length > 0:
            raise ConfigError("expected Cylinder.a != Cylinder.b (zero length)")

    @property
    def length(self) -> float:
        """Distance between the end faces [m]."""
        return _segment_length(self.a, self.b)


@dataclass(frozen=True, kw_only=True)
class Box:
    """A solid box whose edges are aligned with the link frame's axes."""

    center: Vec3  # centre of the box [m]
    half_extents: Vec3  # half sizes along x, y, z [m], each > 0

    def __post_init__(self) -> None:
        _check_vec3("Box.center", self.center)
        _check_vec3("Box.half_extents", self.half_extents)
        if not all(h > 0 for h in self.half_extents):
            raise ConfigError(f"expected Box.half_extents > 0, got {self.half_extents}")


Geometry = Capsule | Cylinder | Box
