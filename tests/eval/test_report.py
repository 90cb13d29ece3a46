"""Sweep reports: gathering, summary tables, Markdown, plots and the paper's table."""

from __future__ import annotations

import math
import re
from pathlib import Path

import matplotlib.image
import numpy as np
import pandas as pd
import pytest

from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.report import (
    PAPER_SCENARIOS,
    PLANNERS,
    format_table,
    gather_results,
    paper_table_simulation,
    plot_comparison,
    plot_sweep,
    side_by_side,
    summary_table,
    to_markdown,
    write_sweep_report,
)
from iplanner_torch.recording import EpisodeWriter

PAPER = Path(__file__).resolve().parents[2].parent / "shared" / "paper"
PAPER_TEX = PAPER / "000_21911837daab3a29.txt"


def _episodes(seed: int = 0) -> list[dict]:
    g = np.random.default_rng(seed)
    rows = []
    for scen in ("arrangements_1", "confidence_level_3"):
        for planner, base in (("itomp", 3.0), ("iplanner_no_ni", 1.2), ("iplanner_ni", 1.0)):
            for conf in (0.9, 0.95, 0.99):
                d = float(g.normal(0.08, 0.03))
                rows.append(
                    {
                        "metadata": {"scenario": scen, "planner": planner, "confidence": conf},
                        "metrics": {
                            "eval/smoothness": base * (1 + 0.1 * g.normal()),
                            "eval/jerkiness": 1.5 * base * (1 + 0.1 * g.normal()),
                            "eval/min_distance": d,
                            "eval/contact": float(d <= 0),
                            "eval/efficiency": 1.5 + 0.1 * g.normal(),
                        },
                    }
                )
    return rows


@pytest.fixture
def results() -> pd.DataFrame:
    return gather_results(_episodes())


def test_gather_results_from_dicts_strips_the_stage_prefix(results: pd.DataFrame) -> None:
    assert len(results) == 18
    assert {"scenario", "planner", "confidence", "smoothness", "min_distance"} <= set(
        results.columns
    )
    flat = gather_results([{"scenario": "s", "eval/smoothness": 2.0, "nested": {"a": 1}}])
    assert flat.loc[0, "smoothness"] == 2.0 and flat.loc[0, "nested.a"] == 1


def test_gather_results_reads_episode_logs_and_folders(tmp_path: Path) -> None:
    for i, planner in enumerate(("itomp", "iplanner_ni")):
        path = tmp_path / "runs" / f"{i}" / "episode.mcap"
        with EpisodeWriter(path, metadata={"scenario": "s1", "planner": planner}) as log:
            log.metrics(3.0, {"eval/smoothness": 1.0 + i, "eval/min_distance": math.nan})
    df = gather_results(tmp_path / "runs")
    assert list(df["planner"]) == ["itomp", "iplanner_ni"]
    assert list(df["smoothness"]) == [1.0, 2.0] and df["min_distance"].isna().all()
    assert df["path"].str.endswith("episode.mcap").all() and df["complete"].all()
    with pytest.raises(DataError, match="no such result file"):
        gather_results([tmp_path / "nope.mcap"])


def test_summary_table_means_stds_and_counts(results: pd.DataFrame) -> None:
    s = summary_table(results)
    assert len(s) == 6 and list(s.columns[:4]) == [
        "scenario",
        "planner",
        "episodes",
        "contact_free",
    ]
    for _, row in s.iterrows():
        g = results[(results.scenario == row.scenario) & (results.planner == row.planner)]
        assert row.episodes == len(g) == 3
        assert row.contact_free == int((g.min_distance > 0).sum())
        vals = g.smoothness.to_numpy()
        assert row.smoothness_mean == pytest.approx(vals.mean())
        assert row.smoothness_std == pytest.approx(vals.std(ddof=1))
    with pytest.raises(ConfigError, match=r"group columns \['robot'\]"):
        summary_table(results, group_by=("robot",))


def test_markdown_and_console_tables(results: pd.DataFrame) -> None:
    s = summary_table(results, metrics=["smoothness", "min_distance"])
    md = to_markdown(s)
    lines = md.strip().splitlines()
    assert len(lines) == 2 + len(s)
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == [
        "scenario",
        "planner",
        "episodes",
        "contact_free",
        "smoothness",
        "min_distance",
    ]
    assert all(line.count("|") == lines[0].count("|") for line in lines)
    assert "±" in lines[2] and lines[1].startswith("| :---")
    text = format_table(s).splitlines()
    assert len({len(line) for line in text[:2]}) == 1  # header and rule equally wide
    # Columns align: each numeric cell ends where its header ends.
    end = text[0].index("episodes") + len("episodes")
    assert all(line[end - 1] != " " for line in text[2:])


def test_paper_table_matches_the_latex_source() -> None:
    """Every number of table performance_simulation, parsed from the paper's LaTeX."""
    if not PAPER_TEX.is_file():
        pytest.skip("paper source not found")
    tex = PAPER_TEX.read_text()
    end = tex.index(r"\label{table:performance_simulation}")
    start = tex.rindex(r"\begin{table*}", 0, end)
    rows = re.findall(
        r"^& (ITOMP|I-Planner, no NI|I-Planner, NI)\s*&(.*)\\\\", tex[start:end], re.M
    )
    assert len(rows) == 27
    paper = paper_table_simulation()
    assert len(paper) == 27
    names = {v: k for k, v in PLANNERS.items()}

    def num(cell: str, scale: float) -> float:
        cell = cell.strip().replace("cm", "").replace("ms", "").strip()
        return math.nan if cell.upper() == "N/A" else float(cell) * scale

    for (name, rest), (_, ours) in zip(rows, paper.iterrows()):
        cells = rest.split("&")
        assert names[name] == ours.planner
        expected = [
            num(cells[0], 1.0),
            num(cells[1], 0.01),
            num(cells[2], 1.0),
            num(cells[3], 1.0),
            num(cells[4], 0.01),
            num(cells[5], 1.0),
        ]
        got = ours[
            ["prediction_ms", "mhd", "smoothness", "jerkiness", "min_distance", "efficiency"]
        ]
        np.testing.assert_allclose(got.to_numpy(float), expected, rtol=1e-12)
    labels = paper.drop_duplicates("scenario")["label"].tolist()
    assert labels == [v[0] for v in PAPER_SCENARIOS.values()]


def test_side_by_side(results: pd.DataFrame) -> None:
    sbs = side_by_side(results)
    assert len(sbs) == 6
    row = sbs[(sbs.scenario == "confidence_level_3") & (sbs.planner == "itomp")].iloc[0]
    assert row["smoothness (paper)"] == 3.76 and row["min_distance (paper)"] == pytest.approx(0.13)
    g = results[(results.scenario == "confidence_level_3") & (results.planner == "itomp")]
    assert row["smoothness (ours)"] == pytest.approx(g.smoothness.mean())
    from_summary = side_by_side(summary_table(results))
    np.testing.assert_allclose(from_summary["jerkiness (ours)"], sbs["jerkiness (ours)"])
    assert "mhd (ours)" not in sbs.columns  # we have no MHD column


def test_plots_are_written(results: pd.DataFrame, tmp_path: Path) -> None:
    paths = plot_comparison(results, tmp_path / "plots")
    assert [p.name for p in paths] == [
        "compare_smoothness.png",
        "compare_jerkiness.png",
        "compare_min_distance.png",
        "compare_efficiency.png",
    ]
    for p in paths:
        img = matplotlib.image.imread(p)
        assert img.ndim == 3 and img.shape[0] > 300 and img.std() > 0.01
    sweep = plot_sweep(results, "confidence", "min_distance", "planner", tmp_path / "s.png")
    assert matplotlib.image.imread(sweep).shape[1] > 500


def test_write_sweep_report(results: pd.DataFrame, tmp_path: Path) -> None:
    written = write_sweep_report(results, tmp_path / "report", sweep="confidence")
    names = {p.name for p in written}
    assert {"results.csv", "results.md", "compare_smoothness.png", "sweep_efficiency.png"} <= names
    assert all(p.is_file() and p.stat().st_size > 0 for p in written)
    back = pd.read_csv(tmp_path / "report" / "results.csv")
    assert len(back) == len(results)
    assert "| scenario |" in (tmp_path / "report" / "results.md").read_text()
