#!/usr/bin/env bash
# Install + find_package (issue 16; docs/install.md): installs the build into a temporary prefix,
# builds examples/ against that installed package (find_package(rsfm), rsfm::rsfm) and runs it on
# a synthetic tracks file with known truth (python/tests/synthetic.py: focal 500 px, two planes at
# 90 degrees); runs the installed CLI, whose plot scripts must be found relative to it; imports
# the installed Python module; then the figure promises of docs/outputs.md: with the scripts
# missing every numeric output is still written and a warning names the missing figures, and a
# second run into the same directory with --no-plots leaves no figure of the first.
#   tests/install_example.sh BUILD_DIR SOURCE_DIR
set -euo pipefail
BUILD=$(cd "$1" && pwd)
SRC=$(cd "$2" && pwd)
PY=/usr/bin/python3
WORK=$(mktemp -d /tmp/rsfm-install.XXXXXX)
trap 'rm -rf "$WORK"' EXIT
PREFIX=$WORK/prefix
fail() { echo "install_example: FAIL: $*" >&2; exit 1; }

cmake --install "$BUILD" --prefix "$PREFIX" >"$WORK/install.log" || { cat "$WORK/install.log"; fail "cmake --install"; }
for f in bin/rsfm bin/rsfm-video include/rsfm/version.hpp include/rsfm/pipeline/estimate.hpp \
         lib/cmake/rsfm/rsfmConfig.cmake lib/cmake/rsfm/rsfmConfigVersion.cmake lib/cmake/rsfm/rsfmTargets.cmake \
         share/rsfm/scripts/plot_estimate.py share/doc/rsfm/LICENSE share/doc/rsfm/CITATION.cff; do
  [ -e "$PREFIX/$f" ] || fail "not installed: $f"
done
echo "install_example: installed into $PREFIX"

# An outside project: find_package(rsfm) + rsfm::rsfm, against the installed copy only.
cmake -S "$SRC/examples" -B "$WORK/example" -DCMAKE_PREFIX_PATH="$PREFIX" -DCMAKE_BUILD_TYPE=Release >"$WORK/cfg.log" 2>&1 ||
  { cat "$WORK/cfg.log"; fail "configuring examples/ against the installed package"; }
grep -q "$PREFIX/lib/cmake/rsfm" "$WORK/example/CMakeCache.txt" || fail "examples/ did not find the installed rsfm"
cmake --build "$WORK/example" -j2 >"$WORK/build.log" 2>&1 || { tail -30 "$WORK/build.log"; fail "building examples/"; }

"$PY" "$SRC/python/tests/synthetic.py" "$WORK/tracks.csv"
"$WORK/example/planes_from_tracks" "$WORK/tracks.csv" >"$WORK/example.out" 2>"$WORK/example.err" ||
  { cat "$WORK/example.err"; fail "planes_from_tracks"; }
cat "$WORK/example.out"
"$PY" - "$WORK/example.out" <<'PYEOF'
import math, re, sys
text = open(sys.argv[1]).read()
f = float(re.search(r"focal length: ([0-9.]+) px", text).group(1))
normals = [tuple(map(float, m)) for m in re.findall(r"normal \(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)\)", text)]
assert abs(f - 500.0) < 0.05 * 500.0, f"focal {f}"
assert len(normals) == 2, normals
c = abs(sum(a * b for a, b in zip(*normals)))
angle = math.degrees(math.acos(min(1.0, c)))
assert abs(angle - 90.0) < 3.0, f"angle {angle}"
print(f"install_example: example: focal {f:.1f} px (truth 500), planes at {angle:.2f} deg (truth 90)")
PYEOF

# The installed CLI finds its plot scripts in PREFIX/share/rsfm/scripts (no build-time path).
[ "$("$PREFIX/bin/rsfm" --version)" = "rsfm $(sed -n 's/^#define RSFM_VERSION "\(.*\)"/\1/p' "$PREFIX/include/rsfm/version.hpp")" ] ||
  fail "rsfm --version differs from version.hpp"
env -u RSFM_SCRIPTS_DIR "$PREFIX/bin/rsfm" estimate --tracks "$WORK/tracks.csv" --out "$WORK/est" --quiet
for f in summary.json trajectory.tum planes.csv motion.png normals.png focal.png; do
  [ -s "$WORK/est/$f" ] || fail "installed rsfm estimate did not write $f"
done
echo "install_example: the installed rsfm found its scripts and wrote every figure"

# The installed Python module.
PYDIR=$(ls -d "$PREFIX"/lib/python3.*/dist-packages 2>/dev/null | head -1 || true)
if [ -d "$BUILD/python/rsfm" ] && { [ -z "$PYDIR" ] || [ ! -d "$PYDIR/rsfm" ]; }; then
  fail "the build has the Python module but the install has none under lib/python3.X/dist-packages"
fi
if [ -n "$PYDIR" ] && [ -d "$PYDIR/rsfm" ]; then
  v=$(cd "$WORK" && PYTHONPATH="$PYDIR" "$PY" -c "import rsfm; print(rsfm.__version__)")
  [ "rsfm $v" = "$("$PREFIX/bin/rsfm" --version)" ] || fail "installed Python module version $v"
  echo "install_example: import rsfm from the prefix: $v"
fi

# Figures are never worth the numbers: the scripts missing -> every numeric output, a warning.
mv "$PREFIX/share/rsfm/scripts" "$PREFIX/share/rsfm/scripts.gone"
env -u RSFM_SCRIPTS_DIR "$PREFIX/bin/rsfm" estimate --tracks "$WORK/tracks.csv" --out "$WORK/est" --quiet 2>"$WORK/warn.txt" ||
  fail "rsfm estimate failed without its plot scripts"
grep -q "warning: figures not written (motion.png, motion.svg, normals.png, normals.svg, focal.png, focal.svg, process_noise.png, process_noise.svg, angles.png, angles.svg): the plot scripts were not found" "$WORK/warn.txt" ||
  { cat "$WORK/warn.txt"; fail "no warning naming the missing figures"; }
for f in summary.json trajectory.tum trajectory_online.tum planes.csv poses.csv labels.csv camera.yaml; do
  [ -s "$WORK/est/$f" ] || fail "without scripts: $f missing"
done
for f in motion.png normals.png focal.png; do [ ! -e "$WORK/est/$f" ] || fail "a figure of the earlier run survived: $f"; done
"$PY" -c "
import json, sys
s = json.load(open('$WORK/est/summary.json'))
assert s['figures']['written'] == [] and 'focal.png' in s['figures']['missing'] and 'not found' in s['figures']['why'], s['figures']
assert s['focal_px'] is not None
"
/usr/bin/python3 "$SRC/tests/check_report_html.py" "$WORK/est" || fail "report.html without figures"
grep -q 'id="warnings"' "$WORK/est/report.html" || fail "report.html does not show the missing figures' warning"
echo "install_example: without scripts: numbers written, warning: $(head -1 "$WORK/warn.txt")"
mv "$PREFIX/share/rsfm/scripts.gone" "$PREFIX/share/rsfm/scripts"
# A plot script that exits 0 without writing its figures: they are missing, not empty files.
mkdir -p "$WORK/quiet-scripts"
printf 'import sys\n' >"$WORK/quiet-scripts/plot_estimate.py"
RSFM_SCRIPTS_DIR="$WORK/quiet-scripts" "$PREFIX/bin/rsfm" estimate --tracks "$WORK/tracks.csv" --out "$WORK/est" --quiet \
  2>"$WORK/warn.txt" || fail "rsfm estimate failed with a silent plot script"
grep -q "figures not written (.*angles.svg): plot_estimate.py exited without writing them" "$WORK/warn.txt" ||
  { cat "$WORK/warn.txt"; fail "no warning for figures a script did not write"; }
[ -z "$(cd "$WORK/est" && ls ./*.png ./*.svg 2>/dev/null)" ] || fail "empty figure files were kept"
echo "install_example: a plot script that writes nothing: $(head -1 "$WORK/warn.txt")"
"$PREFIX/bin/rsfm" estimate --tracks "$WORK/tracks.csv" --out "$WORK/est2" --quiet
[ -e "$WORK/est2/motion.png" ] || fail "first run of the pair wrote no figure"
"$PREFIX/bin/rsfm" estimate --tracks "$WORK/tracks.csv" --out "$WORK/est2" --quiet --no-plots
leftover=$(cd "$WORK/est2" && ls *.png *.svg 2>/dev/null || true)
[ -z "$leftover" ] || fail "--no-plots run left figures of the earlier run: $leftover"
"$PY" -c "
import json
s = json.load(open('$WORK/est2/summary.json'))
assert 'figures' not in s, 'a --no-plots summary lists figures'
"
echo "install_example: a --no-plots run into the same directory left no figure of the first run"
echo "install_example: PASS"
