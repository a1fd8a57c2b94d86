#!/usr/bin/env bash
# Rebuilds liver_23k_repaired.msh from liver_23k.msh (scenes/meshes/README.md): peels the thin
# surface caps, then improves the tets with TetGen keeping the surface (apt-get install tetgen).
# Writes into a temporary folder and refuses to replace an existing output.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
out="${1:-$here/liver_23k_repaired.msh}"
[[ -e "$out" ]] && { echo "$out exists; pass another path or remove it" >&2; exit 1; }
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
python3 "$here/peel_caps.py" "$here/liver_23k.msh" "$tmp/peeled.msh"
python3 "$here/tetgen_msh.py" to-tetgen "$tmp/peeled.msh" "$tmp/peeled"
tetgen -rq2.0/8 -O9/7 -Y "$tmp/peeled" > "$tmp/tetgen.log"
python3 "$here/tetgen_msh.py" from-tetgen "$tmp/peeled.1" "$out"
echo "wrote $out"
