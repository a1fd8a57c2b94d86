#!/usr/bin/env python3
"""Peels the flat "caps" off a tetrahedral mesh's surface (scenes/meshes/README.md).

A cap is a tetrahedron whose four nodes all lie on the surface and two of whose faces are
boundary faces: a thin wedge over a surface edge. A flat pad pressing the curved surface flat
makes its four nodes coplanar, so its volume ratio falls to zero whatever the tissue does.
Removing it replaces its two boundary faces by its two inner ones (an edge flip of the surface,
which moves inward by the cap's height). A cap is peeled only when the result stays a 2-manifold
(the edge of its two inner faces is not already a surface edge) and it is thin (height at most
--max-height-ratio of its longest edge). Caps that appear after a peel are peeled in later
passes. Nodes are kept (each belongs to other tets); tets keep their order.

Usage: peel_caps.py IN.msh OUT.msh [--max-height-ratio 0.25]   (Gmsh 2.2 ASCII, tets only)
"""
import argparse
import math
import os
import sys
from collections import Counter


def read_msh(path):
    if not os.path.isfile(path) or os.path.getsize(path) > 512 * 1024 * 1024:
        sys.exit(f"{path}: not a regular file of sane size")
    lines = open(path).read().split("\n")
    i = lines.index("$Nodes")
    n = int(lines[i + 1])
    ids, nodes = [], []
    for k in range(n):
        f = lines[i + 2 + k].split()
        ids.append(int(f[0]))
        nodes.append(tuple(float(x) for x in f[1:4]))
    index = {node_id: k for k, node_id in enumerate(ids)}
    j = lines.index("$Elements")
    m = int(lines[j + 1])
    tets = []
    for k in range(m):
        f = lines[j + 2 + k].split()
        if f[1] != "4":
            sys.exit(f"{path}: element {f[0]} is not a tetrahedron")
        tags = int(f[2])
        tets.append(tuple(index[int(x)] for x in f[3 + tags:7 + tags]))
    return nodes, tets


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def faces(t):
    a, b, c, d = t
    return ((b, c, d), (a, d, c), (a, b, d), (a, c, b))


def key(f):
    return tuple(sorted(f))


def smallest_height(nodes, t):
    """The tet's smallest height 3 V / A_max, and that height over its longest edge."""
    p = [nodes[v] for v in t]
    vol6 = dot(sub(p[1], p[0]), cross(sub(p[2], p[0]), sub(p[3], p[0])))
    edges = [math.dist(p[i], p[j]) for i in range(4) for j in range(i + 1, 4)]
    lmax = max(edges)
    areas = [0.5 * math.sqrt(dot(x, x)) for x in
             (cross(sub(nodes[f[1]], nodes[f[0]]), sub(nodes[f[2]], nodes[f[0]])) for f in faces(t))]
    height = abs(vol6) / 2.0 / max(areas)
    return height, height / lmax


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--max-height-ratio", type=float, default=0.25,
                    help="peel only caps whose smallest height is at most this part of their "
                         "longest edge (default 0.25)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing OUT.msh")
    a = ap.parse_args()
    if os.path.exists(a.output) and not a.overwrite:
        sys.exit(f"{a.output} exists (--overwrite to replace it)")
    nodes, tets = read_msh(a.input)
    alive = [True] * len(tets)
    count = Counter(key(f) for t in tets for f in faces(t))
    peeled, largest_height, passes = 0, 0.0, 0
    while True:
        passes += 1
        surface_node = set(v for f, c in count.items() if c == 1 for v in f)
        surface_edge = set()
        for f, c in count.items():
            if c == 1:
                surface_edge.update({(f[0], f[1]), (f[0], f[2]), (f[1], f[2])})
        changed = False
        for i, t in enumerate(tets):
            if not alive[i] or not all(v in surface_node for v in t):
                continue
            boundary = [f for f in faces(t) if count[key(f)] == 1]
            if len(boundary) != 2:
                continue
            inner = [f for f in faces(t) if count[key(f)] == 2]
            shared = tuple(sorted(set(inner[0]) & set(inner[1])))
            if shared in surface_edge:
                continue   # the two inner faces' edge is on the surface: a peel would pinch it
            height, ratio = smallest_height(nodes, t)
            if ratio > a.max_height_ratio:
                continue
            alive[i] = False
            for f in faces(t):
                count[key(f)] -= 1
                if count[key(f)] == 0:
                    del count[key(f)]
            for f in inner:
                surface_edge.update({(min(x, y), max(x, y)) for x, y in
                                     ((f[0], f[1]), (f[0], f[2]), (f[1], f[2]))})
            peeled += 1
            largest_height = max(largest_height, height)
            changed = True
        if not changed:
            break
    kept = [t for i, t in enumerate(tets) if alive[i]]
    used = sorted(set(v for t in kept for v in t))
    if len(used) != len(nodes):
        sys.exit("a peel left a node without tetrahedron: not written")
    tmp = a.output + ".tmp"
    with open(tmp, "w") as out:
        out.write("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n" % len(nodes))
        for k, p in enumerate(nodes):
            out.write("%d %.17g %.17g %.17g\n" % (k + 1, p[0], p[1], p[2]))
        out.write("$EndNodes\n$Elements\n%d\n" % len(kept))
        for k, t in enumerate(kept):
            out.write("%d 4 2 1 1 %d %d %d %d\n" % (k + 1, t[0] + 1, t[1] + 1, t[2] + 1, t[3] + 1))
        out.write("$EndElements\n")
    os.replace(tmp, a.output)
    print(f"{a.input}: peeled {peeled} caps in {passes} passes ({len(tets)} -> {len(kept)} tets, "
          f"{len(nodes)} nodes kept); largest height {largest_height:.4g} (mesh units)")


if __name__ == "__main__":
    main()
