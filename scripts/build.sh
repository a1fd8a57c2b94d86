#!/usr/bin/env bash
# Configures and builds Tactus (Release) into build/ (or $TACTUS_BUILD_DIR). Extra arguments are
# ninja targets; none builds everything. Installs missing Debian packages first.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${TACTUS_BUILD_DIR:-$root/build}"
"$root/scripts/install_deps.sh"
if [[ ! -f "$build/build.ninja" ]]; then
  cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release ${TACTUS_CMAKE_ARGS:-} >/dev/null
fi
jobs="${TACTUS_JOBS:-$(nproc)}"
ninja -C "$build" -j "$jobs" "$@"
