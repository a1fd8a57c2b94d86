#!/usr/bin/env bash
# The main job: builds if needed, then starts sim_server and haptic_server on a scene (default:
# the paper's liver grasp) with a device backend (default: the simulated hand), prints a status
# line every second, and stops both cleanly on Ctrl-C, SIGTERM, SIGHUP (terminal closed) or at
# the end of --duration S (0, the default: until stopped).
#
# A scene with several instruments (scenes/liver_bimanual.yaml) gets one simulated hand each.
# Usage: scripts/start.sh [SCENE.yaml] [--device NAME|PATH.so] [--device-option [I:]k=v]...
#                         [--duration S] [--segment NAME] [--run-dir DIR] [--no-haptic]
#                         [--core N] [--rate HZ] [--view [--view-port N]] [--no-build]
#        --rate: the haptic loop's rate (default: the scene's haptics.rate, else 1000 Hz)
#        --view: also serve the live view in a browser (scripts/view; http://127.0.0.1:8090/)
#        --run-dir: logs there (default run/<date-time>, which run/latest then points to)
#        --no-build: use the binaries already built. Exit status: 0 after a clean run or stop,
#        else the failing daemon's (sim_server's, or haptic_server's when it stopped early).
#
# Examples:
#   scripts/start.sh
#   scripts/start.sh scenes/liver_bimanual.yaml --duration 10 --view
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$root/scripts/env.sh"
build="${TACTUS_BUILD_DIR:-$root/build}"
scene="$root/scenes/liver_grasp.yaml"
device="simulated"
device_opts=()
duration=0
segment="tactus"
run_dir=""
haptic=1
core=-1
rate=""
view=0
view_port=8090
build_first=1
usage() { sed -n '2,19p' "$0" | sed 's/^# \{0,1\}//'; }
while [[ $# -gt 0 ]]; do
  case "$1" in
    -h|--help) usage; exit 0 ;;
    --device) device="$2"; shift 2 ;;
    --device-option) device_opts+=(--device-option "$2"); shift 2 ;;
    --duration) duration="$2"; shift 2 ;;
    --segment) segment="$2"; shift 2 ;;
    --run-dir) run_dir="$2"; shift 2 ;;
    --no-haptic) haptic=0; shift ;;
    --core) core="$2"; shift 2 ;;
    --rate) rate="$2"; shift 2 ;;
    --view) view=1; shift ;;
    --view-port) view_port="$2"; shift 2 ;;
    --no-build) build_first=0; shift ;;
    -*) echo "start.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) scene="$1"; shift ;;
  esac
done
[[ -f "$scene" ]] || { echo "start.sh: no scene file '$scene'" >&2; exit 2; }
scene="$(cd "$(dirname "$scene")" && pwd)/$(basename "$scene")"
[[ "$duration" =~ ^[0-9]+(\.[0-9]+)?$ ]] ||
  { echo "start.sh: --duration must be a number of seconds >= 0 (got '$duration')" >&2; exit 2; }
[[ "$duration" =~ ^0+(\.0*)?$ ]] && duration=0  # 0, 0.0, ...: until stopped

if [[ $build_first -eq 1 ]]; then
  "$root/scripts/build.sh" sim_server haptic_server tactus-monitor >/dev/null
fi

if [[ -z "$run_dir" ]]; then
  run_dir="$root/run/$(date +%Y%m%d-%H%M%S)"
  mkdir -p "$run_dir"
  # only the default run dir is "the latest run" of this checkout
  ln -sfn "$run_dir" "$root/run/latest" 2>/dev/null || true
fi
mkdir -p "$run_dir"
echo "tactus: scene $scene, device $device, segment '$segment', logs in $run_dir"

sim_pid=""; haptic_pid=""; monitor_pid=""; view_pid=""
sim_rc=0; haptic_rc=0; stopped_rc=0; stopped=0; interrupted=0
# Stops PID (SIGTERM, SIGKILL after 5 s); its exit status goes into stopped_rc (not a subshell:
# only this shell can wait for its children).
stop_pid() {
  local pid="$1"
  kill -TERM "$pid" 2>/dev/null || true
  for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
  kill -KILL "$pid" 2>/dev/null || true
  stopped_rc=0
  wait "$pid" 2>/dev/null || stopped_rc=$?
}
stop_all() {
  [[ $stopped -eq 1 ]] && return 0
  stopped=1
  [[ -n "$monitor_pid" ]] && kill "$monitor_pid" 2>/dev/null || true
  [[ -n "$view_pid" ]] && kill "$view_pid" 2>/dev/null || true
  if [[ -n "$haptic_pid" ]]; then stop_pid "$haptic_pid"; haptic_rc=$stopped_rc; fi
  if [[ -n "$sim_pid" ]]; then stop_pid "$sim_pid"; sim_rc=$stopped_rc; fi
  wait 2>/dev/null || true
  rm -f "$run_dir"/*.pid
  echo
  echo "=== summary (logs: $run_dir) ==="
  sed -n '/stage \[ms\]/,$p' "$run_dir/sim.log" 2>/dev/null || tail -5 "$run_dir/sim.log"
  [[ $haptic -eq 1 ]] && grep -E "stopping|Hz" "$run_dir/haptic.log" | tail -2 || true
}
# Ctrl-C, SIGTERM and SIGHUP end the wait below; the daemons are then stopped cleanly
trap 'interrupted=1' INT TERM HUP
trap stop_all EXIT

sim_args=("$scene" --segment "$segment")
[[ "$duration" != "0" ]] && sim_args+=(--duration "$duration")
"$build/sim_server/sim_server" "${sim_args[@]}" >"$run_dir/sim.log" 2>&1 &
sim_pid=$!
echo "$sim_pid" >"$run_dir/sim.pid"

if [[ $haptic -eq 1 ]]; then
  device_args=(--device "$device")
  if [[ "$device" == "simulated" && ${#device_opts[@]} -eq 0 ]]; then
    # one simulated hand per instrument, each following its instrument's scripted trajectory
    # (trajectory.csv for instrument 0, trajectoryI.csv for instrument I)
    instruments=$("$build/sim_server/sim_server" "$scene" --print-instrument-count \
      2>>"$run_dir/sim_export.log" || echo 1)
    [[ "$instruments" =~ ^[1-9]$ ]] || instruments=1
    for ((i = 0; i < instruments; i++)); do
      csv="$run_dir/trajectory.csv"
      if (( i > 0 )); then
        csv="$run_dir/trajectory$i.csv"
        device_args+=(--device simulated)
      fi
      "$build/sim_server/sim_server" "$scene" --overwrite --export-trajectory "$csv" \
        --export-instrument "$i" >>"$run_dir/sim_export.log" 2>&1 &&
        device_opts+=(--device-option "$i:trajectory=$csv" --device-option "$i:loop=true")
    done
  fi
  # the scene's haptics section as haptic_server options (rate, force clamp and scale, watchdog,
  # sweep budget, tolerance, workspace mapping); --rate on this command line wins over the scene's
  scene_haptic_opts=()
  mapfile -t scene_haptic_opts < <("$build/sim_server/sim_server" "$scene" --print-haptic-options \
    2>>"$run_dir/sim_export.log" || true)
  rate_opts=()
  if [[ -n "$rate" ]]; then
    rate_opts=(--rate "$rate")
    kept=()
    for o in "${scene_haptic_opts[@]}"; do [[ "$o" == --rate=* ]] || kept+=("$o"); done
    scene_haptic_opts=("${kept[@]}")
  fi
  # haptics.workspaces entries past the devices started (one --device given for a scene of
  # several instruments) have no device to map: drop them rather than have haptic_server refuse
  devices=$(( ${#device_args[@]} / 2 ))
  kept=()
  for o in "${scene_haptic_opts[@]}"; do
    if [[ "$o" =~ ^--workspace-option=([0-9]+): ]] && (( BASH_REMATCH[1] >= devices )); then
      continue
    fi
    kept+=("$o")
  done
  scene_haptic_opts=("${kept[@]}")
  "$build/haptic_server/haptic_server" --segment "$segment" "${device_args[@]}" \
    "${device_opts[@]}" "${scene_haptic_opts[@]}" "${rate_opts[@]}" --core "$core" \
    >"$run_dir/haptic.log" 2>&1 &
  haptic_pid=$!
  echo "$haptic_pid" >"$run_dir/haptic.pid"
fi

if [[ $view -eq 1 ]]; then
  "$root/scripts/view" --segment "$segment" --port "$view_port" >"$run_dir/view.log" 2>&1 &
  view_pid=$!
  echo "tactus: live view at http://127.0.0.1:$view_port/ (log: $run_dir/view.log)"
fi

mon_args=(--segment "$segment")
"$build/tools/monitor/tactus-monitor" "${mon_args[@]}" --wait 600 &
monitor_pid=$!

start=$(date +%s)
haptic_early=0
while [[ $interrupted -eq 0 ]] && kill -0 "$sim_pid" 2>/dev/null; do
  if [[ "$duration" != "0" ]] && (( $(date +%s) - start >= ${duration%.*} + 1 )); then break; fi
  if [[ $haptic -eq 1 ]] && ! kill -0 "$haptic_pid" 2>/dev/null; then
    echo "tactus: haptic_server exited; see $run_dir/haptic.log" >&2
    haptic_early=1
    break
  fi
  sleep 0.5
done
stop_all
rc=$sim_rc
if [[ $rc -ne 0 ]]; then
  echo "tactus: sim_server exited with $rc; see $run_dir/sim.log" >&2
  tail -3 "$run_dir/sim.log" >&2
elif [[ $haptic_early -eq 1 ]]; then
  # haptic_server never stops by itself in a good run
  rc=$haptic_rc
  [[ $rc -eq 0 ]] && rc=1
  echo "tactus: haptic_server exited with $haptic_rc" >&2
  tail -3 "$run_dir/haptic.log" >&2
fi
exit "$rc"
