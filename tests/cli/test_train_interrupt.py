"""An interrupted training (Ctrl-C, SIGTERM) prints one ``interrupted: ...`` line and exits 130,
keeping the sub-models it finished, also when the signal lands inside a Lightning fit (which
ends the process with its own ``SystemExit(1)``)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from iplanner_torch.cli._common import friendly_errors
from iplanner_torch.data.reaching import ReachingCfg, generate_reaching_dataset

#: a classifier that trains in a fraction of a second, so the GPs' fits start soon
CHEAP_CLASSIFIER = ("predictor.classifier_kernel=rbf", "predictor.ivm_max_import=6",
                    "predictor.ivm_candidates=8")  # fmt: skip


def _fit_in_progress(out: Path) -> str | None:
    """The sub-model whose Lightning fit has started (its log folder is there) and not ended
    (no checkpoint yet), once a first GP's checkpoint is written; else None."""
    if not any(out.glob("gp_*.ckpt")):
        return None
    logs = out / "logs"
    started = {re.sub(r"_r\d+$", "", p.name) for p in logs.iterdir()} if logs.is_dir() else set()
    running = sorted(n for n in started if not (out / f"{n}.ckpt").exists())
    return running[0] if running else None


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_training_interrupted_during_a_fit_exits_130_and_keeps_its_sub_models(
    tmp_path: Path, sig: str
) -> None:
    """Stopped as a GP's fit starts, after a first GP is written: one line, exit 130, the
    finished sub-models and the record kept, no checkpoint of the cut GP nor predictor.ckpt."""
    ds, out, run = tmp_path / "ds", tmp_path / "out", tmp_path / "run"
    generate_reaching_dataset(ReachingCfg(n_targets=2, reaches_per_target=3), ds, progress=False)
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    proc = subprocess.Popen(
        [sys.executable, "-m", "iplanner_torch.cli.train", f"data.path={ds}", "trainer=fast",
         f"train.out_dir={out}", "progress=false", f"hydra.run.dir={run}",
         *CHEAP_CLASSIFIER],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 300
    running = None
    while proc.poll() is None and time.monotonic() < deadline:
        running = _fit_in_progress(out)
        if running is not None:
            break
        time.sleep(0.005)
    if running is None:
        proc.kill()
        _, err = proc.communicate(timeout=60)
        pytest.fail(f"no fit after a first GP's checkpoint (exit {proc.returncode}): "
                    f"{err[-2000:]}")  # fmt: skip
    finished = sorted(p.name for p in out.glob("*.ckpt"))
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"interrupted: what was written before is kept in {out} "), err[-3000:]
    assert "train.resume=true" in last
    assert set(finished) <= {p.name for p in out.glob("*.ckpt")}  # the finished ones are kept
    assert not (out / f"{running}.ckpt").exists() and not (out / "predictor.ckpt").exists()
    assert (out / "training_inputs.json").is_file()
    assert "interrupted: what was written before is kept" in (run / "train.log").read_text()


def test_an_exit_that_follows_an_interrupt_is_an_interrupt(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Lightning's ``sys.exit(1)`` in its ``except KeyboardInterrupt`` block is reported as
    the interrupt, and so is an error its teardown raises while handling the interrupt (a race
    seen in CI: ``RuntimeError: Please call iter(combined_loader) first``, exit 1); another
    ``SystemExit`` passes through as it is."""

    @friendly_errors
    def fit_interrupted() -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            sys.exit(1)

    @friendly_errors
    def exits(code: int) -> None:
        raise SystemExit(code)

    @friendly_errors
    def teardown_fails(kind: type[Exception]) -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:  # Lightning's teardown of a cut fit may fail in turn
            raise kind("Please call `iter(combined_loader)` first.") from None

    with pytest.raises(SystemExit) as stop:
        fit_interrupted()
    assert stop.value.code == 130
    assert capsys.readouterr().err.startswith("interrupted: ")
    for kind in (RuntimeError, ValueError):  # raised while the interrupt was handled
        with pytest.raises(SystemExit) as stop:
            teardown_fails(kind)
        assert stop.value.code == 130
        err = capsys.readouterr().err
        assert err.startswith("interrupted: ") and "Traceback" not in err
    for code in (0, 1, 3):
        with pytest.raises(SystemExit) as stop:
            exits(code)
        assert stop.value.code == code
    assert capsys.readouterr().err == ""


def test_an_interrupt_that_lands_in_a_finalizer_is_not_lost(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Python ignores an exception raised in a ``__del__`` (where a signal may land while the
    garbage collector frees a Lightning trainer): the interrupt is raised again after it."""

    class Finalized:
        def __del__(self) -> None:
            raise KeyboardInterrupt  # as Ctrl-C arriving while it runs

    @friendly_errors
    def busy() -> None:
        Finalized()  # freed at once
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            time.sleep(0.01)

    with pytest.raises(SystemExit) as stop:
        busy()
    assert stop.value.code == 130
    assert capsys.readouterr().err.startswith("interrupted: ")
