#!/usr/bin/python3
"""Issue 22's S3 targets, checked on bench_calib_shift's JSON rows (one object per line, read
from stdin): for every strategy, on X and Y, the mean RMS over the five shifts ("all") against
0.5 x that of hourly step recalibration, and the largest first-hour error against half of
today's (hourly step's: before the first touch no strategy of today corrects anything).

  build/release/bench/calib/bench_calib_shift --json | bench/calib/s3_targets.py

Prints a markdown table; exit status 0 when some strategy meets every target, 1 otherwise.
"""
import json
import sys

rows = {}
for n, line in enumerate(sys.stdin, 1):
    line = line.strip()
    if not line:
        continue
    try:
        r = json.loads(line)
        if r["shift"] == "all":
            rows[(r["strategy"], r["axis"])] = (float(r["rms_um"]), float(r["first_hour_max_um"]))
    except (ValueError, KeyError, TypeError) as e:
        sys.exit("s3_targets: stdin line %d: not a bench_calib_shift row (%s)" % (n, e))

ref = "hourly, step"
if (ref, "X") not in rows or (ref, "Y") not in rows:
    sys.exit("s3_targets: no '%s' rows for X and Y on stdin" % ref)
print("| strategy | X RMS / step | Y RMS / step | X first hour / today | Y first hour / today | all met |")
print("| --- | --- | --- | --- | --- | --- |")
any_met = False
for strategy in dict.fromkeys(s for s, _ in rows):
    if (strategy, "X") not in rows or (strategy, "Y") not in rows:
        continue
    ratios = []
    for kind in (0, 1):
        for axis in ("X", "Y"):
            ratios.append(rows[(strategy, axis)][kind] / rows[(ref, axis)][kind])
    met = all(r <= 0.5 for r in ratios)
    any_met = any_met or met
    print("| %s | %s | %s |" % (strategy, " | ".join("%.3f" % r for r in ratios),
                                 "yes" if met else "no"))
sys.exit(0 if any_met else 1)
