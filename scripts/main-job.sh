#!/usr/bin/env bash
# The main job: install what is missing (the build's packages and gnuplot,
# nothing the tests need), build riccatid and riccati, start riccatid on
# loopback (SQLite in a temporary data directory), upload the two-tank data
# and identify it twice through the riccati command, as a user would:
#
#   Hensen's iterated EKF (examples/two_tank_hensen.yaml: 10 passes from
#   theta0 = [20 20 1 1]), its parameter table as the 1999 toolbox reports it;
#   output error (examples/two_tank_oe.yaml: from the same start, the initial
#   levels estimated), its estimates with standard errors and 95 % intervals;
#
# then both side by side, each model simulated over the data (the fit), and
# a PNG of measured and model outputs over time; stop the daemon.
#
#   scripts/main-job.sh          # Hensen's with the EKF
#   scripts/main-job.sh ukf      # the same with the UKF
#
# The figure and the CSV files it is drawn from go to $RICCATI_MAIN_JOB_OUT
# (default build/main-job).
set -euo pipefail
cd "$(dirname "$0")/.."
filter=${1:-ekf}
start=$SECONDS
scripts/install-deps.sh plot
packages_s=$((SECONDS - start))
echo "main-job: building riccatid and riccati in build/ (ninja; the first time takes minutes)"
build_log=$(mktemp)
# ninja writes its errors to stdout: shown when the build fails, else dropped.
scripts/build.sh riccatid riccati >"$build_log" 2>&1 || { tail -n 40 "$build_log" >&2; echo "main-job: the build failed" >&2; exit 1; }
rm -f "$build_log"
build_s=$((SECONDS - start - packages_s))
out=$(mkdir -p "${RICCATI_MAIN_JOB_OUT:-build/main-job}" && cd "${RICCATI_MAIN_JOB_OUT:-build/main-job}" && pwd)

data_dir=$(mktemp -d)
build/bin/riccatid --listen 127.0.0.1:0 --data-dir "$data_dir" --port-file "$data_dir/port" --log-level warn &
daemon=$!
trap 'kill -TERM $daemon 2>/dev/null; wait $daemon 2>/dev/null; rm -rf "$data_dir"' EXIT
for _ in $(seq 100); do [ -s "$data_dir/port" ] && break; sleep 0.1; done
[ -s "$data_dir/port" ] || { echo "main-job: riccatid did not start" >&2; exit 1; }
export RICCATI_SERVER="127.0.0.1:$(cat "$data_dir/port")"
truth=10,5,0.0791,0.1342
# riccati, its messages kept in $out/riccati.log and shown if it fails.
riccati() {
  build/bin/riccati "$@" 2>"$out/riccati.log" || { cat "$out/riccati.log" >&2; echo "main-job: riccati $1 failed" >&2; exit 1; }
}

dataset=$(riccati data upload tests/data/two_tank.csv --inputs F1,F2 --outputs h1,h2)
echo "Identification of two_tank on two_tank.csv, riccatid at $RICCATI_SERVER"
echo
echo "Hensen's iterated $filter (examples/two_tank_hensen.yaml)"
hensen=$(riccati identify --config examples/two_tank_hensen.yaml --data "$dataset" --filter "$filter" --no-wait)
riccati job watch "$hensen" >/dev/null
riccati result "$hensen" --truth "$truth" | tee "$out/hensen.txt"
echo
echo "Output error (examples/two_tank_oe.yaml; sigma sqrt(1e-3), the noise Hensen's R = 1e-3 assumes)"
oe=$(riccati identify --config examples/two_tank_oe.yaml --data "$dataset" --no-wait)
riccati job watch "$oe" >/dev/null
# The optimiser's summary and the parameter table (correlations, fit and
# residual tests: riccati result with the job's id).
riccati result "$oe" --truth "$truth" >"$out/oe.txt"
sed -n '1,/^$/p' "$out/oe.txt"
sed -n '/^parameter/,/^$/p' "$out/oe.txt" | sed '/^$/d'
echo
echo "Side by side: each estimate, its standard error and 95 % interval"
# The rows of the two tables: Hensen's "NAME initial estimate stderr [lo, hi]
# filterstd final true error%", output error's "NAME initial estimate stderr
# [lo, hi] rel.std true error%".
awk -v method="$filter" '
  FNR == 1 { file++ }
  /^parameter/ { table = 1; next }
  table && (NF == 0 || /^\(/ || /^innovation/) { table = 0 }
  table && file == 1 { names[++n] = $1; h[$1] = $3; hs[$1] = $4; hci[$1] = $5 " " $6; t[$1] = $9 }
  table && file == 2 { o[$1] = $3; os[$1] = $4; ci[$1] = $5 " " $6 }
  END {
    printf "%-9s %7s   %-49s   %s\n", "", "", "Hensen'"'"'s iterated " method, "output error"
    printf "%-9s %7s   %11s %9s %27s   %11s %9s %27s\n", "parameter", "true", "estimate", "std. err.", "95 % interval",
           "estimate", "std. err.", "95 % interval"
    for (i = 1; i <= n; i++) {
      p = names[i]
      printf "%-9s %7s   %11s %9s %27s   %11s %9s %27s\n", p, t[p], h[p], hs[p], hci[p], o[p], os[p], ci[p]
    }
  }' "$out/hensen.txt" "$out/oe.txt"
echo
echo "Validation: each identified model simulated over the data"
echo "Hensen's:"
riccati validate --model two_tank --params "$hensen" --data "$dataset" >"$out/validate.txt"
validation=$(sed -n 's/^job \(job-[0-9a-f]*\).*/\1/p' "$out/riccati.log")
tail -n +2 "$out/validate.txt"
echo "output error's:"
riccati validate --model two_tank --params "$oe" --data "$dataset" >"$out/validate.txt"
tail -n +2 "$out/validate.txt"

# The figure: measured and model levels over time, and each model's error.
riccati result "$validation" --format csv -o "$out/hensen_simulated.csv"
riccati result "$oe" --format csv -o "$out/oe_fit.csv"
gnuplot <<EOF
set terminal pngcairo size 1100,800 font "DejaVu Sans,10" noenhanced
set output "$out/two_tank_fit.png"
set datafile separator ","
set multiplot layout 2,1 title "riccati: two_tank on tests/data/two_tank.csv, identified from theta0 = [20 20 1 1]"
set xlabel "t (s)"
set ylabel "level (m)"
set yrange [0:1]
set key top center maxrows 2 width -2
set title "measured (every 20th sample) and simulated with each estimate"
plot "$out/oe_fit.csv" every 20 using 2:3 with points pt 7 ps 0.45 lc rgb "#303030" title "h1 measured", \
     "" every 20 using 2:4 with points pt 6 ps 0.45 lc rgb "#303030" title "h2 measured", \
     "" using 2:5 with lines lw 1.2 lc rgb "#1f77b4" title "h1 output error", \
     "" using 2:6 with lines lw 1.2 lc rgb "#2ca02c" title "h2 output error", \
     "$out/hensen_simulated.csv" using 1:4 with lines lw 1.2 dt 2 lc rgb "#d62728" title "h1 Hensen's $filter", \
     "" using 1:5 with lines lw 1.2 dt 2 lc rgb "#ff7f0e" title "h2 Hensen's $filter"
set title "simulation error, measured - simulated (output error's is all but 0: the record has no noise)"
set ylabel "m"
set autoscale y
set key top right maxrows 4
plot "$out/hensen_simulated.csv" using 1:(\$2-\$4) with lines lw 1.2 lc rgb "#d62728" title "h1 Hensen's $filter", \
     "" using 1:(\$3-\$5) with lines lw 1.2 lc rgb "#ff7f0e" title "h2 Hensen's $filter", \
     "$out/oe_fit.csv" using 2:(\$3-\$5) with lines lw 2 lc rgb "#1f77b4" title "h1 output error", \
     "" using 2:(\$4-\$6) with lines lw 1.2 lc rgb "#2ca02c" title "h2 output error"
unset multiplot
EOF
echo
echo "Figure: $out/two_tank_fit.png (measured and simulated levels over time, and the simulation errors)"
echo "main-job: packages ${packages_s} s, build ${build_s} s, identifications and figure $((SECONDS - start - packages_s - build_s)) s"
