import numpy as np
import pytest

from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.prediction_sweep import resample_speed


def _demo(t: int = 31) -> Demonstration:
    frames = np.arange(t, dtype=np.float32)
    clean = np.zeros((t, 2, 3), dtype=np.float32)
    clean[:, 0, 0] = 0.01 * frames  # linear in time
    clean[:, 1, 2] = 0.001 * frames**2  # quadratic in time
    return Demonstration(
        positions=clean + 0.5,
        clean_positions=clean,
        labels=(frames >= 15).astype(np.int64),
        fps=15.0,
        joint_names=("a", "b"),
        action_names=("idle", "move"),
        name="d",
    )


def test_resample_speed_matches_the_time_scaled_motion() -> None:
    demo = _demo()
    fast = resample_speed(demo, 2.0)
    assert fast.num_frames == 16
    k = np.arange(16, dtype=np.float64) * 2.0  # original frame index of each new frame
    np.testing.assert_allclose(fast.clean_positions[:, 0, 0], 0.01 * k, atol=1e-6)
    np.testing.assert_allclose(fast.clean_positions[:, 1, 2], 0.001 * k**2, atol=1e-6)
    # observed positions start as the clean motion (noise is added separately)
    np.testing.assert_array_equal(fast.positions, fast.clean_positions)
    np.testing.assert_array_equal(fast.labels, (k >= 15).astype(np.int64))
    slow = resample_speed(demo, 0.5)
    assert slow.num_frames == 61
    # between frames, linear interpolation of the quadratic: exact at even new frames
    np.testing.assert_allclose(slow.clean_positions[::2, 1, 2], demo.clean_positions[:, 1, 2])


def test_resample_speed_errors() -> None:
    with pytest.raises(ConfigError, match="speed factor"):
        resample_speed(_demo(), 0.0)
    demo = _demo()
    demo.clean_positions = None
    with pytest.raises(DataError, match="clean_positions"):
        resample_speed(demo, 2.0)
