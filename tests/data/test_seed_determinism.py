"""Generated datasets and the data module's split and shuffling are functions of their seed: the
same seed gives byte-identical demonstration files and the same batches, another seed other
ones, and a value that is not a seed is refused rather than read as another seed."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from iplanner_torch.data.datamodule import ReachingDataModule
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
from iplanner_torch.data.tasks import TaskDatasetCfg, generate_task_dataset
from iplanner_torch.data.windows import WindowCfg
from iplanner_torch.errors import ConfigError

#: the dataset card records the wall-clock generation time; the demonstrations must not differ
CARD = "README.md"


def _files(folder: Path) -> dict[str, bytes]:
    """Every demonstration file of ``folder`` by name, as bytes."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.name != CARD}


@pytest.mark.parametrize("file_format", ["npz", "csv"])
def test_reaching_files_are_byte_identical_for_one_seed(tmp_path: Path, file_format: str) -> None:
    def generate(name: str, seed: int) -> dict[str, bytes]:
        cfg = ReachingCfg(n_targets=2, reaches_per_target=2, seed=seed, file_format=file_format)
        generate_reaching_dataset(cfg, tmp_path / name, progress=False)
        return _files(tmp_path / name)

    a, b, other = generate("a", 0), generate("b", 0), generate("c", 1)
    assert len(a) == 4 and a == b
    assert other.keys() == a.keys()
    assert all(other[name] != a[name] for name in a)


def test_task_files_are_byte_identical_for_one_seed(tmp_path: Path) -> None:
    def generate(name: str, seed: int) -> dict[str, bytes]:
        generate_task_dataset(
            TaskDatasetCfg(n_demos=2, seed=seed), tmp_path / name, progress=False
        )
        return _files(tmp_path / name)

    a, b, other = generate("a", 0), generate("b", 0), generate("c", 1)
    assert len(a) == 2 and a == b
    assert all(other[name] != a[name] for name in a)


@pytest.fixture(scope="module")
def reaches(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("reaches")
    generate_reaching_dataset(
        ReachingCfg(n_targets=2, reaches_per_target=5), folder, progress=False
    )
    return folder


def _module(folder: Path, seed: object) -> ReachingDataModule:
    return ReachingDataModule(
        folder,
        WindowCfg(n_prev=6, n_future=8, stride=2),
        fractions=(0.6, 0.2, 0.2),
        batch_size=16,
        seed=seed,  # type: ignore[arg-type]
    )


def _drawn(dm: ReachingDataModule) -> tuple[list[str], torch.Tensor]:
    """The held-out names and the first shuffled batch's windows."""
    dm.setup("fit")
    return [d.name for d in dm.test_demos], next(iter(dm.train_dataloader()))["frame_index"]


def test_data_module_split_and_shuffle_follow_the_seed(reaches: Path) -> None:
    names, order = _drawn(_module(reaches, 1))
    again_names, again_order = _drawn(_module(reaches, 1))
    assert names == again_names and torch.equal(order, again_order)
    other_names, _ = _drawn(_module(reaches, 2))
    assert other_names != names


@pytest.mark.parametrize("seed", [1.5, True, "1", -1, 2**32, None])
def test_data_module_refuses_what_is_not_a_seed(reaches: Path, seed: object) -> None:
    """1.5, True and "1" were read as the seed 1 (the same split and batches as seed 1); -1
    failed only in setup(), with numpy's bare ValueError."""
    with pytest.raises(ConfigError, match="seed"):
        _module(reaches, seed)
