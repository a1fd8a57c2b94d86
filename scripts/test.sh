#!/usr/bin/env bash
# The test command: installs missing packages, builds everything (Release) and runs ctest.
# Usage: scripts/test.sh [extra ctest arguments, e.g. -L unit or -R nsgs]
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/env.sh"
build="${TACTUS_BUILD_DIR:-$root/build}"
"$root/scripts/build.sh"
cd "$build"
# ctest schedules by cores (tests/CMakeLists.txt, TACTUS_TEST_ON_A_CORE): a resource "cores"
# with one slot per usable core (env -u: scripts/env.sh sets OMP_NUM_THREADS=1, which GNU nproc
# honours), held by every test that computes, and twice as many jobs, so that the tests that
# wait on their daemons run beside them. RUN_SERIAL tests (they act at fixed times) run alone.
cores="${TACTUS_TEST_CORES:-$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)}"
((cores >= 2)) || cores=2   # the live view's test holds two slots
printf '{"version": {"major": 1, "minor": 0}, "local": [{"cores": [{"id": "0", "slots": %d}]}]}\n' \
  "$cores" > ctest_resources.json
ctest --output-on-failure --resource-spec-file ctest_resources.json \
  -j "${TACTUS_TEST_JOBS:-$((2 * cores))}" --timeout 900 "$@"
