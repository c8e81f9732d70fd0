#!/usr/bin/env bash
# Makes the test PKI in tests/data/tls: a CA, a server certificate for
# localhost / 127.0.0.1 and a client certificate signed by the CA, and a
# self-signed client certificate (stranger), all valid for 100 years. They are test fixtures, checked in; run this only to
# replace them (needs the openssl command).
set -euo pipefail
cd "$(dirname "$0")/../tests/data/tls"
days=36500
openssl req -x509 -newkey rsa:2048 -nodes -days $days -subj "/CN=riccati test CA" \
  -keyout ca.key -out ca.pem 2>/dev/null
sign() {  # name subject extensions
  openssl req -newkey rsa:2048 -nodes -subj "$2" -keyout "$1.key" -out "$1.csr" 2>/dev/null
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days $days \
    -extfile <(printf '%s\n' "$3") -out "$1.pem" 2>/dev/null
  rm "$1.csr"
}
sign server "/CN=localhost" "subjectAltName=DNS:localhost,IP:127.0.0.1
extendedKeyUsage=serverAuth"
sign client "/CN=riccati test client" "extendedKeyUsage=clientAuth"
rm -f ca.srl ca.key  # nothing more is signed with it
# A client certificate from no CA riccati knows: mutual TLS must refuse it.
openssl req -x509 -newkey rsa:2048 -nodes -days $days -subj "/CN=stranger" \
  -keyout stranger.key -out stranger.pem 2>/dev/null
ls
