#!/usr/bin/env bash
# COLMAP reference reconstruction of an image sequence, reduced to two small files that rsfm's
# evaluator reads as a "truth" directory, so rsfm can be compared with COLMAP without running it.
#
# Usage: bench/colmap_reference.sh INPUT NAME [OUTDIR]
#   INPUT  an image-sequence pattern with one printf integer field
#          (/usr/share/visp-images-data/ViSP-images/cube/image.%04d.pgm), a folder of images
#          (png jpg jpeg pgm ppm pnm bmp tif tiff webp, sorted by file name), or a video file.
#   NAME   name of the reference; OUTDIR defaults to bench/reference/colmap/NAME (in this repo).
# Environment: RSFM_COLMAP_WORK (work directory, default /tmp/rsfm-colmap-NAME; emptied of any
#   previous COLMAP database/model on each run).
#
# Frame numbers follow rsfm's FrameSource (src/vision/frame_source.cpp), so both number frames alike:
#   - pattern: the first existing index in 0..1000 is frame 0 and the sequence runs to the first
#     missing index (for image.%04d.pgm starting at image.0000.pgm, frame k = image.k);
#   - folder: frame k = the k-th image file in file-name order (0-based);
#   - video:  frame k = the k-th decoded frame (0-based), extracted by ffmpeg with -vsync 0
#     (every decoded frame, none duplicated or dropped).
# Every frame is written as WORK/images/frame_%06d.png (frame number in the name; ffmpeg keeps
# grey images grey); WORK/frames.csv maps frame numbers to the source files.
#
# What it runs (CPU only, one thread everywhere; QT_QPA_PLATFORM=offscreen, OMP_NUM_THREADS=1):
#   apt-get install colmap ffmpeg (only when dpkg-query says they are missing; needs root)
#   colmap feature_extractor  --ImageReader.single_camera 1 --ImageReader.camera_model SIMPLE_RADIAL
#                             --SiftExtraction.use_gpu 0 --SiftExtraction.num_threads 1
#   colmap sequential_matcher --SiftMatching.use_gpu 0 --SiftMatching.num_threads 1  (defaults:
#                             overlap 10, quadratic overlap, no loop detection)
#   colmap mapper             --Mapper.num_threads 1
#   colmap model_converter    --output_type TXT, for every model the mapper wrote; the model with
#                             the most registered images is used (WORK/sparse_txt/N)
#   colmap model_analyzer     of that model (log only, to cross-check the extracted figures)
#   /usr/bin/python3 bench/colmap_extract.py  (conventions and the plane fit: see its docstring)
# Logs of every stage: WORK/logs/STAGE.log. Progress and per-stage times go to stderr.
#
# What it writes to OUTDIR (nothing else; written under temporary names and renamed at the end):
#   trajectory.tum  one line per registered frame, `t tx ty tz qx qy qz qw`: t the frame number,
#                   camera centre and Hamilton rotation camera -> reference in the reference camera
#                   frame (frame 0 if registered, else the lowest registered frame), x right,
#                   y down, z forward, qw >= 0; units: COLMAP's (arbitrary scale).
#   summary.json    rsfm's summary schema (docs/evaluate.md): frames, image size, principal point
#                   (COLMAP's cx, cy minus 0.5: COLMAP puts the top-left pixel's centre at (0.5, 0.5),
#                   rsfm/OpenCV at (0, 0)), focal_px, the dominant plane of points3D (n . X = d,
#                   d > 0, reference camera frame) as "colmap_dominant_plane", scene_size,
#                   radial_distortion [k1, 0] (OpenCV convention), and under
#                   "colmap": k1, registered frames, reference frame, points, reprojection error,
#                   plane inliers, seconds per stage, the command.
set -euo pipefail

usage() { echo "usage: bench/colmap_reference.sh INPUT NAME [OUTDIR]" >&2; exit 2; }
[ $# -ge 2 ] && [ $# -le 3 ] || usage
INPUT="$1"
NAME="$2"
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
OUTDIR="${3:-$HERE/reference/colmap/$NAME}"
WORK="${RSFM_COLMAP_WORK:-/tmp/rsfm-colmap-$NAME}"
COMMAND="bench/colmap_reference.sh $(printf '%q ' "$@")"
COMMAND="${COMMAND% }"

log() { echo "colmap_reference: $*" >&2; }
die() { echo "colmap_reference: error: $*" >&2; exit 1; }
case "$NAME" in ''|*/*) die "NAME must be a non-empty name without '/'";; esac

export QT_QPA_PLATFORM=offscreen OMP_NUM_THREADS=1
T_START=$(date +%s.%N)
declare -a STAGES=()
declare -A SECONDS_OF=()
STAGE_T0=0
stage_begin() { STAGE_T0=$(date +%s.%N); log "[$1] ..."; }
stage_end() {
  local s
  s=$(awk -v a="$STAGE_T0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }')
  STAGES+=("$1"); SECONDS_OF[$1]=$s
  log "[$1] done in ${s} s"
}
# run STAGE cmd...: runs a command with its output in WORK/logs/STAGE.log; on failure shows its tail.
run() {
  local st="$1"; shift
  local rc=0
  "$@" >>"$WORK/logs/$st.log" 2>&1 || rc=$?
  if [ "$rc" -ne 0 ]; then
    tail -n 20 "$WORK/logs/$st.log" >&2
    die "$st failed with exit code $rc (last lines above; full log: $WORK/logs/$st.log)"
  fi
}

# --- install --------------------------------------------------------------------------------------
stage_begin install
missing=()
for p in colmap ffmpeg; do
  [ "$(dpkg-query -W -f='${db:Status-Status}' "$p" 2>/dev/null || true)" = installed ] || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  log "installing ${missing[*]} with apt-get"
  [ "$(id -u)" = 0 ] || die "${missing[*]} missing and not root: apt-get install ${missing[*]}"
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends -o DPkg::Lock::Timeout=600 \
    "${missing[@]}" >&2 || die "apt-get install ${missing[*]} failed"
fi
COLMAP_VERSION=$(colmap help 2>/dev/null | sed -n 's/^COLMAP \([0-9.]*\).*/\1/p' | head -n1)
log "COLMAP ${COLMAP_VERSION:-?}, work directory $WORK, output $OUTDIR"
stage_end install

# --- frames ---------------------------------------------------------------------------------------
mkdir -p "$WORK" "$OUTDIR"
rm -rf "$WORK/images" "$WORK/sparse" "$WORK/sparse_txt" "$WORK/logs" "$WORK/database.db" \
  "$WORK/database.db-shm" "$WORK/database.db-wal" "$WORK/frames.csv" "$WORK/seconds.txt"
mkdir -p "$WORK/images" "$WORK/sparse" "$WORK/sparse_txt" "$WORK/logs"
stage_begin frames
echo "frame,source" >"$WORK/frames.csv"
convert_one() {  # convert_one SRC FRAME
  local dst
  dst=$(printf '%s/images/frame_%06d.png' "$WORK" "$2")
  run frames ffmpeg -nostdin -hide_banner -loglevel error -y -i "$1" -frames:v 1 "$dst"
  echo "$2,$1" >>"$WORK/frames.csv"
}
is_image() {
  case "${1,,}" in *.png|*.jpg|*.jpeg|*.pgm|*.ppm|*.pnm|*.bmp|*.tif|*.tiff|*.webp) return 0;; esac
  return 1
}
if [[ "$INPUT" == *%* ]]; then
  start=-1
  for ((i = 0; i <= 1000; i++)); do
    # shellcheck disable=SC2059
    if [ -f "$(printf "$INPUT" "$i")" ]; then start=$i; break; fi
  done
  [ "$start" -ge 0 ] || die "$INPUT: no image matches the pattern (tried indices 0..1000)"
  i=$start
  # shellcheck disable=SC2059
  while [ -f "$(printf "$INPUT" "$i")" ]; do
    # shellcheck disable=SC2059
    convert_one "$(printf "$INPUT" "$i")" $((i - start))
    i=$((i + 1))
  done
  for ((gap = 1; gap <= 10; gap++)); do  # as rsfm: a hole followed by more frames is an error
    # shellcheck disable=SC2059
    [ ! -f "$(printf "$INPUT" $((i + gap)))" ] || die "$INPUT: missing frame: the sequence stops at index $((i - 1)) but index $((i + gap)) exists"
  done
  [ "$start" -eq 0 ] || log "pattern starts at index $start: frame k is index $start + k (as rsfm numbers it)"
elif [ -d "$INPUT" ]; then
  k=0
  while IFS= read -r -d '' f; do
    is_image "$f" || continue
    convert_one "$f" "$k"
    k=$((k + 1))
  done < <(find "$INPUT" -maxdepth 1 -type f -print0 | LC_ALL=C sort -z)
  [ "$k" -gt 0 ] || die "$INPUT: folder contains no images"
elif [ -f "$INPUT" ]; then
  run frames ffmpeg -nostdin -hide_banner -loglevel error -y -i "$INPUT" -map 0:v:0 -vsync 0 \
    -start_number 0 "$WORK/images/frame_%06d.png"
  for f in "$WORK"/images/frame_*.png; do
    b=$(basename "$f" .png); echo "$((10#${b#frame_})),$INPUT#${b#frame_}" >>"$WORK/frames.csv"
  done
else
  die "$INPUT: no such file, folder or pattern"
fi
FRAMES=$(($(wc -l <"$WORK/frames.csv") - 1))
[ "$FRAMES" -ge 2 ] || die "$INPUT: fewer than 2 frames"
log "$FRAMES frames in $WORK/images"
stage_end frames

# --- COLMAP ---------------------------------------------------------------------------------------
stage_begin feature_extractor
run feature_extractor colmap feature_extractor --database_path "$WORK/database.db" --image_path "$WORK/images" \
  --ImageReader.single_camera 1 --ImageReader.camera_model SIMPLE_RADIAL \
  --SiftExtraction.use_gpu 0 --SiftExtraction.num_threads 1
stage_end feature_extractor

stage_begin sequential_matcher
run sequential_matcher colmap sequential_matcher --database_path "$WORK/database.db" \
  --SiftMatching.use_gpu 0 --SiftMatching.num_threads 1
stage_end sequential_matcher

stage_begin mapper
run mapper colmap mapper --database_path "$WORK/database.db" --image_path "$WORK/images" \
  --output_path "$WORK/sparse" --Mapper.num_threads 1
stage_end mapper

stage_begin model_converter
best=""; best_n=-1
for m in "$WORK"/sparse/*/; do
  [ -f "$m/images.bin" ] || continue
  id=$(basename "$m")
  mkdir -p "$WORK/sparse_txt/$id"
  run model_converter colmap model_converter --input_path "$m" --output_path "$WORK/sparse_txt/$id" --output_type TXT
  # images.txt: 4 comment lines, then two lines per registered image.
  n=$(( $(grep -vc '^#' "$WORK/sparse_txt/$id/images.txt" || true) / 2 ))
  log "model $id: $n registered images"
  if [ "$n" -gt "$best_n" ]; then best="$id"; best_n=$n; fi
done
[ -n "$best" ] || die "the mapper wrote no model (see $WORK/logs/mapper.log)"
MODEL_TXT="$WORK/sparse_txt/$best"
log "using model $best ($best_n of $FRAMES frames registered)"
run model_analyzer colmap model_analyzer --path "$WORK/sparse/$best"
stage_end model_converter

# --- extraction -----------------------------------------------------------------------------------
stage_begin extract
for s in "${STAGES[@]}"; do echo "$s ${SECONDS_OF[$s]}" >>"$WORK/seconds.txt"; done
/usr/bin/python3 "$HERE/colmap_extract.py" --model "$MODEL_TXT" --frames "$FRAMES" --out "$OUTDIR" \
  --seconds "$WORK/seconds.txt" --command "$COMMAND" --version "${COLMAP_VERSION:-unknown}" \
  --input "$INPUT" --model-id "$best" --models "$(ls "$WORK/sparse_txt" | wc -l)"
stage_end extract
TOTAL=$(awk -v a="$T_START" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
line="times (s):"
for s in "${STAGES[@]}"; do line+=" $s ${SECONDS_OF[$s]}"; done
log "$line; total $TOTAL"
log "wrote $OUTDIR/trajectory.tum and $OUTDIR/summary.json (logs in $WORK/logs)"
