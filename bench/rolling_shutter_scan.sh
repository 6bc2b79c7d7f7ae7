#!/bin/bash
# Is there a rolling shutter in a run's video? (docs/regimes.md, "box.mp4 has a rolling shutter").
# A rolling shutter exposes row y at time t_k + tau (y - (h - 1) / 2) / h (tau: the readout time
# of the image height in frame intervals; the middle row at the frame's time), so a point moving
# at v px/frame is seen at x_gs + tau (y - (h - 1) / 2) / h v. This script takes a run's tracks on
# its planes (labels.csv >= 0, so that every tau sees the same tracks) and refines them with
# `rsfm estimate --rolling-shutter-readout TAU` (default options otherwise), which moves them back
# to first order with each track's own velocity (rsfm/track/tracks.hpp, correctRollingShutter;
# docs/estimate.md section 6). A global shutter's residual sd is lowest at tau = 0 (a rendered
# run: rising with tau); a rolling shutter's near its readout.
# Usage: bash bench/rolling_shutter_scan.sh BUILD_DIR RUN_DIR [TAU...] (RUN_DIR: an `rsfm run` or
# `rsfm estimate` output with tracks.csv and labels.csv; default taus 0 0.5 1 1.5). Prints one
# line per tau: residual sd and robust sd (px), focal length, k1, the tracks, the determined
# angles between planes. Writes its scratch runs under a temporary directory.
set -euo pipefail
build=${1:?build directory}; run=${2:?a run directory with tracks.csv and labels.csv}
shift 2
taus=("$@"); [ ${#taus[@]} -gt 0 ] || taus=(0 0.5 1 1.5)
py=/usr/bin/python3
for f in tracks.csv labels.csv; do [ -f "$run/$f" ] || { echo "$run/$f: missing" >&2; exit 2; }; done
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
cat >"$tmp/keep.py" <<'PY'
import csv, sys
tracks, labels, out = sys.argv[1:4]
keep = {int(r["track"]) for r in csv.DictReader(open(labels)) if int(r["label"]) >= 0}
lines = []
for line in open(tracks):
    if line.startswith("#") or line.startswith("frame,") or int(line.split(",")[1]) in keep:
        lines.append(line)
open(out, "w").write("".join(lines))
PY
cat >"$tmp/row.py" <<'PY'
import json, sys
tau, s = sys.argv[1], json.load(open(sys.argv[2]))
r = s.get("refinement") or {}
if not r.get("ok"):
    print(f"tau {tau:>5}: no refinement ({r.get('message', '')})"); sys.exit(0)
f = s["focal_px"] if s.get("focal_determined") else s.get("focal_estimate_px")
ang = ", ".join("%.1f +- %.1f" % (a["angle_deg"], a["sd_deg"]) for a in s.get("angles_between_planes_deg") or []
                if a.get("determined") and a.get("sd_deg") is not None)
print(f"tau {tau:>5}: residual sd {r['sigma_px']:.4f} px, robust {r['robust_sigma_px']:.4f} px; focal {f:.1f} px"
      f"{'' if s.get('focal_determined') else ' (not determined)'}; k1 {s['radial_distortion'][0]:+.3f}; "
      f"tracks {s['plane_tracks']}, relabelled {r['relabelled_outliers']}; angles [{ang}]")
PY
$py "$tmp/keep.py" "$run/tracks.csv" "$run/labels.csv" "$tmp/t.csv"
for tau in "${taus[@]}"; do
  if "$build/rsfm" estimate --tracks "$tmp/t.csv" --rolling-shutter-readout "$tau" --no-plots --quiet --out "$tmp/e" \
    >/dev/null 2>"$tmp/err"; then
    $py "$tmp/row.py" "$tau" "$tmp/e/summary.json"
  else
    echo "tau $tau: rsfm estimate failed: $(head -c 200 "$tmp/err")"
  fi
done
