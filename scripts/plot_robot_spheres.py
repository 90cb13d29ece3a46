"""Draw each robot's bounding spheres at the home pose (matplotlib 3D), in the table frame.

Usage:
    python scripts/plot_robot_spheres.py [--out experiments/robot_spheres] [--force]

Files that exist (the committed record, by default) are replaced only with ``--force``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from _report import fail, main_guard, refuse_existing  # noqa: E402

from iplanner_torch.robot.model import RobotModel  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "experiments" / "robot_spheres"


def plot_robot(name: str, path: Path) -> None:
    """Write a PNG of robot ``name``'s spheres and link chain at its home pose."""
    model = RobotModel.load(name, dtype=torch.float64)
    centers = model.sphere_centers(model.q_home).numpy()  # (S, 3)
    radii = model.sphere_radii.numpy()
    links = model.link_positions(model.q_home)
    chain = np.stack([links[n].numpy() for n in model.link_names])  # (L, 3)
    owners = sorted(set(model.sphere_link), key=model.sphere_link.index)
    colours = plt.cm.tab10(np.linspace(0, 1, max(len(owners), 2)))
    fig = plt.figure(figsize=(7, 7))
    ax = fig.add_subplot(projection="3d", computed_zorder=False)  # the tool point on top
    u, v = np.mgrid[0 : 2 * np.pi : 16j, 0 : np.pi : 10j]
    for c, r, link in zip(centers, radii, model.sphere_link):
        col = colours[owners.index(link)]
        ax.plot_wireframe(
            c[0] + r * np.cos(u) * np.sin(v),
            c[1] + r * np.sin(u) * np.sin(v),
            c[2] + r * np.cos(v),
            color=col,
            linewidth=0.4,
            alpha=0.6,
        )
    ax.plot(chain[:, 0], chain[:, 1], chain[:, 2], "k-o", markersize=3, label="link frames")
    ee = model.ee_position(model.q_home).numpy()
    # on top of the spheres that enclose it (drawn last, no depth shading), or it is hidden
    ax.scatter(*ee, color="red", s=60, label="tool point", depthshade=False, zorder=10)
    # Table top (z = 0) and the seated human's position (x = -0.45) for orientation.
    tx, ty = np.meshgrid([-0.6, 0.6], [-0.6, 0.6])
    ax.plot_surface(tx, ty, np.zeros_like(tx), color="tan", alpha=0.25)
    ax.scatter(-0.45, 0.0, 0.0, color="blue", marker="^", s=40, label="human seat (x=-0.45)")
    lo = np.minimum(centers.min(0) - radii.max(), [-0.6, -0.6, -0.1])
    hi = np.maximum(centers.max(0) + radii.max(), [0.6, 0.6, 0.5])
    span = (hi - lo).max() / 2
    mid = (hi + lo) / 2
    ax.set_xlim(mid[0] - span, mid[0] + span)
    ax.set_ylim(mid[1] - span, mid[1] + span)
    ax.set_zlim(mid[2] - span, mid[2] + span)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.view_init(elev=20, azim=-60)
    ax.set_title(f"{name}: {model.num_spheres} spheres at q_home (excess <= 2 cm)")
    ax.legend(loc="upper left", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


@main_guard
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=OUT,
        help=f"folder for kuka_iiwa14.png and fetch.png (default {OUT})",
    )
    parser.add_argument("--force", action="store_true", help="replace existing files")
    args = parser.parse_args()
    if args.out.exists() and not args.out.is_dir():
        fail(f"--out must be a folder: {args.out} is a file")
    files = [args.out / f for f in ("kuka_iiwa14.png", "fetch.png")]
    refuse_existing(files, args.force, "--out <folder>")  # the default: the committed record
    for name, file in (("kuka_iiwa14", "kuka_iiwa14.png"), ("fetch", "fetch.png")):
        plot_robot(name, args.out / file)
        print(args.out / file)


if __name__ == "__main__":
    main()
