#!/usr/bin/env bash
# Fan-out benchmark (issue 4; a benchmark, not a test): physd runs a 10,000-body world at
# 60 Hz (configs/bench/fanout_10k.toml) and N subscriber processes (physctl subscribe) each
# report how many complete ticks they received and the tick-to-subscriber latency. The
# daemon's own counters (tick overruns, frames handed to the publisher, frames its ring
# dropped) are read before and after the measuring window. Each subscriber logs its
# per-tick latencies (physctl subscribe --latency-log); the last line is, per tick, the latency
# of the last subscriber to have it. Everything is read from physctl's --json output.
#
#   tools/fanout_bench.sh [--subscribers N] [--seconds S] [--warmup S] [--build DIR]
#                         [--config TOML] [--domain N] [--scene NAME]
#
# --domain: the DDS domain (default: the config's; the run has a Cyclone discovery tag of its
# own either way); --scene: the world's scene instead of the config's (ctest's bench.fanout
# runs pyramid_20 for a second with two subscribers: the script, not the figures).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
subs=8 seconds=30 warmup=5 build="$root/build" config="$root/configs/bench/fanout_10k.toml"
domain="" scene=""
usage="usage: $0 [--subscribers N] [--seconds S] [--warmup S] [--build DIR] [--config TOML] [--domain N] [--scene NAME]"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --subscribers) subs="$2"; shift 2 ;;
    --seconds) seconds="$2"; shift 2 ;;
    --warmup) warmup="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --config) config="$2"; shift 2 ;;
    --domain) domain="$2"; shift 2 ;;
    --scene) scene="$2"; shift 2 ;;
    *) echo "$usage" >&2; exit 2 ;;
  esac
done
source "$root/tools/physd_bench.sh"
pids=()
for i in $(seq "$subs"); do
  ctl subscribe fanout --json --warmup "$warmup" --seconds "$seconds" --latency-log "$out/lat$i.txt" \
    > "$out/sub$i.json" 2> "$out/sub$i.err" &
  pids+=($!)
done
sleep "$warmup"
ctl list --json > "$out/before.json"
sleep "$seconds"
ctl list --json > "$out/after.json"
for p in "${pids[@]}"; do wait "$p" || true; done

echo "fanout: $subs subscribers, $seconds s measured after ${warmup} s warm-up, $(nproc) cores, $(date -u +%F)"
field() { world_json "$out/$1.json" fanout "$2"; }
bodies=$(field before bodies) awake=$(field after awake_bodies)
tick0=$(field before tick) tick1=$(field after tick)
over0=$(field before overruns) over1=$(field after overruns)
frames0=$(field before frames) frames1=$(field after frames)
echo "physd: $bodies bodies ($awake awake at the end), $((tick1 - tick0)) ticks, $((over1 - over0)) overruns, $((frames1 - frames0)) frames published in the window"
python3 - "$out" "$subs" <<'PY'
import glob, json, sys
out, n = sys.argv[1], int(sys.argv[2])
rows = []
for f in sorted(glob.glob(out + "/sub*.json")):
    text = open(f).read().strip()
    err = open(f[:-5] + ".err").read().strip()
    if not text:
        print(f"subscriber {f}: no result{': ' + err if err else ''}")
        continue
    s = json.loads(text)
    rows.append(s)
    if s["received"] == 0:
        print(f"subscriber {s['subscriber']}: world {s['world']}: no frames in {s['seconds']:.1f} s")
        continue
    lat = s["latency_ms"]
    print(f"subscriber {s['subscriber']}: world {s['world']} ticks {s['first_tick']}..{s['last_tick']} "
          f"received {s['received']} expected {s['expected']} delivered {s['delivered_percent']:.3f}% "
          f"bodies_min {s['bodies_min']} latency_ms p50 {lat['p50']:.3f} p99 {lat['p99']:.3f} "
          f"max {lat['max']:.3f} bytes_per_tick {s['bytes_per_tick']:.0f}")
got = [s for s in rows if s["received"] > 0]
if got:
    print(f"all {len(got)} subscribers: worst delivered {min(s['delivered_percent'] for s in got):.3f}%, "
          f"worst p99 latency {max(s['latency_ms']['p99'] for s in got):.3f} ms, "
          f"mean {sum(s['bytes_per_tick'] for s in got) / len(got):.0f} bytes per tick received")
else:
    print("no subscriber reported")
if len(got) < n:
    sys.exit(f"{n - len(got)} of {n} subscribers received nothing")
PY
# Per tick: when the last subscriber had it (over the ticks every subscriber received).
cat "$out"/lat*.txt 2>/dev/null |
  awk -v n="$subs" '{ c[$1]++; if (!($1 in m) || $2 > m[$1]) m[$1] = $2 }
                    END { for (t in c) if (c[t] == n) print m[t] }' | sort -g |
  awk '{ v[++k] = $1 }
       END { if (!k) { print "no tick reached every subscriber"; exit 1 }
             i50 = int(0.5 * k) + 1; i99 = int(0.99 * k) + 1; if (i99 > k) i99 = k
             printf "last subscriber per tick (%d ticks that all had): p50 %.3f ms, p99 %.3f ms, max %.3f ms\n", k, v[i50], v[i99], v[k] }'
