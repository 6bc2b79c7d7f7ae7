#!/usr/bin/env bash
# End to end on a rendered sequence (issue 4's targets): render -> rsfm run -> rsfm evaluate, then
# check the focal length within 3 %, every matched plane normal within 2 deg, Sim(3)-aligned ATE
# under 2 % of the scene size, at least two planes matched, and every output file present.
# Usage: video_chain.sh path/to/rsfm
set -euo pipefail
RSFM="$1"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
"$RSFM" render box --out "$TMP/r" --frames 100 --quiet
"$RSFM" run "$TMP/r/video.mp4" --out "$TMP/e" --quiet
"$RSFM" evaluate --estimate "$TMP/e" --truth "$TMP/r/truth" >"$TMP/table.txt"
for f in trajectory.tum planes.csv summary.json labels.csv tracks.csv overlay.mp4 motion.png normals.png focal.png \
         motion.svg normals.svg focal.svg evaluation.json evaluation.md; do
  [ -s "$TMP/e/$f" ] || { echo "FAIL missing output $f"; exit 1; }
done
/usr/bin/python3 - "$TMP/e/evaluation.json" <<'PY'
import json, sys
e = json.load(open(sys.argv[1]))
focal = abs(e["focal"]["error_pct"])
ate = e["ate"]["rmse_pct"]
matched = [p for p in e["planes"] if p["estimate"] is not None]
worst = max(p["angle_deg"] for p in matched)
print(f"focal error {focal:.2f} %, ATE {ate:.3f} % of scene size, {len(matched)} planes matched, worst normal {worst:.2f} deg")
ok = focal < 3.0 and ate < 2.0 and len(matched) >= 2 and worst < 2.0
sys.exit(0 if ok else 1)
PY
