#!/usr/bin/env bash
# Installs the Debian 12 packages cvre needs to build, test and run, if any
# is missing. Needs root (apt-get). The same list is in docker/Dockerfile,
# less chromium: the map render test (tests/integration/test_map.py) draws
# cvre-admin map's SVG with headless Chromium, the image builds no tests.
# python3-sklearn and python3-numpy serve the tests and the scenario runner
# (DBSCAN against scikit-learn's; triangle tests of simulated users).
# --bench also installs what only the benchmarks compare against: OpenVDB
# (libopenvdb-dev, with TBB) for bench-voxel; and libFuzzer
# (libclang-rt-14-dev), which fuzz-long links its targets with.
# --coverage installs gcovr, which tools/coverage.sh reads gcc's counts with.
# Node.js and npm (Debian's, unless a node is already on the PATH) install
# the JavaScript the lockfiles name: three.js for the browser client
# (client/web) and puppeteer-core for its test (tests/browser), from npm's
# registry with `npm ci`, only when a lockfile changed since the last time.
set -euo pipefail
cd "$(dirname "$0")/.."
packages=(build-essential cmake pkg-config clang libsqlite3-dev sqlite3 libcmocka-dev python3
          libflann-dev python3-sklearn python3-numpy time libassimp-dev libjansson-dev libsodium-dev libseccomp-dev libhttp-parser-dev libssl-dev chromium)
for arg in "$@"; do
  case "$arg" in
    --bench) packages+=(libopenvdb-dev libclang-rt-14-dev) ;;
    --coverage) packages+=(gcovr) ;;
    *) echo "usage: bash tools/deps.sh [--bench] [--coverage]" >&2; exit 2 ;;
  esac
done
missing=()
node_packages=(nodejs npm)
command -v npm >/dev/null || packages+=("${node_packages[@]}")
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "deps: installing ${missing[*]}" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
for dir in client/web tests/browser; do
  lock=$dir/package-lock.json
  [ -f "$lock" ] || continue
  if ! [ "$dir/node_modules/.package-lock.json" -nt "$lock" ]; then
    echo "deps: npm ci in $dir" >&2
    (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
  fi
done
