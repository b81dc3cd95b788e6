#!/usr/bin/env bash
# Runs every CAN HIL gtest binary given, one after the other, on the vcan0 that run_in_vm.sh
# provides; prints each one's gtest output and exits non-zero if any failed.
#   run_hil.sh OUTDIR BINARY...
set -u
out=$1
shift
if [ $# -eq 0 ]; then echo "run_hil.sh: no test binaries given" >&2; exit 2; fi
mkdir -p "$out"
export NCCOMP_HIL_OUT=$out
status=0
for bin in "$@"; do
  echo "=== $(basename "$bin")"
  "$bin" --gtest_color=no ${NCCOMP_HIL_GTEST_ARGS:-}
  rc=$?
  echo "=== $(basename "$bin") exit status $rc"
  [ $rc -eq 0 ] || status=1
done
exit $status
