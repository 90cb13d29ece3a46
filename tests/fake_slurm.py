"""A stand-in SLURM cluster on this machine: ``sbatch``, ``srun``, ``sacct`` and ``scancel``
executables that run a submitted batch script (a job array task by task) in the background
with the environment SLURM gives a job, and report the tasks' states as ``sacct`` does.

Enough of SLURM for Submitit's SLURM executor (``hydra/launcher=slurm``) to submit, watch and
collect a sweep end to end; nothing is scheduled, limited or isolated.
"""

from __future__ import annotations

import stat
import sys
from pathlib import Path

_SBATCH = r"""
import os, re, subprocess, sys
from pathlib import Path

state = Path(os.environ["FAKE_SLURM_STATE"])
state.mkdir(parents=True, exist_ok=True)
script = Path(sys.argv[-1])
text = script.read_text()
with open(state / "counter", "a+") as f:  # job ids 1001, 1002, ...
    f.seek(0)
    job_id = 1001 + len(f.read())
    f.write("x")
m = re.search(r"^#SBATCH --array=(\d+)-(\d+)", text, re.M)
tasks = list(range(int(m.group(1)), int(m.group(2)) + 1)) if m else [-1]
for t in tasks:
    (state / (f"{job_id}_{t}" if t >= 0 else str(job_id))).write_text("PENDING")
(state / f"{job_id}.sbatch_args").write_text(" ".join(sys.argv[1:]))
subprocess.Popen(
    [sys.executable, os.environ["FAKE_SLURM_RUNNER"], str(job_id), str(script)]
    + [str(t) for t in tasks],
    start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
)
print(f"Submitted batch job {job_id}")
"""

_RUNNER = r"""
import os, subprocess, sys
from pathlib import Path

state = Path(os.environ["FAKE_SLURM_STATE"])
job_id, script, tasks = sys.argv[1], sys.argv[2], [int(t) for t in sys.argv[3:]]
for i, t in enumerate(tasks):
    name = f"{job_id}_{t}" if t >= 0 else job_id
    env = dict(os.environ, SLURM_JOB_ID=str(int(job_id) * 1000 + i), SLURM_NTASKS="1",
               SLURM_JOB_NUM_NODES="1", SLURM_NODEID="0", SLURM_PROCID="0",
               SLURM_LOCALID="0", SLURM_JOB_NODELIST="localhost")
    if t >= 0:
        env.update(SLURM_ARRAY_JOB_ID=job_id, SLURM_ARRAY_TASK_ID=str(t))
    (state / name).write_text("RUNNING")
    rc = subprocess.call(["bash", script], env=env)
    (state / name).write_text("COMPLETED" if rc == 0 else "FAILED")
"""

_SRUN = r"""
import os, subprocess, sys

args = sys.argv[1:]
paths = {}
while args and args[0].startswith("--"):
    flag = args.pop(0)
    if flag in ("--output", "--error"):
        paths[flag] = args.pop(0)
env = os.environ
def expand(p):
    return (p.replace("%A", env.get("SLURM_ARRAY_JOB_ID", "")).replace("%a", env.get(
        "SLURM_ARRAY_TASK_ID", "")).replace("%j", env["SLURM_JOB_ID"]).replace("%t", "0"))
out = open(expand(paths["--output"]), "a") if "--output" in paths else None
err = open(expand(paths["--error"]), "a") if "--error" in paths else out
sys.exit(subprocess.call(args, stdout=out, stderr=err))
"""

_SACCT = r"""
import os, sys
from pathlib import Path

state = Path(os.environ["FAKE_SLURM_STATE"])
ids = [sys.argv[i + 1] for i, a in enumerate(sys.argv) if a == "-j"]
print("JobID|State|NodeList")
for job in ids:
    for f in sorted(state.glob(f"{job}*")):
        if f.name == job or f.name.startswith(f"{job}_"):
            print(f"{f.name}|{f.read_text()}|localhost")
"""

_SCANCEL = "import sys\n"


def install(bin_dir: Path, state_dir: Path) -> dict[str, str]:
    """Write the four executables (and the task runner) into ``bin_dir``.

    Returns:
        The environment variables to add (prepend ``bin_dir`` to PATH yourself): where the
        stand-in keeps its job states (``state_dir``) and its task runner.
    """
    bin_dir.mkdir(parents=True, exist_ok=True)
    head = f"#!{sys.executable}\n"
    for name, body in (
        ("sbatch", _SBATCH),
        ("srun", _SRUN),
        ("sacct", _SACCT),
        ("scancel", _SCANCEL),
        ("fake_slurm_runner", _RUNNER),
    ):
        path = bin_dir / name
        path.write_text(head + body)
        path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return {
        "FAKE_SLURM_STATE": str(state_dir),
        "FAKE_SLURM_RUNNER": str(bin_dir / "fake_slurm_runner"),
    }
