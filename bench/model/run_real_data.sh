#!/usr/bin/env bash
# Runs `nccomp analyze` on the two real data sets of /work/shared/data and copies the reports and
# figures used by docs/closing-the-loop.md into bench/model/figures/.
#   bench/model/run_real_data.sh [path/to/nccomp]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
nccomp="${1:-build/release/tools/nccomp}"
data=/work/shared/data
out="${TMPDIR:-/tmp}/nccomp_closing_the_loop"
rm -rf "$out"
"$nccomp" analyze \
  --log "$data/phm2010_milling_wear/c4_wear.csv" --map "$here/phm2010/c4.map.toml" \
  --log "$data/phm2010_milling_wear/c6_wear.csv" --map "$here/phm2010/c6.map.toml" \
  --config "$here/phm2010/phm.toml" --out "$out/phm2010"
for ch in 1 3 5; do
  "$nccomp" analyze --log "$data/fl_thermal_spindle_drift/data.csv" \
    --map "$here/fl_thermal/ch$ch.map.toml" --config "$here/fl_thermal/fl_thermal.toml" \
    --out "$out/fl_thermal_ch$ch"
done
rm -rf "$here/figures"
mkdir -p "$here/figures"
for d in phm2010 fl_thermal_ch1 fl_thermal_ch3 fl_thermal_ch5; do
  mkdir -p "$here/figures/$d"
  cp "$out/$d/summary.json" "$out/$d/report.md" "$out/$d/model.toml" "$here/figures/$d/"
  cp -r "$out/$d/plots" "$here/figures/$d/"
done
echo "figures in $here/figures"
