#!/bin/sh
# The container's entrypoint: riccatid with the arguments given (the image's
# CMD: --config /etc/riccati/riccatid.yaml), after one thing a config file
# cannot say: the PostgreSQL password may be a file (a mounted secret) named
# by RICCATI_DATABASE_PASSWORD_FILE. It goes to riccatid's environment only,
# as PGPASSWORD, which libpq uses for a database URL without a password
# (postgresql://riccati@db:5432/riccati). A PGPASSWORD given directly (a
# Kubernetes secretKeyRef) works as it is.
set -eu
if [ -n "${RICCATI_DATABASE_PASSWORD_FILE:-}" ]; then
  if [ ! -r "$RICCATI_DATABASE_PASSWORD_FILE" ]; then
    echo "riccatid-entrypoint: cannot read RICCATI_DATABASE_PASSWORD_FILE=$RICCATI_DATABASE_PASSWORD_FILE" >&2
    exit 1
  fi
  PGPASSWORD=$(cat "$RICCATI_DATABASE_PASSWORD_FILE")
  export PGPASSWORD
fi
exec "${RICCATI_PREFIX:-/opt/riccati}/bin/riccatid" "$@"
