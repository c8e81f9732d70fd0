#!/usr/bin/env bash
# Configures (once) and builds riccati in build/, with ccache.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${RICCATI_BUILD_DIR:-build}
if [ ! -f "$build_dir/build.ninja" ]; then
  cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
ninja -C "$build_dir" "$@"
