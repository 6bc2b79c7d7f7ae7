#!/usr/bin/env bash
# Runs every libFuzzer target of tests/fuzz for SECONDS each (tests/fuzz/README.md):
#   bash tests/fuzz/run.sh BUILD_DIR SECONDS [TARGET...]
# Each target starts from its seed corpus (tests/fuzz/corpus/NAME, read only) and grows a work
# corpus in BUILD_DIR/fuzz-corpus/NAME; findings (crash-*, timeout-*, oom-*) go to
# BUILD_DIR/fuzz-findings/NAME and the log to BUILD_DIR/fuzz-logs/NAME.log. Prints one line per
# target: executions, coverage, corpus size, findings. Exit 1 if any target found anything.
set -uo pipefail
build=${1:?usage: run.sh BUILD_DIR SECONDS [TARGET...]}
seconds=${2:?usage: run.sh BUILD_DIR SECONDS [TARGET...]}
shift 2
here=$(cd "$(dirname "$0")" && pwd)
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(tracks patches tum summary camera)
status=0
for t in "${targets[@]}"; do
  bin=$build/fuzz_$t
  [ -x "$bin" ] || { echo "run.sh: $bin not built (make fuzz-build)" >&2; exit 2; }
  mkdir -p "$build/fuzz-corpus/$t" "$build/fuzz-findings/$t" "$build/fuzz-logs"
  log=$build/fuzz-logs/$t.log
  # Limits: 2 GB of memory and 10 s per input are findings (oom-*, timeout-*): a reader's memory
  # and time follow its input.
  ASAN_OPTIONS=detect_leaks=0 "$bin" "$build/fuzz-corpus/$t" "$here/corpus/$t" \
    -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -max_len=16384 -print_final_stats=1 \
    -artifact_prefix="$build/fuzz-findings/$t/" >"$log" 2>&1
  rc=$?
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$')
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  corpus=$(find "$build/fuzz-corpus/$t" -type f | wc -l)
  found=$(find "$build/fuzz-findings/$t" -type f | wc -l)
  echo "fuzz $t: ${seconds} s, ${execs:-?} executions, coverage ${cov:-?} edges (${ft:-?} features), corpus $corpus, findings $found (exit $rc)"
  [ "$rc" -ne 0 ] || [ "$found" -ne 0 ] && status=1
done
exit $status
