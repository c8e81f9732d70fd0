#!/usr/bin/env bash
# The Debian 12 packages that riccatid, riccati and the model plugins need at
# run time, and nothing more: the container image's runtime stage runs this
# (deploy/container/Dockerfile), and so can a host that runs an install made
# elsewhere (cmake --install).
#
#   install-runtime-deps.sh                 install the packages that are missing (apt-get; root or sudo)
#   install-runtime-deps.sh --list          print the packages, one a line
#   install-runtime-deps.sh --check PREFIX  install nothing; check an install under PREFIX:
#       every package of the list is installed here or installable from apt,
#       every shared library of PREFIX/bin/* and PREFIX/lib/riccati/models/*.so
#       resolves (ldd), and every library they link directly (DT_NEEDED) belongs
#       to a package of the list (so the image lacks none; apt brings the
#       libraries those link in turn).
set -euo pipefail

# Which library each is for; the names are those of Debian 12 (bookworm):
# a new Debian release renames the ones with a version or soname in the name.
packages=(
  libgrpc++1.51 libgrpc29           # gRPC (libgrpc++, libgrpc++_reflection, libgrpc, libgpr)
  libprotobuf32                     # Protocol Buffers
  libabsl20220623                   # Abseil (linked by the generated gRPC code)
  libsundials-cvode6                # CVODE integrators
  libsundials-arkode5               # ARKODE integrators
  libspdlog1.10 libfmt9             # logs
  libmatio11                        # MAT files
  libyaml-cpp0.7                    # config and job files
  libsqlite3-0                      # the embedded store
  libpqxx-6.4                       # the PostgreSQL store (depends on libpq5)
  libssl3                           # TLS and SHA-256 (libssl, libcrypto)
  libprometheus-cpp-core1.0         # metrics in Prometheus' model and text format
  libcpp-httplib0.11                # the HTTP servers of /metrics and of the workbench (--http-listen)
  # Ceres Solver (output error, maximum likelihood) is linked statically
  # (Debian ships libceres.a to CMake); these are what it links in turn:
  libgoogle-glog0v6                 # its logging
  libcholmod3 libcxsparse3          # SuiteSparse: its sparse solvers
  libatlas3-base                    # LAPACK and BLAS (libceres-dev depends on ATLAS)
  zlib1g                            # checking compressed MAT variables
  libstdc++6 libgcc-s1 libc6        # the C and C++ runtimes
  ca-certificates                   # the system's CAs: riccati --tls, PostgreSQL with sslmode=verify-full
)

installed() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }

install() {
  local missing=()
  for p in "${packages[@]}"; do installed "$p" || missing+=("$p"); done
  [ ${#missing[@]} -eq 0 ] && return 0
  echo "install-runtime-deps: installing ${missing[*]}"
  local sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  # An image keeps no package lists.
  [ -n "${RICCATI_KEEP_APT_LISTS:-}" ] || "${sudo_cmd[@]}" rm -rf /var/lib/apt/lists/*
}

# The Debian package that owns a library file ("" if none: e.g. built here).
owner() {
  local path=$1 real
  real=$(readlink -f "$path")
  for candidate in "$path" "$real" "${path#/usr}" "${real#/usr}" "/usr${path}" "/usr${real}"; do
    local pkg
    pkg=$(dpkg-query -S "$candidate" 2>/dev/null | head -1 | cut -d: -f1) || true
    [ -n "$pkg" ] && { echo "$pkg"; return; }
  done
}

check() {
  local prefix=$1 failures=0
  local files=()
  for f in "$prefix"/bin/* "$prefix"/lib/riccati/models/*.so; do
    [ -f "$f" ] && files+=("$f")
  done
  [ ${#files[@]} -gt 0 ] || { echo "install-runtime-deps: nothing installed under $prefix" >&2; return 1; }

  # 1. The list: installed here, or apt knows a candidate for it.
  for p in "${packages[@]}"; do
    if ! installed "$p" && ! apt-cache policy "$p" 2>/dev/null | grep -q 'Candidate: [0-9]'; then
      echo "install-runtime-deps: package $p is neither installed nor available from apt" >&2
      failures=$((failures + 1))
    fi
  done

  # 2. Every library resolves, and those linked directly come from the list.
  local needed_total=0
  for f in "${files[@]}"; do
    local resolved libs
    resolved=$(ldd "$f")
    if grep -q 'not found' <<<"$resolved"; then
      echo "install-runtime-deps: $f: libraries not found:" >&2
      grep 'not found' <<<"$resolved" >&2
      failures=$((failures + 1))
    fi
    libs=$(LC_ALL=C readelf -d "$f" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p')
    for lib in $libs; do
      needed_total=$((needed_total + 1))
      local path pkg
      # "libx.so.1 => /lib/.../libx.so.1 (0x...)", or the loader as "/lib64/ld-linux-x86-64.so.2 (0x...)".
      path=$(awk -v l="$lib" '!found && $1 == l && $3 ~ /^\// { print $3; found = 1 }
                              !found && $1 ~ /^\// && substr($1, length($1) - length(l) + 1) == l { print $1; found = 1 }' \
             <<<"$resolved")
      [ -n "$path" ] || continue  # reported as not found above
      pkg=$(owner "$path")
      if [ -z "$pkg" ]; then
        echo "install-runtime-deps: $f needs $lib ($path), which no Debian package provides" >&2
        failures=$((failures + 1))
      elif [[ " ${packages[*]} " != *" $pkg "* ]]; then
        echo "install-runtime-deps: $f needs $lib from package $pkg, which is not in the list" >&2
        failures=$((failures + 1))
      fi
    done
  done
  if [ $failures -gt 0 ]; then
    echo "install-runtime-deps: $failures problems" >&2
    return 1
  fi
  echo "install-runtime-deps: ${#packages[@]} packages available; ${#files[@]} files under $prefix," \
       "$needed_total direct library links, all resolved and all from those packages"
}

case "${1:-}" in
  "") install ;;
  --list) printf '%s\n' "${packages[@]}" ;;
  --check)
    [ $# -eq 2 ] || { echo "usage: install-runtime-deps.sh --check PREFIX" >&2; exit 2; }
    command -v readelf >/dev/null || { echo "install-runtime-deps: --check needs readelf (binutils)" >&2; exit 2; }
    check "$2"
    ;;
  *) echo "usage: install-runtime-deps.sh [--list | --check PREFIX]" >&2; exit 2 ;;
esac
