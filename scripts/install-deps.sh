#!/usr/bin/env bash
# Installs the Debian 12 packages riccati needs to build and test, and only
# those that are missing (so a machine that has them all is left alone).
set -euo pipefail

packages=(
  build-essential cmake ninja-build ccache pkg-config   # toolchain, one cached build
  libeigen3-dev                                         # linear algebra
  libboost-dev                                          # Boost.Math (header-only): chi-square quantiles in residual diagnostics
  libsundials-dev                                       # CVODE / ARKODE integrators
  libspdlog-dev                                         # logging
  libmatio-dev                                          # MAT files (the 1999 toolbox's T/U/Y layout)
  zlib1g-dev                                            # inflating MAT variable headers to check them first
  libcli11-dev                                          # command-line parsing
  libgrpc++-dev protobuf-compiler-grpc                  # gRPC (server, client, code generator)
  libprotobuf-dev protobuf-compiler                     # Protocol Buffers
  libsqlite3-dev                                        # the embedded store
  libpqxx-dev                                           # the PostgreSQL store (libpqxx 6.4, with libpq)
  libssl-dev                                            # SHA-256 (token digests, plugin checksums)
  prometheus-cpp-dev                                    # metrics in Prometheus' model and text format
  libcpp-httplib-dev                                    # the HTTP endpoints: /metrics, the web workbench and its JSON API
  chromium chromium-driver python3-selenium             # the workbench's tests in a real browser (tests/web)
  libyaml-cpp-dev                                       # config and job files
  nlohmann-json3-dev                                    # JSON (dataset metadata in tests)
  libgtest-dev libgmock-dev                             # GoogleTest
  libbenchmark-dev                                      # Google Benchmark
  libceres-dev                                          # Ceres Solver: the least squares of output error and maximum likelihood
  python3-grpcio python3-protobuf                       # the Python client (client/python): gRPC, messages (stubs: protoc above)
  python3-numpy python3-pandas                          # its arrays and frames
  python3-pip python3-setuptools python3-pytest         # installing it from source (no other registry) and its tests
  python3-matplotlib                                    # docs/python.md's example (its figure), run as a test
)

# "fuzz": also what scripts/fuzz.sh needs (clang with libFuzzer and the sanitizers' runtime).
if [ "${1:-}" = fuzz ]; then
  packages+=(clang libclang-rt-14-dev)
fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}"
sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
