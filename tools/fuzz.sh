#!/usr/bin/env bash
# Fuzzing (issue 24): the libFuzzer targets of fuzz/ under AddressSanitizer and
# UndefinedBehaviorSanitizer (LeakSanitizer with them), built with clang in build-fuzz/.
#
#   tools/fuzz.sh [--target codec|apply|scene|restore|all] [--runs N] [--jobs J] [--seconds S]
#                 [--build DIR] [--keep DIR]
#
#   --target   which target (default all, one after the other)
#   --runs     inputs per target (default 100000); with --jobs J, N/J per job
#   --jobs     fuzzing processes per target (default 1; libFuzzer -jobs/-workers)
#   --seconds  also stop each target after S seconds (libFuzzer -max_total_time)
#   --build    the clang build directory (default build-fuzz; configured and built if needed)
#   --keep     also start from DIR/<target>/ when it exists, and copy each target's grown
#              corpus there at the end (the scratch copy is deleted either way)
#
# Each target starts from a scratch copy of fuzz/corpus/<target>/ under /tmp (the inputs it
# finds go there, never into the repository), with fuzz/<target>.dict when present,
# -rss_limit_mb=2048 -timeout=10 (30 for restore). A crash, sanitizer report, leak, timeout or out-of-memory
# is written to fuzz/crashes/<target>-* and makes the script exit non-zero. Leaks are
# detected (LeakSanitizer runs with ASan under libFuzzer). A finding's reproducer:
#   build-fuzz/fuzz/fuzz_<target> fuzz/crashes/<target>-crash-...     (runs it once)
#   build-fuzz/fuzz/fuzz_<target> -minimize_crash=1 -runs=100000 fuzz/crashes/<file>
# Once fixed, keep it as fuzz/corpus/<target>/regression-<what> (ctest's fuzz.<target>
# replays it in every test build).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
target=all runs=100000 jobs=1 seconds=0 build="$root/build-fuzz" keep=""
usage() {
  echo "usage: $0 [--target codec|apply|scene|restore|all] [--runs N] [--jobs J] [--seconds S] [--build DIR] [--keep DIR]" >&2
  exit 2
}
while [[ $# -gt 0 ]]; do
  case "$1" in
    --target) target="$2"; shift 2 ;;
    --runs) runs="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --keep) keep="$2"; shift 2 ;;
    *) usage ;;
  esac
done
case "$target" in
  all) targets="codec apply scene restore" ;;
  codec|apply|scene|restore) targets="$target" ;;
  *) usage ;;
esac
[[ "$runs" =~ ^[0-9]+$ && "$jobs" =~ ^[1-9][0-9]*$ && "$seconds" =~ ^[0-9]+$ ]] || usage

# --- Build (clang, libFuzzer, ASan + UBSan over every library the targets link) ---
cc="${FUZZ_CC:-clang-14}" cxx="${FUZZ_CXX:-clang++-14}"
if ! grep -q "^PHYS_FUZZ:BOOL=ON" "$build/CMakeCache.txt" 2>/dev/null; then
  command -v "$cxx" > /dev/null || { echo "fuzz.sh: $cxx not found (apt-get install clang-14 libclang-rt-14-dev)" >&2; exit 1; }
  # The GPU backend, the peer engines, the tools and the test suites are not needed by the
  # targets; UBSan aborts at the first report (-fno-sanitize-recover) so libFuzzer keeps it.
  CC="$cc" CXX="$cxx" cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPHYS_FUZZ=ON -DPHYS_SANITIZE="address;undefined;fuzzer-no-link" \
    -DCMAKE_C_FLAGS="-fno-sanitize-recover=undefined" \
    -DCMAKE_CXX_FLAGS="-fno-sanitize-recover=undefined" \
    -DPHYS_WITH_GPU=OFF -DPHYS_WITH_PEERS=OFF -DPHYS_BUILD_TOOLS=OFF -DPHYS_BUILD_TESTS=OFF
fi
cmake --build "$build" --target $(for t in $targets; do printf 'fuzz_%s ' "$t"; done)

# --- Run ---
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
crashes="$root/fuzz/crashes"
mkdir -p "$crashes"
scratch="$(mktemp -d /tmp/phys_fuzz_run.XXXXXX)"
trap 'rm -rf "$scratch"' EXIT
status=0
summary=""
for t in $targets; do
  work="$scratch/$t"
  mkdir -p "$work/corpus"
  cp "$root/fuzz/corpus/$t/"* "$work/corpus/"
  if [[ -n "$keep" && -d "$keep/$t" ]]; then cp "$keep/$t/"* "$work/corpus/" 2> /dev/null || true; fi
  seeds=$(ls "$work/corpus" | wc -l)
  dict="$root/fuzz/$t.dict"
  [[ "$t" == apply ]] && dict="$root/fuzz/codec.dict"
  # restore steps what it restored: a legitimate pile under direct contacts with the guard's
  # retries (24 substeps) takes 0.5-0.9 s a step under ASan, over 10 s for an input when the
  # other core is busy; a step's cost is the budgets' business (docs/BENCHMARKS.md).
  limit=10
  [[ "$t" == restore ]] && limit=30
  args=(-rss_limit_mb=2048 "-timeout=$limit" -print_final_stats=1 "-artifact_prefix=$crashes/$t-")
  [[ -f "$dict" ]] && args+=("-dict=$dict")
  [[ "$seconds" -gt 0 ]] && args+=("-max_total_time=$seconds")
  per=$(( (runs + jobs - 1) / jobs ))
  echo "== fuzz_$t: $runs inputs ($jobs job(s) of $per) from $seeds seeds, $(date -u '+%F %T') UTC"
  t0=$(date +%s.%N)
  rc=0
  if [[ "$jobs" -eq 1 ]]; then
    (cd "$work" && "$build/fuzz/fuzz_$t" "${args[@]}" "-runs=$per" corpus > log.txt 2>&1) || rc=$?
    logs=("$work/log.txt")
  else
    # libFuzzer's jobs share the corpus directory; each writes fuzz-<n>.log in the cwd.
    (cd "$work" && "$build/fuzz/fuzz_$t" "${args[@]}" "-runs=$per" "-jobs=$jobs" "-workers=$jobs" \
       corpus > log.txt 2>&1) || rc=$?
    logs=("$work"/fuzz-*.log)
  fi
  t1=$(date +%s.%N)
  wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN {printf "%.0f", b - a}')
  # Inputs and exec/s as libFuzzer counted them (the "Done N runs in S second(s)" of each job).
  done_runs=$(cat "${logs[@]}" | awk '/^Done [0-9]+ runs in/ {n += $2} END {print n + 0}')
  execs=$(cat "${logs[@]}" | awk '/stat::average_exec_per_sec:/ {s += $2} END {print s + 0}')
  final=$(cat "${logs[@]}" | grep -E '^#[0-9]+[[:space:]]+DONE' | tail -n 1 || true)
  bad=$(cat "${logs[@]}" | grep -E 'ERROR: (libFuzzer|AddressSanitizer|LeakSanitizer|UndefinedBehaviorSanitizer)|runtime error:|^SUMMARY: |^fuzz_[a-z]+: |Test unit written to' || true)
  grown=$(ls "$work/corpus" | wc -l)
  echo "   ${final:-"(no DONE line)"}"
  echo "   $(cat "${logs[@]}" | grep -E '^Done [0-9]+ runs in' | tail -n 1 || echo '(no Done line)')"
  line="fuzz_$t: $done_runs inputs in $wall s wall, $execs exec/s (libFuzzer's average, summed over jobs), corpus $seeds -> $grown, exit $rc"
  echo "   $line"
  if [[ "$rc" -ne 0 || -n "$bad" ]]; then
    status=1
    echo "   FINDING (log: $crashes/$t-log.txt):"
    echo "$bad" | head -n 20 | sed 's/^/     /'
    cat "${logs[@]}" > "$crashes/$t-log.txt"
    line="$line  FINDING"
  fi
  if [[ -n "$keep" ]]; then
    mkdir -p "$keep/$t"
    cp "$work/corpus/"* "$keep/$t/"
  fi
  summary+="$line"$'\n'
done
echo "== summary ($(nproc) cores, $(date -u +%F)):"
printf '%s' "$summary"
exit "$status"
