"""A sweep's job record nested too deep for the JSON parser loses its row, as a damaged one
does: it used to escape as a RecursionError and end the sweep's summary."""

from __future__ import annotations

import json
from pathlib import Path

from iplanner_torch.cli.callbacks import JOB_METRICS_FILES, gather_job_metrics, job_metrics_rows

DEEP = "[" * 100_000 + "]" * 100_000


def test_a_job_record_nested_too_deep_loses_its_row(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    for job, text in ((0, json.dumps({"seconds": 1.5})), (1, DEEP), (2, "{not json")):
        (sweep / str(job) / ".hydra").mkdir(parents=True)
        (sweep / str(job) / JOB_METRICS_FILES[0]).write_text(text, encoding="utf-8")
    rows = job_metrics_rows(sweep)
    assert list(rows["job"]) == ["0"]
    assert list(rows["seconds"]) == [1.5]
    written = gather_job_metrics(sweep, tmp_path / "summary")
    assert {"results.csv", "results.md"} <= {p.name for p in written}
