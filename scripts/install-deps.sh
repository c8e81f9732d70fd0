#!/usr/bin/env bash
# Installs the Debian 12 packages riccati needs, and only those that are
# missing (so a machine that has them all is left alone). Sets, by purpose
# (README.md, "Dependencies", says what each package is for):
#
#   scripts/install-deps.sh              building riccatid, riccati and the models (the main job's build)
#   scripts/install-deps.sh plot         and gnuplot, for the main job's figure (scripts/main-job.sh)
#   scripts/install-deps.sh python       and the Python client's packages (client/python)
#   scripts/install-deps.sh test         and everything the test suite uses (scripts/test.sh): GoogleTest,
#                                        Google Benchmark, the browser, PostgreSQL, the Python client, pytest
#   scripts/install-deps.sh test fuzz    and clang with libFuzzer (scripts/sanitize.sh, scripts/fuzz.sh)
set -euo pipefail

# Building and running riccatid and riccati.
packages=(
  build-essential cmake ninja-build ccache pkg-config   # toolchain, one cached build
  libeigen3-dev                                         # linear algebra
  libboost-dev                                          # Boost.Math (header-only): chi-square quantiles in residual diagnostics
  libsundials-cvode6 libsundials-arkode5                # CVODE / ARKODE integrators (headers: below)
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
  libyaml-cpp-dev                                       # config and job files, text models
  nlohmann-json3-dev                                    # the command line's --json (and the tests' JSON)
  libceres-dev                                          # Ceres Solver: the least squares of output error and maximum likelihood
)
plot=(
  gnuplot-nox                                           # the main job's PNG of the fit (pngcairo, no X)
)
python=(
  python3-grpcio python3-protobuf                       # the Python client (client/python): gRPC, messages (stubs: protoc above)
  python3-numpy python3-pandas                          # its arrays and frames
  python3-pip python3-setuptools                        # installing it from source (no other registry)
)
test=(
  libgtest-dev libgmock-dev                             # GoogleTest
  libbenchmark-dev                                      # Google Benchmark (bench/)
  chromium chromium-driver python3-selenium             # the workbench's tests in a real browser (tests/web)
  postgresql                                            # a throw-away server for the PostgreSQL store's tests (with-postgres.sh)
  python3-pytest                                        # the Python client's tests
  python3-matplotlib                                    # docs/python.md's example (its figure), run as a test
)
fuzz=(
  clang libclang-rt-14-dev                              # the sanitized build, libFuzzer and the sanitizers' runtime
)

for set in "$@"; do
  case $set in
    plot) packages+=("${plot[@]}") ;;
    python) packages+=("${python[@]}") ;;
    test) packages+=("${python[@]}" "${test[@]}") ;;
    fuzz) packages+=("${fuzz[@]}") ;;
    *) echo "install-deps: unknown set \"$set\" (plot, python, test, fuzz)" >&2; exit 2 ;;
  esac
done

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
missing=()
for p in "${packages[@]}"; do
  installed "$p" || missing+=("$p")
done

sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
export DEBIAN_FRONTEND=noninteractive
updated=0
if [ ${#missing[@]} -gt 0 ]; then
  echo "install-deps: installing ${missing[*]}"
  "${sudo_cmd[@]}" apt-get update -qq
  updated=1
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# SUNDIALS' headers: libsundials-dev depends on MPI, PETSc, hypre and gfortran
# (about 150 packages) for parallel vectors riccati never uses, so unless it
# is installed its headers alone are unpacked from the package into
# build/_deps/sundials (cmake/sundials_runtime.cmake looks there).
headers="$(cd "$(dirname "$0")/.." && pwd)/build/_deps/sundials"
if ! installed libsundials-dev && [ ! -f "$headers/include/sundials/sundials_config.h" ]; then
  echo "install-deps: unpacking SUNDIALS' headers from libsundials-dev into $headers"
  [ $updated -eq 1 ] || "${sudo_cmd[@]}" apt-get update -qq
  download=$(mktemp -d)
  # apt-get download checks the package against the signed index; run as
  # root, apt drops to the _apt user, which needs to write there.
  chmod 0777 "$download"
  (cd "$download" && apt-get download -qq libsundials-dev)
  rm -rf "$headers" && mkdir -p "$headers"
  dpkg-deb -x "$download"/libsundials-dev_*.deb "$download/root"
  mv "$download/root/usr/include" "$headers/include"
  rm -rf "$download"
fi
