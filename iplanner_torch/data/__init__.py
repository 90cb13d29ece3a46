"""Human motion data: skeleton, demonstrations, synthetic generators, files, windows.

``skeleton`` (joints, segments, bones), ``demonstration`` (the in-memory recording),
``kinematic_human`` (a seated kinematic human), ``reaching`` (the synthetic reaching dataset),
``tasks`` (task orders and task demonstrations), ``io`` (NPZ / CSV files, the LEGO recording),
``windows`` (features, progress states, training windows, splits) and ``datamodule`` (the
Lightning DataModule, imported from its module so that ``lightning`` loads only when needed).
"""

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import load_demonstrations, load_lego_assembly, save_demonstration
from iplanner_torch.data.reaching import (
    BodyParams,
    ReachingCfg,
    generate_reaching_dataset,
    reach_motion,
    rest_pose,
    sample_body,
)
from iplanner_torch.data.tasks import (
    TaskDatasetCfg,
    TaskOrder,
    generate_task_dataset,
    generate_task_demonstration,
    parse_task_order,
)
from iplanner_torch.data.windows import (
    WindowCfg,
    WindowSet,
    build_windows,
    compute_features,
    progress_bitmask,
    split_by_demonstration,
)

__all__ = [
    "BodyParams",
    "Demonstration",
    "ReachingCfg",
    "TaskDatasetCfg",
    "TaskOrder",
    "WindowCfg",
    "WindowSet",
    "build_windows",
    "compute_features",
    "generate_reaching_dataset",
    "generate_task_dataset",
    "generate_task_demonstration",
    "load_demonstrations",
    "load_lego_assembly",
    "parse_task_order",
    "progress_bitmask",
    "reach_motion",
    "rest_pose",
    "sample_body",
    "save_demonstration",
    "split_by_demonstration",
]
