#!/bin/bash
# opencv-doc box.mp4 (455 frames: a hand turns a box before a still webcam) in windows spread over
# the whole video, default options: what a user who picks any stretch of it would see
# (docs/regimes.md, "box.mp4 across the whole video"). The regime bench scores ten 150-frame
# windows starting at 0-18; this covers the rest. Prints a Markdown table, one row per window:
# exit code, planes, which are determined, the determined angles between planes with their sds, the focal length
# and its sd (or "not determined" with the supported interval), the rolling shutter's readout
# estimated and its sd (frame intervals), and the start of not_determined_why. Usage: bash bench/box_windows.sh BUILD_DIR [LENGTH [STEP [FIRST]]]
# (defaults 150 frames, every 25 frames from 20). Needs opencv-doc (box.mp4.gz) or the regime
# bench's cached copy. Writes its runs under a temporary directory.
set -euo pipefail
build=${1:?build directory}
len=${2:-150}; step=${3:-25}; first=${4:-20}
py=/usr/bin/python3
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
gz=/usr/share/doc/opencv-doc/opencv4/html/box.mp4.gz
if [ -f "$gz" ]; then
  zcat "$gz" >"$tmp/box.mp4"
elif [ -f "$HOME/.cache/rsfm/regimes/real/box.mp4" ]; then
  cp "$HOME/.cache/rsfm/regimes/real/box.mp4" "$tmp/box.mp4"
else
  echo "box.mp4 not found: sudo apt-get install opencv-doc" >&2; exit 77
fi
frames=455
cat >"$tmp/row.py" <<'PY'
import json, sys
w, rc, path = sys.argv[1], int(sys.argv[2]), sys.argv[3]
if rc != 0:
    print("| %s | %d | | | | | | |" % (w, rc))
    sys.exit(0)
s = json.load(open(path))
det = s.get("plane_determined") or []
ang = ["%.1f +- %.1f" % (a["angle_deg"], a["sd_deg"]) if a.get("sd_deg") is not None else "%.1f" % a["angle_deg"]
       for a in s.get("angles_between_planes_deg") or [] if a.get("determined")]
if s.get("focal_determined"):
    f = "%.1f +- %.1f" % (s["focal_px"], s["focal_sd_px"])
else:
    lo, hi = s.get("focal_interval_px") or [None, None]
    f = "not determined (%s to %s px)" % ("0" if lo is None else "%.0f" % lo, "inf" if hi is None else "%.0f" % hi)
why = (s.get("not_determined_why") or "").replace("|", "/")
why = "; ".join(p for p in why.split("; ") if not p.startswith(("principal point not determined", "held at")))[:110]
cam = s.get("camera") or {}
ro = "%.2f +- %.2f" % (cam["readout"], cam["readout_sd"]) if cam.get("readout") is not None and cam.get("readout_sd") is not None else "-"
print("| %s | 0 | %d (tracks %s) | %d | %s | %s | %s | %s |" % (w, len(det), s["plane_tracks"], sum(map(bool, det)), ", ".join(ang), f, ro, why))
PY
echo "| window | exit | planes | determined | angles deg | focal px | rolling shutter readout | not determined (principal point omitted) |"
echo "|---|---|---|---|---|---|---|---|"
for ((s = first; s + len <= frames; s += step)); do
  e=$((s + len - 1))
  rc=0
  "$build/rsfm" run "$tmp/box.mp4" --first "$s" --last "$e" --out "$tmp/w$s" --no-overlay --no-plots --quiet \
    >"$tmp/w$s.log" 2>&1 || rc=$?
  $py "$tmp/row.py" "$s-$e" "$rc" "$tmp/w$s/summary.json"
done
