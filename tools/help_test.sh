#!/usr/bin/env bash
# Every tool's --help exits 0 and ends with an example: a line "Example:" or "Examples:" followed
# only by lines that run the tool (two spaces, then its name).
# Usage: help_test.sh TOOL_BINARY...
set -uo pipefail
failures=0
for tool in "$@"; do
  name="$(basename "$tool")"
  if ! out="$("$tool" --help 2>&1)"; then
    echo "FAIL $name: --help exited non-zero"; failures=$((failures + 1)); continue
  fi
  tail_lines="$(printf '%s\n' "$out" | sed -e '/^[[:space:]]*$/d' |
                awk '/^Examples?( \(.*\))?:$/ {buf=""; seen=1; next} seen {buf = buf $0 "\n"} END {printf "%s", buf}')"
  if [[ -z "$tail_lines" ]] || printf '%s' "$tail_lines" | grep -qv "^  $name "; then
    echo "FAIL $name: --help does not end with an example"; failures=$((failures + 1))
  else
    echo "ok   $name"
  fi
done
exit $((failures > 0))
