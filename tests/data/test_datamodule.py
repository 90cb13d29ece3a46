"""ReachingDataModule on a tiny generated dataset."""

from __future__ import annotations

import pytest
import torch

from iplanner_torch.data.datamodule import ReachingDataModule
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
from iplanner_torch.data.windows import WindowCfg
from iplanner_torch.errors import DataError


def test_setup_and_batches(tmp_path):
    cfg = ReachingCfg(n_targets=4, reaches_per_target=5, speeds=(1.0, 2.0))
    generate_reaching_dataset(cfg, tmp_path, progress=False)
    dm = ReachingDataModule(tmp_path, WindowCfg(n_prev=8, n_future=6), fractions=(0.6, 0.2, 0.2),
                            batch_size=64, seed=1)  # fmt: skip
    dm.setup("fit")
    assert len(dm.demos) == 40
    assert len(dm.train_demos) + len(dm.val_demos) + len(dm.test_demos) == 40
    splits = [{d.name for d in s} for s in (dm.train_demos, dm.val_demos, dm.test_demos)]
    assert not (splits[0] & splits[1] or splits[0] & splits[2] or splits[1] & splits[2])
    assert len(dm.val_windows) > 0 and len(dm.test_windows) > 0
    batches = list(dm.train_dataloader())
    assert sum(b["f_prev"].shape[0] for b in batches) == len(dm.train_windows)
    b = batches[0]
    assert b["f_prev"].shape == (64, 8, 90) and b["xi_next"].shape == (64, 6, 10, 3)
    assert b["current"].dtype == torch.int64 and b["pose_now"].shape == (64, 10, 3)
    # seeded shuffling: the same order twice
    again = next(iter(dm.train_dataloader()))
    torch.testing.assert_close(again["frame_index"], b["frame_index"])
    val = next(iter(dm.val_dataloader()))
    torch.testing.assert_close(val["f_prev"], dm.val_windows.f_prev[:64])


def test_missing_dataset_tells_how_to_generate(tmp_path):
    dm = ReachingDataModule(tmp_path / "nope")
    with pytest.raises(DataError, match="iplanner-data generate"):
        dm.setup()
