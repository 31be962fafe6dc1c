#!/usr/bin/env bash
# A domain of daemons on this machine (docs/SERVER.md "Several daemons"): N physd processes
# on loopback DDS, each with its own server.id (1..N), [cluster] enabled, and its own data
# directory under RUN_DIR. Worlds created without naming a daemon are placed by the SDK
# (physctl create, Python create_world); `physctl daemons` and `physctl list` show where they
# are. Ctrl-C (or SIGTERM) stops every daemon.
#
#   tools/cluster.sh [--daemons N] [--domain D] [--run-dir DIR] [--memory]
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
while [ $# -gt 0 ]; do
  case "$1" in
    --daemons) N=$2; shift 2 ;;
    --domain) DOMAIN=$2; shift 2 ;;
    --run-dir) RUN_DIR=$2; shift 2 ;;
    --memory) MEMORY=1; shift ;;
    -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
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
