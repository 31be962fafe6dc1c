#!/usr/bin/env bash
# Soak: physd and 32 scripted clients (build/tools/physsoak) for a given time, the daemon
# killed with SIGKILL and restarted on its data directory a few times (docs/BENCHMARKS.md
# "Soak").
#
#   tools/soak.sh [--seconds 3600] [--kills 5] [--clients 32] [--build DIR] [--out DIR]
#                 [--domain N]
#
# Clients: half editors (each owns a world "soak-<i>": spawns, removals, joints, impulses,
# solver changes, Steps, Run, Pause; after every restart it checks the restored world against
# what was acknowledged), one monitor (tick overruns from phys/status), and subscribers: a
# third of them slow (50 ms per frame), a third killed and restarted at random.
# The kills come between 2 % and 10 % of the run (1 % and 5 %, minutes 0.6 to 3, from an
# hour on), so the daemon that runs from then to the end is well past its restore by a sixth
# of the run (minute 10) and shows whether memory grows under load from there.
#
# Reports: replies lost (must be 0), restore mismatches (must be 0), daemon crashes (must be
# 0), kills, tick overruns, frames received, daemon RSS over time (rss.csv) and its growth
# from a sixth of the run to the end (means of the first and last 5 minutes of that span;
# under 5 % for a run of an hour or more), and beside it what the memory should follow
# (memory.csv from the monitor: the daemon's heap in use, its worlds' bodies, joints,
# contacts and step buffers). Exits 1 when a must-be-zero count is not.
set -uo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
seconds=3600 kills=5 clients=32 build="$root/build" out="" domain=$((100 + $$ % 100))
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --kills) kills="$2"; shift 2 ;;
    --clients) clients="$2"; shift 2 ;;
    --build) build="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --domain) domain="$2"; shift 2 ;;
    *) echo "usage: $0 [--seconds S] [--kills K] [--clients N] [--build DIR] [--out DIR] [--domain N]" >&2; exit 2 ;;
  esac
done
for b in "$build/server/physd" "$build/tools/physsoak"; do
  [ -x "$b" ] || { echo "missing $b (build first)" >&2; exit 2; }
done
[ -n "$out" ] || out=$(mktemp -d /tmp/physd_soak.XXXXXX)
mkdir -p "$out/bin"
# Copies: a rebuild during the run must not change the daemon that restarts.
cp "$build/server/physd" "$build/tools/physsoak" "$out/bin/"
physd="$out/bin/physd" soak="$out/bin/physsoak"
rm -rf "$out/data" "$out/clients.jsonl" "$out/rss.csv" "$out/memory.csv" "$out"/physd*.log
# Loopback Cyclone with a discovery tag of this run: other runs and tests never see it.
sed "s|<Discovery>|<Discovery><Tag>physd-soak-$$</Tag>|" "$root/configs/cyclonedds/loopback.xml" >"$out/cyclone.xml"
cat >"$out/physd.toml" <<EOF
[server]
name = "physd-soak"
log_level = "warn"
status_period_s = 1.0
[dds]
domain = $domain
config = "$out/cyclone.xml"
[paths]
presets = "$root/configs/presets.json"
scenes = "$root/configs/scenes"
snapshots = "$out/snapshots"
data = "$out/data"
EOF

now() { date +%s.%N; }
t0=$(now)
elapsed() { echo "$(now) - $t0" | bc; }
epoch=0
start_physd() {
  epoch=$((epoch + 1))
  "$physd" --config "$out/physd.toml" >>"$out/physd.$epoch.log" 2>&1 &
  pid=$!
}
start_physd

editors=$((clients / 2))
subs=$((clients - editors - 1))
cpids=()
lastpid=0
client() {  # role index seconds [more physsoak options]: in the background, its pid in lastpid
  "$soak" --role "$1" --index "$2" --seconds "$3" --domain "$domain" --config "$out/cyclone.xml" \
    --seed "$((1000 + $2))" --out "$out/clients.jsonl" "${@:4}" >/dev/null 2>>"$out/clients.err" &
  lastpid=$!
}
for i in $(seq 1 "$editors"); do client editor "$i" "$seconds"; cpids+=("$lastpid"); done
client monitor 0 "$seconds" --memory "$out/memory.csv"; cpids+=("$lastpid")
churn=()
declare -A churnpid
for i in $(seq 1 "$subs"); do
  case $((i % 3)) in
    0) client slow "$i" "$seconds"; cpids+=("$lastpid") ;;
    1) client subscriber "$i" "$seconds"; cpids+=("$lastpid") ;;
    2) churn+=("$i"); client subscriber "$i" "$seconds"; churnpid[$i]=$lastpid ;;
  esac
done

# Kill times: spread over [2 %, 10 %] of the run; from an hour on, over [1 %, 5 %] (minutes
# 0.6 to 3): a restored daemon takes about a quarter of an hour to grow its step buffers to
# their working set (the hour of 2026-11-27: restored at minute 6, flat from minute 21), and
# the memory criterion measures from minute 10.
killat=()
span=$((kills > 1 ? kills - 1 : 1))
lo=0.02 hi=0.10
[ "$seconds" -ge 3600 ] && lo=0.01 hi=0.05
for k in $(seq 1 "$kills"); do
  killat+=("$(echo "$seconds * ($lo + ($hi - $lo) * ($k - 1) / $span)" | bc -l)")
done
killed=0 crashes=0 next=0
echo "t_s,rss_kb,epoch" >"$out/rss.csv"
echo "soak: $seconds s, $clients clients ($editors editors, 1 monitor, $subs subscribers), $kills kills, domain $domain, out $out"
while :; do
  t=$(elapsed)
  (( $(echo "$t >= $seconds" | bc) )) && break
  if ! kill -0 "$pid" 2>/dev/null; then
    wait "$pid"; rc=$?
    echo "physd exited by itself at ${t}s (status $rc): a crash"
    crashes=$((crashes + 1))
    start_physd
  fi
  if [ "$next" -lt "${#killat[@]}" ] && (( $(echo "$t >= ${killat[$next]}" | bc) )); then
    kill -KILL "$pid"; wait "$pid" 2>/dev/null
    killed=$((killed + 1)); next=$((next + 1))
    echo "killed physd (SIGKILL) at ${t}s"
    sleep 1
    start_physd
  fi
  # A churn subscriber is killed and started again now and then.
  if [ "${#churn[@]}" -gt 0 ] && [ $((RANDOM % 20)) -eq 0 ]; then
    i=${churn[$((RANDOM % ${#churn[@]}))]}
    kill -KILL "${churnpid[$i]}" 2>/dev/null; wait "${churnpid[$i]}" 2>/dev/null
    left=$(echo "$seconds - $t" | bc | cut -d. -f1)
    if [ "${left:-0}" -gt 2 ]; then client subscriber "$i" "$left"; churnpid[$i]=$lastpid; fi
  fi
  rss=$(ps -o rss= -p "$pid" 2>/dev/null | tr -d ' ')
  [ -n "$rss" ] && echo "$(printf '%.1f' "$t"),$rss,$epoch" >>"$out/rss.csv"
  sleep 2
done

# The clients end by themselves; then physd stops on SIGTERM (exit 0 expected).
for p in "${cpids[@]}"; do wait "$p" 2>/dev/null; done
for i in "${churn[@]}"; do kill -TERM "${churnpid[$i]}" 2>/dev/null; wait "${churnpid[$i]}" 2>/dev/null; done
if kill -0 "$pid" 2>/dev/null; then
  kill -TERM "$pid"; wait "$pid"; rc=$?
  [ "$rc" -ne 0 ] && { echo "physd exited $rc on SIGTERM"; crashes=$((crashes + 1)); }
else
  crashes=$((crashes + 1))
fi

python3 - "$out" "$seconds" "$killed" "$crashes" "$t0" <<'EOF'
import json, sys
out, seconds, killed, crashes = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
t0 = float(sys.argv[5])
rows = [json.loads(l) for l in open(out + "/clients.jsonl") if l.strip()]
def total(k, role=None):
    return sum(r[k] for r in rows if role is None or r["role"] == role)
editors = [r for r in rows if r["role"] == "editor"]
failed = [r for r in rows if not r["ok"]]
rss = [l.strip().split(",") for l in open(out + "/rss.csv")][1:]
rss = [(float(t), int(k), int(e)) for t, k, e in rss]
last = [r for r in rss if r[2] == rss[-1][2]] if rss else []
# Growth from a sixth of the run to its end, of the last daemon: the mean over the first
# window from then against the mean over the last one (a tenth of that span, at most 5
# minutes). The daemon's memory follows its worlds' activity, which swings within seconds
# (contacts by a factor of 2 in the soak), so single samples at either end would measure
# the swing, not a trend.
span0 = max(seconds / 6, last[0][0]) if last else seconds / 6
window = max(10.0, min(300.0, (seconds - span0) / 10))
def ends(rows, t):  # rows (t, ...) from span0 on: the first and the last window
    rows = [r for r in rows if t(r) >= span0]
    if len(rows) < 2:
        return None, None
    a = [r for r in rows if t(r) <= t(rows[0]) + window]
    b = [r for r in rows if t(r) >= t(rows[-1]) - window]
    return a, b
growth = None
a, b = ends(last, lambda r: r[0])
if a:
    ma, mb = sum(r[1] for r in a) / len(a), sum(r[1] for r in b) / len(b)
    growth = (mb - ma) / ma * 100
print(f"clients: {len(rows)} reported ({len(editors)} editors), {len(failed)} failed to run")
print(f"acknowledged commands: {total('acked', 'editor')}, refused with a status: {total('refused', 'editor')}")
print(f"replies lost: {total('lost')}")
print(f"cut off by a kill (retried): {total('cut_by_kill')}; restarts seen by editors: {total('restarts', 'editor')}")
print(f"restore checks: {total('checks')}, mismatches: {total('mismatches')}")
for r in rows:
    if r["mismatches"]:
        print("  mismatch:", r["last_mismatch"])
print(f"daemon kills: {killed}, crashes: {crashes}")
print(f"tick overruns (all worlds, all daemons): {total('overruns', 'monitor')}")
print(f"state frames received by subscribers: {total('frames')}")
if rss:
    print(f"daemon RSS: first {rss[0][1]} kB, max {max(r[1] for r in rss)} kB, last {rss[-1][1]} kB")
if growth is not None:
    print(f"RSS growth of the last daemon from {span0:.0f} s to the end (means of the first and"
          f" last {window:.0f} s): {ma / 1024:.1f} -> {mb / 1024:.1f} MiB, {growth:+.1f} %")
# What the memory should follow (memory.csv, from the monitor's phys/status samples): the
# heap in use and the worlds' activity, at the same two ends as the RSS.
try:
    mem = [l.strip().split(",") for l in open(out + "/memory.csv")][1:]
    mem = [(float(r[0]) - t0,) + tuple(int(x) for x in r[1:]) for r in mem if r[0][0].isdigit()]
    a, b = ends([r for r in mem if r[2] > 0], lambda r: r[0])
    if a:
        def avg(rows, i): return sum(r[i] for r in rows) / len(rows)
        for name, i, unit in (("heap in use", 1, 1e6), ("step buffers", 7, 1e6),
                              ("contacts", 6, 1), ("awake bodies", 4, 1), ("bodies", 3, 1),
                              ("joints", 5, 1)):
            print(f"{name} (all worlds): {avg(a, i) / unit:.1f} -> {avg(b, i) / unit:.1f}"
                  + (" MB" if unit > 1 else ""))
except (OSError, ValueError, IndexError):
    pass
bad = total('lost') + total('mismatches') + crashes + len(failed)
if seconds >= 3600 and growth is not None and growth >= 5:
    print("RSS grew 5 % or more"); bad += 1
print("PASS" if bad == 0 else "FAIL")
sys.exit(0 if bad == 0 else 1)
EOF
