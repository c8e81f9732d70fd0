#!/usr/bin/env bash
# Output error on the two-tank record: riccati (engine_bench's
# TwoTankOutputError/substeps:10, RK4, and TwoTankOutputErrorDop853/substeps:1,
# the 8th-order method one step a sample) against scipy.optimize.least_squares
# (bench/oe_scipy.py) on the same data, start, bounds and tolerances, in one
# run on the same machine state (docs/benchmarks.md, "Identification: output
# error against scipy").
#
#   bench/oe_versus_scipy.sh [rounds] [repetitions]      # default 2 rounds of 5
#
# Each round runs, for every scipy variant in turn, riccati (both
# integrators) and then that variant, `repetitions` times each, so every
# ratio comes from adjacent measurements; each time is the median of its repetitions. Prints a Markdown
# table (CPU and wall time, the ratio, the worst relative error against the
# truth of two_tank.json, the simulations of the record); the raw JSON stays
# in $OUT (default build/oe_versus_scipy).
#
# Needs Debian's python3-scipy and python3-numpy (apt-get install
# python3-scipy python3-numpy), which the build itself does not: the script
# runs /usr/bin/python3 (set PYTHON to another interpreter that has them).
# VARIANTS picks the scipy variants ("integrator:jacobian ..."); NO_BUILD=1
# skips the build.
set -euo pipefail
cd "$(dirname "$0")/.."

rounds=${1:-2}
repetitions=${2:-5}
python=${PYTHON:-/usr/bin/python3}
out=${OUT:-build/oe_versus_scipy}
default_variants="odeint:2-point odeint:sensitivity rk4:2-point rk4:sensitivity solve_ivp:2-point solve_ivp:sensitivity"
read -r -a variants <<<"${VARIANTS:-$default_variants}"

if ! "$python" -c 'import numpy, scipy' 2>/dev/null; then
  echo "oe_versus_scipy: $python has no numpy/scipy; on Debian: apt-get install python3-scipy python3-numpy" >&2
  exit 1
fi
[ "${NO_BUILD:-0}" = 1 ] || scripts/build.sh engine_bench >/dev/null
bench=${RICCATI_BUILD_DIR:-build}/bin/engine_bench

# One core each, like riccati's solver (Ceres with one thread): no BLAS threads.
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1

mkdir -p "$out"
rm -f "$out"/*.json
{
  echo "date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  echo "commit: $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- . 2>/dev/null || echo ' (modified)')"
  echo "cpu: $(getconf _NPROCESSORS_ONLN) x $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')"
  echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
} >"$out/machine.txt"

for ((r = 1; r <= rounds; r++)); do
  for v in "${variants[@]}"; do
    integrator=${v%%:*} jacobian=${v#*:}
    echo "round $r: riccati, then scipy $integrator $jacobian" >&2
    "$bench" --benchmark_filter='^TwoTankOutputError/substeps:10$' --benchmark_repetitions="$repetitions" \
      --benchmark_format=json 2>/dev/null >"$out/riccati.$r.$v.json"
    "$bench" --benchmark_filter='^TwoTankOutputErrorDop853/substeps:1$' --benchmark_repetitions="$repetitions" \
      --benchmark_format=json 2>/dev/null >"$out/riccati-dop853.$r.$v.json"
    "$python" bench/oe_scipy.py --integrator "$integrator" --jacobian "$jacobian" \
      --repetitions "$repetitions" >"$out/scipy.$r.$v.json"
  done
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)" >>"$out/machine.txt"

"$python" - "$out" "$rounds" "${variants[@]}" <<'EOF'
import json, statistics, sys

out, rounds, variants = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
names = {"rk4": "RK4, 10 substeps (pure Python)", "odeint": "odeint (LSODA), rtol 1e-13",
         "solve_ivp": "solve_ivp (DOP853), rtol 1e-13"}

def riccati(path):
    runs = json.load(open(path))["benchmarks"]
    one = next(b for b in runs if b.get("run_type") == "iteration")
    med = next((b for b in runs if b.get("aggregate_name") == "median"), one)  # none with one repetition
    scale = {"ms": 1e-3, "us": 1e-6, "ns": 1e-9, "s": 1.0}[med["time_unit"]]
    return {"cpu_s": med["cpu_time"] * scale, "wall_s": med["real_time"] * scale,
            "worst_rel_error": one["worst_rel_error"], "simulations": int(one["evaluations"]),
            "sensitivity_simulations": int(one["jacobian_evaluations"]), "iterations": int(one["iterations"]),
            "label": one.get("label", "")}

def ms(values):
    return ", ".join("%.0f" % (1e3 * v) if v >= 0.1 else "%.1f" % (1e3 * v) for v in values)

print(open(out + "/machine.txt").read().rstrip())
print()
print("| solver | integrator | Jacobian | CPU ms (each round) | wall ms (each round) | "
      "worst rel. error | simulations: states + with sensitivities | riccati RK4 faster by | riccati DOP853 faster by |")
print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
runs = {tag: [riccati("%s/%s.%d.%s.json" % (out, tag, r, v)) for r in range(1, rounds + 1) for v in variants]
        for tag in ("riccati", "riccati-dop853")}
rc = runs["riccati"][0]
for tag, what in (("riccati", "RK4, 10 substeps"), ("riccati-dop853", "DOP853 (8th order), 1 step a sample")):
    all_runs = runs[tag]
    first = all_runs[0]
    print("| riccati `oe` (Ceres LM) | %s | forward sensitivities "
          "| %.0f (median of %d medians, %.0f-%.0f) | %.0f | %.1e | %d + %d | | |" % (
        what, 1e3 * statistics.median(x["cpu_s"] for x in all_runs), len(all_runs),
        1e3 * min(x["cpu_s"] for x in all_runs), 1e3 * max(x["cpu_s"] for x in all_runs),
        1e3 * statistics.median(x["wall_s"] for x in all_runs), first["worst_rel_error"],
        first["simulations"] - first["sensitivity_simulations"], first["sensitivity_simulations"]))
for v in variants:
    integrator, jacobian = v.split(":", 1)
    s = [json.load(open("%s/scipy.%d.%s.json" % (out, r, v))) for r in range(1, rounds + 1)]
    ratios = []
    for tag in ("riccati", "riccati-dop853"):
        ric = [riccati("%s/%s.%d.%s.json" % (out, tag, r, v)) for r in range(1, rounds + 1)]
        ratios.append(", ".join("%.1f" % (a["cpu_s"] / b["cpu_s"]) for a, b in zip(s, ric)))
    print("| scipy least_squares (trf) | %s | %s | %s | %s | %.1e | %d + %d | %s | %s |" % (
        names.get(integrator, integrator), "finite differences (2-point)" if jacobian == "2-point" else
        "forward sensitivities", ms(x["cpu_s"] for x in s), ms(x["wall_s"] for x in s), s[0]["worst_rel_error"],
        s[0]["simulations"], s[0]["sensitivity_simulations"], ratios[0], ratios[1]))
print()
print("riccati's estimate (RK4): " + rc["label"])
print("riccati's estimate (DOP853): " + runs["riccati-dop853"][0]["label"])
for v in variants:
    s = json.load(open("%s/scipy.%d.%s.json" % (out, 1, v)))
    print("scipy %-22s theta=%s  nfev=%d njev=%s, %s (scipy %s, numpy %s)" % (
        v, s["theta"], s["nfev"], s["njev"], s["message"], s["scipy"], s["numpy"]))
EOF
