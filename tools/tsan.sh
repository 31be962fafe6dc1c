#!/usr/bin/env bash
# ThreadSanitizer (issue 26): the server, client, protocol and unit tests (the thread pool's
# determinism tests among them) in a -fsanitize=thread build, build-tsan/.
#
#   tools/tsan.sh [--build DIR] [--labels REGEX] [ctest arguments...]
#
#   --build   the build directory (default build-tsan; configured and built when needed)
#   --labels  the ctest labels (default "server|client|protocol|unit")
#   anything else goes to ctest (-R NAME, -j 2, ...)
#
# The build has no Vulkan backend (-DPHYS_WITH_GPU=OFF): the Mesa driver is not instrumented
# and its threads would be all TSan sees there; GPU worlds of the server tests run on the CPU
# and say so. Reports inside Cyclone DDS, its security plugins and OpenSSL are suppressed by
# tools/tsan.supp, each entry with its reason; nothing of ours is. A TSan report fails the run
# even where the process that printed it was a child whose exit status no test reads (a
# physd started by a client test): the script reads every test's output for one.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
build="$root/build-tsan" labels="server|client|protocol|unit"
ctest_args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --build) build="$2"; shift 2 ;;
    --labels) labels="$2"; shift 2 ;;
    *) ctest_args+=("$1"); shift ;;
  esac
done

if [ ! -f "$build/build.ninja" ]; then
  cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPHYS_SANITIZE=thread -DPHYS_WITH_GPU=OFF -DPHYS_WITH_PEERS=OFF
fi
cmake --build "$build"

# halt_on_error=0: every report of a run, not only the first; a process with a report exits 66.
export TSAN_OPTIONS="suppressions=$root/tools/tsan.supp halt_on_error=0 second_deadlock_stack=1 history_size=4"
status=0
# The browser test is left out (chromium and node are not instrumented, and it is about the
# page, not our threads); the Python bindings and the package test are not built here.
ctest --test-dir "$build" -L "$labels" -LE viewer --output-on-failure --timeout 3600 \
  "${ctest_args[@]}" || status=$?
log="$build/Testing/Temporary/LastTest.log"
reports=$(grep -c "WARNING: ThreadSanitizer" "$log" || true)
echo "tsan: $reports report(s) in $log"
if [ "$reports" -gt 0 ]; then
  grep -B2 "WARNING: ThreadSanitizer" "$log" | grep -E "^(Test: |WARNING)" | head -20
  [ "$status" -ne 0 ] || status=1
fi
exit "$status"
