#!/usr/bin/env python
"""Write ``experiments/table_simulation/README.md``: our table beside the paper's numbers.

Usage::

    iplanner-experiment experiment=table_simulation hydra.run.dir=RUN_DIR
    python scripts/table_simulation_report.py RUN_DIR --command "<the command above>"

Reads ``RUN_DIR/results.csv`` (one row per episode), averages per scenario and planner, and
puts the paper's table performance_simulation beside it (matched on arrangement, task order,
confidence level and planner).
"""

from __future__ import annotations

from pathlib import Path

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

from iplanner_torch.eval.report import (
    paper_table_simulation,
    side_by_side,
    summary_table,
    to_markdown,
)

OUT = Path(__file__).resolve().parents[1] / "experiments" / "table_simulation"
KEYS = ["arrangement", "task_order", "confidence", "planner"]


@main_guard
def main() -> None:
    args = parse_report_args(
        __doc__.split("\n\n")[0], "iplanner-experiment experiment=table_simulation", OUT
    )
    path = args.run_dir / "results.csv"
    if not path.is_file():
        fail(f"{path}: not found (give the folder of an `experiment=table_simulation` run)")
    df = read_results(path)
    if df.empty:
        fail(f"{path}: no episode rows (a header at most; was the run stopped?)")
    require_columns(df, path, ("scenario", *KEYS))
    complete_rows(df, path, "smoothness")
    df = numeric_column(df, path, "confidence")
    # the tables average over every setting but the confidence (a key): one value of each
    single_setting(df, path, [c for c in SETTINGS if c != "confidence"])
    df["confidence"] = df["confidence"].round(2)
    paper = paper_table_simulation()
    paper["confidence"] = paper["confidence"].astype(float).round(2)
    table = side_by_side(df, paper, on=KEYS)
    scen = df.groupby(KEYS, sort=False)["scenario"].first().reset_index()
    table = scen.merge(table, on=KEYS)
    summary = summary_table(df, ("scenario", "planner"))
    write_readme(
        args.out,
        title="Paper table performance_simulation, reproduced",
        command=args.command,
        report="python scripts/table_simulation_report.py <run dir>",
        episodes=df,
        note=args.note,
        force=args.force,
        body=[
            "Units: `mhd` and `min_distance` in metres, smoothness and jerkiness in rad^2/s^4",
            "(paper eq. smoothness and jerkiness; the paper does not state its units or time",
            "scaling, so compare the ratios between planners rather than absolute values).",
            "",
            "## Ours beside the paper (means over episodes)",
            "",
            to_markdown(table),
            "",
            "## Ours: means, spread and contact-free episodes",
            "",
            to_markdown(summary),
            "",
        ],
    )


if __name__ == "__main__":
    main()
