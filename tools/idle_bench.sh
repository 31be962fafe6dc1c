#!/usr/bin/env bash
# Idle daemon (issue 22; a benchmark, not a test): physd with ten worlds of 10,000 resting
# boxes (configs/bench/idle_10x10k.toml), each running at 60 Hz, everything asleep after half a
# second, one subscriber (physctl subscribe) on each world. Reports the daemon's CPU time over
# the measuring window as a share of one core, and what the subscribers received. Everything is
# read from physctl's --json output.
#   tools/idle_bench.sh [--seconds S] [--warmup S] [--build DIR] [--config TOML] [--domain N]
#                       [--scene NAME] [--worlds N]
# --domain: the DDS domain (default: the config's; the run has a Cyclone discovery tag of its
# own either way); --scene and --worlds: every world's scene instead of the config's, and only
# the config's first N worlds (ctest's bench.idle runs two worlds of pyramid_20 for a second:
# the script, not the figures).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
seconds=30 warmup=5 build="$root/build" config="$root/configs/bench/idle_10x10k.toml"
domain="" scene="" max_worlds=""
usage="usage: $0 [--seconds S] [--warmup S] [--build DIR] [--config TOML] [--domain N] [--scene NAME] [--worlds N]"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --warmup) warmup="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --config) config="$2"; shift 2 ;;
    --domain) domain="$2"; shift 2 ;;
    --scene) scene="$2"; shift 2 ;;
    --worlds) max_worlds="$2"; shift 2 ;;
    *) echo "$usage" >&2; exit 2 ;;
  esac
done
source "$root/tools/physd_bench.sh"
ctl list --json > "$out/start.json"
worlds=$(python3 -c 'import json, sys; print(" ".join(w["name"] for w in json.load(open(sys.argv[1])) if w["name"].startswith("idle")))' "$out/start.json")
[[ -n "$worlds" ]] || { echo "no idle* worlds in $config" >&2; exit 1; }
pids=()
for w in $worlds; do
  ctl subscribe "$w" --json --warmup "$warmup" --seconds "$seconds" > "$out/sub_$w.json" 2> "$out/sub_$w.err" &
  pids+=($!)
done
sleep "$warmup"
ticks() { awk '{print $14 + $15}' "/proc/$daemon/stat"; }  # utime + stime, clock ticks
hz=$(getconf CLK_TCK)
c0=$(ticks); t0=$(date +%s.%N)
ctl list --json > "$out/before.json"
sleep "$seconds"
c1=$(ticks); t1=$(date +%s.%N)
ctl list --json > "$out/after.json"
for p in "${pids[@]}"; do wait "$p" || true; done
echo "idle: $(echo "$worlds" | wc -w) worlds, $seconds s measured after ${warmup} s warm-up, $(nproc) cores, $(date -u +%F)"
python3 - "$out" "$seconds" <<'PY'
import glob, json, sys
out, seconds = sys.argv[1], float(sys.argv[2])
def idle(name):
    return {w["name"]: w for w in json.load(open(f"{out}/{name}.json")) if w["name"].startswith("idle")}
before, after = idle("before"), idle("after")
print(f"worlds {len(after)}, awake bodies {sum(w['awake_bodies'] for w in after.values())} of "
      f"{sum(w['bodies'] for w in after.values())} at the end")
ticks = [after[n]["tick"] - before[n]["tick"] for n in after if n in before]
print(f"ticks per world per second {sum(ticks) / len(ticks) / seconds:.1f}")
PY
awk -v c0="$c0" -v c1="$c1" -v t0="$t0" -v t1="$t1" -v hz="$hz" \
  'BEGIN {printf "physd CPU: %.2f s in %.1f s = %.2f %% of one core\n", (c1 - c0) / hz, t1 - t0, 100 * (c1 - c0) / hz / (t1 - t0)}'
python3 - "$out" <<'PY'
import glob, json, sys
bad = 0
for f in sorted(glob.glob(sys.argv[1] + "/sub_*.json")):
    text = open(f).read().strip()
    if not text:
        print(f"{f}: no result: {open(f[:-5] + '.err').read().strip()}")
        bad += 1
        continue
    s = json.loads(text)
    if s["received"] == 0:
        print(f"subscriber {s['subscriber']}: world {s['world']}: no frames in {s['seconds']:.1f} s")
        bad += 1
        continue
    lat = s["latency_ms"]
    print(f"subscriber {s['subscriber']}: world {s['world']} ticks {s['first_tick']}..{s['last_tick']} "
          f"received {s['received']} expected {s['expected']} delivered {s['delivered_percent']:.3f}% "
          f"bodies_min {s['bodies_min']} latency_ms p50 {lat['p50']:.3f} p99 {lat['p99']:.3f} "
          f"max {lat['max']:.3f} bytes_per_tick {s['bytes_per_tick']:.0f}")
sys.exit(1 if bad else 0)
PY
