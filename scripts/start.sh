#!/usr/bin/env bash
# The main job: builds if needed, then starts sim_server and haptic_server on a scene (default:
# the paper's liver grasp) with a device backend (default: the simulated hand), prints a status
# line every second, and stops both cleanly on Ctrl-C or at the end of --duration.
#
# Usage: scripts/start.sh [SCENE.yaml] [--device NAME|PATH.so] [--device-option k=v]...
#                         [--duration S] [--segment NAME] [--run-dir DIR] [--no-haptic]
#                         [--core N] [--rate HZ] [--view [--view-port N]]
#        --view: also serve the live view in a browser (scripts/view; http://127.0.0.1:8090/)
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
rate=1000
view=0
view_port=8090
usage() { sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; }
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
    -*) echo "start.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) scene="$1"; shift ;;
  esac
done
[[ -f "$scene" ]] || { echo "start.sh: no scene file '$scene'" >&2; exit 2; }
scene="$(cd "$(dirname "$scene")" && pwd)/$(basename "$scene")"

"$root/scripts/build.sh" sim_server haptic_server tactus-monitor >/dev/null

if [[ -z "$run_dir" ]]; then
  run_dir="$root/run/$(date +%Y%m%d-%H%M%S)"
fi
mkdir -p "$run_dir"
ln -sfn "$run_dir" "$root/run/latest" 2>/dev/null || true
echo "tactus: scene $scene, device $device, segment '$segment', logs in $run_dir"

sim_pid=""; haptic_pid=""; monitor_pid=""; view_pid=""
stop_all() {
  trap - INT TERM EXIT
  [[ -n "$monitor_pid" ]] && kill "$monitor_pid" 2>/dev/null || true
  [[ -n "$view_pid" ]] && kill "$view_pid" 2>/dev/null || true
  for pid in $haptic_pid $sim_pid; do kill -TERM "$pid" 2>/dev/null || true; done
  for pid in $haptic_pid $sim_pid; do
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  done
  wait 2>/dev/null || true
  rm -f "$run_dir"/*.pid
  echo
  echo "=== summary (logs: $run_dir) ==="
  sed -n '/stage \[ms\]/,$p' "$run_dir/sim.log" 2>/dev/null || tail -5 "$run_dir/sim.log"
  [[ $haptic -eq 1 ]] && grep -E "stopping|Hz" "$run_dir/haptic.log" | tail -2 || true
}
trap stop_all INT TERM EXIT

sim_args=("$scene" --segment "$segment")
[[ "$duration" != "0" ]] && sim_args+=(--duration "$duration")
"$build/sim_server/sim_server" "${sim_args[@]}" >"$run_dir/sim.log" 2>&1 &
sim_pid=$!
echo "$sim_pid" >"$run_dir/sim.pid"

if [[ $haptic -eq 1 ]]; then
  if [[ "$device" == "simulated" && ${#device_opts[@]} -eq 0 ]]; then
    # the simulated hand follows the scene's scripted trajectory
    "$build/sim_server/sim_server" "$scene" --export-trajectory "$run_dir/trajectory.csv" \
      >>"$run_dir/sim_export.log" 2>&1 &&
      device_opts=(--device-option "trajectory=$run_dir/trajectory.csv" --device-option loop=true)
  fi
  "$build/haptic_server/haptic_server" --segment "$segment" --device "$device" \
    "${device_opts[@]}" --core "$core" --rate "$rate" >"$run_dir/haptic.log" 2>&1 &
  haptic_pid=$!
  echo "$haptic_pid" >"$run_dir/haptic.pid"
fi

if [[ $view -eq 1 ]]; then
  "$root/scripts/view" --segment "$segment" --port "$view_port" >"$run_dir/view.log" 2>&1 &
  view_pid=$!
  echo "tactus: live view at http://127.0.0.1:$view_port/ (log: $run_dir/view.log)"
fi

mon_args=(--segment "$segment")
"$build/haptic_server/tactus-monitor" "${mon_args[@]}" &
monitor_pid=$!

start=$(date +%s)
while kill -0 "$sim_pid" 2>/dev/null; do
  if [[ "$duration" != "0" ]] && (( $(date +%s) - start >= ${duration%.*} + 1 )); then break; fi
  if [[ $haptic -eq 1 ]] && ! kill -0 "$haptic_pid" 2>/dev/null; then
    echo "tactus: haptic_server exited; see $run_dir/haptic.log" >&2; break
  fi
  sleep 0.5
done
if ! kill -0 "$sim_pid" 2>/dev/null; then
  wait "$sim_pid" && rc=0 || rc=$?
  [[ $rc -ne 0 ]] && { echo "tactus: sim_server exited with $rc; see $run_dir/sim.log" >&2; tail -3 "$run_dir/sim.log" >&2; }
fi
