#!/bin/sh
# The image's runtime stage, after install-runtime-deps.sh and the copy of the
# install into PREFIX (/opt/riccati):
#
#   deploy/container/setup-runtime.sh PREFIX
#
# checks that every shared library of the install resolves (a package missing
# from install-runtime-deps.sh fails the image build here, not at the first
# start), creates the user riccatid runs as (riccati, uid and gid 10001: a
# number, so that Kubernetes can check runAsNonRoot; no login, no home but its
# data), its data directory /var/lib/riccati (0750, its own) and the
# directories of its config, TLS files and tokens, which stay root's and
# read-only to it. Run as root, in the image only: it changes the system.
set -eu
[ $# -eq 1 ] || { echo "usage: setup-runtime.sh PREFIX" >&2; exit 2; }
prefix=$1
status=0
for f in "$prefix"/bin/* "$prefix"/lib/riccati/models/*.so; do
  if ldd "$f" | grep 'not found'; then
    echo "setup-runtime: $f needs libraries that are not installed (add their packages to install-runtime-deps.sh)" >&2
    status=1
  fi
done
[ $status -eq 0 ] || exit 1
"$prefix/bin/riccatid" --help >/dev/null
"$prefix/bin/riccati" --help >/dev/null

groupadd --system --gid 10001 riccati
useradd --system --uid 10001 --gid riccati --home-dir /var/lib/riccati --no-create-home \
  --shell /usr/sbin/nologin --comment "riccati estimation daemon" riccati
install -d -o riccati -g riccati -m 0750 /var/lib/riccati
install -d -m 0755 /etc/riccati /etc/riccati/tls /etc/riccati/tokens
echo "setup-runtime: user riccati (10001), /var/lib/riccati, /etc/riccati"
