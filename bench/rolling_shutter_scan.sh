#!/bin/bash
# Is there a rolling shutter in a run's video? (docs/regimes.md, "box.mp4 has a rolling shutter").
# A rolling shutter exposes row y at time t_k + tau (y - cy) / h (tau: the readout time of the
# image height in frame intervals; the middle row at the frame's time), so a point moving at v
# px/frame is seen at x_gs + tau (y - cy) / h v. This script takes a run's tracks on its planes
# (labels.csv >= 0, so that every tau sees the same tracks), corrects them to first order with
# each track's own velocity (central differences; one-sided at its ends),
#   x_gs = x_obs - tau (y_obs - cy) / h v,
# and refines each corrected set with `rsfm estimate` (default options). A global shutter's
# residual sd is lowest at tau = 0 (a rendered run: rising with tau); a rolling shutter's at its
# readout. The correction uses the observed velocity, noisy and constant over the frame: a
# measurement, not a model of the shutter.
# Usage: bash bench/rolling_shutter_scan.sh BUILD_DIR RUN_DIR [TAU...] (RUN_DIR: an `rsfm run` or
# `rsfm estimate` output with tracks.csv and labels.csv; default taus 0 0.5 1 1.5). Prints one
# line per tau: residual sd and robust sd (px), focal length, k1, the determined angles between
# planes. Writes its scratch runs under a temporary directory.
set -euo pipefail
build=${1:?build directory}; run=${2:?a run directory with tracks.csv and labels.csv}
shift 2
taus=("$@"); [ ${#taus[@]} -gt 0 ] || taus=(0 0.5 1 1.5)
py=/usr/bin/python3
for f in tracks.csv labels.csv; do [ -f "$run/$f" ] || { echo "$run/$f: missing" >&2; exit 2; }; done
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
cat >"$tmp/correct.py" <<'PY'
import csv, sys
tracks, labels, tau, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
keep = {int(r["track"]) for r in csv.DictReader(open(labels)) if int(r["label"]) >= 0}
head, rows = [], []
h, cy = None, None
for line in open(tracks):
    if line.startswith("#") or line.startswith("frame,"):
        head.append(line)
        w = line.split()
        if line.startswith("# image_size"): h = float(w[3])
        if line.startswith("# principal_point"): cy = float(w[3])
        continue
    f, t, x, y = line.strip().split(",")[:4]
    if int(t) in keep: rows.append((int(f), int(t), float(x), float(y)))
if h is None: sys.exit(f"{tracks}: no '# image_size' line")
if cy is None: cy = (h - 1) / 2
by = {}
for f, t, x, y in rows: by.setdefault(t, {})[f] = (x, y)
body = []
for f, t, x, y in rows:
    o = by[t]; a, b = o.get(f - 1), o.get(f + 1)
    if a and b: v = ((b[0] - a[0]) / 2, (b[1] - a[1]) / 2)
    elif b: v = (b[0] - x, b[1] - y)
    elif a: v = (x - a[0], y - a[1])
    else: v = (0.0, 0.0)
    s = tau * (y - cy) / h
    body.append(f"{f},{t},{x - s * v[0]:.6f},{y - s * v[1]:.6f}\n")
open(out, "w").write("".join(head) + "".join(body))
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
for tau in "${taus[@]}"; do
  $py "$tmp/correct.py" "$run/tracks.csv" "$run/labels.csv" "$tau" "$tmp/t.csv"
  if "$build/rsfm" estimate --tracks "$tmp/t.csv" --no-plots --quiet --out "$tmp/e" >/dev/null 2>"$tmp/err"; then
    $py "$tmp/row.py" "$tau" "$tmp/e/summary.json"
  else
    echo "tau $tau: rsfm estimate failed: $(head -c 200 "$tmp/err")"
  fi
done
