#!/usr/bin/env bash
# Derives day01.csv … day18.csv of this folder from the two workbooks of the source repository
# (SOURCE.md): each sheet of ACE_X.xlsx (temperatures) beside the same sheet of ACE_Y.xlsx
# (displacement), with a sample counter in front.
#   derive.sh ACE_X.xlsx ACE_Y.xlsx OUT_DIR
set -euo pipefail
[ $# -eq 3 ] || { echo "usage: $0 ACE_X.xlsx ACE_Y.xlsx OUT_DIR" >&2; exit 2; }
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
# docs/analyze.md's "Spreadsheets" command: one CSV per sheet, values as stored.
for w in X Y; do
  src="$1"
  [ "$w" = Y ] && src="$2"
  ssconvert -S -T Gnumeric_stf:stf_assistant \
    -O 'separator=, format=raw locale=C charset=UTF-8 eol=unix quoting-mode=auto' \
    "$src" "$tmp/$w-%n.csv" 2>/dev/null
done
mkdir -p "$3"
n=0
while [ -f "$tmp/X-$n.csv" ]; do
  paste -d, "$tmp/X-$n.csv" "$tmp/Y-$n.csv" |
    awk 'NR == 1 { print "sample," $0; next } { print NR - 1 "," $0 }' \
      > "$3/$(printf 'day%02d.csv' $((n + 1)))"
  n=$((n + 1))
done
echo "$n days in $3"
