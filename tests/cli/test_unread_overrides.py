"""``iplanner-data``, ``iplanner-train`` and ``iplanner-evaluate`` refuse command-line settings
they do not read (a ``device`` given to training, a ``trainer`` given to the evaluation of a
trained checkpoint, a ``seed`` given to the generator), instead of running as if they had not
been given."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import iplanner_torch.cli.evaluate as evaluate
from iplanner_torch.cli._common import unread_overrides
from iplanner_torch.errors import ConfigError


def test_unread_overrides_matches_groups_keys_and_group_choices() -> None:
    read = ("data", "evaluate.logs", "predictor=")
    given = [
        "data=tasks",  # the group's option
        "data.windows.n_prev=5",  # a key below a read group
        "+data.extra=1",
        "evaluate.logs=a.mcap",
        "evaluate.logs.x=1",  # below a read key
        "predictor=iplanner_no_ni",  # the group's option alone is read ...
        "progress=false",  # always read
        "predictor.min_group_size=3",  # ... not its keys
        "predictor@alias.svgp.epochs=2",  # a package override of the same group
        "evaluate.labels=[a]",
        "datapath=x",  # a prefix of "data" but another key
        "seed=1",
        "~trainer",
    ]
    assert unread_overrides(read, given) == [
        "predictor.min_group_size=3",
        "predictor@alias.svgp.epochs=2",
        "evaluate.labels=[a]",
        "datapath=x",
        "seed=1",
        "~trainer",
    ]
    assert unread_overrides(read, []) == []


@pytest.mark.parametrize(
    ("mode", "given", "refused"),
    [
        ("prediction", ["trainer=fast"], "trainer=fast"),
        ("prediction", ["predictor.min_group_size=3"], "predictor.min_group_size=3"),
        ("prediction", ["evaluate.noises=[0.0]"], "evaluate.noises=[0.0]"),
        ("prediction", ["tracker.noise=0.02"], "tracker.noise=0.02"),
        # evaluate.checkpoint names the checkpoint: the options that name the default do not
        ("prediction", ["evaluate.checkpoint=x.ckpt", "predictor=iplanner_no_ni"],
         "predictor=iplanner_no_ni"),
        ("prediction", ["evaluate.checkpoint=x.ckpt", "train.out_dir=y"], "train.out_dir=y"),
        ("noise_sweep", ["evaluate.logs=a.mcap"], "evaluate.logs=a.mcap"),
        ("noise_sweep", ["planner.confidence=0.9"], "planner.confidence=0.9"),
        ("episode", ["seed=3"], "seed=3"),
        ("episode", ["data=tasks", "device=cpu"], "data=tasks device=cpu"),
    ],
)  # fmt: skip
def test_each_evaluate_mode_refuses_what_it_does_not_read(
    mode: str, given: list[str], refused: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    overrides = [f"evaluate.mode={mode}", *given]
    monkeypatch.setattr(evaluate, "_task_overrides", lambda: overrides)
    with pytest.raises(
        ConfigError,
        match="^" + re.escape(f"iplanner-evaluate evaluate.mode={mode} does not read {refused}: "),
    ):
        evaluate._refuse_unread(mode)


@pytest.mark.parametrize(
    ("mode", "given"),
    [
        ("prediction", ["predictor=iplanner_no_ni", "train.out_dir=y", "seed=1", "device=cpu",
                        "data=tasks", "data.windows.n_prev=5", "paths.checkpoints=c",
                        "evaluate.out_dir=o", "progress=false"]),
        ("prediction", ["evaluate.checkpoint=x.ckpt", "data.path=d", "paths.datasets=p"]),
        ("noise_sweep", ["trainer=fast", "trainer.max_steps=3", "seed=2", "device=cpu",
                         "evaluate.compare=[iplanner_ni]", "evaluate.noises=[0.0]",
                         "evaluate.speeds=[slow]", "data.split=[0.5,0.25,0.25]"]),
        ("episode", ["evaluate.logs=a.mcap", "evaluate.labels=[a]", "evaluate.baseline=itomp",
                     "evaluate.out_dir=o", "progress=false"]),
    ],
)  # fmt: skip
def test_each_evaluate_mode_accepts_what_it_reads(
    mode: str, given: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    overrides = [f"evaluate.mode={mode}", *given]
    monkeypatch.setattr(evaluate, "_task_overrides", lambda: overrides)
    evaluate._refuse_unread(mode)


def _run(module: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize(
    ("module", "args", "line"),
    [
        ("train", ["device=cpu", "trainer=fast"],
         "error: ConfigError: iplanner-train does not read device=cpu: it reads data, "
         "predictor, trainer, train, seed, paths and progress; it trains on "
         "trainer.accelerator"),
        ("train", ["run.seeds=[1]"], "error: ConfigError: iplanner-train does not read "
         "run.seeds=[1]: "),
        # refused as unread before its value is checked (where there is no CUDA)
        ("train", ["device=cuda"], "error: ConfigError: iplanner-train does not read "
         "device=cuda: "),
        ("data", ["info", "device=cuda"], "error: ConfigError: iplanner-data info does not "
         "read device=cuda: "),
        ("train", ["predictor.svgp.nigp_refit_steps=3", "predictor.svgp.velocity_limit=2"],
         "error: ConfigError: predictor.svgp.nigp_refit_steps: not read with "
         "predictor.svgp.noisy_input=simple (nigp_iterations and nigp_refit_steps are read "
         "with noisy_input=nigp"),
        ("data", ["generate", "seed=3"], "error: ConfigError: iplanner-data generate does not "
         "read seed=3: it reads data, paths.datasets and progress (a generated set draws from "
         "data.generator.seed, not seed)"),
        ("data", ["info", "trainer=fast"], "error: ConfigError: iplanner-data info does not "
         "read trainer=fast: "),
        ("evaluate", ["trainer.max_steps=5"], "error: ConfigError: iplanner-evaluate "
         "evaluate.mode=prediction does not read trainer.max_steps=5: the checkpoint defines "
         "the predictor and how it was trained"),
    ],
)  # fmt: skip
def test_commands_refuse_unread_settings_before_any_work(
    module: str, args: list[str], line: str, tmp_path: Path
) -> None:
    """One error line, exit code 2, and nothing generated, trained or written."""
    res = _run(module, [*args, f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), res.stderr
    for folder in ("datasets", "checkpoints"):
        assert not (tmp_path / folder).exists()


@pytest.mark.parametrize(
    ("given", "refused"),
    [
        (["predictor.svgp.nigp_iterations=3"], ["nigp_iterations"]),
        (["predictor=iplanner_no_ni", "predictor.svgp.input_noise_sigma=0.02",
          "predictor.svgp.velocity_limit=2", "predictor.svgp.nigp_iterations=3"],
         ["input_noise_sigma", "nigp_iterations", "velocity_limit"]),
        (["predictor.svgp.noisy_input=nigp", "predictor.svgp.velocity_limit=2"],
         ["velocity_limit"]),
        (["predictor.svgp.noisy_input=nigp", "predictor.svgp.nigp_iterations=3",
          "predictor.svgp.input_noise_sigma=0.02"], []),
        (["predictor.svgp.velocity_limit=2", "predictor.svgp.input_noise_sigma=0.02"], []),
        (["predictor.svgp.noisy_input=none", "predictor.svgp.num_inducing=8"], []),
    ],
)  # fmt: skip
def test_train_refuses_svgp_fields_its_noisy_input_does_not_read(
    given: list[str], refused: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """iplanner_ni's noisy_input is simple, iplanner_no_ni's none."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    import iplanner_torch.cli._common as common
    import iplanner_torch.cli.train as cli_train
    from iplanner_torch.cli._common import CONF_DIR

    GlobalHydra.instance().clear()
    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        cfg = compose("config", overrides=given)
    GlobalHydra.instance().clear()
    monkeypatch.setattr(common, "task_overrides", lambda: given)
    if not refused:
        cli_train._refuse_unread_svgp_fields(cfg)
        return
    keys = ", ".join(f"predictor.svgp.{k}" for k in refused)
    mode = cfg.predictor.svgp.noisy_input
    start = f"{keys}: not read with predictor.svgp.noisy_input={mode} "
    with pytest.raises(ConfigError, match="^" + re.escape(start)):
        cli_train._refuse_unread_svgp_fields(cfg)


@pytest.mark.parametrize("option", ["iplanner_ni", "iplanner_no_ni"])
def test_a_predictor_file_that_sets_unread_svgp_fields_is_warned(
    option: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A variant file (``defaults: [iplanner_ni, _self_]`` then ``svgp: {nigp_iterations:
    3}``) trained without a word, the value doing nothing; the shipped files list those
    fields at their defaults (for a switch of noisy_input) and stay quiet."""
    import warnings

    from omegaconf import open_dict
    from root_config import root_config

    import iplanner_torch.cli._common as common
    import iplanner_torch.cli.train as cli_train
    from iplanner_torch.errors import ConfigWarning

    monkeypatch.setattr(common, "task_overrides", lambda: [])  # set in the file, not typed
    cfg = root_config(f"predictor={option}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cli_train._refuse_unread_svgp_fields(cfg)  # the shipped file: quiet
    with open_dict(cfg):
        cfg.predictor.svgp.nigp_iterations = 3
    mode = cfg.predictor.svgp.noisy_input
    with pytest.warns(
        ConfigWarning,
        match=rf"sets svgp.nigp_iterations: 3, which noisy_input={mode} does not read",
    ):
        cli_train._refuse_unread_svgp_fields(cfg)


def test_a_predictor_file_that_is_not_a_predictor_config_is_named(tmp_path: Path) -> None:
    """A user's conf/predictor file without ``defaults:`` or ``_target_`` (and without an
    ``svgp`` node) gets the one-line refusal the README promises, not a KeyError from the
    svgp fields' check."""
    (tmp_path / "conf" / "predictor").mkdir(parents=True)
    (tmp_path / "conf" / "predictor" / "mine.yaml").write_text("ivm_max_import: 30\n")
    args = ["-cd", str(tmp_path / "conf"), "predictor=mine", "trainer=fast"]
    res = _run("train", [*args, f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        "error: ConfigError: config node 'predictor' built a dict, not a PredictorCfg: its file "
        "needs '_target_: iplanner_torch.prediction.predictor.PredictorCfg', or, to change only "
        "some fields of an existing file of its group, a first line 'defaults: [<that file>, "
        "_self_]'"
    ]
    assert not (tmp_path / "datasets").exists()
