"""iplanner_torch: intention-aware motion planning with learned human motion prediction.

The package is organised by concern (see the README's layout section):
``data`` (skeletons, demonstrations, windows), ``prediction`` (DTW, IVM, sparse GPs, the
human motion predictor), ``robot`` (models, forward kinematics, bounding spheres),
``collision`` (the probabilistic sphere collision bound), ``planning`` (trajectory optimiser,
replanner, task MDP), ``sim`` (MuJoCo scenes and the closed loop), ``eval`` (metrics, reports),
``recording`` (MCAP logs) and ``cli`` (the Hydra entry points, the only place Hydra is used).
"""

__version__ = "0.1.0"
