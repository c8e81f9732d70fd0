#!/usr/bin/env bash
# Fuzzes the CSV and MAT readers, the request validation and the text model
# compiler with libFuzzer
# (clang, AddressSanitizer, UndefinedBehaviorSanitizer), each target for
# SECONDS seconds (default 60; CI runs 30). Any crash, leak, sanitizer report,
# timeout (10 s per input) or out-of-memory fails the run; the input that did
# it is kept in build-san/artifacts/ and its path printed. The build is the
# sanitized tree that scripts/sanitize.sh tests (scripts/configure-sanitized.sh).
#
#   scripts/fuzz.sh [SECONDS] [TARGET...]     targets: csv_fuzz mat_fuzz request_fuzz
#                                                       text_model_fuzz
#
# The corpora grow in build-san/corpus/ from one run to the next.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(csv_fuzz mat_fuzz request_fuzz text_model_fuzz)

scripts/install-deps.sh test fuzz
build_dir=${RICCATI_SAN_BUILD_DIR:-build-san}
scripts/configure-sanitized.sh "$build_dir"
ninja -C "$build_dir" "${targets[@]}" fuzz_seed_writer

seeds="$build_dir/seeds"
"$build_dir/bin/fuzz_seed_writer" "$seeds"
mkdir -p "$build_dir/artifacts"
export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1
export UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
status=0
for target in "${targets[@]}"; do
  corpus="$build_dir/corpus/$target"
  mkdir -p "$corpus"
  case $target in
    csv_fuzz) seed="$seeds/csv" ;;
    mat_fuzz) seed="$seeds/mat" ;;
    request_fuzz) seed="$seeds/request" ;;
    text_model_fuzz) seed=models/text ;;  # the shipped text models
    *) echo "fuzz: unknown target $target" >&2; exit 2 ;;
  esac
  echo "fuzz: $target for ${seconds}s"
  if ! "$build_dir/bin/$target" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -max_len=8192 \
      -print_final_stats=1 -artifact_prefix="$build_dir/artifacts/$target-" "$corpus" "$seed" \
      >"$build_dir/$target.log" 2>&1; then
    echo "fuzz: $target FAILED; its log:" >&2
    tail -n 60 "$build_dir/$target.log" >&2
    status=1
  else
    grep -E "^stat::number_of_executed_units|^Done" "$build_dir/$target.log" | sed "s/^/fuzz: $target: /"
  fi
done
exit $status
