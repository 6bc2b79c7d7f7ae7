#!/usr/bin/env bash
# Runs `rsfm experiment table1` under the variants discussed in docs/table1.md and writes a
# combined summary to OUT/study.md (each variant's full report is in OUT/<variant>/).
# Usage: scripts/table1_study.sh [TRIALS=200] [OUT=out/study] [RSFM=build/rsfm]
set -euo pipefail
TRIALS="${1:-200}"
OUT="${2:-out/study}"
RSFM="${3:-build/rsfm}"
mkdir -p "$OUT"
variants=(
  "default|"
  "inflate|--reference inflate"
  "exact|--reference exact"
  "noise-free-reference|--reference-noise false --reference exact"
  "rate-reading|--reading rate"
  "0.3deg-per-frame|--deg-per-frame -0.3"
  "small-Q|--q-trans 3e-5 --q-omega 3e-5"
)
{
  echo "# Table 1 study: $TRIALS trials per noise level, seed 1"
  echo
  echo "Each row: plane / point. sigma_t, sigma_q: RMS errors; med: median over trials of each trial's RMS;"
  echo "normal and beta: mean error at frame 100; ordering: plane better on (sigma_t, sigma_q, r_s, r_c)."
  echo
  echo "| variant | options | noise | sigma_t plane / point | sigma_q plane / point | med sigma_t plane / point | r_s | r_c | normal deg plane / point | beta % plane / point | ordering |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|"
} >"$OUT/study.md"
for v in "${variants[@]}"; do
  name="${v%%|*}"
  opts="${v#*|}"
  # shellcheck disable=SC2086
  "$RSFM" experiment table1 --quiet --trials "$TRIALS" $opts --out "$OUT/$name"
  awk -F'|' -v name="$name" -v opts="$opts" '
    /^\| (plane|point) \| [0-9]/ && !seen[$2 $3]++ {
      gsub(/ /, "", $2); gsub(/ /, "", $3)
      key = $3; f = $2
      st[f, key] = $5; sq[f, key] = $7; rs[f, key] = $8; rc[f, key] = $9
      ne[f, key] = $14; be[f, key] = $15; mt[f, key] = $16
      if (f == "plane") order[++n] = key
    }
    /^\| [0-9.]+ \| (yes|NO)/ { gsub(/ /, "", $2); ord[$2] = $3 $4 $5 $6; gsub(/ +/, " ", ord[$2]) }
    END {
      for (i = 1; i <= n; i++) {
        k = order[i]
        printf "| %s | `%s` | %s | %s / %s | %s / %s | %s / %s | %s / %s | %s / %s | %s / %s | %s / %s | %s |\n",
          name, opts, k, st["plane", k], st["point", k], sq["plane", k], sq["point", k],
          mt["plane", k], mt["point", k], rs["plane", k], rs["point", k], rc["plane", k], rc["point", k],
          ne["plane", k], ne["point", k], be["plane", k], be["point", k], ord[k]
      }
    }' "$OUT/$name/table1.md" | sed 's/  */ /g' >>"$OUT/study.md"
done
echo "wrote $OUT/study.md" >&2
