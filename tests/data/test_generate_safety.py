"""Generating a dataset never loses an earlier one: settings are checked first, files are
written beside the folder and moved in only when complete, and an unfinished generation's
temporary folder is never read as a dataset."""

from __future__ import annotations

from pathlib import Path

import pytest

from iplanner_torch.data import reaching, tasks
from iplanner_torch.data.dataset_card import CARD_NAME
from iplanner_torch.data.io import demonstration_files, load_demonstrations
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
from iplanner_torch.data.tasks import TaskDatasetCfg, generate_task_dataset
from iplanner_torch.errors import ConfigError, DataError

TINY = ReachingCfg(n_targets=2, reaches_per_target=1)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _interrupt_after(monkeypatch: pytest.MonkeyPatch, module, n: int) -> None:
    """Make ``module``'s save_demonstration raise KeyboardInterrupt on its (n+1)-th call."""
    real = module.save_demonstration
    calls = {"n": 0}

    def save(demo, path):
        if calls["n"] == n:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real(demo, path)

    monkeypatch.setattr(module, "save_demonstration", save)


@pytest.mark.parametrize(
    ("make", "name"), [(ReachingCfg, "ReachingCfg.seed"), (TaskDatasetCfg, "TaskDatasetCfg.seed")]
)
def test_a_negative_seed_is_a_config_error(make, name):
    with pytest.raises(ConfigError, match=rf"expected {name} an integer >= 0, got -1"):
        make(seed=-1)


def test_an_interrupted_generation_leaves_no_folder_and_no_temporary_folder(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, reaching, 1)
    with pytest.raises(KeyboardInterrupt):
        generate_reaching_dataset(TINY, tmp_path / "ds", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_overwrite_keeps_the_earlier_dataset(tmp_path, monkeypatch):
    from iplanner_torch.data.dataset_card import check_dataset_folder

    out = tmp_path / "ds"
    generate_reaching_dataset(ReachingCfg(n_targets=2, reaches_per_target=2), out, progress=False)
    before = _snapshot(out)
    old = check_dataset_folder(out, overwrite=True)
    _interrupt_after(monkeypatch, tasks, 1)
    with pytest.raises(KeyboardInterrupt):
        generate_task_dataset(TaskDatasetCfg(n_demos=3), out, progress=False, replace=old)
    assert _snapshot(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_a_complete_generation_replaces_the_earlier_files_only_at_the_end(tmp_path):
    from iplanner_torch.data.dataset_card import check_dataset_folder

    out = tmp_path / "ds"
    generate_reaching_dataset(ReachingCfg(n_targets=2, reaches_per_target=2), out, progress=False)
    (out / "notes.txt").write_text("mine")
    old = check_dataset_folder(out, overwrite=True)
    assert len(old) == 5 and out / CARD_NAME in old  # nothing deleted yet
    assert len(demonstration_files(out)) == 4
    summary = generate_reaching_dataset(TINY, out, progress=False, replace=old)
    assert sorted(p.name for p in out.iterdir()) == [
        "README.md",
        "notes.txt",
        "reach_t0_r00_v1.npz",
        "reach_t1_r00_v1.npz",
    ]
    assert summary.out_dir == out and all(f.parent == out and f.is_file() for f in summary.files)
    assert "| demonstrations | 2 |" in (out / CARD_NAME).read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_a_leftover_temporary_folder_is_never_read_as_a_dataset(tmp_path):
    generate_reaching_dataset(TINY, tmp_path / "ds", progress=False)
    left = tmp_path / "other.partial-4242"
    generate_reaching_dataset(TINY, left, progress=False)
    assert len(demonstration_files(tmp_path)) == 2  # ds only
    assert len(load_demonstrations(tmp_path)) == 2
    with pytest.raises(DataError, match=r"other\.partial-4242: an unfinished generation's"):
        load_demonstrations(left)
