"""Episode logs: MCAP files with Foxglove-shaped JSON channels (the only package using mcap)."""

from iplanner_torch.recording.mcap import EpisodeWriter, SceneEllipsoid, ellipsoid_pose
from iplanner_torch.recording.reader import Episode, read_episode

__all__ = ["Episode", "EpisodeWriter", "SceneEllipsoid", "ellipsoid_pose", "read_episode"]
