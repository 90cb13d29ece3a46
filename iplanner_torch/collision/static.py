"""Static obstacles (the table, the chair): signed distances from robot spheres.

Distances are between the sphere's surface and the obstacle: negative values are penetration
depths. Everything is differentiable with respect to the sphere centres.

Shapes and dtypes are checked on every call (no host synchronisation). The obstacle's numbers
are checked as :class:`Box` and :class:`Plane` check theirs: by the dataclasses at construction,
and by :func:`sphere_box_distance` and :func:`sphere_plane_distance` when they are given tensors
(``validate=True``, one host synchronisation); :class:`StaticScene`, whose obstacles were checked
when they were built, checks only the spheres (it runs in every optimiser iteration, without a
host synchronisation). The spheres' values are never checked (that would take a host
synchronisation): a NaN or infinite centre or radius gives a NaN or infinite distance for that
sphere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from iplanner_torch.checks import finite, finite_tuple, is_real
from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.types import check_device, check_shape


def _check_spheres(centers: torch.Tensor, radii: torch.Tensor) -> None:
    """ShapeError unless ``centers`` is a floating (..., 3) tensor and ``radii`` a real tensor
    that broadcasts to ``centers[..., 0]``."""
    check_shape("centers", centers, ("...", 3))
    if not isinstance(radii, torch.Tensor):
        raise ShapeError(f"expected radii to be a torch.Tensor, got {type(radii).__name__}")
    _check_dtypes(centers, radii)
    if radii.dim() > 0:  # a 0-d tensor goes with a tensor on any device, as a number does
        check_device("centers", centers, radii=radii)
    lead = tuple(centers.shape[:-1])
    shape = tuple(radii.shape)
    # broadcastable to ``lead`` (a Python test: torch.broadcast_shapes costs tens of us)
    ok = len(shape) <= len(lead) and all(
        s in (1, t) for s, t in zip(reversed(shape), reversed(lead), strict=False)
    )
    if not ok:
        raise ShapeError(
            f"expected radii broadcastable to centers[..., 0] {lead}, got {tuple(radii.shape)}"
        )


def _check_dtypes(centers: torch.Tensor, radii: torch.Tensor) -> None:
    """ShapeError unless ``centers`` is of a floating dtype and ``radii`` of a real one."""
    if not centers.is_floating_point():
        raise ShapeError(f"expected centers of a floating dtype, got {centers.dtype}")
    if radii.dtype == torch.bool or radii.is_complex():
        raise ShapeError(f"expected radii of a real dtype, got {radii.dtype}")


def sphere_box_distance(
    centers: torch.Tensor,
    radii: torch.Tensor,
    box_center: torch.Tensor,
    box_half_extents: torch.Tensor,
    box_rotation: torch.Tensor | None = None,
    *,
    validate: bool = True,
) -> torch.Tensor:
    """Signed distance between sphere surfaces and an oriented box.

    Args:
        centers: (..., 3) sphere centres [m], world frame, of a floating dtype.
        radii: (...) sphere radii [m], broadcastable to ``centers[..., 0]``.
        box_center: (3,) box centre [m], world frame.
        box_half_extents: (3,) half side lengths [m], box frame, > 0.
        box_rotation: (3, 3) rotation ``R_world_box`` (columns: box axes in the world frame);
            identity when None.
        validate: check the box's numbers as :class:`Box` does (one host synchronisation);
            False skips that (for boxes taken from a :class:`Box`).

    Returns:
        (...) signed distance [m]: the box's signed distance at the centre minus the radius.

    Raises:
        ShapeError: on wrong shapes, ``centers`` not of a floating dtype (an integer one would
            round the box to integers), or ``radii`` not a real tensor.
        ConfigError: (``validate``) when the box centre or rotation is not finite, a half
            extent is not finite and > 0, or the rotation is not orthonormal (as :class:`Box`).
    """
    _check_spheres(centers, radii)
    check_shape("box_center", box_center, (3,))
    check_shape("box_half_extents", box_half_extents, (3,))
    if box_rotation is not None:
        check_shape("box_rotation", box_rotation, (3, 3))
    check_device(
        "centers",
        centers,
        box_center=box_center,
        box_half_extents=box_half_extents,
        box_rotation=box_rotation,
    )
    if validate:
        parts = [box_center, box_half_extents]
        if box_rotation is not None:
            parts.append(box_rotation.reshape(-1))
        vals = torch.cat([x.detach().to("cpu", torch.float64) for x in parts]).tolist()
        rows = [vals[6:9], vals[9:12], vals[12:15]] if box_rotation is not None else None
        Box(center=vals[0:3], half_extents=vals[3:6], **({"rotation": rows} if rows else {}))
    return _box_distance(centers, radii, box_center, box_half_extents, box_rotation)


def _box_distance(
    centers: torch.Tensor,
    radii: torch.Tensor,
    box_center: torch.Tensor,
    box_half_extents: torch.Tensor,
    box_rotation: torch.Tensor | None,
) -> torch.Tensor:
    """:func:`sphere_box_distance` without its checks."""
    p = centers - box_center.to(centers)  # (..., 3)
    if box_rotation is not None:
        p = p @ box_rotation.to(centers)  # (..., 3) box frame
    q = p.abs() - box_half_extents.to(centers)  # (..., 3)
    outside = torch.linalg.vector_norm(q.clamp_min(0.0), dim=-1)
    inside = q.amax(-1).clamp_max(0.0)
    return outside + inside - radii


def sphere_plane_distance(
    centers: torch.Tensor,
    radii: torch.Tensor,
    normal: torch.Tensor,
    offset: float | torch.Tensor,
    *,
    validate: bool = True,
) -> torch.Tensor:
    """Signed distance between sphere surfaces and the half-space ``n . x <= offset``.

    Args:
        centers: (..., 3) sphere centres [m], of a floating dtype.
        radii: (...) sphere radii [m], broadcastable to ``centers[..., 0]``.
        normal: (3,) plane normal pointing out of the obstacle (normalised here, whatever its
            magnitude), finite and non-zero, of a real dtype (an integer one too).
        offset: plane offset [m]: the plane is ``n . x = offset``; a finite number (or a
            one-element tensor).
        validate: check ``normal`` (and a tensor ``offset``) as :class:`Plane` does (one
            host synchronisation); False skips that (for planes taken from a :class:`Plane`).

    Returns:
        (...) signed distance [m] (negative: penetration).

    Raises:
        ShapeError: on wrong shapes (``offset`` a tensor of more than one element included),
            ``centers`` not of a floating dtype (an integer one would round the normal to
            integers), or ``radii`` not a real tensor.
        ConfigError: when ``offset`` is not a number or a tensor, or a number that is not
            finite; (``validate``) when ``normal`` is zero or not finite, or a tensor
            ``offset`` is not finite.
    """
    _check_spheres(centers, radii)
    check_shape("normal", normal, (3,))
    check_device(
        "centers",
        centers,
        normal=normal,
        offset=offset if isinstance(offset, torch.Tensor) else None,
    )
    if isinstance(offset, torch.Tensor):
        if offset.numel() != 1:
            raise ShapeError(
                f"expected offset a number or a one-element tensor [m], got a tensor of shape "
                f"{tuple(offset.shape)}"
            )
    elif is_real(offset):
        finite("offset", offset)
    else:
        raise ConfigError(f"expected offset a finite number [m], got {offset!r}")
    if validate:
        # the checks of Plane: 3 finite numbers, not all zero
        off = float(offset) if isinstance(offset, torch.Tensor) else offset
        Plane(normal=tuple(normal.detach().cpu().tolist()), offset=off)
    # in the wider of the two dtypes (an integer normal in that of the centres)
    n = normal.to(centers.device, torch.promote_types(normal.dtype, centers.dtype))
    n = n / n.abs().amax()  # (3,) largest entry +-1: its norm neither overflows nor underflows
    return _plane_distance(centers, radii, (n / torch.linalg.vector_norm(n)).to(centers), offset)


def _plane_distance(
    centers: torch.Tensor, radii: torch.Tensor, unit: torch.Tensor, offset: float | torch.Tensor
) -> torch.Tensor:
    """:func:`sphere_plane_distance` without its checks, for a unit normal ``unit`` (3,) of the
    centres' dtype and device."""
    return centers @ unit - offset - radii


#: how far ``R R^T`` of a :class:`Box` rotation may be from the identity (rounding of a
#: rotation written out to 7 digits passes)
ROTATION_TOL = 1e-6


@dataclass(frozen=True, kw_only=True)
class Box:
    """An oriented box obstacle.

    The numbers are checked and stored as tuples of floats at construction.

    Raises:
        ConfigError: when ``center`` or a row of ``rotation`` is not 3 finite numbers (a
            string, NaN, inf or a bool included), ``rotation`` has not 3 rows or is not
            orthonormal (within :data:`ROTATION_TOL`), or ``half_extents`` are not 3 finite
            numbers > 0; the message names the field and the box.
    """

    center: tuple[float, float, float]  # box centre [m], world frame
    half_extents: tuple[float, float, float]  # half side lengths [m]
    rotation: tuple[tuple[float, float, float], ...] = (  # R_world_box, rows
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
    )
    name: str = "box"  # label in logs

    def __post_init__(self) -> None:
        label = f"({self.name!r})"
        center = finite_tuple(f"Box.center {label}", self.center, 3)
        half = finite_tuple(f"Box.half_extents {label}", self.half_extents, 3)
        if min(half) <= 0:
            raise ConfigError(f"expected positive Box.half_extents {label}, got {half}")
        rows = self.rotation
        if isinstance(rows, (str, bytes)) or not hasattr(rows, "__len__") or len(rows) != 3:
            raise ConfigError(f"expected Box.rotation {label} a 3x3 rotation, got {rows!r}")
        rotation = tuple(
            finite_tuple(f"Box.rotation[{i}] {label}", row, 3) for i, row in enumerate(rows)
        )
        # the box frame must be orthonormal, or the distances are not distances
        worst = max(
            abs(sum(a * b for a, b in zip(rotation[i], rotation[j], strict=True)) - (i == j))
            for i in range(3)
            for j in range(3)
        )
        if worst > ROTATION_TOL:
            raise ConfigError(
                f"expected Box.rotation {label} orthonormal (R R^T = I within {ROTATION_TOL:g}), "
                f"got {rotation} (off by {worst:.3g})"
            )
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "half_extents", half)
        object.__setattr__(self, "rotation", rotation)


@dataclass(frozen=True, kw_only=True)
class Plane:
    """A half-space obstacle ``normal . x <= offset`` (e.g. the floor).

    The numbers are checked and stored as floats at construction.

    Raises:
        ConfigError: when ``normal`` is not 3 finite numbers (a string, NaN, inf or a bool
            included) or is zero, or ``offset`` is not a finite number; the message names the
            field and the plane.
    """

    normal: tuple[float, float, float]  # outward normal (normalised when used)
    offset: float  # plane offset along the normal [m]
    name: str = "plane"  # label in logs

    def __post_init__(self) -> None:
        label = f"({self.name!r})"
        normal = finite_tuple(f"Plane.normal {label}", self.normal, 3)
        if all(v == 0 for v in normal):
            raise ConfigError(f"expected a non-zero Plane.normal {label}, got {self.normal!r}")
        offset = finite(f"Plane.offset {label}", self.offset)
        object.__setattr__(self, "normal", normal)
        object.__setattr__(self, "offset", offset)


@dataclass(frozen=True, kw_only=True)
class StaticScene:
    """Static obstacles of a scene: boxes (table, chair) and planes (floor)."""

    boxes: tuple[Box, ...] = field(default_factory=tuple)  # oriented boxes
    planes: tuple[Plane, ...] = field(default_factory=tuple)  # half-spaces

    def __post_init__(self) -> None:
        for field_name, kind in (("boxes", Box), ("planes", Plane)):
            items = getattr(self, field_name)
            if not isinstance(items, (tuple, list)) or not all(
                isinstance(item, kind) for item in items
            ):
                raise ConfigError(
                    f"expected StaticScene.{field_name} a tuple of {kind.__name__} objects, "
                    f"got {items!r}"
                )
        if not self.boxes and not self.planes:
            raise ConfigError("expected at least one box or plane in a StaticScene")

    def distances(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """Signed distance of every sphere to every obstacle.

        Args:
            centers: (..., S, 3) sphere centres [m].
            radii: (S,) sphere radii [m].

        Returns:
            (..., S, O) signed distances [m], boxes first, then planes.

        Raises:
            ShapeError: on wrong shapes, or ``centers`` not of a floating dtype, or ``radii``
                not a real tensor.
        """
        check_shape("centers", centers, ("...", "S", 3))
        check_shape("radii", radii, (centers.shape[-2],))
        _check_dtypes(centers, radii)
        kw = {"dtype": centers.dtype, "device": centers.device}
        out = []
        for box in self.boxes:
            out.append(
                _box_distance(  # the box was checked by Box, the spheres above
                    centers,
                    radii,
                    torch.tensor(box.center, **kw),
                    torch.tensor(box.half_extents, **kw),
                    torch.tensor(box.rotation, **kw),
                )
            )
        for plane in self.planes:
            # the plane was checked by Plane, the spheres above; normalised in Python floats,
            # scaled first (a normal of 1e300 or 1e-200 overflows or underflows its norm)
            big = max(abs(v) for v in plane.normal)
            scaled = [v / big for v in plane.normal]
            norm = math.hypot(*scaled)
            unit = torch.tensor([v / norm for v in scaled], **kw)
            out.append(_plane_distance(centers, radii, unit, plane.offset))
        return torch.stack(out, dim=-1)

    def clearance(self, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """Smallest signed distance of each sphere to all obstacles.

        Args:
            centers: (..., S, 3) sphere centres [m].
            radii: (S,) sphere radii [m].

        Returns:
            (..., S) signed clearance [m] (negative: penetration), differentiable.

        Raises:
            ShapeError: as :meth:`distances`.
        """
        return self.distances(centers, radii).amin(-1)
