# Sourced by the daemon benchmarks (fanout_bench.sh, idle_bench.sh): starts physd with
# $config from $build, defines ctl (physctl on the config's DDS domain), $out (a scratch
# directory removed on exit, physd's log in it) and $daemon (its pid), and waits until it
# answers (up to wait_s seconds, default 60: ten 10,000-body worlds take a while to load).
physd="$build/server/physd" physctl="$build/tools/physctl"
domain="$(sed -n 's/^domain *= *\([0-9]*\).*/\1/p' "$config" | head -1)"
ctl() { "$physctl" --domain "$domain" "$@"; }
out="$(mktemp -d)"
cleanup() { [[ -n "${daemon:-}" ]] && kill "$daemon" 2>/dev/null; wait 2>/dev/null || true; rm -rf "$out"; }
trap cleanup EXIT
"$physd" --config "$config" > "$out/physd.log" 2>&1 &
daemon=$!
for _ in $(seq $((${wait_s:-60} * 5))); do ctl --timeout 500 list > /dev/null 2>&1 && break; sleep 0.2; done
