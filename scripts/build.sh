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
# One job per usable core. GNU nproc honours OMP_NUM_THREADS, which scripts/env.sh sets to 1 for
# the solvers' determinism: without the env -u the build would run one job on any machine.
jobs="${TACTUS_JOBS:-$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)}"
ninja -C "$build" -j "$jobs" "$@"
