"""scripts/safety_seeds_report.py: episode rows gathered from a sweep folder, counted per
scenario and planner."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pandas as pd

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
