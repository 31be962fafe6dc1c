#!/usr/bin/env bash
# A domain of daemons on this machine (docs/SERVER.md "Several daemons"): N physd processes
# on loopback DDS, each with its own server.id (1..N), [cluster] enabled, and its own data
# directory under RUN_DIR. Worlds created without naming a daemon are placed by the SDK
# (physctl create, Python create_world); `physctl daemons` and `physctl list` show where they
# are. Ctrl-C (or SIGTERM) stops every daemon.
#
# --etcd PORT adds the coordinator (docs/SERVER.md "Standby and takeover"): an etcd on
# 127.0.0.1:PORT (its data under RUN_DIR/etcd; Debian's etcd-server), and each daemon i gets
# daemon i+1 (N: 1) as the standby of its kept worlds: kill one and the next takes them over.
#
#   tools/cluster.sh [--daemons N] [--domain D] [--run-dir DIR] [--memory] [--etcd PORT]
#   build/tools/physctl --domain D daemons
#
# Build first (./test.sh or ./run.sh builds build/); PHYSD overrides the binary.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
N=3
DOMAIN=0
RUN_DIR=/tmp/physd-cluster
MEMORY=0
ETCD_PORT=0
while [ $# -gt 0 ]; do
  case "$1" in
    --daemons) N=$2; shift 2 ;;
    --domain) DOMAIN=$2; shift 2 ;;
    --run-dir) RUN_DIR=$2; shift 2 ;;
    --memory) MEMORY=1; shift ;;
    --etcd) ETCD_PORT=$2; shift 2 ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    *) echo "cluster.sh: unknown argument $1" >&2; exit 2 ;;
  esac
done
PHYSD=${PHYSD:-$ROOT/build/server/physd}
[ -x "$PHYSD" ] || { echo "cluster.sh: no $PHYSD (build first: ./test.sh -L unit)" >&2; exit 1; }
if [ "$N" -lt 1 ] || [ "$N" -gt 4095 ]; then echo "cluster.sh: --daemons 1..4095" >&2; exit 2; fi

PIDS=()
stop_all() {
  for p in "${PIDS[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  for p in "${PIDS[@]}"; do wait "$p" 2>/dev/null || true; done
}
trap 'stop_all; exit 0' INT TERM
COORDINATOR=""
if [ "$ETCD_PORT" != 0 ]; then
  [ "$MEMORY" = 1 ] && { echo "cluster.sh: --etcd needs kept worlds (not --memory)" >&2; exit 2; }
  command -v etcd >/dev/null || { echo "cluster.sh: no etcd (apt-get install etcd-server)" >&2; exit 1; }
  mkdir -p "$RUN_DIR/etcd"
  etcd --name cluster --data-dir "$RUN_DIR/etcd/data" \
    --listen-client-urls "http://127.0.0.1:$ETCD_PORT" --advertise-client-urls "http://127.0.0.1:$ETCD_PORT" \
    --listen-peer-urls "http://127.0.0.1:$((ETCD_PORT + 1))" \
    --initial-advertise-peer-urls "http://127.0.0.1:$((ETCD_PORT + 1))" \
    --initial-cluster "cluster=http://127.0.0.1:$((ETCD_PORT + 1))" >"$RUN_DIR/etcd/etcd.log" 2>&1 &
  PIDS+=($!)
  COORDINATOR="http://127.0.0.1:$ETCD_PORT"
  for _ in $(seq 100); do
    (exec 3<>"/dev/tcp/127.0.0.1/$ETCD_PORT") 2>/dev/null && break
    sleep 0.1
  done
  echo "etcd: $COORDINATOR (log $RUN_DIR/etcd/etcd.log)"
fi
for i in $(seq 1 "$N"); do
  dir="$RUN_DIR/d$i"
  mkdir -p "$dir"
  data="$dir/data"
  [ "$MEMORY" = 1 ] && data=""
  cat >"$dir/physd.toml" <<TOML
[server]
name = "physd-$i"
id = $i
log_level = "info"
[cluster]
enabled = true
$([ -n "$COORDINATOR" ] && printf 'coordinator = "%s"\nstandby = %d\n' "$COORDINATOR" $((N > 1 ? i % N + 1 : 0)))
[dds]
domain = $DOMAIN
config = "$ROOT/configs/cyclonedds/loopback.xml"
[paths]
presets = "$ROOT/configs/presets.json"
scenes = "$ROOT/configs/scenes"
snapshots = "$dir/snapshots"
data = "$data"
TOML
  "$PHYSD" --config "$dir/physd.toml" >"$dir/physd.log" 2>&1 &
  PIDS+=($!)
  echo "physd-$i (server.id $i): pid $! log $dir/physd.log"
done
echo "domain $DOMAIN; Ctrl-C stops the $N daemons"
wait
