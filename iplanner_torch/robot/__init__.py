"""Robot models: our own URDF / MJCF assets, forward kinematics, bounding spheres, limits.

Entry points: :class:`iplanner_torch.robot.model.RobotModel` (and its ``RobotCfg``),
:func:`iplanner_torch.robot.spheres.fit_link_spheres`; the assets are regenerated from
``description.py`` with ``python -m iplanner_torch.robot.description``.
"""
