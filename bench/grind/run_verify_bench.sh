#!/bin/sh
# The verification on every sample (core/grind/verify_grid.hpp) at the seed's resolution:
# 2·10⁷ samples, W = 150 mm, h = 0.5 mm (and h = 0), inside the whole `nccomp grind-path`.
# Interleaved, REPEATS times, under /usr/bin/time -v (wall, user, system, max RSS):
#   A. no verification at all          (--verify-points 0 --no-verify-samples)
#   B. the verification on every sample (--verify-points 0): B at all 2·10⁷ samples for the
#      usual practice and the exact envelope; the command prints that section's wall time.
# B − A in user + system time is the verification's CPU; B's max RSS is the command's peak with
# the verification's stack alive.
#
#   bench/grind/run_verify_bench.sh NCCOMP WORKDIR [REPEATS=3]
# e.g. after  cmake -S . -B build/grindrel -G Ninja -DCMAKE_BUILD_TYPE=Release -DNCCOMP_WERROR=ON
#             cmake --build build/grindrel --target bench_grind_path_cli
#   bench/grind/run_verify_bench.sh build/grindrel/bench/grind/bench_grind_path_cli /tmp/grind-verify
set -eu
nccomp=$1
work=$2
repeats=${3:-3}
mkdir -p "$work"
src=$(cd "$(dirname "$0")/../.." && pwd)

. "$(dirname "$0")/machine.sh"

family="--family convex --height-mm 0.6 --z-from-mm -1000 --z-to-mm 1000 --spacing-mm 0.0001"

timed() {  # label, then the command's arguments
  label=$1
  shift
  echo "== $label: grind-path $*"
  # shellcheck disable=SC2086
  /usr/bin/time -v "$nccomp" grind-path "$@" > "$work/out" 2> "$work/time"
  sed -n '/^verification on every sample/,/^    ([0-9.]* s)/p' "$work/out"
  grep -E "^exact envelope|^total" "$work/out"
  grep -E "Elapsed \(wall|User time|System time|Maximum resident" "$work/time" | sed 's/^\t*/    /'
}

r=1
while [ "$r" -le "$repeats" ]; do
  for h in 0.5 0; do
    # shellcheck disable=SC2086
    timed "run $r, h $h, A (no verification)" $family --wheel-width-mm 150 --arc-height-mm "$h" \
      --verify-points 0 --no-verify-samples
    # shellcheck disable=SC2086
    timed "run $r, h $h, B (verification on every sample)" $family --wheel-width-mm 150 \
      --arc-height-mm "$h" --verify-points 0
  done
  r=$((r + 1))
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
