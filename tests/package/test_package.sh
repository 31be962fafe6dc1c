#!/usr/bin/env bash
# The SDK as a package (issues 25, 44): `cmake --install` into a scratch prefix, then
# client_sdk/examples built as an outside project twice, with find_package(phys CONFIG) and
# with pkg-config, and both programs run against a physd of their own. The client carries
# nothing of the engine: its project configures with Eigen3 and Vulkan made unfindable, its
# headers, compile and link lines and its program's shared libraries name none of Eigen,
# qhull, Vulkan or phys_core, and the client's exported targets name none of them. A second
# outside project asks for the engine (COMPONENTS core) and steps a world in process.
#
#   tests/package/test_package.sh BUILD_DIR
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
build="$(cd "$1" && pwd)"
scratch=$(mktemp -d /tmp/phys_package.XXXXXX)
pid=""
cleanup() {
  [ -n "$pid" ] && kill -TERM "$pid" 2>/dev/null && wait "$pid" 2>/dev/null
  rm -rf "$scratch"
}
trap cleanup EXIT
prefix="$scratch/prefix"

echo "== cmake --install $build --prefix $prefix"
cmake --install "$build" --prefix "$prefix" >/dev/null
for f in lib/libphysclient.a lib/libphys_core.a lib/cmake/phys/physConfig.cmake \
         lib/cmake/phys/physTargets.cmake lib/cmake/phys/physCoreTargets.cmake \
         lib/pkgconfig/phys-client.pc include/phys/client/client.h include/phys/defs/body_def.h \
         include/phys/protocol/physics_generated.h include/phys/world/world.h; do
  [ -f "$prefix/$f" ] || { echo "not installed: $f"; exit 1; }
done
# What the engine needs, by name, that a client must not (the libraries' files and targets).
engine='eigen|qhull|vulkan|phys_core|phys_gpu|phys::core|phys::gpu'
nothing_of_engine() {  # WHAT FILE...: fails naming the lines of FILE that match $engine
  local what=$1
  shift
  if grep -inE "$engine" "$@"; then
    echo "$what names the engine or its dependencies (above)"
    exit 1
  fi
}
nothing_of_engine "the client's exported targets" "$prefix/lib/cmake/phys/physTargets.cmake" \
  "$prefix/lib/cmake/phys/physTargets-"*.cmake "$prefix/lib/pkgconfig/phys-client.pc"
# Every header client.h reaches, system headers too: none of the engine's, Eigen's or Vulkan's.
g++ -std=c++20 -M -I"$prefix/include" -x c++ "$prefix/include/phys/client/client.h" \
  | tr ' \\' '\n\n' | grep -v '^$' >"$scratch/client_headers.txt"
grep -q 'phys/defs/body_def.h' "$scratch/client_headers.txt" || { echo "no header list"; exit 1; }
if grep -E '/phys/(world|collision|gpu)/|eigen|vulkan|qhull' "$scratch/client_headers.txt"; then
  echo "client.h includes headers of the engine (above)"
  exit 1
fi

echo "== find_package(phys CONFIG) from an outside project, without Eigen3 and Vulkan"
# Only the prefix: nothing of the source or build tree is on any path. Eigen3 and Vulkan
# cannot be found (as on a machine without libeigen3-dev and libvulkan-dev): the client's
# package must not ask for them.
cmake -S "$root/client_sdk/examples" -B "$scratch/ex" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_DISABLE_FIND_PACKAGE_Eigen3=ON \
  -DCMAKE_DISABLE_FIND_PACKAGE_Vulkan=ON -DCMAKE_DISABLE_FIND_PACKAGE_Qhull=ON \
  >"$scratch/configure.log" 2>&1 || { cat "$scratch/configure.log"; exit 1; }
cmake --build "$scratch/ex" >"$scratch/build.log" 2>&1 || { cat "$scratch/build.log"; exit 1; }
nothing_of_engine "the example's compile and link lines" "$scratch/ex/build.ninja"

echo "== pkg-config phys-client"
export PKG_CONFIG_PATH="$prefix/lib/pkgconfig"
# shellcheck disable=SC2046
g++ -O1 -o "$scratch/minimal_pc" "$root/client_sdk/examples/minimal.cpp" \
  $(pkg-config --cflags --libs phys-client)
for exe in "$scratch/ex/minimal" "$scratch/minimal_pc"; do
  ldd "$exe" >"$scratch/ldd.txt"
  grep -q 'libddsc' "$scratch/ldd.txt" || { echo "$exe: no ldd listing"; exit 1; }
  nothing_of_engine "ldd $exe" "$scratch/ldd.txt"
done

echo "== find_package(phys CONFIG COMPONENTS core): the engine in process"
cmake -S "$root/tests/package/in_process" -B "$scratch/core" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$prefix" >"$scratch/core_configure.log" 2>&1 ||
  { cat "$scratch/core_configure.log"; exit 1; }
cmake --build "$scratch/core" >"$scratch/core_build.log" 2>&1 || { cat "$scratch/core_build.log"; exit 1; }
out=$("$scratch/core/fall")
echo "$out"
# A unit cube of 1000 kg/m^3 built from its corners' hull (and an interior point it drops),
# after 1 s of free fall from 10 m: z = 10 - g/2 = 5.095 m, within the integrator's
# first-order error (g h / 2 per second at h = 1/60 s / 6 substeps: 0.014 m).
python3 - "$out" <<'PY'
import re, sys
m = re.search(r"mass=([0-9.]+) z=(-?[0-9.]+) t=([0-9.]+)", sys.argv[1])
assert m, sys.argv[1]
mass, z, t = map(float, m.groups())
assert abs(mass - 1000.0) < 0.1, f"mass {mass}"
assert abs(t - 1.0) < 1e-4, f"time {t}"
assert abs(z - (10.0 - 9.81 / 2)) < 0.02, f"z {z}"
PY

echo "== both against a physd"
domain=232  # the package test's own (docs/CLIENT.md "Tests"); the Tag isolates it further
sed "s|<Discovery>|<Discovery><Tag>phys-package-$$</Tag>|" "$root/configs/cyclonedds/loopback.xml" \
  >"$scratch/cyclone.xml"
cat >"$scratch/physd.toml" <<TOML
[server]
name = "physd-package-test"
log_level = "warn"
[dds]
domain = $domain
config = "$scratch/cyclone.xml"
[paths]
presets = "$root/configs/presets.json"
scenes = "$root/configs/scenes"
snapshots = "$scratch/snapshots"
data = "$scratch/data"
TOML
"$build/server/physd" --config "$scratch/physd.toml" >"$scratch/physd.log" 2>&1 &
pid=$!
export CYCLONEDDS_URI="file://$scratch/cyclone.xml"
for exe in "$scratch/ex/minimal" "$scratch/minimal_pc"; do
  out=$("$exe" "$domain" 2>&1) || { echo "$exe failed:"; echo "$out"; cat "$scratch/physd.log"; exit 1; }
  echo "$out"
  # Connected to this daemon, spawned the ground and five unit boxes (centres 0.5, 1.6, ...,
  # 4.9 m), and received frames in which the stack has settled: the top box's centre at
  # 4.5 m, four boxes on one another, none through the ground or still in the air.
  grep -q "connected to physd-package-test" <<<"$out" || { echo "no connection line"; exit 1; }
  grep -q "spawned 6 bodies" <<<"$out" || { echo "no spawn line"; exit 1; }
  frames=$(grep -c "^tick " <<<"$out" || true)
  [ "$frames" -ge 3 ] || { echo "only $frames frames"; exit 1; }
  python3 - "$out" <<'PY'
import re, sys
z = [float(m) for m in re.findall(r"top box z=(-?[0-9.]+)", sys.argv[1])]
assert z and all(0.0 < v <= 4.95 for v in z), f"top box heights out of range: {z}"
assert abs(z[-1] - 4.5) < 0.05, f"the stack did not settle at 4.5 m: {z}"
PY
done
echo "package test passed"
