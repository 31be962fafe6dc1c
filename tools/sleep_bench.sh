#!/usr/bin/env bash
# Islands and sleeping (issue 22), side by side in one run: many_pyramids and pile_10k with
# sleeping on (their files' default), Bullet with its deactivation on (the same scene switch),
# and our steps with sleeping off as the baseline. Prints one line per run: the median ms per
# step over the whole run and after the scene's settle time, and the bodies awake at the end.
#   tools/sleep_bench.sh [build dir]     (the pile runs 25 simulated seconds: minutes)
#   tools/sleep_bench.sh --device [build dir]
# --device: the GPU backend instead (lavapipe where there is no GPU: PHYS_GPU_ALLOW_CPU=1),
# on configs/bench/sleep_device.json (240 cubes in 16 pyramids that fall asleep, one ball that
# never does): sleeping on and off, and beside them the ball alone and the pyramids alone, so
# what the sleeping bodies still cost the device is the difference from the ball alone.
# --scenes "a b" (CPU runs: other scenes of configs/scenes/) and --seconds S (every run at most
# S simulated seconds) make it small: ctest's bench.sleep and bench.sleep_device run it so (the
# script, not the figures).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
device=0 scenes="many_pyramids pile_10k" cap=""
while [ $# -gt 0 ]; do
  case "$1" in
    --device) device=1; shift ;;
    --scenes) scenes=$2; shift 2 ;;
    --seconds) cap=$2; shift 2 ;;
    -*) echo "usage: $0 [--device] [--scenes \"a b\"] [--seconds S] [build dir]" >&2; exit 2 ;;
    *) break ;;
  esac
done
capped() {  # seconds: at most the --seconds cap
  if [ -n "$cap" ]; then python3 -c "import sys; print(min(float(sys.argv[1]), float(sys.argv[2])))" "$1" "$cap"; else echo "$1"; fi
}
build=${1:-$root/build}
bench=$build/tools/physbench
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
row() {  # label json
  python3 - "$1" "$2" <<'PY'
import json, sys
j = json.load(open(sys.argv[2]))
m = j["metrics"]
s = m.get("ms_per_step_settled_median")
# A peer's run reports our mirror world's count, not the engine's: left out.
awake = '-' if j.get('backend', '').startswith(('Bullet', 'bullet')) else m.get('awake_bodies_final', '-')
print(f"{sys.argv[1]:<44} steps {j['steps']:>5}  ms/step median {m['ms_per_step_median']:9.3f}"
      f"  settled median {'-' if s is None else f'{s:9.4f}'}  awake at the end {awake}")
PY
}
if [ "$device" = 1 ]; then
  export PHYS_GPU_ALLOW_CPU=${PHYS_GPU_ALLOW_CPU:-1}
  export MESA_SHADER_CACHE_DIR=${MESA_SHADER_CACHE_DIR:-$build/mesa_shader_cache}
  file=$root/configs/bench/sleep_device.json
  python3 - "$file" "$out" <<'PY'
import json, sys
scene = json.load(open(sys.argv[1]))
ball = dict(scene, name="ball_alone", generators=[], metrics={"settle_time": 1.5},
            criteria=[{"metric": "nan", "max": 0}])
pyramids = dict(scene, name="pyramids_alone", bodies=scene["bodies"][:1])
json.dump(ball, open(sys.argv[2] + "/ball.json", "w"))
json.dump(pyramids, open(sys.argv[2] + "/pyramids.json", "w"))
PY
  gpu() {  # label scene sleep
    rm -f "$out/run.json"
    "$bench" --scene "$2" --backend gpu --require-device --seconds "$(capped 3)" --sleep "$3" \
      --json "$out/run.json" > /dev/null || true
    row "$1" "$out/run.json"
  }
  gpu "sleep_device: device, sleeping on" "$file" on
  gpu "sleep_device: device, sleeping off" "$file" off
  gpu "the ball alone: device, sleeping on" "$out/ball.json" on
  gpu "the pyramids alone: device, sleeping on" "$out/pyramids.json" on
  exit 0
fi
for scene in $scenes; do
  rm -f "$out"/*.json  # a run that writes none must not show the one before
  file=$root/configs/scenes/$scene.json
  seconds=$(capped "$([ "$scene" = pile_10k ] && echo 25 || echo 10)")
  "$bench" --scene "$file" --seconds "$seconds" --threads 2 --json "$out/ours.json" > /dev/null || true
  row "$scene: phys, sleeping on, 2 threads" "$out/ours.json"
  if "$bench" --scene "$file" --seconds "$seconds" --peer bullet --sleep on --json "$out/bullet.json" > /dev/null 2>&1 ||
     [ -s "$out/bullet.json" ]; then
    row "$scene: Bullet, deactivation on, 1 thread" "$out/bullet.json"
  else
    echo "$scene: Bullet not compiled in (PHYS_WITH_PEERS)"
  fi
  "$bench" --scene "$file" --seconds "$(capped 3)" --threads 2 --sleep off --json "$out/off.json" > /dev/null || true
  row "$scene: phys, sleeping off, $(capped 3) s, 2 threads" "$out/off.json"
done
