"""The ``data`` group refuses keys no command reads, as every other config group does: a
misspelt ``fsp: 60.0`` in a ``conf/data`` file used to leave the frame rate at 30 Hz without a
word."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import DictConfig, OmegaConf, open_dict
from root_config import root_config

from iplanner_torch.cli._common import (
    CONF_DIR,
    DATA_KEYS,
    check_data_keys,
    data_format,
    data_fps,
    data_settings,
    dataset_generator,
)
from iplanner_torch.errors import ConfigError

DATA_OPTIONS = sorted(p.stem for p in (Path(CONF_DIR) / "data").glob("*.yaml"))
EXPERIMENTS = sorted(p.stem for p in (Path(CONF_DIR) / "experiment").glob("*.yaml"))


@pytest.mark.parametrize("option", DATA_OPTIONS)
def test_every_shipped_data_option_passes(option: str) -> None:
    """Every conf/data file, composed or loaded alone (as iplanner-experiment loads the task
    and reaching sets), holds only known keys; so do the optional keys a command line adds."""
    cfg = root_config(f"data={option}")
    check_data_keys(cfg.data)
    data_settings(cfg.data)
    check_data_keys(OmegaConf.load(Path(CONF_DIR) / "data" / f"{option}.yaml"))
    added = ["+data.format=native"] if "format" not in cfg.data else []
    added += ["+data.fps=60"] if "fps" not in cfg.data else ["data.fps=60"]
    cfg = root_config(f"data={option}", *added)
    assert data_fps(cfg.data) == 60.0


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_leaves_only_known_data_keys(experiment: str) -> None:
    check_data_keys(root_config(f"experiment={experiment}").data)


def _with(cfg: DictConfig, **changes: object) -> DictConfig:
    with open_dict(cfg):
        for key, value in changes.items():
            if value is None:
                del cfg.data[key]
            else:
                cfg.data[key] = value
    return cfg


def test_a_misspelt_data_key_is_refused_naming_it_and_the_known_keys() -> None:
    cfg = _with(root_config("data=lego"), fps=None, fsp=60.0)
    known = ", ".join(DATA_KEYS)
    for read in (data_fps, data_format, data_settings, check_data_keys):
        with pytest.raises(ConfigError) as err:
            read(cfg.data)
        assert str(err.value) == (
            "unknown key 'data.fsp' (did you mean 'data.fps'?) in the data config, which "
            f"nothing reads; data keys: {known}"
        )
    cfg = _with(root_config("data=reaching"), overwrite=None, overwrit=True)
    with pytest.raises(ConfigError, match=r"unknown key 'data\.overwrit' \(did you mean "):
        dataset_generator(cfg.data)  # iplanner-data generate reads the node through here
    cfg = _with(root_config("data=tasks"), colour="blue")
    with pytest.raises(ConfigError, match=r"^unknown key 'data\.colour' in the data config, "):
        data_settings(cfg.data)


def test_a_misspelt_key_in_a_data_file_ends_the_command_in_one_line(tmp_path: Path) -> None:
    """The audit's case: conf/data/lego.yaml copied with ``fps: 30.0`` made ``fsp: 60.0``."""
    text = (Path(CONF_DIR) / "data" / "lego.yaml").read_text(encoding="utf-8")
    assert "\nfps: 30.0\n" in text
    (tmp_path / "myconf" / "data").mkdir(parents=True)
    (tmp_path / "myconf" / "data" / "lego60.yaml").write_text(
        text.replace("\nfps: 30.0\n", "\nfsp: 60.0\n"), encoding="utf-8"
    )
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    env.pop("HYDRA_FULL_ERROR", None)
    res = subprocess.run(
        [sys.executable, "-m", "iplanner_torch.cli.data", "info",
         "--config-dir", str(tmp_path / "myconf"), "data=lego60",
         f"data.path={tmp_path / 'nowhere'}", "progress=false",
         f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    assert res.stderr.strip().splitlines() == [
        "error: ConfigError: unknown key 'data.fsp' (did you mean 'data.fps'?) in the data "
        f"config (data=lego60), which nothing reads; data keys: {', '.join(DATA_KEYS)}"
    ]
