"""iplanner_torch: intention-aware motion planning with learned human motion prediction.

The package is organised by concern (see the README's layout section):
``data`` (skeletons, demonstrations, windows), ``prediction`` (DTW, IVM, sparse GPs, the
human motion predictor), ``robot`` (models, forward kinematics, bounding spheres),
``collision`` (the probabilistic sphere collision bound), ``planning`` (trajectory optimiser,
replanner, task MDP), ``sim`` (MuJoCo scenes and the closed loop), ``eval`` (metrics, reports),
``recording`` (MCAP logs) and ``cli`` (the Hydra entry points, the only place Hydra is used).
"""

__version__ = "0.1.0"


def _load_mujoco_whatever_mujoco_gl_says() -> None:
    """Import MuJoCo once, early, when ``MUJOCO_GL`` is set: MuJoCo reads it on import and
    raises there for a value it does not know (``RuntimeError``) or a backend whose library is
    missing (``MUJOCO_GL=osmesa`` without libOSMesa: PyOpenGL's ``AttributeError``), which made
    every command fail, though only pictures need OpenGL. Then MuJoCo is imported without its
    rendering (``MUJOCO_GL=disable`` for the import alone) and a ``ConfigWarning`` says so;
    the simulation runs, and drawing says what to install (``scripts/render_episode.py``)."""
    import os

    value = os.environ.get("MUJOCO_GL")
    if value is None:
        return
    try:
        import mujoco  # noqa: F401
    except Exception as err:  # noqa: BLE001 - MuJoCo's and PyOpenGL's own errors, named below
        import warnings

        from iplanner_torch.errors import ConfigWarning

        os.environ["MUJOCO_GL"] = "disable"
        try:
            import mujoco  # noqa: F401, F811
        finally:
            os.environ["MUJOCO_GL"] = value
        warnings.warn(
            f"MUJOCO_GL={value!r}: MuJoCo's rendering does not load "
            f"({type(err).__name__}: {err}); the simulation runs without it, but nothing can "
            "be drawn: unset MUJOCO_GL, or set MUJOCO_GL=osmesa (package libosmesa6) or "
            "MUJOCO_GL=egl (libegl-mesa0)",
            ConfigWarning,
            stacklevel=2,
        )


_load_mujoco_whatever_mujoco_gl_says()
