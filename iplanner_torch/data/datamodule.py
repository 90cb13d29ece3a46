"""Lightning DataModule over demonstration windows (paper sec. 4.1 training tuples)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import lightning as L
import torch
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from iplanner_torch import checks
from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.windows import (
    DEFAULT_SPLIT,
    WindowCfg,
    WindowSet,
    build_windows,
    check_split_fractions,
    split_by_demonstration,
)
from iplanner_torch.errors import ConfigError, DataError


class _WindowBatches(Dataset):
    """Indexable by a list of window indices; returns a dict of batched tensors."""

    def __init__(self, windows: WindowSet) -> None:
        self.windows = windows

    def __len__(self) -> int:
        return len(self.windows)

    def __getitem__(self, index: list[int]) -> dict[str, torch.Tensor]:
        return self.windows.batch(torch.as_tensor(index, dtype=torch.int64))


class ReachingDataModule(L.LightningDataModule):
    """Loads demonstrations, splits them by demonstration and serves window batches.

    Batches are dicts with the :class:`WindowSet` tensors: ``f_prev`` (B, n_p, D),
    ``progress``, ``current``, ``next_action`` (B,), ``xi_next`` (B, n_f, K, 3), ``pose_now``
    (B, K, 3), ``demo_index``, ``frame_index`` (B,); ``demo_index`` indexes the split's own
    list (``train_demos``, ``val_demos``, ``test_demos``).

    Args:
        data: a dataset folder or file (see :func:`load_demonstrations`), or demonstrations.
        window_cfg: window settings (default :class:`WindowCfg`).
        fractions: (train, val, test) fractions of demonstrations.
        batch_size: windows per batch.
        seed: split and shuffling seed, an integer in [0, 2^32 - 1].
        fps: frame rate for files that do not state one.
        num_workers: DataLoader workers (0 keeps everything in-process).
    """

    def __init__(
        self,
        data: str | Path | Sequence[Demonstration],
        window_cfg: WindowCfg | None = None,
        *,
        fractions: tuple[float, float, float] = DEFAULT_SPLIT,
        batch_size: int = 256,
        seed: int = 0,
        fps: float | None = None,
        num_workers: int = 0,
    ) -> None:
        super().__init__()
        if batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1, got {batch_size}")
        self.data = data
        self.window_cfg = window_cfg or WindowCfg()
        self.fractions = check_split_fractions(fractions)
        self.batch_size = int(batch_size)
        self.seed = checks.seed(seed)
        self.fps = fps
        self.num_workers = int(num_workers)
        self.demos: list[Demonstration] = []
        self.train_demos: list[Demonstration] = []
        self.val_demos: list[Demonstration] = []
        self.test_demos: list[Demonstration] = []
        self.train_windows: WindowSet | None = None
        self.val_windows: WindowSet | None = None
        self.test_windows: WindowSet | None = None

    def _load(self) -> list[Demonstration]:
        if isinstance(self.data, (str, Path)):
            path = Path(self.data)
            if not path.exists():
                raise DataError(
                    f"{path}: dataset not found; generate it first with `iplanner-data "
                    "generate` (or iplanner_torch.data.reaching.generate_reaching_dataset)"
                )
            return load_demonstrations(path, fps=self.fps, joints=self.window_cfg.joints)
        return list(self.data)

    def setup(self, stage: str | None = None) -> None:
        """Load, split by demonstration and build the three window sets (once)."""
        if self.train_windows is not None:
            return
        self.demos = self._load()
        self.train_demos, self.val_demos, self.test_demos = split_by_demonstration(
            self.demos, self.fractions, self.seed
        )
        self.train_windows = build_windows(self.train_demos, self.window_cfg)
        none = torch.zeros(0, dtype=torch.int64)
        self.val_windows = (
            build_windows(self.val_demos, self.window_cfg)
            if self.val_demos
            else self.train_windows.subset(none)
        )
        self.test_windows = (
            build_windows(self.test_demos, self.window_cfg)
            if self.test_demos
            else self.train_windows.subset(none)
        )

    def _loader(self, windows: WindowSet | None, shuffle: bool) -> DataLoader:
        if windows is None:
            raise DataError("call setup() before asking for a dataloader")
        ds = _WindowBatches(windows)
        if shuffle:
            gen = torch.Generator().manual_seed(self.seed)
            base = RandomSampler(range(len(ds)), generator=gen)
        else:
            base = SequentialSampler(range(len(ds)))
        sampler = BatchSampler(base, batch_size=self.batch_size, drop_last=False)
        return DataLoader(ds, sampler=sampler, batch_size=None, num_workers=self.num_workers)

    def train_dataloader(self) -> DataLoader:
        """Shuffled (seeded) training batches."""
        return self._loader(self.train_windows, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        """Validation batches in order."""
        return self._loader(self.val_windows, shuffle=False)

    def test_dataloader(self) -> DataLoader:
        """Test batches in order."""
        return self._loader(self.test_windows, shuffle=False)
