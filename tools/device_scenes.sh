#!/usr/bin/env bash
# Whole scenes at full length on the GPU backend, each judged against the CPU backend at the
# same length (physbench --against-cpu): what ctest's scene.gpu.* tests check on CI-sized
# runs, at the scenes' own durations. On lavapipe this takes most of an hour (pyramid_20:
# 250-330 ms a step, box_stack: 3.5 s a step), so it is a benchmark, not a test;
# docs/BENCHMARKS.md keeps its table ("Whole scenes on the device").
#
#   tools/device_scenes.sh [--scenes "a b"] [--preset P] [--jobs N] [--build-dir DIR]
#                          [--out DIR] [--timeout S] [--seconds S]
#
# Defaults: the scenes ctest runs on the device CI-sized, which are every scene with criteria
# but box_stack, pyramid_40, pyramid_100 and the scale scenes (many_pyramids, the piles,
# fanout_10k), each an hour or more on lavapipe (name them to run them); the scenes' own
# solvers, one at a time, the build of ./test.sh (build/). Without a GPU it runs on lavapipe
# (PHYS_GPU_ALLOW_CPU=1 is set). --timeout stops a run after S wall seconds (exit 124 in the
# table). Each run's JSON and output go to DIR (default
# build/device_scenes/); the Markdown table goes to stdout. The exit status is 1 when a run
# failed a criterion the CPU run passed, or did not run every step on the device. --seconds S
# runs S simulated seconds instead of each scene's own length (ctest's bench.device_scenes:
# one scene for a few steps, to keep the script working, not to judge the device).
set -euo pipefail
cd "$(dirname "$0")/.."

scenes="restitution friction_ramp tunnelling free_flight ball_and_chain default overlap
        suspension_bridge vertical_stack windmill pyramid_20"
preset=""
jobs=1
build_dir=build
out=""
limit=()
length=()
while [ $# -gt 0 ]; do
  case "$1" in
    --scenes) scenes=$2; shift 2 ;;
    --preset) preset=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --build-dir) build_dir=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --timeout) limit=(timeout "$2"); shift 2 ;;
    --seconds) length=(--seconds "$2"); shift 2 ;;
    -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
    *) echo "device_scenes.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
bench="$build_dir/tools/physbench"
[ -x "$bench" ] || { echo "device_scenes.sh: $bench not built (./test.sh builds it)" >&2; exit 2; }
[ -n "$out" ] || out="$build_dir/device_scenes"
mkdir -p "$out"
export PHYS_GPU_ALLOW_CPU=1

run_one() {
  local scene=$1 args=(--scene "configs/scenes/$1.json" --backend gpu --require-device
                       --against-cpu --json "$out/$1.json" "${length[@]}")
  [ -n "$preset" ] && args+=(--preset "$preset")
  local start end
  start=$(date +%s)
  "${limit[@]}" "$bench" "${args[@]}" >"$out/$scene.txt" 2>&1 && echo 0 >"$out/$scene.status" ||
    echo $? >"$out/$scene.status"
  end=$(date +%s)
  echo $((end - start)) >"$out/$scene.wall"
  echo "device_scenes.sh: $scene done in $((end - start)) s (exit $(cat "$out/$scene.status"))" >&2
}

running=0
for scene in $scenes; do
  run_one "$scene" &
  running=$((running + 1))
  if [ "$running" -ge "$jobs" ]; then
    wait -n || true
    running=$((running - 1))
  fi
done
wait || true

device=$( { grep -ho 'backend gpu ([^;]*' "$out"/*.txt 2>/dev/null || true; } | head -1 |
         sed 's/.*backend gpu (//')
echo "tools/device_scenes.sh ${preset:+--preset $preset }on $(date -u +%F), device: ${device:-none}"
echo
echo "| scene | preset | simulated | wall | device ms/step | criteria on the device (CPU at the same length) | largest position difference to the CPU | result |"
echo "|---|---|---|---|---|---|---|---|"
status=0
for scene in $scenes; do
  txt="$out/$scene.txt"
  code=$(cat "$out/$scene.status")
  [ "$code" = 0 ] || status=1
  line=$(grep -m1 '^scene ' "$txt" || true)
  used=$(sed -n 's/^scene [^,]*, preset \([^,]*\),.*/\1/p' <<<"$line")
  [ "$used" = scene ] && used="scene's"
  sim=$(sed -n 's/.*steps (\([0-9.]*\) s)$/\1 s/p' <<<"$line")
  ms=$(sed -n 's/^  ms\/step median \([0-9.]*\).*/\1/p' "$txt")
  crit=$(sed -n 's/^  \[\([A-Z ]*\)\] \([a-z_.]*\): device \([^,]*\), cpu \([^ ]*\) (\(.*\))$/\1 \2 \3 (cpu \4, \5)/p' "$txt" |
         paste -sd';' - | sed 's/;/; /g')
  diff=$(sed -n 's/.*largest position difference \([^ ]*\) m (\([^)]*\)).*/\1 m (\2)/p' "$txt")
  result=PASS
  [ "$code" = 0 ] || result="FAIL (exit $code)"
  echo "| $scene | $used | $sim | $(cat "$out/$scene.wall") s | $ms | $crit | $diff | $result |"
done
exit $status
