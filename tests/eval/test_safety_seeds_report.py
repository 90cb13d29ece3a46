"""scripts/safety_seeds_report.py: episode rows gathered from a sweep folder, counted per
scenario and planner."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pandas as pd
import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def _load():
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec = importlib.util.spec_from_file_location("ssr", SCRIPTS / "safety_seeds_report.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        return mod
    finally:
        sys.path.remove(str(SCRIPTS))


def _rows(planner: str, seeds: range, contacts: list[int]) -> pd.DataFrame:
    n = len(seeds)
    return pd.DataFrame(
        {
            "planner": planner,
            "scenario": "s1",
            "seed": list(seeds),
            "sim/contacts": contacts,
            "eval/completed": [1.0] * n,
            "eval/min_distance": [0.05 + 0.01 * s for s in seeds],
            "eval/smoothness": [10.0] * n,
            "eval/jerkiness": [100.0] * n,
            "eval/efficiency": [1.5] * n,
            "plan/waits": [2.0] * n,
            "plan/emergencies": [0.0] * n,
            "sim/realtime_factor": [3.0] * n,
        }
    )


def test_gather_reads_every_job_and_skips_summaries(tmp_path: Path) -> None:
    ssr = _load()
    for job, seeds, contacts in (("0", range(0, 3), [0, 1, 0]), ("1", range(3, 5), [0, 0])):
        d = tmp_path / job / "s1"
        d.mkdir(parents=True)
        (tmp_path / job / ".hydra").mkdir()
        _rows("iplanner_ni", seeds, contacts).to_csv(d / "results.csv", index=False)
    # a gathered summary (renamed columns) must not be counted twice
    (tmp_path / "summary").mkdir()
    pd.DataFrame({"planner": ["iplanner_ni"], "scenario": ["s1"], "seed": [0]}).to_csv(
        tmp_path / "summary" / "results.csv", index=False
    )
    df = ssr.gather(tmp_path)
    assert len(df) == 5
    row = ssr.summarise(df).iloc[0]
    assert row["episodes"] == 5 and row["contact_free"] == 4 and row["completed"] == 5
    assert abs(row["min_distance_min"] - 0.05) < 1e-12


def test_gather_reads_a_finished_single_scenario_run(tmp_path: Path) -> None:
    """A single-scenario run keeps only the summary-style results.csv (eval/ prefix dropped)."""
    ssr = _load()
    rows = _rows("itomp", range(3), [0, 0, 1])
    rows.columns = [c[5:] if c.startswith("eval/") else c for c in rows.columns]
    rows.to_csv(tmp_path / "results.csv", index=False)
    row = ssr.summarise(ssr.gather(tmp_path)).iloc[0]
    assert row["episodes"] == 3 and row["contact_free"] == 2
    assert abs(row["min_distance_mean"] - 0.06) < 1e-12


def test_reports_refuse_cut_rows_and_existing_records(tmp_path: Path) -> None:
    import subprocess

    run = tmp_path / "run"
    run.mkdir()
    text = _rows("itomp", range(3), [0, 0, 0]).to_csv(index=False)
    (run / "results.csv").write_text(text[: text.rindex(",0.07")])  # cut in the last row
    out = tmp_path / "record"
    script = [sys.executable, str(SCRIPTS / "safety_seeds_report.py")]
    res = subprocess.run([*script, str(run), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "results.csv: the last row (file row 4) is cut short" in res.stderr
    assert res.stderr.rstrip().endswith("a record needs every row whole")
    assert not out.exists()  # nothing written from a cut file
    rows = _rows("itomp", range(3), [0, 0, 0])
    rows.loc[1, "eval/min_distance"] = None  # an empty cell
    rows.to_csv(run / "results.csv", index=False)
    res = subprocess.run([*script, str(run), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 2
    assert "1 of 3 episode row(s) lack 'min_distance'" in res.stderr
    assert not out.exists()  # nothing written from an incomplete file
    _rows("itomp", range(3), [0, 0, 0]).to_csv(run / "results.csv", index=False)
    res = subprocess.run([*script, str(run), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    (out / "README.md").write_text("hand-written")
    res = subprocess.run([*script, str(run), "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 2 and "pass --force" in res.stderr
    assert (out / "README.md").read_text() == "hand-written"
    res = subprocess.run([*script, str(tmp_path / "nope")], capture_output=True, text=True)
    assert res.returncode == 2 and "not a folder" in res.stderr


def test_paired_section_is_each_planner_minus_itomp_per_seed() -> None:
    mod = _load()
    a = _rows("itomp", range(4), [0] * 4)
    b = _rows("iplanner_ni", range(4), [0] * 4)
    b["eval/min_distance"] += [0.01, 0.02, 0.01, 0.02]  # +1.5 cm mean
    b["eval/smoothness"] = [12.0, 9.0, 13.0, 10.0]  # +1 mean: rougher in 2, smoother in 1
    df = pd.concat([a, b], ignore_index=True).rename(columns=lambda c: c.removeprefix("eval/"))
    t = mod.paired(df).set_index("metric")
    assert list(t.index) == ["distance cm", "smoothness"] and set(t.planner) == {"iplanner_ni"}
    dist, smooth = t.loc["distance cm"], t.loc["smoothness"]
    assert dist.pairs == 4 and abs(dist.mean_diff - 1.5) < 1e-9 and dist.better == 4
    assert dist.ci_low < 1.5 < dist.ci_high and dist.p_value < 0.05
    assert abs(smooth.mean_diff - 1.0) < 1e-9 and smooth.better == 1 and smooth.p_value > 0.05
    assert mod.paired(b.rename(columns=lambda c: c.removeprefix("eval/"))).empty  # no ITOMP


def _job(root: Path, job: str, seeds: range, **settings: object) -> None:
    d = root / job / "s1"
    d.mkdir(parents=True)
    (root / job / ".hydra").mkdir()
    rows = _rows("itomp", seeds, [0] * len(seeds))
    for key, value in settings.items():
        rows.insert(2, key, value)
    rows.to_csv(d / "results.csv", index=False)


def test_gather_drops_repeats_of_one_setting_only(tmp_path: Path, monkeypatch, capsys) -> None:
    """A job repeated at the same confidence is one episode per seed; rows of another
    confidence or robot are refused (the report covers one), naming the values."""
    ssr = _load()
    _job(tmp_path / "a", "0", range(3), confidence=0.99)
    _job(tmp_path / "a", "1", range(1, 4), confidence=0.99)  # seeds 1, 2 again
    df = ssr.gather(tmp_path / "a")
    assert sorted(df["seed"]) == [0, 1, 2, 3] and set(df["confidence"]) == {0.99}
    out = tmp_path / "record"
    monkeypatch.setattr(sys, "argv", ["ssr", str(tmp_path / "a"), "--out", str(out)])
    ssr.main()
    assert "(confidence 0.99)" in (out / "README.md").read_text().splitlines()[0]
    for name, key, values in (
        ("b", "confidence", (0.95, 0.99)),
        ("c", "robot", ("fetch", "kuka_iiwa14")),
    ):
        _job(tmp_path / name, "0", range(3), **{key: values[0]})
        _job(tmp_path / name, "1", range(3), **{key: values[1]})
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            ssr.gather(tmp_path / name)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and err.count("\n") == 1, err
        assert f"more than one {key} ({values[0]}, {values[1]})" in err


def test_gather_skips_the_sweep_summary_of_a_real_sweep(tmp_path: Path, monkeypatch) -> None:
    """A multirun folder as iplanner-experiment -m leaves it: jobs with .hydra/, their
    results.csv (no robot column) and scenario sub-folders, and the gathered
    summary/results.csv (with robot and path columns, no .hydra/) that repeats every episode:
    each episode is counted once, and the paired section pairs them."""
    ssr = _load()
    episodes = []
    for job, seed in (("0", 0), ("1", 1)):
        rows = pd.concat([_rows(p, range(seed, seed + 1), [0]) for p in ("itomp", "oracle")])
        rows = rows.rename(columns=lambda c: c.removeprefix("eval/"))
        (tmp_path / job / ".hydra").mkdir(parents=True)
        (tmp_path / job / ".hydra" / "overrides.yaml").write_text(f"- run.seeds=[{seed}]\n")
        (tmp_path / job / "s1").mkdir()
        rows.to_csv(tmp_path / job / "results.csv", index=False)
        rows.to_csv(tmp_path / job / "s1" / "results.csv", index=False)
        episodes.append(rows.assign(robot="kuka_iiwa14", path=str(tmp_path / job / "x.mcap")))
    (tmp_path / "summary").mkdir()
    pd.concat(episodes).to_csv(tmp_path / "summary" / "results.csv", index=False)
    df = ssr.gather(tmp_path)
    assert len(df) == 4 and "robot" not in df.columns
    assert list(ssr.summarise(df)["episodes"]) == [2, 2]
    assert ssr.results_files(tmp_path) == [
        tmp_path / "0" / "results.csv",
        tmp_path / "0" / "s1" / "results.csv",
        tmp_path / "1" / "results.csv",
        tmp_path / "1" / "s1" / "results.csv",
    ]
    out = tmp_path / "record"
    monkeypatch.setattr(sys, "argv", ["ssr", str(tmp_path), "--out", str(out)])
    ssr.main()  # pairs one episode per planner and seed
    assert "| s1 | oracle | distance cm | 2 |" in (out / "README.md").read_text()
