"""Parallel jobs of a sweep that lack the same predictors train them once: the others wait
for the first (``iplanner_torch.cli.experiment.training_lock``)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from iplanner_torch.cli.experiment import training_lock

fcntl = pytest.importorskip("fcntl")  # POSIX only; elsewhere the lock is a no-op


def test_a_second_run_waits_for_the_first_to_finish_training(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    folder = tmp_path / "ck" / "tasks_1x4"
    order: list[str] = []
    with training_lock(folder):
        assert (folder / ".training.lock").is_file()

        def second() -> None:
            with training_lock(folder):
                order.append("second")

        thread = threading.Thread(target=second)
        thread.start()
        seen, deadline = "", time.monotonic() + 30
        while "waiting for another run" not in seen and time.monotonic() < deadline:
            seen += capsys.readouterr().out
            time.sleep(0.01)
        assert f"waiting for another run training the predictors in {folder}" in seen
        assert thread.is_alive() and order == []  # still waiting while the first holds it
        order.append("first")
    thread.join(30)
    assert order == ["first", "second"]
    with training_lock(folder):  # released: taken at once, without waiting
        pass
    assert "waiting" not in capsys.readouterr().out


def test_a_noise_sweep_lacking_its_predictors_waits_before_it_generates_or_trains(
    tmp_path: Path,
) -> None:
    """``iplanner-evaluate evaluate.mode=noise_sweep`` whose predictors (and dataset) are
    missing takes the same lock before it generates the dataset and trains: a parallel job
    doing that for the same folder is waited for, not raced."""
    import os
    import subprocess
    import sys

    datasets, ck = tmp_path / "datasets", tmp_path / "ck"
    folder = ck / "small"
    args = [sys.executable, "-u", "-m", "iplanner_torch.cli.evaluate", "evaluate.mode=noise_sweep",
            f"paths.datasets={datasets}", f"data.path={datasets / 'small'}",
            f"paths.checkpoints={ck}", "trainer=fast", "progress=false",
            f"hydra.run.dir={tmp_path / 'run'}"]  # fmt: skip
    with training_lock(folder):
        proc = subprocess.Popen(
            args,
            cwd=tmp_path,
            env=dict(os.environ, MPLBACKEND="Agg"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            while line and "waiting for another run" not in line:
                line = proc.stdout.readline()
            assert f"waiting for another run training the predictors in {folder}" in line
            time.sleep(0.5)
            assert proc.poll() is None  # still waiting
            assert not (datasets / "small").exists()  # nothing generated while it waits
        finally:
            proc.kill()
            proc.wait(30)
