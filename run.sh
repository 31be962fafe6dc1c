#!/usr/bin/env bash
# Installs what is missing, builds, starts physd on the default scene in the background, the
# browser viewer physview beside it (its URL printed; PHYSVIEW_PORT, default 8088), and shows
# the worlds live with `physctl watch`. Ctrl-C stops all three. Extra arguments go to physctl
# watch.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/common.sh
phys_install_deps
phys_build build

CONFIG=configs/physd.toml
PIDFILE=build/physd.pid
LOG=build/physd.log
VIEW_PIDFILE=build/physview.pid
VIEW_LOG=build/physview.log
PHYSVIEW_PORT=${PHYSVIEW_PORT:-8088}

# A daemon (or viewer) left over from an earlier run.sh (its pid file) is stopped first.
stop_left_over() {
  local pidfile=$1 comm=$2
  if [ -f "$pidfile" ]; then
    local old
    old=$(cat "$pidfile")
    if [ -n "$old" ] && kill -0 "$old" 2>/dev/null && [ "$(ps -o comm= -p "$old")" = "$comm" ]; then
      echo "stopping the $comm left running by an earlier run.sh (pid $old)"
      kill -TERM "$old" 2>/dev/null || true
      for _ in $(seq 50); do kill -0 "$old" 2>/dev/null || break; sleep 0.1; done
    fi
    rm -f "$pidfile"
  fi
}
stop_left_over "$VIEW_PIDFILE" physview
stop_left_over "$PIDFILE" physd

build/server/physd --config "$CONFIG" >"$LOG" 2>&1 &
PHYSD=$!
echo "$PHYSD" >"$PIDFILE"

PHYSVIEW=""
stop_daemon() {
  trap - EXIT INT TERM
  if [ -n "$PHYSVIEW" ] && kill -0 "$PHYSVIEW" 2>/dev/null; then
    kill -TERM "$PHYSVIEW" 2>/dev/null || true
    wait "$PHYSVIEW" 2>/dev/null || true
    rm -f "$VIEW_PIDFILE"
    echo "physview stopped (log: $VIEW_LOG)"
  fi
  if kill -0 "$PHYSD" 2>/dev/null; then
    kill -TERM "$PHYSD" 2>/dev/null || true
    wait "$PHYSD" 2>/dev/null || true
  fi
  rm -f "$PIDFILE"
  echo "physd stopped (log: $LOG)"
}
trap stop_daemon EXIT
trap 'exit 130' INT TERM

# The config's start-up world runs the default scene: wait until physd lists it running.
echo "starting physd ($CONFIG, log $LOG) ..."
ok=0
for _ in $(seq 30); do
  if ! kill -0 "$PHYSD" 2>/dev/null; then
    echo "physd exited during start-up:" >&2
    cat "$LOG" >&2
    exit 1
  fi
  listed=$(build/tools/physctl --timeout 2000 list 2>/dev/null || true)
  if echo "$listed" | grep -Eq '^ +[0-9]+ +default .* running'; then
    ok=1
    break
  fi
  # Restored paused from an earlier run (worlds are kept in [paths] data): run it again.
  if echo "$listed" | grep -Eq '^ +[0-9]+ +default '; then
    build/tools/physctl --timeout 2000 run default >/dev/null 2>&1 || true
  fi
  sleep 0.5
done
if [ "$ok" != 1 ]; then
  echo "physd did not report its default world running; log:" >&2
  cat "$LOG" >&2
  exit 1
fi

# The browser viewer beside physd (tools/physview; built when CivetWeb and npm are there). Its
# port taken: a free one.
if [ -x build/tools/physview/physview ]; then
  for port in "$PHYSVIEW_PORT" 0; do
    build/tools/physview/physview --port "$port" >"$VIEW_LOG" 2>&1 &
    PHYSVIEW=$!
    for _ in $(seq 100); do
      grep -q 'serving http' "$VIEW_LOG" 2>/dev/null && break
      kill -0 "$PHYSVIEW" 2>/dev/null || break
      sleep 0.1
    done
    grep -q 'serving http' "$VIEW_LOG" 2>/dev/null && break
    kill -TERM "$PHYSVIEW" 2>/dev/null || true
    wait "$PHYSVIEW" 2>/dev/null || true
    PHYSVIEW=""
  done
  if [ -n "$PHYSVIEW" ]; then
    echo "$PHYSVIEW" >"$VIEW_PIDFILE"
    url=$(grep -o 'http://[^ ]*' "$VIEW_LOG" | head -n1)
    echo "viewer: open $url in a browser (physview, log $VIEW_LOG)"
  else
    echo "physview did not start (log $VIEW_LOG):" >&2
    cat "$VIEW_LOG" >&2
  fi
else
  echo "no viewer: physview is not built (it needs libcivetweb-dev and npm)"
fi

# Foreground: the live table; Ctrl-C ends it, then the EXIT trap stops the viewer and the daemon.
build/tools/physctl watch "$@" || true
