#!/usr/bin/env bash
# Quick start: installs what is missing, builds, and runs cvre-server on
# 127.0.0.1:7878 with its database in cvre-demo.db, plus a few wandering bots
# so the world is not empty. Connect with: ./build/cvre-client --name you,
# or a browser at http://127.0.0.1:8080/ (--web: the web client and the
# WebSocket; CVRE_WEB_PORT changes the port).
# Ctrl-C stops everything cleanly.
set -euo pipefail
cd "$(dirname "$0")/.."
say() { echo "cvre demo: $*" >&2; }
say "checking the packages it needs (tools/deps.sh; installs what is missing)"
bash tools/deps.sh
say "configuring build/ (cmake, Release)"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
if [ -x build/cvre-server ]; then
  say "building what changed"
else
  say "building the five programs into build/ (about half a minute the first time)"
fi
started=$SECONDS
cmake --build build -j "$(nproc)" --target cvre-server cvre-import cvre-client cvre-admin cvre-cluster >/dev/null
say "built in $((SECONDS - started)) s"
port=${CVRE_PORT:-7878}
ready=$(mktemp)
say "starting cvre-server on 127.0.0.1:$port and loading server/worlds/demo.world"
web_port=${CVRE_WEB_PORT:-8080}
./build/cvre-server --port "$port" --db cvre-demo.db --world server/worlds/demo.world \
  --web "127.0.0.1:$web_port" "$@" >"$ready" &
server=$!
# the bots start once the server says it listens (loading the world takes
# seconds); if it stops first, so does the demo, with its exit code
until grep -q '^listening on' "$ready"; do
  if ! kill -0 $server 2>/dev/null; then
    rm -f "$ready"
    wait $server
    exit $?
  fi
  sleep 0.2
done
rm -f "$ready"
say "starting 8 bots that wander the world"
./build/cvre-client --port "$port" --bots 8 --rate 5 --pattern random-walk --duration 86400 --name wanderer >/dev/null &
bots=$!
trap 'kill -TERM $bots $server 2>/dev/null; wait $server' INT TERM EXIT
say "server on 127.0.0.1:$port (database cvre-demo.db), 8 bots walking; Ctrl-C stops it."
say "in another terminal: ./build/cvre-client --port $port --name you"
say "or in a browser: http://127.0.0.1:$web_port/"
wait $server
