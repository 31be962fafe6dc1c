#!/usr/bin/env bash
# How fast an etcd lease lets go of a key when its holder dies (groundwork for issue 45,
# docs/BENCHMARKS.md "etcd leases"): a private single-member etcd on loopback, a key put
# under a lease of TTL seconds and kept alive by `etcdctl lease keep-alive`, which is then
# killed with SIGKILL; a watch reports the key's deletion. Prints the lease the server
# granted and, per trial, the time from the kill to the deletion.
#
#   tools/etcd_lease_probe.sh [TTL=1] [TRIALS=5] [HEARTBEAT_MS=10] [ELECTION_MS=100]
#
# Needs etcd-server and etcd-client (Debian packages). Ports 23791/23801.
set -u
ttl=${1:-1} trials=${2:-5} heartbeat=${3:-10} election=${4:-100}
dir=$(mktemp -d /tmp/etcd_probe.XXXXXX)
E="etcdctl --endpoints=http://127.0.0.1:23791"
now() { date +%s.%N; }
t0=$(now)
etcd --name probe --data-dir "$dir/data" --listen-client-urls http://127.0.0.1:23791 \
  --advertise-client-urls http://127.0.0.1:23791 --listen-peer-urls http://127.0.0.1:23801 \
  --initial-advertise-peer-urls http://127.0.0.1:23801 \
  --initial-cluster probe=http://127.0.0.1:23801 --heartbeat-interval "$heartbeat" \
  --election-timeout "$election" --log-level error >"$dir/etcd.log" 2>&1 &
etcd_pid=$!
trap 'kill $etcd_pid 2>/dev/null; wait $etcd_pid 2>/dev/null; rm -rf "$dir"' EXIT
until $E endpoint health >/dev/null 2>&1; do sleep 0.02; done
echo "etcd $(etcd --version | head -1 | awk '{print $3}') ready after $(echo "$(now) - $t0" | bc) s (heartbeat $heartbeat ms, election $election ms)"
lease=$($E lease grant "$ttl" | awk '{print $2}')
$E lease timetolive "$lease"
for trial in $(seq "$trials"); do
  lease=$($E lease grant "$ttl" | awk '{print $2}')
  $E put probe/owner holder --lease="$lease" >/dev/null
  $E lease keep-alive "$lease" >/dev/null 2>&1 &
  keeper=$!
  sleep 0.5
  $E watch probe/owner >"$dir/watch" 2>&1 &
  watcher=$!
  sleep 0.3
  killed=$(now)
  kill -9 "$keeper"
  wait "$keeper" 2>/dev/null
  until grep -q DELETE "$dir/watch"; do sleep 0.005; done
  echo "trial $trial: the key was deleted $(echo "$(now) - $killed" | bc) s after the holder's SIGKILL"
  kill "$watcher" 2>/dev/null
  wait "$watcher" 2>/dev/null
done
exit 0
