"""Hydra callbacks: check every job of a sweep before the first runs, and gather the sweep's
episode logs into one table and plots when it ends."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

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
        pairs = [str(x).lstrip("+~").split("=", 1) for x in items if "=" in str(x)]
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
    numbered order), then the ``results.csv`` rows of each run folder (``root`` itself or a job
    folder directly below it, one with ``.hydra/``) that holds no episode log, as a run with
    ``run.write_mcap=false`` leaves it. Each row has a ``path`` (its log, or that
    ``results.csv``), so :func:`sweep_overrides` can place it in its job. A gathered summary
    (``summary/results.csv``, no ``.hydra/``) is never read back.

    Returns:
        A DataFrame; empty when the folder holds neither.
    """
    import pandas as pd

    from iplanner_torch.eval.report import gather_results, natural_key

    root = Path(root)
    if not root.is_dir():
        return pd.DataFrame()
    frames = [gather_results(root)] if any(root.rglob("*.mcap")) else []
    runs = [root, *sorted((d for d in root.iterdir() if d.is_dir()), key=natural_key)]
    for run in runs:
        csv = run / "results.csv"
        if (run / ".hydra").is_dir() and csv.is_file() and not any(run.rglob("*.mcap")):
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
            text = " ".join(str(o) for o in items)  # type: ignore[union-attr]
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
#: table and its episode logs
RESULT_FILES = ("results.csv", "episodes")


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
#: before a sweep starts, as ``module:function``; it raises an
#: :class:`~iplanner_torch.errors.IPlannerError` for a bad setting
JOB_CHECKS = {"experiment": "iplanner_torch.cli.experiment:check_job"}


def sweep_job_overrides(config: DictConfig) -> list[list[str]] | None:
    """The overrides of each job of the multirun ``config`` describes, in job order, as
    Hydra's basic sweeper splits them (``hydra.sweeper.params`` first, then the command
    line); None for another sweeper."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    sweeper = config.hydra.get("sweeper")
    if sweeper is None or not str(sweeper.get("_target_", "")).endswith(".BasicSweeper"):
        return None
    params = sweeper.get("params") or {}
    given = [f"{k}={v}" for k, v in params.items()] + [str(o) for o in config.hydra.overrides.task]
    batches = BasicSweeper.split_arguments(OverridesParser.create().parse_overrides(given), None)
    return [list(job) for batch in batches for job in batch]


def check_sweep_jobs(config: DictConfig) -> None:
    """Compose every job of the multirun ``config`` describes and check its settings as the
    job will (:data:`JOB_CHECKS`), before the first job runs; exit 2 naming what is wrong.

    Hydra composes each batch of jobs (``hydra.sweeper.max_batch_size``) only when it comes
    to it, so a job of a later batch with an unknown option or key stopped the sweep midway
    with Hydra's own report: that is one ``error: ConfigError:`` line now. A value that is
    wrong in one job (``planner.confidence=0.95,1.5``) was found only when that job started,
    after the jobs before it had run: every such job is named now, with its overrides, and
    no job runs. A check that fails other than on a bad setting (a bug) is left to the job,
    which reports it with its traceback.

    Raises:
        SystemExit: with code 2, after printing the error lines (Hydra turns an exception
            raised in a callback into a warning; an exit is not one).
    """
    import copy
    import importlib
    import sys

    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from iplanner_torch.cli._common import composition_error_text
    from iplanner_torch.errors import IPlannerError

    jobs = sweep_job_overrides(config)
    if not jobs:
        return
    target = JOB_CHECKS.get(str(config.hydra.job.get("name", "")))
    check = None
    if target is not None:
        module, _, name = target.partition(":")
        check = getattr(importlib.import_module(module), name)
    loader = GlobalHydra.instance().config_loader()
    hydra_config = HydraConfig.instance()
    saved = hydra_config.cfg
    bad: list[str] = []
    try:
        for num, overrides in enumerate(jobs):
            try:
                job_cfg = loader.load_sweep_config(config, overrides)
            except Exception as exc:  # noqa: BLE001 - Hydra would only warn of it here
                text = composition_error_text(exc) or f"{type(exc).__name__}: {exc}"
                print(f"error: ConfigError: {text}", file=sys.stderr, flush=True)
                raise SystemExit(2) from None
            if check is None:
                continue
            with open_dict(job_cfg.hydra):
                job_cfg.hydra.job.num = num
            hydra_config.set_config(job_cfg)  # the job's overrides, as the job reads them
            task_cfg = copy.deepcopy(job_cfg)
            with open_dict(task_cfg):
                del task_cfg["hydra"]
            try:
                check(task_cfg)
            except IPlannerError as exc:
                bad.append(f"  job {num} [{' '.join(overrides)}]: {type(exc).__name__}: {exc}")
            except Exception:  # noqa: BLE001 - a bug: the job reports it with its traceback
                continue
    finally:
        hydra_config.cfg = saved
    if bad:
        print(
            f"error: ConfigError: {len(bad)} of {len(jobs)} sweep job(s) would stop on a bad "
            "setting; no job was run:\n" + "\n".join(bad),
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(2)


class GatherSweepResults(Callback):
    """At the end of a multirun, write ``<sweep dir>/summary/results.{csv,md}`` and plots of
    the jobs that ran, then name the jobs that failed, if any, and exit 2. When the summary
    cannot be written (``summary`` is a file, a disk is full, a report error), that is one
    ``error:`` line, the failed jobs are named all the same, and the sweep exits 2: Hydra
    would turn the exception into a warning and exit 0.

    At its start, a sweep folder whose job folders hold an earlier sweep's results is refused
    (:func:`used_sweep_dir_text`), before Hydra rewrites their records; then every job's
    config is composed and its settings checked (:func:`check_sweep_jobs`), so that a bad
    value in one job stops the sweep before any job runs.

    Hydra turns an exception raised in these methods into a warning; they end the process
    with ``SystemExit(2)`` instead, which it lets through."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        import sys

        used = used_sweep_dir_text(Path(str(config.hydra.sweep.dir)))
        if used:
            print(f"error: ConfigError: {used}", file=sys.stderr, flush=True)
            raise SystemExit(2)
        check_sweep_jobs(config)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        import sys

        sweep_dir = Path(str(config.hydra.sweep.dir))
        summary = sweep_dir / "summary"
        gathered = True
        try:
            written = gather_episode_logs(sweep_dir, summary)
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
