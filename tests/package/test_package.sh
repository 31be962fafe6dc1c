#!/usr/bin/env bash
# The SDK as a package (issue 25): `cmake --install` into a scratch prefix, then
# client_sdk/examples built as an outside project twice, with find_package(phys CONFIG) and
# with pkg-config, and both programs run against a physd of their own.
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
         lib/pkgconfig/phys-client.pc include/phys/client/client.h \
         include/phys/protocol/physics_generated.h include/phys/world/world.h; do
  [ -f "$prefix/$f" ] || { echo "not installed: $f"; exit 1; }
done

echo "== find_package(phys CONFIG) from an outside project"
# Only the prefix: nothing of the source or build tree is on any path.
cmake -S "$root/client_sdk/examples" -B "$scratch/ex" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$prefix" >"$scratch/configure.log" 2>&1 || { cat "$scratch/configure.log"; exit 1; }
cmake --build "$scratch/ex" >"$scratch/build.log" 2>&1 || { cat "$scratch/build.log"; exit 1; }

echo "== pkg-config phys-client"
export PKG_CONFIG_PATH="$prefix/lib/pkgconfig"
# shellcheck disable=SC2046
g++ -O1 -o "$scratch/minimal_pc" "$root/client_sdk/examples/minimal.cpp" \
  $(pkg-config --cflags --libs phys-client)

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
