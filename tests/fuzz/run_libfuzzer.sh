#!/usr/bin/env bash
# One coverage-guided run of a libFuzzer target (ctest in the `fuzz` preset, bench/fuzz):
#   run_libfuzzer.sh TARGET CORPUS_DIR WORK_DIR [libFuzzer flags...]
# libFuzzer writes the inputs it finds into its first corpus directory, so that is a fresh
# WORK_DIR/corpus and the committed CORPUS_DIR is only read. A finding is saved as
# WORK_DIR/crash-* (leak-*, timeout-*, oom-*) and makes the run fail; reproduce it with
# `TARGET WORK_DIR/crash-…`.
set -euo pipefail
target="$1" corpus="$2" work="$3"
shift 3
rm -rf "$work"
mkdir -p "$work/corpus"
exec "$target" -artifact_prefix="$work/" -print_final_stats=1 "$@" "$work/corpus" "$corpus"
