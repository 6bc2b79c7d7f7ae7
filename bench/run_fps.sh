#!/usr/bin/env bash
# Frames per second of `rsfm run` without the overlay video (and without plots) on opencv-doc's
# box.mp4 (640x480, 455 frames), pinned to one core. Usage: bench/run_fps.sh [BUILD_DIR]
set -euo pipefail
BUILD="${1:-build}"
BOX_GZ=/usr/share/doc/opencv-doc/opencv4/html/box.mp4.gz
[ -f "$BOX_GZ" ] || { echo "run_fps: $BOX_GZ not installed (apt-get install opencv-doc)" >&2; exit 1; }
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
zcat "$BOX_GZ" >"$TMP/box.mp4"
PIN=()
command -v taskset >/dev/null && PIN=(taskset -c 0)
/usr/bin/python3 - "$BUILD/rsfm" "$TMP" "${PIN[@]}" <<'PY'
import json, os, subprocess, sys, time
rsfm, tmp, pin = sys.argv[1], sys.argv[2], sys.argv[3:]
env = dict(os.environ, OPENCV_FOR_THREADS_NUM="1")
best = None
for _ in range(3):
    t0 = time.monotonic()
    subprocess.run(pin + [rsfm, "run", f"{tmp}/box.mp4", "--out", f"{tmp}/run", "--no-overlay", "--no-plots", "--quiet"],
                   check=True, env=env)
    t = time.monotonic() - t0
    best = t if best is None else min(best, t)
summary = json.load(open(f"{tmp}/run/summary.json"))
frames = summary["frames"]
print(f"rsfm run (no overlay, no plots) on box.mp4: {frames} frames in {best:.2f} s "
      f"(best of 3, {'one core' if pin else 'unpinned'}) = {frames / best:.1f} frames/s")
# The last run's stages (summary.json stage_seconds): this machine's speed varies between runs,
# the split between stages much less.
stages = summary.get("stage_seconds", {})
print("  last run's stages: " + ", ".join(f"{k} {v:.2f} s" for k, v in stages.items()))
PY
