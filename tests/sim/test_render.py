"""Offscreen rendering of the workspace; skipped where no GL backend loads."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.robot.model import RobotModel
from iplanner_torch.sim.human import ReachingMotionSource
from iplanner_torch.sim.render import (
    CAMERAS,
    SceneRenderer,
    gl_available,
    save_contact_sheet,
)
from iplanner_torch.sim.scene import SceneCfg, SceneHandles, build_scene, pose_human

needs_gl = pytest.mark.skipif(
    not gl_available(), reason="no OpenGL backend (libosmesa6 or libegl-mesa0)"
)

W, H = 320, 240


class Workspace:
    """The default scene (1x4, iiwa at its default base, human at rest)."""

    def __init__(self) -> None:
        self.cfg = SceneCfg()
        self.robot = RobotModel.load("kuka_iiwa14", dtype=torch.float64)
        self.model = build_scene(self.cfg, self.robot)
        self.data = mujoco.MjData(self.model)
        self.handles = SceneHandles.resolve(self.model, self.cfg, self.robot)
        self.rest = ReachingMotionSource(0, seat_x=self.cfg.human_seat_x).rest_pose()
        self.set_q(self.robot.q_home.numpy())

    def set_q(self, q: np.ndarray) -> None:
        self.data.qpos[self.handles.qpos_adr] = q
        pose_human(self.model, self.data, self.handles, self.rest)
        mujoco.mj_forward(self.model, self.data)

    def ee(self) -> np.ndarray:
        return self.data.site_xpos[self.handles.ee_site].copy()


@pytest.fixture(scope="module")
def ws() -> Workspace:
    return Workspace()


@pytest.fixture(scope="module")
def renderer(ws: Workspace) -> Iterator[SceneRenderer]:
    with SceneRenderer(ws.model, width=W, height=H) as r:
        yield r


def project(point: np.ndarray, camera: str, fovy_deg: float) -> tuple[float, float]:
    """Pinhole projection of a world point (3,) [m] through a named free camera.

    Returns (column, row) in pixels, row 0 at the top.
    """
    lookat, distance, az, el = CAMERAS[camera]
    az, el = math.radians(az), math.radians(el)
    fwd = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    pos = np.asarray(lookat) - distance * fwd
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    v = point - pos
    focal = 0.5 * H / math.tan(math.radians(fovy_deg) / 2)
    depth = v @ fwd
    return 0.5 * W + focal * (v @ right) / depth, 0.5 * H - focal * (v @ up) / depth


@needs_gl
@pytest.mark.parametrize("camera", ["overview", "side", "top"])
def test_default_scene_is_not_blank_and_deterministic(
    ws: Workspace, renderer: SceneRenderer, camera: str
) -> None:
    ws.set_q(ws.robot.q_home.numpy())
    a = renderer.render(ws.data, camera=camera)
    assert a.shape == (H, W, 3) and a.dtype == np.uint8
    assert a.std() > 20.0
    # several distinct colours (table, human, robot, floor), not a flat fill
    assert len(np.unique(a.reshape(-1, 3) // 32, axis=0)) >= 8
    np.testing.assert_array_equal(renderer.render(ws.data, camera=camera), a)


@needs_gl
def test_robot_region_changes_when_the_robot_moves(ws: Workspace, renderer: SceneRenderer) -> None:
    fovy = ws.model.vis.global_.fovy
    q_a = ws.robot.q_home.numpy().copy()
    q_b = q_a.copy()
    q_b[0] += 0.9  # swing the arm about its base axis
    ws.set_q(q_a)
    ee_a = ws.ee()
    img_a = renderer.render(ws.data, camera="overview").astype(int)
    ws.set_q(q_b)
    ee_b = ws.ee()
    img_b = renderer.render(ws.data, camera="overview").astype(int)
    ws.set_q(q_a)
    assert np.linalg.norm(ee_a - ee_b) > 0.2
    changed = np.abs(img_a - img_b).sum(axis=2) > 30  # (H, W)
    assert 0.005 < changed.mean() < 0.5
    # the tool point, projected with an independent pinhole model, lies in changed pixels at
    # both poses (the arm left its old place and appears at the new one)
    for ee in (ee_a, ee_b):
        col, row = project(ee, "overview", fovy)
        assert 0 <= col < W and 0 <= row < H
        r0, c0 = int(round(row)), int(round(col))
        window = changed[max(r0 - 8, 0) : r0 + 9, max(c0 - 8, 0) : c0 + 9]
        assert window.mean() > 0.2
    # the human (torso) does not move, so its pixels do not change
    col, row = project(ws.rest[2], "overview", fovy)
    r0, c0 = int(round(row)), int(round(col))
    assert not changed[r0 - 3 : r0 + 4, c0 - 3 : c0 + 4].any()


@needs_gl
def test_overlay_sphere_lands_at_its_projection(ws: Workspace, renderer: SceneRenderer) -> None:
    centre = np.array([0.2, -0.3, 0.25])
    col, row = project(centre, "side", ws.model.vis.global_.fovy)
    plain = renderer.render(ws.data, camera="side")
    red = renderer.render(
        ws.data,
        camera="side",
        spheres=[(centre[None], np.array([0.06]), (1.0, 0.0, 0.0, 1.0))],
    )
    px = red[int(round(row)), int(round(col))].astype(int)
    assert px[0] > 150 and px[0] > px[1] + 80 and px[0] > px[2] + 80
    assert not np.array_equal(plain, red)
    # nothing drawn for an empty group; NaN centres are skipped
    nan_group = (np.full((1, 3), np.nan), np.array([0.1]), (1.0, 0.0, 0.0, 1.0))
    np.testing.assert_array_equal(
        renderer.render(ws.data, camera="side", spheres=[nan_group]), plain
    )


@needs_gl
def test_render_errors(ws: Workspace, renderer: SceneRenderer) -> None:
    with pytest.raises(ConfigError, match="expected camera in"):
        renderer.render(ws.data, camera="front")  # type: ignore[arg-type]
    with pytest.raises(ShapeError, match=r"expected overlay centres \(S, 3\)"):
        renderer.render(ws.data, spheres=[(np.zeros((2, 2)), np.ones(2), (1, 0, 0, 1))])
    with pytest.raises(ConfigError, match="overlay spheres"):
        many = np.zeros((renderer.scene.maxgeom, 3))
        renderer.render(ws.data, spheres=[(many, np.ones(len(many)), (1, 0, 0, 1))])
    with pytest.raises(ConfigError, match="expected width an integer >= 1"):
        SceneRenderer(ws.model, width=0)
    for bad in ("x", 1.5, None):  # "x" and None raised a bare TypeError; 1.5 was accepted
        with pytest.raises(ConfigError, match="expected height an integer"):
            SceneRenderer(ws.model, height=bad)  # type: ignore[arg-type]
    r = SceneRenderer(ws.model, width=32, height=24)
    r.close()
    r.close()  # idempotent
    with pytest.raises(ConfigError, match="closed"):
        r.render(ws.data)


@needs_gl
def test_large_image_and_model_untouched(ws: Workspace) -> None:
    offwidth = ws.model.vis.global_.offwidth
    with SceneRenderer(ws.model, width=offwidth + 160, height=120) as r:
        assert r.render(ws.data, camera="top").shape == (120, offwidth + 160, 3)
    assert ws.model.vis.global_.offwidth == offwidth


def test_contact_sheet(tmp_path: Path) -> None:
    import matplotlib.image

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (60, 80, 3), dtype=np.uint8) for _ in range(4)]
    path = save_contact_sheet(frames, ["a", "b", "c", "d"], tmp_path / "s" / "sheet.png")
    img = matplotlib.image.imread(path)
    assert img.shape[1] == 3 * 80 and img.shape[0] >= 2 * 60
    # a heading of two lines takes room of its own above the frames (0.25 in a line)
    headed = save_contact_sheet(frames, ["a", "b", "c", "d"], tmp_path / "h.png",
                                heading="planner · seed 0\nred: the robot's spheres")  # fmt: skip
    assert matplotlib.image.imread(headed).shape[0] == img.shape[0] + 50
    with pytest.raises(ConfigError, match="as many titles as frames"):
        save_contact_sheet(frames, ["a"], tmp_path / "x.png")
    with pytest.raises(ShapeError, match=r"expected every frame \(60, 80, 3\)"):
        save_contact_sheet([frames[0], frames[1][:30]], ["a", "b"], tmp_path / "x.png")


def test_headless_backend_names_only_an_installed_library(monkeypatch) -> None:
    """osmesa when libOSMesa is found, else egl when libEGL is, else nothing."""
    import ctypes.util

    from iplanner_torch.sim import render

    def finder(present: set[str]):
        return lambda name: f"lib{name}.so" if name in present else None

    monkeypatch.setattr(ctypes.util, "find_library", finder({"OSMesa", "EGL"}))
    assert render._headless_backend() == "osmesa"
    monkeypatch.setattr(ctypes.util, "find_library", finder({"EGL"}))
    assert render._headless_backend() == "egl"
    monkeypatch.setattr(ctypes.util, "find_library", finder(set()))
    assert render._headless_backend() is None


def test_importing_the_renderer_leaves_mujoco_importable_in_child_processes() -> None:
    """The backend this module picks without a display is inherited by child processes, where
    ``import mujoco`` loads it: it must be one this machine has."""
    import os
    import subprocess
    import sys

    env = {
        k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")
    }
    code = (
        "import os, subprocess, sys; import iplanner_torch.sim.render; "
        "r = subprocess.run([sys.executable, '-c', 'import mujoco'], capture_output=True, "
        "text=True); print(os.environ.get('MUJOCO_GL')); sys.stderr.write(r.stderr); "
        "sys.exit(r.returncode)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr[-2000:]
