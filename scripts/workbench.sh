#!/usr/bin/env bash
# The web workbench on this machine, in one command: builds riccatid if
# needed, starts it on loopback with the workbench (--http-listen), loads the
# shipped datasets (tests/data/*.csv, their columns and true parameters from
# the .json beside them) unless they are there already, and prints the URL. Ctrl-C stops it.
#
#   scripts/workbench.sh [DATA_DIR]       (default: /var/tmp/riccati-workbench)
#   RICCATI_HTTP=127.0.0.1:8080 RICCATI_LISTEN=127.0.0.1:7531 scripts/workbench.sh
#
# Loopback without a tokens file: every caller is tenant "default" and the
# page needs no sign-in. Serving other hosts needs TLS and tokens
# (docs/workbench.md).
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
data_dir=${1:-/var/tmp/riccati-workbench}
http=${RICCATI_HTTP:-127.0.0.1:7532}
listen=${RICCATI_LISTEN:-127.0.0.1:7531}
build_dir=${RICCATI_BUILD_DIR:-build}
[ -x "$build_dir/bin/riccatid" ] || { scripts/install-deps.sh && scripts/build.sh riccatid; }
mkdir -p "$data_dir"
rm -f "$data_dir/http_port"
"$build_dir/bin/riccatid" --listen "$listen" --http-listen "$http" --data-dir "$data_dir" \
  --http-port-file "$data_dir/http_port" --log-level warn &
pid=$!
trap 'kill -TERM $pid 2>/dev/null; wait $pid 2>/dev/null' EXIT INT TERM
for _ in $(seq 100); do
  [ -s "$data_dir/http_port" ] && break
  kill -0 $pid 2>/dev/null || { echo "workbench: riccatid did not start" >&2; exit 1; }
  sleep 0.1
done
base="http://${http%:*}:$(cat "$data_dir/http_port")"
existing=$(curl -fsS -H 'Authorization: Bearer -' "$base/api/v1/datasets")
for csv in "$root"/tests/data/*.csv; do
  name=$(basename "$csv")
  case "$existing" in *"\"name\":\"$name\""*) continue ;; esac
  query=$(/usr/bin/python3 - "${csv%.csv}.json" "$name" <<'PY'
import json, sys, urllib.parse
meta = json.load(open(sys.argv[1]))
query = {"name": sys.argv[2], "format": "csv", "input_columns": ",".join(meta["inputs"]),
         "output_columns": ",".join(meta["outputs"])}
if isinstance(meta.get("parameters"), dict):  # what it was simulated with: the result table's truth column
    query["true_parameters"] = ",".join(f"{k}:{v!r}" for k, v in meta["parameters"].items())
print(urllib.parse.urlencode(query))
PY
)
  curl -fsS -H 'Authorization: Bearer -' -H 'Content-Type: text/csv' --data-binary "@$csv" "$base/api/v1/datasets?$query" >/dev/null
  echo "workbench: loaded $name"
done
echo "workbench: open $base/ (Ctrl-C stops riccatid)"
wait $pid
