#!/usr/bin/env bash
# Makes liver_20k.msh from liver2.obj (scenes/meshes/README.md): writes the OBJ's triangles as
# an ASCII STL in a temporary folder and meshes it with liver_20k.geo. Needs gmsh (4.8.4 made
# the committed file: apt-get install gmsh).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
awk '/^v /{n++; x[n]=$2; y[n]=$3; z[n]=$4}
     /^f /{print " facet normal 0 0 0\n  outer loop"
           for (i = 2; i <= 4; i++) { split($i, a, "/"); k = a[1]
             print "   vertex " x[k] " " y[k] " " z[k] }
           print "  endloop\n endfacet"}
     BEGIN{print "solid liver2"} END{print "endsolid liver2"}' "$here/liver2.obj" > "$tmp/liver2.stl"
cp "$here/liver_20k.geo" "$tmp/"
gmsh "$tmp/liver_20k.geo" -3 -o "${1:-$here/liver_20k.msh}" > "$tmp/gmsh.log" || { cat "$tmp/gmsh.log"; exit 1; }
grep -E "^(Warning|Error)" "$tmp/gmsh.log" || true
