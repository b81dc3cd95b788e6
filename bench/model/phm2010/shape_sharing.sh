#!/usr/bin/env bash
# PHM 2010: does the held-out error on the last cuts depend on whether the searched wear-curve
# shapes are shared by the cutters (and flutes) or fitted per cutter (per flute)? Runs `nccomp
# analyze` on c4 and c6 (the last 20 % of the cuts of each held out) in two views of the data:
#   max:   the per-cut maximum over the flutes (phm2010_wear_percut.csv, max_wear.map.toml);
#   flute: every flute (c4_wear.csv, c6_wear.csv with c4.map.toml, c6.map.toml).
# The declared model is phm.toml's (initial wear and wear rate per cutter, or per flute of each
# cutter); what changes is how the search splits its candidates (`per` or `group_columns`), and
# rank_folds 0 or 3. Prints one markdown row per run: the effects added with the held-out RMS
# after each, and the final held-out RMS.
#   bench/model/phm2010/shape_sharing.sh [path/to/nccomp]   (default: build/release/tools/nccomp)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
nccomp="build/release/tools/nccomp"
[ $# -ge 1 ] && nccomp="$(realpath "$1")"
cd "$here/../../.."
data="${NCCOMP_DATA:-../shared/data}/phm2010_milling_wear"
work="$(mktemp -d "${TMPDIR:-/tmp}/nccomp_phm_sharing.XXXXXX")"
trap 'rm -rf "$work"' EXIT
for c in c4 c6; do
  awk -F, -v c="$c" 'NR == 1 || $1 == c' "$data/phm2010_wear_percut.csv" > "$work/$c.csv"
done
config() {  # declared per, search key, search value, rank_folds
  cat <<EOT
[model]
heldout_fraction = 0.2
alpha = 0.01
max_effects = 4
ar1_correction = false
rank_folds = $4

[[model.term]]
name = "offset"
form = "constant"
per = $1

[[model.term]]
name = "wear"
form = "linear"
column = "path_mm"
per = $1

[model.search]
exclude = ["thermal_drift"]
$2 = $3
EOT
}
run() {  # view, declared per, search key, search value
  local view="$1" declared="$2" key="$3" value="$4" logs rk
  if [ "$view" = max ]; then
    logs=(--log "$work/c4.csv" --log "$work/c6.csv" --map bench/model/phm2010/max_wear.map.toml)
  else
    logs=(--log "$data/c4_wear.csv" --map bench/model/phm2010/c4.map.toml
          --log "$data/c6_wear.csv" --map bench/model/phm2010/c6.map.toml)
  fi
  for rk in 0 3; do
    config "$declared" "$key" "$value" "$rk" > "$work/model.toml"
    "$nccomp" analyze "${logs[@]}" --config "$work/model.toml" --out "$work/out" > "$work/log.txt"
    local declared_rms steps final
    declared_rms="$(sed -n 's/^declared model: .*held-out RMS \([0-9.]*\) µm$/\1/p' "$work/log.txt")"
    steps="$(sed -n 's/^added \(.*\): RMS .* -> \([0-9.]*\) µm, p = .*/\1 \2;/p' "$work/log.txt" \
      | sed 's/ (\([a-z_]*\), \([a-z_]*\))/ \2/' | awk '{ $NF = sprintf("%.2f;", $NF); print }' \
      | tr '\n' ' ')"
    final="$(sed -n 's/^final RMS .* (held-out \([0-9.]*\) µm).*/\1/p' "$work/log.txt")"
    printf '| %s | %s | %s = %s | %s | %.2f | %s| **%.2f** |\n' "$view" "$declared" "$key" \
      "$value" "$rk" "$declared_rms" "${steps:-none }" "$final"
  done
}
echo "| view | declared per | search | rank_folds | declared held-out [µm] | added, held-out RMS after it [µm] | final held-out [µm] |"
echo "| --- | --- | --- | --- | --- | --- | --- |"
run max '["tool"]' per '["tool"]'
run max '["tool"]' group_columns '["tool"]'
run max '["tool"]' per '[]'
run flute '["tool", "point"]' per '["tool", "point"]'
run flute '["tool", "point"]' group_columns '["tool", "point"]'
run flute '["tool", "point"]' per '["tool"]'
run flute '["tool", "point"]' per '["point"]'
run flute '["tool", "point"]' per '[]'
