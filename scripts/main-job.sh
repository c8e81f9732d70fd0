#!/usr/bin/env bash
# The main job: install what is missing, build, start riccatid on loopback
# (SQLite in a temporary data directory), upload the two-tank data, run
# Hensen's identification (examples/two_tank_hensen.yaml: 10 passes from
# theta0 = [20 20 1 1]) through the riccati command, print the parameter
# table and the validation fit, stop the daemon.
#
#   scripts/main-job.sh          # EKF
#   scripts/main-job.sh ukf      # the same with the UKF
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh riccatid riccati >/dev/null
filter=${1:-ekf}

data_dir=$(mktemp -d)
build/bin/riccatid --listen 127.0.0.1:0 --data-dir "$data_dir" --port-file "$data_dir/port" --log-level warn &
daemon=$!
trap 'kill -TERM $daemon 2>/dev/null; wait $daemon 2>/dev/null; rm -rf "$data_dir"' EXIT
for _ in $(seq 100); do [ -s "$data_dir/port" ] && break; sleep 0.1; done
[ -s "$data_dir/port" ] || { echo "main-job: riccatid did not start" >&2; exit 1; }
export RICCATI_SERVER="127.0.0.1:$(cat "$data_dir/port")"
riccati=build/bin/riccati

dataset=$($riccati data upload tests/data/two_tank.csv --inputs F1,F2 --outputs h1,h2)
echo "Identification of two_tank on two_tank.csv ($filter, Hensen's settings), riccatid at $RICCATI_SERVER"
echo
job=$($riccati identify --config examples/two_tank_hensen.yaml --data "$dataset" --filter "$filter" --no-wait)
$riccati job watch "$job" 2>/dev/null
$riccati result "$job" --truth 10,5,0.0791,0.1342
echo
echo "Validation: the identified model simulated over the data"
$riccati validate --model two_tank --params "$job" --data "$dataset" 2>/dev/null
