#!/usr/bin/env bash
# The whole test suite: installs what is missing, then builds and tests twice,
# with gcc (warnings are errors) and with clang under AddressSanitizer and
# UndefinedBehaviorSanitizer. Build trees go to build-test/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/deps.sh
jobs=$(nproc)
run() { # name, then cmake arguments
  local dir=build-test/$1; shift
  echo "== $dir: configure and build" >&2
  cmake -S . -B "$dir" -DCVRE_WERROR=ON "$@" >/dev/null
  cmake --build "$dir" -j "$jobs" >/dev/null
  echo "== $dir: test" >&2
  (cd "$dir" && ctest --output-on-failure -j "$jobs" --timeout 300)
}
run gcc -DCVRE_TEST_HOOKS=ON -DCMAKE_C_COMPILER=gcc -DCMAKE_BUILD_TYPE=RelWithDebInfo
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  run asan-clang -DCVRE_TEST_HOOKS=ON -DCMAKE_C_COMPILER=clang -DCMAKE_BUILD_TYPE=Debug \
      "-DCMAKE_C_FLAGS_DEBUG=-g -O1" -DCVRE_SANITIZE=ON
