#!/usr/bin/env bash
# The whole test suite built with AddressSanitizer and UndefinedBehaviorSanitizer,
# plugins and the daemon included, in build-san/. Any sanitizer report fails
# the test that triggered it. Like scripts/test.sh, PostgreSQL runs beside it
# (scripts/with-postgres.sh) unless RICCATI_TEST_POSTGRES_URL is set.
#
# The tree is built once, with clang, for both this and scripts/fuzz.sh (the
# fuzz targets are in the same build): -O1 with line tables keeps the build
# and the run short and the reports readable, and without NDEBUG Eigen checks
# every index. Left out here: the soak test (it measures RSS, which shadow
# memory makes meaningless) and the allocation test (it interposes malloc,
# which ASan owns).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scripts/install-deps.sh test fuzz
build_dir=${RICCATI_SAN_BUILD_DIR:-build-san}
scripts/configure-sanitized.sh "$build_dir"
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
