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
