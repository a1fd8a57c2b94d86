#!/usr/bin/env bash
# Fuzzes the Tactus parsers with libFuzzer (clang, ASan + UBSan) for a bounded time each:
#   mesh (parseTetMesh), scene (parseScene), trajectory (replay CSV), fclib (FCLIB text),
#   compliance_cache (compliance C0 cache loader, through makeCompliance).
# Harnesses: tests/fuzz/*_fuzz.cpp; seeds: tests/fuzz/corpus/<parser>/; build dir: build-fuzz/.
# A crashing input (crash-*, leak-*, oom-*, timeout-*) is copied to
# tests/data/fuzz_regressions/<parser>/, where the normal test suite replays it
# (tests/unit/<module>/*_fuzz_regression_test.cpp). Exit status 1 when anything was found.
#
# Usage: scripts/fuzz.sh [--seconds N] [--only PARSER[,PARSER...]] [--no-build]
#   --seconds N   time per harness (libFuzzer -max_total_time), default 60
#   --only LIST   run only these harnesses (default: all five)
#   --no-build    reuse build-fuzz as it is
# Single process per harness (-jobs not used): the machine has 2 shared cores.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="$root/build-fuzz"
seconds=60
only=""
do_build=1
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --only) only="$2"; shift 2 ;;
    --no-build) do_build=0; shift ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    *) echo "fuzz.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
if ! [[ "$seconds" =~ ^[0-9]+$ && "$seconds" -gt 0 ]]; then
  echo "fuzz.sh: --seconds needs a positive integer" >&2
  exit 2
fi

parsers=(mesh scene trajectory fclib compliance_cache bridge)
if [[ -n "$only" ]]; then IFS=, read -r -a parsers <<< "$only"; fi

# clang and the compiler-rt runtime (libFuzzer, sanitizers); only needed here, so not in
# install_deps.sh
need=()
command -v clang++ >/dev/null 2>&1 || need+=(clang)
dpkg-query -W -f='${Status}' libclang-rt-14-dev 2>/dev/null | grep -q "install ok installed" ||
  need+=(libclang-rt-14-dev)
if [[ ${#need[@]} -gt 0 ]]; then
  echo "fuzz.sh: installing ${need[*]}"
  sudo=""; [[ $(id -u) -ne 0 ]] && sudo="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq >/dev/null
  $sudo apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

if [[ $do_build -eq 1 ]]; then
  # libraries instrumented for coverage (fuzzer-no-link) and sanitizers; -O1 without NDEBUG so
  # that assertions (Eigen's index checks among them) stay on
  CC=clang CXX=clang++ cmake -S "$root" -B "$build" -G Ninja \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g" \
    -DCMAKE_CXX_FLAGS="-fno-sanitize-recover=undefined" \
    -DTACTUS_SANITIZE="address;undefined;fuzzer-no-link" \
    -DTACTUS_FUZZ=ON -DTACTUS_BUILD_TESTS=OFF -DTACTUS_BUILD_BENCHMARKS=OFF >/dev/null
  targets=()
  for p in "${parsers[@]}"; do targets+=("${p}_fuzz"); done
  ninja -C "$build" -j2 "${targets[@]}"
fi

export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
found=0
summary=()
for p in "${parsers[@]}"; do
  bin="$build/tests/fuzz/${p}_fuzz"
  [[ -x "$bin" ]] || { echo "fuzz.sh: $bin not built" >&2; exit 2; }
  seeds="$root/tests/fuzz/corpus/$p"
  work="$build/fuzz-corpus/$p"
  artifacts="$build/fuzz-artifacts/$p"
  log="$build/fuzz-logs/$p.log"
  mkdir -p "$work" "$artifacts" "$(dirname "$log")"
  rm -f "$artifacts"/*
  if [[ "$p" == compliance_cache ]]; then
    # the valid cache files of this build (the hash depends on the FEM code) as extra seeds
    TACTUS_FUZZ_WRITE_SEEDS="$work" "$bin" -runs=0 "$seeds" >/dev/null 2>&1 || true
  fi
  dict=()
  [[ -f "$root/tests/fuzz/$p.dict" ]] && dict=(-dict="$root/tests/fuzz/$p.dict")
  echo "fuzz.sh: $p for ${seconds}s (log: $log)"
  set +e
  "$bin" "$work" "$seeds" "${dict[@]}" -max_total_time="$seconds" -timeout=10 \
    -rss_limit_mb=2048 -max_len=16384 -print_final_stats=1 \
    -artifact_prefix="$artifacts/" >"$log" 2>&1
  rc=$?
  set -e
  runs=$(grep -Eo 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -Eo '[0-9]+$' |
         tail -1 || true)
  [[ -z "$runs" ]] && runs=$(grep -Eo '^#[0-9]+' "$log" | tail -1 | tr -d '#' || true)
  crashes=("$artifacts"/*)
  if [[ -e "${crashes[0]}" ]]; then
    dest="$root/tests/data/fuzz_regressions/$p"
    mkdir -p "$dest"
    for c in "${crashes[@]}"; do
      cp "$c" "$dest/"
      echo "fuzz.sh: $p: FOUND $(basename "$c") -> tests/data/fuzz_regressions/$p/"
    done
    grep -E 'ERROR: |SUMMARY: |terminate called|what\(\)' "$log" | head -8 |
      sed "s/^/  $p: /" || true
    found=1
    summary+=("$p: ${runs:-?} executions, FOUND ${#crashes[@]} (rc $rc)")
  elif [[ $rc -ne 0 ]]; then
    tail -20 "$log" | sed "s/^/  $p: /"
    found=1
    summary+=("$p: ${runs:-?} executions, libFuzzer exited $rc without an artifact")
  else
    summary+=("$p: ${runs:-?} executions, nothing found")
  fi
done
echo "fuzz.sh: summary (${seconds}s each)"
printf '  %s\n' "${summary[@]}"
exit $found
