#!/usr/bin/env bash
# scripts/start.sh exit status and run dir: 0 after a clean --duration run, non-zero for a bad
# scene and for a missing device plugin; an explicit --run-dir leaves the checkout's run/latest
# alone; no segment is left behind; the scene's haptics clamp and rate reach haptic_server and
# --rate overrides the rate; haptics.workspaces reaches each device; stop.sh never kills what a
# stale pid file names. Uses the built binaries (--no-build), a temp run dir and
# unique segment names; every run is bounded by `timeout`.
#
# Usage: start_script_test.sh SOURCE_DIR BUILD_DIR
set -uo pipefail
src="$1"
build="$2"
tmp="$(mktemp -d)"
seg="tactus_sec_start_$$"
cleanup() {
  rm -rf "$tmp"
  rm -f /dev/shm/"$seg"_*
}
trap cleanup EXIT
failures=0
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }

latest_before="$(readlink "$src/run/latest" 2>/dev/null || echo "(none)")"

# start.sh NAME ARGS...: runs start.sh with its log in $tmp/NAME.out; sets rc
run() {
  local name="$1"
  shift
  TACTUS_BUILD_DIR="$build" TACTUS_SKIP_DEPS=1 timeout -k 5 90 \
    bash "$src/scripts/start.sh" "$@" --no-build --run-dir "$tmp/$name" --segment "${seg}_$name" \
    >"$tmp/$name.out" 2>&1 </dev/null
  rc=$?
  echo "start.sh $name: exit $rc"
}

scene="$src/tests/data/scenes/press_cube.yaml"
run clean "$scene" --duration 3
[[ $rc -eq 0 ]] || { fail "clean --duration 3 run exited $rc"; tail -20 "$tmp/clean.out" >&2; }
[[ -s "$tmp/clean/sim.log" ]] || fail "no sim.log in the --run-dir"

printf 'scene: [unterminated\n' >"$tmp/bad.yaml"
run bad_scene "$tmp/bad.yaml" --duration 3
[[ $rc -ne 0 && $rc -ne 124 && $rc -ne 137 ]] || fail "bad scene: exit $rc (want a failure status)"

run no_plugin "$scene" --duration 3 --device "$tmp/no_such_plugin.so"
[[ $rc -ne 0 && $rc -ne 124 && $rc -ne 137 ]] || fail "missing plugin: exit $rc (want a failure)"
grep -q "haptic_server exited" "$tmp/no_plugin.out" || fail "missing plugin: no message"

# the scene's haptics section reaches haptic_server (clamp, rate), and --rate on the command line
# wins over the scene's rate. The copy sits beside the original so its relative mesh path holds.
limits_scene="$src/tests/data/scenes/.start_test_limits_$$.yaml"
trap 'cleanup; rm -f "$limits_scene"' EXIT
sed 's/^haptics: .*$/haptics: {enabled: true, watchdog_ms: 50, rate: 500, max_force: 2.5}/' \
  "$scene" >"$limits_scene"
grep -q 'max_force: 2.5' "$limits_scene" || fail "could not write the limits scene"
run limits "$limits_scene" --duration 2
[[ $rc -eq 0 ]] || fail "limits scene: exit $rc"
grep -q "max force 2.5 N, loop 500 Hz" "$tmp/limits/haptic.log" ||
  { fail "the scene's max_force/rate did not reach haptic_server"; tail -5 "$tmp/limits/haptic.log" >&2; }
run limits_rate "$limits_scene" --duration 2 --rate 800
grep -q "max force 2.5 N, loop 800 Hz" "$tmp/limits_rate/haptic.log" ||
  { fail "--rate 800 did not win over the scene's rate"; tail -5 "$tmp/limits_rate/haptic.log" >&2; }
rm -f "$limits_scene"

# haptics.workspaces reaches each device (one simulated hand per instrument), and entries past the
# devices started (one --device for two instruments) are dropped instead of refused
ws_scene="$src/tests/data/scenes/.start_test_workspaces_$$.yaml"
trap 'cleanup; rm -f "$ws_scene"' EXIT
sed 's/^haptics: .*$/haptics: {watchdog_ms: 50, workspaces: [{}, {scale: 2, rotation_deg: [0, 0, 90]}]}/' \
  "$src/tests/data/scenes/press_cube_bimanual.yaml" >"$ws_scene"
grep -q 'workspaces:' "$ws_scene" || fail "could not write the workspaces scene"
run workspaces "$ws_scene" --duration 2
[[ $rc -eq 0 ]] || fail "workspaces scene: exit $rc"
grep -q "device 1 workspace: scale 2, offset (0, 0, 0) m, rotation (0.707" \
  "$tmp/workspaces/haptic.log" ||
  { fail "haptics.workspaces did not reach device 1"; tail -5 "$tmp/workspaces/haptic.log" >&2; }
run workspaces_one "$ws_scene" --duration 2 --device null
[[ $rc -eq 0 ]] || { fail "workspaces scene, one device: exit $rc"; tail -5 "$tmp/workspaces_one/haptic.log" >&2; }
grep -q "device 0 workspace: scale 1" "$tmp/workspaces_one/haptic.log" ||
  fail "workspaces scene, one device: device 0's mapping not logged"
# instrument 1's script is exported through its own entry's inverse: R^T p / 2 = (y, -x, z) / 2
"$build/sim_server/sim_server" "$src/tests/data/scenes/press_cube_bimanual.yaml" \
  --export-trajectory "$tmp/plain1.csv" --export-instrument 1 >/dev/null 2>&1
"$build/sim_server/sim_server" "$ws_scene" --export-trajectory "$tmp/mapped1.csv" \
  --export-instrument 1 >/dev/null 2>&1
paste -d, <(sed -n 2p "$tmp/plain1.csv") <(sed -n 2p "$tmp/mapped1.csv") | awk -F, '
  function off(a, b) { d = a - b; return d < 0 ? -d : d }
  { if (NF != 18 || $2 == 0 || off($11, $3 / 2) > 1e-8 || off($12, -$2 / 2) > 1e-8 ||
        off($13, $4 / 2) > 1e-8) exit 1 }' ||
  fail "instrument 1's exported script is not mapped through haptics.workspaces[1]: $(sed -n 2p "$tmp/plain1.csv") / $(sed -n 2p "$tmp/mapped1.csv")"
rm -f "$ws_scene"

run bad_duration "$scene" --duration nan
[[ $rc -eq 2 ]] || fail "--duration nan: exit $rc (want 2)"

# stop.sh and a stale pid file: the pid now names another program, which must survive
mkdir -p "$tmp/stale"
sleep 300 &
sleeper=$!
echo "$sleeper" >"$tmp/stale/sim.pid"
echo "junk" >"$tmp/stale/haptic.pid"
bash "$src/scripts/stop.sh" "$tmp/stale" >"$tmp/stale.out" 2>&1
kill -0 "$sleeper" 2>/dev/null || fail "stop.sh killed the program a stale pid file named"
grep -q "not sim_server" "$tmp/stale.out" || fail "stop.sh: no word on the stale pid file"
grep -q "stopped sim_server" "$tmp/stale.out" && fail "stop.sh reported stopping a sim_server"
[[ -e "$tmp/stale/sim.pid" ]] && fail "stop.sh kept the stale pid file"
kill "$sleeper" 2>/dev/null; wait "$sleeper" 2>/dev/null

latest_after="$(readlink "$src/run/latest" 2>/dev/null || echo "(none)")"
[[ "$latest_before" == "$latest_after" ]] ||
  fail "run/latest was repointed by a --run-dir run: '$latest_before' -> '$latest_after'"
for f in /dev/shm/"$seg"_*; do
  [[ -e "$f" ]] && fail "segment left behind: $f"
done

if [[ $failures -gt 0 ]]; then
  echo "start_script_test: $failures failure(s)"
  exit 1
fi
echo "start_script_test: PASS"
