# Sourced by the daemon benchmarks (fanout_bench.sh, idle_bench.sh): starts physd with
# $config from $build, defines ctl (physctl on the daemon's DDS domain and Cyclone config), $out
# (a scratch directory removed on exit, physd's log in it) and $daemon (its pid), and waits until
# it answers (up to wait_s seconds, default 60: ten 10,000-body worlds take a while to load).
#
# physd runs a copy of $config in $out: its relative paths made absolute, on $domain when the
# caller set one (else the config's; "auto": one from this shell's process id, 1-200, as the
# tests pick theirs), on the loopback Cyclone config with a discovery tag of
# this run (other runs and tests on the same domain never see it); $scene, when set, replaces
# every start-up world's scene and $max_worlds, when set, keeps the first that many (how ctest
# runs the benchmarks at a tiny size).
#
# world_json FILE NAME FIELD: FIELD of the world NAME in FILE (physctl list --json's output).
physd="$build/server/physd" physctl="$build/tools/physctl"
for b in "$physd" "$physctl"; do
  [[ -x "$b" ]] || { echo "missing $b (build physd and physctl first)" >&2; exit 2; }
done
domain="${domain:-$(sed -n 's/^domain *= *\([0-9]*\).*/\1/p' "$config" | head -1)}"
[[ "$domain" == auto ]] && domain=$((1 + $$ % 200))
out="$(mktemp -d)"
cleanup() { [[ -n "${daemon:-}" ]] && kill "$daemon" 2>/dev/null; wait 2>/dev/null || true; rm -rf "$out"; }
trap cleanup EXIT
sed "s|<Discovery>|<Discovery><Tag>physd-bench-$$</Tag>|" "$root/configs/cyclonedds/loopback.xml" > "$out/cyclone.xml"
awk -v dir="$(cd "$(dirname "$config")" && pwd)" -v domain="$domain" -v xml="$out/cyclone.xml" \
    -v scene="${scene:-}" -v max="${max_worlds:-0}" '
  /^\[\[worlds\]\]/ { n++ }
  max > 0 && n > max { next }
  /^domain *=/ { print "domain = " domain; next }
  /^config *=/ { print "config = \"" xml "\""; next }
  scene != "" && /^scene *=/ { print "scene = \"" scene "\""; next }
  /^(presets|scenes|snapshots|data) *= *"[^\/]/ { sub(/"/, "\"" dir "/") }
  { print }' "$config" > "$out/physd.toml"
ctl() { "$physctl" --domain "$domain" --config "$out/cyclone.xml" "$@"; }
world_json() {
  python3 - "$@" <<'PY'
import json, sys
for w in json.load(open(sys.argv[1])):
    if w["name"] == sys.argv[2]:
        print(w[sys.argv[3]])
        break
else:
    sys.exit(f"no world {sys.argv[2]} in {sys.argv[1]}")
PY
}
"$physd" --config "$out/physd.toml" > "$out/physd.log" 2>&1 &
daemon=$!
for _ in $(seq $((${wait_s:-60} * 5))); do
  ctl --timeout 500 list > /dev/null 2>&1 && break
  kill -0 "$daemon" 2>/dev/null || { echo "physd exited at start-up:" >&2; cat "$out/physd.log" >&2; exit 1; }
  sleep 0.2
done
ctl --timeout 2000 list > /dev/null || { echo "physd did not answer within ${wait_s:-60} s" >&2; exit 1; }
