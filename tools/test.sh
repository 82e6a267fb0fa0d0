#!/usr/bin/env bash
# The test suite: installs what is missing, then builds and tests in the
# trees named (by default gcc and asan) under build-test/:
#   gcc   warnings are errors, RelWithDebInfo (-O3 -g): every test;
#   asan  clang, AddressSanitizer and UndefinedBehaviorSanitizer at -O1:
#         every test;
#   tsan  clang, ThreadSanitizer at -O1: the tests labelled `threads` (the
#         log writer, workers and mailbox, importer, refiner, clustering
#         and the integration tests that drive them); about 3 minutes more
#         on two cores, so only when asked: `bash tools/test.sh gcc asan tsan`.
# Every test is meant to take well under 120 s on two cores; ctest's timeout
# is the guard against a hang. ctest runs one test more than there are
# cores: many tests wait on sockets and child processes much of the time
# (two at a time left a third of two cores idle; three take a sixth off the
# ASan tree's time). The city block's entries are labelled `slow`:
# in a tree of your own, `ctest -LE slow` leaves them out.
set -euo pipefail
cd "$(dirname "$0")/.."
trees=("$@")
[ ${#trees[@]} -gt 0 ] || trees=(gcc asan)
for t in "${trees[@]}"; do
  case $t in gcc | asan | tsan) ;; *) echo "test.sh: no tree $t (gcc, asan, tsan)" >&2; exit 2 ;; esac
done
bash tools/deps.sh
jobs=$(nproc)
run() { # name, ctest arguments up to --, then cmake arguments
  local dir=build-test/$1 ctest_args=()
  shift
  while [ "$1" != -- ]; do ctest_args+=("$1"); shift; done
  shift
  echo "== $dir: configure and build" >&2
  cmake -S . -B "$dir" -DCVRE_WERROR=ON -DCVRE_TEST_HOOKS=ON "$@" >/dev/null
  cmake --build "$dir" -j "$jobs" >/dev/null
  echo "== $dir: test" >&2
  (cd "$dir" && ctest --output-on-failure -j $((jobs + 1)) --timeout 300 "${ctest_args[@]}")
}
for t in "${trees[@]}"; do
  case $t in
    gcc) run gcc -- -DCMAKE_C_COMPILER=gcc -DCMAKE_BUILD_TYPE=RelWithDebInfo ;;
    asan)
      ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
        run asan-clang -- -DCMAKE_C_COMPILER=clang -DCMAKE_BUILD_TYPE=Debug "-DCMAKE_C_FLAGS_DEBUG=-g -O1" \
        -DCVRE_SANITIZE=ON ;;
    tsan)
      TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1 \
        run tsan-clang -L threads -- -DCMAKE_C_COMPILER=clang -DCMAKE_BUILD_TYPE=Debug \
        "-DCMAKE_C_FLAGS_DEBUG=-g -O1" -DCVRE_TSAN=ON ;;
  esac
done
