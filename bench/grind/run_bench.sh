#!/bin/sh
# Issue 5 figures at the seed's resolution (2·10⁷ samples, W = 150 mm, h = 0.5 mm), all in one
# run on the same machine state:
#   1. the exact envelope alone, with its peer: memcpy of the same 160 MB in the same process
#      (bench_grind_envelope: median of 3, peak RSS by getrusage);
#   2. the whole `nccomp grind-path` command (/usr/bin/time: wall, user, max RSS), from the
#      convex family (with 21 polyline verification points and the verification on every
#      sample, and without any verification) and from a 2·10⁷-line CSV file (written once into
#      WORKDIR by awk). The verification on every sample alone: run_verify_bench.sh.
# Each is repeated REPEATS times, interleaved, so the ratios compare runs under the same load.
#
#   bench/grind/run_bench.sh NCCOMP BENCH_GRIND_ENVELOPE WORKDIR [REPEATS=3]
# e.g. after  cmake --preset release -B build/grind-rel
#             cmake --build build/grind-rel --target bench_grind_path_cli bench_grind_envelope
#   bench/grind/run_bench.sh build/grind-rel/bench/grind/bench_grind_path_cli \
#       build/grind-rel/bench/grind/bench_grind_envelope /tmp/grind-bench
set -eu
nccomp=$1
envelope=$2
work=$3
repeats=${4:-3}
mkdir -p "$work"
src=$(cd "$(dirname "$0")/../.." && pwd)

. "$(dirname "$0")/machine.sh"

csv=$work/crown2e7.csv
if [ ! -s "$csv" ]; then
  awk 'BEGIN { print "z_mm,u_mm";
               for (i = 0; i <= 20000000; i++) { z = -1000 + i * 0.0001;
                 printf "%.4f,%.9f\n", z, 0.6 * (1 - (z / 1000) ^ 2) } }' > "$csv"
fi

family="--family convex --height-mm 0.6 --z-from-mm -1000 --z-to-mm 1000 --spacing-mm 0.0001"
wheel="--wheel-width-mm 150 --arc-height-mm 0.5"
outs="--verify-points 21 --table-out $work/table.csv --gcode-out $work/crown.nc"

r=1
while [ "$r" -le "$repeats" ]; do
  echo "== run $r: envelope alone + memcpy peer"
  /usr/bin/time -f "process: wall %e s, user %U s, max RSS %M KiB" \
    "$envelope" 2000 0.0001 150 0.5 3 10 crown 2>&1
  echo "== run $r: nccomp grind-path $family $wheel $outs"
  # shellcheck disable=SC2086
  /usr/bin/time -f "process: wall %e s, user %U s, max RSS %M KiB" \
    "$nccomp" grind-path $family $wheel $outs > "$work/family.out" 2> "$work/family.time"
  grep -E "^exact envelope|^total|G-code:|^    \([0-9.]+ s\)" "$work/family.out"
  cat "$work/family.time"
  echo "== run $r: the same without the verification (--verify-points 0 --no-verify-samples)"
  # shellcheck disable=SC2086
  /usr/bin/time -f "process: wall %e s, user %U s, max RSS %M KiB" \
    "$nccomp" grind-path $family $wheel --verify-points 0 --no-verify-samples \
    > "$work/noverify.out" 2> "$work/noverify.time"
  grep -E "^exact envelope|^total" "$work/noverify.out"
  cat "$work/noverify.time"
  echo "== run $r: nccomp grind-path --profile crown2e7.csv $wheel $outs"
  # shellcheck disable=SC2086
  /usr/bin/time -f "process: wall %e s, user %U s, max RSS %M KiB" \
    "$nccomp" grind-path --profile "$csv" $wheel $outs > "$work/csv.out" 2> "$work/csv.time"
  grep -E "^exact envelope|^total|^    \([0-9.]+ s\)" "$work/csv.out"
  cat "$work/csv.time"
  r=$((r + 1))
done
echo "== last full report (family)"
cat "$work/family.out"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
