"""``iplanner-data``: make, inspect and convert human motion datasets.

Subcommands (the first argument), followed by Hydra overrides::

    iplanner-data generate              # synthetic reaching set -> datasets/reaching
    iplanner-data generate data.generator.reaches_per_target=5 data.path=datasets/small
    iplanner-data generate data=tasks   # task demonstrations (Take_i in a task order)
    iplanner-data info data=lego        # check and summarise a dataset folder
"""

from __future__ import annotations

import sys
import time

import hydra
from omegaconf import DictConfig

from iplanner_torch.cli._common import CONF_DIR, friendly_errors, generate_dataset, repo_path

COMMANDS = ("generate", "info")
_command = "generate"


def _generate(cfg: DictConfig) -> None:
    out_dir = repo_path(cfg.data.path)
    t0 = time.perf_counter()
    command = ("iplanner-data generate " + " ".join(sys.argv[1:])).strip()
    summary = generate_dataset(cfg.data, out_dir, progress=bool(cfg.progress), command=command)
    mb = summary.bytes_on_disk / 1e6
    print(
        f"wrote {summary.n_demonstrations} demonstrations ({summary.n_frames} frames, {mb:.1f} MB)"
        f" to {out_dir} in {time.perf_counter() - t0:.1f} s; dataset card: {out_dir / 'README.md'}"
    )


def _info(cfg: DictConfig) -> None:
    from iplanner_torch.data.io import load_demonstrations, load_lego_assembly

    path = repo_path(cfg.data.path)
    fps = cfg.data.get("fps", None)
    if cfg.data.get("format", "native") == "lego_assembly":
        demos = load_lego_assembly(path, fps=float(fps or 30.0))
    else:
        demos = load_demonstrations(path, fps=fps)
    frames = sum(d.num_frames for d in demos)
    joints = demos[0].joint_names if demos else ()
    actions = demos[0].action_names if demos else ()
    nan = sum(int(d.positions.size - (d.positions == d.positions).sum()) for d in demos)
    print(f"{path}: {len(demos)} demonstrations, {frames} frames")
    print(f"  joints ({len(joints)}): {', '.join(joints)}")
    print(f"  actions ({len(actions)}): {', '.join(actions)}")
    print(f"  fps: {sorted({d.fps for d in demos})}; NaN values: {nan}")


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
@friendly_errors
def _app(cfg: DictConfig) -> None:
    {"generate": _generate, "info": _info}[_command](cfg)


def main() -> None:
    """Console entry point: ``iplanner-data {generate,info} [overrides...]``."""
    global _command
    args = sys.argv[1:]
    if args and args[0] in ("-h", "--help") and len(args) == 1:
        print(__doc__)
        return
    if args and not args[0].startswith("-") and "=" not in args[0]:
        if args[0] not in COMMANDS:
            msg = f"error: unknown command {args[0]!r}; expected one of {COMMANDS}"
            print(msg, file=sys.stderr)
            raise SystemExit(2)
        _command = args.pop(0)
        sys.argv = [sys.argv[0], *args]
    _app()


if __name__ == "__main__":
    main()
