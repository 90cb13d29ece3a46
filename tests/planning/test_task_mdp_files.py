"""Task-planner files: a save that fails mid-write keeps the old file; a file nested too deep
or holding a number too long to read is a CheckpointError."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from iplanner_torch.errors import CheckpointError
from iplanner_torch.planning.task_mdp import TaskMDPCfg, TaskPlanner

ROOT = Path(__file__).resolve().parents[2]


class AnyOrder:
    """The human may take any object not yet taken."""

    def __init__(self, n: int) -> None:
        self.n = n

    def allowed_next(self, done: set[int]) -> set[int]:
        return set(range(self.n)) - done


def _trained(n: int = 2, seed: int = 0) -> TaskPlanner:
    planner = TaskPlanner(TaskMDPCfg(num_objects=n, episodes=30, seed=seed), AnyOrder(n))
    planner.train()
    return planner


_FAIL_MID_WRITE = """
import resource, signal, sys
from iplanner_torch.planning.task_mdp import TaskMDPCfg, TaskPlanner

class AnyOrder:
    def allowed_next(self, done):
        return set(range(4)) - done

planner = TaskPlanner(TaskMDPCfg(num_objects=4, episodes=200, seed=1), AnyOrder())
planner.train()
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (256, 256))  # the disk is full after 256 bytes
try:
    planner.save(sys.argv[1])
except OSError as exc:
    print("failed:", exc)
    sys.exit(3)
sys.exit(0)
"""


@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_FSIZE is POSIX")
def test_a_save_that_fails_mid_write_keeps_the_old_file(tmp_path: Path) -> None:
    path = tmp_path / "task_mdp.json"
    planner = _trained()
    planner.save(path)
    before = path.read_bytes()
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(_FAIL_MID_WRITE), str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert done.returncode == 3, done.stdout + done.stderr  # the save failed, with OSError
    assert path.read_bytes() == before  # was cut to 256 bytes of the new file
    loaded = TaskPlanner.load(path)
    assert loaded.cfg == planner.cfg and loaded.q.keys() == planner.q.keys()
    for k, v in planner.q.items():
        np.testing.assert_array_equal(loaded.q[k], v)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left


def test_a_save_replaces_the_old_file_and_leaves_nothing_else(tmp_path: Path) -> None:
    path = tmp_path / "task_mdp.json"
    _trained(seed=0).save(path)
    second = _trained(n=3, seed=1)
    second.save(path)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    assert TaskPlanner.load(path).cfg == second.cfg


def test_a_save_that_raises_before_writing_keeps_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error while the new text is written (here: after some of it) leaves the old file."""
    path = tmp_path / "task_mdp.json"
    _trained().save(path)
    before = path.read_bytes()

    def write_half_then_fail(self: Path, text: str, *args: object, **kwargs: object) -> int:
        with open(self, "w") as fh:
            fh.write(text[: len(text) // 2])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_text", write_half_then_fail)
    with pytest.raises(OSError, match="No space left"):
        _trained(n=3).save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[" * 100_000 + "]" * 100_000, r"nested too deep"),  # raised RecursionError
        ('{"a": ' * 100_000 + "1" + "}" * 100_000, r"nested too deep"),
        ("9" * 5000, r"integer of too many digits"),  # raised ValueError
        ('{"format": "iplanner_torch.task_mdp/1", "cfg": ' + "9" * 5000 + "}", r"too many"),
    ],
    ids=["deep_array", "deep_object", "long_integer", "long_integer_inside"],
)
def test_load_of_a_malformed_json_file_is_a_checkpoint_error(
    tmp_path: Path, text: str, match: str
) -> None:
    path = tmp_path / "deep.json"
    path.write_text(text)
    with pytest.raises(CheckpointError, match=match) as info:
        TaskPlanner.load(path)
    message = str(info.value)
    assert str(path) in message and "malformed" in message
    assert len(message) < len(str(path)) + 200  # the file's text is not echoed


def test_load_of_fields_nested_just_below_the_limit_is_a_checkpoint_error(
    tmp_path: Path,
) -> None:
    """JSON that parses but nests deep in a field: the messages naming the value must not
    recurse past the limit either."""
    data = json.loads(json.dumps({"format": "iplanner_torch.task_mdp/1", "q": {}}))
    depth = 900
    for field in ("format", "cfg", "h_table"):
        broken = dict(data, cfg={"num_objects": 2}, h_table=[[0.0, 0.0], [0.0, 0.0]])
        broken[field] = json.loads("[" * depth + "]" * depth)
        path = tmp_path / f"{field}.json"
        path.write_text(json.dumps(broken))
        with pytest.raises(CheckpointError, match=str(path).replace("\\", "\\\\")):
            TaskPlanner.load(path)
