#!/bin/bash
# The main plane's online reprojection RMS with every plane against the main plane alone, for
# each run of a regime scoreboard with two planes or more (docs/regimes.md, "A per-plane
# consistency test"). Usage: bash bench/plane_consistency.sh BUILD_DIR RUNS_DIR [online|refined]
# (RUNS_DIR: `rsfm bench regimes --out DIR`'s DIR/runs; online: the filter's RMS, --refine none,
# the default; refined: the refinement's). Writes scratch runs under a temporary directory;
# prints one line per run.
set -euo pipefail
build=${1:?build directory}; runs=${2:?the runs directory of rsfm bench regimes}
mode=${3:-online}
case "$mode" in online) refine=(--refine none) ;; refined) refine=(--refine final) ;; *) echo "mode: online or refined" >&2; exit 2 ;; esac
py=/usr/bin/python3
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
report='
import json, sys
name, a, b = sys.argv[1], json.load(open(sys.argv[2])), json.load(open(sys.argv[3]))
ra, rb = a["plane_reprojection_rms_px"], b["plane_reprojection_rms_px"]
print("%-20s planes %d tracks %s rms %s  main alone %.3f  variance ratio %.2f"
      % (name, len(ra), a["plane_tracks"], " ".join("%.3f" % x for x in ra), rb[0], (ra[0] / rb[0]) ** 2))
'
for dir in "$runs"/*/; do
  d=$(basename "$dir")
  [ -f "$dir/tracks.csv" ] && [ -f "$dir/summary.json" ] || continue
  n=$($py -c "import json,sys; print(len(json.load(open(sys.argv[1])).get('plane_tracks', [])))" "$dir/summary.json")
  [ "$n" -ge 2 ] || continue
  "$build/rsfm" estimate --tracks "$dir/tracks.csv" "${refine[@]}" --no-plots --quiet --out "$tmp/$d/all" >/dev/null 2>&1 || continue
  "$build/rsfm" estimate --tracks "$dir/tracks.csv" "${refine[@]}" --no-plots --quiet --max-planes 1 --out "$tmp/$d/one" >/dev/null 2>&1 || continue
  $py -c "$report" "$d" "$tmp/$d/all/summary.json" "$tmp/$d/one/summary.json"
done
