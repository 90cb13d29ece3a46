"""``iplanner-evaluate`` uses what it is given or refuses it: the split a checkpoint's training
recorded, the checkpoint's windows, ``device``; ``noise_sweep`` refuses the keys it does not
read, and an empty held-out split, before it trains anything."""

from __future__ import annotations

import itertools
import json
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import torch
from hydra import compose
from omegaconf import DictConfig

import iplanner_torch.cli.evaluate as evaluate
import iplanner_torch.cli.train as cli_train
import iplanner_torch.eval.prediction as eval_prediction
from iplanner_torch.data.io import load_demonstrations
from iplanner_torch.data.windows import split_by_demonstration
from iplanner_torch.errors import CheckpointError, ConfigError, DataWarning
from iplanner_torch.eval.prediction import INPUTS_FILE, SplitRecord, held_out_demonstrations
from iplanner_torch.prediction.predictor import HumanMotionPredictor
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

FRACTIONS = (0.6, 0.2, 0.2)
#: a bad data setting on the command line and the start of its message
BAD_DATA_SETTINGS = [
    ("+data.format=xyz", r"data\.format: expected one of"),
    ("+data.fps=-1", r"data\.fps: expected a frame rate > 0"),
    ("data.split=abc", r"data\.split: fractions: expected 3 numbers"),
]


@pytest.fixture(scope="module")
def trained(
    tmp_path_factory: pytest.TempPathFactory, tiny_reaching: SimpleNamespace
) -> SimpleNamespace:
    """A tiny predictor trained on ``tiny_reaching`` (10 generated reaching demonstrations
    split with seed 1 and (0.6, 0.2, 0.2), windows n_prev 6, n_future 8, stride 2), with its
    training record."""
    root = tmp_path_factory.mktemp("trained")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        ckpt = train_predictor(
            tiny_reaching.windows,
            predictor_cfg=tiny_reaching.cfg,
            trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
            out_dir=root / "ck" / "ds" / "iplanner_ni",
            progress=False,
            split=tiny_reaching.split,
        )
    finally:
        torch.set_num_threads(threads)
    return SimpleNamespace(ds=tiny_reaching.ds, ckpt=ckpt, held_out=tiny_reaching.held_out)


#: every test composes the project's config (conftest.hydra_conf)
pytestmark = pytest.mark.usefixtures("hydra_conf")


def _cfg(monkeypatch: pytest.MonkeyPatch, *overrides: str) -> DictConfig:
    """The config of ``iplanner-evaluate <overrides>``, with the overrides as its command line."""
    monkeypatch.setattr(evaluate, "_task_overrides", lambda: list(overrides))
    return compose(config_name="config", overrides=["progress=false", *overrides])


@pytest.fixture
def scored(monkeypatch: pytest.MonkeyPatch) -> list[SimpleNamespace]:
    """What ``evaluate_prediction`` is called with (it returns a stub)."""
    calls: list[SimpleNamespace] = []

    def fake(predictor: Any, demos: Any, **kwargs: Any) -> dict[str, float]:
        calls.append(SimpleNamespace(predictor=predictor, names=sorted(d.name for d in demos)))
        return {"n_windows": 1.0}

    monkeypatch.setattr(eval_prediction, "evaluate_prediction", fake)
    return calls


#: numbers the report folders of _prediction_args
_REPORTS = itertools.count()


def _prediction_args(trained: SimpleNamespace, out: Path, ckpt: Path | None = None) -> list[str]:
    """The overrides that evaluate ``ckpt`` (the trained one by default) into a new report
    folder under ``out``: a folder that holds an earlier report is refused."""
    return [f"data.path={trained.ds}", f"evaluate.checkpoint={ckpt or trained.ckpt}",
            f"evaluate.out_dir={out / f'report{next(_REPORTS)}'}"]  # fmt: skip


def test_prediction_scores_the_split_its_checkpoint_recorded(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """Trained with seed 1, evaluated with the default seed 0: the recorded split is scored
    (seed 0 would score training demonstrations); a checkpoint without its record (copied
    away) keeps drawing the split from seed and data.split, and one whose folder holds the
    record of another training run (trained anew since on other data) draws it from the seed
    the command line gives, and is refused without one."""
    seed0 = sorted(d.name for d in split_by_demonstration(
        load_demonstrations(trained.ds), FRACTIONS, 0)[2])  # fmt: skip
    assert seed0 != sorted(trained.held_out)
    split = "data.split=[0.6,0.2,0.2]"
    for given in ([], ["seed=1"], [split], ["seed=1", split]):
        evaluate._prediction(_cfg(monkeypatch, *_prediction_args(trained, tmp_path), *given))
        assert scored[-1].names == sorted(trained.held_out), given
    assert (
        "held-out split: seed=1 data.split=[0.6,0.2,0.2] (recorded in" in capsys.readouterr().out
    )
    # the record must name this checkpoint's training data
    other = tmp_path / "other"
    shutil.copytree(trained.ckpt.parent, other)
    inputs = json.loads((other / INPUTS_FILE).read_text())
    (other / INPUTS_FILE).write_text(json.dumps({**inputs, "fingerprint": "retrained"}))
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(trained.ckpt, alone / "predictor.ckpt")
    for ckpt, source in (
        (other / "predictor.ckpt", f"the {INPUTS_FILE} beside the checkpoint does not record"),
        (alone / "predictor.ckpt", f"no {INPUTS_FILE} beside the checkpoint"),
    ):
        args = _prediction_args(trained, tmp_path, ckpt)
        seed = ["seed=0"] if ckpt.parent == other else []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataWarning)  # other: the record is another run's
            evaluate._prediction(_cfg(monkeypatch, *args, *seed, split))
        assert scored[-1].names == seed0, ckpt
        assert source in capsys.readouterr().out
        empty = r"seed=0 data.split=\[0.8,0.1,0.1\] \(from seed and data.split.*leaves no held-out"
        args = _prediction_args(trained, tmp_path, ckpt)
        with pytest.raises(ConfigError, match=empty), warnings.catch_warnings():
            warnings.simplefilter("ignore", DataWarning)
            evaluate._prediction(_cfg(monkeypatch, *args, *seed))
    args = _prediction_args(trained, tmp_path, other / "predictor.ckpt")
    with pytest.raises(
        CheckpointError,
        match="is not the record of .*or the checkpoint was copied",
    ):
        evaluate._prediction(_cfg(monkeypatch, *args, split))


def _interrupted_retrain(trained: SimpleNamespace, folder: Path, seed: int) -> list[str]:
    """``folder``: a copy of the trained checkpoint's folder in which ``iplanner-train ...
    seed=<seed>`` started again and was interrupted: it wrote its training_inputs.json (the
    same data and settings, another seed and split) at its start, as training does, and no
    predictor.ckpt. Returns the demonstrations its split holds out."""
    shutil.copytree(trained.ckpt.parent, folder)
    record = json.loads((folder / INPUTS_FILE).read_text())
    demos = load_demonstrations(trained.ds)
    held_out = sorted(d.name for d in split_by_demonstration(demos, FRACTIONS, seed)[2])
    record["trainer_cfg"]["seed"] = seed
    record["split"] = {"seed": seed, "fractions": list(FRACTIONS), "held_out": held_out}
    (folder / INPUTS_FILE).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return held_out


def test_prediction_refuses_the_record_of_a_later_unfinished_training(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    """The checkpoint was trained with seed 1; an interrupted retrain with seed 0 replaced the
    record beside it. Its split (seed 0) holds out demonstrations the checkpoint was trained
    on: it was scored, and the message said no record was there. Now the record is refused
    (the checkpoint keeps the digest of its own), or, with seed given, the split is drawn from
    the command line's seed and data.split with a warning that says so."""
    folder = tmp_path / "ck" / "ds" / "iplanner_ni"
    seed0 = _interrupted_retrain(trained, folder, seed=0)
    assert seed0 != sorted(trained.held_out)
    args = _prediction_args(trained, tmp_path / "out", folder / "predictor.ckpt")
    refusal = (rf"^{re.escape(str(folder / INPUTS_FILE))} is not the record of "
               r".*predictor.ckpt \(it records the split seed=0 "
               r"data.split=\[0.6,0.2,0.2\]\).*may include demonstrations it was trained on; "
               r"retrain it .*, or pass the seed and data.split it was trained with")  # fmt: skip
    for given in ([], ["data.split=[0.6,0.2,0.2]"]):
        with pytest.raises(CheckpointError, match=refusal):
            evaluate._prediction(_cfg(monkeypatch, *args, *given))
    assert not scored
    warned = (r"is not the record of .*the held-out split is drawn from "
              r"seed and data.split as the command line gives them")  # fmt: skip
    with pytest.warns(DataWarning, match=warned):
        evaluate._prediction(_cfg(monkeypatch, *args, "seed=1", "data.split=[0.6,0.2,0.2]"))
    assert scored[-1].names == sorted(trained.held_out)
    out = capsys.readouterr().out
    assert "held-out split: seed=1 data.split=[0.6,0.2,0.2] (from seed and data.split: the " in out
    assert "no training_inputs.json" not in out


def test_prediction_does_not_write_over_an_earlier_report(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A given evaluate.out_dir that holds prediction_metrics.json is refused, before the
    checkpoint is scored, and the file is kept; another folder is written."""
    earlier = tmp_path / "prediction_metrics.json"
    earlier.write_text('{"mhd_1s": 0.1}')
    args = [*_prediction_args(trained, tmp_path)[:-1], f"evaluate.out_dir={tmp_path}"]
    with pytest.raises(ConfigError, match=rf"^evaluate.out_dir={re.escape(str(tmp_path))} "
                       r"already holds prediction_metrics.json of an earlier report, which "
                       r"this one would replace; choose another evaluate.out_dir"):  # fmt: skip
        evaluate._prediction(_cfg(monkeypatch, *args))
    assert not scored and earlier.read_text() == '{"mhd_1s": 0.1}'
    evaluate._prediction(_cfg(monkeypatch, *_prediction_args(trained, tmp_path)))
    assert len(scored) == 1 and earlier.read_text() == '{"mhd_1s": 0.1}'


def test_prediction_refuses_data_that_holds_none_of_the_held_out_demonstrations(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A checkpoint scored on other data (the reaching default for a LEGO predictor) printed
    its "held-out" metrics of demonstrations it may have been trained on, with warnings,
    and exited 0."""
    import shutil

    from iplanner_torch.errors import DataError

    other = tmp_path / "other"
    shutil.copytree(trained.ds, other)
    for npz in other.glob("*.npz"):
        npz.rename(npz.with_name("x_" + npz.name))
    args = [f"data.path={other}", *_prediction_args(trained, tmp_path)[1:]]
    shown = ", ".join(sorted(trained.held_out)[:3])
    with pytest.raises(DataError, match=re.escape(
        f"none of the {len(trained.held_out)} demonstration(s) the checkpoint's training held "
        f"out ({shown}) is among the 10 of {other}: it was trained on other data"
    )):  # fmt: skip
        evaluate._prediction(_cfg(monkeypatch, *args))
    assert not scored


def test_prediction_refuses_another_split_on_the_command_line(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    args = _prediction_args(trained, tmp_path)
    recorded = (rf"{trained.ckpt} was trained on the split seed=1 data.split=\[0.6,0.2,0.2\] "
                rf"\(recorded in {trained.ckpt.parent / INPUTS_FILE}\)")  # fmt: skip
    with pytest.raises(ConfigError, match=rf"^seed=0: {recorded}.*leave seed out"):
        evaluate._prediction(_cfg(monkeypatch, *args, "seed=0"))
    with pytest.raises(ConfigError, match=rf"^data.split=\[0.2,0.2,0.6\]: {recorded}"):
        evaluate._prediction(_cfg(monkeypatch, *args, "data.split=[0.2,0.2,0.6]"))
    assert not scored


def test_prediction_refuses_window_settings_other_than_the_checkpoints(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The checkpoint (n_prev 6, n_future 8, stride 2, three feature kinds) defines the
    windows; a command-line value it does not have is named with the checkpoint's."""
    args = _prediction_args(trained, tmp_path)
    for given, text in (
        ("data.windows.n_prev=15", r"data.windows.n_prev=15 \(checkpoint: 6\)"),
        ("data.windows.n_future=4", r"data.windows.n_future=4 \(checkpoint: 8\)"),
        ("data.windows.stride=1", r"data.windows.stride=1 \(checkpoint: 2\)"),
        ("data.windows.feature_kinds=[position]",
         r"data.windows.feature_kinds=\['position'\] \(checkpoint: \['position', 'velocity', "
         r"'acceleration'\]\)"),
    ):  # fmt: skip
        with pytest.raises(ConfigError, match=rf"^{text}: .*predictor.ckpt was trained with "
                           "other window settings.*leave it out"):  # fmt: skip
            evaluate._prediction(_cfg(monkeypatch, *args, given))
    assert not scored
    same = ("data.windows.n_prev=6", "data.windows.n_future=8", "data.windows.stride=2")
    evaluate._prediction(_cfg(monkeypatch, *args, *same))
    assert scored[-1].names == sorted(trained.held_out)


@pytest.mark.parametrize(("given", "message"), BAD_DATA_SETTINGS)
def test_prediction_checks_the_data_settings_before_loading_the_checkpoint(
    given: str, message: str, trained: SimpleNamespace, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """A bad data setting is named before the checkpoint loads (it was reported only after a
    checkpoint load, and not at all where the checkpoint was damaged)."""
    damaged = tmp_path / "damaged.ckpt"
    damaged.write_bytes(b"not a checkpoint")
    args = _prediction_args(trained, tmp_path, damaged)
    with pytest.raises(ConfigError, match=f"^{message}"):
        evaluate._prediction(_cfg(monkeypatch, *args, given))
    with pytest.raises(CheckpointError):
        evaluate._prediction(_cfg(monkeypatch, *args))


def test_prediction_loads_the_predictor_on_device(
    trained: SimpleNamespace, scored: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    device: torch.device,
) -> None:  # fmt: skip
    asked: list[Any] = []
    load = HumanMotionPredictor.load

    def spy(path: Any, map_location: Any = None, **kwargs: Any) -> HumanMotionPredictor:
        asked.append(map_location)
        return load(path, map_location=map_location, **kwargs)

    monkeypatch.setattr(HumanMotionPredictor, "load", spy)
    evaluate._prediction(_cfg(monkeypatch, *_prediction_args(trained, tmp_path),
                              f"device={device.type}"))  # fmt: skip
    assert asked == [device] and scored[-1].predictor.device.type == device.type


@pytest.fixture
def no_training(monkeypatch: pytest.MonkeyPatch) -> None:
    """Training fails the test."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("trained before the refusal")

    monkeypatch.setattr(cli_train, "train_from_config", refuse)


def _sweep_args(trained: SimpleNamespace, tmp_path: Path) -> list[str]:
    return [
        "evaluate.mode=noise_sweep",
        f"data.path={trained.ds}",
        f"paths.checkpoints={tmp_path / 'ck'}",
        f"evaluate.out_dir={tmp_path / 'out'}",
    ]


def test_noise_sweep_refuses_the_keys_it_does_not_read(
    trained: SimpleNamespace, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_training: None
) -> None:
    sweep = _sweep_args(trained, tmp_path)
    for given in ("predictor=iplanner_no_ni", "predictor.min_group_size=3",
                  f"evaluate.checkpoint={trained.ckpt}", f"train.out_dir={tmp_path}"):  # fmt: skip
        with pytest.raises(ConfigError, match=rf"^evaluate.mode=noise_sweep does not read "
                           rf"{given}: it compares <paths.checkpoints>/<data folder>/<option>/"
                           rf"predictor.ckpt for each option of evaluate.compare \(here "
                           rf"{tmp_path / 'ck' / 'ds'}/{{iplanner_no_ni,iplanner_ni}}\).*"
                           "evaluate.mode=prediction evaluate.checkpoint=<file>$"):  # fmt: skip
            evaluate._noise_sweep(_cfg(monkeypatch, *sweep, given))
    assert not (tmp_path / "ck").exists()


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ("evaluate.noises=[]", r"evaluate.noises: expected at least one value, got \[\]"),
        ("evaluate.speeds=[]", r"evaluate.speeds: expected at least one value"),
        ("evaluate.compare=[]", r"evaluate.compare: expected at least one value"),
        ("evaluate.noises=[0.01,-1]", r"evaluate.noises: expected finite noise levels >= 0"),
        ("evaluate.noises=[nan]", r"evaluate.noises: expected finite .* got \[nan\]"),
        ("evaluate.speeds=[brisk]", r"evaluate.speeds: unknown \['brisk'\]"),
    ],
)
def test_noise_sweep_checks_its_grid_before_any_work(
    given: str,
    message: str,
    trained: SimpleNamespace,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    no_training: None,
) -> None:
    """An empty or bad grid is refused by key before anything is loaded, trained or scored
    (an empty one ended in a plotting error after all the work)."""
    sweep = _sweep_args(trained, tmp_path)
    with pytest.raises(ConfigError, match=f"^{message}"):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep, given))
    assert not (tmp_path / "ck").exists() and not (tmp_path / "out").exists()


def test_noise_sweep_checks_the_split_and_windows_before_training(
    trained: SimpleNamespace, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_training: None
) -> None:
    """An empty held-out split, a missing checkpoint that would hold out other demonstrations
    than a trained one, and window settings a trained one does not have are refused before
    the missing checkpoint is trained."""
    sweep = _sweep_args(trained, tmp_path)
    with pytest.raises(ConfigError, match=r"^seed=0 data.split=\[0.8,0.1,0.1\] \(from seed and "
                       r"data.split, which iplanner_no_ni, iplanner_ni will be trained on\) "
                       r"leaves no held-out demonstrations of the 10"):  # fmt: skip
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    shutil.copytree(trained.ckpt.parent, tmp_path / "ck" / "ds" / "iplanner_ni")
    with pytest.raises(ConfigError, match=r"iplanner_ni/predictor.ckpt was trained on the split "
                       r"seed=1 data.split=\[0.6,0.2,0.2\] .* but the missing .*iplanner_no_ni/"
                       r"predictor.ckpt would be trained on seed=0 data.split=\[0.8,0.1,0.1\].*"
                       r"pass seed=1 data.split=\[0.6,0.2,0.2\]"):  # fmt: skip
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    with pytest.raises(ConfigError, match=r"^data.windows.n_prev=15 \(checkpoint: 6\)"):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep, "data.windows.n_prev=15"))
    with pytest.raises(AssertionError, match="trained before the refusal"):  # now it may train
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep, "seed=1", "data.split=[0.6,0.2,0.2]"))


@pytest.mark.parametrize(("given", "message"), BAD_DATA_SETTINGS)
def test_noise_sweep_checks_the_data_settings_before_loading_a_checkpoint(
    given: str, message: str, trained: SimpleNamespace, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, no_training: None,
) -> None:  # fmt: skip
    """A bad data setting is named before the checkpoints load (a damaged one hid it)."""
    folder = tmp_path / "ck" / "ds" / "iplanner_ni"
    folder.mkdir(parents=True)
    (folder / "predictor.ckpt").write_bytes(b"not a checkpoint")
    sweep = _sweep_args(trained, tmp_path)
    with pytest.raises(ConfigError, match=f"^{message}"):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep, given))
    with pytest.raises(CheckpointError):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))


def test_held_out_demonstrations_warn_on_other_data(trained: SimpleNamespace) -> None:
    demos = load_demonstrations(trained.ds)
    split = SplitRecord(seed=1, fractions=FRACTIONS, held_out=["reach_t0_r00_v1", "elsewhere"])
    with pytest.warns(DataWarning, match=r"seed=1 data.split=\[0.6,0.2,0.2\] holds out 2 "
                      r"demonstration\(s\) of this data, 2 of them not among the 2"):  # fmt: skip
        assert len(held_out_demonstrations(demos, split)) == 2
    with pytest.raises(ConfigError, match=r"fractions: expected 3 non-negative shares"):
        SplitRecord(seed=0, fractions=(0.5, 0.5))


def test_the_refusal_is_one_line_with_exit_code_2(tmp_path: Path) -> None:
    """The command line's overrides reach the check through Hydra (no stand-in)."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.evaluate", "evaluate.mode=noise_sweep",
         "predictor=iplanner_no_ni", f"paths.checkpoints={tmp_path / 'ck'}",
         f"data.path={tmp_path / 'ds'}", f"hydra.run.dir={tmp_path / 'run'}", "progress=false"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "error: ConfigError: evaluate.mode=noise_sweep does not read predictor=iplanner_no_ni: "
    )


def test_noise_sweep_scores_the_recorded_split_and_draws_its_noise_with_seed(
    trained: SimpleNamespace,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    no_training: None,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """In the noise sweep ``seed`` also draws the noise: a seed other than the recorded split's
    is not refused there, and the recorded split is still the one scored."""
    shutil.copytree(trained.ckpt.parent, tmp_path / "ck" / "ds" / "iplanner_ni")
    sweep = [*_sweep_args(trained, tmp_path), "evaluate.compare=[iplanner_ni]",
             "evaluate.noises=[0.0,0.02]", "evaluate.speeds=[medium]"]  # fmt: skip
    evaluate._noise_sweep(_cfg(monkeypatch, *sweep, "seed=5"))
    out = capsys.readouterr().out
    assert "held-out split: seed=1 data.split=[0.6,0.2,0.2] (recorded in" in out


def test_noise_sweep_compares_the_constant_velocity_baseline_without_a_checkpoint(
    trained: SimpleNamespace, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_training: None
) -> None:
    """``constant_velocity`` in ``evaluate.compare`` is scored on the windows of the compared
    checkpoint (the same windows: n_prev 6, n_future 8, stride 2), with ``run.cv``'s
    settings, and is neither loaded nor trained; its class metrics are NaN."""
    import pandas as pd

    shutil.copytree(trained.ckpt.parent, tmp_path / "ck" / "ds" / "iplanner_ni")
    sweep = [*_sweep_args(trained, tmp_path), "evaluate.compare=[iplanner_ni,constant_velocity]",
             "evaluate.noises=[0.0,0.02]", "evaluate.speeds=[medium]",
             "run.cv.spread_mps=0.2"]  # fmt: skip
    evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    df = pd.read_csv(tmp_path / "out" / "prediction_vs_noise.csv")
    assert list(dict.fromkeys(df["predictor"])) == ["iplanner_ni", "constant_velocity"]
    cv, ni = df[df["predictor"] == "constant_velocity"], df[df["predictor"] == "iplanner_ni"]
    assert cv["n_windows"].tolist() == ni["n_windows"].tolist() and len(cv) == 2
    assert cv["class_precision"].isna().all() and ni["class_precision"].notna().all()
    assert (cv["mhd_1s"] > 0).all() and (cv["mhd_1s"] < 1.0).all()
    assert not (tmp_path / "ck" / "ds" / "constant_velocity").exists()
    # that report is not written over
    with pytest.raises(ConfigError, match=r"out already holds README.md, prediction_vs_noise.csv, "
                       r"prediction_vs_noise.png of an earlier report"):  # fmt: skip
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    assert pd.read_csv(tmp_path / "out" / "prediction_vs_noise.csv").equals(df)
    # a fit longer than the checkpoint's windows: named, before any row is written
    sweep[-1] = "run.cv.fit_frames=7"
    sweep[sweep.index(f"evaluate.out_dir={tmp_path / 'out'}")] = f"evaluate.out_dir={tmp_path}"
    with pytest.raises(ConfigError, match=r"run.cv: on windows of 6 frames: .*n_prev"):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    assert not (tmp_path / "prediction_vs_noise.csv").exists()


def test_noise_sweep_of_the_constant_velocity_baseline_alone_trains_nothing(
    trained: SimpleNamespace,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    no_training: None,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without a checkpoint to compare, the split comes from seed and data.split and the
    windows from data.windows; nothing is trained or written into paths.checkpoints."""
    import pandas as pd

    sweep = [*_sweep_args(trained, tmp_path), "evaluate.compare=[constant_velocity]",
             "evaluate.noises=[0.0]", "evaluate.speeds=[medium]", "data.split=[0.6,0.2,0.2]",
             "data.windows.n_prev=6", "data.windows.n_future=8"]  # fmt: skip
    evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
    assert "from seed and data.split: no checkpoint is compared" in capsys.readouterr().out
    df = pd.read_csv(tmp_path / "out" / "prediction_vs_noise.csv")
    assert df["predictor"].tolist() == ["constant_velocity"] and df["n_windows"].iloc[0] > 0
    assert not (tmp_path / "ck").exists()


def test_noise_sweep_refuses_the_record_of_a_later_unfinished_training(
    trained: SimpleNamespace, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_training: None
) -> None:
    """As ``prediction`` does (the record beside the checkpoint is an interrupted retrain's)."""
    _interrupted_retrain(trained, tmp_path / "ck" / "ds" / "iplanner_ni", seed=0)
    sweep = [*_sweep_args(trained, tmp_path), "evaluate.compare=[iplanner_ni]",
             "evaluate.noises=[0.0,0.02]", "evaluate.speeds=[medium]"]  # fmt: skip
    with pytest.raises(
        CheckpointError,
        match="is not the record of .*or the checkpoint was copied",
    ):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))


@pytest.fixture(scope="module")
def trained_no_ni(
    tmp_path_factory: pytest.TempPathFactory, tiny_reaching: SimpleNamespace
) -> Path:
    """The folder of a tiny predictor like ``trained``'s but without the noisy-input
    correction (``svgp.noisy_input=none``, as conf/predictor/iplanner_no_ni.yaml)."""
    from tiny_settings import tiny_predictor_cfg

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        ckpt = train_predictor(
            tiny_reaching.windows,
            predictor_cfg=tiny_predictor_cfg(noisy_input="none"),
            trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
            out_dir=tmp_path_factory.mktemp("no_ni") / "iplanner_no_ni",
            progress=False,
            split=tiny_reaching.split,
        )
    finally:
        torch.set_num_threads(threads)
    return ckpt.parent


def test_noise_sweep_refuses_checkpoints_of_another_option_in_an_options_folder(
    trained: SimpleNamespace,
    trained_no_ni: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    no_training: None,
) -> None:
    """Each checkpoint in the other's folder would label the table's rows the wrong way round:
    refused before anything is trained or scored, naming the checkpoint, the option, the
    setting that differs and the way out; in their own folders they are compared."""
    import iplanner_torch.eval.prediction_sweep as prediction_sweep

    swept: list[dict[str, str]] = []

    def sweep_stub(predictors: Any, demos: Any, **kwargs: Any) -> Any:
        import pandas as pd

        swept.append(
            {o: type(p.cfg).__name__ if o == "constant_velocity" else p.cfg.svgp.noisy_input
             for o, p in predictors.items()}
        )  # fmt: skip
        return pd.DataFrame({"predictor": list(predictors)})

    monkeypatch.setattr(prediction_sweep, "prediction_vs_noise", sweep_stub)
    monkeypatch.setattr(prediction_sweep, "write_noise_report", lambda *a, **k: [])
    ck = tmp_path / "ck" / "ds"
    shutil.copytree(trained.ckpt.parent, ck / "iplanner_no_ni")  # noisy_input=simple
    shutil.copytree(trained_no_ni, ck / "iplanner_ni")  # noisy_input=none
    sweep = _sweep_args(trained, tmp_path)
    for option, recorded, config in (
        ("iplanner_no_ni", "simple", "none"),
        ("iplanner_ni", "none", "simple"),
    ):
        ckpt = ck / option / "predictor.ckpt"
        with pytest.raises(ConfigError, match=(
            rf"^{ckpt} was trained with other predictor settings than conf/predictor/"
            rf"{option}.yaml, so the sweep would report it as {option}: svgp.noisy_input: "
            rf"'{recorded}' -> '{config}' \(recorded -> "
            rf"config\). Retrain it into that folder \(`iplanner-train data=reaching "
            rf"data.path={trained.ds} predictor={option} trainer=default "
            rf"train.out_dir={ckpt.parent} train.overwrite=true`\), or delete {ckpt.parent}"
        )):  # fmt: skip
            evaluate._noise_sweep(_cfg(monkeypatch, *sweep, f"evaluate.compare=[{option}]"))
    shutil.rmtree(ck / "iplanner_no_ni")  # the missing one would be trained: refused first
    with pytest.raises(ConfigError, match=r"iplanner_ni/predictor.ckpt was trained with other"):
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep, "seed=1", "data.split=[0.6,0.2,0.2]"))
    assert not swept and not (ck / "iplanner_no_ni").exists()
    shutil.rmtree(ck / "iplanner_ni")
    shutil.copytree(trained_no_ni, ck / "iplanner_no_ni")
    shutil.copytree(trained.ckpt.parent, ck / "iplanner_ni")
    evaluate._noise_sweep(_cfg(monkeypatch, *sweep, "seed=5"))  # seed draws only the noise
    # (the default list ends with the constant-velocity baseline, which has no checkpoint)
    assert swept == [{"iplanner_no_ni": "none", "iplanner_ni": "simple",
                      "constant_velocity": "ConstantVelocityCfg"}]  # fmt: skip


def test_noise_sweep_refuses_motion_without_clean_positions_before_training(
    trained: SimpleNamespace, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, no_training: None
) -> None:
    """Held-out demonstrations without clean_positions (a recording) cannot be re-noised:
    refused before the missing predictor is trained (it failed after the training)."""
    from dataclasses import replace

    from iplanner_torch.errors import DataError

    shutil.copytree(trained.ckpt.parent, tmp_path / "ck" / "ds" / "iplanner_ni")
    real = evaluate._held_out

    def recorded(*args: Any, **kwargs: Any) -> list[Any]:
        return [replace(d, clean_positions=None) for d in real(*args, **kwargs)]

    monkeypatch.setattr(evaluate, "_held_out", recorded)
    sweep = [*_sweep_args(trained, tmp_path), "seed=1", "data.split=[0.6,0.2,0.2]"]
    with pytest.raises(DataError, match=r"^2 of the 2 held-out demonstrations have no "
                       r"clean_positions to re-noise"):  # fmt: skip
        evaluate._noise_sweep(_cfg(monkeypatch, *sweep))
