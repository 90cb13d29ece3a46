"""Offscreen pictures of the workspace: fixed free cameras, sphere overlays, contact sheets.

:class:`SceneRenderer` draws a compiled scene (:func:`iplanner_torch.sim.scene.build_scene`)
from one of three free cameras framed on the table, the seated human and the robot, and can
add translucent spheres (predicted human spheres, robot bounding spheres) to the picture.

GL backend: MuJoCo picks its OpenGL backend from ``MUJOCO_GL``. When that variable is unset
and no display is configured (``DISPLAY`` / ``WAYLAND_DISPLAY``), importing this module sets
``MUJOCO_GL=osmesa`` when libOSMesa is installed (software rendering, Debian package
``libosmesa6``), else ``MUJOCO_GL=egl`` when libEGL is (Mesa's software EGL, package
``libegl-mesa0``, or a GPU driver), else leaves it unset; set it yourself to choose. The
renderer opens its GL context from the backend this variable names, so it works even when
``mujoco`` was imported before this module. Rendering is optional: :func:`gl_available` says
whether a context can be opened, without raising.

Close every renderer (``close()`` or a ``with`` block) before the process exits, as MuJoCo's
documentation asks: GL contexts freed during interpreter shutdown can crash.
"""

from __future__ import annotations

import copy
import functools
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal


def _headless_backend() -> str | None:
    """The offscreen GL backend whose library this machine has: ``osmesa`` (libOSMesa) first,
    then ``egl`` (libEGL, e.g. Mesa's llvmpipe or a GPU driver), or None.

    Only a backend whose library is found is named: ``MUJOCO_GL`` is inherited by child
    processes, and with mujoco 4.0 a backend whose library is missing makes ``import mujoco``
    itself fail there.
    """
    import ctypes.util

    for backend, library in (("osmesa", "OSMesa"), ("egl", "EGL")):
        if ctypes.util.find_library(library):
            return backend
    return None


if "MUJOCO_GL" not in os.environ and not (
    os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
):
    _backend = _headless_backend()
    if _backend is not None:
        os.environ["MUJOCO_GL"] = _backend

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from iplanner_torch.checks import integer  # noqa: E402
from iplanner_torch.errors import ConfigError, ShapeError  # noqa: E402

CameraName = Literal["overview", "side", "top"]

#: Free cameras as (lookat (3,) [m], distance [m], azimuth [deg], elevation [deg]) in the table
#: frame (x from the human to the robot, y to the human's left, table top at z = 0). MuJoCo's
#: camera looks along (cos el cos az, cos el sin az, sin el) at ``lookat``.
CAMERAS: dict[str, tuple[tuple[float, float, float], float, float, float]] = {
    "overview": ((0.15, 0.0, 0.0), 2.3, 120.0, -35.0),
    "side": ((0.25, 0.0, 0.05), 2.3, 90.0, -12.0),
    "top": ((0.25, 0.0, 0.0), 2.6, 90.0, -89.0),
}
#: Translucent red: robot bounding spheres.
ROBOT_SPHERE_RGBA = (0.9, 0.2, 0.2, 0.2)
#: Translucent blue: predicted human spheres.
HUMAN_SPHERE_RGBA = (0.2, 0.4, 0.95, 0.35)


def _gl_context_class() -> Any:
    """The ``GLContext`` class of the backend ``MUJOCO_GL`` names (glfw when unset)."""
    backend = os.environ.get("MUJOCO_GL", "").lower().strip()
    if backend == "osmesa":
        from mujoco.osmesa import GLContext
    elif backend == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.glfw import GLContext
    return GLContext


class SceneRenderer:
    """Renders RGB pictures of a compiled scene from named free cameras.

    The renderer draws a private copy of ``model`` whose visual settings are adjusted (an
    offscreen buffer of the requested size, a soft headlight); geom sizes and colours are
    re-read from ``model`` at every :meth:`render`, since
    :func:`~iplanner_torch.sim.scene.pose_human` changes capsule lengths in place.

    Args:
        model: the compiled scene; ``data`` given to :meth:`render` must belong to it.
        width: image width [px].
        height: image height [px].
        max_geom: capacity of the visual scene (model geoms plus overlay spheres).

    Raises:
        ConfigError: when width or height is not an integer >= 1.
        RuntimeError / ImportError: when no GL context can be opened (see :func:`gl_available`).

    Example:
        >>> with SceneRenderer(model) as r:
        ...     rgb = r.render(data, camera="side")  # (480, 640, 3) uint8
    """

    def __init__(
        self, model: mujoco.MjModel, *, width: int = 640, height: int = 480, max_geom: int = 4000
    ) -> None:
        width = integer("width", width, minimum=1)  # "x" raised a bare TypeError, 1.5 passed
        height = integer("height", height, minimum=1)
        self._gl: Any = None
        self._con: mujoco.MjrContext | None = None
        self._src = model
        self._model = copy.copy(model)
        vis = self._model.vis
        vis.global_.offwidth = max(int(width), int(vis.global_.offwidth))
        vis.global_.offheight = max(int(height), int(vis.global_.offheight))
        vis.headlight.ambient[:] = (0.35, 0.35, 0.35)
        vis.headlight.diffuse[:] = (0.45, 0.45, 0.45)
        vis.headlight.specular[:] = (0.1, 0.1, 0.1)
        vis.headlight.active = 1
        vis.map.znear = 0.01
        self.width, self.height = int(width), int(height)
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self.scene = mujoco.MjvScene(self._model, maxgeom=int(max_geom))
        self._opt = mujoco.MjvOption()
        self._pert = mujoco.MjvPerturb()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._gl = _gl_context_class()(self.width, self.height)
        try:
            self._gl.make_current()
            self._con = mujoco.MjrContext(self._model, mujoco.mjtFontScale.mjFONTSCALE_150)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        except Exception:
            self.close()
            raise

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        if self._gl is not None:
            try:
                self._gl.make_current()
                if self._con is not None:
                    self._con.free()
            finally:
                self._gl.free()
        self._con = None
        self._gl = None

    def camera(self, name: CameraName) -> mujoco.MjvCamera:
        """The free camera ``name`` of :data:`CAMERAS`.

        Raises:
            ConfigError: when the name is unknown.
        """
        if name not in CAMERAS:
            raise ConfigError(f"expected camera in {sorted(CAMERAS)}, got {name!r}")
        lookat, distance, azimuth, elevation = CAMERAS[name]
        cam = self._cam
        cam.lookat[:] = lookat
        cam.distance = distance
        cam.azimuth = azimuth
        cam.elevation = elevation
        return cam

    def render(
        self,
        data: mujoco.MjData,
        *,
        camera: CameraName = "overview",
        spheres: Sequence[tuple[np.ndarray, np.ndarray, Sequence[float]]] = (),
    ) -> np.ndarray:
        """Draw the current state.

        ``data`` must be up to date: call ``mj_forward`` after changing qpos or mocap poses
        (``mj_kinematics`` alone leaves the lights and cameras where they were).

        Args:
            data: simulation state of the model given at construction.
            camera: one of :data:`CAMERAS`.
            spheres: overlay groups ``(centres (S, 3) [m], radii (S,) [m], rgba (4,))``, drawn
                as translucent spheres on top of the model's geoms (e.g. the robot's bounding
                spheres with :data:`ROBOT_SPHERE_RGBA`).

        Returns:
            (height, width, 3) uint8 RGB image, top row first.

        Raises:
            ConfigError: unknown camera, closed renderer, or more overlay spheres than the
                visual scene holds.
            ShapeError: when an overlay group is not (S, 3), (S,), (4,).
        """
        if self._con is None:
            raise ConfigError("expected an open renderer, got a closed one")
        cam = self.camera(camera)
        self._model.geom_size[:] = self._src.geom_size
        self._model.geom_rbound[:] = self._src.geom_rbound
        self._model.geom_rgba[:] = self._src.geom_rgba
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self._model, data, self._opt, self._pert, cam, mujoco.mjtCatBit.mjCAT_ALL, self.scene
        )
        for centres, radii, rgba in spheres:
            self._add_spheres(centres, radii, rgba)
        mujoco.mjr_render(self._rect, self.scene, self._con)
        rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(rgb, None, self._rect, self._con)
        return np.ascontiguousarray(rgb[::-1])

    def _add_spheres(self, centres: np.ndarray, radii: np.ndarray, rgba: Sequence[float]) -> None:
        c = np.asarray(centres, dtype=np.float64)
        r = np.asarray(radii, dtype=np.float64)
        color = np.asarray(rgba, dtype=np.float32)
        if c.ndim != 2 or c.shape[1] != 3 or r.shape != (c.shape[0],) or color.shape != (4,):
            raise ShapeError(
                f"expected overlay centres (S, 3), radii (S,), rgba (4,), got {c.shape}, "
                f"{r.shape}, {color.shape}"
            )
        scn = self.scene
        if scn.ngeom + len(r) > scn.maxgeom:
            raise ConfigError(
                f"expected at most {scn.maxgeom - scn.ngeom} overlay spheres, got {len(r)}"
            )
        eye = np.eye(3).ravel()
        for centre, radius in zip(c, r):
            if not (np.isfinite(centre).all() and math.isfinite(radius)):
                continue
            mujoco.mjv_initGeom(
                scn.geoms[scn.ngeom],
                mujoco.mjtGeom.mjGEOM_SPHERE,
                np.array([radius, radius, radius]),
                centre,
                eye,
                color,
            )
            scn.ngeom += 1


@functools.cache
def gl_available() -> bool:
    """Whether an offscreen GL context opens and renders (never raises; cached per process)."""
    try:
        model = mujoco.MjModel.from_xml_string(
            '<mujoco><worldbody><geom type="sphere" size="0.1"/></worldbody></mujoco>'
        )
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with SceneRenderer(model, width=16, height=16) as r:
            r.render(data, camera="side")
        return True
    except Exception:
        return False


def save_contact_sheet(
    frames: list[np.ndarray],
    titles: list[str],
    path: Path,
    *,
    columns: int = 3,
    heading: str | None = None,
) -> Path:
    """Write frames as a titled PNG grid.

    Args:
        frames: images (H, W, 3) uint8, all the same size.
        titles: one title per frame.
        path: the PNG to write (parent folders are created).
        columns: frames per row.
        heading: a line (or lines) above the grid: what the frames show, or None.

    Returns:
        ``path``.

    Raises:
        ConfigError: when there are no frames, titles and frames differ in number, or
            columns < 1.
        ShapeError: when frames are not (H, W, 3) of one size.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not frames or len(frames) != len(titles) or columns < 1:
        raise ConfigError(
            f"expected as many titles as frames (> 0) and columns >= 1, got {len(frames)} "
            f"frames, {len(titles)} titles, {columns} columns"
        )
    h, w = frames[0].shape[:2]
    for f in frames:
        if f.shape != (h, w, 3):
            raise ShapeError(f"expected every frame ({h}, {w}, 3), got {f.shape}")
    cols = min(columns, len(frames))
    rows = math.ceil(len(frames) / cols)
    dpi = 100
    top = 0.0 if heading is None else 0.25 * (heading.count("\n") + 1)
    fig = Figure(
        figsize=(cols * w / dpi, rows * (h / dpi + 0.3) + top), dpi=dpi, layout="constrained"
    )
    FigureCanvasAgg(fig)
    if heading is not None:
        fig.suptitle(heading, fontsize=10)
    for i, (frame, title) in enumerate(zip(frames, titles)):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(frame)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
