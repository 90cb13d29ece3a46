#!/usr/bin/env python
"""Write ``experiments/safety_seeds/README.md``: contacts, distance, smoothness and efficiency
of ITOMP and I-Planner (NI) over 20 seeds per scenario at confidence 0.95.

Usage::

    iplanner-experiment -m experiment=safety_seeds hydra/launcher=joblib \\
        hydra.launcher.n_jobs=2 'experiment.seeds=[0,...,9],[10,...,19]'
    python scripts/safety_seeds_report.py multirun/experiment/<time> --command "<the command>"

Reads the ``results.csv`` files of the run folder (one row per episode: its own, the sweep's
jobs and their scenario sub-folders; not the sweep's gathered ``summary/results.csv``), and
writes the per-scenario table and the episode rows.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from _report import (
    SETTINGS,
    complete_rows,
    fail,
    main_guard,
    numeric_column,
    parse_report_args,
    read_results,
    require_columns,
    single_setting,
    write_readme,
)

from iplanner_torch.eval.report import paired_table, to_markdown

OUT = Path(__file__).resolve().parents[1] / "experiments" / "safety_seeds"
#: the columns naming an episode: rows of one sweep job repeated in another are dropped
KEYS = ("scenario", "planner", "seed")

#: column -> (aggregation, header)
COLUMNS = {
    "episodes": ("seed", "size"),
    "contact_free": ("sim/contacts", lambda x: int((x == 0).sum())),
    "completed": ("completed", lambda x: int((x > 0).sum())),
    "min_distance_mean": ("min_distance", "mean"),
    "min_distance_min": ("min_distance", "min"),
    "smoothness": ("smoothness", "mean"),
    "jerkiness": ("jerkiness", "mean"),
    "efficiency": ("efficiency", "mean"),
    "waits": ("plan/waits", "mean"),
    "emergencies": ("plan/emergencies", "mean"),
    "realtime_factor": ("sim/realtime_factor", "mean"),
}


def results_files(run_dir: Path) -> list[Path]:
    """The ``results.csv`` files of ``run_dir``: its own, and each one below it that lies in a
    run folder (a folder with ``.hydra/``: a sweep's job) or a sub-folder of one (the job's
    scenarios). A sweep's gathered summary (``summary/results.csv``, no ``.hydra/``) is never
    read back, as in :func:`~iplanner_torch.cli.callbacks.run_rows`: it repeats the jobs'
    episodes with other columns (``robot``, ``path``), so its rows would count twice."""
    run_dir = Path(run_dir)

    def in_run(f: Path) -> bool:
        folders = f.relative_to(run_dir).parents  # the file's folder, ..., run_dir ('.')
        return f.parent == run_dir or any((run_dir / d / ".hydra").is_dir() for d in folders)

    return [f for f in sorted(run_dir.rglob("results.csv")) if in_run(f)]


def gather(run_dir: Path) -> pd.DataFrame:
    """Every episode row of ``run_dir`` (:func:`results_files`; a job's rows repeated in its
    scenario sub-folders dropped).

    Raw rows name metrics ``eval/<name>``; a summary's ``results.csv`` (a finished
    single-scenario run keeps only that one) names them ``<name>``: :func:`read_results`
    reads both alike. Rows are the same episode when their :data:`KEYS` and settings
    (:data:`_report.SETTINGS`: robot, confidence, noise, ...) are; an error names the values
    when rows of more than one setting remain (the report covers one)."""
    frames = []
    for f in results_files(run_dir):
        df = read_results(f)
        if "min_distance" not in df.columns:  # not episode rows
            continue
        require_columns(df, f, KEYS)
        complete_rows(df, f, "min_distance")
        if "sim/contacts" in df.columns:  # a cell that is not a number is not a contact
            complete_rows(df, f, "sim/contacts")
        frames.append(numeric_column(df, f, "confidence"))
    if not frames:
        fail(
            f"no results.csv with episode rows in {run_dir} or its jobs' folders (those with "
            ".hydra/)"
        )
    df = pd.concat(frames, ignore_index=True)
    same = [c for c in (*KEYS, *SETTINGS) if c in df.columns]
    df = df.drop_duplicates(subset=same, keep="last")
    single_setting(df, run_dir, SETTINGS)
    return df


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """One row per scenario and planner (:data:`COLUMNS`)."""
    cols = {k: v for k, v in COLUMNS.items() if v[0] in df.columns}
    out = df.groupby(["scenario", "planner"], sort=False).agg(**cols).reset_index()
    return out


def paired(df: pd.DataFrame) -> pd.DataFrame:
    """Each planner minus ITOMP, seed by seed, on the closest distance [cm] and smoothness
    (:func:`~iplanner_torch.eval.report.paired_table`); empty without ITOMP rows."""
    if not (df["planner"] == "itomp").any():
        return pd.DataFrame()
    out = paired_table(df, ("min_distance", "smoothness"))
    dist = out["metric"] == "min_distance"
    out.loc[dist, ["mean_diff", "ci_low", "ci_high"]] *= 100.0
    out.loc[dist, "metric"] = "distance cm"
    return out


@main_guard
def main() -> None:
    args = parse_report_args(
        __doc__.split("\n\n")[0], "iplanner-experiment -m experiment=safety_seeds", OUT
    )
    df = gather(args.run_dir)
    level = ""
    if "confidence" in df.columns and df["confidence"].notna().any():
        level = f" (confidence {df['confidence'].dropna().iloc[0]:g})"
    table = summarise(df)
    pairs = paired(df)
    paired_body = [
        "Paired by seed: each planner minus ITOMP in the same scenario and seed (same",
        "person, noise and task order). `mean_diff` with its 95% Student-t interval",
        "(`ci_low`, `ci_high`) and the two-sided paired t-test's `p_value`; `better` counts",
        "seeds where the planner did better (a larger distance, a smoother trajectory).",
        "",
        to_markdown(pairs),
        "",
    ]
    write_readme(
        args.out,
        title=f"Safety and efficiency over 20 seeds per scenario{level}",
        command=args.command,
        report="python scripts/safety_seeds_report.py <multirun dir>",
        episodes=df,
        note=args.note,
        force=args.force,
        body=[
            "Distances in metres (sphere models; < 0: overlap), smoothness and jerkiness in",
            "rad^2/s^4, efficiency = human alone / with the robot; `contact_free` counts",
            "episodes without a MuJoCo robot-human contact, `completed` episodes that finished",
            "in 60 s.",
            "",
            to_markdown(table),
            "",
            *(paired_body if len(pairs) else []),
        ],
    )


if __name__ == "__main__":
    main()
