#!/usr/bin/env python3
"""Converts a Gmsh 2.2 tetrahedral mesh to TetGen's .node/.ele files and back
(scenes/meshes/README.md, liver_23k_repaired.msh).

Usage: tetgen_msh.py to-tetgen IN.msh BASE      (writes BASE.node, BASE.ele)
       tetgen_msh.py from-tetgen BASE OUT.msh   (reads BASE.node, BASE.ele)
Neither overwrites an existing output.
"""
import os
import sys

from peel_caps import read_msh


def refuse_existing(path):
    if os.path.exists(path):
        sys.exit(f"{path}: exists; remove it first")


def read_text(path):
    if not os.path.isfile(path) or os.path.getsize(path) > 512 * 1024 * 1024:
        sys.exit(f"{path}: not a regular file of sane size")
    with open(path) as f:
        return f.read()


def to_tetgen(msh, base):
    nodes, tets = read_msh(msh)   # peel_caps.py's reader: tets only, 0-based node indices
    for ext in (".node", ".ele"):
        refuse_existing(base + ext)
    with open(base + ".node", "w") as out:
        out.write(f"{len(nodes)} 3 0 0\n")
        out.writelines("%d %.17g %.17g %.17g\n" % (k + 1, *p) for k, p in enumerate(nodes))
    with open(base + ".ele", "w") as out:
        out.write(f"{len(tets)} 4 0\n")
        out.writelines(f"{k + 1} {' '.join(str(v + 1) for v in t)}\n" for k, t in enumerate(tets))


def rows(path):
    return [l.split() for l in read_text(path).split("\n") if l.strip() and not l.startswith("#")]


def from_tetgen(base, msh):
    nodes = rows(base + ".node")
    tets = rows(base + ".ele")
    n, m = int(nodes[0][0]), int(tets[0][0])
    refuse_existing(msh)
    with open(msh, "w") as out:
        out.write("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n" % n)
        out.writelines(" ".join(v[:4]) + "\n" for v in nodes[1:n + 1])
        out.write("$EndNodes\n$Elements\n%d\n" % m)
        out.writelines(f"{k + 1} 4 2 0 1 {' '.join(t[1:5])}\n" for k, t in enumerate(tets[1:m + 1]))
        out.write("$EndElements\n")


if __name__ == "__main__":
    if len(sys.argv) != 4 or sys.argv[1] not in ("to-tetgen", "from-tetgen"):
        sys.exit(__doc__)
    (to_tetgen if sys.argv[1] == "to-tetgen" else from_tetgen)(sys.argv[2], sys.argv[3])
