#!/usr/bin/env bash
# The prediction interval's coverage on real held-out rows, both scales (docs/analyze.md, "The
# prediction interval"): `nccomp analyze` on PHM 2010 (c4 + c6 per flute; c1, c4, c6 per cut),
# FL_THERMAL ch1, ch3, ch5 and ACE spindle thermal as bench/model/run_real_data.sh runs them,
# once with interval = "in_sample" and once with "validation", and a table of the summary.json
# figures.
#   bench/model/run_interval.sh [path/to/nccomp]   (default: build/release/tools/nccomp)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
nccomp="build/release/tools/nccomp"
[ $# -ge 1 ] && nccomp="$(realpath "$1")"
cd "$here/../.."
data="${NCCOMP_DATA:-../shared/data}"
out="$(mktemp -d "${TMPDIR:-/tmp}/nccomp_interval.XXXXXX")"
trap 'rm -rf "$out"' EXIT
# The config with the interval key set: inserted under its [model] line.
with_interval() {  # config, method -> path of the copy
  local c="$out/$(basename "$1" .toml)_$2.toml"
  sed "s/^\[model\]\$/[model]\ninterval = \"$2\"/" "$1" >"$c"
  echo "$c"
}
for m in in_sample validation; do
  "$nccomp" analyze \
    --log "$data/phm2010_milling_wear/c4_wear.csv" --map bench/model/phm2010/c4.map.toml \
    --log "$data/phm2010_milling_wear/c6_wear.csv" --map bench/model/phm2010/c6.map.toml \
    --config "$(with_interval bench/model/phm2010/phm.toml $m)" --out "$out/$m/phm2010_c4_c6" >/dev/null
  "$nccomp" analyze \
    --log "$data/phm2010_milling_wear/phm2010_wear_percut.csv" \
    --map bench/model/phm2010/percut.map.toml \
    --config "$(with_interval bench/model/phm2010/percut.toml $m)" \
    --out "$out/$m/phm2010_c1_c4_c6" >/dev/null
  for ch in 1 3 5; do
    "$nccomp" analyze --log "$data/fl_thermal_spindle_drift/data.csv" \
      --map "bench/model/fl_thermal/ch$ch.map.toml" \
      --config "$(with_interval bench/model/fl_thermal/fl_thermal.toml $m)" \
      --out "$out/$m/fl_thermal_ch$ch" >/dev/null
  done
  "$nccomp" analyze --log bench/data/ace_spindle_thermal --map bench/model/ace_thermal/ace.map.toml \
    --config "$(with_interval bench/model/ace_thermal/ace.toml $m)" --out "$out/$m/ace_thermal" \
    >/dev/null
done
/usr/bin/python3 - "$out" <<'PY'
import json, os, sys
out = sys.argv[1]
runs = ["phm2010_c4_c6", "phm2010_c1_c4_c6", "fl_thermal_ch1", "fl_thermal_ch3", "fl_thermal_ch5",
        "ace_thermal"]
print("| run | held-out rows | held-out RMS [µm] | method | s [µm] | validation RMS [µm] (rows) "
      "| mean / max half-width [µm] | coverage |")
print("| --- | --- | --- | --- | --- | --- | --- | --- |")
for r in runs:
    for m in ["in_sample", "validation"]:
        j = json.load(open(os.path.join(out, m, r, "summary.json")))
        pi = j["prediction_interval"]
        fin = j["effects"][-1]["heldout_rms_after_um"] if j["effects"] else None
        v = pi["validation_rms_um"]
        vs = "—" if v is None else "%.3f (%d)" % (v, pi["validation_rows"])
        print("| %s | %d | %s | %s | %.3f | %s | %.3f / %.3f | %.4f |" % (
            r, pi["rows"], "—" if fin is None else "%.3f" % fin, pi["method"], pi["sigma_in_sample_um"], vs,
            pi["half_width_um"], pi["half_width_max_um"], pi["coverage"]))
PY
