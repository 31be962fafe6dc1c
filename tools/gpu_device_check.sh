#!/usr/bin/env bash
# Everything a session with a lent GPU measures, in one call of the `device` tool (its
# machines have an NVIDIA GPU, no network and no build tools; device time is short, so this
# is one prepared script with a time limit on every part).
#
#   tools/gpu_device_check.sh [--bin DIR] [--out ROOT] [--quick]
#
# DIR (default .devbin) holds binaries built here and stripped: tools/physbench (the build of
# tools/gpu_bench.sh: Release, no peers, no network) and phys_gpu_tests (the test build).
# Prepare and call it like this (from the repository root, on the development machine):
#
#   tools/gpu_bench.sh --seconds 0 --scenes "" ; cmake --build build --target phys_gpu_tests
#   mkdir -p .devbin/tools && strip -o .devbin/tools/physbench build-gpubench/tools/physbench
#   strip -o .devbin/phys_gpu_tests build/tests/gpu/phys_gpu_tests
#   device run: carry [".gl", ".devbin"], command "tools/gpu_device_check.sh"
#
# (.gl holds the Vulkan loader's and libqhull-r8.0's Debian packages, as the device tool's
# README says; both folders are in .git/info/exclude.) In order, most important first:
#   1. the device: nvidia-smi and the Vulkan device physbench picks;
#   2. tools/gpu_bench.sh: the scale scenes, 5 simulated seconds each, with tjsoft;
#   3. the same scenes on the CPU backend, 1 simulated second, on this machine's cores: the
#      ratio of the two, side by side on one machine;
#   4. tools/device_scenes.sh: the scenes at full length, judged against the CPU backend
#      (criteria and the largest position difference: parity);
#   5. the GPU test binary (parity and determinism tests written for lavapipe);
#   6. the seed paper's Table 2: box_stack and overlap at full length with its five solvers.
# Every part's whole output goes to ROOT/all.tgz (ROOT: the device tool's $OUT by default); a
# summary is printed as it goes (and kept in ROOT/summary.txt). Every part has a time limit (in
# all about 10 minutes at the most, 5 to 6 expected on an H100). --quick runs every part on
# short lengths, to try the script on lavapipe.
set -uo pipefail
cd "$(dirname "$0")/.."

bin=.devbin
root=${OUT:-build/gpu_check}
quick=0
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --out) root=$2; shift 2 ;;
    --quick) quick=1; shift ;;
    -h|--help) sed -n '2,30p' "$0"; exit 0 ;;
    *) echo "gpu_device_check.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
# The device tool brings back 8 files at most: every part writes under ROOT/w, and after each
# part ROOT/all.tgz is remade from it (so a run cut short still brings back what it did).
out=$root/w
mkdir -p "$out"
exec > >(tee "$root/summary.txt") 2>&1
t0=$(date +%s)
stamp() { tar czf "$root/all.tgz" -C "$root" w 2>/dev/null; echo "[$(( $(date +%s) - t0 )) s] $*"; }

# The loader and qhull, unpacked where the device tool's README says, when missing.
if ! ldconfig -p | grep -q 'libvulkan.so.1 '; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$nvidia_icd" ]; then export VK_DRIVER_FILES=$nvidia_icd; fi
# The test binary finds scenes under the source directory it was built in (/work/main).
[ -e /work/main ] || { mkdir -p /work && ln -s "$PWD" /work/main; }
[ "$quick" = 1 ] && export PHYS_GPU_ALLOW_CPU=1

stamp "1. the device"
{ command -v nvidia-smi >/dev/null && nvidia-smi; nproc; uname -r; } >"$out/device.txt" 2>&1
head -20 "$out/device.txt"

seconds=5 cpu_seconds=1 bench_limit=100
scale_scenes="pyramid_100 many_pyramids pile_100k pile_1m"
device_scenes=()
test_filter=()
if [ "$quick" = 1 ]; then
  seconds=0.05 cpu_seconds=0.05 bench_limit=60
  scale_scenes="pyramid_100 many_pyramids"
  device_scenes=(--scenes "restitution")
  test_filter=(--gtest_filter='GpuSleep.*')
fi

# The driver's manifest. On some hosts it names its library without a path
# (libGLX_nvidia.so.0) and the loader does not find it: vkCreateInstance fails (-9) and
# physbench would measure the CPU. So probe the plain manifest with one short step that must
# run on a device; if that fails, write a manifest naming the library by its full path and
# use that one. Which manifest was used is printed (and kept in the summary).
# (A short run fails the scene's criteria: exit 1 is fine, "FAILED: --require-device" not.)
probe() {
  timeout 60 "$bin/tools/physbench" --scene configs/scenes/restitution.json --backend gpu \
    --require-device --seconds 0.02 >"$out/probe_$1.txt" 2>&1
  [ $? -le 1 ] && ! grep -q 'FAILED: --require-device' "$out/probe_$1.txt"
}
if [ "$quick" = 0 ] && [ -n "${VK_DRIVER_FILES:-}" ] && ! probe plain; then
  lib=$(sed -n 's/.*"library_path" *: *"\([^"]*\)".*/\1/p' "$VK_DRIVER_FILES" | head -1)
  full=$lib
  if [ -n "$lib" ] && [ "${lib#/}" = "$lib" ]; then
    full=""
    for d in /usr/local/nvidia/lib64 /usr/local/nvidia/lib /usr/lib/x86_64-linux-gnu; do
      [ -e "$d/$lib" ] && { full=$d/$lib; break; }
    done
    [ -n "$full" ] || full=$(ldconfig -p | awk -v l="$lib" '$1 == l { print $NF; exit }')
  fi
  if [ -n "$full" ]; then
    printf '{"file_format_version":"1.0.0","ICD":{"library_path":"%s","api_version":"1.3.0"}}\n' \
      "$full" >"$root/nvidia_icd_full_path.json"
    export VK_DRIVER_FILES=$root/nvidia_icd_full_path.json
    if probe full_path; then
      echo "manifest: the plain one failed ($(tail -1 "$out/probe_plain.txt")); using $VK_DRIVER_FILES ($full)"
    else
      echo "manifest: neither the plain one nor one naming $full gives a device:"
      tail -3 "$out/probe_full_path.txt"
    fi
  else
    echo "manifest: the plain one failed and its library ($lib) was not found"
  fi
else
  echo "manifest: ${VK_DRIVER_FILES:-none set, the default search} (a step ran on the device, or --quick)"
fi

stamp "2. tools/gpu_bench.sh (tjsoft, then soft_step)"
timeout 230 tools/gpu_bench.sh --no-build --build-dir "$bin" --seconds "$seconds" \
  --scenes "$scale_scenes" --timeout "$bench_limit" --out "$out/bench_tjsoft" \
  >"$out/gpu_bench_tjsoft.txt" 2>&1
cat "$out/gpu_bench_tjsoft.txt"
timeout 90 tools/gpu_bench.sh --no-build --build-dir "$bin" --seconds "$seconds" \
  --preset soft_step --scenes "pyramid_100 many_pyramids" --timeout 45 \
  --out "$out/bench_soft_step" >"$out/gpu_bench_soft_step.txt" 2>&1
cat "$out/gpu_bench_soft_step.txt"

stamp "3. the scale scenes on the CPU backend ($cpu_seconds s), this machine"
for scene in pyramid_100 many_pyramids pile_100k; do
  for preset in tjsoft soft_step; do
    timeout 25 "$bin/tools/physbench" --scene "configs/scenes/$scene.json" --preset "$preset" \
      --backend cpu --seconds "$cpu_seconds" >"$out/cpu_${scene}_$preset.txt" 2>&1
    echo "$scene $preset exit $?: $(grep -m1 'ms/step' "$out/cpu_${scene}_$preset.txt")"
  done
done

stamp "4. tools/device_scenes.sh (full length against the CPU)"
timeout 150 tools/device_scenes.sh --build-dir "$bin" --jobs 3 --out "$out/scenes" \
  --timeout 120 "${device_scenes[@]}" \
  >"$out/device_scenes.md" 2>"$out/device_scenes.err"
echo "exit $?"
cat "$out/device_scenes.md"

stamp "5. the GPU tests"
timeout 90 "$bin/phys_gpu_tests" --gtest_brief=1 "${test_filter[@]}" >"$out/gpu_tests.txt" 2>&1
echo "exit $?"
grep -E "^\[  (FAILED|PASSED) |^\[==========\]|Failure|Expected|Which is" "$out/gpu_tests.txt" | head -40

stamp "6. the seed paper's Table 2: box_stack and overlap, the five Jacobi solvers, full length"
# The paper's figures (ms/step on its GPU): box stack 7.09 / 54.83 / 7.65 / 10.34 / 10.50,
# overlap 6.80 / 45.28 / 6.42 / 8.92 / 7.83 for PJ / PJNJ / PJSoft / TJ / TJSoft.
table2_seconds=()
[ "$quick" = 1 ] && table2_seconds=(--seconds 0.05)
echo "| scene | preset | result | ms/step median | p99 |"
echo "|---|---|---|---|---|"
for scene in box_stack overlap; do
  for preset in pj pjnj pjsoft tj tjsoft; do
    f="$out/table2_${scene}_$preset.txt"
    timeout 40 "$bin/tools/physbench" --scene "configs/scenes/$scene.json" --preset "$preset" \
      --backend gpu --require-device "${table2_seconds[@]}" >"$f" 2>&1
    rc=$?
    result=$(tail -1 "$f")
    [ "$rc" = 124 ] && result="timed out (40 s)"
    timing=$(sed -n 's/.*ms\/step median \([^ ]*\) *p99 \([^ ]*\).*/\1 | \2/p' "$f" | head -1)
    echo "| $scene | $preset | $result | ${timing:-- | -} |"
  done
done

stamp "done"
rm -rf "$out"
