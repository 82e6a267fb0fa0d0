#!/usr/bin/env bash
# Quick start: installs what is missing, builds, and runs cvre-server on
# 127.0.0.1:7878 with its database in cvre-demo.db, plus a few wandering bots
# so the world is not empty. Connect with: ./build/cvre-client --name you
# Ctrl-C stops everything cleanly.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build -j "$(nproc)" >/dev/null
port=${CVRE_PORT:-7878}
ready=$(mktemp)
./build/cvre-server --port "$port" --db cvre-demo.db --world server/worlds/demo.world "$@" >"$ready" &
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
./build/cvre-client --port "$port" --bots 8 --rate 5 --pattern random-walk --duration 86400 --name wanderer >/dev/null &
bots=$!
trap 'kill -TERM $bots $server 2>/dev/null; wait $server' INT TERM EXIT
echo "cvre demo: server on 127.0.0.1:$port (database cvre-demo.db), 8 bots walking." >&2
echo "In another terminal: ./build/cvre-client --port $port --name you" >&2
wait $server
