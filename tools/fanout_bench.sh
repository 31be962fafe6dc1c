#!/usr/bin/env bash
# Fan-out benchmark (issue 4; a benchmark, not a test): physd runs a 10,000-body world at
# 60 Hz (configs/bench/fanout_10k.toml) and N subscriber processes (physctl subscribe) each
# report how many complete ticks they received and the tick-to-subscriber latency. The
# daemon's own counters (tick overruns, frames handed to the publisher, frames its ring
# dropped) are read before and after the measuring window. Each subscriber logs its
# per-tick latencies (physctl subscribe --latency-log); the last line is, per tick, the latency
# of the last subscriber to have it.
#
#   tools/fanout_bench.sh [--subscribers N] [--seconds S] [--build DIR] [--config TOML]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
subs=8 seconds=30 build="$root/build" config="$root/configs/bench/fanout_10k.toml"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --subscribers) subs="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --config) config="$2"; shift 2 ;;
    *) echo "usage: $0 [--subscribers N] [--seconds S] [--build DIR] [--config TOML]" >&2; exit 2 ;;
  esac
done
source "$root/tools/physd_bench.sh"
warmup=5
for i in $(seq "$subs"); do
  ctl subscribe fanout --warmup "$warmup" --seconds "$seconds" --latency-log "$out/lat$i.txt" \
    > "$out/sub$i.txt" 2>&1 &
done
sleep "$warmup"
ctl list > "$out/before.txt"
sleep "$seconds"
ctl list > "$out/after.txt"
wait $(jobs -p | grep -v "^$daemon$") 2>/dev/null || true

echo "fanout: $subs subscribers, $seconds s measured after ${warmup} s warm-up, $(nproc) cores, $(date -u +%F)"
# Columns of physctl list: id name preset awake bodies joints tick time state rate overruns
# frames backend [(device)].
read -r _ _ _ _ bodies _ tick0 _ _ _ over0 frames0 _ < <(grep ' fanout ' "$out/before.txt")
read -r _ _ _ awake _ _ tick1 _ _ _ over1 frames1 _ < <(grep ' fanout ' "$out/after.txt")
echo "physd: $bodies bodies ($awake awake at the end), $((tick1 - tick0)) ticks, $((over1 - over0)) overruns, $((frames1 - frames0)) frames published in the window"
cat "$out"/sub*.txt
awk '/delivered/ {
       for (i = 1; i <= NF; i++) { if ($i == "delivered") d = $(i + 1); if ($i == "p99") p = $(i + 1) }
       sub("%", "", d); d += 0; p += 0; n++; if (n == 1 || d < dmin) dmin = d; if (p > pmax) pmax = p
       for (i = 1; i <= NF; i++) if ($i == "bytes_per_tick") { b += $(i + 1); nb++ } }
     END { if (n) printf "all %d subscribers: worst delivered %.3f%%, worst p99 latency %.3f ms, mean %.0f bytes per tick received\n", n, dmin, pmax, nb ? b / nb : 0
           else print "no subscriber reported" }' "$out"/sub*.txt
# Per tick: when the last subscriber had it (over the ticks every subscriber received).
cat "$out"/lat*.txt 2>/dev/null |
  awk -v n="$subs" '{ c[$1]++; if (!($1 in m) || $2 > m[$1]) m[$1] = $2 }
                    END { for (t in c) if (c[t] == n) print m[t] }' | sort -g |
  awk '{ v[++k] = $1 }
       END { if (!k) { print "no tick reached every subscriber"; exit }
             i50 = int(0.5 * k) + 1; i99 = int(0.99 * k) + 1; if (i99 > k) i99 = k
             printf "last subscriber per tick (%d ticks that all had): p50 %.3f ms, p99 %.3f ms, max %.3f ms\n", k, v[i50], v[i99], v[k] }'
