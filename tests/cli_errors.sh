#!/usr/bin/env bash
# CLI bad-input contract: one-line error on stderr, exit code 2, no output files left behind.
# Also a small successful run whose table1.csv has exactly the documented header.
# Usage: cli_errors.sh path/to/rsfm
set -u
RSFM="$1"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
pass=0
fail=0
check() {  # check NAME EXPECTED_CODE DIR -- args...
  local name="$1" want="$2" dir="$3"
  shift 4
  local existed=0
  if [ -n "$dir" ] && [ -e "$dir" ]; then existed=1; fi
  "$RSFM" "$@" >"$TMP/out.txt" 2>"$TMP/err.txt"
  local code=$?
  local lines
  lines=$(wc -l <"$TMP/err.txt")
  local leftovers=""
  if [ -n "$dir" ] && [ -d "$dir" ]; then leftovers=$(ls -A "$dir"); fi
  # A failing command leaves no directory it created and no staging directory (issue 17).
  if [ -n "$dir" ] && [ $existed -eq 0 ] && [ -e "$dir" ]; then leftovers="$leftovers (created $dir)"; fi
  if [ -n "$(find "$TMP" -maxdepth 1 -name '.*.rsfm-*')" ]; then leftovers="$leftovers (staging left)"; fi
  if [ "$code" -eq "$want" ] && [ "$lines" -eq 1 ] && grep -q "^rsfm: error: " "$TMP/err.txt" && [ -z "$leftovers" ]; then
    pass=$((pass + 1))
    echo "ok   $name: $(cat "$TMP/err.txt")"
  else
    fail=$((fail + 1))
    echo "FAIL $name: exit $code (want $want), $lines stderr lines, leftovers '$leftovers'"
    sed 's/^/     | /' "$TMP/err.txt"
  fi
}
D="$TMP/o1"
check "unknown subcommand" 2 "$D" -- frobnicate
check "unknown experiment" 2 "$D" -- experiment table9 --out "$D"
check "unknown option" 2 "$D" -- experiment table1 --out "$D" --bogus 3
check "negative noise" 2 "$D" -- experiment table1 --out "$D" --noise 2,-6
check "zero trials" 2 "$D" -- experiment table1 --out "$D" --trials 0
check "non-numeric trials" 2 "$D" -- experiment table1 --out "$D" --trials many
check "NaN noise" 2 "$D" -- experiment table1 --out "$D" --noise nan
check "bad reading" 2 "$D" -- experiment table1 --out "$D" --reading sideways
check "too few points" 2 "$D" -- experiment table1 --out "$D" --points 4
touch "$TMP/afile"
check "output is a file" 2 "" -- experiment table1 --out "$TMP/afile"
mkdir -p "$TMP/ro"
chmod 555 "$TMP/ro"
if [ "$(id -u)" -eq 0 ]; then
  # root ignores permissions: use a path under a regular file instead (cannot be created)
  check "unwritable output directory" 2 "" -- experiment table1 --out "$TMP/afile/sub"
else
  check "unwritable output directory" 2 "$TMP/ro" -- experiment table1 --out "$TMP/ro"
fi
[ -d "$D" ] && { echo "FAIL output directory $D was created by a failing run"; fail=$((fail + 1)); }

# A small good run: 4 formulations (plane, plane-iekf, batch, point) x 3 noise levels.
G="$TMP/good"
if "$RSFM" experiment table1 --trials 2 --frames 20 --quiet --out "$G" 2>"$TMP/err.txt"; then
  hdr=$(head -1 "$G/table1.csv")
  rows=$(($(wc -l <"$G/table1.csv") - 1))
  if [ "$hdr" = "formulation,noise_px,m_t,sigma_t,m_q,sigma_q,r_s,r_c" ] && [ "$rows" -eq 12 ] &&
     [ -s "$G/table1.md" ] && [ -s "$G/fig1.png" ] && [ -s "$G/fig1.svg" ] &&
     ! ls "$G" | grep -q tmp && ! grep -qi nan "$G/table1.csv"; then
    pass=$((pass + 1)); echo "ok   good run: $(ls "$G" | tr '\n' ' ')"
  else
    fail=$((fail + 1)); echo "FAIL good run: header '$hdr', $rows rows, files: $(ls "$G" | tr '\n' ' ')"
  fi
else
  fail=$((fail + 1)); echo "FAIL good run exited non-zero: $(cat "$TMP/err.txt")"
fi
# experiment planes: a small good run with the documented header, and a bad option.
P="$TMP/planes"
if "$RSFM" experiment planes --trials 1 --frames 15 --deg-per-frame 1 --noise 2 --quiet --out "$P" 2>"$TMP/err.txt"; then
  hdr=$(head -1 "$P/planes.csv")
  if [ "$hdr" = "method,noise_px,rms_t,rms_q,normal_err_deg,face_angle_err_deg,beta_err_pct,ratio_to_batch" ] &&
     [ -s "$P/planes.md" ] && [ -s "$P/planes.png" ] && [ -s "$P/planes.svg" ] && ! ls "$P" | grep -q tmp; then
    pass=$((pass + 1)); echo "ok   planes good run: $(ls "$P" | tr '\n' ' ')"
  else
    fail=$((fail + 1)); echo "FAIL planes good run: header '$hdr', files: $(ls "$P" | tr '\n' ' ')"
  fi
else
  fail=$((fail + 1)); echo "FAIL planes good run exited non-zero: $(cat "$TMP/err.txt")"
fi
D2="$TMP/o2"
check "planes: zero trials" 2 "$D2" -- experiment planes --out "$D2" --trials 0
check "planes: too few points per face" 2 "$D2" -- experiment planes --out "$D2" --points-per-face 2

# render box / evaluate (docs/render.md, docs/evaluate.md).
R="$TMP/render"
check "render: one frame" 2 "$R" -- render box --out "$R" --frames 1
check "render: odd width" 2 "$R" -- render box --out "$R" --width 321
check "render: NaN focal" 2 "$R" -- render box --out "$R" --focal-px nan
check "render: elevation out of range" 2 "$R" -- render box --out "$R" --elevation 80,90
check "render: one elevation" 2 "$R" -- render box --out "$R" --elevation 40
check "render: approach out of range" 2 "$R" -- render box --out "$R" --approach 0.1
check "render: missing texture" 2 "$R" -- render box --out "$R" --texture "$TMP/none.png"
echo "not an image" >"$TMP/bad.png"
check "render: texture not an image" 2 "$R" -- render box --out "$R" --texture "$TMP/bad.png"
check "render: unknown option" 2 "$R" -- render box --out "$R" --bogus
check "render: missing --out" 2 "" -- render box
check "render: output is a file" 2 "" -- render box --out "$TMP/afile" --frames 3
# The regimes' options (issue 12; docs/render.md, docs/regimes.md).
check "render: unknown scene" 2 "$R" -- render cylinder --out "$R"
check "render: unknown regime" 2 "$R" -- render regime no-such-regime --out "$R"
check "render: regime without a name" 2 "$R" -- render regime --out "$R"
check "render: negative focal" 2 "$R" -- render corner --out "$R" --focal-px -300
check "render: k1 folds the image" 2 "$R" -- render box --out "$R" --k1 -0.3
check "render: k1 out of range" 2 "$R" -- render box --out "$R" --k1 1.5 --focal-px 2000
check "render: still stretch longer than the sequence" 2 "$R" -- render box --out "$R" --frames 20 --still-start 30
check "render: still stretches leave one moving frame" 2 "$R" -- render box --out "$R" --frames 20 --still-start 10 --still-middle 9
check "render: unknown motion" 2 "$R" -- render poster --out "$R" --motion spiral
check "render: forward without approach" 2 "$R" -- render poster --out "$R" --motion forward --approach 1
check "render: principal point too far off" 2 "$R" -- render box --out "$R" --principal-offset 40,0
check "render: blur out of range" 2 "$R" -- render box --out "$R" --blur 1.5
check "render: jpeg quality out of range" 2 "$R" -- render box --out "$R" --jpeg-quality 101
check "render: jitter out of range" 2 "$R" -- render box --out "$R" --jitter-deg 9
check "render: no floor in the corner" 2 "$R" -- render corner --out "$R" --no-floor
check "render: too fast" 2 "$R" -- render box --out "$R" --deg-per-frame 31
echo '{"format":"rsfm-regimes","version":1,"sequences":[{"name":"a","options":{"seed":1,"colour":2}}]}' >"$TMP/suite1.json"
check "render: suite with an unknown option" 2 "$R" -- render regime a --out "$R" --suite "$TMP/suite1.json"
echo '{"format":"rsfm-regimes","version":1,"sequences":[{"name":"a","options":{"frames":5}}]}' >"$TMP/suite2.json"
check "render: suite sequence without a seed" 2 "$R" -- render regime a --out "$R" --suite "$TMP/suite2.json"
echo '{"format":"rsfm-regimes","version":1,"sequences":[{"name":"a","options":{"seed":1,"k1":-0.6}}]}' >"$TMP/suite3.json"
check "render: suite sequence with an invalid option" 2 "$R" -- render regime a --out "$R" --suite "$TMP/suite3.json"
printf '{"format":"rsfm-regimes",\n "version":1,\n "sequences":[}' >"$TMP/suite4.json"
B="$TMP/bench"
check "bench: unknown sequence" 2 "$B" -- bench regimes --out "$B" --only box-orbit,no-such
check "bench: negative jobs" 2 "$B" -- bench regimes --out "$B" --jobs -1
check "bench: missing rsfm binary" 2 "$B" -- bench regimes --out "$B" --rsfm "$TMP/none"
check "bench: bad suite" 2 "$B" -- bench regimes --out "$B" --suite "$TMP/suite1.json"
check "bench: unknown bench" 2 "$B" -- bench speed --out "$B"
# A small good bench: a two-sequence suite (a 20-frame poster orbit and a still one), no real rows.
cat >"$TMP/suite-small.json" <<'JSON'
{"format":"rsfm-regimes","version":1,"sequences":[
 {"name":"tiny-poster","why":"smoke test","axes":["scene:poster"],
  "options":{"scene":"poster","frames":20,"width":320,"height":240,"focal_px":260,"orbit_deg":20,"seed":3}},
 {"name":"tiny-still","why":"smoke test","axes":["motion:none"],
  "options":{"scene":"poster","frames":8,"width":320,"height":240,"focal_px":260,"motion":"none","seed":4}}]}
JSON
BG="$TMP/bench-good"
if "$RSFM" bench regimes --out "$BG" --suite "$TMP/suite-small.json" --cache "$TMP/cache" --no-real --quiet 2>"$TMP/err.txt" &&
   head -1 "$BG/scoreboard.csv" | grep -q '^sequence,kind,axes,frames,exit_code,message,frames_processed' &&
   grep -q '^tiny-poster,rendered,' "$BG/scoreboard.csv" && grep -q '^tiny-still,rendered,' "$BG/scoreboard.csv" &&
   grep -q '^aggregate:share,' "$BG/scoreboard.csv" && grep -q '"format": "rsfm-scoreboard"' "$BG/scoreboard.json" &&
   grep -q 'sequences run to the end' "$BG/scoreboard.md" && [ -s "$BG/runs/tiny-poster/summary.json" ] &&
   [ -d "$TMP/cache" ] && [ -z "$(find "$BG" -name "*.tmp*")" ]; then
  pass=$((pass + 1)); echo "ok   bench good run: $(grep -c ',rendered,' "$BG/scoreboard.csv") rendered rows"
else
  fail=$((fail + 1)); echo "FAIL bench good run: $(cat "$TMP/err.txt"); $(ls -R "$BG" 2>&1 | tr '\n' ' ')"
fi
# A tracks file whose first frames have no tracks (a video that fades in): the estimate starts
# at the first frame with tracks and says so (here it then finds no plane in two tracks).
LT="$TMP/late-tracks.csv"
{ printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 9\nframe,track,x,y\n'
  for k in 2 3 4 5 6 7 8 9; do echo "$k,0,$((10 + k)),10"; echo "$k,1,$((10 + k)),50"; done; } >"$LT"
if ! "$RSFM" estimate --tracks "$LT" --out "$TMP/late" 2>"$TMP/err.txt" &&
   grep -q "^tracks: frames 0-1 of .* have no tracks: the estimate starts at frame 2$" "$TMP/err.txt" &&
   grep -q "^rsfm: error: no plane .*(tracks: 2;" "$TMP/err.txt" && [ ! -e "$TMP/late" ]; then
  pass=$((pass + 1)); echo "ok   estimate: leading frames without tracks left out"
else
  fail=$((fail + 1)); echo "FAIL estimate: leading frames without tracks: $(cat "$TMP/err.txt")"
fi
# Camera files and the refinement's options (issue 13; docs/estimate.md).
CT="$TMP/cam-tracks.csv"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 2\nframe,track,x,y\n0,0,10,10\n1,0,11,10\n2,0,12,10\n' >"$CT"
E="$TMP/est"
check "estimate: unknown --refine" 2 "$E" -- estimate --tracks "$CT" --out "$E" --refine later
check "estimate: references in the state" 2 "$E" -- estimate --tracks "$CT" --out "$E" --reference state
check "experiment two-object: references conditional on the state" 2 "$E" -- experiment two-object --out "$E" --reference conditional
check "estimate: missing camera file" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/none.yaml"
printf 'not: [a yaml camera\n' >"$TMP/bad.yaml"
check "estimate: malformed camera file" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/bad.yaml"
printf '%%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n' >"$TMP/nok.yaml"
check "estimate: camera file without camera_matrix" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/nok.yaml"
cam() {  # cam FILE W H FX FY CX CY
  printf '%%YAML:1.0\n---\nimage_width: %s\nimage_height: %s\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ %s, 0., %s, 0., %s, %s, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ -0.1, 0.01, 0., 0., 0. ]\n' "$2" "$3" "$4" "$6" "$5" "$7" >"$1"
}
cam "$TMP/size.yaml" 800 600 500 500 399.5 299.5
check "estimate: camera for another image size" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/size.yaml"
cam "$TMP/fxfy.yaml" 640 480 500 560 319.5 239.5
check "estimate: non-square pixels" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/fxfy.yaml"
cam "$TMP/ppout.yaml" 640 480 500 500 700 239.5
check "estimate: camera principal point outside the image" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/ppout.yaml"
cam "$TMP/good.yaml" 640 480 500 500 319.5 239.5
check "estimate: camera with --focal-px" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/good.yaml" --focal-px 500
check "estimate: principal point outside the image" 2 "$E" -- estimate --tracks "$CT" --out "$E" --principal-point 900,10
check "estimate: principal point not a pair" 2 "$E" -- estimate --tracks "$CT" --out "$E" --principal-point 300
check "estimate: rolling shutter readout out of range" 2 "$E" -- estimate --tracks "$CT" --out "$E" --rolling-shutter-readout 3
check "estimate: rolling shutter readout with the patch model" 2 "$E" -- estimate --tracks "$CT" --out "$E" --model patches --rolling-shutter-readout 1
says() {  # says TEXT: the last check's one line names the problem
  if grep -qF -- "$1" "$TMP/err.txt"; then pass=$((pass + 1)); else
    fail=$((fail + 1)); echo "FAIL the message does not say '$1': $(cat "$TMP/err.txt")"; fi
}
check "render: rolling shutter readout out of range" 2 "$R" -- render box --out "$R" --readout 2
says "--readout must be in [0, 1] (the rolling shutter's readout / frame interval), got 2"
check "estimate: readout direction not a direction" 2 "$E" -- estimate --tracks "$CT" --out "$E" --readout-direction sideways
says "--readout-direction: sideways not in {down,up,right,left}"
check "estimate: readout direction with the patch model" 2 "$E" -- estimate --tracks "$CT" --out "$E" --model patches --readout-direction left
says "--readout-direction applies to the point and plane models"
{ printf '# rsfm-tracks 1\n# image_size 640 480\n# readout_direction diagonal\n# frames 0 1\nframe,track,x,y\n0,0,1,1\n1,0,2,1\n'; } >"$TMP/rd.csv"
check "estimate: tracks file with a bad readout direction" 2 "$E" -- estimate --tracks "$TMP/rd.csv" --out "$E"
says "rd.csv:3: readout_direction needs one of down, up, right, left"
{ cat "$TMP/good.yaml"; echo "rolling_shutter_readout: 0.9"; } >"$TMP/rs.yaml"
check "estimate: readout given and in the camera file, different" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/rs.yaml" --rolling-shutter-readout 0.5
check "estimate: camera file's readout with the patch model" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/rs.yaml" --model patches
{ cat "$TMP/good.yaml"; echo "rolling_shutter_readout: 7"; } >"$TMP/rs7.yaml"
check "estimate: camera file's readout out of range" 2 "$E" -- estimate --tracks "$CT" --out "$E" --camera "$TMP/rs7.yaml"
check "render: suite not JSON" 2 "$R" -- render regime a --out "$R" --suite "$TMP/suite4.json"
if "$RSFM" render box --out "$R" --frames 4 --width 160 --height 120 --focal-px 130 --quiet 2>"$TMP/err.txt" &&
   [ -s "$R/video.mp4" ] && [ "$(grep -vc '^#' "$R/truth/trajectory.tum")" -eq 4 ] &&
   grep -q '"format": "rsfm-summary"' "$R/truth/summary.json" && [ -z "$(find "$R" -name "*.tmp*")" ]; then
  pass=$((pass + 1)); echo "ok   render good run: $(ls "$R" "$R/truth" | tr '\n' ' ')"
else
  fail=$((fail + 1)); echo "FAIL render good run: $(cat "$TMP/err.txt"), files: $(ls -R "$R" | tr '\n' ' ')"
fi
# Without the photographs: procedural textures, said once on stderr.
R2="$TMP/render2"
if RSFM_VISP_IMAGES_DIR="$TMP/no-visp" "$RSFM" render box --out "$R2" --frames 2 --width 160 --height 120 \
     --focal-px 130 2>"$TMP/err.txt" && [ "$(grep -c 'using procedural textures' "$TMP/err.txt")" -eq 1 ] &&
   [ -s "$R2/video.mp4" ]; then
  pass=$((pass + 1)); echo "ok   render fallback: $(grep procedural "$TMP/err.txt")"
else
  fail=$((fail + 1)); echo "FAIL render fallback: $(cat "$TMP/err.txt")"
fi
T="$R/truth"
E="$TMP/est"
mkdir -p "$E"
cp "$T/summary.json" "$E/"
V="$TMP/evalout"
check "evaluate: missing estimate dir" 2 "$V" -- evaluate --estimate "$TMP/nodir" --truth "$T" --out "$V"
check "evaluate: missing trajectory" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V"
printf '0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 zero 0 0 0 1\n' >"$E/trajectory.tum"
check "evaluate: malformed TUM" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V"
grep -q "trajectory.tum:3: field tz ('zero') is not a number" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL malformed TUM message lacks file:line: $(cat "$TMP/err.txt")"; }
printf '0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1.5\n' >"$E/trajectory.tum"
check "evaluate: non-unit quaternion" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V"
# Timestamps in seconds (the truth's summary states fps): two poses at the truth's times, two far off.
{ grep -v '^#' "$T/trajectory.tum" | head -2; printf '100 0 0 0 0 0 0 1\n200 0 0 0 0 0 0 1\n'; } >"$E/trajectory.tum"
check "evaluate: too few matched poses" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V"
grep -q "only 2 poses match a timestamp of .* within 0.01 s" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL too-few message: $(cat "$TMP/err.txt")"; }
cp "$T/trajectory.tum" "$E/"
check "evaluate: rpe-delta 0" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V" --rpe-delta 0
printf '{"format": "rsfm-summary",\n "version": 1,\n "frames": }\n' >"$E/summary.json"
check "evaluate: malformed summary" 2 "$V" -- evaluate --estimate "$E" --truth "$T" --out "$V"
grep -q "summary.json:3: invalid JSON" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL malformed summary message: $(cat "$TMP/err.txt")"; }
cp "$T/summary.json" "$E/"
if "$RSFM" evaluate --estimate "$E" --truth "$T" --out "$V" >"$TMP/out.txt" 2>"$TMP/err.txt" &&
   grep -q "4 matched by timestamp (seconds, within 0.01)" "$TMP/out.txt" && [ -s "$V/evaluation.json" ] && [ -s "$V/evaluation.md" ] &&
   grep -q '"format": "rsfm-evaluation"' "$V/evaluation.json" && ! ls "$V" | grep -q tmp; then
  pass=$((pass + 1)); echo "ok   evaluate good run: $(ls "$V" | tr '\n' ' ')"
else
  fail=$((fail + 1)); echo "FAIL evaluate good run: $(cat "$TMP/err.txt") $(ls "$V" 2>&1 | tr '\n' ' ')"
fi
# experiment two-object: a small good run with the documented header, and bad options.
W="$TMP/two"
if "$RSFM" experiment two-object --trials 1 --frames 20 --noise 1 --quiet --out "$W" 2>"$TMP/err.txt"; then
  hdr=$(head -1 "$W/two_object.csv")
  rows=$(($(wc -l <"$W/two_object.csv") - 1))
  if [ "$hdr" = "noise_px,object,rot_err_deg,t_err_pct,normal_err_deg,beta_err_pct,failed" ] && [ "$rows" -eq 2 ] &&
     [ -s "$W/two_object.md" ] && [ -s "$W/two_object_data.csv" ] && [ -s "$W/two_object.png" ] &&
     [ -s "$W/two_object.svg" ] && ! ls "$W" | grep -q tmp && ! grep -qi nan "$W/two_object.csv"; then
    pass=$((pass + 1)); echo "ok   two-object good run: $(ls "$W" | tr '\n' ' ')"
  else
    fail=$((fail + 1)); echo "FAIL two-object good run: header '$hdr', $rows rows, files: $(ls "$W" | tr '\n' ' ')"
  fi
else
  fail=$((fail + 1)); echo "FAIL two-object good run exited non-zero: $(cat "$TMP/err.txt")"
fi
D3="$TMP/o3"
check "two-object: zero trials" 2 "$D3" -- experiment two-object --out "$D3" --trials 0
check "two-object: negative noise" 2 "$D3" -- experiment two-object --out "$D3" --noise 0.5,-1
check "two-object: NaN noise" 2 "$D3" -- experiment two-object --out "$D3" --noise nan
check "two-object: too few points" 2 "$D3" -- experiment two-object --out "$D3" --points-per-object 4
check "two-object: bad reference" 2 "$D3" -- experiment two-object --out "$D3" --reference magic
check "two-object: non-positive beta0" 2 "$D3" -- experiment two-object --out "$D3" --beta0 0
check "two-object: unknown option" 2 "$D3" -- experiment two-object --out "$D3" --bogus 1
check "two-object: output is a file" 2 "" -- experiment two-object --out "$TMP/afile"
check "planes: beta bound above beta0" 2 "$D2" -- experiment planes --out "$D2" --beta-min 0.6
check "planes: negative warm-up" 2 "$D2" -- experiment planes --out "$D2" --warmup-frames -1
check "planes: negative iekf-after" 2 "$D2" -- experiment planes --out "$D2" --iekf-after -1
check "table1: negative iekf-after" 2 "$D2" -- experiment table1 --out "$D2" --iekf-after -2


# track / estimate / run (docs/tracks.md, docs/estimate.md): bad videos, frames and track files.
V4="$TMP/video"
mkdir -p "$TMP/frames"
check "track: missing video" 2 "$V4" -- track "$TMP/nope.mp4" --out "$V4" --quiet
echo "this is not a video" >"$TMP/notavideo.mp4"
check "track: unreadable video" 2 "$V4" -- track "$TMP/notavideo.mp4" --out "$V4" --quiet
check "run: unreadable video" 2 "$V4" -- run "$TMP/notavideo.mp4" --out "$V4" --quiet
echo "x" | gzip >"$TMP/box.mp4.gz"
check "track: compressed video" 2 "$V4" -- track "$TMP/box.mp4.gz" --out "$V4" --quiet
check "track: bad roi" 2 "$V4" -- track "$TMP/frames" --out "$V4" --roi 1,2,3 --quiet
check "track: empty folder" 2 "$V4" -- track "$TMP/frames" --out "$V4" --quiet
check "track: max-levels below levels" 2 "$V4" -- track "$TMP/frames" --out "$V4" --levels 3 --max-levels 2 --quiet
grep -q "max-levels" "$TMP/err.txt" || { fail=$((fail + 1)); echo "FAIL max-levels message: $(cat "$TMP/err.txt")"; }
check "track: old --fb-check" 2 "$V4" -- track "$TMP/frames" --out "$V4" --fb-check 1 --quiet
# A short image sequence whose third frame is corrupt.
for i in 0 1 2; do cp "$TMP/bad.png" "$TMP/frames/f00$i.png"; done
check "track: corrupt frame" 2 "$V4" -- track "$TMP/frames/f%03d.png" --out "$V4" --quiet
grep -q "f000.png: frame 0 cannot be decoded" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL corrupt-frame message does not name the file: $(cat "$TMP/err.txt")"; }
# Frames 0, 1 and 3 of a PGM sequence: frame 2 is missing.
mkdir -p "$TMP/gap"
for i in 0 1 3; do
  /usr/bin/python3 -c "import sys; open(sys.argv[1], 'wb').write(b'P5 64 48 255\n' + bytes((x * 7 + y * 13) % 256 for y in range(48) for x in range(64)))" "$TMP/gap/g$i.pgm"
done
check "run: missing frame in a pattern" 2 "$V4" -- run "$TMP/gap/g%d.pgm" --out "$V4" --quiet
grep -q "missing frame" "$TMP/err.txt" || { fail=$((fail + 1)); echo "FAIL missing-frame message: $(cat "$TMP/err.txt")"; }
# A folder whose images' names number them twice (1 and 01): which comes first is not rsfm's to guess.
mkdir -p "$TMP/twice"
cp "$TMP/gap/g0.pgm" "$TMP/twice/1.pgm"; cp "$TMP/gap/g0.pgm" "$TMP/twice/01.pgm"; cp "$TMP/gap/g1.pgm" "$TMP/twice/2.pgm"
check "run: two images with one number" 2 "$V4" -- run "$TMP/twice" --out "$V4" --quiet
grep -q "01.pgm and .*1.pgm: two images with one number\|1.pgm and .*01.pgm: two images with one number" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL two-images message does not name both: $(cat "$TMP/err.txt")"; }
T4="$TMP/tracks"
mkdir -p "$T4"
: >"$T4/empty.csv"
check "estimate: missing tracks file" 2 "$V4" -- estimate --tracks "$T4/none.csv" --out "$V4" --quiet
check "estimate: empty tracks file" 2 "$V4" -- estimate --tracks "$T4/empty.csv" --out "$V4" --quiet
printf '# rsfm-tracks 1\n# image_size 640 480\n# time_origin 1305031102.5\n# frames 0 9\nframe,track,x,y\n0,0,10,10\n' >"$T4/origin.csv"
check "estimate: time origin without fps" 2 "$V4" -- estimate --tracks "$T4/origin.csv" --out "$V4" --quiet
grep -q "origin.csv:3: time_origin needs '# fps'" "$TMP/err.txt" || { fail=$((fail + 1)); echo "FAIL time_origin message: $(cat "$TMP/err.txt")"; }
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 9\nframe,track,x,y\n0,0,10,10\n0,1,abc,4\n' >"$T4/bad.csv"
check "estimate: malformed tracks file" 2 "$V4" -- estimate --tracks "$T4/bad.csv" --out "$V4" --quiet
grep -q "bad.csv:6: x or y is not a number" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL malformed tracks message lacks file:line: $(cat "$TMP/err.txt")"; }
# Two planes of 4 tracks each (fewer than the plane model's 5), 10 frames.
/usr/bin/python3 - "$T4/four.csv" <<'PY'
import sys
rows = ["# rsfm-tracks 1", "# image_size 640 480", "# frames 0 9", "frame,track,x,y"]
pts = [(100 + 60 * (i % 2), 100 + 50 * (i // 2)) for i in range(4)] + [(400 + 50 * (i % 2), 300 + 40 * (i // 2)) for i in range(4)]
for k in range(10):
    for i, (x, y) in enumerate(pts):
        s = 1 + 0.01 * k if i < 4 else 1 - 0.01 * k
        rows.append(f"{k},{i},{x * s + 2 * k:.4f},{y * s:.4f}")
open(sys.argv[1], "w").write("\n".join(rows) + "\n")
PY
check "estimate: fewer than 5 points on every plane" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --quiet
check "estimate: fewer than 5 points (manual planes)" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --quiet \
  --plane-roi "0,0,300,0,300,250,0,250;350,250,640,250,640,480,350,480" --min-plane-tracks 5
check "estimate: bad model" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --model cubes --quiet
check "estimate: negative focal" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --focal-px -3 --quiet
check "estimate: negative iekf-after" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --iterations 3 --iekf-after -1 --quiet
check "estimate: still-px not a number" 2 "$V4" -- estimate --tracks "$T4/four.csv" --out "$V4" --still-px nan --quiet

# Affine patches (docs/tracks.md "patches.csv", docs/patches.md).
check "experiment patches: negative noise" 2 "$D" -- experiment patches --out "$D" --plane-noise 0.1,-0.2
check "experiment patches: bad centres" 2 "$D" -- experiment patches --out "$D" --centres somewhere
check "experiment patches: too few patches" 2 "$D" -- experiment patches --out "$D" --sphere-patches 2
check "experiment patches: maps in the state need tracked maps" 2 "$D" -- experiment patches --out "$D" --centres state
check "experiment patches: obliquity over 90 deg" 2 "$D" -- experiment patches --out "$D" --sphere-max-obliquity 95
check "experiment patches: anneal frames -2" 2 "$D" -- experiment patches --out "$D" --anneal-frames -2
check "experiment planes: negative structure noise" 2 "$D" -- experiment planes --out "$D" --q-structure -1
check "experiment two-object: references in the state" 2 "$D" -- experiment two-object --out "$D" --reference state
check "track --patches: radius 1" 2 "$V4" -- track "$TMP/gap/g%d.pgm" --patches --patch-radius 1 --out "$V4" --quiet
check "estimate: missing patches file" 2 "$V4" -- estimate --patches "$T4/none.csv" --out "$V4" --quiet
check "estimate: tracks and patches" 2 "$V4" -- estimate --patches "$T4/four.csv" --tracks "$T4/four.csv" --out "$V4" --quiet
check "estimate: model patches without a patches file" 2 "$V4" -- estimate --tracks "$T4/four.csv" --model patches --out "$V4" --quiet
printf '# rsfm-patches 1\n# image_size 640 480\n# frames 0 9\n# radius 15\nframe,patch,x0,y0,x,y,a11,a12,a21,a22,tx,ty,rms\n0,0,10,10,10,10,1,0,0,1,0,0,0\n1,0,10,10,11,10,1,0,0,-1,1,20,0\n' >"$T4/badp.csv"
check "estimate: patches file with a mirrored map" 2 "$V4" -- estimate --patches "$T4/badp.csv" --out "$V4" --quiet
grep -q "badp.csv:7: the affine map A has a non-positive determinant" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL malformed patches message lacks file:line: $(cat "$TMP/err.txt")"; }
printf '# rsfm-patches 1\n# image_size 640 480\n# frames 0 3\n# radius 15\nframe,patch,x0,y0,x,y,a11,a12,a21,a22,tx,ty,rms\n' >"$T4/twop.csv"
for k in 0 1 2 3; do for i in 0 1; do echo "$k,$i,$((100 + 200 * i)),100,$((100 + 200 * i + k)),100,1,0,0,1,$k,0,0" >>"$T4/twop.csv"; done; done
check "estimate: two patches (the filter needs 3)" 2 "$V4" -- estimate --patches "$T4/twop.csv" --out "$V4" --quiet
check "estimate: bad measurement" 2 "$V4" -- estimate --patches "$T4/twop.csv" --measurement approximate --out "$V4" --quiet
check "estimate: maps in the state, instantaneous" 2 "$V4" -- estimate --patches "$T4/twop.csv" --centres state --measurement instantaneous --out "$V4" --quiet
check "estimate: maps in the state and fused maps" 2 "$V4" -- estimate --patches "$T4/twop.csv" --centres state --fused-maps true --out "$V4" --quiet

# Issue 17: one reproducer per defect of the error contract and the bounded readers.
I17="$TMP/i17"
mkdir -p "$I17"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 100000000\nframe,track,x,y\n0,0,1,1\n1,0,2,2\n' >"$I17/frames1e8.csv"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 1\nframe,track,x,y\n0,100000000,1,1\n1,100000000,2,2\n' >"$I17/id1e8.csv"
printf '# rsfm-tracks 1\n# image_size 100000000 100000000\n# frames 0 1\nframe,track,x,y\n0,0,1,1\n1,0,2,2\n' >"$I17/img1e8.csv"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 3000000000 3000000001\nframe,track,x,y\n' >"$I17/bigframe.csv"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 1\nfra\033[31mme,track\n' >"$I17/esc.csv"
head -c 100000 /dev/zero | tr '\0' 'a' >"$I17/longline.csv"
check "i17: header frame range beyond the rows" 2 "$I17/o" -- estimate --tracks "$I17/frames1e8.csv" --out "$I17/o"
check "i17: track id 1e8" 2 "$I17/o" -- estimate --tracks "$I17/id1e8.csv" --out "$I17/o"
check "i17: image_size 1e8" 2 "$I17/o" -- estimate --tracks "$I17/img1e8.csv" --out "$I17/o"
check "i17: frame above INT_MAX" 2 "$I17/o" -- estimate --tracks "$I17/bigframe.csv" --out "$I17/o"
check "i17: escape bytes" 2 "$I17/o" -- estimate --tracks "$I17/esc.csv" --out "$I17/o"
check "i17: a 100 kB line" 2 "$I17/o" -- estimate --tracks "$I17/longline.csv" --out "$I17/o"
check "i17: /dev/zero" 2 "$I17/o" -- estimate --tracks /dev/zero --out "$I17/o"
if grep -q "$(printf '\033')" "$TMP/err.txt"; then fail=$((fail + 1)); echo "FAIL an ESC byte reached stderr"; fi
"$RSFM" estimate --tracks "$I17/esc.csv" --out "$I17/o" 2>"$TMP/err.txt"
if grep -q '\\x1b\[31m' "$TMP/err.txt" && ! grep -q "$(printf '\033')" "$TMP/err.txt"; then pass=$((pass + 1)); echo "ok   i17: control bytes escaped: $(cat "$TMP/err.txt")"
else fail=$((fail + 1)); echo "FAIL i17: control bytes not escaped: $(cat -v "$TMP/err.txt")"; fi
mkdir -p "$I17/tiny"
for i in 0 1 2; do
  /usr/bin/python3 -c "import sys; open(sys.argv[1], 'wb').write(b'P5 8 8 255\n' + bytes((x * 37 + y * 91 + $i * 5) % 256 for y in range(8) for x in range(8)))" "$I17/tiny/f$i.pgm"
done
check "i17: 8x8 images" 2 "$I17/o" -- track "$I17/tiny" --out "$I17/o"
check "i17: --window 100001" 2 "$I17/o" -- track "$I17/tiny" --window 100001 --out "$I17/o"
# summary.json and TUM numbers out of range, a still truth, --rpe-delta INT64_MAX (evaluate).
E17="$I17/est"
mkdir -p "$E17"
cp "$T/trajectory.tum" "$E17/"
sed 's/"version": 1/"version": 1e999/' "$T/summary.json" >"$E17/summary.json"
check "i17: version 1e999" 2 "" -- evaluate --estimate "$E17" --truth "$T" --out "$I17/ev"
sed 's/"version": 1/"version": 4294967297/' "$T/summary.json" >"$E17/summary.json"
check "i17: version 2^32+1" 2 "" -- evaluate --estimate "$E17" --truth "$T" --out "$I17/ev"
cp "$T/summary.json" "$E17/"
# Two poses for one time are refused; a pose 1e-10 s beside another is a pose of its own, and the
# truth's pose takes the nearer one only (association as evo's, each estimate pose used once).
{ cat "$T/trajectory.tum"; grep -v '^#' "$T/trajectory.tum" | head -1; } >"$E17/trajectory.tum"
check "i17: TUM timestamp twice" 2 "" -- evaluate --estimate "$E17" --truth "$T" --out "$I17/ev"
grep -q "trajectory.tum:6: timestamp 0 is not greater than the previous one" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL twice message: $(cat "$TMP/err.txt")"; }
{ grep '^#' "$T/trajectory.tum"; grep -v '^#' "$T/trajectory.tum" | head -1; printf '1e-10 5 5 5 0 0 0 1\n';
  grep -v '^#' "$T/trajectory.tum" | tail -n +2; } >"$E17/trajectory.tum"
if "$RSFM" evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" >"$TMP/out.txt" 2>"$TMP/err.txt" &&
   grep -q "4 truth, 5 estimate, 4 matched by timestamp" "$TMP/out.txt" && awk '/^ATE \(truth units\)/ {found = 1; ok = ($4 < 1e-9)} END {exit !(found && ok)}' "$TMP/out.txt"; then
  pass=$((pass + 1)); echo "ok   i17: t = 1e-10 beside 0: a pose of its own, not matched twice, not merged"
else
  fail=$((fail + 1)); echo "FAIL t = 1e-10 beside 0: $(cat "$TMP/out.txt" "$TMP/err.txt")"
fi
# Association by timestamp (issue 16): shifted 5 ms, matched within the default --t-max-diff 0.01 s,
# not within 1 ms; frame numbers against a truth in seconds are taken at the truth's frame rate.
awk '/^#/ {print; next} {$1 = sprintf("%.9f", $1 + 0.005); print}' "$T/trajectory.tum" >"$E17/trajectory.tum"
if "$RSFM" evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" 2>"$TMP/err.txt" | grep -q "4 matched by timestamp"; then
  pass=$((pass + 1)); echo "ok   evaluate: 5 ms off, matched within --t-max-diff 0.01"
else
  fail=$((fail + 1)); echo "FAIL evaluate 5 ms off: $(cat "$TMP/err.txt")"
fi
check "evaluate: 5 ms off, --t-max-diff 0.001" 2 "" -- evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" --t-max-diff 0.001
grep -q "only 0 poses match a timestamp" "$TMP/err.txt" || { fail=$((fail + 1)); echo "FAIL t-max-diff message: $(cat "$TMP/err.txt")"; }
check "evaluate: --t-max-diff -1" 2 "" -- evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" --t-max-diff -1
awk '/^#/ {print; next} {$1 = NR - 2; print}' "$T/trajectory.tum" >"$E17/trajectory.tum"
grep -v '"fps"\|"timestamps"' "$T/summary.json" >"$E17/summary.json"
if "$RSFM" evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" >"$TMP/out.txt" 2>"$TMP/err.txt" &&
   grep -q "4 matched by timestamp" "$TMP/out.txt" && grep -q "taken as seconds at the truth's 30 fps" "$TMP/out.txt"; then
  pass=$((pass + 1)); echo "ok   evaluate: frame numbers against seconds: taken at the truth's 30 fps"
else
  fail=$((fail + 1)); echo "FAIL frame numbers against seconds: $(cat "$TMP/out.txt" "$TMP/err.txt")"
fi
# A bare TUM trajectory as the truth (a dataset's groundtruth.txt) is in seconds: an estimate in
# frame numbers cannot be matched to it.
check "evaluate: bare truth file, estimate in frames" 2 "" -- evaluate --estimate "$E17" --truth "$T/trajectory.tum" --out "$I17/ev"
grep -q "is in seconds, and the estimate's timestamps are frame numbers" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL bare truth file message: $(cat "$TMP/err.txt")"; }
cp "$T/summary.json" "$E17/"
S17="$I17/still"
mkdir -p "$S17"
cp "$T/summary.json" "$S17/"
awk '!/^#/{print $1, 0, 0, 0, $5, $6, $7, $8}' "$T/trajectory.tum" >"$S17/trajectory.tum"
cp "$T/trajectory.tum" "$E17/"
check "i17: a still truth" 2 "" -- evaluate --estimate "$E17" --truth "$S17" --out "$I17/ev"
grep -q "still/trajectory.tum: cannot align" "$TMP/err.txt" ||
  { fail=$((fail + 1)); echo "FAIL still truth not named: $(cat "$TMP/err.txt")"; }
if "$RSFM" evaluate --estimate "$E17" --truth "$T" --out "$I17/ev" --rpe-delta 9223372036854775807 >"$TMP/out.txt" 2>"$TMP/err.txt" &&
   grep -q "RPE not computed" "$I17/ev/evaluation.md"; then
  pass=$((pass + 1)); echo "ok   i17: --rpe-delta INT64_MAX: no pairs, no overflow"
else
  fail=$((fail + 1)); echo "FAIL i17: --rpe-delta INT64_MAX: $(cat "$TMP/err.txt")"
fi

# --help succeeds.
if "$RSFM" experiment table1 --help >/dev/null 2>&1; then pass=$((pass + 1)); echo "ok   --help"; else fail=$((fail + 1)); echo "FAIL --help"; fi

# Issue 15: `rsfm` does not load OpenCV's video and image I/O; the video commands are handed over
# to rsfm-video beside it (the same arguments), and without it the hand-over fails in one line.
if ldd "$RSFM" | grep -q "libopencv_videoio\|libopencv_imgcodecs\|libavcodec"; then
  fail=$((fail + 1)); echo "FAIL rsfm links the video stack: $(ldd "$RSFM" | grep -c opencv) OpenCV libraries"
else
  pass=$((pass + 1)); echo "ok   rsfm loads $(ldd "$RSFM" | wc -l) shared libraries, no video or image I/O"
fi
if "$RSFM" track --help 2>/dev/null | grep -q -- "--max-tracks" && "$RSFM" --help | grep -q "^ *run "; then
  pass=$((pass + 1)); echo "ok   rsfm hands 'track' over to rsfm-video and lists 'run' in --help"
else
  fail=$((fail + 1)); echo "FAIL rsfm track --help (through rsfm-video) or rsfm --help"
fi
mkdir -p "$TMP/lone" && cp "$RSFM" "$TMP/lone/rsfm"
RSFM_SAVED="$RSFM"
RSFM="$TMP/lone/rsfm"
check "video command without rsfm-video" 1 "$TMP/o9" -- run "$TMP/none.mp4" --out "$TMP/o9"
grep -q "rsfm-video" "$TMP/err.txt" || { fail=$((fail + 1)); echo "FAIL the message does not name rsfm-video"; }
RSFM="$RSFM_SAVED"
echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
