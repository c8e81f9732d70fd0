#!/usr/bin/env bash
# The main job: install what is missing, build, identify the two-tank
# parameters with Hensen's settings (1999 EKF toolbox: 10 passes from
# theta0 = [20 20 1 1]) and validate the identified model on the data.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh >/dev/null
filter=${1:-ekf}
exec build/bin/riccati-engine identify \
  --model two_tank --data tests/data/two_tank.csv --inputs F1,F2 --outputs h1,h2 \
  --filter "$filter" --passes 10 --x0 first \
  --theta0 20,20,1,1 --p0 0,0,10,10,10,10 --q 0 --r 1e-3,1e-3 \
  --integrator rk4 --substeps 10 \
  --truth 10,5,0.0791,0.1342 --validate
