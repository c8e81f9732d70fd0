#!/usr/bin/env bash
# Makes what deploy/compose.yaml mounts as secrets, for trying it out on one
# host: in deploy/compose/secrets/ (ignored by git; RICCATI_SECRETS_DIR to
# make them elsewhere)
#
#   ca.crt, tls.crt, tls.key   a test CA, and a server certificate signed by it for
#                              riccatid, riccatid-1, riccatid-2, localhost, 127.0.0.1
#   token, tokens              a random bearer token (tenant "default") and its
#                              digest line for riccatid (riccatid --hash-token)
#   postgres_password          a random password for the database
#
# Needs openssl, and riccatid on the PATH or in ../../build/bin for the
# digest. Leaves existing files alone (delete the directory to start again).
# Compose mounts these files as they are (bind mounts), so they must be
# readable by the containers' users (uid 10001 for riccatid, 999 for
# PostgreSQL): the files are 0644 in a directory only you can enter (0700),
# but tls.key, which riccatid refuses if others can read it: it is 0600 and
# owned by uid 10001 (run as root, or `sudo chown 10001:10001 tls.key`).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
dir=${RICCATI_SECRETS_DIR:-$root/deploy/compose/secrets}
riccatid=$(command -v riccatid || echo "$root/build/bin/riccatid")
mkdir -p "$dir"
chmod 700 "$dir"
cd "$dir"

[ -x "$riccatid" ] || { echo "make-dev-secrets: no riccatid (build it, or put it on the PATH)" >&2; exit 1; }

if [ ! -f ca.crt ]; then
  openssl req -x509 -newkey rsa:2048 -nodes -days 825 -subj "/CN=riccati compose test CA" \
    -keyout ca.key -out ca.crt 2>/dev/null
  openssl req -newkey rsa:2048 -nodes -subj "/CN=riccatid" -keyout tls.key -out tls.csr 2>/dev/null
  openssl x509 -req -in tls.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 825 -out tls.crt \
    -extfile <(printf '%s\n' "subjectAltName=DNS:riccatid,DNS:riccatid-1,DNS:riccatid-2,DNS:localhost,IP:127.0.0.1" \
                              "extendedKeyUsage=serverAuth") 2>/dev/null
  rm -f tls.csr ca.srl ca.key  # nothing more is signed with this CA
fi
if [ ! -f token ]; then
  (umask 077; head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >token)
  printf '%s' "$(cat token)" | "$riccatid" --hash-token --tenant default >tokens
fi
[ -f postgres_password ] || head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' >postgres_password
chmod 644 ca.crt tls.crt tokens postgres_password
chmod 600 tls.key  # riccatid refuses a private key others can read
if [ "$(id -u)" -eq 0 ]; then
  chown 10001:10001 tls.key  # the container's riccatid
elif [ "$(stat -c %u tls.key)" != 10001 ]; then
  echo "make-dev-secrets: for compose's riccatid (uid 10001) to read it: sudo chown 10001:10001 $(pwd)/tls.key" >&2
fi
chmod 600 token  # the client's copy: riccati refuses a token file others can read
echo "make-dev-secrets: $(pwd): ca.crt tls.crt tls.key tokens token postgres_password"
