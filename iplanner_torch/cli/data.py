"""``iplanner-data``: generate synthetic human motion datasets and check dataset folders.

Usage: ``iplanner-data COMMAND [overrides...]`` (Hydra overrides of ``conf/``; no COMMAND
runs ``generate``; ``-h`` or ``--help`` anywhere prints this help).

Commands:

    generate   write a synthetic dataset (one file per demonstration and a dataset card,
               README.md) into data.path; refuses when data.path already holds
               demonstration files unless data.overwrite=true. The files are written into
               <data.path>.partial-<pid> beside it and moved in when all are written, so a
               failed or interrupted run leaves data.path as it was
    info       load and check every file of data.path (as training does) and summarise it:
               counts, joints, actions, fps, NaN values, joints lost in every frame,
               and whether the counts agree with a generated folder's card (README.md)

Config group and main options:

    data=reaching|tasks|lego       the dataset (conf/data/<option>.yaml; default reaching):
                                   reaching = synthetic reaches -> datasets/reaching,
                                   tasks = synthetic task demonstrations -> datasets/tasks,
                                   lego = the recorded LEGO assembly set (info only) at
                                   ../shared/data/lego_assembly_3d
    data.path=<folder>             the dataset folder (relative to the current directory);
                                   iplanner-train and the other commands never generate
                                   one given this way outside paths.datasets: generate
                                   writes it
    paths.datasets=<folder>        the folder of the generated sets (default datasets):
                                   data=reaching and data=tasks put their data.path in it
    data.overwrite=true            generate: replace the demonstration files (.npz, .csv) and
                                   dataset card already in data.path, nothing else; they are
                                   deleted only once the new set is complete
    data.generator.<field>=<value> generate: a generator setting (info and iplanner-train
                                   check them too); the main fields are
        reaching: reaches_per_target, n_targets, n_subjects, fps, noise_sigma, speeds, seed
        tasks: order, arrangement, n_demos, n_subjects, fps, noise_sigma, seed, file_format
    data.windows.joints=[a,b]      info: check only these joints, as training selects them
                                   (a list, also of one: [right_hand]; any format)
    progress=false                 generate: no progress bar

Other overrides (seed, trainer, ...) are refused: neither command reads them; the generator
draws from data.generator.seed.

Examples:

    iplanner-data generate              # synthetic reaching set -> datasets/reaching
    iplanner-data generate data.generator.reaches_per_target=5 data.path=datasets/small
    iplanner-data generate data.path=datasets/small data.overwrite=true   # replace it
    iplanner-data generate data=tasks   # task demonstrations (take objects in a task order)
    iplanner-data info data=lego        # check and summarise a dataset folder
    iplanner-data info data.path=my_recordings
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import hydra
import numpy as np
from omegaconf import DictConfig

from iplanner_torch.cli._common import (
    CONF_DIR,
    check_added_keys,
    check_root_keys,
    data_format,
    data_fps,
    dataset_generator,
    friendly_errors,
    instantiate,
    override_word,
    print_help_if_asked,
    read_demonstrations,
    refuse_unread_overrides,
    repo_path,
    run_app,
    shell_command,
    write_job_record,
)
from iplanner_torch.errors import ConfigError, DataError

COMMANDS = ("generate", "info")
#: Files listed by name in ``info``'s report before the rest are counted.
_MAX_LISTED = 10
_command = "generate"


def _generate_settings(cfg: DictConfig) -> tuple[bool, Any, Any]:
    """``data.overwrite`` and the generator settings with their function
    (:func:`~iplanner_torch.cli._common.dataset_generator`), checked.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    overwrite = cfg.data.get("overwrite", False)
    if not isinstance(overwrite, bool):
        raise ConfigError(f"data.overwrite: expected true or false, got {overwrite!r}")
    gen_cfg, generate = dataset_generator(cfg.data, name="data.generator")
    return overwrite, gen_cfg, generate


def check_job(cfg: DictConfig) -> dict[str, Path]:
    """What a sweep checks of each ``iplanner-data`` job before the first starts: the overrides
    it does not read and, for ``generate``, every setting of the set; for ``info``, the
    settings it reads before any file (:func:`_info_settings`).

    Returns:
        ``{"data.path": folder}`` for ``generate`` (two jobs would write the same set), ``{}``
        for ``info``, which writes nothing.

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    check_added_keys(cfg)
    _refuse_unread(cfg)
    check_root_keys(cfg)
    if _command != "generate":
        _info_settings(cfg)
        return {}
    _generate_settings(cfg)
    return {"data.path": repo_path(cfg.data.path)}


def _generate(cfg: DictConfig) -> None:
    from iplanner_torch.data.dataset_card import CARD_NAME, check_dataset_folder

    out_dir = repo_path(cfg.data.path)
    # every setting is checked before the folder is touched
    overwrite, gen_cfg, generate = _generate_settings(cfg)
    old = check_dataset_folder(out_dir, overwrite=overwrite)
    t0 = time.perf_counter()
    command = shell_command("iplanner-data", "generate", *sys.argv[1:])
    # written beside out_dir first; the earlier files go only once the new set is complete
    summary = generate(gen_cfg, out_dir, progress=bool(cfg.progress), command=command, replace=old)
    if old:
        had_card = out_dir / CARD_NAME in old
        card = " and its dataset card" if had_card else ""
        print(f"deleted {len(old) - had_card} earlier demonstration files{card} in {out_dir}")
    mb = summary.bytes_on_disk / 1e6
    seconds = time.perf_counter() - t0
    print(
        f"wrote {summary.n_demonstrations} demonstrations ({summary.n_frames} frames, {mb:.1f} MB)"
        f" to {out_dir} in {seconds:.1f} s; dataset card: {out_dir / 'README.md'}"
    )
    write_job_record(
        JOB_RECORD,
        {
            "dataset": str(out_dir),
            "demonstrations": summary.n_demonstrations,
            "frames": summary.n_frames,
            "megabytes": round(mb, 3),
            "seconds": round(seconds, 2),
        },
    )


#: the record each iplanner-data run writes into its own run folder, gathered into a
#: sweep's summary table (:data:`~iplanner_torch.cli.callbacks.JOB_METRICS_FILES`)
JOB_RECORD = "dataset_summary.json"


def _kept_on_interrupt(cfg: DictConfig) -> str:
    """The ``interrupted: ...`` text of an iplanner-data command."""
    if _command != "generate":
        return "nothing to keep: info reads files and writes none"
    from iplanner_torch.data.dataset_card import partial_folder

    out_dir = repo_path(cfg.data.path)
    return (
        f"{out_dir} is left as it was, an earlier dataset there included (unless the new one "
        f"was complete and had replaced it); the unfinished files in {partial_folder(out_dir)} "
        "were deleted"
    )


def _info_settings(cfg: DictConfig) -> tuple[str, tuple[str, ...] | None]:
    """The settings ``info`` reads, checked before any file is: the data format and, from
    the window settings training reads (``data.windows.joints`` selects the joints, so info
    accepts what training accepts), the selected joints (None: all).

    Raises:
        ConfigError: naming the key, for the first setting that is wrong.
    """
    fmt = data_format(cfg.data)
    data_fps(cfg.data)
    if cfg.data.get("generator") is not None:  # checked as training checks it
        dataset_generator(cfg.data, name="data.generator")
    selected = None
    if "windows" in cfg.data:
        from iplanner_torch.data.windows import WindowCfg

        selected = instantiate(cfg.data.windows, WindowCfg, name="data.windows").joints
    return fmt, selected


def _info(cfg: DictConfig) -> None:
    from iplanner_torch.data.io import demonstration_files, lost_joints

    path = repo_path(cfg.data.path)
    fmt, selected = _info_settings(cfg)
    if fmt == "native" and not path.exists():
        hint = "set data.path=<folder>"
        if cfg.data.get("generator") is not None:
            gen = f"iplanner-data generate {override_word('data.path', cfg.data.path)}"
            hint = f"generate it with `{gen}` or {hint}"
        raise DataError(f"{path}: no such file or folder; {hint}")
    demos = read_demonstrations(cfg.data, path)
    if fmt == "lego_assembly":
        root = path if path.is_dir() else path.parent
        files = [root / f"{d.name}.txt" for d in demos]
    else:
        files = demonstration_files(path)
    if demos:  # the cross-file checks training makes (action names, fps, joints)
        from iplanner_torch.data.windows import compatible_demonstrations

        compatible_demonstrations(demos, selected)
    frames = sum(d.num_frames for d in demos)
    joints = demos[0].joint_names if demos else ()
    actions = demos[0].action_names if demos else ()
    nan = sum(int(np.isnan(d.positions).sum()) for d in demos)
    print(f"{path}: {len(demos)} demonstrations, {frames} frames")
    write_job_record(
        JOB_RECORD,
        {"dataset": str(path), "demonstrations": len(demos), "frames": frames,
         "joints": len(joints), "actions": len(actions), "nan_values": nan},
    )  # fmt: skip
    print(f"  joints ({len(joints)}): {', '.join(joints)}")
    print(f"  actions ({len(actions)}): {', '.join(actions)}")
    print(f"  fps: {sorted({d.fps for d in demos})}; NaN values: {nan}")
    if path.is_dir():
        from iplanner_torch.data.dataset_card import CARD_NAME, card_mismatch, read_card_counts

        counts = read_card_counts(path)
        differ = card_mismatch(path, len(demos), frames)
        if differ:
            print(f"  dataset card: {differ}")
        elif counts:
            print(f"  dataset card: {CARD_NAME} agrees ({len(demos)} demonstrations, {frames} "
                  "frames)")  # fmt: skip
    lost = [(f, names) for f, d in zip(files, demos, strict=True) if (names := lost_joints(d))]
    if lost:
        print(
            f"  joints NaN in every frame in {len(lost)} file(s) (windows fill them from a "
            "neighbouring joint):"
        )
        for f, names in lost[:_MAX_LISTED]:
            print(f"    {f}: {', '.join(names)}")
        if len(lost) > _MAX_LISTED:
            print(f"    ... and {len(lost) - _MAX_LISTED} more")


def _refuse_unread(cfg: DictConfig) -> None:
    """Refuse the overrides iplanner-data does not read (before their values are checked)."""
    refuse_unread_overrides(
        f"iplanner-data {_command}",
        ("data", "paths.datasets"),
        "it reads data, paths.datasets and progress (a generated set draws from "
        "data.generator.seed, not seed)",
    )


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors(before=_refuse_unread, kept=_kept_on_interrupt)
def _app(cfg: DictConfig) -> None:
    {"generate": _generate, "info": _info}[_command](cfg)


def main() -> None:
    """Console entry point: ``iplanner-data {generate,info} [overrides...]``."""
    global _command
    args = sys.argv[1:]
    print_help_if_asked(
        __doc__ or "",
        args,
        groups=("data",),
        root_keys="progress=true|false (a generated set draws from data.generator.seed)",
    )
    at = command_index(args)
    if at is not None:
        if args[at] not in COMMANDS:
            msg = f"error: unknown command {args[at]!r}; expected one of {COMMANDS}"
            print(msg, file=sys.stderr)
            raise SystemExit(2)
        _command = args.pop(at)
        sys.argv = [sys.argv[0], *args]
    _drop_command_from_completion_line()
    run_app(_app)


def _drop_command_from_completion_line() -> None:
    """Hydra's shell completion (``-sc query=bash``) reads the line typed so far from
    ``COMP_LINE``, where the command word (``iplanner-data generate data.gen``) read as an
    override it cannot parse: no suggestion came once a command was typed. The word is
    taken out of the line (and ``COMP_POINT``, the cursor, moved back by it)."""
    import os

    line = os.environ.get("COMP_LINE")
    if not line:
        return
    words = line.split(" ")
    if len(words) < 2 or words[1] not in COMMANDS:
        return
    os.environ["COMP_LINE"] = " ".join([words[0], *words[2:]])
    point = os.environ.get("COMP_POINT")
    if point is not None and point.isdigit():
        cut = len(words[0]) + 1  # where the command word starts
        os.environ["COMP_POINT"] = str(max(cut, int(point) - len(words[1]) - 1))


#: Hydra's flags that take the next word as their value (``--cfg job``, ``-cn config``)
_VALUE_FLAGS = frozenset(
    ("--cfg", "-c", "--package", "-p", "--config-path", "-cp", "--config-name", "-cn",
     "--config-dir", "-cd", "--experimental-rerun")
)  # fmt: skip
#: the values of Hydra's ``--info`` (``-i``), whose value may be left out
_INFO_VALUES = frozenset(("all", "config", "defaults", "defaults-tree", "plugins", "searchpath"))


def command_index(args: list[str]) -> int | None:
    """The place of the command word in ``args`` (``generate`` in ``-m generate seed=1``):
    the first word that is not a flag, a flag's value, nor an override (``key=value``,
    ``~key``); None when there is none (``generate`` by default)."""
    value_next = False
    for i, arg in enumerate(args):
        if value_next:
            value_next = False
            continue
        if arg.startswith("-"):
            value_next = arg in _VALUE_FLAGS or (
                arg in ("--info", "-i") and i + 1 < len(args) and args[i + 1] in _INFO_VALUES
            )
            continue
        if "=" in arg or arg.startswith("~"):
            continue
        return i
    return None


if __name__ == "__main__":
    # one module under both names: a sweep's check of its jobs imports this one by name
    # (callbacks.JOB_CHECKS) and must read the command word this run was given
    sys.modules.setdefault("iplanner_torch.cli.data", sys.modules[__name__])
    main()
