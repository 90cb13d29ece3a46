"""Plot a few synthetic reaches and record the default dataset's generation cost.

Writes ``experiments/dataset/reaches.png`` (hand paths in top and side view with the skeleton at
the target, and hand speed against time, by target) and ``experiments/dataset/README.md`` (the
command, and the generation time and size of the default dataset measured by this script);
``--out <folder>`` writes them there instead. Files that exist are replaced only with
``--force``.

Usage::

    python scripts/plot_dataset.py --force    # plots and measures: replaces the record
    python scripts/plot_dataset.py --no-measure --force
    python scripts/plot_dataset.py --no-measure --out /tmp/preview   # leaves the record as is
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from _report import fail, main_guard, refuse_existing  # noqa: E402

from iplanner_torch.data.reaching import (  # noqa: E402
    ReachingCfg,
    generate_reaching_dataset,
    reach_targets,
    reaching_demonstrations,
)
from iplanner_torch.data.skeleton import BONES, JOINT_INDEX  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "dataset"


def plot_reaches(path: Path, cfg: ReachingCfg) -> None:
    """Draw reach 0 to every target (and reach 1 to target 1 at every speed) into ``path``."""
    targets = reach_targets(cfg.n_targets)
    colors = plt.cm.tab10(np.arange(cfg.n_targets) % 10)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5.2))
    top, side, speed = axes
    for tgt in range(cfg.n_targets):
        demo = reaching_demonstrations(cfg, tgt, 0)[0]
        clean = demo.clean_positions
        hand = clean[:, JOINT_INDEX[f"{demo.metadata['arm']}_hand"]]
        c = colors[tgt]
        top.plot(hand[:, 0], hand[:, 1], "-", color=c, lw=1.5, label=f"target {tgt}")
        top.plot(demo.positions[:, JOINT_INDEX[f"{demo.metadata['arm']}_hand"], 0],
                 demo.positions[:, JOINT_INDEX[f"{demo.metadata['arm']}_hand"], 1],
                 ".", color=c, ms=2, alpha=0.5)  # fmt: skip
        side.plot(hand[:, 0], hand[:, 2], "-", color=c, lw=1.5)
        v = np.linalg.norm(np.diff(hand, axis=0), axis=1) * demo.fps
        speed.plot(demo.timestamps[1:], v, "-", color=c, lw=1.5)
        if tgt == cfg.n_targets - 1:  # skeleton at the end of the hold
            f = int(np.flatnonzero(demo.labels == 1 + tgt).max())
            for a, b in BONES:
                ia, ib = JOINT_INDEX[a], JOINT_INDEX[b]
                top.plot(clean[f, [ia, ib], 0], clean[f, [ia, ib], 1], "-", color="0.4", lw=1)
                side.plot(clean[f, [ia, ib], 0], clean[f, [ia, ib], 2], "-", color="0.4", lw=1)
            top.plot(clean[f, :, 0], clean[f, :, 1], "o", color="0.4", ms=3)
            side.plot(clean[f, :, 0], clean[f, :, 2], "o", color="0.4", ms=3)
    top.scatter(targets[:, 0], targets[:, 1], marker="x", c=colors, s=60, zorder=5)
    for i, p in enumerate(targets):
        top.annotate(str(i), p[:2], xytext=(4, 4), textcoords="offset points")
    side.axhline(0.0, color="k", lw=0.8)
    side.text(0.12, -0.03, "table top", fontsize=8)
    top.set(title="top view: hand paths (reach 0 of each target)", xlabel="x [m] (to robot)",
            ylabel="y [m] (human's left)", aspect="equal")  # fmt: skip
    side.set(title="side view (skeleton at the hold, target 7)", xlabel="x [m]",
             ylabel="z [m]", aspect="equal")  # fmt: skip
    speed.set(title=f"hand speed (clean, {cfg.fps:g} Hz)", xlabel="time [s]", ylabel="m/s")
    top.legend(fontsize=7, loc="lower left", ncol=2)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


@main_guard
def main() -> None:
    """Plot, then (unless ``--no-measure``) generate the default dataset to a temp folder."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-measure", action="store_true", help="skip the timing run")
    parser.add_argument(
        "--out", type=Path, default=OUT, help=f"folder for reaches.png and README.md ({OUT})"
    )
    parser.add_argument("--force", action="store_true", help="replace existing files")
    args = parser.parse_args()
    if args.out.exists() and not args.out.is_dir():
        fail(f"--out must be a folder: {args.out} is a file")
    writes = [args.out / "reaches.png"] + ([] if args.no_measure else [args.out / "README.md"])
    refuse_existing(writes, args.force, "--out <folder>")  # the default: the committed record
    args.out.mkdir(parents=True, exist_ok=True)
    plot_reaches(args.out / "reaches.png", ReachingCfg())
    print(f"wrote {args.out / 'reaches.png'}")
    if args.no_measure:
        return
    rows = []
    for cfg in (ReachingCfg(), ReachingCfg(speeds=(0.5, 1.0, 2.0))):
        with tempfile.TemporaryDirectory() as tmp:
            s = generate_reaching_dataset(cfg, Path(tmp), progress=False)
        rows.append(
            f"| {cfg.speeds} | {s.n_demonstrations} | {s.n_frames} | {s.seconds:.2f} s "
            f"| {s.bytes_on_disk / 1e6:.2f} MB |"
        )
    try:
        git = ["git", "rev-parse", "--short", "HEAD"]
        out = subprocess.run(git, cwd=ROOT, capture_output=True, text=True, check=False)
        commit = out.stdout.strip() or "uncommitted"
    except OSError:
        commit = "unknown"
    text = f"""# Synthetic reaching dataset

Command (from the repository root): `python scripts/plot_dataset.py --force`

Commit: {commit}. Machine: {platform.processor() or platform.machine()}, shared CPU.

![reaches](reaches.png)

`reaches.png`: left, the hand path of reach 0 to each of the 8 targets in top view (lines:
clean positions; dots: the noisy, tracked positions with sigma = 1 cm) with the skeleton at
the end of the hold for target 7 (the resting left hand slides with the trunk); middle, the
same in side view (the trunk leans forward for far targets); right, the hand speed against
time (bell-shaped, one peak per movement: reach, then return).

Default settings (`ReachingCfg()`: 8 targets x 30 reaches, 15 Hz, noise 0.01 m, dropout 0.5 %,
seed 0), written as NPZ, generation time measured by this script:

| speed factors | demonstrations | frames | generation time | size on disk |
|---|---|---|---|---|
{chr(10).join(rows)}
"""
    (args.out / "README.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
