#!/usr/bin/env bash
# Idle daemon (issue 22; a benchmark, not a test): physd with ten worlds of 10,000 resting
# boxes (configs/bench/idle_10x10k.toml), each running at 60 Hz, everything asleep after half a
# second, one subscriber (physctl subscribe) on each world. Reports the daemon's CPU time over
# the measuring window as a share of one core, and what the subscribers received.
#   tools/idle_bench.sh [--seconds S] [--build DIR] [--config TOML]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
seconds=30 build="$root/build" config="$root/configs/bench/idle_10x10k.toml"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --config) config="$2"; shift 2 ;;
    *) echo "usage: $0 [--seconds S] [--build DIR] [--config TOML]" >&2; exit 2 ;;
  esac
done
source "$root/tools/physd_bench.sh"
worlds=$(ctl list | awk '$2 ~ /^idle/ {print $2}')
warmup=5
for w in $worlds; do
  ctl subscribe "$w" --warmup "$warmup" --seconds "$seconds" > "$out/sub_$w.txt" 2>&1 &
done
sleep "$warmup"
ticks() { awk '{print $14 + $15}' "/proc/$daemon/stat"; }  # utime + stime, clock ticks
hz=$(getconf CLK_TCK)
c0=$(ticks); t0=$(date +%s.%N)
ctl list > "$out/before.txt"
sleep "$seconds"
c1=$(ticks); t1=$(date +%s.%N)
ctl list > "$out/after.txt"
wait $(jobs -p | grep -v "^$daemon$") 2>/dev/null || true
echo "idle: $(echo "$worlds" | wc -w) worlds, $seconds s measured after ${warmup} s warm-up, $(nproc) cores, $(date -u +%F)"
# Columns of physctl list: id name preset awake bodies joints tick time state rate overruns frames backend.
awk '$2 ~ /^idle/ {a += $4; b += $5; n++} END {printf "worlds %d, awake bodies %d of %d at the end\n", n, a, b}' "$out/after.txt"
paste <(awk '$2 ~ /^idle/ {print $2, $7}' "$out/before.txt") <(awk '$2 ~ /^idle/ {print $7}' "$out/after.txt") |
  awk -v s="$seconds" '{t += $3 - $2; n++} END {printf "ticks per world per second %.1f\n", t / n / s}'
awk -v c0="$c0" -v c1="$c1" -v t0="$t0" -v t1="$t1" -v hz="$hz" \
  'BEGIN {printf "physd CPU: %.2f s in %.1f s = %.2f %% of one core\n", (c1 - c0) / hz, t1 - t0, 100 * (c1 - c0) / hz / (t1 - t0)}'
cat "$out"/sub_*.txt
