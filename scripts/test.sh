#!/usr/bin/env bash
# The whole test suite, from a clean clone: install what is missing, build,
# run every test with CTest.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh
cd "${RICCATI_BUILD_DIR:-build}"
ctest --output-on-failure --timeout 600 -j "$(nproc)"
