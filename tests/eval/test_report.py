"""Sweep reports: gathering, summary tables, Markdown, plots and the paper's table."""

from __future__ import annotations

import json
import math
import os
import re
import warnings
from pathlib import Path

import matplotlib.image
import numpy as np
import pandas as pd
import pytest
from foreign_mcap import write_foreign_mcap
from matplotlib.backends.backend_agg import FigureCanvasAgg

from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.eval.report import (
    PAPER_SCENARIOS,
    PLANNERS,
    TABLE_COLUMNS,
    comparison_key,
    comparison_table,
    episode_contact,
    format_table,
    gather_results,
    hue_colours,
    incomplete_logs_note,
    natural_key,
    ordered_values,
    overrun_note,
    paired_differences,
    paper_table_simulation,
    plot_comparison,
    plot_paired,
    plot_sweep,
    report_groups,
    side_by_side,
    spread_note,
    summary_table,
    to_markdown,
    write_sweep_report,
)
from iplanner_torch.recording import EpisodeWriter, read_episode

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


def test_gather_results_reads_json_results_and_names_malformed_ones(tmp_path: Path) -> None:
    """A .json result file: a flat object of metrics or the {metadata, metrics} form; any
    other JSON value is a DataError naming the file (it was an AttributeError)."""
    good = tmp_path / "good.json"
    good.write_text('{"metadata": {"planner": "itomp"}, "metrics": {"eval/smoothness": 2.0}}')
    flat = tmp_path / "flat.json"
    flat.write_text('{"planner": "oracle", "eval/smoothness": 1.0}')
    df = gather_results([good, flat])
    assert list(df["planner"]) == ["itomp", "oracle"] and list(df["smoothness"]) == [2.0, 1.0]
    for text, why in (
        ("[1, 2]", "expected a JSON object of metrics, got list"),
        ('"str"', "expected a JSON object of metrics, got str"),
        ('{"metadata": 5, "metrics": {}}', "expected 'metadata' to be a JSON object, got int"),
        ('{"metadata": {}, "metrics": [1]}', "expected 'metrics' to be a JSON object, got list"),
        ("{", "not valid JSON"),
    ):
        bad = tmp_path / "bad.json"
        bad.write_text(text)
        with pytest.raises(DataError, match=re.escape(f"{bad}: {why}")):
            gather_results([good, bad])


def test_gather_results_reads_results_csv_with_or_without_the_prefix(tmp_path: Path) -> None:
    raw = pd.DataFrame(
        {
            "planner": ["itomp", "iplanner_ni", "itomp"],
            "seed": [0, 0, 1],
            "eval/smoothness": [40.0, 50.0, math.nan],  # the last row was cut
            "sim/contacts": [0, 0, 1],
        }
    )
    raw.to_csv(tmp_path / "raw.csv", index=False)
    raw.rename(columns={"eval/smoothness": "smoothness"}).to_csv(
        tmp_path / "table.csv", index=False
    )
    a = gather_results(tmp_path / "raw.csv")
    b = gather_results([tmp_path / "table.csv"])
    for df in (a, b):
        assert list(df.columns) == ["planner", "seed", "smoothness", "sim/contacts"]
        assert list(df["planner"]) == ["itomp", "iplanner_ni", "itomp"]
        assert df["smoothness"].iloc[:2].tolist() == [40.0, 50.0]
        assert math.isnan(df["smoothness"].iloc[2]) and df["sim/contacts"].tolist() == [0, 0, 1]
    (tmp_path / "odd.csv").write_text(
        "scenario,planner,eval/smoothness,sim/contacts,note\n"
        "s,itomp,40,0,fine\n"
        "s,itomp,abc,zero,also fine\n"
    )
    with pytest.warns(DataWarning) as caught:
        odd = gather_results(tmp_path / "odd.csv")
    messages = sorted(str(w.message) for w in caught)
    assert len(messages) == 2
    assert "1 value(s) of 'eval/smoothness' are not numbers (file rows [3])" in messages[0]
    assert "1 value(s) of 'sim/contacts' are not numbers (file rows [3])" in messages[1]
    assert odd["smoothness"].tolist()[0] == 40.0 and math.isnan(odd["smoothness"].tolist()[1])
    assert odd["note"].tolist() == ["fine", "also fine"]  # other columns are left as they are
    (tmp_path / "bad.csv").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(DataError, match="bad.csv: not a readable results CSV"):
        gather_results(tmp_path / "bad.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(DataError, match="empty.csv: not a readable results CSV"):
        gather_results(tmp_path / "empty.csv")


def test_gather_results_warns_of_metric_values_that_are_not_numbers(tmp_path: Path) -> None:
    """A string or a list where a metric belongs (a result dict or JSON file) is read as
    missing with a warning naming the file; before, the mean left it out unsaid."""
    meta = {"scenario": "s", "planner": "itomp"}
    (tmp_path / "a.json").write_text(
        json.dumps({"metadata": meta, "metrics": {"eval/smoothness": "abc", "sim/waits": 1}})
    )
    (tmp_path / "b.json").write_text(
        json.dumps({"metadata": meta, "metrics": {"eval/smoothness": 3.0, "sim/waits": 2}})
    )
    with pytest.warns(DataWarning) as caught:
        df = gather_results([tmp_path / "a.json", tmp_path / "b.json"])
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "1 value(s) of 'smoothness' are not numbers" in message and "a.json" in message
    assert "'abc'" in message
    assert math.isnan(df["smoothness"].iloc[0]) and df["smoothness"].iloc[1] == 3.0
    assert df["sim/waits"].tolist() == [1, 2]
    assert summary_table(df)["smoothness_mean"].tolist() == [3.0]
    with pytest.warns(DataWarning, match=r"value\(s\) of 'sim/waits' are not numbers \(row 1"):
        rows = gather_results([dict(meta, **{"sim/waits": 1}), dict(meta, **{"sim/waits": [2]})])
    assert rows["sim/waits"].iloc[0] == 1 and math.isnan(rows["sim/waits"].iloc[1])


def test_gather_results_leaves_out_a_cut_short_last_row(tmp_path: Path) -> None:
    """A results CSV whose writer stopped inside its last row ends without a line end and
    with fewer cells than the header: that row (whose last cell may be cut, "42." of
    "42.75") is left out, with a warning; a short row elsewhere is kept, its missing cells
    NaN, also with a warning; a full last row without a line end is read as it is."""
    header = "planner,seed,eval/smoothness,eval/min_distance\n"
    cut = tmp_path / "cut.csv"
    cut.write_text(header + "itomp,0,41.5,0.06\nitomp,1,42.")
    with pytest.warns(DataWarning, match=r"cut.csv: the last row \(file row 3\) is cut short "
                      r"\(3 of 4 cells and no line end"):  # fmt: skip
        df = gather_results(cut)
    assert df["seed"].tolist() == [0] and df["smoothness"].tolist() == [41.5]
    only = tmp_path / "only.csv"
    only.write_text(header + "itomp,1,4")
    with pytest.warns(DataWarning, match="cut short"):
        assert gather_results(only).empty
    short = tmp_path / "short.csv"
    short.write_text(header + "itomp,0,41.5\nitomp,1,42.75,0.1\n")
    with pytest.warns(DataWarning, match=r"1 row\(s\) have fewer cells than the header's 4 "
                      r"\(file rows \[2\]\)"):  # fmt: skip
        df = gather_results(short)
    assert df["smoothness"].tolist() == [41.5, 42.75]
    assert math.isnan(df["min_distance"].iloc[0]) and df["min_distance"].iloc[1] == 0.1
    whole = tmp_path / "whole.csv"
    whole.write_text(header + "itomp,0,41.5,0.06\nitomp,1,42.75,0.1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gather_results(whole)["smoothness"].tolist() == [41.5, 42.75]


def test_gather_results_refuses_rows_longer_than_the_header(tmp_path: Path) -> None:
    """A note typed after the last cell of one row made pandas read the first column as the
    index and shift every other column one place left, silently: such rows are refused,
    named; extra cells that are all empty (a trailing separator) lose nothing and are read
    with the columns in place."""
    header = "planner,seed,eval/smoothness,eval/min_distance\n"
    noted = tmp_path / "noted.csv"
    noted.write_text(header + "itomp,0,41.5,0.06\nitomp,1,42.75,0.1,rerun\n")
    with pytest.raises(DataError, match=r"noted.csv: 1 row\(s\) have more cells than the "
                       r"header's 4 \(file rows \[3\]\)"):  # fmt: skip
        gather_results(noted)
    every = tmp_path / "every.csv"
    every.write_text(header + "itomp,0,41.5,0.06,ok\nitomp,1,42.75,0.1,ok\n")
    with pytest.raises(DataError, match=r"every.csv: 2 row\(s\) .* \(file rows \[2, 3\]\)"):
        gather_results(every)
    trailing = tmp_path / "trailing.csv"
    trailing.write_text(header + "itomp,0,41.5,0.06,\nitomp,1,42.75,0.1,\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        df = gather_results(trailing)
    assert df["planner"].tolist() == ["itomp", "itomp"] and df["seed"].tolist() == [0, 1]
    assert df["smoothness"].tolist() == [41.5, 42.75]


def test_gather_results_refuses_a_csv_with_another_separator(tmp_path: Path) -> None:
    """A results CSV re-saved with ';' separators (a spreadsheet in a European locale; the
    commas inside a quoted task order split its rows) ended in a raw TypeError: a DataError
    saying it is not comma-separated."""
    rows = ["planner,task_order,seed,eval/smoothness", 'itomp,"(0,1)->(2,3)",0,41.5',
            'itomp,"(0,1)->(2,3)",1,42.75']  # fmt: skip
    for sep, name in ((";", "';'"), ("\t", "a tab")):
        path = tmp_path / "semi.csv"
        path.write_text("\n".join(r.replace(",", sep) for r in rows) + "\n")
        with pytest.raises(DataError, match=f"semi.csv: not a comma-separated results CSV: "
                           f"its header is one cell holding {name}"):  # fmt: skip
            gather_results(path)


def test_a_folder_leaves_out_mcap_files_that_are_not_episode_logs(tmp_path: Path) -> None:
    """An unfetched Git LFS pointer and another program's MCAP file below a folder aborted
    the whole gathering: they are left out, named in one warning, while a log cut short is
    still read (an incomplete episode) and a good log as it is. Given by its path, either
    is refused."""
    runs = tmp_path / "runs"
    for name in ("good", "cut"):
        with EpisodeWriter(
            runs / f"{name}.mcap", metadata={"scenario": "s", "planner": name}
        ) as log:
            log.robot_state(0.0, [0.0] * 7, [0.0] * 7, list("abcdefg"))
            log.metrics(1.0, {"eval/smoothness": 2.0, "eval/min_distance": 0.1})
    data = (runs / "cut.mcap").read_bytes()  # cut before its data end record (13 bytes)
    summary_start = int.from_bytes(data[-8 - 29 + 9 : -8 - 29 + 17], "little")
    (runs / "cut.mcap").write_bytes(data[: summary_start - 13])
    pointer = runs / "sub" / "lfs.mcap"
    pointer.parent.mkdir()
    pointer.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:ab\nsize 9\n")
    foreign = write_foreign_mcap(runs / "other.mcap")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        df = gather_results(runs)
    assert sorted(df["planner"].dropna()) == ["cut", "good"]
    assert df.set_index("planner")["complete"].to_dict() == {"good": True, "cut": False}
    left_out = [str(w.message) for w in caught if "left out" in str(w.message)]
    assert len(left_out) == 1 and left_out[0].startswith(
        f"{runs}: left out 2 of its 4 .mcap file(s), which are not readable episode logs: "
    )
    assert f"{foreign}: not an iplanner episode log (a valid MCAP file with no " in left_out[0]
    assert f"{pointer} is not an MCAP file (bad magic bytes)" in left_out[0]
    assert not any(
        "truncated or damaged" in str(w.message) for w in caught if foreign.name in str(w.message)
    )
    with pytest.raises(DataError, match="other.mcap: not an iplanner episode log"):
        gather_results(foreign)
    with pytest.raises(DataError, match="lfs.mcap is not an MCAP file"):
        gather_results(pointer)


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
        assert row.contact_unknown == 0
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
        "contact_unknown",
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


def test_spread_note_says_what_a_bar_and_whisker_are() -> None:
    assert spread_note([3, 3]) == "mean of 3 episodes per bar, whiskers ± 1 std within min-max"
    assert spread_note([1, 1, 1]) == "one episode per bar (no spread to show)"
    assert spread_note([1, 3, 2]) == (
        "mean of 1-3 episodes per bar, whiskers ± 1 std within min-max (none for a bar of one "
        "episode)"
    )
    assert spread_note([0, 2]) == "mean of 2 episodes per bar, whiskers ± 1 std within min-max"
    assert spread_note([]) == "no values"


def _recorded_figures(monkeypatch: pytest.MonkeyPatch) -> list:
    """The matplotlib Figures the report module makes from now on."""
    import iplanner_torch.eval.report as report

    figures = []

    class Recorded(report.Figure):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            figures.append(self)

    monkeypatch.setattr(report, "Figure", Recorded)
    return figures


def _whisker_ends(ax) -> list[tuple[float, float]]:
    """``(low, high)`` of every drawn whisker of a bar chart, in data units."""
    ends = []
    for bars in (c for c in ax.containers if hasattr(c, "errorbar")):
        if bars.errorbar is None:
            continue
        for seg in bars.errorbar.lines[2][0].get_segments():
            if seg.size and np.isfinite(seg).all():
                ends.append((float(seg[:, 1].min()), float(seg[:, 1].max())))
    return ends


def test_whiskers_stay_within_the_episodes_values(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Jerkiness of [0, 0, 0, 8] has mean 2 and std 4: the whisker went to -2, a value no
    episode can have. Whiskers are cut at the least and largest episode value, so a metric
    that cannot be negative never gets one below 0, and a signed distance goes below 0 only
    where an episode did."""
    figures = _recorded_figures(monkeypatch)
    rows = [
        {"scenario": "s", "planner": p, "seed": i, "jerkiness": j, "min_distance": d}
        for p, js, ds in (
            ("itomp", (0.0, 0.0, 0.0, 8.0), (0.01, 0.01, 0.01, 0.2)),
            ("iplanner_ni", (5.0, 6.0, 7.0, 8.0), (-0.05, 0.1, 0.12, 0.14)),
        )
        for i, (j, d) in enumerate(zip(js, ds))
    ]
    df = pd.DataFrame(rows)
    plot_comparison(df, tmp_path, metrics=("jerkiness", "min_distance"))
    jerk, dist = (f.axes[0] for f in figures)
    ends = _whisker_ends(jerk)
    assert len(ends) == 2
    lows = sorted(lo for lo, _ in ends)
    assert lows[0] == pytest.approx(0.0)  # itomp: mean 2 - std 4 cut at its least value, 0
    assert min(lo for lo, _ in ends) >= 0.0
    itomp = next(e for e in ends if e[0] == pytest.approx(0.0))
    assert itomp[1] == pytest.approx(2.0 + 4.0)  # the upper end is within the values: kept
    d_ends = sorted(_whisker_ends(dist))  # in cm
    assert d_ends[0][0] >= -5.0 - 1e-9 and d_ends[0][0] < 0.0  # an episode overlapped
    assert min(lo for lo, _ in d_ends[1:]) >= 1.0 - 1e-9  # itomp never went below 1 cm
    assert "whiskers ± 1 std within min-max" in jerk.get_title()


def test_sweep_bands_stay_within_the_episodes_values(tmp_path: Path) -> None:
    """The ± 1 std band of a sweep plot went below 0 for a metric that cannot be negative."""
    with pytest.MonkeyPatch.context() as mp:
        figures = _recorded_figures(mp)
        rows = [
            {"planner": "itomp", "noise": n, "seed": i, "jerkiness": v}
            for n in (0.0, 0.02)
            for i, v in enumerate((0.0, 0.0, 0.0, 8.0))
        ]
        plot_sweep(pd.DataFrame(rows), "noise", "jerkiness", "planner", tmp_path / "s.png")
    (ax,) = figures[0].axes
    (band,) = [c for c in ax.collections if c.get_paths()]
    ys = band.get_paths()[0].vertices[:, 1]
    assert ys.min() == pytest.approx(0.0) and ys.max() == pytest.approx(6.0)  # 2 ± 4, cut
    assert "within min-max" in figures[0]._suptitle.get_text()
    renderer = FigureCanvasAgg(figures[0]).get_renderer()
    legend = ax.get_legend().get_window_extent(renderer)
    assert legend.x0 >= ax.get_window_extent(renderer).x1


def test_comparison_charts_name_their_axes_keep_the_legend_off_the_bars_and_skip_empty_metrics(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``-m tracker.noise=0,0.02``: the charts' x axis had ticks 0.0 and 0.02 and no label; the
    legend stood inside the axes over the tallest bar; a metric with no value in any episode
    (efficiency of a run where none finished) was written as an empty chart and listed."""
    figures = _recorded_figures(monkeypatch)
    rows = [
        {"scenario": "s", "planner": p, "noise": n, "seed": i, "smoothness": v + i,
         "efficiency": math.nan}
        for n in (0.0, 0.02) for p, v in (("itomp", 3.0), ("iplanner_ni", 9.0))
        for i in range(2)
    ]  # fmt: skip
    df = pd.DataFrame(rows)
    written = write_sweep_report(df, tmp_path, report_groups(df))
    names = [p.name for p in written]
    assert "compare_smoothness.png" in names
    assert "compare_efficiency.png" not in names
    assert not (tmp_path / "compare_efficiency.png").exists()
    (fig,) = [f for f in figures if f.axes and f.axes[0].get_ylabel().startswith("smoothness")]
    ax = fig.axes[0]
    assert ax.get_xlabel() == "tracker noise [m]"
    assert [t.get_text() for t in ax.get_xticklabels()] == ["0.0", "0.02"]
    renderer = FigureCanvasAgg(fig).get_renderer()
    legend = ax.get_legend().get_window_extent(renderer)
    plot_area = ax.get_window_extent(renderer)
    assert legend.x0 >= plot_area.x1  # beside the plotting area, covering no bar
    assert legend.x1 <= fig.bbox.x1 + 1  # and inside the figure
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["ITOMP", "I-Planner, NI"]


def test_a_bar_of_one_episode_has_no_whisker(
    results: pd.DataFrame, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A standard deviation of one value is undefined: the chart used to draw it as a flat
    # whisker of 0, which reads as "no spread". Now such a bar has no whisker at all.
    figures = _recorded_figures(monkeypatch)
    keep = results.groupby(["scenario", "planner"], sort=False).cumcount() < 2
    two_or_one = results[keep & ~((results.planner == "itomp") & (results.index % 2 == 1))]
    counts = two_or_one.groupby(["scenario", "planner"], sort=False).size()
    assert set(counts) == {1, 2}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_comparison(two_or_one, tmp_path, metrics=("smoothness",))
    (ax,) = figures[-1].axes
    whiskers = 0
    for bars in (c for c in ax.containers if hasattr(c, "errorbar")):
        segments = bars.errorbar.lines[2][0].get_segments()
        whiskers += sum(seg.size > 0 and bool(np.isfinite(seg).all()) for seg in segments)
    assert whiskers == int((counts >= 2).sum())
    assert ax.get_title().endswith("(none for a bar of one episode)")


def test_write_sweep_report(results: pd.DataFrame, tmp_path: Path) -> None:
    written = write_sweep_report(results, tmp_path / "report", sweep="confidence")
    names = {p.name for p in written}
    assert {"results.csv", "results.md", "compare_smoothness.png", "sweep_efficiency.png"} <= names
    assert all(p.is_file() and p.stat().st_size > 0 for p in written)
    back = pd.read_csv(tmp_path / "report" / "results.csv")
    assert len(back) == len(results)
    md = (tmp_path / "report" / "results.md").read_text()
    assert "| scenario |" in md
    assert "smoothness [rad²/s⁴]" in md and "closest distance [cm]" in md  # the units
    assert md.endswith("\n") and not md.endswith("\n\n")


def test_a_failed_report_write_keeps_the_earlier_table(
    results: pd.DataFrame, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """results.csv is an experiment's record of its episodes: a write that fails midway
    (a full disk) leaves the earlier file as it was, not cut short."""
    out = tmp_path / "report"
    out.mkdir()
    earlier = "planner,scenario,speed,noise,seed\nitomp,s,medium,0.0,0\n"
    (out / "results.csv").write_text(earlier)
    real = pd.DataFrame.to_csv

    def full_disk(self, path, *args, **kwargs):
        Path(path).write_text(real(self, None, *args, **kwargs)[:50])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_csv", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_sweep_report(results, out, sweep="confidence")
    assert (out / "results.csv").read_text() == earlier
    assert [p.name for p in out.iterdir()] == ["results.csv"]  # no temporary file left


def test_distances_are_shown_in_cm(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """results.csv keeps metres; results.md's mean ± std and paired tables and the plots
    show cm, as the comparison table does. Expected values from the rows, by hand."""
    figures = _recorded_figures(monkeypatch)
    d = {"itomp": (0.05, 0.07, 0.06), "iplanner_ni": (0.09, 0.10, 0.14)}
    rows = [
        {"scenario": "s", "planner": p, "seed": i, "min_distance": v, "smoothness": 1.0 + i,
         "mhd": 0.031 if p != "itomp" else np.nan}
        for p, vs in d.items()
        for i, v in enumerate(vs)
    ]  # fmt: skip
    df = pd.DataFrame(rows)
    write_sweep_report(df, tmp_path)
    back = pd.read_csv(tmp_path / "results.csv")
    assert back["min_distance"].tolist() == [v for vs in d.values() for v in vs]  # metres
    md = (tmp_path / "results.md").read_text()
    mean_std = md.split("## Mean ± std")[1].split("## Paired")[0]
    header = next(ln for ln in mean_std.splitlines() if ln.startswith("| scenario"))
    cells = [c.strip() for c in header.strip("|").split("|")]
    assert "min_distance cm" in cells and "mhd cm" in cells and "min_distance" not in cells
    ni = next(ln for ln in mean_std.splitlines() if "| iplanner_ni |" in ln)
    ni_cells = [c.strip() for c in ni.strip("|").split("|")]
    dist = ni_cells[cells.index("min_distance cm")]
    sd = float(np.std([9.0, 10.0, 14.0], ddof=1))
    assert [float(x) for x in dist.split(" ± ")] == pytest.approx([11.0, sd], rel=3e-3), dist
    mhd = ni_cells[cells.index("mhd cm")]
    assert [float(x) for x in mhd.split(" ± ")] == pytest.approx([3.1, 0.0], abs=1e-9), mhd
    # paired: the NI minus ITOMP, seed by seed: +4, +3, +8 cm, mean 5
    paired = md.split("## Paired by seed")[1]
    phead = next(ln for ln in paired.splitlines() if ln.startswith("| scenario"))
    pcells = [c.strip() for c in phead.strip("|").split("|")]
    row = next(ln for ln in paired.splitlines() if "| min_distance cm |" in ln)
    rcells = [c.strip() for c in row.strip("|").split("|")]
    assert float(rcells[pcells.index("mean_diff")]) == pytest.approx(5.0), row
    # the plots: bars at the means in cm, the paired point at +5 cm
    bar = next(f for f in figures if "closest distance [cm]" == f.axes[0].get_ylabel())
    heights = sorted(p.get_height() for p in bar.axes[0].patches)
    assert heights == pytest.approx([6.0, 11.0])
    forest = next(
        f for f in figures if f.axes[0].get_xlabel().startswith("closest distance [cm]:")
    )
    (line,) = [ln for ln in forest.axes[0].get_lines() if ln.get_marker() == "o"]
    assert line.get_xdata()[0] == pytest.approx(5.0)


def _sweep_rows() -> pd.DataFrame:
    """A noise x speed x confidence sweep, rows in a scrambled order, two seeds each."""
    g = np.random.default_rng(3)
    rows = []
    for planner in ("iplanner_ni", "oracle", "itomp", "iplanner_no_ni"):
        for speed in ("fast", "slow", "medium"):
            for noise in (0.05, 0.0, 0.02):
                for conf in (0.99, 0.9):
                    for seed in (1, 0):
                        rows.append(
                            {
                                "scenario": "arrangement_1x4",
                                "planner": planner,
                                "speed": speed,
                                "noise": noise,
                                "confidence": conf,
                                "seed": seed,
                                "eval/smoothness": 10 * noise + g.normal(),
                                "eval/min_distance": 0.1,
                                "eval/contact": 0.0,
                            }
                        )
    return gather_results(rows)


def test_summary_rows_follow_the_settings_natural_order() -> None:
    df = _sweep_rows()
    groups = report_groups(df)
    assert groups == ("scenario", "speed", "noise", "confidence", "planner")
    s = summary_table(df, groups)
    assert len(s) == 3 * 3 * 2 * 4 and (s["episodes"] == 2).all()
    first = s.iloc[:4]
    assert list(first["planner"]) == ["itomp", "iplanner_no_ni", "iplanner_ni", "oracle"]
    assert (first["speed"] == "slow").all() and (first["noise"] == 0.0).all()
    assert (first["confidence"] == 0.9).all()
    assert list(dict.fromkeys(s["speed"])) == ["slow", "medium", "fast"]
    assert list(s["noise"].iloc[:24:8]) == [0.0, 0.02, 0.05]
    # a value outside the known order follows it; other columns keep first appearance
    assert ordered_values("speed", ["fast", "sprint", "slow"]) == ["slow", "fast", "sprint"]
    assert ordered_values("scenario", ["b", "a", "b"]) == ["b", "a"]
    with_nan = ordered_values("noise", [0.05, math.nan, 0.0, math.nan])
    assert with_nan[:2] == [0.0, 0.05] and len(with_nan) == 3 and math.isnan(with_nan[2])


def test_one_scenario_name_run_in_two_arrangements_gives_two_rows() -> None:
    """An override of scenario.arrangement (or task_order) keeps the scenario's name: its
    episodes are not averaged together; settings that come with the name add no column."""
    rows = [
        {"scenario": "s", "arrangement": arr, "task_order": "0->1->2->3", "planner": p,
         "seed": seed, "eval/smoothness": {"1x4": 1.0, "2x2": 3.0}[arr],
         "eval/min_distance": 0.1, "eval/contact": 0.0}
        for arr in ("2x2", "1x4") for p in ("itomp", "iplanner_ni") for seed in (0, 1)
    ]  # fmt: skip
    df = gather_results(rows)
    assert report_groups(df) == ("scenario", "arrangement", "planner")
    s = summary_table(df, report_groups(df))
    assert list(s["arrangement"]) == ["2x2", "2x2", "1x4", "1x4"]
    assert list(s["smoothness_mean"]) == [3.0, 3.0, 1.0, 1.0] and (s["episodes"] == 2).all()
    c = comparison_table(df)
    assert list(c["arrangement"]) == ["2x2", "2x2", "1x4", "1x4"]
    orders = gather_results([dict(r, task_order=o) for r in rows[:4] for o in ("0->1", "1->0")])
    assert report_groups(orders) == ("scenario", "task_order", "planner")
    # one arrangement and task order per scenario name: grouped by the name alone
    named = gather_results([dict(r, scenario=f"s_{r['arrangement']}") for r in rows])
    assert report_groups(named) == ("scenario", "planner")
    assert len(summary_table(named, report_groups(named))) == 4


def test_a_dropout_sweep_keeps_its_rows_apart(tmp_path: Path) -> None:
    from iplanner_torch.cli.callbacks import episode_report

    rows = [
        {"scenario": "s", "planner": p, "noise": 0.01, "dropout": d, "seed": seed,
         "eval/smoothness": 1.0 + d, "eval/min_distance": 0.1, "eval/contact": 0.0}
        for d in (0.3, 0.0, 0.1) for p in ("itomp", "iplanner_ni") for seed in (0, 1)
    ]  # fmt: skip
    df = gather_results(rows)
    assert report_groups(df) == ("scenario", "dropout", "planner")
    s = summary_table(df, report_groups(df))
    assert list(s["dropout"]) == [0.0, 0.0, 0.1, 0.1, 0.3, 0.3] and (s["episodes"] == 2).all()
    names = {p.name for p in episode_report(df, tmp_path)}
    assert "sweep_smoothness.png" in names  # plotted against the swept dropout


def test_natural_key_orders_numbered_folders_by_number() -> None:
    paths = ["m/10/e/a.mcap", "m/2/e/b.mcap", "m/1/e/c.mcap", "m/2/e/a.mcap"]
    assert sorted(paths, key=natural_key) == [
        "m/1/e/c.mcap",
        "m/2/e/a.mcap",
        "m/2/e/b.mcap",
        "m/10/e/a.mcap",
    ]


def test_sweep_plot_has_a_panel_per_setting(tmp_path: Path) -> None:
    df = _sweep_rows()
    single = plot_sweep(df, "noise", "smoothness", "planner", tmp_path / "one.png")
    grid = plot_sweep(
        df,
        "noise",
        "smoothness",
        "planner",
        tmp_path / "grid.png",
        facet_col="speed",
        facet_row="confidence",
    )
    h1, w1 = matplotlib.image.imread(single).shape[:2]
    h3, w3 = matplotlib.image.imread(grid).shape[:2]
    assert w3 > 1.5 * w1 and h3 > 1.3 * h1  # 3 columns (speeds) x 2 rows (confidences)
    with pytest.raises(ConfigError, match="not in the results"):
        plot_sweep(df, "noise", "smoothness", "planner", tmp_path / "x.png", facet_col="robot")


def test_sweep_report_lays_out_the_other_settings_and_skips_flat_sweeps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import iplanner_torch.eval.report as report

    calls = []
    real = report.plot_sweep

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(report, "plot_sweep", spy)
    df = _sweep_rows()
    written = write_sweep_report(df, tmp_path / "a", report_groups(df), sweep="noise")
    assert "sweep_smoothness.png" in {p.name for p in written}
    assert calls and calls[0] == {"facet_col": "confidence", "facet_row": "speed", "pooled": []}
    # one confidence per scenario (the table_simulation layout): no line to draw over it
    calls.clear()
    flat = gather_results(
        [
            {"scenario": s, "planner": p, "confidence": c, "eval/smoothness": 1.0}
            for s, c in (("a", 0.9), ("b", 0.95), ("c", 0.99))
            for p in ("itomp", "iplanner_ni")
        ]
    )
    written = write_sweep_report(flat, tmp_path / "b", report_groups(flat), sweep="confidence")
    assert not calls and not any(p.name.startswith("sweep_") for p in written)
    assert "compare_smoothness.png" in {p.name for p in written}


def test_charts_say_what_they_average_over_and_draw_only_what_has_values(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A speed x noise x confidence sweep charted by confidence pooled the speeds and noises
    into each bar without a word; a metric with no value got an empty sweep plot, and a
    planner with no value (ITOMP's MHD) a legend entry."""
    import iplanner_torch.eval.report as report

    seen: dict[str, list] = {"bars": [], "lines": []}
    real_bars, real_lines = report.plot_comparison, report.plot_sweep
    figures = _recorded_figures(monkeypatch)

    def bars(*args, **kwargs):
        seen["bars"].append(kwargs.get("pooled"))
        return real_bars(*args, **kwargs)

    def lines(*args, **kwargs):
        seen["lines"].append((args[2], kwargs.get("pooled")))
        return real_lines(*args, **kwargs)

    monkeypatch.setattr(report, "plot_comparison", bars)
    monkeypatch.setattr(report, "plot_sweep", lines)
    df = _sweep_rows().assign(efficiency=np.nan, mhd=0.05)
    df.loc[df.planner == "itomp", "mhd"] = np.nan
    groups = report_groups(df)
    assert groups == ("scenario", "speed", "noise", "confidence", "planner")
    written = {p.name for p in write_sweep_report(df, tmp_path, groups, sweep="noise")}
    # one chart per metric, each pooling the same settings
    assert seen["bars"] == [["speed", "noise"]] * 4
    titles = [f.axes[0].get_title() for f in figures if f.axes and f.axes[0].get_title()]
    pooled_note = (
        "\naveraged over speed, noise: each bar pools every speed, noise, so its spread holds "
        "their differences too (the sweep_* plots keep them apart)"
    )
    assert any(t.endswith(pooled_note) for t in titles)
    # the lines over noise: speed and confidence lay out the panels, nothing is pooled
    assert {m for m, _ in seen["lines"]} >= {"smoothness", "mhd"}
    assert all(pooled == [] for _, pooled in seen["lines"])
    assert "sweep_efficiency.png" not in written and "sweep_mhd.png" in written
    mhd = figures[[m for m, _ in seen["lines"]].index("mhd") - len(seen["lines"])]
    labels = mhd.axes[0].get_legend_handles_labels()[1]
    assert "ITOMP" not in labels and labels
    assert mhd.axes[-1].get_xlabel() == "tracker noise [m]"
    assert "bands ± 1 std" in mhd._suptitle.get_text()


def test_results_of_two_robots_stay_apart() -> None:
    """run_experiment rows had no robot column, and report_groups pooled a Fetch and an iiwa
    run given together (with a warning that one was a repeat of the other)."""
    rows = [
        {"scenario": "s", "planner": "itomp", "robot": r, "seed": 0, "eval/smoothness": v}
        for r, v in (("kuka_iiwa14", 1.0), ("fetch", 3.0))
    ]
    df = gather_results(rows)
    assert report_groups(df) == ("scenario", "robot", "planner")
    table = summary_table(df, report_groups(df))
    assert sorted(table["smoothness_mean"]) == [1.0, 3.0]


def _episode_log(path: Path, metrics: dict, planner: str = "itomp", steps: int = 2000) -> Path:
    """A real episode log: ``steps`` robot states in 8 KiB chunks, then the metrics."""
    g = np.random.default_rng(0)
    joints = [f"j{i}" for i in range(7)]
    meta = {"scenario": "s1", "planner": planner, "seed": 0}
    with EpisodeWriter(path, metadata=meta, chunk_size=8 * 1024) as log:
        for i in range(steps):
            log.robot_state(i / 15, g.normal(size=7), g.normal(size=7), joints)
        log.metrics(steps / 15, metrics)
    return path


def _cut(path: Path, fraction: float = 0.9) -> Path:
    """Truncate a log to ``fraction`` of its size, as a killed episode leaves it."""
    os.truncate(path, int(fraction * path.stat().st_size))
    return path


FREE = {"eval/contact": 0.0, "eval/min_distance": 0.0604, "eval/completed": 1.0}
TOUCH = {"eval/contact": 1.0, "eval/min_distance": -0.01, "eval/completed": 1.0}


def test_episode_contact_is_unknown_without_a_value_not_a_contact() -> None:
    df = pd.DataFrame(
        {
            "contact": [0.0, 1.0, math.nan, math.nan, math.nan],
            "min_distance": [0.1, -0.01, -0.02, 0.03, math.nan],
        }
    )
    np.testing.assert_array_equal(episode_contact(df), [0.0, 1.0, 1.0, 0.0, math.nan])
    assert episode_contact(pd.DataFrame({"smoothness": [1.0, 2.0]})).isna().all()


def test_a_truncated_log_counts_as_unknown_contact_in_every_table(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    _episode_log(logs / "0.mcap", FREE)
    _episode_log(logs / "1.mcap", TOUCH)
    cut = _cut(_episode_log(logs / "2.mcap", FREE))
    with pytest.warns(DataWarning, match="truncated or damaged"):
        assert read_episode(cut).metrics() == {}  # the cut took the metrics with it

    with pytest.warns(DataWarning, match="truncated or damaged"):
        alone = gather_results(cut)
    assert not alone.loc[0, "complete"] and alone.loc[0, "planner"] == "itomp"
    for table in (summary_table(alone, ["planner"]), comparison_table(alone)):
        row = table.iloc[0]
        assert (row.episodes, row.contact_free, row.contact_unknown) == (1, 0, 1)

    with pytest.warns(DataWarning, match="truncated or damaged"):
        df = gather_results(logs)
    assert list(df["complete"]) == [True, True, False]
    for table in (summary_table(df, ["planner"]), comparison_table(df)):
        row = table.iloc[0]
        # one contact-free, one contact, one unknown: the cut log is neither
        assert (row.episodes, row.contact_free, row.contact_unknown) == (3, 1, 1)
        assert row.completed == 2
    note = incomplete_logs_note(df)
    assert note.startswith("truncated or damaged episode logs: 1 of 3; the contact of 1 ")
    assert incomplete_logs_note(df[df["complete"]]) == ""
    write_sweep_report(df, tmp_path / "report", ["planner"])
    md = (tmp_path / "report" / "results.md").read_text()
    assert note in md and "| itomp | 3 | 1 | 1 | 2 |" in md


def _stopped_log(path: Path) -> Path:
    """A whole log of an episode stopped by Ctrl-C: its writer closed on the interrupt (an
    ``interrupted`` event), before the metrics."""
    joints = [f"j{i}" for i in range(7)]
    meta = {"scenario": "s1", "planner": "itomp", "seed": 0}
    with pytest.raises(KeyboardInterrupt):
        with EpisodeWriter(path, metadata=meta) as log:
            log.robot_state(0.0, [0.0] * 7, [0.0] * 7, joints)
            raise KeyboardInterrupt
    return path


def test_an_interrupted_episode_counts_as_unknown_and_is_named(tmp_path: Path) -> None:
    """Its log is whole (complete) but it has no metrics: the note names it apart from the
    cut logs (it was counted in contact_unknown and named nowhere)."""
    logs = tmp_path / "logs"
    _episode_log(logs / "0.mcap", FREE)
    stopped = read_episode(_stopped_log(logs / "1.mcap"))
    assert stopped.complete and stopped.interrupted and stopped.metrics() == {}
    assert not read_episode(logs / "0.mcap").interrupted
    df = gather_results(logs)
    assert list(df["complete"]) == [True, True] and list(df["interrupted"]) == [False, True]
    row = comparison_table(df).iloc[0]
    assert (row.episodes, row.contact_free, row.contact_unknown) == (2, 1, 1)
    assert incomplete_logs_note(df) == (
        "episodes interrupted before their end: 1 of 2; the contact of 1 of them is unknown "
        "(counted in contact_unknown, not in contact_free)."
    )
    _cut(_episode_log(logs / "2.mcap", FREE))
    with pytest.warns(DataWarning, match="truncated or damaged"):
        df = gather_results(logs)
    assert incomplete_logs_note(df).startswith(
        "truncated or damaged episode logs: 1 of 3; episodes interrupted before their end: 1 "
        "of 3; the contact of 2 of those is unknown"
    )


def _overrun_rows(overruns: list[float], realtime: list[float]) -> pd.DataFrame:
    rows = [
        {"scenario": "s", "planner": "itomp", "seed": i, "smoothness": 3.0,
         "plan/overruns": 0.0, "plan/cycles": 10.0, "plan/mean_solve_ms": 80.0,
         "sim/realtime_factor": 3.0}
        for i in range(2)
    ] + [
        {"scenario": "s", "planner": "iplanner_ni", "seed": i, "smoothness": 9.0,
         "plan/overruns": o, "plan/cycles": c, "plan/mean_solve_ms": ms,
         "sim/realtime_factor": rt}
        for i, (o, c, ms, rt) in enumerate(zip(overruns, (10.0, 30.0), (300.0, 500.0), realtime))
    ]  # fmt: skip
    return pd.DataFrame(rows)


def test_overrun_note_names_the_planners_whose_solves_overran(tmp_path: Path) -> None:
    """Counts and the cycle-weighted mean solve by hand: (300 x 10 + 500 x 30) / 40 = 450 ms;
    a planner without overruns is not named; the slowest episode only below real time."""
    df = _overrun_rows([3.0, 4.0], [0.6, 1.2])
    note = overrun_note(df)
    assert note.startswith(
        "replanning solves over their wall-clock budget: iplanner_ni 7 of 40 (mean solve "
        "450 ms). The slowest episode ran at 0.60x real time."
    )
    assert "itomp" not in note and "as if the planner were faster" in note
    assert overrun_note(_overrun_rows([0.0, 0.0], [0.6, 1.2])) == ""
    # above real time: no sentence on it; a NaN count is skipped, not summed as 0 or NaN
    fast = overrun_note(_overrun_rows([math.nan, 2.0], [1.5, 1.2]))
    assert "iplanner_ni 2 of 40" in fast and "real time." not in fast
    # no cycles or solve columns (older results): the count alone
    bare = df.drop(columns=["plan/cycles", "plan/mean_solve_ms", "sim/realtime_factor"])
    assert "iplanner_ni 7." in overrun_note(bare)
    assert overrun_note(df.drop(columns=["plan/overruns"])) == ""
    write_sweep_report(df, tmp_path, ["scenario", "planner"])
    assert note in (tmp_path / "results.md").read_text()


def test_overrun_note_names_the_solves_stopped_at_their_budget() -> None:
    """``plan/cut_short`` (stop_at_budget) gets a sentence of its own, after the overruns' or
    alone; zero counts and older results without the column add nothing."""
    df = _overrun_rows([3.0, 4.0], [0.6, 1.2])
    df["plan/cut_short"] = [0.0, 0.0, 8.0, 25.0]
    note = overrun_note(df)
    cut = "Solves stopped iterating at their budget (planner.replanner.stop_at_budget; "
    assert note.startswith("replanning solves over their wall-clock budget: iplanner_ni 7 of 40")
    assert note.endswith(f"results.csv). {cut}plan/cut_short): iplanner_ni 33 of 40.")
    df["plan/overruns"] = 0.0
    assert overrun_note(df) == f"{cut}plan/cut_short): iplanner_ni 33 of 40."
    assert overrun_note(df.drop(columns=["plan/overruns"])).startswith(cut)
    df["plan/cut_short"] = 0.0
    assert overrun_note(df) == ""


def test_a_log_cut_after_its_metrics_keeps_its_contact(tmp_path: Path) -> None:
    """Only the summary and footer lost: every message, the metrics included, was read, so
    the episode is complete (with a warning) and counts as contact-free."""
    cut = _cut(_episode_log(tmp_path / "0.mcap", FREE, steps=20), 0.98)
    with pytest.warns(DataWarning, match="truncated or damaged"):
        df = gather_results(cut)
    assert df.loc[0, "complete"] and df.loc[0, "contact"] == 0.0
    row = comparison_table(df).iloc[0]
    assert (row.contact_free, row.contact_unknown) == (1, 0)
    assert incomplete_logs_note(df) == ""


def test_comparison_table_shows_the_paper_units_and_completed_episodes() -> None:
    rows = [
        {
            "scenario": "s1",
            "planner": "iplanner_ni",
            "seed": seed,
            "eval/min_distance": d,
            "sim/body_distance": d + 0.02,
            "eval/mhd": mhd,
            "eval/contact": 0.0,
            "eval/completed": done,
            "eval/efficiency": eff,
            "eval/prediction_ms": 2.0,
            "plan/waits": waits,
        }
        for seed, d, mhd, done, eff, waits in (
            (0, 0.0504, 0.0358, 1.0, 1.5, 3.0),
            (1, 0.0704, 0.0558, 1.0, 1.7, 5.0),
            (2, 0.0604, 0.0458, 0.0, math.nan, 10.0),  # time ran out: no efficiency
        )
    ]
    df = gather_results(rows)
    table = comparison_table(df)
    assert list(table.columns[:6]) == [
        "scenario",
        "planner",
        "episodes",
        "contact_free",
        "contact_unknown",
        "completed",
    ]
    row = table.iloc[0]
    assert (row.episodes, row.completed, row.contact_free) == (3, 2, 3)
    assert row["distance cm"] == pytest.approx(6.04) and row["MHD cm"] == pytest.approx(4.58)
    assert row["body cm"] == pytest.approx(8.04)  # MuJoCo's geoms, sim/body_distance
    assert row["efficiency"] == pytest.approx(1.6)  # the two finished episodes
    assert row["waits"] == pytest.approx(6.0) and row["pred. ms"] == pytest.approx(2.0)
    text = format_table(table).splitlines()
    assert "distance cm" in text[0] and "MHD cm" in text[0] and "completed" in text[0]
    assert "6.04" in text[2] and "4.58" in text[2] and "0.0604" not in text[2]
    # the summary counts completed episodes the same way
    assert summary_table(df).iloc[0]["completed"] == 2
    # without a completed column there is nothing to count
    assert "completed" not in comparison_table(gather_results([{"planner": "a", "x": 1.0}]))


def test_console_key_explains_every_column_of_the_comparison_table() -> None:
    """The console printed the comparison table without a key to its columns; the key has a
    line for each count and each metric the table shows, in its order, and none for a
    column it does not show."""
    rows = [{"scenario": "s1", "planner": "itomp", "seed": 0, "eval/min_distance": 0.05,
             "eval/contact": 0.0, "eval/completed": 1.0}]  # fmt: skip
    table = comparison_table(gather_results(rows))
    lines = comparison_key(table).splitlines()
    assert lines[0].startswith("key (") and "–" in lines[0]
    named = [line.split("  ")[1] for line in lines[1:]]
    counts = ["contact_free", "contact_unknown", "completed", "touched"]
    assert named == [c for c in table.columns if c in counts or c in {
        h for h, _ in TABLE_COLUMNS.values()}]  # fmt: skip
    # every metric header the table can have is explained, with its unit where it has one
    for header, _ in TABLE_COLUMNS.values():
        text = comparison_key(pd.DataFrame(columns=["planner", header]))
        assert text.splitlines()[1].split("  ")[1] == header
        if header.endswith((" cm", " ms")):
            assert f"[{header.split()[-1]}]" in text
    assert "below 0 they overlapped" in comparison_key(table)
    assert comparison_key(pd.DataFrame(columns=["planner", "x"])) == ""


def test_results_md_holds_the_table_the_console_prints(tmp_path: Path) -> None:
    """results.md lacked the console's `body cm` and `waits` and gave the distances and the
    MHD in metres; its "Comparison" section is now the printed table, cell for cell, and the
    mean ± std summary follows it."""
    rows = [
        {"scenario": "s1", "planner": p, "seed": seed, "eval/min_distance": d,
         "sim/body_distance": d + 0.02, "eval/mhd": 0.04, "eval/contact": 0.0,
         "eval/completed": 1.0, "eval/efficiency": 1.5, "eval/smoothness": 2.0,
         "plan/waits": w}
        for p, d, w in (("itomp", 0.0504, 1.0), ("iplanner_ni", 0.109, 5.0))
        for seed in (0, 1)
    ]  # fmt: skip
    df = gather_results(rows)
    groups = report_groups(df)
    write_sweep_report(df, tmp_path, groups)
    md = (tmp_path / "results.md").read_text()
    section = md.split("## Comparison")[1].split("## Mean ± std")[0]
    table = [ln for ln in section.splitlines() if ln.startswith("|")]
    printed = format_table(comparison_table(df)).splitlines()
    header = [c.strip() for c in table[0].strip("|").split("|")]
    assert header == re.split(r"\s{2,}", printed[0].strip())
    assert {"distance cm", "body cm", "MHD cm", "waits"} <= set(header)
    for md_row, console_row in zip(table[2:], printed[2:], strict=True):
        cells = [c.strip() for c in md_row.strip("|").split("|")]
        assert cells == re.split(r"\s{2,}", console_row.strip())
    row = dict(zip(header, [c.strip() for c in table[3].strip("|").split("|")]))
    assert (row["distance cm"], row["body cm"], row["MHD cm"], row["waits"]) == (
        "10.9", "12.9", "4.00", "5.00",  # means to 3 digits, trailing zeros kept
    )  # fmt: skip
    # the summary with standard deviations is still there, after it, distances in cm too
    assert md.index("## Comparison") < md.index("## Mean ± std")
    assert "| s1 | iplanner_ni | 2 | 2 | 0 | 2 | 2.00 ± 0 | 10.9 ± 0 |" in md


def test_the_log_metadatas_second_names_give_no_second_column(tmp_path: Path) -> None:
    """A sweep summary had both `noise` and `tracker_noise`, and `speed` and `human_speed`:
    the episode log records each setting under both names."""
    for seed in (0, 1):
        meta = {"scenario": "s", "planner": "itomp", "seed": seed, "speed": "fast",
                "human_speed": "fast", "noise": 0.02 * seed,
                "tracker_noise": 0.02 * seed}  # fmt: skip
        with EpisodeWriter(tmp_path / "logs" / f"{seed}.mcap", metadata=meta) as log:
            log.metrics(1.0, {"eval/smoothness": 1.0, "eval/min_distance": 0.1})
    df = gather_results(tmp_path / "logs")
    assert {"noise", "speed"} <= set(df.columns)
    assert not {"tracker_noise", "human_speed"} & set(df.columns)
    assert list(df["noise"]) == [0.0, 0.02] and list(df["speed"]) == ["fast", "fast"]
    write_sweep_report(df, tmp_path / "report", report_groups(df))
    header = (tmp_path / "report" / "results.csv").read_text().splitlines()[0].split(",")
    assert "tracker_noise" not in header and "human_speed" not in header
    # a second name that disagrees is kept: it says something the first does not
    odd = gather_results([{"noise": 0.01, "tracker_noise": 0.05, "speed": "slow"}])
    assert odd.loc[0, "tracker_noise"] == 0.05 and odd.loc[0, "noise"] == 0.01


def test_paired_differences_match_a_paired_t_test() -> None:
    from scipy import stats

    g = np.random.default_rng(3)
    rows = []
    for scen in ("b_scen", "a_scen"):
        for seed in range(12):
            shared = g.normal(0.05, 0.03)  # what a seed gives every planner
            for planner, shift in (("iplanner_ni", 0.02), ("itomp", 0.0), ("iplanner_no_ni", 0.0)):
                rows.append({"scenario": scen, "seed": seed, "planner": planner,
                             "min_distance": shared + shift + g.normal(0, 0.01)})  # fmt: skip
    df = pd.DataFrame(rows)
    df.loc[
        (df.planner == "itomp") & (df.seed == 11) & (df.scenario == "a_scen"), "min_distance"
    ] = math.nan  # a cut episode: its pair is left out
    df = df[~((df.planner == "iplanner_ni") & (df.seed == 10))]  # an episode that never ran
    out = paired_differences(df, "min_distance", level=0.9)
    assert list(out.columns) == ["scenario", "planner", "pairs", "mean_diff", "ci_low",
                                 "ci_high", "p_value", "better"]  # fmt: skip
    assert list(out.scenario) == ["b_scen", "b_scen", "a_scen", "a_scen"]  # first seen first
    assert list(out.planner) == ["iplanner_no_ni", "iplanner_ni"] * 2  # PLANNER_ORDER
    for _, row in out.iterrows():
        a = df[(df.scenario == row.scenario) & (df.planner == row.planner)].set_index("seed")
        b = df[(df.scenario == row.scenario) & (df.planner == "itomp")].set_index("seed")
        both = a.min_distance.dropna().index.intersection(b.min_distance.dropna().index)
        x, y = a.min_distance[both].to_numpy(), b.min_distance[both].to_numpy()
        d = x - y
        assert (
            row.pairs
            == len(d)
            == (12 - (row.scenario == "a_scen") - (row.planner == "iplanner_ni"))
        )
        ref = stats.ttest_rel(x, y)
        assert row.mean_diff == pytest.approx(d.mean(), rel=1e-12)
        assert row.p_value == pytest.approx(ref.pvalue, rel=1e-9)
        ci = ref.confidence_interval(0.9)
        assert (row.ci_low, row.ci_high) == (pytest.approx(ci.low), pytest.approx(ci.high))
        assert row.better == int((d > 0).sum())  # farther from the person
    ni = out[out.planner == "iplanner_ni"]
    assert (ni.ci_low > 0).all() and (ni.p_value < 0.01).all()  # the 2 cm shift is found


def test_paired_differences_refuse_what_cannot_be_paired() -> None:
    df = pd.DataFrame(
        {
            "scenario": ["s"] * 4,
            "seed": [0, 0, 1, 1],
            "planner": ["itomp", "iplanner_ni"] * 2,
            "x": [1.0, 2.0, 1.0, 2.0],
        }
    )
    out = paired_differences(df, "x")
    assert out.loc[0, "mean_diff"] == 1.0 and out.loc[0, "p_value"] == 0.0  # no spread
    assert out.loc[0, "ci_low"] == out.loc[0, "ci_high"] == 1.0
    assert math.isnan(out.loc[0, "better"])  # "x": which way is better is not known
    one = paired_differences(df[df.seed == 0], "x")
    assert one.loc[0, "pairs"] == 1 and math.isnan(one.loc[0, "ci_low"])
    with pytest.raises(ConfigError, match="no episodes of the baseline planner 'oracle'"):
        paired_differences(df, "x", baseline="oracle")
    with pytest.raises(ConfigError, match="appears more than once"):
        paired_differences(pd.concat([df, df.iloc[:1]]), "x")
    with pytest.raises(ConfigError, match=r"columns \['y'\] not in"):
        paired_differences(df, "y")
    with pytest.raises(ConfigError, match="expected level in"):
        paired_differences(df, "x", level=95)


def test_sweep_report_pairs_planners_with_itomp_by_seed(tmp_path: Path) -> None:
    g = np.random.default_rng(5)
    rows = []
    for seed in range(6):
        for planner, shift in (("itomp", 0.0), ("iplanner_ni", 0.03)):
            rows.append({"scenario": "s", "planner": planner, "seed": seed,
                         "min_distance": 0.05 + shift + g.normal(0, 0.005),
                         "smoothness": 40.0 + g.normal(0, 1.0)})  # fmt: skip
    df = pd.DataFrame(rows)
    written = write_sweep_report(df, tmp_path / "a", ["scenario", "planner"])
    md = (tmp_path / "a" / "results.md").read_text()
    assert "## Paired by seed" in md
    for m in ("min_distance", "smoothness"):  # a forest plot each, listed and readable
        png = tmp_path / "a" / f"paired_{m}.png"
        assert png in written and f"`paired_{m}.png`" in md
        assert matplotlib.image.imread(png).shape[2] in (3, 4)
    table = paired_differences(df, "min_distance")
    section = md.split("## Paired by seed")[1].splitlines()
    line = next(ln for ln in section if ln.startswith("| s |") and "| min_distance cm |" in ln)
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[:4] == ["s", "iplanner_ni", "min_distance cm", "6"]
    assert float(cells[4]) == pytest.approx(100.0 * table.loc[0, "mean_diff"], rel=2e-3)
    assert cells[-1] == "6" and float(cells[5]) > 0  # all six larger, interval above 0
    # one seed: nothing to pair, which the section says (it was left out without a word)
    write_sweep_report(df[df.seed == 0], tmp_path / "b", ["scenario", "planner"])
    section = (tmp_path / "b" / "results.md").read_text().split("## Paired by seed")[1]
    assert section.strip() == (
        "Paired comparison skipped: needs at least 2 seeds shared by itomp and another "
        "planner in one setting; found 1."
    )
    assert not (tmp_path / "b" / "paired_min_distance.png").exists()
    # no ITOMP: nothing to compare with, nothing said
    write_sweep_report(df[df.planner != "itomp"], tmp_path / "c", ["scenario", "planner"])
    assert "Paired by seed" not in (tmp_path / "c" / "results.md").read_text()
    # an episode twice in a group (a setting the groups do not keep apart): said, not raised
    write_sweep_report(pd.concat([df, df.iloc[:1]]), tmp_path / "d", ["scenario", "planner"])
    assert "Not computed: episode" in (tmp_path / "d" / "results.md").read_text()


def test_paired_skip_note_counts_the_seeds_a_baseline_shares(tmp_path: Path) -> None:
    """``evaluate.logs=[a,b] evaluate.labels=[held,spread] evaluate.baseline=itomp@spread``
    with one seed per run wrote no "Paired by seed" section and said nothing."""
    from iplanner_torch.eval.report import paired_skip_note

    def runs(seeds_a: list[int], seeds_b: list[int]) -> pd.DataFrame:
        return pd.DataFrame(
            [
                {"scenario": "s", "planner": f"{p}@{label}", "seed": seed,
                 "min_distance": 0.1, "smoothness": 1.0}
                for label, seeds in (("held", seeds_a), ("spread", seeds_b))
                for p in ("itomp", "iplanner_ni") for seed in seeds
            ]
        )  # fmt: skip

    groups = ("scenario", "planner")
    one = runs([0], [0])
    note = paired_skip_note(one, groups, "itomp@spread")
    assert note == (
        "paired comparison skipped: needs at least 2 seeds shared by itomp@spread and another "
        "planner in one setting; found 1"
    )
    write_sweep_report(one, tmp_path / "one", groups, baseline="itomp@spread")
    md = (tmp_path / "one" / "results.md").read_text()
    assert "## Paired by seed" in md and "Paired comparison skipped: needs at least 2" in md
    # seeds 0, 1 and 2, 3, the spread run of the baseline alone: two seeds a planner, none
    # shared with the baseline
    apart = runs([0, 1], [2, 3])
    apart = apart[apart.planner != "iplanner_ni@spread"]
    assert paired_skip_note(apart, groups, "itomp@spread").endswith("; found 0")
    # two shared seeds: the comparison is made, nothing to say
    assert paired_skip_note(runs([0, 1], [0, 1]), groups, "itomp@spread") == ""
    # the baseline alone, or absent, or a summary not by planner: nothing to compare
    alone = one[one.planner == "itomp@spread"]
    assert paired_skip_note(alone, groups, "itomp@spread") == ""
    assert paired_skip_note(one, groups, "oracle") == ""
    assert paired_skip_note(one, ("scenario",), "itomp@spread") == ""
    assert "no seed column" in paired_skip_note(one.drop(columns="seed"), groups, "itomp@held")
    # the default baseline, renamed by the labels: the section said nothing at all
    assert paired_skip_note(runs([0, 1], [0, 1]), groups) == (
        "paired comparison skipped: no planner is named itomp (the labelled runs name it "
        "itomp@held, itomp@spread); choose one with evaluate.baseline=<name>"
    )


def test_plot_paired_names_the_baseline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The axis said "planner minus baseline" without naming the baseline."""
    figures = _recorded_figures(monkeypatch)
    table = pd.DataFrame(
        {"scenario": ["a"], "planner": ["iplanner_ni"], "pairs": [5], "mean_diff": [0.02],
         "ci_low": [0.01], "ci_high": [0.03]}
    )  # fmt: skip
    plot_paired(table, "min_distance", tmp_path / "p.png")
    plot_paired(table, "min_distance", tmp_path / "q.png", baseline="itomp@spread")
    labels = [f.axes[0].get_xlabel() for f in figures]
    assert labels == [
        "closest distance [cm]: planner minus ITOMP, 95% interval",
        "closest distance [cm]: planner minus itomp@spread, 95% interval",
    ]
    assert (
        figures[0].axes[0].get_title() == "closest distance, paired by seed (5 pairs of episodes)"
    )
    # rows name their settings: which number is the noise and which the confidence
    swept = table.assign(noise=[0.02], confidence=[0.9])[
        ["scenario", "noise", "confidence", *table.columns[1:]]
    ]
    plot_paired(swept, "min_distance", tmp_path / "r.png")
    rows = [t.get_text() for t in figures[-1].axes[0].get_yticklabels()]
    assert rows == ["a, noise 0.02, confidence 0.9, I-Planner, NI"]


def test_plot_paired_draws_rows_without_an_interval(tmp_path: Path) -> None:
    table = pd.DataFrame(
        {
            "scenario": ["a", "b"],
            "planner": ["iplanner_ni", "iplanner_ni"],
            "pairs": [5, 1],
            "mean_diff": [0.02, -0.01],
            "ci_low": [0.01, math.nan],  # one pair: no interval
            "ci_high": [0.03, math.nan],
        }
    )
    out = plot_paired(table, "min_distance", tmp_path / "sub" / "p.png", level=0.9)
    assert out.is_file() and matplotlib.image.imread(out).ndim == 3
    with pytest.raises(ConfigError, match="paired columns"):
        plot_paired(table.drop(columns="ci_low"), "min_distance", tmp_path / "q.png")


def test_touched_counts_mujoco_contacts_apart_from_sphere_overlaps() -> None:
    """``contact_free`` is about the sphere models (``min_distance``); ``touched`` counts
    MuJoCo's robot-human contacts (``sim/contacts``), and appears only with that column."""
    rows = [
        {"planner": "itomp", "seed": 0, "eval/min_distance": 0.02, "sim/contacts": 0.0},
        {"planner": "itomp", "seed": 1, "eval/min_distance": -0.01, "sim/contacts": 0.0},
        {"planner": "itomp", "seed": 2, "eval/min_distance": -0.03, "sim/contacts": 2.0},
        {"planner": "itomp", "seed": 3, "eval/min_distance": math.nan, "sim/contacts": math.nan},
    ]
    df = gather_results(rows)
    for table in (comparison_table(df), summary_table(df, group_by=("planner",))):
        row = table.iloc[0]
        assert (row.episodes, row.contact_free, row.contact_unknown) == (4, 1, 1)
        assert row.touched == 1
    plain = gather_results([{k: v for k, v in r.items() if k != "sim/contacts"} for r in rows])
    assert "touched" not in comparison_table(plain).columns


def test_sweep_report_refuses_an_output_it_cannot_write_before_writing(
    results: pd.DataFrame, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    (out / "results.md").mkdir(parents=True)
    (out / "results.csv").write_text("old rows\n")
    with pytest.raises(DataError, match=r"results\.md: a folder where the report writes"):
        write_sweep_report(results, out)
    assert (out / "results.csv").read_text() == "old rows\n"  # the old results are kept
    (tmp_path / "file").write_text("x")
    with pytest.raises(DataError, match="file: not a folder"):
        write_sweep_report(results, tmp_path / "file")


def test_sweep_report_of_no_episode_or_one_that_fails_keeps_the_earlier_results(
    results: pd.DataFrame, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """No rows were a ConfigError about group columns (reading as a settings mistake), and a
    report that failed while building its tables had already replaced results.csv."""
    import iplanner_torch.eval.report as report

    out = tmp_path / "run"
    out.mkdir()
    (out / "results.csv").write_text("old rows\n")
    with pytest.raises(DataError, match=r"run: no episode to report .* nothing was written"):
        write_sweep_report(results.iloc[:0], out)

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("a table that does not build")

    monkeypatch.setattr(report, "comparison_table", broken)
    with pytest.raises(RuntimeError, match="does not build"):
        write_sweep_report(results, out)
    assert sorted(p.name for p in out.iterdir()) == ["results.csv"]
    assert (out / "results.csv").read_text() == "old rows\n"


def test_a_plot_that_cannot_be_saved_costs_neither_the_tables_nor_the_other_plots(
    tmp_path: Path,
) -> None:
    """A folder where a chart goes (or a full disk) made the report stop with an OSError
    after results.csv, without the other plots; now it is one warning naming the chart."""
    df = _sweep_rows()
    groups = report_groups(df)
    (tmp_path / "compare_smoothness.png").mkdir()
    (tmp_path / "paired_min_distance.png").mkdir()
    with pytest.warns(DataWarning) as record:
        written = {p.name for p in write_sweep_report(df, tmp_path, groups, sweep="noise")}
    messages = [str(w.message) for w in record if issubclass(w.category, DataWarning)]
    assert len(messages) == 1
    assert "2 plot(s) not written: paired_min_distance.png (IsADirectoryError" in messages[0]
    assert "compare_smoothness.png (IsADirectoryError" in messages[0]
    assert messages[0].endswith("results.csv and results.md are")
    assert {"results.csv", "results.md", "compare_min_distance.png"} <= written
    assert "paired_smoothness.png" in written and "sweep_smoothness.png" in written
    assert "compare_smoothness.png" not in written and "paired_min_distance.png" not in written
    assert (tmp_path / "results.csv").is_file()
    assert (tmp_path / "compare_min_distance.png").is_file()
    # results.md names the paired plots that were drawn, not the one that failed
    md = (tmp_path / "results.md").read_text()
    assert "`paired_smoothness.png`" in md and "paired_min_distance.png" not in md


def test_boundaries_of_contact_and_of_a_paired_win() -> None:
    """``min_distance == 0`` (spheres that just touch) is a contact where no ``contact``
    column says otherwise; a paired difference of 0 is no win, 1 is one."""
    df = pd.DataFrame({"min_distance": [0.0, 0.001, -0.01, math.nan]})
    assert episode_contact(df).tolist()[:3] == [1.0, 0.0, 1.0]
    assert math.isnan(episode_contact(df).iloc[3])
    runs = pd.DataFrame(
        {
            "scenario": ["s"] * 4,
            "seed": [0, 1, 0, 1],
            "planner": ["itomp", "itomp", "iplanner_ni", "iplanner_ni"],
            "min_distance": [0.02, 0.02, 0.02, 0.03],
        }
    )
    (row,) = paired_differences(runs, "min_distance").itertuples()
    assert (row.pairs, row.better) == (2, 1)


def test_a_planner_keeps_its_colour_whichever_others_a_plot_shows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The I-Planner NI is green (tab10's third) in a plot of all planners, in a paired plot
    that leaves ITOMP out and in one with the oracle alone beside it; a labelled second run
    of a planner and a hue that is no planner take spare colours."""
    assert hue_colours(["itomp", "iplanner_no_ni", "iplanner_ni", "oracle"]) == {
        "itomp": "C0", "iplanner_no_ni": "C1", "iplanner_ni": "C2", "oracle": "C4"
    }  # fmt: skip
    assert hue_colours(["oracle", "iplanner_ni"]) == {"oracle": "C4", "iplanner_ni": "C2"}
    both = hue_colours(["itomp", "itomp@spread", "iplanner_ni@held"])
    assert both == {"itomp": "C0", "itomp@spread": "C6", "iplanner_ni@held": "C2"}
    assert hue_colours(["slow", "medium"]) == {"slow": "C6", "medium": "C7"}
    # what the bar charts draw: the NI's bars in green with and without ITOMP beside them
    import matplotlib.axes

    drawn: list[tuple[str, str]] = []
    bar = matplotlib.axes.Axes.bar

    def recording(self, *args, **kwargs):
        drawn.append((kwargs.get("label"), kwargs.get("color")))
        return bar(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "bar", recording)
    rows = [{"scenario": "s", "planner": p, "seed": 0, "smoothness": 1.0}
            for p in ("itomp", "iplanner_ni")]  # fmt: skip
    plot_comparison(pd.DataFrame(rows), tmp_path / "a", metrics=("smoothness",))
    plot_comparison(pd.DataFrame(rows[1:]), tmp_path / "b", metrics=("smoothness",))
    assert drawn == [("ITOMP", "C0"), ("I-Planner, NI", "C2"), ("I-Planner, NI", "C2")]


def test_sweep_lines_start_at_zero_say_their_count_and_how_to_read_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With one seed the line plots said "bands ± 1 std" over crisp lines, and autoscaled a
    few percent of jitter (1.59-1.65 efficiency) to the panel's full height; nothing said
    which way is better or where the robot starts to help."""
    from iplanner_torch.eval.report import plot_comparison, plot_sweep

    figures = _recorded_figures(monkeypatch)
    df = pd.DataFrame(
        {
            "planner": ["itomp", "iplanner_ni"] * 2,
            "noise": [0.0, 0.0, 0.05, 0.05],
            "scenario": ["s"] * 4,
            "efficiency": [1.65, 1.62, 1.59, 1.64],
            "smoothness": [8.0, 19.9, 8.1, 21.0],
        }
    )
    plot_sweep(df, "noise", "efficiency", "planner", tmp_path / "eff.png")
    eff = figures[-1]
    title = eff._suptitle.get_text()
    assert "one episode per point (no spread to show)" in title
    assert "above 1 (dashed): the robot helps" in title
    assert eff.axes[0].get_ylim()[0] == 0.0
    assert any(list(ln.get_ydata()) == [1.0, 1.0] for ln in eff.axes[0].get_lines())
    plot_comparison(df, tmp_path, metrics=("smoothness",), group_by=("noise", "planner"))
    assert "(lower is smoother)" in figures[-1].axes[0].get_title()


def test_bars_of_labelled_runs_sit_on_their_own_group(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two labelled runs, each with its own planners under its own group: every group kept a
    slot for all six bars and filled three, so the bars sat off their group's tick."""
    from iplanner_torch.eval.report import plot_comparison

    figures = _recorded_figures(monkeypatch)
    rows = [
        {"robot": robot, "planner": f"{p}@{label}", "smoothness": v}
        for robot, label in (("kuka_iiwa14", "iiwa"), ("fetch", "fetch"))
        for p, v in (("itomp", 8.0), ("iplanner_no_ni", 17.0), ("iplanner_ni", 20.0))
    ]
    plot_comparison(pd.DataFrame(rows), tmp_path, ("smoothness",), ("robot", "planner"))
    ax = figures[-1].axes[0]
    centres = [(r.get_x() + r.get_width() / 2, r.get_height()) for r in ax.patches]
    assert len(centres) == 6
    for x, _ in centres:  # each bar within its own group, three to a group
        assert abs(x - round(x)) < 0.4
    assert sorted(round(x) for x, _ in centres) == [0, 0, 0, 1, 1, 1]
    # centred: the middle bar of each group on its tick
    assert sorted(abs(x - round(x)) for x, _ in centres)[:2] == pytest.approx([0.0, 0.0])
