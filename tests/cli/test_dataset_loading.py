"""How the commands find and read a dataset (``load_dataset``, ``iplanner-data info``): a
``data.path`` given on the command line is never generated, and every format and command
reads ``data.format`` and ``data.windows`` alike."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from root_config import root_config

import iplanner_torch.cli._common as common
from iplanner_torch.cli._common import instantiate, load_dataset
from iplanner_torch.data.windows import WindowCfg
from iplanner_torch.errors import ConfigError, DataError

#: a generator small enough to write in a moment (2 reaching demonstrations)
TINY = ["data.generator.n_targets=2", "data.generator.reaches_per_target=1"]


def _run(module: str, args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run(
        [sys.executable, "-m", f"iplanner_torch.cli.{module}", *args, "progress=false",
         f"hydra.run.dir={cwd / 'run'}"],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def _error_line(res: subprocess.CompletedProcess[str]) -> str:
    """The one line a refused command printed on stderr (exit code 2)."""
    assert res.returncode == 2, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    return lines[0]


@pytest.fixture
def lego(tmp_path: Path) -> Path:
    """A LEGO-assembly-like recording: 2 trials of 12 rows (x, y, z of left_hand, right_hand,
    left_elbow, right_elbow, left_shoulder, right_shoulder), one NaN in a left_hand and one in
    a right_hand coordinate."""
    root = tmp_path / "lego"
    for trial in (1, 2):
        rows = []
        for t in range(12):
            row = [f"{0.1 * j + 0.01 * t + 0.001 * trial:.4f}" for j in range(18)]
            if t == 5 and trial == 1:
                row[0], row[3] = "nan", "nan"  # left_hand x, right_hand x
            rows.append(" ".join(row))
        path = root / "Task1" / "Human1" / f"trial{trial}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(rows) + "\n")
    return root


# --- 1. a data.path given on the command line ---------------------------------------------------


@pytest.mark.parametrize(
    ("module", "args"),
    [
        ("train", ["data.path={missing}", "data.windows.joints=[right_hand]", "trainer=fast"]),
        ("train", ["++data.path={empty}", "trainer=fast"]),
        ("evaluate", ["evaluate.mode=noise_sweep", "data.path={missing}"]),
        (
            "experiment",
            ["run.train_data=data", "data.path={missing}", "run.planners=[iplanner_ni]"],
        ),
    ],
)
def test_a_data_path_given_on_the_command_line_is_never_generated(
    module: str, args: list[str], tmp_path: Path
) -> None:
    """A misspelt ``data.path`` to one's own recordings (``own_csv_hdrr``) or an empty folder
    was filled with 240 synthetic reaching files and trained on, exit 0; every command that
    generates a missing dataset now refuses it in one line, touching nothing."""
    missing, empty = tmp_path / "own_csv_hdrr", tmp_path / "empty"
    empty.mkdir()
    args = [a.format(missing=missing, empty=empty) for a in args]
    if module != "train":
        args.append(f"paths.checkpoints={tmp_path / 'ck'}")
    res = _run(module, args, tmp_path)
    folder = empty if "++data.path" in args[0] else missing
    assert _error_line(res) == (
        f"error: DataError: {folder}: no such dataset folder (or empty); to generate the "
        f"synthetic reaching set there, run `iplanner-data generate data.path={folder}`"
    )
    assert "generating" not in res.stdout
    assert not missing.exists() and not any(empty.iterdir())
    assert not (tmp_path / "datasets").exists()


def test_the_refusal_gives_the_generate_command_of_the_option_asked_for(tmp_path: Path) -> None:
    """The command it suggests writes the dataset the command line describes: its
    ``data=<option>`` and ``data.generator.*`` overrides, quoted as typed."""
    missing = tmp_path / "mine"
    order = "data.generator.order='(0,1)->(2,3)'"
    res = _run("train", ["data=tasks", f"data.path={missing}", "data.generator.n_demos=3", order,
                         "trainer=fast"], tmp_path)  # fmt: skip
    assert _error_line(res).endswith(
        "to generate the synthetic tasks set there, run `iplanner-data generate data=tasks "
        f"data.generator.n_demos=3 \"data.generator.order='(0,1)->(2,3)'\" data.path={missing}`"
    )
    assert not missing.exists()


def test_the_data_options_own_folder_is_still_generated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without ``data.path`` on the command line, the option's own folder
    (``${paths.datasets}/reaching``, also where ``paths.datasets`` moves it) is generated when
    missing or empty, and so is a dataset a command picks itself (iplanner-experiment's task
    sets), whatever the command line says of ``data.path``."""
    from iplanner_torch.cli.experiment import option_node

    given = [f"paths.datasets={tmp_path / 'sets'}", *TINY]
    monkeypatch.setattr(common, "task_overrides", lambda: given)
    cfg = root_config(*given)
    (tmp_path / "sets" / "reaching").mkdir(parents=True)  # empty: generated too
    assert len(load_dataset(cfg.data, generate_if_missing=True, progress=False)) == 2
    assert len(list((tmp_path / "sets" / "reaching").glob("*.npz"))) == 2
    # the rule reads the command line: the same folder given as data.path is refused
    given[:] = [f"data.path={tmp_path / 'other'}", *TINY]
    cfg = root_config(*given)
    with pytest.raises(DataError, match=r"other: no such dataset folder \(or empty\); to "
                       r"generate the synthetic set there, run `iplanner-data generate "
                       r"data\.generator\.n_targets=2 data\.generator\.reaches_per_target=1 "
                       r"data\.path="):  # fmt: skip
        load_dataset(cfg.data, generate_if_missing=True, progress=False)
    node = option_node("data", "reaching", cfg)  # not the data node the command line sets
    node.path = str(tmp_path / "tasks_1x4")
    node.generator.n_targets, node.generator.reaches_per_target = 2, 1
    assert len(load_dataset(node, generate_if_missing=True, progress=False)) == 2
    # without generating (iplanner-evaluate's default), the message is the one it was
    with pytest.raises(DataError, match=r"other: dataset not found; generate it with"):
        load_dataset(cfg.data, progress=False)


def test_a_data_path_in_the_generated_data_home_is_generated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``data.path`` below ``paths.datasets`` names a generated set, not one's own
    recordings (the README trains a task set with ``data.path=datasets/tasks_1x4_...``
    before the experiment has generated it): it is generated when missing; a sibling of the
    home folder is still refused."""
    home = tmp_path / "sets"
    given = [f"paths.datasets={home}", f"data.path={home / 'tasks_1x4'}", *TINY]
    monkeypatch.setattr(common, "task_overrides", lambda: given)
    cfg = root_config(*given)
    assert len(load_dataset(cfg.data, generate_if_missing=True, progress=False)) == 2
    assert len(list((home / "tasks_1x4").glob("*.npz"))) == 2
    given[1] = f"data.path={tmp_path / 'sets_mine'}"  # shares the prefix, not the folder
    cfg = root_config(*given)
    with pytest.raises(DataError, match=r"sets_mine: no such dataset folder \(or empty\)"):
        load_dataset(cfg.data, generate_if_missing=True, progress=False)
    assert not (tmp_path / "sets_mine").exists()


# --- 2. to 5. data.windows and data.format, one check for every format and command ------------


@pytest.mark.parametrize("fmt", ["native", "lego_assembly"])
def test_a_single_joint_string_is_refused_for_every_format(
    fmt: str, lego: Path, tiny_reaching: object
) -> None:
    """``data.windows.joints=right_hand`` (no list): refused for NPZ / CSV folders and, as it
    was not, for the LEGO recording, with the message instantiating the windows gives."""
    path = lego if fmt == "lego_assembly" else tiny_reaching.ds  # type: ignore[attr-defined]
    cfg = root_config("data=lego" if fmt == "lego_assembly" else "data=reaching",
                  f"data.path={path}", "data.windows.joints=right_hand")  # fmt: skip
    text = re.escape(
        "data.windows.joints: expected a list of joint names, got the single string "
        "'right_hand'; write it as a list: [right_hand]"
    )
    with pytest.raises(ConfigError, match=rf"^{text}$"):
        load_dataset(cfg.data, progress=False)
    with pytest.raises(ConfigError, match=rf"^{text}$"):
        instantiate(cfg.data.windows, WindowCfg, name="data.windows")


@pytest.mark.parametrize(
    ("module", "option"),
    [("data", "lego"), ("data", "reaching"), ("train", "lego"), ("train", "reaching")],
)
def test_every_command_refuses_a_single_joint_string_alike(
    module: str, option: str, lego: Path, tiny_reaching: object, tmp_path: Path
) -> None:
    """``iplanner-data info`` took it for any folder and ``iplanner-train`` for data=lego."""
    path = lego if option == "lego" else tiny_reaching.ds  # type: ignore[attr-defined]
    args = ["info"] if module == "data" else ["trainer=fast", f"train.out_dir={tmp_path / 'ck'}"]
    res = _run(module, [*args, f"data={option}", f"data.path={path}",
                        "data.windows.joints=right_hand"], tmp_path)  # fmt: skip
    assert _error_line(res) == (
        "error: ConfigError: data.windows.joints: expected a list of joint names, got the "
        "single string 'right_hand'; write it as a list: [right_hand]"
    )
    assert not (tmp_path / "ck").exists()


def test_info_and_loading_select_the_joints_of_a_lego_recording(lego: Path) -> None:
    """``iplanner-data info data=lego 'data.windows.joints=[right_hand]'`` summarised all 6
    joints and both NaN values; the LEGO trials now hold the selected joints, as files do."""
    res = _run("data", ["info", "data=lego", f"data.path={lego}",
                        "data.windows.joints=[right_hand]"], lego.parent)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "2 demonstrations, 24 frames" in res.stdout
    assert "joints (1): right_hand\n" in res.stdout and "NaN values: 1\n" in res.stdout
    res = _run("data", ["info", "data=lego", f"data.path={lego}"], lego.parent)
    assert res.returncode == 0, res.stderr
    assert "joints (6): " in res.stdout and "NaN values: 2\n" in res.stdout
    cfg = root_config(
        "data=lego", f"data.path={lego}", "data.windows.joints=[right_hand,left_hand]"
    )
    demos = load_dataset(cfg.data, progress=False)
    assert [d.joint_names for d in demos] == [("right_hand", "left_hand")] * 2
    cfg = root_config("data=lego", f"data.path={lego}", "data.windows.joints=[head,right_hand]")
    lacks = r"lego: data\.windows\.joints names \['head'\], which the LEGO assembly recording "
    with pytest.raises(DataError, match=lacks + r"lacks; its joints: \['left_shoulder'"):
        load_dataset(cfg.data, progress=False)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("n_future=0", "data.windows.n_future: expected an integer >= 1, got 0"),
        ("n_future=-5", "data.windows.n_future: expected an integer >= 1, got -5"),
        ("stride=0", "data.windows.stride: expected an integer >= 1, got 0"),
        ("n_prev=2", "data.windows.n_prev: expected an integer >= 3, got 2"),
    ],
)
def test_a_bad_window_setting_names_its_own_key(override: str, message: str) -> None:
    """``data.windows.n_future=0`` was reported as ``data.windows.n_prev: need n_prev >= 3,
    n_future >= 1, stride >= 1; got 30, 0, 2``."""
    cfg = root_config("data=lego", f"data.windows.{override}")
    with pytest.raises(ConfigError, match=rf"^{message}$"):
        instantiate(cfg.data.windows, WindowCfg, name="data.windows")


@pytest.mark.parametrize("value", ["lego", "npz", "LEGO_ASSEMBLY", "1"])
def test_an_unknown_data_format_is_refused(value: str, tiny_reaching: object) -> None:
    """``+data.format=lego`` was read as native files without a word."""
    path = tiny_reaching.ds  # type: ignore[attr-defined]
    cfg = root_config(f"data.path={path}", f"+data.format={value}")
    got = repr(int(value)) if value.isdigit() else repr(value)
    with pytest.raises(ConfigError, match=rf"^data\.format: expected one of native, "
                       rf"lego_assembly, got {got} \(native: "):  # fmt: skip
        load_dataset(cfg.data, progress=False)
    cfg = root_config(f"data.path={path}", "+data.format=native")  # the default, spelt out
    assert len(load_dataset(cfg.data, progress=False)) == 10


def test_the_format_is_checked_before_anything_is_generated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(common, "task_overrides", lambda: [f"paths.datasets={tmp_path}"])
    cfg = root_config(f"paths.datasets={tmp_path}", "+data.format=lego", *TINY)
    with pytest.raises(ConfigError, match=r"^data\.format: expected one of"):
        load_dataset(cfg.data, generate_if_missing=True, progress=False)
    assert not (tmp_path / "reaching").exists()


# --- 6. a folder of .txt trials read as demonstration files -------------------------------------


def test_a_folder_of_txt_trials_read_as_files_says_to_use_data_lego(lego: Path) -> None:
    """``iplanner-data info data.path=<the LEGO recording>`` said only "no .npz or .csv
    demonstration files in this folder"."""
    res = _run("data", ["info", f"data.path={lego}"], lego.parent)
    line = _error_line(res)
    assert line.startswith(f"error: DataError: {lego}: no .npz or .csv demonstration files")
    assert line.endswith(
        f"; it holds 2 .txt files: for LEGO-assembly trials use data=lego data.path={lego}"
    )
    cfg = root_config(f"data.path={lego}")
    with pytest.raises(DataError, match=r"; it holds 2 \.txt files: for LEGO-assembly trials "):
        load_dataset(cfg.data, progress=False)
    (lego / "Task1" / "Human1" / "trial2.txt").unlink()
    with pytest.raises(DataError, match=r"; it holds 1 \.txt file: for LEGO-assembly trials "):
        load_dataset(cfg.data, progress=False)
    empty = lego.parent / "nothing"
    (empty / "sub").mkdir(parents=True)
    (empty / "sub" / "notes.md").write_text("no data\n")
    with pytest.raises(DataError, match=r"no \.npz or \.csv demonstration files") as err:
        load_dataset(root_config(f"data.path={empty}").data, progress=False)
    assert ".txt" not in str(err.value)  # no hint without .txt files


@pytest.mark.parametrize(
    "word",
    [
        "data.path=datasets/x",
        "data.generator.order='(0,1)->(2,3)'",
        "data.generator.speeds=[0.5,1.0]",
        "data.path=/tmp/with space",
        'data.note=say "hi" $HOME `x` !',
        "data.note=it's",
        "",
    ],
)
def test_shell_command_splits_back_into_its_words(word: str) -> None:
    """What the commands write as "regenerate with" / "run with" reads back through the
    shell's own word splitting (bash -c, printf of each argument) as the arguments given."""
    import shlex

    from iplanner_torch.cli._common import shell_command

    line = shell_command("prog", word, "progress=false")
    assert shlex.split(line) == ["prog", word, "progress=false"]
    shown = subprocess.run(
        ["bash", "-c", line.replace("prog", "printf '%s\\n'", 1)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert shown == f"{word}\nprogress=false\n"


@pytest.mark.parametrize(
    "value",
    [
        "datasets/x",
        "2024",
        "1.5",
        "true",
        "null",
        "a,b",
        "x[1]",
        "it's",
        "k=v",
        "a b",
        "e\\",
        "q\\'x",
    ],
)
def test_override_word_reaches_hydra_as_the_string_given(value: str) -> None:
    """The shell splits the word back (shlex) and Hydra's override parser reads the string."""
    import shlex

    from hydra.core.override_parser.overrides_parser import OverridesParser

    from iplanner_torch.cli._common import override_word

    (word,) = shlex.split(override_word("data.path", value))
    (parsed,) = OverridesParser.create().parse_overrides([word])
    assert parsed.key_or_group == "data.path" and parsed.value() == value


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["data=lego", "data.path={lego}"],
            r"error: ConfigError: run\.train_data=data with a LEGO assembly recording .*its 6 "
            r"arm joints are not the simulated person's 10",
        ),
        (
            ["data.path={lego}", "data.windows.joints=[left_hand,right_hand]"],
            r"error: ConfigError: data\.windows\.joints=\['left_hand', 'right_hand'\]: the "
            r"closed loop forecasts every joint",
        ),
        (
            ["data.path={lego}", "+data.fps=30"],
            r"error: ConfigError: data\.fps=30, but the tracker samples the person at "
            r"sim\.tracker_fps=15 Hz",
        ),
    ],
)
def test_an_experiment_refuses_training_data_its_loop_cannot_use(
    args: list[str], message: str, lego: Path, tmp_path: Path
) -> None:
    """With run.train_data=data, a predictor of other joints or another rate than the
    simulated person's is refused before anything is trained or run (it failed with a shape
    error in the first I-Planner episode, after training and the ITOMP episodes)."""
    args = [a.format(lego=lego) for a in args]
    ck = tmp_path / "ck"
    res = _run(
        "experiment",
        [
            "run.train_data=data",
            *args,
            "run.planners=[itomp,iplanner_ni]",
            f"paths.checkpoints={ck}",
        ],
        tmp_path,
    )
    assert re.fullmatch(message + ".*", _error_line(res))
    assert not ck.exists()
    assert not list((tmp_path / "run").glob("episodes/*"))
