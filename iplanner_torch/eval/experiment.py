"""Sweeps of closed-loop episodes (paper sec. 7, tables performance / performance_simulation
and fig. speed_response): planners x scenarios x human speeds x tracker noises x seeds.
"""

from __future__ import annotations

import glob
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError
from iplanner_torch.eval.episode import (
    CHECKPOINT_VARIANTS,
    PLANNER_KINDS,
    EpisodeCfg,
    check_predictor_rate,
    run_episode,
)
from iplanner_torch.eval.report import INTERRUPTED_DIR
from iplanner_torch.files import whole_file
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
    # planner kinds: "itomp", "iplanner_no_ni", "iplanner_ni", "iplanner_cv", "oracle", "blind"
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


#: the columns of ``results.csv`` that name an episode of the grid (with the log's stem)
EPISODE_KEY = ("scenario", "speed", "noise", "planner", "seed")
#: columns of ``results.csv`` read back as text (a task order "0" is not the number 0)
TEXT_COLUMNS = ("planner", "robot", "scenario", "arrangement", "task_order", "speed")
#: the columns of a row of :func:`run_experiment` before the episode's metrics
ROW_SETTINGS = (
    "planner",
    "robot",
    "scenario",
    "arrangement",
    "task_order",
    "confidence",
    "noise",
    "dropout",
    "speed",
    "seed",
)
_EVAL = "eval/"


def episode_stem(scenario: str, speed: str, noise: float, planner: str, seed: int) -> str:
    """The name of an episode of a grid: its log is ``<stem>.mcap``."""
    return f"{scenario}_{speed}_n{noise:g}_{planner}_s{seed}"


def read_finished(results_csv: Path) -> dict[str, dict[str, Any]]:
    """The episodes an earlier run of a grid finished: the rows of its ``results.csv`` by
    :func:`episode_stem` (a row is written when its episode has ended).

    Args:
        results_csv: the earlier run's ``results.csv``; a missing file: none finished.

    Returns:
        stem -> the row as :func:`run_experiment` writes it (text columns as text, empty
        cells NaN). A table that a report rewrote, with the ``eval/`` metrics under their
        short names (:func:`~iplanner_torch.eval.report.gather_results`), is read back with
        the prefix.

    Raises:
        DataError: when the file cannot be read as a results table, lacks a column of
            :data:`EPISODE_KEY`, or names an episode twice.
    """
    path = Path(results_csv)
    if not path.exists():
        return {}
    try:
        df = pd.read_csv(path, dtype={c: str for c in TEXT_COLUMNS})
    except pd.errors.EmptyDataError:
        return {}
    except (pd.errors.ParserError, UnicodeDecodeError, OSError) as exc:
        raise DataError(f"{path}: not a results table of an earlier run ({exc})") from exc
    missing = [c for c in EPISODE_KEY if c not in df.columns]
    if missing:
        raise DataError(f"{path}: no column {', '.join(missing)}: not an experiment's results")
    df = df.rename(
        columns={c: _EVAL + c for c in df.columns if "/" not in c and c not in ROW_SETTINGS}
    )
    out: dict[str, dict[str, Any]] = {}
    for row in df.to_dict("records"):
        try:
            stem = episode_stem(
                str(row["scenario"]),
                str(row["speed"]),
                float(row["noise"]),
                str(row["planner"]),
                int(row["seed"]),
            )
        except (TypeError, ValueError) as exc:
            raise DataError(f"{path}: a row without its episode's {EPISODE_KEY}: {row}") from exc
        if stem in out:
            raise DataError(f"{path}: episode {stem} has two rows")
        out[stem] = row
    return out


def set_aside(log: Path, folder: Path) -> Path:
    """Move the log of an episode that did not finish into ``folder``, with the files beside
    it of the same name (its timeline plot, ``<stem>.png``), so that running the episode again
    loses nothing. A number is added to the names when ``folder`` has a log of that name.

    Returns:
        The log's new path.
    """
    folder.mkdir(parents=True, exist_ok=True)
    stem = log.stem
    n = 0
    while (folder / f"{stem}{f'.{n}' if n else ''}{log.suffix}").exists():
        n += 1
    new_stem = f"{stem}.{n}" if n else stem
    for sibling in sorted(log.parent.glob(f"{glob.escape(stem)}.*")):
        if sibling.is_file() and sibling.name[len(stem) :].count(".") == 1:
            sibling.replace(folder / f"{new_stem}{sibling.suffix}")
    return folder / f"{new_stem}{log.suffix}"


def _write_rows(rows: list[dict[str, Any]], path: Path) -> None:
    """``rows`` to the CSV ``path`` whole or not at all (a temporary file replaces it), so that
    a run killed while writing keeps the rows of its finished episodes."""
    with whole_file(path) as tmp:
        pd.DataFrame(rows).to_csv(tmp, index=False)


def grid_episodes(cfg: ExperimentCfg) -> list[tuple[str, ScenarioCfg, str, float, str, int]]:
    """The episodes of the grid in the order they run: (stem, scenario, speed, noise,
    planner, seed), the stem as :func:`episode_stem`."""
    speeds = cfg.speeds or [cfg.episode.sim.human.speed]
    noises = cfg.noises or [cfg.episode.sim.tracker_noise]
    return [
        (episode_stem(scenario.name, speed, noise, kind, seed), scenario, speed, noise, kind, seed)
        for scenario in cfg.scenarios
        for speed in speeds
        for noise in noises
        for kind in cfg.planners
        for seed in cfg.seeds
    ]


def kept_episodes(
    cfg: ExperimentCfg, out_dir: Path, episodes_dir: Path | None = None
) -> dict[str, dict[str, Any]]:
    """The episodes of the grid that an earlier run in ``out_dir`` finished and that a
    resumed run keeps: each with a row in ``out_dir/results.csv`` and, when the grid writes
    logs, its log in ``episodes_dir`` (None: ``out_dir/episodes``).

    Returns:
        stem -> the earlier row.

    Raises:
        ConfigError: when ``results.csv`` holds episodes that are not in this grid.
        DataError: as :func:`read_finished`.
    """
    out_dir = Path(out_dir)
    episodes = Path(episodes_dir) if episodes_dir is not None else out_dir / "episodes"
    finished = read_finished(out_dir / "results.csv")
    other = sorted(set(finished) - {e[0] for e in grid_episodes(cfg)})
    if other:
        raise ConfigError(
            f"{out_dir / 'results.csv'} holds episodes that are not in this grid "
            f"({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}): not the same "
            "experiment, so there is nothing to resume"
        )
    return {
        stem: row
        for stem, row in finished.items()
        if not cfg.write_mcap or (episodes / f"{stem}.mcap").exists()
    }


def run_experiment(
    cfg: ExperimentCfg,
    out_dir: Path,
    *,
    episodes_dir: Path | None = None,
    resume: bool = False,
    on_done: Callable[[int], None] | None = None,
) -> pd.DataFrame:
    """Run every episode of the grid and gather one metric row per episode.

    ``results.csv`` is rewritten after each episode, so that a run that stops keeps the rows
    of the episodes it finished. With ``resume`` the run continues such a run in the same
    folder: an episode with a row in its ``results.csv`` (and its log, when logs are written)
    keeps that row and is not run again, the others run. The log of an episode that began
    but has no row (it was stopped) is moved first to ``interrupted/`` beside the logs'
    folder (:data:`~iplanner_torch.eval.report.INTERRUPTED_DIR`, which folder reads leave
    out). The caller makes sure that the earlier run had the same settings (the CLI compares
    them).

    Args:
        cfg: the grid.
        out_dir: results folder: ``results.csv`` and, unless ``episodes_dir`` is given,
            ``episodes/*.mcap``.
        episodes_dir: where the MCAP logs go; None: ``out_dir/episodes``.
        resume: keep the episodes an earlier run in ``out_dir`` finished.
        on_done: called with the number of episodes that have just been done: once with the
            kept ones (when there are), then with 1 after each episode run (a progress bar's
            ``update``).

    Returns:
        One row per episode: planner, robot, scenario, arrangement, task_order, confidence,
        noise, dropout, speed, seed, then the episode's metrics.

    Raises:
        ConfigError: when an I-Planner variant has no predictor checkpoint, or as
            :func:`kept_episodes` when resuming.
        DataError: as :func:`kept_episodes` when resuming.
    """
    from iplanner_torch.robot.model import RobotModel

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    episodes = Path(episodes_dir) if episodes_dir is not None else out_dir / "episodes"
    # the finished episodes kept (a row, and the log when logs are written), by stem
    table = kept_episodes(cfg, out_dir, episodes) if resume else {}
    assert isinstance(cfg.robot, RobotCfg)  # a name became one in __post_init__
    robot = RobotModel.from_cfg(cfg.robot, device=cfg.device)
    predictors: dict[str, Any] = {}
    for kind in cfg.planners:
        variant = PLANNER_KINDS[kind]
        if variant not in CHECKPOINT_VARIANTS or variant in predictors:
            continue  # (iplanner_cv's forecast is built by the episode)
        if variant not in cfg.predictor_paths:
            raise ConfigError(f"planner {kind!r} needs predictor_paths[{variant!r}], none given")
        predictors[variant] = _load_predictor(cfg.predictor_paths[variant], cfg.device)
        check_predictor_rate(predictors[variant], cfg.episode.sim.tracker_fps)  # before episodes
    base = cfg.episode
    grid = grid_episodes(cfg)
    stems = [e[0] for e in grid]
    if on_done is not None and table:
        on_done(len(table))
    for stem, scenario, speed, noise, kind, seed in grid:
        if stem in table:
            continue
        log = episodes / f"{stem}.mcap"
        if resume and log.exists():  # begun, not finished: kept aside
            set_aside(log, episodes.parent / INTERRUPTED_DIR)
        sim = replace(base.sim, tracker_noise=noise, human=replace(base.sim.human, speed=speed))
        variant = PLANNER_KINDS[kind]
        res = run_episode(
            replace(base, scenario=scenario, sim=sim),
            robot=robot,
            predictor=predictors.get(variant) if variant else None,
            planner_kind=kind,  # type: ignore[arg-type]
            writer_path=log if cfg.write_mcap else None,
            seed=seed,
        )
        settings = (
            kind,
            cfg.robot.name,
            scenario.name,
            scenario.arrangement,
            scenario.task_order,
            scenario.confidence,
            noise,
            sim.tracker_dropout,
            speed,
            seed,
        )  # in the order of ROW_SETTINGS, whose names read_finished knows
        table[stem] = {**dict(zip(ROW_SETTINGS, settings, strict=True)), **res.metrics}
        # the kept rows of later episodes too: none is lost if the run stops again
        _write_rows([table[s] for s in stems if s in table], out_dir / "results.csv")
        if on_done is not None:
            on_done(1)
    rows = [table[s] for s in stems]
    _write_rows(rows, out_dir / "results.csv")
    return pd.DataFrame(rows)
