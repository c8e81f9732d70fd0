#!/usr/bin/env bash
# The image's build stage (deploy/container/Dockerfile), which deploy/check.sh
# runs as it is, without a container engine:
#
#   deploy/container/build-install.sh PREFIX
#
# builds riccatid, riccati, riccati-engine and the built-in models in
# $RICCATI_BUILD_DIR (default build/; when it configures that directory, it
# leaves out the tests and benchmarks) and installs them, stripped, into
# PREFIX (cmake --install: bin/, lib/riccati/models/, include/riccati/).
# The packages to build with come first: scripts/install-deps.sh.
set -euo pipefail
[ $# -eq 1 ] || { echo "usage: deploy/container/build-install.sh PREFIX" >&2; exit 2; }
prefix=$1
cd "$(dirname "$0")/../.."
build_dir=${RICCATI_BUILD_DIR:-build}
if [ ! -f "$build_dir/build.ninja" ]; then
  cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DRICCATI_BUILD_TESTS=OFF \
    -DRICCATI_BUILD_BENCH=OFF >/dev/null
fi
ninja -C "$build_dir" ${RICCATI_NINJA_JOBS:+-j "$RICCATI_NINJA_JOBS"} riccatid riccati riccati-engine >/dev/null
cmake --install "$build_dir" --prefix "$prefix" --strip >/dev/null
echo "build-install: riccati installed in $prefix"
