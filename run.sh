#!/usr/bin/env bash
# Installs what is missing, builds, starts physd on the default scene in the background and
# shows it live with `physctl watch`. Ctrl-C stops both. Extra arguments go to physctl watch.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/common.sh
phys_install_deps
phys_build build

CONFIG=configs/physd.toml
PIDFILE=build/physd.pid
LOG=build/physd.log

# A daemon left over from an earlier run.sh (its pid file) is stopped first.
if [ -f "$PIDFILE" ]; then
  old=$(cat "$PIDFILE")
  if [ -n "$old" ] && kill -0 "$old" 2>/dev/null && [ "$(ps -o comm= -p "$old")" = physd ]; then
    echo "stopping the physd left running by an earlier run.sh (pid $old)"
    kill -TERM "$old" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$old" 2>/dev/null || break; sleep 0.1; done
  fi
  rm -f "$PIDFILE"
fi

build/server/physd --config "$CONFIG" >"$LOG" 2>&1 &
PHYSD=$!
echo "$PHYSD" >"$PIDFILE"

stop_daemon() {
  trap - EXIT INT TERM
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

# Foreground: the live table; Ctrl-C ends it, then the EXIT trap stops the daemon.
build/tools/physctl watch "$@" || true
