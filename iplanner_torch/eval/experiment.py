"""Sweeps of closed-loop episodes (paper sec. 7, tables performance / performance_simulation
and fig. speed_response): planners x scenarios x human speeds x tracker noises x seeds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError
from iplanner_torch.eval.episode import (
    PLANNER_KINDS,
    EpisodeCfg,
    check_predictor_rate,
    run_episode,
)
from iplanner_torch.robot.model import RobotCfg
from iplanner_torch.sim.human import SPEED_FACTORS
from iplanner_torch.sim.tasks import ScenarioCfg
from iplanner_torch.sim.tracker import MAX_NOISE_M


@dataclass(frozen=True, kw_only=True)
class ExperimentCfg:
    """A grid of closed-loop episodes."""

    # experiment name (printed when the run starts)
    name: str = "table_simulation"
    # the robot and its base pose (a name: RobotCfg(name=...) with the robot's defaults;
    # None: the iiwa)
    robot: RobotCfg | str | None = "kuka_iiwa14"
    # device of the robot model, planner and predictor ("cpu", "cuda")
    device: str = "cpu"
    # scenarios (rows of the paper's table)
    scenarios: list[ScenarioCfg] = field(default_factory=lambda: [ScenarioCfg()])
    # planner kinds: "itomp", "iplanner_no_ni", "iplanner_ni", "oracle", "blind"
    planners: list[str] = field(default_factory=lambda: ["itomp", "iplanner_no_ni", "iplanner_ni"])
    # episode seeds
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    # human speeds ("slow", "medium", "fast"); empty keeps the episode's
    speeds: list[str] = field(default_factory=list)
    # tracker noise standard deviations [m]; empty keeps the episode's
    noises: list[float] = field(default_factory=list)
    # predictor checkpoint per variant ("no_ni", "ni")
    predictor_paths: dict[str, str] = field(default_factory=dict)
    # the episode template (scenario, speed and noise are replaced per run)
    episode: EpisodeCfg = field(default_factory=EpisodeCfg)
    # write one MCAP log per episode under out_dir/episodes
    write_mcap: bool = True

    def __post_init__(self) -> None:
        for name in ("scenarios", "planners", "seeds", "speeds", "noises"):
            value = getattr(self, name)
            if not isinstance(value, (list, tuple)):  # a string would iterate as letters
                raise ConfigError(f"{name}: expected a list, e.g. {name}=[...], got {value!r}")
        if self.robot is None:  # a config's "robot: null" (the CLI's robot group)
            object.__setattr__(self, "robot", RobotCfg(name="kuka_iiwa14"))
        elif isinstance(self.robot, str):
            object.__setattr__(self, "robot", RobotCfg(name=self.robot))  # type: ignore[arg-type]
        elif not isinstance(self.robot, RobotCfg):
            raise ConfigError(f"expected robot a RobotCfg or a name, got {self.robot!r}")
        unknown = [p for p in self.planners if p not in PLANNER_KINDS]
        if unknown or not self.planners:
            raise ConfigError(
                f"planners: expected planners from {sorted(PLANNER_KINDS)}, got "
                f"{unknown or self.planners}"
            )
        bad = [s for s in self.speeds if s not in SPEED_FACTORS]
        if bad:
            raise ConfigError(f"speeds: expected speeds from {sorted(SPEED_FACTORS)}, got {bad}")
        for name in ("seeds", "scenarios"):
            if not getattr(self, name):
                raise ConfigError(f"{name}: expected at least one, got []")
        odd = [s for s in self.scenarios if not isinstance(s, ScenarioCfg)]
        if odd:  # [1,2], or a mapping without _target_: an AttributeError when the run starts
            raise ConfigError(
                f"scenarios: expected a list of ScenarioCfg settings (each with _target_: "
                f"iplanner_torch.sim.tasks.ScenarioCfg), got {odd[0]!r}"
            )
        if not all(isinstance(n, (int, float)) and 0 <= n <= MAX_NOISE_M for n in self.noises):
            raise ConfigError(
                f"noises: expected noises in [0, {MAX_NOISE_M:g}] m, got {self.noises}"
            )
        if not all(
            isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= checks.MAX_SEED
            for s in self.seeds
        ):
            raise ConfigError(
                f"seeds: expected seeds as integers in [0, 2^32 - 1], got {self.seeds}"
            )
        for name in ("seeds", "planners", "speeds", "noises"):
            values = list(getattr(self, name))
            twice = sorted({str(v) for v in values if values.count(v) > 1})
            if twice:  # the same episode twice: counted twice, its log written over
                raise ConfigError(f"{name}: {', '.join(twice)} given twice")
        for scenario in self.scenarios:  # each scenario's episode settings, before any runs
            try:
                replace(self.episode, scenario=scenario)
            except ConfigError as err:
                raise ConfigError(f"scenario {scenario.name!r}: {err}") from err


def _load_predictor(path: str, device: str) -> Any:
    from iplanner_torch.prediction.predictor import HumanMotionPredictor

    predictor = HumanMotionPredictor.load(path)
    to = getattr(predictor, "to", None)
    return to(device) if callable(to) and device != "cpu" else predictor


def run_experiment(cfg: ExperimentCfg, out_dir: Path) -> pd.DataFrame:
    """Run every episode of the grid and gather one metric row per episode.

    Args:
        cfg: the grid.
        out_dir: results folder: ``results.csv`` and ``episodes/*.mcap``.

    Returns:
        One row per episode: planner, robot, scenario, arrangement, task_order, confidence,
        noise, dropout, speed, seed, then the episode's metrics.

    Raises:
        ConfigError: when an I-Planner variant has no predictor checkpoint.
    """
    from iplanner_torch.robot.model import RobotModel

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    assert isinstance(cfg.robot, RobotCfg)  # a name became one in __post_init__
    robot = RobotModel.from_cfg(cfg.robot, device=cfg.device)
    predictors: dict[str, Any] = {}
    for kind in cfg.planners:
        variant = PLANNER_KINDS[kind]
        if variant is None or variant in predictors:
            continue
        if variant not in cfg.predictor_paths:
            raise ConfigError(f"planner {kind!r} needs predictor_paths[{variant!r}], none given")
        predictors[variant] = _load_predictor(cfg.predictor_paths[variant], cfg.device)
        check_predictor_rate(predictors[variant], cfg.episode.sim.tracker_fps)  # before episodes
    base = cfg.episode
    speeds = cfg.speeds or [base.sim.human.speed]
    noises = cfg.noises or [base.sim.tracker_noise]
    rows: list[dict[str, Any]] = []
    for scenario in cfg.scenarios:
        for speed in speeds:
            for noise in noises:
                sim = replace(
                    base.sim, tracker_noise=noise, human=replace(base.sim.human, speed=speed)
                )
                ep_cfg = replace(base, scenario=scenario, sim=sim)
                for kind in cfg.planners:
                    variant = PLANNER_KINDS[kind]
                    for seed in cfg.seeds:
                        stem = f"{scenario.name}_{speed}_n{noise:g}_{kind}_s{seed}"
                        res = run_episode(
                            ep_cfg,
                            robot=robot,
                            predictor=predictors.get(variant) if variant else None,
                            planner_kind=kind,  # type: ignore[arg-type]
                            writer_path=(out_dir / "episodes" / f"{stem}.mcap")
                            if cfg.write_mcap
                            else None,
                            seed=seed,
                        )
                        rows.append(
                            {
                                "planner": kind,
                                "robot": cfg.robot.name,
                                "scenario": scenario.name,
                                "arrangement": scenario.arrangement,
                                "task_order": scenario.task_order,
                                "confidence": scenario.confidence,
                                "noise": noise,
                                "dropout": sim.tracker_dropout,
                                "speed": speed,
                                "seed": seed,
                                **res.metrics,
                            }
                        )
                        pd.DataFrame(rows).to_csv(out_dir / "results.csv", index=False)
    return pd.DataFrame(rows)
