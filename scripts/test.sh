#!/usr/bin/env bash
# The whole test suite, from a clean clone: install what is missing, build,
# run every test with CTest beside a throw-away PostgreSQL server
# (scripts/with-postgres.sh), so the PostgreSQL store's tests run too and
# must not be skipped. With RICCATI_TEST_POSTGRES_URL already set, that
# server is used instead.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scripts/install-deps.sh
scripts/build.sh
cd "${RICCATI_BUILD_DIR:-build}"
export RICCATI_REQUIRE_POSTGRES=1
ctest=(ctest --output-on-failure --timeout 600 -j "$(nproc)")
if [ -n "${RICCATI_TEST_POSTGRES_URL:-}" ]; then
  "${ctest[@]}"
else
  "$root/scripts/with-postgres.sh" "${ctest[@]}"
fi
