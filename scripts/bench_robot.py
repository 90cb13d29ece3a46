"""Benchmark: forward kinematics to bounding spheres for the planner's batch (1024 x 20).

Each figure is measured together with its reference in the same run: pytorch-kinematics'
own ``forward_kinematics`` (chain built from our URDF, every link frame) on the same batch and
device. ``ratio`` is reference time / our time (> 1: ours is faster).

Usage:
    python scripts/bench_robot.py [--quick]

On a CPU shared with other work, pin the thread count (``OMP_NUM_THREADS=1``): oversubscribed
threads make the small GEMMs of both implementations erratic.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable

import pytorch_kinematics as pk
import torch
from _timing import median_seconds

from iplanner_torch.robot.model import RobotModel
from iplanner_torch.types import default_device

BATCH, WAYPOINTS = 1024, 20


def _median_ms(fn: Callable[[], object], device: torch.device, reps: int, warmup: int) -> float:
    sync = (lambda: torch.cuda.synchronize(device)) if device.type == "cuda" else None
    return 1e3 * median_seconds(fn, reps, warmup=warmup, sync=sync)


def _bench_robot(name: str, device: torch.device, reps: int, warmup: int) -> dict[str, dict]:
    model = RobotModel.load(name, device=device, dtype=torch.float32)
    chain = pk.build_serial_chain_from_urdf(model.urdf_xml(), model.tool_link).to(
        device=device, dtype=torch.float32
    )
    gen = torch.Generator(device="cpu").manual_seed(0)
    q = model.q_home.cpu() + 0.5 * torch.randn(BATCH, WAYPOINTS, model.num_joints, generator=gen)
    q = q.to(device)  # (B, W, J)
    q_flat = q.reshape(-1, model.num_joints)  # (B*W, J)

    def ours_fwd() -> torch.Tensor:
        with torch.no_grad():
            return model.sphere_centers(q)

    def ref_fwd() -> object:
        with torch.no_grad():
            return chain.forward_kinematics(q_flat, end_only=False)

    def ours_bwd() -> None:
        x = q.detach().requires_grad_(True)
        model.sphere_centers(x).square().sum().backward()

    def ref_bwd() -> None:
        x = q_flat.detach().requires_grad_(True)
        frames = chain.forward_kinematics(x, end_only=False)
        sum(m.get_matrix()[:, :3, 3].square().sum() for m in frames.values()).backward()

    out: dict[str, dict] = {}
    for key, ours, ref in (("", ours_fwd, ref_fwd), ("_backward", ours_bwd, ref_bwd)):
        t_ours = _median_ms(ours, device, reps, warmup)
        t_ref = _median_ms(ref, device, reps, warmup)
        out[f"fk.{name}.spheres{key}_{BATCH}x{WAYPOINTS}_ms"] = {
            "value": t_ours,
            "unit": "ms",
            "reference": t_ref,
            "reference_name": "pytorch_kinematics forward_kinematics (all links)"
            + (" + backward" if key else ""),
            "ratio": t_ref / t_ours,
            "spheres": model.num_spheres,
            "device": str(device),
            "reps": reps,
        }
    return out


def run(quick: bool) -> dict[str, dict]:
    """Median timings of FK to spheres (forward, forward + backward) with their references.

    Args:
        quick: few repetitions, iiwa only (a few seconds); otherwise both robots, 30 reps.

    Returns:
        ``{figure: {"value", "unit", "reference", "ratio", ...}}``; the iiwa's figures are
        also reported under the short names ``fk.spheres_1024x20_ms`` and
        ``fk.spheres_backward_1024x20_ms``.
    """
    torch.manual_seed(0)
    device = default_device()
    reps, warmup = (3, 1) if quick else (30, 5)
    names = ("kuka_iiwa14",) if quick else ("kuka_iiwa14", "fetch")
    results: dict[str, dict] = {}
    for name in names:
        results.update(_bench_robot(name, device, reps, warmup))
    results["fk.spheres_1024x20_ms"] = results["fk.kuka_iiwa14.spheres_1024x20_ms"]
    results["fk.spheres_backward_1024x20_ms"] = results[
        "fk.kuka_iiwa14.spheres_backward_1024x20_ms"
    ]
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few repetitions, iiwa only")
    args = parser.parse_args()
    print(json.dumps(run(args.quick), indent=2))


if __name__ == "__main__":
    main()
