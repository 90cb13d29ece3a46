"""``iplanner-train`` records what evaluation and a resume must know: the split by
demonstration (seed, fractions, held-out names) and the trainer settings."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import torch
from omegaconf import DictConfig
from root_config import root_config

import iplanner_torch.prediction.training as training
from iplanner_torch.cli._common import config_split
from iplanner_torch.cli.train import train_from_config
from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.windows import split_by_demonstration
from iplanner_torch.errors import CheckpointError, ConfigError, DataError, DataWarning
from iplanner_torch.eval.prediction import INPUTS_FILE, SplitRecord
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

FRACTIONS = (0.6, 0.2, 0.2)


def _config(*overrides: str) -> DictConfig:
    """The root config with ``overrides``, then ``trainer=fast``."""
    return root_config(*overrides, "trainer=fast")


@pytest.fixture
def dataset(tiny_reaching: SimpleNamespace) -> Path:
    """10 generated reaching demonstrations (2 targets x 5 reaches)."""
    return tiny_reaching.ds


def test_train_from_config_records_the_split_it_trains_on(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The split handed to train_predictor is the one seed and data.split draw, with the
    names of the demonstrations it holds out."""
    given: dict[str, Any] = {}

    class Stop(Exception):
        pass

    def capture(data: Any, **kwargs: Any) -> None:
        given.update(kwargs)
        raise Stop

    monkeypatch.setattr(training, "train_predictor", capture)
    cfg = _config(f"data.path={dataset}", "seed=1", "data.split=[0.6,0.2,0.2]")
    with pytest.raises(Stop):
        train_from_config(cfg, cfg.predictor, tmp_path / "ck", trainer_node=cfg.trainer)
    test = split_by_demonstration(load_demonstrations(dataset), FRACTIONS, 1)[2]
    assert test and given["split"] == SplitRecord(
        seed=1, fractions=FRACTIONS, held_out=tuple(d.name for d in test)
    )


@pytest.mark.parametrize(
    ("overrides", "fractions"),
    [((), (0.8, 0.1, 0.1)), (("~data.split",), (0.8, 0.1, 0.1)), (("seed=4",), (0.8, 0.1, 0.1))],
)
def test_config_split_reads_seed_and_data_split(
    overrides: tuple[str, ...], fractions: tuple[float, ...]
) -> None:
    """iplanner-train and iplanner-evaluate draw the split from one reader: ``seed`` and
    ``data.split``, or DEFAULT_SPLIT where a data config has no ``split``."""
    cfg = _config(*overrides)
    assert config_split(cfg) == SplitRecord(
        seed=4 if "seed=4" in overrides else 0, fractions=fractions
    )


def test_a_bad_split_is_refused_before_the_dataset_is_read(tmp_path: Path) -> None:
    """``data.split`` is checked before the (possibly long) generation of a missing dataset."""
    missing = tmp_path / "not_generated"
    cfg = _config(f"data.path={missing}", "data.split=[0.5,0.5,0.5]")
    with pytest.raises(ConfigError, match=r"^data.split: fractions: .* got \[0.5, 0.5, 0.5\]"):
        train_from_config(cfg, cfg.predictor, tmp_path / "ck", trainer_node=cfg.trainer)
    assert not missing.exists()


def test_resume_refuses_other_trainer_settings_and_split(
    tiny_reaching: SimpleNamespace, tmp_path: Path
) -> None:
    """training_inputs.json records the trainer settings and the split; a resume under other
    ones that shape the sub-models (max_steps, the split) is refused, while logging settings
    may change; a folder recorded before the trainer settings were resumes as before."""
    windows, cfg, split = tiny_reaching.windows, tiny_reaching.cfg, tiny_reaching.split
    out = tmp_path / "ck"

    def run(
        resume: bool = False, split: SplitRecord = split, predictor: Any = cfg, **trainer: Any
    ) -> Path:
        return train_predictor(
            windows,
            predictor_cfg=predictor,
            trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False, **trainer),
            out_dir=out,
            progress=False,
            resume=resume,
            split=split,
        )

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        run(max_steps=8)
        inputs = json.loads((out / INPUTS_FILE).read_text())
        assert inputs["split"] == {"seed": 1, "fractions": list(FRACTIONS),
                                   "held_out": tiny_reaching.held_out}  # fmt: skip
        assert inputs["trainer_cfg"]["max_steps"] == 8
        stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.ckpt")}
        with pytest.raises(CheckpointError, match=rf"^cannot resume in {out}: its sub-models were "
                           r"trained with other trainer settings \(max_steps 8 -> 5\) than this "
                           r"run's "
                           r"\(recorded -> now\).*train.resume=false$"):  # fmt: skip
            run(resume=True, max_steps=5)
        with pytest.raises(CheckpointError, match=r"other trainer settings \(seed 0 -> 3\)"):
            run(resume=True, max_steps=8, seed=3)
        # the settings that differ are named by their keys, not as the record's field
        imp, ind = cfg.ivm_max_import, cfg.svgp.num_inducing
        fewer = replace(cfg, ivm_max_import=imp + 1, svgp=replace(cfg.svgp, num_inducing=ind + 2))
        named = (rf"other predictor settings \(svgp.num_inducing {ind} -> {ind + 2}, "
                 rf"ivm_max_import {imp} -> {imp + 1}\) than")  # fmt: skip
        with pytest.raises(CheckpointError, match=named):
            run(resume=True, max_steps=8, predictor=fewer)
        other = SplitRecord(seed=1, fractions=(0.5, 0.25, 0.25), held_out=split.held_out)
        with pytest.raises(CheckpointError, match=r"other split \(fractions \[0.6, 0.2, 0.2\] "
                           r"-> \[0.5, 0.25, 0.25\]\)"):  # fmt: skip
            run(resume=True, split=other, max_steps=8)
        run(resume=True, max_steps=8, log_every_n_steps=1)  # logging only: resumes
        del inputs["trainer_cfg"]  # a folder from before the trainer settings were recorded
        (out / INPUTS_FILE).write_text(json.dumps(inputs))
        for ckpt in out.glob("*.ckpt"):  # and before the sub-models kept the record's digest
            if ckpt.stem != "predictor":
                d = torch.load(ckpt, weights_only=False)
                del d["inputs_digest"], d["model_digest"]
                torch.save(d, ckpt)
        stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.ckpt")}
        with pytest.warns(DataWarning, match="carries no digests"):
            run(resume=True, max_steps=5)
    finally:
        torch.set_num_threads(threads)
    sub_models = {
        p.name: p.stat().st_mtime_ns for p in out.glob("*.ckpt") if p.stem != "predictor"
    }
    assert sub_models == {k: v for k, v in stamps.items() if k != "predictor.ckpt"}


def test_a_split_that_holds_out_nothing_is_said(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """5 reaches per target and a test fraction of 0.05 round to no held-out demonstration:
    training goes on, and says there are no held-out metrics instead of printing none."""

    def fake_train(data: Any, *, out_dir: Path, **kwargs: Any) -> Path:
        out_dir.mkdir(parents=True, exist_ok=True)
        return out_dir / "predictor.ckpt"

    monkeypatch.setattr(training, "train_predictor", fake_train)
    cfg = _config(f"data.path={dataset}", "data.split=[0.75,0.2,0.05]")
    with pytest.warns(DataWarning, match=r"data.split=\[0.75, 0.2, 0.05\] holds out none of "
                      r"the 10 demonstrations .* no held-out metrics"):  # fmt: skip
        _, metrics = train_from_config(
            cfg, cfg.predictor, tmp_path / "ck", trainer_node=cfg.trainer
        )
    assert "mhd_1s" not in metrics and metrics["train_windows"] > 0


def test_windows_longer_than_every_demonstration_are_named(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """n_prev + n_future beyond the longest demonstration gives no window: the error names
    the two settings and the longest demonstration, before training starts."""
    called = []
    monkeypatch.setattr(training, "train_predictor", lambda *a, **k: called.append(1))
    longest = max(d.num_frames for d in load_demonstrations(dataset))
    cfg = _config(f"data.path={dataset}", f"data.windows.n_prev={longest}")
    with pytest.raises(DataError, match=rf"n_prev \+ n_future = {longest + 15} frames.*"
                       r"the longest demonstration has \d+ frames"):  # fmt: skip
        train_from_config(cfg, cfg.predictor, tmp_path / "ck", trainer_node=cfg.trainer)
    assert not called


def test_a_resumed_runs_training_time_adds_the_recorded_one(tmp_path: Path) -> None:
    """train_seconds of a resumed folder adds what its earlier run recorded (a resume that
    reused every sub-model recorded well under a second as the predictor's training time);
    a missing, unreadable or nonsensical record adds nothing."""
    from iplanner_torch.cli.train import _recorded_seconds

    path = tmp_path / "heldout_metrics.json"
    assert _recorded_seconds(path) == 0.0
    path.write_text(json.dumps({"train_seconds": 12.5, "mhd_1s": 0.05}))
    assert _recorded_seconds(path) == 12.5
    for text in ("{", "[1]", '{"train_seconds": "12"}', '{"train_seconds": -1}',
                 '{"train_seconds": NaN}', '{"train_seconds": true}', "[" * 100000):  # fmt: skip
        path.write_text(text)
        assert _recorded_seconds(path) == 0.0, text
