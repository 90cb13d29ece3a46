"""Dataset folders: a generator refuses to write over an earlier dataset unless told to clear it,
and clearing deletes only the demonstration files and the dataset card."""

from __future__ import annotations

from pathlib import Path

import pytest

from iplanner_torch.data.dataset_card import (
    DatasetSummary,
    is_dataset_card,
    prepare_dataset_folder,
    write_dataset_card,
)
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset
from iplanner_torch.errors import ConfigError, DataError

SMALL = ReachingCfg(n_targets=2, reaches_per_target=2)


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}


def test_new_or_empty_folder_is_ready(tmp_path):
    assert prepare_dataset_folder(tmp_path / "new", overwrite=False) == ()
    assert not (tmp_path / "new").exists()
    (tmp_path / "notes.txt").write_text("mine")
    assert prepare_dataset_folder(tmp_path, overwrite=False) == ()
    assert _files(tmp_path) == {"notes.txt"}


def test_refuses_a_folder_with_demonstrations(tmp_path):
    generate_reaching_dataset(SMALL, tmp_path, progress=False)
    before = _files(tmp_path)
    assert len(before) == 5  # 4 demonstrations and the card
    with pytest.raises(ConfigError, match=rf"{tmp_path} already holds 4 demonstration file\(s\)"
                       r".*data\.overwrite=true"):  # fmt: skip
        prepare_dataset_folder(tmp_path, overwrite=False)
    assert _files(tmp_path) == before


def test_overwrite_deletes_only_demonstrations_and_card(tmp_path):
    generate_reaching_dataset(SMALL, tmp_path, progress=False)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "old.csv").write_text("a_x,a_y,a_z\n1,2,3\n")
    keep = {"notes.txt", "sub/plot.png", "labels.json", "sub/README.md"}
    for name in keep:
        (tmp_path / name).write_text("keep")
    demos = {p.name for p in tmp_path.glob("*.npz")}
    removed = prepare_dataset_folder(tmp_path, overwrite=True)
    assert {p.name for p in removed} == demos | {"old.csv", "README.md"}
    assert (tmp_path / "sub" / "README.md") not in removed
    assert _files(tmp_path) == keep
    # a new, smaller dataset is then all the loader sees
    generate_reaching_dataset(ReachingCfg(n_targets=2, reaches_per_target=1), tmp_path,
                              progress=False)  # fmt: skip
    assert len(list(tmp_path.rglob("*.npz"))) + len(list(tmp_path.rglob("*.csv"))) == 2


def test_refuses_to_overwrite_a_readme_that_is_not_a_card(tmp_path):
    (tmp_path / "a.npz").write_bytes(b"")
    (tmp_path / "README.md").write_text("# my recordings\n")
    for overwrite in (False, True):
        with pytest.raises(ConfigError, match="README.md is not a dataset card"):
            prepare_dataset_folder(tmp_path, overwrite=overwrite)
    assert _files(tmp_path) == {"a.npz", "README.md"}


def test_is_dataset_card(tmp_path):
    summary = DatasetSummary(out_dir=tmp_path, files=(), n_demonstrations=0, n_frames=0,
                             seconds=0.0, bytes_on_disk=0)  # fmt: skip
    card = write_dataset_card(summary, title="t", facts=[], command="c")
    assert is_dataset_card(card)
    (tmp_path / "other.md").write_text("# t\n\nhand written\n")
    assert not is_dataset_card(tmp_path / "other.md")
    assert not is_dataset_card(tmp_path / "missing.md")
    assert not is_dataset_card(tmp_path)


def test_card_keeps_the_generator_settings(tmp_path):
    """Both generators write their settings into the card; they read back equal to the
    dataclass; a card without them reads as None, and a broken block is named."""
    from dataclasses import asdict

    from iplanner_torch.data.dataset_card import read_generator_settings
    from iplanner_torch.data.tasks import TaskDatasetCfg, generate_task_dataset

    cfg = ReachingCfg(n_targets=2, reaches_per_target=1, speeds=(0.5, 2.0), seed=7)
    generate_reaching_dataset(cfg, tmp_path / "reach", progress=False)
    saved = read_generator_settings(tmp_path / "reach")
    assert saved == {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()}
    tasks = TaskDatasetCfg(n_demos=2, order="(1,5)->(2,6)", arrangement="2x2")
    generate_task_dataset(tasks, tmp_path / "tasks", progress=False)
    saved = read_generator_settings(tmp_path / "tasks")
    assert saved is not None and saved["n_demos"] == 2 and saved["order"] == "(1,5)->(2,6)"
    assert saved["arrangement"] == "2x2"

    card = tmp_path / "reach" / "README.md"
    text = card.read_text()
    card.write_text(text.replace('"seed": 7', '"seed": 7,,'))  # a hand edit that breaks it
    broken = r"README.md: the generator settings block is not valid JSON \(Expecting property"
    with pytest.raises(DataError, match=broken):
        read_generator_settings(tmp_path / "reach")
    card.write_text(text.replace("```json", "```"))  # its fence lost
    with pytest.raises(DataError, match="has no ```json ... ``` fence; repair it"):
        read_generator_settings(tmp_path / "reach")
    block = text.split("```json", 1)[1].split("```", 1)[0]
    card.write_text(text.replace(block, "\n[1, 2]\n"))  # valid JSON, not an object
    with pytest.raises(DataError, match="holds a list, not a JSON object"):
        read_generator_settings(tmp_path / "reach")
    card.write_text(text.split("Generator settings")[0])  # a card of an earlier version
    assert read_generator_settings(tmp_path / "reach") is None
    assert read_generator_settings(tmp_path / "absent") is None


def test_loading_refuses_a_dataset_generated_with_other_settings(tmp_path):
    """The commands that generate a dataset when it is missing refuse one that exists with
    other values of the generator settings the command line gives, instead of training on it
    silently; settings the command line does not give are not compared."""
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import load_dataset

    def node(**generator):
        return OmegaConf.create(
            {
                "path": str(tmp_path / "ds"),
                "generator": {
                    "_target_": "iplanner_torch.data.reaching.ReachingCfg",
                    "n_targets": 2,
                    "reaches_per_target": 1,
                    **generator,
                },
                "windows": {"joints": None},
            }
        )

    demos = load_dataset(node(), generate_if_missing=True, progress=False)
    assert len(demos) == 2
    given = {"reaches_per_target", "n_subjects"}
    assert len(load_dataset(node(), progress=False, overridden=given)) == 2
    # only data.path given: the folder is read whatever it was generated with
    assert len(load_dataset(node(reaches_per_target=2), progress=False, overridden=set())) == 2
    with pytest.raises(
        ConfigError,
        match=r"generated with other settings than data\.generator: "
        r"n_subjects: 6 -> 3; reaches_per_target: 1 -> 2 \(dataset -> data\.generator\)",
    ):
        load_dataset(node(reaches_per_target=2, n_subjects=3), progress=False, overridden=given)
    assert len(list((tmp_path / "ds").glob("*.npz"))) == 2  # nothing was touched


def test_a_settings_block_nested_too_deep_is_named(tmp_path):
    """JSON nested deeper than the decoder's recursion: a DataError, not a RecursionError."""
    from iplanner_torch.data.dataset_card import (
        CARD_MARK,
        SETTINGS_MARK,
        read_generator_settings,
    )

    deep = "[" * 100_000 + "]" * 100_000
    (tmp_path / "README.md").write_text(
        f"# data\n\n{CARD_MARK}\n\n{SETTINGS_MARK}\n\n```json\n{deep}\n```\n"
    )
    broken = r"README.md: the generator settings block is not valid JSON \(nested too deep\)"
    with pytest.raises(DataError, match=broken):
        read_generator_settings(tmp_path)


def test_a_folder_that_no_longer_matches_its_card_is_said(tmp_path):
    """Loading a generated folder from which a file was removed by hand warns with the card's
    counts and the folder's, and reads what is there; iplanner-data info says the same, or
    that the card agrees."""
    import subprocess
    import sys
    import warnings

    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import load_dataset
    from iplanner_torch.data.dataset_card import card_mismatch, read_card_counts
    from iplanner_torch.data.io import load_demonstrations
    from iplanner_torch.errors import DataWarning

    out = tmp_path / "ds"
    summary = generate_reaching_dataset(SMALL, out, progress=False)
    counts = read_card_counts(out)
    assert counts == {"demonstrations": 4, "frames": summary.n_frames}
    assert summary.n_frames == sum(d.num_frames for d in load_demonstrations(out))
    assert card_mismatch(out, 4, summary.n_frames) is None
    node = OmegaConf.create({"path": str(out), "windows": {"joints": None}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(load_dataset(node, progress=False)) == 4

    def info() -> str:
        res = subprocess.run(
            [sys.executable, "-m", "iplanner_torch.cli.data", "info", f"data.path={out}",
             f"hydra.run.dir={tmp_path / 'run'}"],
            capture_output=True, text=True, timeout=120, cwd=tmp_path,
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        return res.stdout

    assert f"dataset card: README.md agrees (4 demonstrations, {summary.n_frames} frames)" in (
        info()
    )
    gone = sorted(out.glob("*.npz"))[0]
    left = summary.n_frames - load_demonstrations(gone)[0].num_frames
    gone.unlink()
    said = (f"README.md records 4 demonstrations, {summary.n_frames} frames but the folder "
            f"holds 3 demonstrations, {left} frames: files were removed")  # fmt: skip
    with pytest.warns(DataWarning, match=said.replace("(", r"\(")):
        assert len(load_dataset(node, progress=False)) == 3
    assert said in info()
    assert read_card_counts(tmp_path / "absent") is None


def test_a_right_demonstration_count_with_a_wrong_frame_count_is_a_mismatch(tmp_path):
    """Every count the card records must agree: 4 demonstrations read as recorded but 99
    frames of the 100 recorded is a mismatch, and the message names both counts."""
    from iplanner_torch.data.dataset_card import card_mismatch

    summary = DatasetSummary(
        out_dir=tmp_path, files=(), n_demonstrations=4, n_frames=100, seconds=0.0, bytes_on_disk=0
    )
    write_dataset_card(summary, title="t", facts=(), command="regenerate")
    assert card_mismatch(tmp_path, 4, 100) is None
    said = card_mismatch(tmp_path, 4, 99)
    assert said is not None
    assert (
        "records 4 demonstrations, 100 frames but the folder holds 4 demonstrations, 99 frames"
        in said
    )


def _staged(tmp_path: Path) -> tuple[Path, DatasetSummary]:
    """An existing dataset folder ``out`` and a complete new dataset staged beside it: two
    demonstrations, one in a sub-folder, and the card (which sorts before them by name)."""
    from iplanner_torch.data.dataset_card import staged_dataset

    out = tmp_path / "out"
    out.mkdir()
    with staged_dataset(out) as staging:
        files = [staging / "a.csv", staging / "sub" / "b.csv"]
        for f in files:
            f.parent.mkdir(exist_ok=True)
            f.write_text("a_x,a_y,a_z\n1,2,3\n")
    summary = DatasetSummary.of_files(staging, files, n_frames=2, seconds=0.0)
    write_dataset_card(summary, title="t", facts=(), command="regenerate")
    return out, summary


def test_the_card_moves_into_place_last(tmp_path, monkeypatch):
    """A folder whose card is new holds the whole new dataset: the card is moved after every
    demonstration file."""
    from iplanner_torch.data import dataset_card

    out, summary = _staged(tmp_path)
    moves: list[Path] = []
    real_move = dataset_card.shutil.move

    def move(src, dest):
        moves.append(Path(dest))
        return real_move(src, dest)

    monkeypatch.setattr(dataset_card.shutil, "move", move)
    done = dataset_card.finish_staged_dataset(summary, out)
    assert sorted(moves) == sorted([out / "a.csv", out / "sub" / "b.csv", out / "README.md"])
    assert moves[-1] == out / "README.md"
    assert done.files == (out / "a.csv", out / "sub" / "b.csv")
    assert not summary.out_dir.exists()


def test_a_move_failing_part_way_keeps_the_rest_of_the_staged_dataset(tmp_path, monkeypatch):
    """When the second move fails, one new file is already in place: the staging folder is
    kept with the files not moved yet (deleting it would lose them), and the error is
    raised."""
    from iplanner_torch.data import dataset_card

    out, summary = _staged(tmp_path)
    staging = summary.out_dir
    calls = []
    real_move = dataset_card.shutil.move

    def move(src, dest):
        calls.append(dest)
        if len(calls) == 2:
            raise OSError("disk gone")
        return real_move(src, dest)

    monkeypatch.setattr(dataset_card.shutil, "move", move)
    with pytest.raises(OSError, match="disk gone"):
        dataset_card.finish_staged_dataset(summary, out)
    assert _files(out) == {"a.csv"}
    assert _files(staging) == {"sub/b.csv", "README.md"}
