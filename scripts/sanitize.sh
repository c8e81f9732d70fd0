#!/usr/bin/env bash
# The whole test suite built with AddressSanitizer and UndefinedBehaviorSanitizer
# (gcc; plugins and the daemon included), in build-asan/. Any sanitizer
# report fails the test that triggered it. Like scripts/test.sh, PostgreSQL
# runs beside it (scripts/with-postgres.sh) unless RICCATI_TEST_POSTGRES_URL
# is set. The soak test is left to scripts/test.sh (it measures RSS, which
# the sanitizers' shadow memory makes meaningless).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scripts/install-deps.sh
build_dir=${RICCATI_ASAN_BUILD_DIR:-build-asan}
if [ ! -f "$build_dir/build.ninja" ]; then
  cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DRICCATI_SANITIZE=address,undefined -DRICCATI_BUILD_BENCH=OFF >/dev/null
fi
ninja -C "$build_dir"
cd "$build_dir"
export RICCATI_REQUIRE_POSTGRES=1
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=1
export LSAN_OPTIONS=suppressions=$root/scripts/lsan.supp:print_suppressions=0
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
ctest=(ctest --output-on-failure --timeout 1200 -j "$(nproc)" -LE soak)
if [ -n "${RICCATI_TEST_POSTGRES_URL:-}" ]; then
  "${ctest[@]}"
else
  "$root/scripts/with-postgres.sh" "${ctest[@]}"
fi
