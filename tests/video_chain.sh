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

# The affine-patch filter on the same sequence (issue 5): rsfm run --model patches -> evaluate, then
# focal within 5 %, ATE under 3 %, and each patch normal against the nearest true face: median
# under 3 deg, at least 90 % within 5 deg.
"$RSFM" run "$TMP/r/video.mp4" --model patches --out "$TMP/p" --quiet
"$RSFM" evaluate --estimate "$TMP/p" --truth "$TMP/r/truth" >"$TMP/ptable.txt"
for f in trajectory.tum patch_normals.csv summary.json patches.csv overlay.mp4 patch_run.png patch_run.svg \
         evaluation.json; do
  [ -s "$TMP/p/$f" ] || { echo "FAIL missing patch output $f"; exit 1; }
done
/usr/bin/python3 - "$TMP/p" "$TMP/r/truth/summary.json" <<'PY'
import csv, json, math, sys
d, truth = sys.argv[1], json.load(open(sys.argv[2]))
e = json.load(open(d + "/evaluation.json"))
rows = list(csv.DictReader(open(d + "/patch_normals.csv")))
last = max(int(r["frame"]) for r in rows)
def angle(a, b):
    c = abs(sum(x * y for x, y in zip(a, b))) / math.sqrt(sum(x * x for x in a) * sum(y * y for y in b))
    return math.degrees(math.acos(min(1.0, c)))
errs = sorted(min(angle((float(r["rx"]), float(r["ry"]), float(r["rz"])), t) for t in truth["planes"])
              for r in rows if int(r["frame"]) == last)
med, within = errs[len(errs) // 2], sum(x <= 5 for x in errs) / len(errs)
focal, ate = abs(e["focal"]["error_pct"]), e["ate"]["rmse_pct"]
print(f"patches: focal error {focal:.2f} %, ATE {ate:.2f} %, {len(errs)} patches: normal error to the nearest face "
      f"median {med:.2f} deg, {100 * within:.0f} % within 5 deg")
sys.exit(0 if focal < 5 and ate < 3 and med < 3 and within >= 0.9 else 1)
PY
