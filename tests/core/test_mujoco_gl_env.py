"""A MUJOCO_GL that MuJoCo's rendering cannot load (a value it does not know, or a backend
whose library is missing) used to make ``import mujoco`` raise, and with it every command,
though only pictures need OpenGL: the package now loads MuJoCo without its rendering, says so
once, and the simulation runs."""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys

import pytest

SIMULATE = (
    "import iplanner_torch.sim.env\nimport mujoco\n"
    "m = mujoco.MjModel.from_xml_string("
    "'<mujoco><worldbody><body><freejoint/><geom size=\"0.1\"/></body></worldbody></mujoco>')\n"
    "d = mujoco.MjData(m)\n"
    "mujoco.mj_step(m, d)\n"
    "print('z', d.qpos[2] < 0)\n"
)


def _run(value: str) -> subprocess.CompletedProcess:
    # PyOpenGL's platform as this process may have set it (MuJoCo's EGL module sets it when
    # loaded) would make MuJoCo skip a missing OSMesa quietly
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    env["MUJOCO_GL"] = value
    return subprocess.run(
        [sys.executable, "-c", SIMULATE], env=env, capture_output=True, text=True, timeout=120
    )


def test_an_unknown_mujoco_gl_leaves_the_simulation_running_with_a_warning() -> None:
    res = _run("bogus")
    assert res.returncode == 0, res.stderr
    assert "z True" in res.stdout  # the body fell: MuJoCo simulates
    assert "ConfigWarning: MUJOCO_GL='bogus': MuJoCo's rendering does not load" in res.stderr
    assert res.stderr.count("ConfigWarning") == 1
    assert "libosmesa6" in res.stderr


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is not None, reason="libOSMesa present")
def test_osmesa_without_its_library_leaves_the_simulation_running() -> None:
    res = _run("osmesa")
    assert res.returncode == 0, res.stderr
    assert "z True" in res.stdout
    assert "MUJOCO_GL='osmesa'" in res.stderr


def test_mujoco_gl_disable_is_quiet() -> None:
    res = _run("disable")
    assert res.returncode == 0, res.stderr
    assert "ConfigWarning" not in res.stderr
