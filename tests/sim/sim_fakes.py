"""Small stand-ins used by the simulation tests: a 3-joint arm and an analytic reaching human.

They implement only the parts of ``RobotModel`` and the reaching generator that ``sim/`` uses,
with MuJoCo's own kinematics of the same MJCF (so planner model and simulation agree).
"""

from __future__ import annotations

import contextlib
import math
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np
import torch

from iplanner_torch.data.skeleton import JOINT_INDEX, JOINT_NAMES, K_UPPER_BODY

FAKE_ARM_XML = """
<mujoco model="fakearm">
  <compiler angle="radian"/>
  <worldbody>
    <body name="fakearm_base">
      <geom type="cylinder" size="0.06 0.05" pos="0 0 0.05"/>
      <body name="link1" pos="0 0 0.1">
        <joint name="j1" type="hinge" axis="0 0 1" range="-3 3" damping="2"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.04"/>
        <body name="link2" pos="0 0 0.3">
          <joint name="j2" type="hinge" axis="0 1 0" range="-2.5 2.5" damping="2"/>
          <geom type="capsule" fromto="0 0 0 0.5 0 0" size="0.035"/>
          <body name="link3" pos="0.5 0 0">
            <joint name="j3" type="hinge" axis="0 1 0" range="-2.8 2.8" damping="2"/>
            <geom type="capsule" fromto="0 0 0 0.45 0 0" size="0.03"/>
            <site name="ee_site" pos="0.45 0 0"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="j1" kp="400" kv="40" ctrlrange="-3 3"/>
    <position joint="j2" kp="400" kv="40" ctrlrange="-2.5 2.5"/>
    <position joint="j3" kp="400" kv="40" ctrlrange="-2.8 2.8"/>
  </actuator>
</mujoco>
"""


class FakeArm:
    """A 3-joint arm with the ``RobotModel`` attributes the simulation uses."""

    name = "fakearm"
    joint_names = ("j1", "j2", "j3")
    num_joints = 3

    def __init__(self, tmp: Path, base_position=(0.7, 0.0, 0.0), base_yaw=math.pi) -> None:
        self.mjcf_path = tmp / "fakearm.xml"
        self.mjcf_path.write_text(FAKE_ARM_XML)
        self.base_position = tuple(base_position)
        self.base_yaw = float(base_yaw)
        spec = mujoco.MjSpec.from_string(FAKE_ARM_XML)
        spec.body("fakearm_base").pos = list(self.base_position)
        c, s = math.cos(0.5 * self.base_yaw), math.sin(0.5 * self.base_yaw)
        spec.body("fakearm_base").quat = [c, 0.0, 0.0, s]
        self._m = spec.compile()
        self._d = mujoco.MjData(self._m)
        self.q_home = torch.tensor([0.0, -0.6, 1.6])
        self.q_min = torch.tensor([-3.0, -2.5, -2.8])
        self.q_max = torch.tensor([3.0, 2.5, 2.8])
        self.v_max = torch.tensor([1.5, 1.5, 1.5])
        self.sphere_radii = torch.tensor([0.04, 0.035, 0.035, 0.03, 0.03])

    def _fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._d.qpos[:] = q
        mujoco.mj_kinematics(self._m, self._d)
        mujoco.mj_comPos(self._m, self._d)
        return self._d.site_xpos[0].copy(), self._d.xpos.copy()

    def ee_position(self, q: torch.Tensor) -> torch.Tensor:
        """(..., 3) tool point [m]."""
        flat = q.reshape(-1, 3).detach().cpu().numpy()
        out = np.stack([self._fk(qi)[0] for qi in flat])
        return torch.as_tensor(out, dtype=q.dtype).reshape(*q.shape[:-1], 3)

    def sphere_centers(self, q: torch.Tensor) -> torch.Tensor:
        """(..., 5, 3): link2 start/mid, link3 start/mid, tool point [m]."""
        flat = q.reshape(-1, 3).detach().cpu().numpy()
        rows = []
        for qi in flat:
            ee, xpos = self._fk(qi)
            l2, l3 = xpos[3], xpos[4]
            rows.append([l2, 0.5 * (l2 + l3), l3, 0.5 * (l3 + ee), ee])
        out = torch.as_tensor(np.asarray(rows), dtype=q.dtype)
        return out.reshape(*q.shape[:-1], 5, 3)

    def ik(self, target: torch.Tensor, q_init: torch.Tensor, iters: int = 200) -> torch.Tensor:
        """Damped least squares on MuJoCo's site Jacobian (position only)."""
        q = q_init.detach().cpu().numpy().astype(np.float64).copy()
        tgt = np.asarray(target, dtype=np.float64)
        jac = np.zeros((3, self._m.nv))
        for _ in range(iters):
            ee, _ = self._fk(q)
            err = tgt - ee
            if np.linalg.norm(err) < 1e-5:
                break
            mujoco.mj_jacSite(self._m, self._d, jac, None, 0)
            dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(3), err)
            q = np.clip(q + dq, self.q_min.numpy(), self.q_max.numpy())
        return torch.as_tensor(q, dtype=q_init.dtype)


def rest_pose() -> np.ndarray:
    """(K, 3) a seated rest pose at x = -0.45 [m]."""
    p = np.zeros((K_UPPER_BODY, 3))
    rows = {
        "head": (-0.45, 0.0, 0.55),
        "neck": (-0.45, 0.0, 0.40),
        "torso": (-0.45, 0.0, 0.15),
        "waist": (-0.45, 0.0, -0.05),
        "left_shoulder": (-0.45, 0.18, 0.38),
        "left_elbow": (-0.42, 0.22, 0.12),
        "left_hand": (-0.22, 0.20, 0.08),
        "right_shoulder": (-0.45, -0.18, 0.38),
        "right_elbow": (-0.42, -0.22, 0.12),
        "right_hand": (-0.22, -0.20, 0.08),
    }
    for name, xyz in rows.items():
        p[JOINT_INDEX[name]] = xyz
    return p


class FakeMotion:
    """Minimum-jerk hand reach with the elbow halfway, hold, and return (``MotionSource``)."""

    fps = 30.0

    def rest_pose(self) -> np.ndarray:
        return rest_pose()

    def reach(self, arm, target, rng, *, speed, hold_s, start_pose) -> np.ndarray:
        hand, elbow, shoulder = (JOINT_INDEX[f"{arm}_{n}"] for n in ("hand", "elbow", "shoulder"))
        move_s = float(np.linalg.norm(target - start_pose[hand])) / (0.5 * speed) + 0.2
        n = max(2, int(round(move_s * self.fps)))
        s = np.linspace(0.0, 1.0, n)
        s = 10 * s**3 - 15 * s**4 + 6 * s**5
        hold = max(1, int(round(hold_s * self.fps)))
        prof = np.concatenate([s, np.ones(hold), s[::-1]])
        frames = np.repeat(start_pose[None], prof.size, axis=0)
        hand_path = start_pose[hand] + prof[:, None] * (np.asarray(target) - start_pose[hand])
        frames[:, hand] = hand_path
        frames[:, elbow] = 0.5 * (hand_path + start_pose[shoulder]) - [0.0, 0.0, 0.08]
        return frames


def fake_solo_duration(order, far, targets, *, speed: float, hold_s: float, idle_s) -> float:
    """The human-alone time in closed form for :class:`FakeMotion` (reach out, hold, back to
    the rest pose: 2 n + hold frames, n from the distance to the hand on the target's side)."""
    rest, fps = rest_pose(), FakeMotion.fps
    total = 0.0
    for i in order:
        for target in (far[i], targets[i]):
            hand = rest[JOINT_INDEX["left_hand" if target[1] > 0 else "right_hand"]]
            move_s = float(np.linalg.norm(target - hand)) / (0.5 * speed) + 0.2
            n = max(2, round(move_s * fps))
            total += (2 * n + max(1, round(hold_s * fps)) - 1) / fps
        total += 0.5 * (idle_s[0] + idle_s[1])
    return total


class FakeOrder:
    """A fixed sequential task order."""

    def __init__(self, ids) -> None:
        self.ids = [int(i) for i in ids]

    def sample(self, rng) -> list[int]:
        return list(self.ids)

    def allowed_next(self, done) -> set[int]:
        rest = [i for i in self.ids if i not in done]
        return {rest[0]} if rest else set()


class LinearReplanner:
    """A stand-in replanner: straight joint-space motion to the goal at a fixed speed."""

    def __init__(self, speed: float = 1.0) -> None:
        self.speed = speed
        self.stats = type(
            "Stats",
            (),
            {
                "cycles": 0,
                "overruns": 0,
                "waits": 0,
                "wait_s": 0.0,
                "solve_ms": [],
                "mean_solve_ms": 0.0,
            },
        )()
        self.forecasts = []

    def reset(self, q_start, q_goal, t) -> None:
        self.q = q_start.clone()
        self.goal = q_goal.clone()
        self.t = t

    def set_goal(self, q_goal, t=None) -> None:
        self.goal = q_goal.clone()

    def step(self, t, q_now, forecast, *, forecast_t0):
        self.stats.cycles += 1
        self.forecasts.append((t, forecast))
        return None

    def command(self, t):
        dt = max(0.0, t - self.t)
        self.t = t
        err = self.goal - self.q
        n = float(err.abs().max())
        v = torch.zeros_like(err)
        if n > 1e-9:
            v = err / n * self.speed
            self.q = self.q + err * min(1.0, self.speed * dt / n)
        if float((self.goal - self.q).abs().max()) < 1e-9:
            v = torch.zeros_like(err)
        return self.q.clone(), v


class ConstantPredictor:
    """A stand-in predictor: the last observed pose held over the horizon, two actions."""

    n_p = 15
    action_names = ("reach_0", "reach_1")

    def __init__(self) -> None:
        self.calls = []

    def predict_positions(self, positions, progress):
        from iplanner_torch.prediction.forecast import Forecast

        self.calls.append((positions.clone(), progress.clone()))
        last = torch.nan_to_num(positions[:, -1], nan=0.0)  # (B, K, 3)
        b, k = last.shape[:2]
        mean = last[:, None, None].expand(b, 2, 20, k, 3).clone()
        return Forecast(
            weights=torch.full((b, 2), 0.5),
            mean=mean,
            var=torch.full_like(mean, 1e-4),
            dt=0.1,
            joint_names=tuple(JOINT_NAMES),
            action_names=self.action_names,
        )


@contextlib.contextmanager
def deadline(seconds: float) -> Iterator[None]:
    """Raise ``TimeoutError`` inside the block once it has run ``seconds`` (a hang becomes a
    test failure). Needs SIGALRM and the main thread; elsewhere the block just runs."""
    if (
        not hasattr(signal, "setitimer")
        or threading.current_thread() is not threading.main_thread()
    ):
        yield
        return

    def _expire(signum: int, frame: object) -> None:
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, _expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
