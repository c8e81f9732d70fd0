#!/usr/bin/env bash
# The whole test suite, from a clean clone: install what is missing (the
# build's packages and the tests': scripts/install-deps.sh test), build,
# run every test with CTest beside a throw-away PostgreSQL server
# (scripts/with-postgres.sh), so the PostgreSQL store's tests run too and
# must not be skipped; then deploy/check.sh (the deployment files). With
# RICCATI_TEST_POSTGRES_URL already set, that server is used instead.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
scripts/install-deps.sh test
build_dir=${RICCATI_BUILD_DIR:-build}
# Tests and benchmarks required, also in a tree that the main job configured
# before their packages were installed.
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DRICCATI_BUILD_TESTS=ON -DRICCATI_BUILD_BENCH=ON >/dev/null
scripts/build.sh
cd "$build_dir"
export RICCATI_REQUIRE_POSTGRES=1
ctest=(ctest --output-on-failure --timeout 600 -j "$(nproc)")
# CTest, then the deployment files' checks (deploy/check.sh, which starts
# riccatid from an install on the same PostgreSQL server), in one run:
# bash -c 'SCRIPT' ROOT CTEST... ($0 is the repository, $@ the ctest command).
steps='"$@" && cd "$0" && deploy/check.sh'
if [ -n "${RICCATI_TEST_POSTGRES_URL:-}" ]; then
  bash -c "$steps" "$root" "${ctest[@]}"
else
  "$root/scripts/with-postgres.sh" bash -c "$steps" "$root" "${ctest[@]}"
fi
