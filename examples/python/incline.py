#!/usr/bin/env python3
"""A block slides down an inclined plane under Coulomb friction.

A stiff 2 cm block (4 x 4 x 2 hexahedra, six tetrahedra each) rests on a plane tilted by theta,
friction mu. Once sliding, its velocity down the slope grows by h g (sin theta - mu cos theta)
every step of length h (when tan theta > mu; it sticks otherwise): the example prints that increment next to the simulated one and exits
non-zero when they differ by more than 1 %.

    export PYTHONPATH=$PWD/build/python
    /usr/bin/python3 examples/python/incline.py --theta 30 --mu 0.3
"""
import argparse
import math
import pathlib
import sys
import tempfile

import numpy as np

import tactus


def write_box_mesh(path, size_m, cells, origin_m):
    """A box of size_m split into cells[0] x cells[1] x cells[2] hexahedra of six tetrahedra each
    (around each cell's diagonal from its lowest to its highest corner), as a legacy VTK file."""
    nx, ny, nz = cells
    ids = {}
    nodes = []
    for k in range(nz + 1):
        for j in range(ny + 1):
            for i in range(nx + 1):
                ids[i, j, k] = len(nodes)
                nodes.append([origin_m[0] + size_m[0] * i / nx, origin_m[1] + size_m[1] * j / ny,
                              origin_m[2] + size_m[2] * k / nz])
    six = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    tets = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                corner = [ids[i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2)] for c in range(8)]
                for t in six:
                    tet = [corner[a] for a in t]
                    a, b, c, d = (np.array(nodes[n]) for n in tet)
                    if np.dot(np.cross(b - a, c - a), d - a) < 0:   # positively oriented
                        tet[2], tet[3] = tet[3], tet[2]
                    tets.append(tet)
    lines = ["# vtk DataFile Version 3.0", "box", "ASCII", "DATASET UNSTRUCTURED_GRID",
             f"POINTS {len(nodes)} double"]
    lines += [f"{x:.17g} {y:.17g} {z:.17g}" for x, y, z in nodes]
    lines.append(f"CELLS {len(tets)} {5 * len(tets)}")
    lines += ["4 " + " ".join(map(str, t)) for t in tets]
    lines.append(f"CELL_TYPES {len(tets)}")
    lines += ["10"] * len(tets)
    pathlib.Path(path).write_text("\n".join(lines) + "\n")


def slide(theta_deg=30.0, mu=0.3, steps=40, h=0.001, folder=None):
    """Runs the block on the incline; returns the mean node velocity along the slope after each
    step [m/s] and the expected increment per step h g (sin theta - mu cos theta)."""
    th = math.radians(theta_deg)
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(folder or tmp)
        side = 0.02
        write_box_mesh(folder / "block.vtk", (side, side, side / 2), (4, 4, 2),
                       (-side / 2, -side / 2, 0.0))
        # the block turned by theta about y so that its base lies on the plane through the
        # origin whose normal is (sin theta, 0, cos theta)
        yaml = f"""
time_step: {h}
gravity: [0, 0, -9.81]
tissues:
  - name: block
    mesh: block.vtk
    transform: {{rotation_deg: [0, {theta_deg!r}, 0]}}
    material: {{law: corotational, young_modulus: 2.0e7, poisson_ratio: 0.3, density: 1000}}
    damping: {{rayleigh_stiffness: 0.001}}
    compliance: {{model: exact}}
obstacles:
  - {{name: slope, plane: {{point: [0, 0, 0], normal: [{math.sin(th)!r}, 0, {math.cos(th)!r}]}},
      friction: {mu!r}}}
solver: {{nsgs_tolerance: 1.0e-9, nsgs_max_sweeps: 20000}}
"""
        sim = tactus.Simulation(tactus.Model.from_string(yaml, str(folder), "incline.yaml"))
        down = np.array([math.cos(th), 0.0, -math.sin(th)])
        v_down = []
        for _ in range(steps):
            report = sim.step()
            if not report.nsgs.converged:
                raise RuntimeError(f"step {sim.step_index}: NSGS {report.nsgs}")
            v_down.append(float(sim.velocities(0).mean(axis=0) @ down))
    # it slides when tan theta > mu, else it sticks (no gain)
    return np.array(v_down), max(0.0, h * 9.81 * (math.sin(th) - mu * math.cos(th)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--theta", type=float, default=30.0, help="slope [deg]")
    parser.add_argument("--mu", type=float, default=0.3, help="friction coefficient")
    parser.add_argument("--steps", type=int, default=40)
    args = parser.parse_args()
    v, expected = slide(args.theta, args.mu, args.steps)
    dv = np.diff(v)
    scale = expected if expected > 0 else 1e-3 * 9.81 * math.sin(math.radians(args.theta))
    worst = np.max(np.abs(dv - expected)) / scale
    print(f"theta {args.theta} deg, mu {args.mu}: velocity gain per step, expected "
          f"h g (sin theta - mu cos theta) = {expected:.6g} m/s")
    print(f"simulated: first {dv[0]:.6g}, last {dv[-1]:.6g}, largest deviation "
          f"{100 * worst:.3f} %")
    return 0 if worst < 0.01 else 1


if __name__ == "__main__":
    sys.exit(main())
