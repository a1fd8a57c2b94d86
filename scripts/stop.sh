#!/usr/bin/env bash
# Stops a pair started by scripts/start.sh (the latest run, or the run directory given).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
run_dir="${1:-$root/run/latest}"
[[ -d "$run_dir" ]] || { echo "stop.sh: no run directory $run_dir" >&2; exit 1; }
stopped=0
for name in haptic sim; do
  f="$run_dir/$name.pid"
  [[ -f "$f" ]] || continue
  pid=$(cat "$f")
  if kill -TERM "$pid" 2>/dev/null; then
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
    echo "stopped ${name}_server (pid $pid)"
    stopped=1
  fi
  rm -f "$f"
done
[[ $stopped -eq 1 ]] || echo "stop.sh: nothing running in $run_dir"
