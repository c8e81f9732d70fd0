#!/usr/bin/env bash
# Configures the sanitized tree shared by scripts/sanitize.sh and
# scripts/fuzz.sh (clang, ASan + UBSan, libFuzzer targets), once.
#
#   scripts/configure-sanitized.sh BUILD_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=$1
if [ ! -f "$build_dir/build.ninja" ]; then
  CC=clang CXX=clang++ cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -g1" -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" \
    -DRICCATI_FUZZ=ON -DRICCATI_BUILD_TESTS=ON -DRICCATI_BUILD_BENCH=OFF >/dev/null
fi
