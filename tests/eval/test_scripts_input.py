"""The scripts under scripts/ refuse bad input in one line (``error: ...``, exit code 2) before
doing any work, and leave existing records and truncated logs alone."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from iplanner_torch.errors import DataError
from iplanner_torch.recording import EpisodeWriter

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def _load(name: str):
    sys.path.insert(0, str(SCRIPTS))
    try:
        spec = importlib.util.spec_from_file_location(f"script_{name}", SCRIPTS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # its dataclasses look their module up
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        return mod
    finally:
        sys.path.remove(str(SCRIPTS))


@pytest.fixture
def run_script(monkeypatch, capsys):
    """``run_script(name, *args) -> (exit code, stdout, stderr)`` of ``scripts/<name>.py``'s
    ``main`` run in this process with ``args`` as its command line."""
    monkeypatch.setattr(sys, "path", list(sys.path))  # bench.py adds scripts/ to it

    def run(name: str, *args: object, module=None) -> tuple[int, str, str]:
        mod = module or _load(name)
        monkeypatch.setattr(sys, "argv", [f"{name}.py", *map(str, args)])
        try:
            code = mod.main() or 0
        except SystemExit as exc:
            code = exc.code
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


def _episodes(n: int = 3, **settings: object) -> pd.DataFrame:
    """Episode rows of one scenario and planner, as a results.csv holds them."""
    return pd.DataFrame(
        {
            "planner": "itomp",
            "scenario": "s1",
            "arrangement": "1x4",
            "task_order": "(0,1)->(2,3)",
            "confidence": 0.95,
            **settings,
            "seed": list(range(n)),
            "sim/contacts": [0] * n,
            "completed": [1.0] * n,
            "eval/min_distance": [0.05] * n,
            "eval/smoothness": [10.0] * n,
        }
    )


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# --- the report scripts: results.csv columns and values ----------------------------------------


@pytest.mark.parametrize(
    ("script", "drop", "message"),
    [
        ("safety_seeds_report", "seed", "no 'seed' column"),
        ("safety_seeds_report", "planner", "no 'planner' column"),
        ("table_simulation_report", "confidence", "no 'confidence' column"),
        ("table_simulation_report", "arrangement", "no 'arrangement' column"),
        ("table_simulation_report", "scenario", "no 'scenario' column"),
    ],
)
def test_reports_name_a_missing_key_column(tmp_path, run_script, script, drop, message) -> None:
    _episodes().drop(columns=[drop]).to_csv(tmp_path / "results.csv", index=False)
    code, _, err = run_script(script, tmp_path, "--out", tmp_path / "record")
    assert code == 2 and message in _one_error_line(err)
    assert not (tmp_path / "record").exists()


@pytest.mark.parametrize("script", ["safety_seeds_report", "table_simulation_report"])
def test_reports_name_a_confidence_that_is_not_a_number(tmp_path, run_script, script) -> None:
    df = _episodes()
    df["confidence"] = df["confidence"].astype(object)
    df.loc[1, "confidence"] = "high"
    df.to_csv(tmp_path / "results.csv", index=False)
    code, _, err = run_script(script, tmp_path, "--out", tmp_path / "record")
    line = _one_error_line(err)
    assert code == 2 and "'confidence' value(s) are not numbers" in line and "'high'" in line
    assert "rows [3]" in line


@pytest.mark.parametrize("script", ["safety_seeds_report", "table_simulation_report"])
@pytest.mark.parametrize("damage", ["cut", "short"])
def test_reports_refuse_rows_the_reader_would_drop_or_fill(
    tmp_path, run_script, script, damage
) -> None:
    """gather_results leaves out a last row cut short and fills a short row's missing cells,
    with a warning; a record must not lose or invent an episode, so the scripts refuse."""
    text = _episodes().to_csv(index=False)
    if damage == "cut":
        text = text[: text.rindex(",0.05")]  # the writer stopped inside the last row
        said = "the last row (file row 4) is cut short"
    else:
        lines = text.splitlines(keepends=True)
        lines[2] = lines[2][: lines[2].rindex(",0.05")] + "\n"
        text = "".join(lines)
        said = "1 row(s) have fewer cells than the header's"
    (tmp_path / "results.csv").write_text(text)
    code, _, err = run_script(script, tmp_path, "--out", tmp_path / "record")
    line = _one_error_line(err)
    assert code == 2 and said in line and "a record needs every row whole" in line
    assert not (tmp_path / "record").exists()


def test_table_report_says_a_header_only_file_has_no_rows(tmp_path, run_script) -> None:
    _episodes().iloc[:0].to_csv(tmp_path / "results.csv", index=False)
    code, _, err = run_script("table_simulation_report", tmp_path, "--out", tmp_path / "rec")
    assert code == 2 and "no episode rows" in _one_error_line(err)


def test_a_contacts_cell_that_is_not_a_number_is_not_counted_as_a_contact(
    tmp_path, run_script
) -> None:
    df = _episodes()
    df["sim/contacts"] = df["sim/contacts"].astype(object)
    df.loc[0, "sim/contacts"] = "x"
    df.to_csv(tmp_path / "results.csv", index=False)
    with pytest.warns(UserWarning, match="not numbers"):
        code, _, err = run_script("safety_seeds_report", tmp_path, "--out", tmp_path / "rec")
    assert code == 2 and "lack 'sim/contacts'" in _one_error_line(err)
    assert not (tmp_path / "rec").exists()


def test_reports_keep_an_existing_results_csv_without_force(tmp_path, run_script) -> None:
    run, out = tmp_path / "run", tmp_path / "record"
    run.mkdir()
    out.mkdir()
    _episodes().to_csv(run / "results.csv", index=False)
    (out / "results.csv").write_text("hand-made")
    for script in ("safety_seeds_report", "table_simulation_report"):
        code, _, err = run_script(script, run, "--out", out)
        assert code == 2 and "pass --force" in _one_error_line(err) and "results.csv" in err
        assert (out / "results.csv").read_text() == "hand-made"
        assert not (out / "README.md").exists()
    code, _, err = run_script("safety_seeds_report", run, "--out", out, "--force")
    assert code == 0, err
    assert len(pd.read_csv(out / "results.csv")) == 3


def test_out_must_be_a_folder(tmp_path, run_script) -> None:
    _episodes().to_csv(tmp_path / "results.csv", index=False)
    out = tmp_path / "record.txt"
    out.write_text("keep")
    code, _, err = run_script("safety_seeds_report", tmp_path, "--out", out)
    assert code == 2 and "--out must be a folder" in _one_error_line(err)
    code, _, err = run_script("plot_robot_spheres", "--out", out)
    assert code == 2 and "--out must be a folder" in _one_error_line(err)
    assert out.read_text() == "keep"


def test_plot_dataset_refuses_an_out_it_cannot_make_in_one_line(tmp_path, run_script) -> None:
    """--out through a regular file (or naming one) is an error line with exit code 2, not a
    traceback, and nothing is plotted (main_guard)."""
    afile = tmp_path / "afile"
    afile.write_text("keep")
    code, out, err = run_script("plot_dataset", "--no-measure", "--out", afile / "sub")
    line = _one_error_line(err)
    assert code == 2 and line.startswith("error: NotADirectoryError: ") and "afile" in line
    assert "wrote" not in out and afile.read_text() == "keep"
    code, _, err = run_script("plot_dataset", "--no-measure", "--out", afile)
    assert code == 2 and "--out must be a folder" in _one_error_line(err)


# --- bench.py: its arguments are checked before any benchmark runs ------------------------------


@pytest.fixture
def bench(monkeypatch):
    mod = _load("bench")

    def no_run(area: str):
        raise AssertionError(f"benchmark {area} started")

    monkeypatch.setattr(mod, "_load", no_run)
    return mod


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--only", "nosuch"], "unknown area(s) nosuch"),
        (["--only", "DTW"], "unknown area(s) DTW"),
        (["--only", ","], "no area"),
        (["--only", "dtw,x"], "unknown area(s) x"),
        (["--threads", "0"], "--threads must be >= 1"),
        (["--threads", "-1"], "--threads must be >= 1"),
    ],
)
def test_bench_refuses_bad_arguments(tmp_path, run_script, bench, args, message) -> None:
    figures = tmp_path / "cpu.json"
    figures.write_text('{"kept": 1}\n')
    code, _, err = run_script("bench", *args, "--json", figures, module=bench)
    assert code == 2 and message in err
    if "--only" in args:
        assert "dtw, prediction, robot, collision, planning, sim" in err
    assert figures.read_text() == '{"kept": 1}\n'


def test_bench_refuses_a_json_folder_and_writes_no_json_without_figures(
    tmp_path, run_script, bench, monkeypatch
) -> None:
    code, _, err = run_script("bench", "--only", "dtw", "--json", tmp_path, module=bench)
    assert code == 2 and "is a folder" in err

    class Failing:
        @staticmethod
        def run(quick: bool) -> dict:
            raise RuntimeError("no figures")

    monkeypatch.setattr(bench, "_load", lambda area: Failing)
    figures = tmp_path / "cpu.json"
    figures.write_text('{"kept": 1}\n')
    args = ("--only", "dtw", "--json", figures, "--force")  # kept even with --force
    code, _, err = run_script("bench", *args, module=bench)
    assert code == 2 and "no figure was produced" in err
    assert figures.read_text() == '{"kept": 1}\n'
    assert not figures.with_suffix(".meta.json").exists()


# --- bench_gpu.py: arguments, no CUDA, and a run on the CPU against itself ---------------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--only", "dtw"], "unknown area(s) dtw; the areas are fk, replan, prediction, sim"),
        (["--only", ","], "no area"),
        (["--cpu-threads", "0"], "--cpu-threads must be >= 1"),
        (["--device", "tpu"], "--device tpu: unknown device 'tpu'"),
        # it printed "[sim] ... skipped", an empty table, and exited 0
        (["--only", "sim", "--device", "cpu"], "the sim area needs the prediction area"),
    ],
)
def test_bench_gpu_refuses_bad_arguments(tmp_path, run_script, args, message) -> None:
    figures = tmp_path / "gpu.json"
    figures.write_text('{"kept": 1}\n')
    code, _, err = run_script("bench_gpu", *args, "--json", figures, "--force")
    assert code == 2 and message in err
    assert figures.read_text() == '{"kept": 1}\n'
    code, _, err = run_script("bench_gpu", "--json", figures)  # a record is kept
    assert code == 2 and "exists (stored results); pass --force" in err
    figures.unlink()  # and so is its .meta.json alone
    figures.with_suffix(".meta.json").write_text("{}\n")
    code, _, err = run_script("bench_gpu", "--json", figures)
    assert code == 2 and "gpu.meta.json exists (stored results); pass --force" in err


def test_bench_gpu_without_cuda_says_so(run_script, monkeypatch) -> None:
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code, _, err = run_script("bench_gpu")
    assert code == 2
    assert "--device cuda: device 'cuda' requested but CUDA is not available" in err


def test_bench_gpu_on_the_cpu_compares_equal_numbers(tmp_path, run_script) -> None:
    """``--device cpu``: the spheres are computed twice on the CPU, the same numbers, and the
    figures are written with the reference beside each."""
    figures = tmp_path / "gpu.json"
    code, out, _ = run_script(
        "bench_gpu", "--device", "cpu", "--quick", "--only", "fk", "--json", figures
    )
    assert code == 0, out
    got = json.loads(figures.read_text())
    names = {f"gpu.fk.{r}.spheres{k}_{b}x20_ms" for r in ("kuka_iiwa14", "fetch")
             for k in ("", "_backward") for b in (1024,)}  # fmt: skip
    assert set(got) == names
    for fig in got.values():
        assert fig["max_abs_diff_m"] == 0.0
        assert fig["ratio"] == pytest.approx(fig["reference"] / fig["value"])
    meta = json.loads(figures.with_suffix(".meta.json").read_text())
    assert meta["device"] == "cpu" and meta["failed_areas"] == []


# --- count_cycle_ops.py ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--trajectories", "0"], "--trajectories must be >= 1"),
        (["--top", "-1"], "--top must be >= 0"),
        (["--robot", "ur5"], "error: --robot ur5: unknown robot 'ur5'"),  # was "name: ..."
    ],
)
def test_count_cycle_ops_refuses_bad_arguments(run_script, args, message) -> None:
    code, _, err = run_script("count_cycle_ops", *args)
    assert code == 2 and message in err


def test_count_cycle_ops_counts_the_same_operations_at_any_batch(run_script) -> None:
    """The operation count of a warm cycle does not grow with the batch (within 1 %: the
    launches a CUDA cycle pays for), and the optimiser is among the lines listed first."""
    totals = {}
    for b in (2, 16):
        code, out, _ = run_script("count_cycle_ops", "--trajectories", b, "--top", "3")
        assert code == 0
        head, *lines = out.strip().splitlines()
        assert head.startswith(f"one warm cycle, kuka_iiwa14, B = {b}: ")
        totals[b] = int(head.split(": ", 1)[1].split(" operations")[0])
        assert len(lines) == 3 and all(int(line.split()[0]) > 0 for line in lines)
        assert any("planning/optimizer.py" in line for line in lines)
    assert totals[2] > 1000 and abs(totals[16] - totals[2]) <= 0.01 * totals[2]


# --- smoothness_breakdown.py: truncated logs, one log, bad numbers ------------------------------


def _log(path: Path, seed: int) -> None:
    """An episode log with one plan and 250 robot states in many small chunks."""
    t = np.arange(0.0, 10.0, 0.04)
    q = np.stack([np.sin(t), np.cos(t)], axis=1)
    meta = {"scenario": "s1", "planner": "itomp", "seed": seed}
    with EpisodeWriter(path, metadata=meta, chunk_size=2048) as log:
        times = np.linspace(0.0, 3.0, 8)
        log.plan(0.0, times, np.stack([times, times], axis=1), True, 0.0, 1.0)
        for i in range(len(t)):
            log.robot_state(float(t[i]), q[i], np.zeros(2), ["a", "b"])


def _table_rows(stdout: str) -> list[list[str]]:
    return [[c.strip() for c in ln.split("|")[1:-1]] for ln in stdout.splitlines() if "| s1" in ln]


def test_breakdown_leaves_truncated_logs_out_and_names_them(tmp_path, run_script) -> None:
    _log(tmp_path / "full.mcap", 0)
    _log(tmp_path / "cut.mcap", 1)
    data = (tmp_path / "cut.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: int(0.3 * len(data))])  # some chunks remain
    code, out, err = run_script("smoothness_breakdown", tmp_path)
    assert code == 0, err
    assert "skipped" in err and "cut.mcap: truncated or damaged" in err
    assert [r[2] for r in _table_rows(out)] == ["1"]  # one episode: the full log
    code, out, err = run_script("smoothness_breakdown", tmp_path, "--include-incomplete")
    assert code == 0 and [r[2] for r in _table_rows(out)] == ["2"]
    assert "warning: " in err and "truncated" in err
    # a whole log of an episode stopped by Ctrl-C (it was counted as a finished episode)
    with (
        pytest.raises(KeyboardInterrupt),
        EpisodeWriter(
            tmp_path / "stopped.mcap", metadata={"scenario": "s1", "planner": "itomp", "seed": 2}
        ) as log,
    ):
        log.robot_state(0.0, [0.0, 0.0], [0.0, 0.0], ["a", "b"])
        raise KeyboardInterrupt
    code, out, err = run_script("smoothness_breakdown", tmp_path)
    assert code == 0 and [r[2] for r in _table_rows(out)] == ["1"]
    assert "stopped.mcap: the episode was interrupted before its end" in err


def test_breakdown_reads_one_log_and_names_a_missing_path(tmp_path, run_script) -> None:
    _log(tmp_path / "full.mcap", 0)
    code, out, err = run_script("smoothness_breakdown", tmp_path / "full.mcap")
    assert code == 0, err
    assert [r[2] for r in _table_rows(out)] == ["1"]
    code, _, err = run_script("smoothness_breakdown", tmp_path / "nope")
    assert code == 2 and "not found" in _one_error_line(err)


def test_breakdown_names_each_log_it_cannot_split_once(tmp_path, run_script) -> None:
    for name, states in (("empty.mcap", 0), ("short.mcap", 1)):
        with EpisodeWriter(tmp_path / name, metadata={"scenario": "s1"}) as log:
            for i in range(states):
                log.robot_state(float(i), np.zeros(2), np.zeros(2), ["a", "b"])
    code, _, err = run_script("smoothness_breakdown", tmp_path)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.startswith("skipped ")]
    assert lines == [
        f"skipped {tmp_path / 'empty.mcap'}: no messages on /robot/joint_state",
        f"skipped {tmp_path / 'short.mcap'}: expected at least 3 robot states in the log, got 1",
    ]


@pytest.mark.parametrize("settle", ["-1", "nan", "inf"])
def test_breakdown_refuses_a_bad_settle_time(tmp_path, run_script, settle) -> None:
    code, _, err = run_script("smoothness_breakdown", tmp_path, "--settle", settle)
    assert code == 2 and "--settle must be" in _one_error_line(err)


@pytest.mark.parametrize("near", ["0", "-0.1", "1.5", "nan"])
def test_breakdown_refuses_a_bad_near_share(tmp_path, run_script, near) -> None:
    code, _, err = run_script("smoothness_breakdown", tmp_path, "--near", near)
    assert code == 2 and "--near must be a share of the confidence limit" in _one_error_line(err)


# --- human_sphere_gaps.py, render_episode.py and the shared error reporting ---------------------


@pytest.mark.parametrize("frames", ["0", "-5"])
def test_sphere_gaps_refuses_no_frames(tmp_path, run_script, frames) -> None:
    code, _, err = run_script("human_sphere_gaps", "--data", tmp_path, "--frames", frames)
    assert code == 2 and "--frames must be >= 1" in _one_error_line(err)


def test_sphere_gaps_hints_at_generating_only_a_missing_dataset(tmp_path, run_script) -> None:
    code, _, err = run_script("human_sphere_gaps", "--data", tmp_path / "nope")
    assert code == 2 and "not found (generate it with" in _one_error_line(err)
    code, _, err = run_script("human_sphere_gaps", "--data", tmp_path)  # a folder with no files
    line = _one_error_line(err)
    assert code == 2 and line.startswith("error: DataError: ") and "generate" not in line


def test_main_guard_reports_package_and_os_errors_in_one_line(capsys) -> None:
    report = _load("_report")

    @report.main_guard
    def broken(exc: Exception) -> None:
        raise exc

    for exc, line in (
        (DataError("bad file\n"), "error: DataError: bad file"),
        (FileNotFoundError(2, "No such file", "x.csv"), "error: FileNotFoundError: "),
    ):
        with pytest.raises(SystemExit) as info:
            broken(exc)
        assert info.value.code == 2
        assert capsys.readouterr().err.startswith(line)
    with pytest.raises(KeyError):  # other errors are bugs: their traceback stays
        broken(KeyError("x"))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--fps", "0", "--video", "v.gif"], "--fps must be"),
        (["--fps", "nan"], "--fps must be"),
        (["--video", "v.avi"], "ending in .gif or .mp4"),
        (["--out", "sheet.xyz"], "not an image type"),
        (["--width", "0", "--height", "0"], "--width must be >= 1"),
        (["--height", "-2"], "--height must be >= 1"),
        (["--frames", "0"], "--frames must be >= 1"),
    ],
)
def test_render_refuses_bad_settings_before_rendering(tmp_path, run_script, args, message):
    code, _, err = run_script("render_episode", "--mcap", tmp_path / "none.mcap", *args)
    assert code == 2 and message in _one_error_line(err)


def test_render_keeps_existing_files_without_force(tmp_path, run_script) -> None:
    """The episode's sheet goes to ``<stem>.frames.png``, not over its timeline plot
    ``<stem>.png``; an existing sheet or video is refused, before the log is read, unless
    --force is given."""
    log = tmp_path / "ep.mcap"
    log.write_bytes(b"")  # cut before anything was written: the render stops at reading it
    (tmp_path / "ep.png").write_bytes(b"timeline")
    with pytest.warns(UserWarning, match="truncated"):
        code, _, err = run_script("render_episode", "--mcap", log)
    assert code == 2 and "the log has no messages" in _one_error_line(err)
    assert (tmp_path / "ep.png").read_bytes() == b"timeline"
    for given, existing in (([], "ep.frames.png"), (["--video", tmp_path / "v.gif"], "v.gif")):
        (tmp_path / existing).write_bytes(b"earlier")
        code, _, err = run_script("render_episode", "--mcap", log, *given)
        line = _one_error_line(err)
        assert code == 2 and f"{tmp_path / existing} exist(s): pass --force" in line, line
        with pytest.warns(UserWarning, match="truncated"):
            code, _, err = run_script("render_episode", "--mcap", log, *given, "--force")
        assert code == 2 and "the log has no messages" in _one_error_line(err)
        assert (tmp_path / existing).read_bytes() == b"earlier"
        (tmp_path / existing).unlink()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--video", "v.gif"], "--video: for an episode (--mcap)"),
        (["--overlay", "--frames", "3"], "--overlay, --frames: for an episode (--mcap)"),
        (["--camera", "top"], "--camera: for an episode"),
    ],
)
def test_render_scene_refuses_the_episode_settings(tmp_path, run_script, args, message) -> None:
    """They were left unused without a word (no GIF written for --video)."""
    code, _, err = run_script("render_episode", "--scene", "--out", tmp_path / "s.png", *args)
    assert code == 2 and message in _one_error_line(err)
    assert not (tmp_path / "s.png").exists()


def test_render_refuses_a_folder_as_out(tmp_path, run_script) -> None:
    """It wrote <folder>.png beside the folder."""
    (tmp_path / "sheets").mkdir()
    code, _, err = run_script("render_episode", "--mcap", tmp_path / "x.mcap", "--out",
                              tmp_path / "sheets")  # fmt: skip
    assert code == 2 and "is a folder; give the image file to write" in _one_error_line(err)


def test_render_says_a_log_has_no_messages(tmp_path, run_script) -> None:
    (tmp_path / "empty.mcap").write_bytes(b"")  # cut before anything was written
    with pytest.warns(UserWarning, match="truncated"):
        code, _, err = run_script("render_episode", "--mcap", tmp_path / "empty.mcap")
    assert code == 2 and "the log has no messages (truncated" in _one_error_line(err)
    assert "use --robot" not in err
    with EpisodeWriter(tmp_path / "no_states.mcap", metadata={"robot": "kuka_iiwa14"}):
        pass  # no robot state: the render finds none
    code, _, err = run_script("render_episode", "--mcap", tmp_path / "no_states.mcap")
    line = _one_error_line(err)
    if "OpenGL" not in line:  # where a GL backend loads, the render itself refuses it
        assert code == 2 and line.startswith("error: DataError: ") and "no messages on" in line
    code, _, err = run_script("render_episode", "--mcap", tmp_path / "nope.mcap")
    assert code == 2 and _one_error_line(err).startswith("error: DataError: ")


def test_bench_refuses_to_replace_stored_results_without_force(
    tmp_path, run_script, bench, monkeypatch
) -> None:
    """An existing --json file (or its .meta.json) is refused in one line naming it and
    --force, before any benchmark runs (the ``bench`` fixture fails any that starts);
    --force replaces both."""
    figures = tmp_path / "cpu.json"
    meta = tmp_path / "cpu.meta.json"
    for existing in ((figures,), (meta,), (figures, meta)):
        for p in (figures, meta):
            p.unlink(missing_ok=True)
        for p in existing:
            p.write_text('{"kept": 1}\n')
        code, out, err = run_script("bench", "--only", "dtw", "--json", figures, module=bench)
        line = _one_error_line(err)
        assert code == 2 and "pass --force to replace" in line and "[dtw]" not in out
        assert all(str(p) in line for p in existing)
        assert all(p.read_text() == '{"kept": 1}\n' for p in existing)

    class One:
        @staticmethod
        def run(quick: bool) -> dict:
            return {"x.ms": {"value": 1.0, "unit": "ms"}}

    monkeypatch.setattr(bench, "_load", lambda area: One)
    code, _, err = run_script("bench", "--only", "dtw", "--json", figures, "--force", module=bench)
    assert code == 0, err
    assert json.loads(figures.read_text()) == {"x.ms": {"value": 1.0, "unit": "ms"}}
    assert "--force" in json.loads(meta.read_text())["command"]


def test_bench_json_written_with_figures(tmp_path, run_script, bench, monkeypatch) -> None:
    class One:
        @staticmethod
        def run(quick: bool) -> dict:
            return {"x.ms": {"value": 1.0, "unit": "ms"}}

    monkeypatch.setattr(bench, "_load", lambda area: One)
    figures = tmp_path / "cpu.json"
    code, _, err = run_script("bench", "--only", "dtw", "--quick", "--json", figures, module=bench)
    assert code == 0, err
    assert json.loads(figures.read_text()) == {"x.ms": {"value": 1.0, "unit": "ms"}}


def test_bench_prints_each_area_and_keeps_the_figures_of_an_interrupted_run(
    tmp_path, run_script, bench, monkeypatch
) -> None:
    """Each area's figures are printed when it ends, with what they were measured against;
    an interrupt in a later area prints those measured so far (they were lost: the table came
    only at the end), exits 130 and writes no JSON."""
    calls = []

    class Area:
        @staticmethod
        def run(quick: bool) -> dict:
            calls.append(quick)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return {
                "a.pairs_per_s": {"value": 10.0, "unit": "pairs/s", "reference_pairs_per_s": 4.0,
                                  "reference_name": "the plain loop", "ratio": 2.5},
                "a.goal_s": {"value": 3.0, "unit": "s", "goal": "< 600 s"},
                "a.vs": {"value": 2.0, "unit": "x", "reference": "numpy", "reference_s": 0.5},
                "a.bare": {"value": 1.0, "unit": "ms"},
            }  # fmt: skip

    monkeypatch.setattr(bench, "_load", lambda area: Area)
    target = tmp_path / "cpu.json"
    code, out, err = run_script("bench", "--only", "dtw,robot", "--json", target, module=bench)
    assert code == 130 and not target.exists()
    assert "interrupted in area 'robot': 4 figure(s) above; " in err and "not written" in err
    rows = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("a.")}
    assert rows["a.pairs_per_s"].endswith("ref 4  (the plain loop)  ratio 2.5")
    assert rows["a.goal_s"].endswith("goal < 600 s")
    assert rows["a.vs"].endswith("ref 0.5  against numpy")
    assert rows["a.bare"].endswith("(absolute)")
    assert out.index("[dtw] done") < out.index("a.pairs_per_s") < out.index("[robot] running")


def test_bench_prints_the_figures_when_the_json_cannot_be_written(
    tmp_path, run_script, bench, monkeypatch
) -> None:
    """A long run's figures are not lost to a path it can no longer write (here a file put
    where its folder was to be while the benchmarks ran)."""
    target = tmp_path / "later" / "cpu.json"

    class One:
        @staticmethod
        def run(quick: bool) -> dict:
            (tmp_path / "later").write_text("")
            return {"x.ms": {"value": 1.0, "unit": "ms"}}

    monkeypatch.setattr(bench, "_load", lambda area: One)
    code, out, err = run_script("bench", "--only", "dtw", "--json", target, module=bench)
    assert code == 2 and "error: FileExistsError" in err and "the figures are above" in err
    assert '"x.ms"' in out and not target.exists()


@pytest.mark.parametrize("force", [False, True])
@pytest.mark.parametrize("script", ["bench", "bench_gpu"])
def test_bench_refuses_a_json_it_cannot_write_before_running(
    tmp_path, run_script, bench, script: str, force: bool
) -> None:
    """A --json path under a file was found only after the whole run (the ``bench`` fixture
    fails any benchmark that starts)."""
    (tmp_path / "afile").write_text("kept")
    target = tmp_path / "afile" / "sub" / "cpu.json"
    args = ("--json", target, *(("--force",) if force else ()))
    code, out, err = run_script(script, *args, **({"module": bench} if script == "bench" else {}))
    assert code == 2 and f"cannot write {target}: {tmp_path / 'afile'} is not a folder" in err
    assert (tmp_path / "afile").read_text() == "kept" and "running" not in out


@pytest.mark.parametrize("name", ["plot_episode", "safety_seeds_report"])
def test_help_describes_a_script_with_its_whole_first_paragraph(
    run_script, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A docstring whose first paragraph runs over two lines: --help showed only its first
    line, a sentence cut off (an opened bracket never closed)."""
    monkeypatch.setenv("COLUMNS", "1000")  # argparse wraps at the terminal width (hyphens too)
    code, out, _ = run_script(name, "--help")
    assert code == 0
    doc = _load(name).__doc__
    first = " ".join(doc.split("\n\n")[0].split())
    assert len(doc.split("\n\n")[0].strip().splitlines()) > 1  # the case this test is about
    assert first in " ".join(out.split())


@pytest.mark.parametrize(
    ("script", "file", "args"),
    [("plot_robot_spheres", "fetch.png", []), ("plot_dataset", "reaches.png", ["--no-measure"])],
)
def test_plot_scripts_keep_existing_files_without_force(
    tmp_path, run_script, script, file, args
) -> None:
    """Their default folders are committed records, which they replaced without a word."""
    (tmp_path / file).write_bytes(b"earlier")
    code, _, err = run_script(script, "--out", tmp_path, *args)
    line = _one_error_line(err)
    assert code == 2 and f"{tmp_path / file}" in line and "pass --force" in line, line
    assert (tmp_path / file).read_bytes() == b"earlier"


def test_bench_sim_names_a_bad_checkpoint_in_one_line(tmp_path, run_script) -> None:
    """It ended in a CheckpointError traceback, exit 1."""
    (tmp_path / "bad.ckpt").write_bytes(b"not a checkpoint")
    for path in (tmp_path / "gone.ckpt", tmp_path / "bad.ckpt"):
        code, out, err = run_script("bench_sim", "--predictor", path)
        assert code == 2 and _one_error_line(err).startswith("error: CheckpointError: "), err
        assert "Traceback" not in err and not out


def test_bench_names_an_area_failing_on_bad_input_in_one_line(
    tmp_path, run_script, bench, monkeypatch
) -> None:
    """A bad IPLANNER_PREDICTOR failed the sim area with a traceback."""
    from iplanner_torch.errors import CheckpointError

    class Bad:
        @staticmethod
        def run(quick: bool) -> dict:
            raise CheckpointError("predictor checkpoint /x.ckpt does not exist")

    monkeypatch.setattr(bench, "_load", lambda area: Bad)
    code, _, err = run_script("bench", "--only", "sim", module=bench)
    assert code == 1 and "Traceback" not in err
    assert "[sim] error: CheckpointError: predictor checkpoint /x.ckpt does not exist" in err


def test_plot_episode_refuses_a_file_as_out(tmp_path, run_script) -> None:
    """It was a FileExistsError; the other scripts say what --out must be."""
    (tmp_path / "afile").write_text("")
    code, _, err = run_script("plot_episode", tmp_path, "--out", tmp_path / "afile")
    assert code == 2 and "--out must be a folder" in _one_error_line(err)


@pytest.mark.parametrize(("args", "code"), [(["--help"], 0), (["-h"], 0), ([], 2), (["-x"], 2)])
def test_gpu_check_answers_help_and_bad_arguments_with_its_usage(
    tmp_path: Path, args: list[str], code: int
) -> None:
    """``bash scripts/gpu_check.sh --help`` printed mkdir's help and then ran its stages with
    ``--help`` as the output folder; now it prints its usage and starts nothing."""
    import subprocess

    res = subprocess.run(
        ["bash", str(SCRIPTS / "gpu_check.sh"), *args],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == code
    assert "usage: bash scripts/gpu_check.sh OUT_DIR" in (res.stdout if code == 0 else res.stderr)
    assert list(tmp_path.iterdir()) == []
