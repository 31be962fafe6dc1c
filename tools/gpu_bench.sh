#!/usr/bin/env bash
# GPU benchmark: the scale scenes on the GPU backend with tjsoft (4 substeps), ms per step in
# all and per stage (the device's timestamps), one scene after the other.
#
#   tools/gpu_bench.sh [--seconds S] [--preset P] [--scenes "a b"] [--sleep on|off]
#                      [--timeout S] [--out DIR] [--build-dir DIR] [--no-build]
#
# Defaults: 5 simulated seconds of pyramid_100, many_pyramids, pile_100k and pile_1m; preset
# tjsoft; sleeping as each scene says (--sleep overrides it); no time limit per scene (--timeout
# stops a scene after S wall seconds and says so); --out keeps each run's whole output there as
# SCENE.txt. Every step must run on the device (physbench --require-device): a machine without a
# GPU reports that and moves on. A lavapipe run (PHYS_GPU_ALLOW_CPU=1) works but measures
# nothing useful about GPUs.
#
# On the `device` tool's machines (an NVIDIA GPU, no network, no build tools): build here with
# this script (the build has no peer engines and no network stack, so the binary needs only
# libvulkan1 and libqhull-r8.0 there), then carry the loader and qhull packages as the device
# tool's README explains (.gl/*.deb plus libqhull-r8.0's .deb, unpacked with dpkg -x) and run
#   tools/gpu_bench.sh --no-build
# there. It sets VK_DRIVER_FILES to NVIDIA's ICD when that file exists and none is set.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=5
preset=tjsoft
scenes="pyramid_100 many_pyramids pile_100k pile_1m"
build_dir=build-gpubench
build=1
sleep_arg=()
limit=()
keep=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift 2 ;;
    --preset) preset=$2; shift 2 ;;
    --scenes) scenes=$2; shift 2 ;;
    --build-dir) build_dir=$2; shift 2 ;;
    --sleep) sleep_arg=(--sleep "$2"); shift 2 ;;
    --timeout) limit=(timeout "$2"); shift 2 ;;
    --out) keep=$2; mkdir -p "$keep"; shift 2 ;;
    --no-build) build=0; shift ;;
    -h|--help) sed -n '2,25p' "$0"; exit 0 ;;
    *) echo "gpu_bench.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done

if [ "$build" = 1 ]; then
  if [ ! -f "$build_dir/build.ninja" ]; then
    cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DPHYS_BUILD_TESTS=OFF \
      -DPHYS_BUILD_NETWORK=OFF -DPHYS_WITH_PEERS=OFF >/dev/null
  fi
  cmake --build "$build_dir" --target physbench
fi
bench="$build_dir/tools/physbench"
[ -x "$bench" ] || { echo "gpu_bench.sh: $bench not built" >&2; exit 2; }

nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$nvidia_icd" ]; then export VK_DRIVER_FILES=$nvidia_icd; fi

echo "# tools/gpu_bench.sh --seconds $seconds --preset $preset ${sleep_arg[*]}; $(date -u +%F)"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
status=0
for scene in $scenes; do
  echo
  echo "## $scene"
  # physbench exits 1 when a scene's criteria fail too (these runs are short): only the
  # device requirement decides this script's status.
  start=$(date +%s)
  code=0
  out=$("${limit[@]}" "$bench" --scene "configs/scenes/$scene.json" --preset "$preset" \
    --backend gpu --require-device --seconds "$seconds" "${sleep_arg[@]}" 2>&1) || code=$?
  [ -n "$keep" ] && printf '%s\n' "$out" >"$keep/$scene.txt"
  grep -E "^scene|ms/step|stages|gpu profile|FAILED: --require|physbench:" <<<"$out" || true
  echo "  wall $(( $(date +%s) - start )) s, exit $code"
  [ "$code" = 124 ] && echo "  STOPPED: over the --timeout" && status=1
  grep -q "FAILED: --require-device" <<<"$out" && status=1
done
exit $status
