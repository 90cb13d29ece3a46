"""Hydra callbacks: check every job of a sweep before the first runs, and gather the sweep's
episode logs into one table and plots when it ends."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NoReturn

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from iplanner_torch.cli import SPIN_SET_MARK

#: numeric columns a sweep may vary, in the order they are preferred as the x axis of the
#: sweep plots (the other swept settings lay out their panels; seeds are repeats, not a
#: setting, and are never plotted against)
SWEEP_COLUMNS = ("noise", "dropout", "confidence")


def sweep_overrides(df: Any, root: Path) -> tuple[Any, list[str]]:
    """Add to episode rows ``df`` the command-line overrides that differ between the jobs of
    the multirun folder ``root``.

    Each job folder below ``root`` keeps its overrides in ``.hydra/overrides.yaml``; a row
    belongs to the job folder its log ``path`` lies in. Every override key whose value is not
    the same in all jobs (e.g. ``planner.itomp_spread_mps`` in ``-m
    planner.itomp_spread_mps=0,0.1``) becomes a column named by the key, holding the job's
    value (a number where it reads as one). A key that is already a column of ``df`` (e.g.
    ``planner=itomp`` or ``seed=1`` against the episodes' own ``planner`` and ``seed``) gets
    the column ``override.<key>`` instead, so the episodes' values are never replaced.

    Returns:
        ``(rows, columns)``: the rows with those columns, and the columns' names in the order
        the jobs give the keys; ``(df, [])`` when ``df`` has no ``path`` column or no job
        folder has overrides.
    """
    import pandas as pd
    from omegaconf import OmegaConf

    if "path" not in df.columns:
        return df, []
    root = Path(root).resolve()
    jobs: dict[str, dict[str, str]] = {}
    for file in sorted(root.glob("*/.hydra/overrides.yaml")):
        try:
            items = OmegaConf.to_container(OmegaConf.load(file))
        except Exception:  # noqa: BLE001 - an unreadable job record only loses its columns
            continue
        if not isinstance(items, list):
            continue
        pairs = [_unescaped(str(x)).lstrip("+~").split("=", 1) for x in items if "=" in str(x)]
        jobs[file.parent.parent.name] = {k: v for k, v in pairs if not k.startswith("hydra")}
    if len(jobs) < 2:
        return df, []
    keys = list(dict.fromkeys(k for o in jobs.values() for k in o))
    swept = [k for k in keys if len({o.get(k) for o in jobs.values()}) > 1]
    if not swept:
        return df, []

    def job_of(path: Any) -> str | None:
        try:
            return Path(str(path)).resolve().relative_to(root).parts[0]
        except (ValueError, IndexError):
            return None

    job = df["path"].map(job_of)
    out = df.copy()
    columns = []
    for k in swept:
        values = job.map(lambda j, k=k: jobs.get(j, {}).get(k) if j is not None else None)
        numbers = pd.to_numeric(values, errors="coerce")
        name = f"override.{k}" if k in df.columns else k
        out[name] = numbers if bool(numbers.notna().eq(values.notna()).all()) else values
        columns.append(name)
    return out, columns


#: override keys ending in these name repeats of one setting, never a setting to keep apart
REPEAT_KEYS = ("seed", "seeds")


def split_columns(df: Any, groups: tuple[str, ...], extra: list[str]) -> list[str]:
    """The columns of ``extra`` that take several values within a group of ``groups``: those a
    summary by ``groups`` would average over. Seeds (:data:`REPEAT_KEYS`, e.g.
    ``experiment.seeds`` split over two jobs) are repeats and never kept apart."""
    keys = list(groups)
    out = []
    for c in extra:
        if c not in df.columns or c in groups or c.rsplit(".", 1)[-1] in REPEAT_KEYS:
            continue
        if keys:
            values = int(df.groupby(keys, dropna=False)[c].nunique(dropna=False).max())
        else:
            values = int(df[c].nunique(dropna=False))
        if values > 1:
            out.append(c)
    return out


def episode_report(
    df: Any, out_dir: Path, baseline: str = "itomp", split_by: list[str] | None = None
) -> list[Path]:
    """Write the report of per-episode results ``df`` into ``out_dir``.

    The summary keeps every setting that takes several values apart
    (:func:`~iplanner_torch.eval.report.report_groups`), and also each column of ``split_by``
    (e.g. the swept overrides of :func:`sweep_overrides`) that those groups would average
    over; the sweep plots put the first of :data:`SWEEP_COLUMNS` that varies on their x axis;
    the paired section compares each planner with ``baseline``.

    Returns:
        The written files (``results.csv``, ``results.md``, PNGs).
    """
    from iplanner_torch.eval.report import report_groups, write_sweep_report

    sweep = next(
        (
            c
            for c in SWEEP_COLUMNS
            if c in df.columns and df[c].nunique() > 1 and df[c].dtype.kind in "fi"
        ),
        None,
    )
    groups = report_groups(df)
    extra = split_columns(df, groups, list(split_by or []))
    if extra:  # ("scenario", swept settings, ..., "planner"): the overrides go before planner
        groups = (*groups[:-1], *extra, groups[-1])
    return write_sweep_report(df, out_dir, group_by=groups, sweep=sweep, baseline=baseline)


def run_rows(root: Path) -> Any:
    """The episode rows of a run or multirun folder: one per ``*.mcap`` below ``root`` (in
    numbered order, :func:`~iplanner_torch.eval.report.episode_logs`: not the ones a resumed
    run set aside), then the ``results.csv`` rows of each run folder (``root`` itself or a job
    folder directly below it, one with ``.hydra/``) that holds no episode log, as a run with
    ``run.write_mcap=false`` leaves it. Each row has a ``path`` (its log, or that
    ``results.csv``), so :func:`sweep_overrides` can place it in its job. A gathered summary
    (``summary/results.csv``, no ``.hydra/``) is never read back.

    Returns:
        A DataFrame; empty when the folder holds neither.
    """
    import pandas as pd

    from iplanner_torch.eval.report import episode_logs, gather_results, natural_key

    root = Path(root)
    if not root.is_dir():
        return pd.DataFrame()
    frames = [gather_results(root)] if episode_logs(root) else []
    runs = [root, *sorted((d for d in root.iterdir() if d.is_dir()), key=natural_key)]
    for run in runs:
        csv = run / "results.csv"
        if (run / ".hydra").is_dir() and csv.is_file() and not episode_logs(run):
            rows = gather_results(csv)
            if not rows.empty:
                frames.append(rows.assign(path=str(csv)))
    frames = [f for f in frames if not f.empty]
    if not frames:
        return pd.DataFrame()
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def gather_episode_logs(root: Path, out_dir: Path) -> list[Path]:
    """Read the episode rows of ``root`` (:func:`run_rows`: every ``*.mcap`` below it, and the
    ``results.csv`` of jobs that wrote no log) and report them into ``out_dir``
    (:func:`episode_report`), with the overrides that differ between the jobs of a multirun
    as columns kept apart in the summary (:func:`sweep_overrides`).

    Returns:
        The written files, or [] when there are no episode rows.
    """
    df = run_rows(root)
    if df.empty:
        return []
    df, swept = sweep_overrides(df, root)  # numbered order kept
    return episode_report(df, out_dir, split_by=swept)


#: per-job metrics files a sweep of iplanner-train (held-out metrics of the trained predictor),
#: iplanner-evaluate evaluate.mode=prediction or iplanner-data (the dataset's counts) writes
#: into its job folder
JOB_METRICS_FILES = ("heldout_metrics.json", "prediction_metrics.json", "dataset_summary.json")

#: metrics drawn in a metrics sweep's plot, when the jobs report them, with their titles
#: (see :mod:`iplanner_torch.eval.prediction`)
PLOTTED_METRICS = {
    "mhd_1s": "hand MHD over 1 s [m]",
    "class_accuracy": "action accuracy",
    "coverage95": "95% ellipsoid coverage",
    "reg_precision": "regression precision [m^2 s]",
    "train_seconds": "training time [s]",
}


def job_metrics_rows(root: Path) -> Any:
    """One row per job folder of the multirun folder ``root`` that holds a metrics file
    (:data:`JOB_METRICS_FILES`): ``job`` (the folder's name), the file's numbers and ``path``.
    A file that does not read as a JSON object (damaged, or nested too deep for the parser)
    only loses its row.

    Returns:
        A DataFrame in job order; empty when no job wrote one.
    """
    import json

    import pandas as pd

    from iplanner_torch.eval.report import natural_key

    root = Path(root)
    if not root.is_dir():
        return pd.DataFrame()
    rows = []
    for job in sorted((d for d in root.iterdir() if (d / ".hydra").is_dir()), key=natural_key):
        file = next((job / n for n in JOB_METRICS_FILES if (job / n).is_file()), None)
        if file is None:
            continue
        try:
            record = json.loads(file.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):  # a damaged file only loses its row
            continue  # RecursionError: arrays or objects nested too deep for the parser
        if not isinstance(record, dict):
            continue
        values = {k: v for k, v in record.items() if isinstance(v, int | float | str)}
        rows.append({"job": job.name, **values, "path": str(file)})
    return pd.DataFrame.from_records(rows)


def gather_job_metrics(root: Path, out_dir: Path, *, echo: bool = False) -> list[Path]:
    """Report the per-job metrics of a multirun folder (:func:`job_metrics_rows`) into
    ``out_dir``: ``results.csv`` and ``results.md`` with a row per job and the overrides that
    differ between the jobs as columns (:func:`sweep_overrides`), and ``metrics.png``: the
    metrics of :data:`PLOTTED_METRICS` against the first swept override (its values in job
    order when they are not numbers). With ``echo``, also print a table of the jobs, the
    swept overrides and those metrics (the files hold every metric).

    Returns:
        The written files, or [] when no job wrote metrics.
    """
    from iplanner_torch.eval.report import to_markdown

    df = job_metrics_rows(root)
    if df.empty:
        return []
    df, swept = sweep_overrides(df, root)
    front = ["job", *swept]
    df = df[front + [c for c in df.columns if c not in front and c != "path"] + ["path"]]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    csv, md = out_dir / "results.csv", out_dir / "results.md"
    df.to_csv(csv, index=False)
    md.write_text(
        f"# Sweep of {Path(root).resolve()}\n\nOne row per job; the `path` column of "
        "`results.csv` names each job's metrics file.\n\n" + to_markdown(df.drop(columns="path")),
        encoding="utf-8",
    )
    written = [csv, md]
    if echo:  # the plotted metrics; a dataset sweep's counts (it has none of them)
        plotted = [c for c in PLOTTED_METRICS if c in df.columns]
        shown = df[front + (plotted or [c for c in df.columns if c not in (*front, "path")])]
        print(shown.to_string(index=False, float_format=lambda x: f"{x:.4g}"), flush=True)
    plot = _plot_job_metrics(df, swept, out_dir / "metrics.png")
    if plot is not None:
        written.append(plot)
    return written


def _plot_job_metrics(df: Any, swept: list[str], path: Path) -> Path | None:
    """One panel per metric of :data:`PLOTTED_METRICS` in ``df``, against ``swept[0]`` (a
    line over numeric values, else the jobs' values as categories); None when there is no
    swept override or no such metric."""
    import numpy as np
    import pandas as pd
    from matplotlib.figure import Figure

    metrics = [m for m in PLOTTED_METRICS if m in df.columns]
    if not swept or not metrics:
        return None
    x_col = swept[0]
    numeric = pd.api.types.is_numeric_dtype(df[x_col])
    fig = Figure(figsize=(3.4 * len(metrics) + 0.6, 3.4))
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(1, len(metrics), i + 1)
        y = pd.to_numeric(df[m], errors="coerce")
        if numeric:
            order = np.argsort(df[x_col].to_numpy(dtype=float), kind="stable")
            ax.plot(df[x_col].to_numpy(dtype=float)[order], y.to_numpy()[order], "o-")
        else:
            ax.plot(np.arange(len(df)), y.to_numpy(), "o")
            ax.set_xticks(np.arange(len(df)))
            ax.set_xticklabels([str(v) for v in df[x_col]], rotation=25, ha="right")
            ax.set_xlim(-0.5, len(df) - 0.5)
        ax.set_xlabel(x_col, fontsize="small")
        ax.set_title(f"{PLOTTED_METRICS[m]}\n({m})", fontsize="medium")
        ax.grid(alpha=0.3)
    if len(swept) > 1:
        fig.suptitle(f"one point per job; also varied: {', '.join(swept[1:])}", fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def failed_jobs(sweep_dir: Path) -> list[tuple[Path, str, str]]:
    """The jobs of a multirun folder that failed: ``(job folder, its overrides, its error
    line)`` for each job folder holding a :data:`~iplanner_torch.cli._common.FAILED_MARKER`,
    in job order."""
    from omegaconf import OmegaConf

    from iplanner_torch.cli._common import FAILED_MARKER

    def order(path: Path) -> tuple[int, str]:
        name = path.parent.name
        return (int(name), "") if name.isdigit() else (1 << 30, str(path))

    out = []
    for marker in sorted(Path(sweep_dir).rglob(FAILED_MARKER), key=order):
        job = marker.parent
        overrides = job / ".hydra" / "overrides.yaml"
        try:
            items = OmegaConf.load(overrides) if overrides.exists() else []
            text = " ".join(_unescaped(str(o)) for o in items)  # type: ignore[union-attr]
        except Exception:  # noqa: BLE001 - a damaged overrides file still names the job
            text = "?"
        try:  # the error line; an unexpected error's traceback follows it
            lines = marker.read_text(encoding="utf-8").strip().splitlines()
            error = lines[0] if lines else "?"
        except (OSError, UnicodeDecodeError) as exc:  # the job is named all the same
            error = f"? ({marker} does not read: {exc})"
        out.append((job, text, error))
    return out


#: what a run folder holds once it has results: an experiment's (or an episode report's)
#: table and its episode logs, or a training or evaluation job's metrics
RESULT_FILES = ("results.csv", "episodes", *JOB_METRICS_FILES)


def used_job_dirs(sweep_dir: Path) -> list[Path]:
    """The job folders of the multirun folder ``sweep_dir`` that hold an earlier sweep's
    results: each folder directly below it with Hydra's ``.hydra/`` record and one of
    :data:`RESULT_FILES`, in numbered order. A job that failed before writing any (only its
    :data:`~iplanner_torch.cli._common.FAILED_MARKER`) is not one."""
    from iplanner_torch.eval.report import natural_key

    root = Path(sweep_dir)
    if not root.is_dir():
        return []
    jobs = [
        d
        for d in root.iterdir()
        if (d / ".hydra").is_dir() and any((d / name).exists() for name in RESULT_FILES)
    ]
    return sorted(jobs, key=natural_key)


def used_sweep_dir_text(sweep_dir: Path) -> str | None:
    """The refusal of a multirun into ``sweep_dir`` when its job folders hold an earlier
    sweep's results (:func:`used_job_dirs`), or None. Hydra would rewrite each job's
    ``.hydra/`` record (its config and overrides) before the job itself refuses to replace
    the results, and the summary would then label the old episodes with the new overrides."""
    used = used_job_dirs(sweep_dir)
    if not used:
        return None
    names = ", ".join(d.name for d in used[:5]) + (", ..." if len(used) > 5 else "")
    return (
        f"{sweep_dir} already holds the results of an earlier sweep (job folder(s) {names}), "
        "whose .hydra/ records this sweep would overwrite; choose another hydra.sweep.dir "
        "(or delete it)"
    )


#: per command (``hydra.job.name``): the function that checks one job's composed config
#: before a sweep starts, as ``module:function``. It raises an
#: :class:`~iplanner_torch.errors.IPlannerError` for a bad setting, and returns the places
#: the job writes outside its own job folder (``{"train.out_dir": folder}``), or None
JOB_CHECKS = {
    "experiment": "iplanner_torch.cli.experiment:check_job",
    "train": "iplanner_torch.cli.train:check_job",
    "evaluate": "iplanner_torch.cli.evaluate:check_job",
    "data": "iplanner_torch.cli.data:check_job",
}


def shared_outputs(
    written: list[tuple[int, dict[str, Any]]],
) -> list[tuple[str, Path, list[int]]]:
    """The places that several jobs of a sweep would write: the later job would replace (or,
    run in parallel, mix into) what the earlier one wrote.

    Args:
        written: per job, ``(job number, {key: path it writes})``; a ``(path, settings)``
            value (a folder of predictors an experiment trains when missing) is shared only
            by jobs that ask for other settings there (:func:`shared_trainings`).

    Returns:
        ``(key, path, job numbers)`` for each path written by more than one job, in job order.
    """
    by_place: dict[tuple[str, Path], list[int]] = {}
    for num, places in written:
        for key, path in places.items():
            if not isinstance(path, tuple):
                by_place.setdefault((key, Path(path)), []).append(num)
    return [(key, path, nums) for (key, path), nums in by_place.items() if len(nums) > 1]


def shared_trainings(
    written: list[tuple[int, dict[str, Any]]],
) -> list[tuple[Path, dict[str, list[int]]]]:
    """The folders of predictors that jobs of a sweep would train with different settings:
    the first job to get there trains them, and a later one stops on the difference (or,
    without those settings on its command line, uses them unchecked).

    Args:
        written: per job, ``(job number, {key: value})``; the ``(path, settings)`` values
            count (:func:`~iplanner_torch.cli.experiment.check_job`).

    Returns:
        ``(folder, {settings: job numbers})`` for each folder asked for with more than one
        setting, in job order.
    """
    by_folder: dict[Path, dict[str, list[int]]] = {}
    for num, places in written:
        for value in places.values():
            if isinstance(value, tuple):
                folder, settings = value
                jobs = by_folder.setdefault(Path(folder), {}).setdefault(str(settings), [])
                if num not in jobs:
                    jobs.append(num)
    return [(folder, asks) for folder, asks in by_folder.items() if len(asks) > 1]


def _job_numbers(nums: list[int]) -> str:
    """``job 3``, ``jobs 0, 2, 4`` (the first eight, then ``...``)."""
    listed = ", ".join(str(n) for n in nums[:8]) + (", ..." if len(nums) > 8 else "")
    return f"job {listed}" if len(nums) == 1 else f"jobs {listed}"


def sweep_job_overrides(config: DictConfig) -> list[list[str]] | None:
    """The overrides of each job of the multirun ``config`` describes, in job order, as
    Hydra's basic sweeper splits them (``hydra.sweeper.params`` first, then the command
    line); None for another sweeper."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    sweeper = config.hydra.get("sweeper")
    if sweeper is None or not str(sweeper.get("_target_", "")).endswith(".BasicSweeper"):
        return None
    # as typed: an override's ${...} (train.out_dir=ck/${hydra:job.num}) is the job's to resolve
    params = sweeper.get("params")
    params = OmegaConf.to_container(params, resolve=False) if params is not None else {}
    task = OmegaConf.to_container(config.hydra.overrides.task, resolve=False)
    given = [f"{k}={v}" for k, v in params.items()] + [str(o) for o in task]
    batches = BasicSweeper.split_arguments(OverridesParser.create().parse_overrides(given), None)
    return [list(job) for batch in batches for job in batch]


def _unescaped(override: str) -> str:
    """A job's override as typed: Hydra's sweeper hands it over with the characters of an
    interpolation escaped (``ck/$\\{hydra\\:job.num\\}``)."""
    import re

    return re.sub(r"\\([\\{}:=,\[\]()'\" ])", r"\1", override)


#: (sweep folder, whether it existed before) of each multirun this process began
#: (:meth:`GatherSweepResults.on_multirun_start`), for :func:`drop_unlaunched_sweep`
STARTED_SWEEPS: list[tuple[Path, bool]] = []
#: what Hydra writes into a sweep folder before its launcher starts a job
_UNLAUNCHED_SWEEP_FILES = frozenset({"multirun.yaml", ".submitit"})


def drop_unlaunched_sweep() -> Path | None:
    """Delete the folder of the sweep this process began when its launcher failed before any
    job (``hydra/launcher=slurm`` off a cluster): a folder this sweep made, holding nothing
    but Hydra's ``multirun.yaml`` (and an empty ``.submitit/``), then its parents left empty
    up to the working folder, as a refused single run's folder is
    (:func:`~iplanner_torch.cli._common.delete_run_dir`). A folder that existed before, or
    holds anything else, is kept.

    Returns:
        The deleted folder, or None.
    """
    from iplanner_torch.cli._common import delete_run_dir

    if not STARTED_SWEEPS:
        return None
    folder, existed = STARTED_SWEEPS[-1]
    try:
        names = {p.name for p in folder.iterdir()}
        submitit = folder / ".submitit"
        if existed or not names <= _UNLAUNCHED_SWEEP_FILES:
            return None
        if submitit.exists() and any(p.is_file() for p in submitit.rglob("*")):
            return None
    except OSError:
        return None
    delete_run_dir(folder, Path.cwd())
    return folder


def _refuse_sweep(text: str) -> NoReturn:
    """Print ``error: ConfigError: <text>`` and end the sweep with exit code 2 before any job
    runs (Hydra turns an exception raised in a callback into a warning; an exit is not one)."""
    import sys

    print(f"error: ConfigError: {text}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def check_sweep_jobs(config: DictConfig) -> int | None:
    """Compose every job of the multirun ``config`` describes and check its settings as the
    job will (:data:`JOB_CHECKS`), before the first job runs; exit 2 naming what is wrong.

    Hydra composes each batch of jobs (``hydra.sweeper.max_batch_size``) only when it comes
    to it, so a job of a later batch with an unknown option or key stopped the sweep midway
    with Hydra's own report: that is one ``error: ConfigError:`` line now. A value that is
    wrong in one job (``planner.confidence=0.95,1.5``) was found only when that job started,
    after the jobs before it had run: every such job is named now, with its overrides, and
    no job runs. Two jobs that would write the same folder outside their job folders
    (``iplanner-train -m predictor.svgp.num_inducing=16,32`` both into the default
    ``train.out_dir``) are refused too: the later would replace the earlier's predictor, or
    mix with it when they run in parallel. A check that fails other than on a bad setting (a
    bug) is left to the job, which reports it with its traceback.

    Returns:
        The number of jobs; None for a sweeper other than Hydra's basic one (not checked).

    Raises:
        SystemExit: with code 2, after printing the error lines (Hydra turns an exception
            raised in a callback into a warning; an exit is not one).
    """
    import copy
    import importlib

    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from iplanner_torch.cli._common import check_added_hydra_keys, composition_error_text
    from iplanner_torch.errors import IPlannerError

    try:  # +hydra.launcher.n_job=2 would otherwise run the jobs one at a time
        check_added_hydra_keys(config.hydra)
    except IPlannerError as exc:
        _refuse_sweep(str(exc))
    jobs = sweep_job_overrides(config)
    if not jobs:
        return None if jobs is None else 0
    target = JOB_CHECKS.get(str(config.hydra.job.get("name", "")))
    check = None
    if target is not None:
        module, _, name = target.partition(":")
        check = getattr(importlib.import_module(module), name)
    loader = GlobalHydra.instance().config_loader()
    hydra_config = HydraConfig.instance()
    saved = hydra_config.cfg
    bad: list[str] = []
    written: list[tuple[int, dict[str, Any]]] = []
    try:
        for num, overrides in enumerate(jobs):
            try:
                job_cfg = loader.load_sweep_config(config, overrides)
            except Exception as exc:  # noqa: BLE001 - Hydra would only warn of it here
                text = composition_error_text(exc) or f"{type(exc).__name__}: {exc}"
                _refuse_sweep(text)
            if check is None:
                continue
            with open_dict(job_cfg.hydra):
                job_cfg.hydra.job.num = num
            hydra_config.set_config(job_cfg)  # the job's overrides, as the job reads them
            task_cfg = copy.deepcopy(job_cfg)
            with open_dict(task_cfg):
                del task_cfg["hydra"]
            try:
                places = check(task_cfg)
            except IPlannerError as exc:
                typed = " ".join(_unescaped(o) for o in overrides)
                bad.append(f"  job {num} [{typed}]: {type(exc).__name__}: {exc}")
            except Exception:  # noqa: BLE001 - a bug: the job reports it with its traceback
                continue
            else:
                written.append((num, dict(places or {})))
    finally:
        hydra_config.cfg = saved
    if bad:
        _refuse_sweep(
            f"{len(bad)} of {len(jobs)} sweep job(s) would stop on a bad setting; no job was "
            "run:\n" + "\n".join(bad)
        )
    trainings = shared_trainings(written)
    if trainings:
        lines = [
            f"  {folder}: "
            + "; ".join(f"{_job_numbers(nums)} with {ask}" for ask, nums in asks.items())
            for folder, asks in trainings
        ]
        _refuse_sweep(
            "sweep jobs would train predictors into the same folder with different settings "
            "(the first trains them, the others stop on the difference or use them "
            "unchecked); no job was run:\n"
            + "\n".join(lines)
            + "\n  give each setting its own folder, e.g. "
            "'paths.checkpoints=checkpoints/seed${seed}' for a sweep of seed, or "
            "'paths.checkpoints=checkpoints/${hydra:job.num}'"
        )
    shared = shared_outputs(written)
    if shared:
        lines = [
            f"  {_job_numbers(nums)} would all write {key}={path}" for key, path, nums in shared
        ]
        keys = dict.fromkeys(key for key, _, _ in shared)
        _refuse_sweep(
            "sweep jobs would write into the same place, each replacing what the one before "
            "wrote (or mixing with it when they run in parallel); no job was run:\n"
            + "\n".join(lines)
            + "\n  give each job its own, e.g. "
            + " ".join(f"'{key}=<folder>/${{hydra:job.num}}'" for key in keys)
        )
    return len(jobs)


class GatherSweepResults(Callback):
    """At the end of a multirun, write ``<sweep dir>/summary/results.{csv,md}`` and plots of
    the jobs that ran (their episodes; for a training or evaluation sweep, each job's
    metrics: :func:`gather_job_metrics`), then name the jobs that failed, if any, and exit 2.
    When the summary cannot be written (``summary`` is a file, a disk is full, a report
    error), that is one ``error:`` line, the failed jobs are named all the same, and the
    sweep exits 2: Hydra would turn the exception into a warning and exit 0.

    At its start, a sweep folder whose job folders hold an earlier sweep's results is refused
    (:func:`used_sweep_dir_text`), before Hydra rewrites their records; then every job's
    config is composed and its settings checked (:func:`check_sweep_jobs`), so that a bad
    value in one job, or two jobs writing the same folder, stop the sweep before any job
    runs.

    Hydra turns an exception raised in these methods into a warning; they end the process
    with ``SystemExit(2)`` instead, which it lets through."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        STARTED_SWEEPS.append((sweep_dir, sweep_dir.exists()))
        used = used_sweep_dir_text(sweep_dir)
        # an experiment sweep with run.resume=true continues the earlier one: each job checks
        # its folder against the run it resumes
        resumes = OmegaConf.select(config, "hydra.job.name") == "experiment" and (
            OmegaConf.select(config, "run.resume") is True
        )
        if used and not resumes:
            _refuse_sweep(used)
        if resumes and not any(sweep_dir.glob("*/run_inputs.json")):
            _refuse_sweep(
                f"run.resume=true: {sweep_dir} holds no sweep to resume (no job folder with "
                "run_inputs.json); name the folder of the sweep to continue with "
                "hydra.sweep.dir=<folder>"
            )
        passive_omp_waits(config, check_sweep_jobs(config))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        import sys

        sweep_dir = Path(str(config.hydra.sweep.dir))
        summary = sweep_dir / "summary"
        gathered = True
        try:
            # a closed-loop sweep's episodes, else a training or evaluation sweep's metrics
            written = gather_episode_logs(sweep_dir, summary) or gather_job_metrics(
                sweep_dir, summary, echo=True
            )
        except Exception as exc:  # noqa: BLE001 - Hydra would only warn of it, and exit 0
            gathered = False
            text = " ".join(t for line in str(exc).splitlines() if (t := line.strip()))
            print(
                f"error: {type(exc).__name__}: {text} (the sweep summary in {summary} is not "
                "written; each job's results are in its folder)",
                file=sys.stderr,
                flush=True,
            )
        else:
            if written:
                print(f"sweep summary: {summary / 'results.md'} ({len(written)} files)")
        failed = failed_jobs(sweep_dir)
        if failed:
            jobs = sum(1 for _ in sweep_dir.rglob("overrides.yaml"))
            lines = [
                f"all {jobs} sweep job(s) failed:"
                if len(failed) >= jobs
                else f"{len(failed)} of {jobs} sweep job(s) failed (the others ran):"
            ]
            for job, overrides, error in failed:
                lines.append(f"  {job} [{overrides}]: {error}")
            print("\n".join(lines), file=sys.stderr, flush=True)
        if failed or not gathered:
            raise SystemExit(2)


#: launchers that run a sweep's jobs as processes side by side on this machine
LOCAL_PARALLEL_LAUNCHERS = ("JoblibLauncher", "submitit_launcher.LocalLauncher")


def jobs_at_once(config: DictConfig, n_jobs: int | None) -> int:
    """How many of the sweep's ``n_jobs`` jobs (None: unknown) run at the same time on this
    machine: joblib's ``hydra.launcher.n_jobs`` (-1 all cores, -k all but k - 1) or
    Submitit's local ``array_parallelism``; 1 for the basic launcher (one after another) and
    for a cluster's."""
    import os

    launcher = config.hydra.get("launcher", {})
    target = str(launcher.get("_target_", ""))
    if not target.endswith(LOCAL_PARALLEL_LAUNCHERS):
        return 1
    cores = os.cpu_count() or 1
    if target.endswith("JoblibLauncher"):
        n = int(launcher.get("n_jobs", -1) or 1)
        at_once = n if n > 0 else max(1, cores + 1 + n)
    else:
        at_once = int(launcher.get("array_parallelism", 0) or 0) or (n_jobs or cores)
    return max(1, min(at_once, n_jobs) if n_jobs else at_once)


def passive_omp_waits(config: DictConfig, n_jobs: int | None = None) -> bool:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` for the job processes of a sweep whose jobs, run side
    by side on this machine (:func:`jobs_at_once`), would start more OpenMP threads than it
    has cores (``trainer.num_threads`` each, 2 by default), unless the environment sets it
    (the bounded spin the commands set otherwise, ``GOMP_SPINCOUNT=1000``, is then removed:
    it would take precedence, and two trainings side by side took 9-10 s each with it against
    5-6 s with passive waits).

    OpenMP's waiting threads then spin against the working ones: two small trainings at once
    on 2 cores took 17-133 s each with the default policy (four runs) and 4.9-5.6 s with
    passive waits, where one alone takes 3.6-4.9 s (``python scripts/bench.py --only
    sweep``; ``experiments/bench/README.md``). A lone training is slower with passive waits
    (7.7-8.7 s), so jobs that have the cores to themselves keep the default. The policy
    changes how threads wait, not what they compute: the trained predictors are the same to
    the bit. The job processes start after this and inherit the environment.

    Returns:
        Whether it was set.
    """
    import os

    if "OMP_WAIT_POLICY" in os.environ:
        return False
    at_once = jobs_at_once(config, n_jobs)
    cores = os.cpu_count() or 1
    trainer = config.get("trainer")
    threads = trainer.get("num_threads", 2) if trainer is not None else 2
    threads = cores if threads is None else max(1, int(threads))
    if at_once < 2 or at_once * threads <= cores:
        return False
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    if os.environ.pop(SPIN_SET_MARK, None) is not None:
        # the commands' bounded spin (iplanner_torch.cli.bounded_omp_spin) would override
        # the policy in the job processes; the user's own GOMP_SPINCOUNT is kept
        os.environ.pop("GOMP_SPINCOUNT", None)
    return True
