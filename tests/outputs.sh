#!/usr/bin/env bash
# All-or-nothing outputs through the CLI (issue 17 item 4; docs/outputs.md "Output directories"):
# a run replaces its directory whole, an interrupted or failing run leaves the previous output
# exactly as it was and nothing behind, a directory rsfm did not write is refused.
# Usage: outputs.sh path/to/rsfm
set -u
RSFM="$1"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
pass=0
fail=0
ok() { pass=$((pass + 1)); echo "ok   $1"; }
bad() { fail=$((fail + 1)); echo "FAIL $1"; }
snapshot() { (cd "$1" && find . -type f -print0 | sort -z | xargs -0 md5sum); }
staging_left() { find "$1" -maxdepth 1 -name '.*.rsfm-*' | wc -l; }

D="$TMP/exp"
"$RSFM" experiment two-object --trials 1 --frames 20 --quiet --out "$D" 2>"$TMP/err.txt" || bad "first run: $(cat "$TMP/err.txt")"
[ -f "$D/.rsfm-output" ] && [ -s "$D/two_object.csv" ] && ok "a committed run holds its files and the marker" ||
  bad "first run files: $(ls -A "$D" | tr '\n' ' ')"

# A new run replaces the directory whole: an earlier run's extra files do not survive.
echo old >"$D/evaluation.json"
echo old >"$D/overlay.mp4"
"$RSFM" experiment two-object --trials 1 --frames 20 --quiet --out "$D" 2>"$TMP/err.txt"
if [ ! -e "$D/evaluation.json" ] && [ ! -e "$D/overlay.mp4" ] && [ -s "$D/two_object.csv" ] && [ "$(staging_left "$TMP")" -eq 0 ]; then
  ok "a second run replaces the first whole (no old evaluation.json, overlay.mp4)"
else
  bad "second run: $(ls -A "$D" | tr '\n' ' '); staging left: $(staging_left "$TMP")"
fi

# Interrupted by SIGINT or SIGTERM (sent by a parent that does not ignore them): the previous
# output is exactly as it was, no staging directory or temporary is left, the exit is the signal's.
before=$(snapshot "$D")
for sig in INT TERM; do
  code=$(/usr/bin/python3 - "$RSFM" "$D" "$sig" <<'PY'
import signal, subprocess, sys, time
p = subprocess.Popen([sys.argv[1], "experiment", "table1", "--trials", "400", "--quiet", "--out", sys.argv[2]],
                     stderr=subprocess.DEVNULL)
time.sleep(1.5)
p.send_signal(getattr(signal, "SIG" + sys.argv[3]))
print(p.wait())
PY
)
  after=$(snapshot "$D")
  if [ "$code" = "-$( [ $sig = INT ] && echo 2 || echo 15)" ] && [ "$before" = "$after" ] && [ "$(staging_left "$TMP")" -eq 0 ] &&
     [ -z "$(find "$TMP" -name '*.tmp-*')" ]; then
    ok "SIG$sig mid-run: killed by the signal ($code), previous output unchanged, nothing left behind"
  else
    bad "SIG$sig mid-run: exit $code, unchanged: $([ "$before" = "$after" ] && echo yes || echo no), staging left $(staging_left "$TMP")"
  fi
done

# A directory rsfm did not write is refused (one line, exit 2) and left untouched.
H="$TMP/home"
mkdir -p "$H"
echo keep >"$H/precious.txt"
"$RSFM" experiment two-object --trials 1 --frames 20 --quiet --out "$H" 2>"$TMP/err.txt"
code=$?
if [ $code -eq 2 ] && [ "$(wc -l <"$TMP/err.txt")" -eq 1 ] && grep -q "not an earlier rsfm output" "$TMP/err.txt" &&
   [ "$(cat "$H/precious.txt")" = keep ] && [ "$(ls -A "$H")" = precious.txt ]; then
  ok "a foreign directory is refused: $(cat "$TMP/err.txt")"
else
  bad "foreign directory: exit $code, $(cat "$TMP/err.txt"), $(ls -A "$H" | tr '\n' ' ')"
fi

# Failing commands leave no directory they created (bad input found after the output was prepared).
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 1\nframe,track,x,y\n0,0,1,1\n1,0,nan,1\n' >"$TMP/bad.csv"
echo "not a video" >"$TMP/bad.mp4"
for cmd in "estimate --tracks $TMP/bad.csv" "track $TMP/bad.mp4" "run $TMP/bad.mp4"; do
  # shellcheck disable=SC2086
  "$RSFM" $cmd --out "$TMP/new/deeper/out" >/dev/null 2>"$TMP/err.txt"
  code=$?
  if [ $code -ne 0 ] && [ ! -e "$TMP/new" ] && [ "$(wc -l <"$TMP/err.txt")" -eq 1 ]; then
    ok "failing '${cmd%% *}' (exit $code) leaves no directory: $(cat "$TMP/err.txt")"
  else
    bad "failing '${cmd%% *}': exit $code, $(ls -R "$TMP/new" 2>&1 | tr '\n' ' '), $(cat "$TMP/err.txt")"
  fi
done

# An output directory that holds the command's own input is refused (replacing it would delete
# the input): estimate --tracks D/tracks.csv --out D.
mkdir -p "$TMP/t"
printf '# rsfm-tracks 1\n# image_size 640 480\n# frames 0 1\nframe,track,x,y\n0,0,1,1\n1,0,2,1\n' >"$TMP/t/tracks.csv"
touch "$TMP/t/.rsfm-output"
before=$(snapshot "$TMP/t")
"$RSFM" estimate --tracks "$TMP/t/tracks.csv" --out "$TMP/t" 2>"$TMP/err.txt"
code=$?
if [ $code -eq 2 ] && grep -q "holds the input" "$TMP/err.txt" && [ "$before" = "$(snapshot "$TMP/t")" ]; then
  ok "an output directory holding the input is refused: $(cat "$TMP/err.txt")"
else
  bad "output holding the input: exit $code, $(cat "$TMP/err.txt")"
fi

echo "outputs: $pass passed, $fail failed"
[ "$fail" -eq 0 ]
