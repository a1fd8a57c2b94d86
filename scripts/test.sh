#!/usr/bin/env bash
# The test command: installs missing packages, builds everything (Release) and runs ctest.
# Usage: scripts/test.sh [extra ctest arguments, e.g. -L unit or -R nsgs]
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/env.sh"
build="${TACTUS_BUILD_DIR:-$root/build}"
"$root/scripts/build.sh"
cd "$build"
# Tests that own a core or spawn daemons are RUN_SERIAL; the rest run two at a time.
ctest --output-on-failure -j "${TACTUS_TEST_JOBS:-2}" --timeout 900 "$@"
