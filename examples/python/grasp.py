#!/usr/bin/env python3
"""Grasp the liver's right lobe (scenes/liver_grasp.yaml) and plot the grasp force.

The grasper follows the scene's script: the liver settles under gravity, the jaws approach the
lobe, close on it (a finite grip), lift it 2 cm, hold it and let it go. Every step records the
total normal force of the contacts, the contact force on the tool and how far the tissue
between the jaws rose since they first touched it; at the
middle of the hold the haptic local model re-solves that step's contact problem with the device
moved 1 mm up, as haptic_server would. The figure (matplotlib) goes to --output.

    export PYTHONPATH=$PWD/build/python
    /usr/bin/python3 examples/python/grasp.py --output grasp_force.png
"""
import argparse
import pathlib
import sys

import numpy as np

import tactus

SCENE = pathlib.Path(__file__).resolve().parents[2] / "scenes" / "liver_grasp.yaml"


def grasp(steps=None, probe_at_s=5.0):
    """Runs the script; returns a dict of per-step series and the local model's probe."""
    sim = tactus.Simulation(tactus.Model.from_file(SCENE))
    steps = steps or round(sim.model.duration / sim.model.time_step)
    held = z0 = None   # the 20 nodes nearest the jaws at the first contact, and their height
    out = {"t": [], "normal_force_n": [], "tool_force_n": [], "lift_mm": [], "contacts": []}
    probe = None
    for _ in range(steps):
        sim.follow_script()
        report = sim.step()
        out["t"].append(sim.time)
        out["normal_force_n"].append(report.total_normal_force_n)
        out["tool_force_n"].append(np.linalg.norm(report.tool_wrench[:3]))
        if held is None and report.contacts > 0:
            tool = sim.instrument(0).pose.position
            held = np.argsort(np.linalg.norm(sim.positions(0) - tool, axis=1))[:20]
            z0 = sim.positions(0)[held, 2].mean()
        out["lift_mm"].append(0.0 if held is None else 1e3 * (sim.positions(0)[held, 2].mean() - z0))
        out["contacts"].append(report.contacts)
        if probe is None and sim.time >= probe_at_s and report.contacts > 0:
            problem = sim.last_problem()
            model = tactus.HapticModel()
            status = model.adopt(problem)
            device = problem.device_pose   # where the device was for this step
            moved = tactus.Pose(device.position + [0.0, 0.0, 1e-3], device.quaternion)
            at_rest, lifted = model.solve(), model.solve([moved])
            probe = {"t": sim.time, "status": status, "force_n": at_rest.force_n[0],
                     "force_lifted_n": lifted.force_n[0], "used": lifted.used}
    return {k: np.array(v) for k, v in out.items()}, probe


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default="grasp_force.png", help="figure file (PNG, PDF, SVG)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing figure")
    parser.add_argument("--steps", type=int, default=None, help="default: the whole script")
    args = parser.parse_args()
    output = pathlib.Path(args.output)
    if output.exists() and not args.overwrite:
        print(f"{output} exists: pass --overwrite to replace it", file=sys.stderr)
        return 2
    series, probe = grasp(args.steps)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    top.plot(series["t"], series["normal_force_n"], label="total normal force")
    top.plot(series["t"], series["tool_force_n"], label="contact force on the tool")
    top.set_ylabel("force [N]")
    top.legend()
    top.set_title("liver_grasp: the grasp")
    bottom.plot(series["t"], series["lift_mm"])
    bottom.set_ylabel("tissue in the jaws: rise [mm]")
    bottom.set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(output)
    held = series["normal_force_n"][series["contacts"] > 0]
    print(f"{len(series['t'])} steps; in contact {len(held)}; normal force median "
          f"{np.median(held) if len(held) else 0:.3f} N, max {series['normal_force_n'].max():.3f} N;"
          f" tissue in the jaws rose at most {series['lift_mm'].max():.1f} mm; figure {output}")
    if probe:
        print(f"haptic local model at t = {probe['t']:.2f} s ({probe['status']}): force on the "
              f"tool {np.round(probe['force_n'], 3)} N; device 1 mm up: "
              f"{np.round(probe['force_lifted_n'], 3)} N ({probe['used']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
