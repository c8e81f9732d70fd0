#!/usr/bin/env bash
# Runs a command beside a throw-away PostgreSQL 15 server:
#
#   scripts/with-postgres.sh <command...>
#
# Installs the `postgresql` package if it is missing, initialises a cluster
# in a temporary directory (as the `postgres` user when run as root: initdb
# refuses root), starts it on 127.0.0.1 on a free port with a random
# password, creates a database, exports
#   RICCATI_TEST_POSTGRES_URL=postgresql://riccati:<password>@127.0.0.1:<port>/riccati_test
# runs the command, then stops the server and removes the cluster. Exits with
# the command's status.
set -euo pipefail

[ $# -gt 0 ] || { echo "usage: scripts/with-postgres.sh <command...>" >&2; exit 2; }

pg_bin=/usr/lib/postgresql/15/bin
sudo_cmd=()
[ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
if [ ! -x "$pg_bin/initdb" ]; then
  echo "with-postgres: installing postgresql"
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends postgresql >/dev/null
fi

# The server runs as an unprivileged user: `postgres` (made by the package)
# when we are root, else ourselves.
as_pg=()
if [ "$(id -u)" -eq 0 ]; then
  pg_user=postgres
  id -u "$pg_user" >/dev/null 2>&1 || { echo "with-postgres: no user $pg_user to run the server as" >&2; exit 1; }
  as_pg=(runuser -u "$pg_user" --)
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/riccati-pg-XXXXXX")
[ ${#as_pg[@]} -eq 0 ] || chown "$pg_user" "$work"
chmod 700 "$work"
cleanup() {
  if [ -f "$work/data/postmaster.pid" ]; then
    "${as_pg[@]}" "$pg_bin/pg_ctl" -D "$work/data" -m fast -w stop >/dev/null 2>&1 || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

password=$(head -c 16 /dev/urandom | od -An -tx1 | tr -d ' \n')
printf '%s\n' "$password" >"$work/pwfile"
[ ${#as_pg[@]} -eq 0 ] || chown "$pg_user" "$work/pwfile"
if ! "${as_pg[@]}" "$pg_bin/initdb" -D "$work/data" -U riccati --pwfile="$work/pwfile" --auth=scram-sha-256 \
    --encoding=UTF8 --no-locale >"$work/initdb.log" 2>&1; then
  echo "with-postgres: initdb failed:" >&2
  cat "$work/initdb.log" >&2
  exit 1
fi
rm -f "$work/pwfile"

# A free port: skip ports something answers on, and try again if the server
# loses a race for one. The socket goes to the cluster's own directory; no
# durability is needed for a cluster that is deleted afterwards (fsync off).
port=
for _ in $(seq 20); do
  candidate=$((20000 + RANDOM % 40000))
  (exec 3<>"/dev/tcp/127.0.0.1/$candidate") 2>/dev/null && continue
  if "${as_pg[@]}" "$pg_bin/pg_ctl" -D "$work/data" -l "$work/server.log" -w -t 60 \
      -o "-c listen_addresses=127.0.0.1 -p $candidate -k $work -c fsync=off -c synchronous_commit=off -c full_page_writes=off" \
      start >/dev/null 2>&1; then
    port=$candidate
    break
  fi
done
if [ -z "$port" ]; then
  echo "with-postgres: the server did not start; its log:" >&2
  cat "$work/server.log" >&2 || true
  exit 1
fi

PGPASSWORD=$password "$pg_bin/createdb" -h 127.0.0.1 -p "$port" -U riccati riccati_test
export RICCATI_TEST_POSTGRES_URL="postgresql://riccati:$password@127.0.0.1:$port/riccati_test"
echo "with-postgres: PostgreSQL 15 on 127.0.0.1:$port (cluster in $work)" >&2

status=0
"$@" || status=$?
exit $status
