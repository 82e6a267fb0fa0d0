#!/usr/bin/env bash
# Line and branch coverage of the whole test suite: a gcc tree built with
# --coverage at -O0 (build-coverage/, or $CVRE_COVERAGE_DIR), every ctest
# entry run once (two at a time), then gcovr's counts per file and the
# targets checked by tools/coverage.py. Exits non-zero when a test fails or
# a target is missed; the table is printed either way. gcovr is not in the
# default package list: `bash tools/deps.sh --coverage` installs it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/deps.sh --coverage
dir=${CVRE_COVERAGE_DIR:-build-coverage}
echo "== $dir: configure and build" >&2
cmake -S . -B "$dir" -DCVRE_COVERAGE=ON -DCVRE_WERROR=ON -DCVRE_TEST_HOOKS=ON \
      -DCMAKE_C_COMPILER=gcc -DCMAKE_BUILD_TYPE=Debug >/dev/null
cmake --build "$dir" -j 2 >/dev/null
find "$dir" -name '*.gcda' -delete # this run's counts only
echo "== $dir: test" >&2
tests=0
(cd "$dir" && ctest --output-on-failure -j 2 --timeout 600) || tests=$?
echo "== $dir: coverage" >&2
# Sources only: the tests, fuzz drivers, benchmarks and the generated
# migrations file are not what is measured.
gcovr -j 2 --root . --object-directory "$dir" --filter 'base/' --filter 'protocol/' --filter 'algo/' --filter 'server/' \
      --filter 'db/' --filter 'client/' --exclude "$dir/" \
      --json-summary-pretty --output "$dir/coverage.json"
check=0
python3 tools/coverage.py "$dir/coverage.json" || check=$?
if ((tests)); then
  echo "coverage: some tests failed (ctest exit $tests): the figures undercount" >&2
  exit "$tests"
fi
exit "$check"
