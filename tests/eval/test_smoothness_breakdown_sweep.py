"""scripts/smoothness_breakdown.py on a multirun folder: one row per swept override, as
``iplanner-evaluate evaluate.mode=episode`` keeps them apart."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.eval.smoothness import PlanRecord, smoothness_breakdown
from iplanner_torch.recording import EpisodeWriter

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"
H = 0.04  # sample period [s]


def _load():
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec = importlib.util.spec_from_file_location("sb", SCRIPTS / "smoothness_breakdown.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        return mod
    finally:
        sys.path.remove(str(SCRIPTS))


def _write_log(path: Path, scale: float, seed: int) -> float:
    """An episode log of joint 0 accelerating at ``scale`` rad/s^2 for 4 s (one plan that
    runs to the end); returns its smoothness (:func:`smoothness_breakdown`)."""
    t = np.round(np.arange(0.0, 4.0 + H / 2, H), 10)  # (T,)
    q = np.stack([0.5 * scale * t**2, np.zeros_like(t)], axis=1)  # (T, 2)
    plan = PlanRecord(times=t[::10], q=q[::10], wait_s=0.0)
    meta = {"scenario": "s1", "planner": "itomp", "speed": "medium", "seed": seed}
    path.parent.mkdir(parents=True, exist_ok=True)
    with EpisodeWriter(path, metadata=meta) as log:
        log.plan(0.0, plan.times, plan.q, True, plan.wait_s, 1.0)
        for i in range(t.shape[0]):
            log.robot_state(float(t[i]), q[i], np.zeros(2), ["a", "b"])
    return smoothness_breakdown(t, q, [plan]).smoothness


def test_sweep_folder_keeps_swept_overrides_apart(tmp_path: Path, monkeypatch, capsys) -> None:
    """Jobs of ``-m planner.itomp_spread_mps=0,0.1`` (same scenario, planner and seeds) give
    one row each; the seeds split over jobs (``run.seeds``) are repeats, never kept apart."""
    expected = {}
    for job, spread, scale in (("0", "0", 1.0), ("1", "0.1", 2.0)):
        hydra = tmp_path / job / ".hydra"
        hydra.mkdir(parents=True)
        (hydra / "overrides.yaml").write_text(
            f"- planner.itomp_spread_mps={spread}\n- run.seeds=[{job}]\n"
        )
        for seed in (0, 1):
            log = tmp_path / job / "episodes" / f"s1_itomp_s{seed}.mcap"
            expected[float(spread)] = _write_log(log, scale, seed)
    monkeypatch.setattr(sys, "argv", ["smoothness_breakdown.py", str(tmp_path)])
    _load().main()
    lines = capsys.readouterr().out.splitlines()
    header = [c.strip() for c in lines[0].split("|")[1:-1]]
    assert header[:4] == ["scenario", "planner.itomp_spread_mps", "planner", "episodes"]
    rows = [[c.strip() for c in ln.split("|")[1:-1]] for ln in lines if ln.startswith("| s1")]
    got = {float(r[1]): (r[2], int(r[3]), float(r[4])) for r in rows}
    assert set(got) == {0.0, 0.1}
    for spread, (planner, episodes, smooth) in got.items():
        assert planner == "itomp" and episodes == 2
        assert smooth == pytest.approx(expected[spread], rel=2e-3)  # 3 significant digits
    assert expected[0.0] > 0.0 and expected[0.1] == pytest.approx(4 * expected[0.0])
