"""Pictures of the simulated workspace and of recorded closed-loop episodes.

Scene mode: the default workspace for both robots and the three block arrangements, each from
the overview, side and top cameras, as one contact sheet::

    python scripts/render_episode.py --scene                  # experiments/scenes/overview.png

Episode mode: replay an episode log (robot joint positions, true human joints, blocks moved
as the task events say) and draw N snapshots evenly spaced in time; ``--video`` also writes an
animation (GIF with Pillow, or MP4 when imageio with ffmpeg is installed)::

    python scripts/render_episode.py --mcap runs/ep.mcap --frames 6 --camera overview \
        --overlay --video runs/ep.gif                     # runs/ep.frames.png, runs/ep.gif

The episode's sheet goes beside its log as ``<log stem>.frames.png`` by default (the
``<log stem>.png`` there is the episode's timeline plot, ``plot_episode.py``). A file that
exists already (the sheet, the video, the scene's record) is replaced only with ``--force``.

Rendering needs a GL backend: ``MUJOCO_GL=osmesa`` (package libosmesa6) or ``MUJOCO_GL=egl``
(Mesa's software EGL, package libegl-mesa0, or a GPU driver); without a display, the one
installed is picked when the variable is unset.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

# first: the package loads MuJoCo whatever MUJOCO_GL says (a backend whose library is missing
# made ``import mujoco`` raise before this script could say what to install)
import iplanner_torch  # noqa: F401

# isort: split
import mujoco
import numpy as np
import torch
from _report import fail, main_guard, refuse_existing
from matplotlib.backend_bases import FigureCanvasBase

from iplanner_torch.data.skeleton import JOINT_INDEX
from iplanner_torch.eval.report import PLANNERS
from iplanner_torch.recording import Episode, read_episode
from iplanner_torch.robot.model import RobotModel
from iplanner_torch.sim.human import ReachingMotionSource
from iplanner_torch.sim.render import (
    HUMAN_SPHERE_RGBA,
    ROBOT_SPHERE_RGBA,
    SceneRenderer,
    gl_available,
    save_contact_sheet,
)
from iplanner_torch.sim.scene import SceneCfg, SceneHandles, build_scene, pose_human

ROOT = Path(__file__).resolve().parents[1]
CAMERA_NAMES = ("overview", "side", "top")
VIDEO_SUFFIXES = (".gif", ".mp4")


@dataclass
class Workspace:
    """A compiled scene with its state, handles and robot."""

    cfg: SceneCfg
    robot: RobotModel
    model: mujoco.MjModel
    data: mujoco.MjData
    handles: SceneHandles

    @classmethod
    def build(cls, robot_name: str, arrangement: str) -> Workspace:
        cfg = SceneCfg(arrangement=arrangement)  # type: ignore[arg-type]
        robot = RobotModel.load(robot_name, dtype=torch.float64)
        model = build_scene(cfg, robot)
        data = mujoco.MjData(model)
        return cls(cfg, robot, model, data, SceneHandles.resolve(model, cfg, robot))

    def pose(self, q: np.ndarray, human: np.ndarray) -> None:
        """Set robot joints (J,) [rad] and human joints (K, 3) [m], then update the state."""
        self.data.qpos[self.handles.qpos_adr] = q
        pose_human(self.model, self.data, self.handles, human)
        mujoco.mj_forward(self.model, self.data)

    def ee(self) -> np.ndarray:
        """(3,) tool point [m] of the current robot pose."""
        if self.handles.ee_site >= 0:
            return self.data.site_xpos[self.handles.ee_site].copy()
        q = torch.as_tensor(self.data.qpos[self.handles.qpos_adr], dtype=torch.float64)
        return self.robot.ee_position(q).numpy()

    def robot_spheres(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounding spheres of the robot at q: centres (S_r, 3) [m], radii (S_r,) [m]."""
        c = self.robot.sphere_centers(torch.as_tensor(q, dtype=torch.float64))
        return c.numpy(), self.robot.sphere_radii.numpy()


def render_scene_sheet(out: Path, width: int, height: int) -> Path:
    """Both robots x three arrangements, each from every camera, at home / rest poses."""
    frames, titles = [], []
    for robot_name in ("kuka_iiwa14", "fetch"):
        for arrangement in ("1x4", "2x2", "2x4"):
            ws = Workspace.build(robot_name, arrangement)
            rest = ReachingMotionSource(0, seat_x=ws.cfg.human_seat_x).rest_pose()
            ws.pose(ws.robot.q_home.numpy(), rest)
            with SceneRenderer(ws.model, width=width, height=height) as r:
                for cam in CAMERA_NAMES:
                    frames.append(r.render(ws.data, camera=cam))
                    titles.append(f"{robot_name}, {arrangement}, {cam}")
    return save_contact_sheet(frames, titles, out, columns=len(CAMERA_NAMES))


class BlockReplay:
    """Block positions over time from the task events (as the environment moves them)."""

    def __init__(self, ws: Workspace, events: list[dict], q_of_t, human_of_t) -> None:
        self.ws = ws
        self.timeline: dict[int, list[tuple[float, str, np.ndarray | None]]] = {
            i: [(-np.inf, "far", None)] for i in ws.cfg.block_ids
        }
        for e in events:
            detail = e.get("detail") or {}
            block = detail.get("block") if isinstance(detail, dict) else None
            if block not in self.timeline:
                continue
            t, kind = float(e["t"]), e["kind"]
            if kind == "picked":
                ws.pose(q_of_t(t), human_of_t(t))
                self.timeline[block].append((t, "robot", ws.cfg.block_position(block) - ws.ee()))
            elif kind == "delivered":
                self.timeline[block].append((t, "delivered", None))
            elif kind == "human_grasped":
                hand = self._hand(block)
                self.timeline[block].append((t, "human", np.array([hand])))
            elif kind == "human_took":
                self.timeline[block].append((t, "taken", None))

    def _hand(self, block: int) -> int:
        side = "left" if self.ws.cfg.delivery_position(block)[1] > 0 else "right"
        return JOINT_INDEX[f"{side}_hand"]

    def apply(self, t: float, human: np.ndarray) -> None:
        """Move the block mocap bodies to time t (robot kinematics already at t)."""
        ws = self.ws
        for block, line in self.timeline.items():
            _, state, extra = [s for s in line if s[0] <= t][-1]
            if state == "far":
                pos = ws.cfg.block_position(block)
            elif state == "robot":
                pos = ws.ee() + extra
            elif state == "delivered":
                pos = ws.cfg.delivery_position(block)
            elif state == "human":
                pos = human[int(extra[0])] - np.array([0.0, 0.0, 0.02])
            else:
                pos = ws.cfg.stash_position(block)
            ws.data.mocap_pos[ws.handles.block_mocap[block]] = pos


def render_episode(
    ep: Episode,
    out: Path,
    *,
    frames: int,
    camera: str,
    overlay: bool,
    robot_name: str | None,
    width: int,
    height: int,
    video: Path | None,
    video_fps: float,
) -> list[Path]:
    """Contact sheet of ``frames`` snapshots of an episode log (and optionally a video)."""
    meta = ep.metadata
    logged = meta.get("robot")
    name = robot_name or logged
    known = RobotModel.available()
    if name is None:
        fail(f"{ep.path} names no robot; use --robot (one of {known})")
    if name not in known:
        fail(f"robot {name!r} of {ep.path} is not one of {known}; use --robot")
    if robot_name and logged and robot_name != logged:
        print(
            f"warning: --robot {robot_name} differs from the log's robot {logged}", file=sys.stderr
        )
    ws = Workspace.build(name, meta.get("arrangement", "1x4"))
    t_q, q = (x.numpy() for x in ep.robot_q())
    t_h, h = (x.numpy() for x in ep.human_true())
    if q.shape[1] != ws.robot.num_joints:
        fail(f"{ep.path} has {q.shape[1]} joints, {name} has {ws.robot.num_joints}")

    def q_of_t(t: float) -> np.ndarray:
        return np.stack([np.interp(t, t_q, q[:, j]) for j in range(q.shape[1])])

    def human_of_t(t: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(t_h, t), 0, len(t_h) - 1))
        return h[i]

    blocks = BlockReplay(ws, ep.events(), q_of_t, human_of_t)
    forecasts = _forecasts(ep) if overlay else None
    t0, t1 = float(max(t_q[0], t_h[0])), float(min(t_q[-1], t_h[-1]))

    def snapshot(r: SceneRenderer, t: float, cam: str) -> np.ndarray:
        qt, ht = q_of_t(t), human_of_t(t)
        ws.pose(qt, ht)
        blocks.apply(t, ht)
        mujoco.mj_forward(ws.model, ws.data)
        spheres = []
        if overlay:
            c, rad = ws.robot_spheres(qt)
            spheres.append((c, rad, ROBOT_SPHERE_RGBA))
            if forecasts is not None:
                spheres.append(_predicted_joints(forecasts, t))
        return r.render(ws.data, camera=cam, spheres=spheres)  # type: ignore[arg-type]

    written = []
    times = np.linspace(t0, t1, frames)
    heading = " · ".join(
        str(v)
        for v in (
            PLANNERS.get(str(meta.get("planner")), meta.get("planner")),
            meta.get("scenario"),
            f"seed {meta['seed']}" if "seed" in meta else None,
            Path(ep.path).name,
        )
        if v is not None
    )
    if overlay:
        heading += "\nred: the robot's spheres" + (
            "; blue: the latest forecast's joints at the end of its horizon (most likely "
            "action), radius 4 cm + 2 std"
            if forecasts is not None
            else ""
        )
    # rows without blank tiles where the count allows: 4 frames in one row, 6 in two of 3
    columns = frames if frames <= 4 else (4 if frames % 4 == 0 else 3)
    with SceneRenderer(ws.model, width=width, height=height) as r:
        shots = [snapshot(r, float(t), camera) for t in times]
        written.append(
            save_contact_sheet(
                shots, [f"t = {t:.2f} s" for t in times], out, columns=columns, heading=heading
            )
        )
        if video is not None:
            n = max(2, int((t1 - t0) * video_fps) + 1)
            anim = [snapshot(r, float(t), camera) for t in np.linspace(t0, t1, n)]
            written.append(_write_video(anim, video, video_fps))
    return written


def _forecasts(ep: Episode) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t (T,), most likely action's last predicted joints (T, K, 3), their std (T, K))."""
    try:
        t, fc = ep.forecasts()
    except Exception:  # no forecasts in this log (e.g. ITOMP)
        return None
    best = fc.weights.argmax(dim=1)  # (T,)
    idx = torch.arange(len(best))
    mean = fc.mean[idx, best, -1]  # (T, K, 3)
    std = fc.var[idx, best, -1].clamp_min(0).sqrt().mean(dim=-1)  # (T, K)
    return t.numpy(), mean.double().numpy(), std.double().numpy()


def _predicted_joints(forecasts, t: float) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Overlay group of the latest forecast before t: joints at the end of its horizon."""
    t_f, mean, std = forecasts
    i = int(np.searchsorted(t_f, t, side="right")) - 1
    if i < 0:
        return np.zeros((0, 3)), np.zeros(0), HUMAN_SPHERE_RGBA
    return mean[i], 0.04 + 2.0 * std[i], HUMAN_SPHERE_RGBA


def _write_video(frames: list[np.ndarray], path: Path, fps: float) -> Path:
    """``frames`` as an MP4 (imageio) or a GIF (Pillow); an ``.mp4`` without imageio was
    made a ``.gif`` by :func:`_check_args`, before any frame was rendered."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".mp4":
        import imageio.v3 as iio

        iio.imwrite(path, np.stack(frames), fps=fps)
        return path
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path


def _check_args(args: argparse.Namespace) -> argparse.Namespace:
    """Refuse settings that would fail only after every frame was rendered; give ``--out``
    without a suffix the PNG one (so the path printed is the one written)."""
    if args.frames < 1:
        fail(f"--frames must be >= 1, got {args.frames}")
    for flag in ("width", "height"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            fail(f"--{flag} must be >= 1 pixel, got {getattr(args, flag)}")
    if not (math.isfinite(args.fps) and args.fps > 0):
        fail(f"--fps must be a finite number > 0, got {args.fps}")
    if args.video is not None and args.video.suffix.lower() not in VIDEO_SUFFIXES:
        fail(f"--video {args.video}: give a file ending in {' or '.join(VIDEO_SUFFIXES)}")
    if args.scene:  # the contact sheet of the workspaces: the episode settings have no use
        unused = [
            flag
            for flag, given in (
                ("--video", args.video is not None),
                ("--overlay", args.overlay),
                ("--robot", args.robot is not None),
                ("--frames", args.frames != 6),
                ("--camera", args.camera != "overview"),
                ("--fps", args.fps != 10.0),
            )
            if given
        ]
        if unused:
            fail(f"{', '.join(unused)}: for an episode (--mcap); --scene draws every camera")
    if args.out is not None and args.out.is_dir():
        fail(f"--out {args.out} is a folder; give the image file to write")
    if args.out is not None:
        if args.out.suffix == "":
            args.out = args.out.with_suffix(".png")
        image_types = FigureCanvasBase.get_supported_filetypes()
        if args.out.suffix.lower().lstrip(".") not in image_types:
            fail(f"--out {args.out}: not an image type ({', '.join(sorted(image_types))})")
    elif args.scene:
        args.out = SCENE_RECORD
    else:
        args.out = frames_path(args.mcap)
    if args.video is not None and args.video.suffix.lower() == ".mp4" and not _has_imageio():
        args.video = args.video.with_suffix(".gif")
        print(f"imageio is not installed: writing {args.video} instead of an MP4")
    refuse_existing((args.out, args.video), args.force, "choose another --out or --video")
    return args


#: the scene mode's default output: the record of experiments/scenes/
SCENE_RECORD = ROOT / "experiments" / "scenes" / "overview.png"


def frames_path(log: Path) -> Path:
    """The default snapshot sheet of an episode log: beside it, ``<log stem>.frames.png``
    (``<log stem>.png`` is its timeline plot,
    :func:`iplanner_torch.eval.timeline.timeline_path`)."""
    return log.with_name(f"{log.stem}.frames.png")


def _has_imageio() -> bool:
    """Whether imageio, which writes MP4 files, can be imported."""
    try:
        import imageio.v3  # noqa: F401
    except ImportError:
        return False
    return True


@main_guard
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--scene", action="store_true", help="contact sheet of the workspaces")
    mode.add_argument("--mcap", type=Path, help="episode log to replay")
    parser.add_argument(
        "--out", type=Path, help="PNG to write (scene: the record; episode: <log>.frames.png)"
    )
    parser.add_argument("--frames", type=int, default=6, help="snapshots of an episode")
    parser.add_argument("--camera", choices=CAMERA_NAMES, default="overview")
    parser.add_argument("--overlay", action="store_true", help="draw robot / predicted spheres")
    parser.add_argument("--robot", help="robot name when the log's is not a known robot")
    parser.add_argument("--video", type=Path, help="also write an animation (.gif or .mp4)")
    parser.add_argument("--fps", type=float, default=10.0, help="animation frame rate")
    parser.add_argument("--width", type=int, help="image width [px] (scene 480, episode 640)")
    parser.add_argument("--height", type=int, help="image height [px] (scene 360, episode 480)")
    parser.add_argument("--force", action="store_true", help="replace existing output files")
    args = _check_args(parser.parse_args(argv))
    ep = None if args.scene else read_episode(args.mcap)
    if ep is not None and not ep.frames:
        cut = "" if ep.complete else " (truncated or damaged)"
        fail(f"{args.mcap}: the log has no messages{cut}; nothing to render")
    if not gl_available():
        fail(
            "no OpenGL backend loads: install libosmesa6 (MUJOCO_GL=osmesa) or libegl-mesa0 "
            "(MUJOCO_GL=egl)"
        )
    if ep is None:
        written = [render_scene_sheet(args.out, args.width or 480, args.height or 360)]
    else:
        written = render_episode(
            ep,
            args.out,
            frames=args.frames,
            camera=args.camera,
            overlay=args.overlay,
            robot_name=args.robot,
            width=args.width or 640,
            height=args.height or 480,
            video=args.video,
            video_fps=args.fps,
        )
    for p in written:
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
