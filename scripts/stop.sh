#!/usr/bin/env bash
# Stops a pair started by scripts/start.sh (the latest run, or the run directory given). A pid
# file is trusted only while it names a running sim_server or haptic_server: a stale one (its
# process gone, its pid reused by another program) is removed and nothing is killed.
#
# Usage: scripts/stop.sh [RUN_DIR]
#
# Example:
#   scripts/stop.sh run/latest
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [[ "${1:-}" == "-h" || "${1:-}" == "--help" ]]; then sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0; fi
run_dir="${1:-$root/run/latest}"
[[ -d "$run_dir" ]] || { echo "stop.sh: no run directory $run_dir" >&2; exit 1; }
stopped=0
for name in haptic sim; do
  f="$run_dir/$name.pid"
  [[ -f "$f" ]] || continue
  pid=$(cat "$f")
  expected="${name}_server"
  if ! [[ "$pid" =~ ^[1-9][0-9]*$ ]]; then
    echo "stop.sh: $f does not hold a pid: removed, nothing stopped" >&2
    rm -f "$f"
    continue
  fi
  # the program the pid runs now (its executable's name; empty when the process is gone)
  running="$(readlink "/proc/$pid/exe" 2>/dev/null || true)"
  running="${running% (deleted)}"   # the binary was rebuilt while it ran
  running="${running##*/}"
  if [[ "$running" != "$expected" ]]; then
    if [[ -z "$running" ]]; then
      echo "stop.sh: $f names pid $pid, which is not running: removed" >&2
    else
      echo "stop.sh: $f names pid $pid, which runs '$running', not $expected (a stale pid" \
           "file): removed, nothing killed" >&2
    fi
    rm -f "$f"
    continue
  fi
  if kill -TERM "$pid" 2>/dev/null; then
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
    echo "stopped $expected (pid $pid)"
    stopped=1
  fi
  rm -f "$f"
done
[[ $stopped -eq 1 ]] || echo "stop.sh: nothing running in $run_dir"
