"""Sweeps of closed-loop episodes (paper sec. 7, tables performance / performance_simulation
and fig. speed_response): planners x scenarios x human speeds x tracker noises x seeds.
"""

from __future__ import annotations

import contextlib
import glob
import importlib
import io
import multiprocessing
import os
import signal
import warnings
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError, DataWarning
from iplanner_torch.eval.episode import (
    CHECKPOINT_VARIANTS,
    PLANNER_KINDS,
    EpisodeCfg,
    check_predictor_joints,
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


#: the start methods of the standard library (a process may have set another's)
_STANDARD_METHODS = ("spawn", "fork", "forkserver")


def episode_pool(jobs: int) -> ProcessPoolExecutor:
    """``jobs`` worker processes for the episodes of :func:`run_experiment` (its ``executor``).

    The workers are started afresh (``spawn``: a forked torch can hang in its thread pool) and
    take this process's warning filters as they are when the pool is made, so that a warning
    this process silences stays silent there. Each worker loads the robot model and the
    predictors once and keeps them for the episodes it runs. Shut the pool down when done
    (``with episode_pool(2) as pool: ...``).

    Raises:
        ConfigError: when ``jobs`` is not an integer >= 1.
    """
    checks.integer("jobs", jobs, minimum=1)
    if multiprocessing.get_start_method(allow_none=True) not in (None, *_STANDARD_METHODS):
        # a worker of another pool (joblib's loky, in a sweep's parallel job): a fresh Python
        # started from here would look for that pool's own start method, and fail
        multiprocessing.set_start_method("spawn", force=True)
    return ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(_portable_filters(),),
    )


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """End ``pool`` soon: the waiting episodes are cancelled and the running ones interrupted
    (each worker gets SIGINT; its log, cut short, reads up to its last chunk, and
    ``run.resume`` runs that episode again), rather than waited for as ``pool.shutdown`` would.
    A worker still running after 10 s is terminated."""
    # (the pool has no public way to reach its processes before Python 3.14; they are taken
    # before the shutdown, whose manager thread lets go of them)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        if process.is_alive() and process.pid is not None:
            with contextlib.suppress(OSError):
                os.kill(process.pid, signal.SIGINT)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.join(timeout=10.0)
        if process.is_alive():
            process.terminate()
            process.join(timeout=5.0)
    pool.shutdown(wait=True)


#: set in a worker by its first interrupt: the episodes queued after it do not start
_INTERRUPTED = False
#: whether the worker is running an episode (:func:`_episode_in_worker`)
_RUNNING = False


def _interrupt(signum: int, frame: Any) -> None:
    """A worker's SIGINT handler: the episode it runs stops with a KeyboardInterrupt, and
    each one after it does not start (:data:`_INTERRUPTED`). A worker waiting for work is
    left to wait: interrupted there, it would end holding its pool's queue."""
    global _INTERRUPTED
    _INTERRUPTED = True
    if _RUNNING:
        raise KeyboardInterrupt


def _portable_filters() -> list[tuple[str, str | None, str, str | None, int]]:
    """This process's warning filters with their categories by name (a worker imports them)."""
    out = []
    for action, message, category, module, lineno in warnings.filters:
        name = f"{category.__module__}:{category.__qualname__}"
        # (a pattern is compiled, or a plain string when added by hand)
        pattern = getattr(message, "pattern", message)
        out.append((action, pattern, name, getattr(module, "pattern", module), lineno))
    return out


def _init_worker(filters: list[tuple[str, str | None, str, str | None, int]]) -> None:
    """A worker's warning filters: the parent's (:func:`_portable_filters`), in its order; a
    filter whose category cannot be imported here is left out. An interrupt stops the
    worker's episode and those queued after it (:func:`_interrupt`)."""
    kept = []
    for action, message, name, module, lineno in filters:
        mod, _, qualname = name.partition(":")
        try:
            category: Any = importlib.import_module(mod)
            for part in qualname.split("."):
                category = getattr(category, part)
        except (ImportError, AttributeError):
            continue
        kept.append((action, message, category, module, lineno))
    warnings.resetwarnings()
    for action, message, category, module, lineno in reversed(kept):
        warnings.filterwarnings(action, message or "", category, module or "", lineno)
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # (ignored as the parent does)
        signal.signal(signal.SIGINT, _interrupt)


#: a worker's robot models and predictors, loaded once (:func:`_episode_in_worker`)
_WORKER_CACHE: dict[tuple[str, ...], Any] = {}


def _episode_in_worker(
    robot_cfg: RobotCfg,
    device: str,
    predictor_path: str | None,
    cfg: EpisodeCfg,
    kind: str,
    log: Path | None,
    seed: int,
) -> dict[str, Any]:
    """One episode in a worker of :func:`episode_pool`: its metrics."""
    from iplanner_torch.robot.model import RobotModel

    global _RUNNING
    if _INTERRUPTED:  # queued before the interrupt: not started
        raise KeyboardInterrupt

    key = ("robot", repr(robot_cfg), device)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = RobotModel.from_cfg(robot_cfg, device=device)
    predictor = None
    if predictor_path is not None:
        pkey = ("predictor", predictor_path, device)
        if pkey not in _WORKER_CACHE:
            _WORKER_CACHE[pkey] = _load_predictor(predictor_path, device)
        predictor = _WORKER_CACHE[pkey]
    _RUNNING = True
    try:
        res = run_episode(
            cfg,
            robot=_WORKER_CACHE[key],
            predictor=predictor,
            planner_kind=kind,  # type: ignore[arg-type]
            writer_path=log,
            seed=seed,
        )
    finally:
        _RUNNING = False
    return res.metrics


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


#: the cut results tables :func:`read_finished` has warned of (path, length)
_WARNED_CUT: set[tuple[str, int]] = set()


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

    Warns:
        DataWarning: when the file's last row has no line end (it was cut short while
            written): that row is left out, so its episode runs again.

    Raises:
        DataError: when the file cannot be read as a results table, lacks a column of
            :data:`EPISODE_KEY`, or names an episode twice.
    """
    path = Path(results_csv)
    if not path.exists():
        return {}
    try:
        text = path.read_text(encoding="utf-8-sig")
        if text and not text.endswith(("\n", "\r")):
            # every table this project writes ends its last row with a line end: a file
            # without one was cut short while written (a full disk, a killed report), and
            # even the last row's full count of cells may hold a cut number
            head, _, last = text.rstrip("\r\n").rpartition("\n")
            seen = (str(path.resolve()), len(text))  # a resume reads it twice: warn once
            if head and seen not in _WARNED_CUT:
                _WARNED_CUT.add(seen)
                warnings.warn(
                    f"{path}: the last row has no line end (the file was cut short while "
                    f"written): its episode is run again ({last[:80]!r})",
                    DataWarning,
                    stacklevel=2,
                )
            if head:
                text = head + "\n"
        df = pd.read_csv(io.StringIO(text), dtype={c: str for c in TEXT_COLUMNS})
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


def _collect(pending: dict[Future, tuple[ExperimentRun, str, tuple]]) -> None:
    """Record each episode run by an executor as it ends, in its run
    (:func:`finish_experiments`). After the first failure none of the waiting episodes
    starts; the running ones end and are recorded, then that failure is raised. An interrupt
    (or any error here) cancels the waiting episodes and is raised at once."""
    from concurrent.futures.process import BrokenProcessPool

    error: BaseException | None = None
    try:
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                run, stem, settings = pending.pop(future)
                if future.cancelled():
                    continue
                exc = future.exception()
                if exc is None:
                    run.record(stem, settings, future.result())
                    continue
                if error is None:
                    if isinstance(exc, BrokenProcessPool):
                        exc = RuntimeError(
                            f"episode {stem}: its worker process ended without a result "
                            f"(killed, say for lack of memory, or it failed to start: see "
                            f"its output above): {exc}"
                        )
                    error = exc
                for other in pending:
                    other.cancel()
    except BaseException:
        for other in pending:
            other.cancel()
        raise
    if error is not None:
        raise error


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


@dataclass(eq=False)
class ExperimentRun:
    """A grid begun by :func:`start_experiment`: its rows so far, and the episodes its
    executor still runs. :func:`finish_experiments` waits for them."""

    #: ``results.csv`` goes here
    out_dir: Path
    #: every episode of the grid, in its order (:func:`episode_stem`)
    stems: list[str]
    #: the finished (and kept) episodes' rows, by stem
    table: dict[str, dict[str, Any]]
    #: the executor's episodes not yet recorded: future -> (stem, settings)
    pending: dict[Future, tuple[str, tuple]]
    on_done: Callable[[int], None] | None = None

    def record(self, stem: str, settings: tuple, metrics: dict[str, Any]) -> None:
        """Add an episode's row and rewrite ``results.csv`` with every row so far."""
        self.table[stem] = {**dict(zip(ROW_SETTINGS, settings, strict=True)), **metrics}
        # the kept rows of later episodes too: none is lost if the run stops again
        _write_rows([self.table[s] for s in self.stems if s in self.table], self.results)
        if self.on_done is not None:
            self.on_done(1)

    @property
    def results(self) -> Path:
        return self.out_dir / "results.csv"

    def failed(self) -> bool:
        """Whether an episode of the executor's has already failed (without waiting)."""
        return any(
            f.done() and not f.cancelled() and f.exception() is not None for f in self.pending
        )


def run_experiment(
    cfg: ExperimentCfg,
    out_dir: Path,
    *,
    episodes_dir: Path | None = None,
    resume: bool = False,
    on_done: Callable[[int], None] | None = None,
    executor: Executor | None = None,
    predictors: Mapping[str, Any] | None = None,
) -> pd.DataFrame:
    """Run every episode of the grid and gather one metric row per episode:
    :func:`start_experiment`, then :func:`finish_experiments` on it alone (see there).

    Returns:
        One row per episode: planner, robot, scenario, arrangement, task_order, confidence,
        noise, dropout, speed, seed, then the episode's metrics.
    """
    run = start_experiment(
        cfg,
        out_dir,
        episodes_dir=episodes_dir,
        resume=resume,
        on_done=on_done,
        executor=executor,
        predictors=predictors,
    )
    return finish_experiments([run])[0]


def start_experiment(
    cfg: ExperimentCfg,
    out_dir: Path,
    *,
    episodes_dir: Path | None = None,
    resume: bool = False,
    on_done: Callable[[int], None] | None = None,
    executor: Executor | None = None,
    predictors: Mapping[str, Any] | None = None,
) -> ExperimentRun:
    """Begin every episode of the grid, to gather one metric row per episode: without an
    executor they run here, one after the other, before this returns; with one they are
    queued for its workers, and :func:`finish_experiments` waits for them (grids begun with
    one executor share its workers, so that none waits for another's last episode).

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
        executor: runs the episodes in other processes, as many at once as it has workers
            (:func:`episode_pool`); None: here, one after the other. Each episode is decided
            by its seed, so its row and log are the same either way but for the wall-clock
            timings (which then measure a machine shared by the workers). The rows are
            written after each episode as above, in the grid's order, by
            :func:`finish_experiments`, which also says what an episode's failure does.
        predictors: planner kind (``"iplanner_ni"``, ``"iplanner_no_ni"``) -> a predictor
            object to drive that planner instead of the checkpoint of ``predictor_paths``
            (any object with ``predict_positions``, the ``PredictorLike`` protocol of
            :mod:`~iplanner_torch.eval.episode`; its rows and logs keep the planner's name).
            They run in this process: not with an ``executor``.

    Returns:
        The grid's run, for :func:`finish_experiments`.

    Raises:
        ConfigError: when an I-Planner variant has neither a predictor checkpoint nor a
            predictor object, ``predictors`` names a planner of no learned predictor or not
            in the grid, or comes with an ``executor``; or as :func:`kept_episodes` when
            resuming.
        DataError: as :func:`kept_episodes` when resuming.
        (and, without an executor, what an episode raises)
    """
    from iplanner_torch.robot.model import RobotModel

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    episodes = Path(episodes_dir) if episodes_dir is not None else out_dir / "episodes"
    # the finished episodes kept (a row, and the log when logs are written), by stem
    table = kept_episodes(cfg, out_dir, episodes) if resume else {}
    assert isinstance(cfg.robot, RobotCfg)  # a name became one in __post_init__
    robot = RobotModel.from_cfg(cfg.robot, device=cfg.device)
    given = dict(predictors or {})
    learned = [k for k in cfg.planners if PLANNER_KINDS[k] in CHECKPOINT_VARIANTS]
    odd = [k for k in given if k not in learned]
    if odd:
        raise ConfigError(
            f"predictors: {odd} are not planners of this grid that use a learned predictor "
            f"(those are {learned})"
        )
    if given and executor is not None:
        raise ConfigError(
            "predictors: predictor objects run in this process; run without an executor "
            "(or give checkpoints in predictor_paths, which the workers load)"
        )
    loaded: dict[str, Any] = {}  # by variant
    for kind in cfg.planners:
        variant = PLANNER_KINDS[kind]
        if variant not in CHECKPOINT_VARIANTS or variant in loaded:
            continue  # (iplanner_cv's forecast is built by the episode)
        if kind in given:
            loaded[variant] = given[kind]
        elif variant not in cfg.predictor_paths:
            raise ConfigError(f"planner {kind!r} needs predictor_paths[{variant!r}], none given")
        else:
            loaded[variant] = _load_predictor(cfg.predictor_paths[variant], cfg.device)
        check_predictor_rate(loaded[variant], cfg.episode.sim.tracker_fps)  # before episodes
        check_predictor_joints(loaded[variant])
    base = cfg.episode
    grid = grid_episodes(cfg)
    stems = [e[0] for e in grid]
    if on_done is not None and table:
        on_done(len(table))
    run = ExperimentRun(out_dir=out_dir, stems=stems, table=table, pending={}, on_done=on_done)
    for stem, scenario, speed, noise, kind, seed in grid:
        if stem in table:
            continue
        log = episodes / f"{stem}.mcap"
        if resume and log.exists():  # begun, not finished: kept aside
            set_aside(log, episodes.parent / INTERRUPTED_DIR)
        sim = replace(base.sim, tracker_noise=noise, human=replace(base.sim.human, speed=speed))
        variant = PLANNER_KINDS[kind]
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
        episode = replace(base, scenario=scenario, sim=sim)
        if executor is not None:  # (no per-episode progress bars from the workers)
            future = executor.submit(
                _episode_in_worker,
                cfg.robot,
                cfg.device,
                cfg.predictor_paths[variant] if variant in loaded else None,
                replace(episode, progress_bar=False),
                kind,
                log if cfg.write_mcap else None,
                seed,
            )
            run.pending[future] = (stem, settings)
            continue
        res = run_episode(
            episode,
            robot=robot,
            predictor=loaded.get(variant) if variant else None,
            planner_kind=kind,  # type: ignore[arg-type]
            writer_path=log if cfg.write_mcap else None,
            seed=seed,
        )
        run.record(stem, settings, res.metrics)
    return run


def finish_experiments(runs: list[ExperimentRun]) -> list[pd.DataFrame]:
    """Wait for the episodes that the runs' executor still runs, record each as it ends, and
    write each run's ``results.csv`` whole.

    ``results.csv`` is rewritten after each episode, in the grid's order, so that a run that
    stops keeps the rows of the episodes it finished. When an episode fails, no further
    episode starts; the ones running finish and keep their rows, then the first error is
    raised. An interrupt cancels the episodes not yet started and is raised at once.

    Returns:
        Per run, one row per episode: planner, robot, scenario, arrangement, task_order,
        confidence, noise, dropout, speed, seed, then the episode's metrics.

    Raises:
        RuntimeError: when a worker ended without a result (killed, or it failed to start).
        (and what an episode raised)
    """
    _collect(
        {future: (run, *item) for run in runs for future, item in run.pending.items()},
    )
    frames = []
    for run in runs:
        run.pending.clear()
        rows = [run.table[s] for s in run.stems]
        _write_rows(rows, run.results)
        frames.append(pd.DataFrame(rows))
    return frames
