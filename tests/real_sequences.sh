#!/usr/bin/env bash
# Real sequences. Issue 5: the ViSP cube (visp-images-data) through the affine-patch filter,
# checked against what the images show (docs/patches.md):
# - the floor patches (within 30 deg of the median normal) agree: at least 90 % within 5 deg of
#   their median;
# - the first view looks straight down at the posters: the floor's median normal in the first
#   camera frame is within 10 deg of the optical axis;
# - the patches on the cube's vertical faces (more than 60 deg off the floor) are within 10 deg of
#   perpendicular to it.
# Skips (exit 77) when visp-images-data is not installed, except under CI, where it fails.
# Usage: real_sequences.sh path/to/rsfm
set -euo pipefail
RSFM="$1"
CUBE=/usr/share/visp-images-data/ViSP-images/cube
if [ ! -f "$CUBE/image.0000.pgm" ]; then
  if [ -n "${CI:-}" ]; then echo "FAIL $CUBE missing under CI (.ci/run installs visp-images-data)"; exit 1; fi
  echo "SKIP: $CUBE not found (sudo apt-get install visp-images-data)"
  exit 77
fi
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
"$RSFM" run "$CUBE/image.%04d.pgm" --model patches --out "$TMP/c" --quiet
/usr/bin/python3 - "$TMP/c/summary.json" <<'PY'
import json, math, sys
s = json.load(open(sys.argv[1]))
n = s["last_frame_normals"]
angles = [p["angle_to_median_deg"] for p in n["patches"]]
floor = [a for a in angles if a < 30]
sides = [a for a in angles if a > 60]
within = sum(a <= 5 for a in floor) / len(floor)
m = n["median_normal_reference"]
tilt = math.degrees(math.acos(abs(m[2]) / math.sqrt(sum(x * x for x in m))))
print(f"cube: {len(floor)} floor patches, {100 * within:.0f} % within 5 deg of their median; floor tilt in the first "
      f"view {tilt:.1f} deg; {len(sides)} side patches at {', '.join(f'{a:.1f}' for a in sides)} deg; "
      f"focal {s['focal_px']:.0f} px")
ok = len(floor) >= 20 and within >= 0.9 and tilt < 10 and all(abs(a - 90) < 10 for a in sides)
sys.exit(0 if ok else 1)
PY

# opencv-doc's box.mp4, frames 14-163 (the regime bench's window 14): without the tracks the
# refinement relabels outliers, the data pull the principal point 195 px below the image centre
# (no camera is like that). Every reported camera must be plausible: the principal point within
# 10 % of the larger side of the centre (RefineOptions::max_principal_offset), or held at the
# centre and said so; and a distortion that does not fold the image.
BOX_GZ=/usr/share/doc/opencv-doc/opencv4/html/box.mp4.gz
if [ ! -f "$BOX_GZ" ]; then
  if [ -n "${CI:-}" ]; then echo "FAIL $BOX_GZ missing under CI (.ci/run installs opencv-doc)"; exit 1; fi
  echo "SKIP: $BOX_GZ not found (sudo apt-get install opencv-doc)"
  exit 77
fi
zcat "$BOX_GZ" >"$TMP/box.mp4"
"$RSFM" run "$TMP/box.mp4" --first 14 --last 163 --out "$TMP/b14" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/b14/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
w, h = s["image"]["width"], s["image"]["height"]
cx, cy = (w - 1) / 2, (h - 1) / 2
px, py = s["principal_point_px"]
off = max(abs(px - cx), abs(py - cy)) / max(w, h)
why = s.get("not_determined_why") or ""
held = (px, py) == (cx, cy)
print(f"box.mp4 frames 14-163: principal point ({px:.1f}, {py:.1f}), {100 * off:.1f} % of the image off centre"
      f"{' (held: ' + why[:90] + ')' if held and why else ''}; k1, k2 {s['radial_distortion']}")
ok = off <= 0.10 and (not held or "principal point" in why)
sys.exit(0 if ok else 1)
PY

# The ViSP mbt/cube (a small cube before a white table, 218 frames): its focal length is at the
# start's grid end, and the filter's second pass, started from the first's end, went through
# infinite focal length at frame 23 and the run stopped with "no outputs written" although the
# first pass had run every frame. A later pass that stops now falls back to the one before it
# and says so (summary.json pass_stopped); the run must end with its outputs, and what it cannot
# determine must be said.
MBT=/usr/share/visp-images-data/ViSP-images/mbt/cube
"$RSFM" run "$MBT/image%04d.pgm" --out "$TMP/mbt" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/mbt/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
stopped = s.get("pass_stopped")
print(f"ViSP mbt/cube: {s['frames']} frames, passes {s['passes']}, pass_stopped {stopped!r}; focal "
      f"{'%.1f px' % s['focal_px'] if s.get('focal_determined') else 'not determined, interval %s' % s.get('focal_interval_px')}; "
      f"why: {(s.get('not_determined_why') or '')[:120]}")
ok = "pass_stopped" in s and (stopped is None or (s["passes"] >= 1 and "the result is pass" in stopped))
ok = ok and (s.get("focal_determined") or ("focal length" in (s.get("not_determined_why") or "")))
sys.exit(0 if ok else 1)
PY

# ViSP mbt-depth/Castle-simu (rendered, f = 700 px, 40 frames; the planes' tracks run out at frame
# 18): the refinement's focal-length profile below its estimate (918 px) had no solution (Ceres
# found none from the distortion it had reached) and those failed steps were read as excluded:
# "the data support 740-1209 px", the truth outside. The reported interval must hold the truth.
CASTLE=/usr/share/visp-images-data/ViSP-images/mbt-depth/Castle-simu/Images
"$RSFM" run "$CASTLE/Image_%04d.pgm" --out "$TMP/castle" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/castle/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
truth = 700.0
if s.get("focal_determined"):
    f, sd = s["focal_px"], s["focal_sd_px"]
    ok = abs(f - truth) <= 1.96 * sd
    print(f"Castle-simu: focal {f:.1f} +- {sd:.1f} px (truth {truth:.0f})")
else:
    lo, hi = s["focal_interval_px"]
    ok = (lo is None or lo <= truth) and (hi is None or truth <= hi)
    print(f"Castle-simu: focal not determined, supported [{lo}, {hi}] px (truth {truth:.0f}); why: "
          f"{(s.get('not_determined_why') or '')[:160]}")
sys.exit(0 if ok else 1)
PY

# opencv-doc box.mp4 frames 45-194 (a hand turns the box before a still camera): the plane
# finder's search at the frame of a quarter of the largest motion found three planes (the second
# face with 8 tracks, 3 of them off it, and 9 background tracks that had moved 10 px) and won
# over the share-of-live-tracks frame's two faces: the start fell to its focal grid's end and
# nothing was determined. A frame with more planes must now find the chosen frame's planes again
# (docs/estimate.md section 1 step 1): both faces determined, 90 +- 3 deg apart, and the focal
# length determined.
"$RSFM" run "$TMP/box.mp4" --first 45 --last 194 --out "$TMP/b45" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/b45/summary.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
tried = s["plane_finding"]["pair_frames_tried"]
det = s.get("plane_determined") or []
angles = [a["angle_deg"] for a in s.get("angles_between_planes_deg") or [] if a.get("determined")]
print(f"box.mp4 frames 45-194: pair frame {s['plane_finding']['pair_frame']} "
      f"(tried {', '.join(str(t['frame']) + ('*' if t.get('loses_plane') else '') for t in tried)}; *: loses a plane); "
      f"{len(det)} planes, determined {det}; determined angles {['%.1f' % a for a in angles]}; "
      f"focal {'%.1f +- %.1f px' % (s['focal_px'], s['focal_sd_px']) if s.get('focal_determined') else 'not determined'}")
ok = sum(bool(d) for d in det) >= 2 and any(abs(a - 90) <= 3 for a in angles) and bool(s.get("focal_determined"))
sys.exit(0 if ok else 1)
PY

# ViSP's video/cube.mpeg: the ViSP cube's 80 images as an MPEG-1 video (79 frames; its first
# frame is an intra frame whose compression differs from the next, so 9 tracks seem to move at
# frame 1 of a camera still until frame 16: those frames are held, docs/estimate.md). Compressed,
# it must agree with the COLMAP reference of the images (bench/reference/colmap/cube, frame 0's
# camera, 596.8 px): focal length determined and within 3 % (issue 14's bar for the cube), the
# floor (the plane with the most tracks) determined and within 2 deg of COLMAP's dominant plane.
VCUBE=/usr/share/visp-images-data/ViSP-images/video/cube.mpeg
REF="$(dirname "$0")/../bench/reference/colmap/cube/summary.json"
"$RSFM" run "$VCUBE" --out "$TMP/vcube" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/vcube/summary.json" "$REF" <<'PY'
import json, math, sys
s, ref = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
f_ref, n_ref = ref["focal_px"], ref["planes"][0]
floor = max(range(len(s["planes"])), key=lambda j: s["plane_tracks"][j])
n = s["planes"][floor]
c = abs(sum(a * b for a, b in zip(n, n_ref))) / math.sqrt(sum(a * a for a in n) * sum(b * b for b in n_ref))
ang = math.degrees(math.acos(min(1.0, c)))
det = bool(s.get("focal_determined"))
err = 100 * (s["focal_px"] / f_ref - 1) if det else float("nan")
print(f"ViSP video/cube.mpeg: {s['frames']} frames, focal "
      f"{'%.1f +- %.1f px (%+.2f %% against COLMAP %.1f)' % (s['focal_px'], s['focal_sd_px'], err, f_ref) if det else 'not determined'}; "
      f"floor ({s['plane_tracks'][floor]} tracks) determined {s['plane_determined'][floor]}, {ang:.2f} deg from COLMAP's")
ok = det and abs(err) <= 3.0 and s["plane_determined"][floor] and ang <= 2.0
sys.exit(0 if ok else 1)
PY

# opencv-doc's cup.mp4: a dark cup turned in a hand before a still camera and a white wall (217
# frames). Nothing in it places the camera: 12220 of its 14032 tracks live a frame or two on the
# wall, and the one plane (18 tracks on the hand and cup) sees a motion a rotation explains. The
# run must end with its outputs and say so: focal length and every plane not determined, with
# the reason in summary.json.
zcat /usr/share/doc/opencv-doc/opencv4/html/cup.mp4.gz >"$TMP/cup.mp4"
"$RSFM" run "$TMP/cup.mp4" --out "$TMP/cup" --no-overlay --no-plots --quiet
/usr/bin/python3 - "$TMP/cup/summary.json" "$TMP/cup/planes.csv" <<'PY'
import csv, json, sys
s = json.load(open(sys.argv[1]))
why = s.get("not_determined_why") or ""
print(f"opencv-doc cup.mp4: {s['frames']} frames estimated, focal determined {s.get('focal_determined')}, planes determined "
      f"{s.get('plane_determined')}; why: {why[:140]}")
ok = not s.get("focal_determined") and not any(s.get("plane_determined") or []) and "focal length" in why
# planes.csv's refined rows print no sd for what is not determined (docs/outputs.md).
refined = [r for r in csv.DictReader(open(sys.argv[2])) if r["estimate"] == "refined"]
sds = {k: sorted({r[k] for r in refined}) for k in ("beta_sd", "focal_sd_px", "normal_sd_deg", "distance_sd")}
print(f"  planes.csv refined rows: {len(refined)}, their sds {sds}")
ok = ok and len(refined) >= 1 and all(v == ["NA"] for v in sds.values())
sys.exit(0 if ok else 1)
PY
