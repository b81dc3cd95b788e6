#!/usr/bin/python3
"""The public ACE spindle thermal set read with its --map alone and analysed (issue 21 item 5).

bench/data/ace_spindle_thermal holds 18 days, one CSV each. bench/model/run_real_data.sh's run
of it (bench/model/ace_thermal/: one map for every file, --validate sessions) is repeated and
what is deterministic is checked against values computed here from the CSVs: the rows read,
one session per file (held out in turn, each with its file's rows), the declared model's fitted
RMS (least squares of the displacement on the spindle-front temperature over the rows the
analysis fits, the earliest in time), and that the search names session_offset with one offset
per fitted day.

  ace_thermal_e2e.py --nccomp NCCOMP --source SRC --work DIR
"""

import argparse
import csv
import glob
import json
import math
import os
import re
import shutil
import subprocess
import sys


def read_days(source):
    """[(file name relative to source, [(spindle_front_c, dia_disp), …])] in file order."""
    days = []
    for path in sorted(glob.glob(os.path.join(source, "bench/data/ace_spindle_thermal/day*.csv"))):
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
        days.append((os.path.relpath(path, source),
                     [(float(r["Spindle Front"]), float(r["Dia Disp"])) for r in rows]))
    return days


def ols_rms(points):
    """RMS residual of y = a + b x fitted by least squares."""
    n = len(points)
    mx = sum(x for x, _ in points) / n
    my = sum(y for _, y in points) / n
    sxx = sum((x - mx) ** 2 for x, _ in points)
    sxy = sum((x - mx) * (y - my) for x, y in points)
    b = sxy / sxx
    return math.sqrt(sum((y - my - b * (x - mx)) ** 2 for x, y in points) / n)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--nccomp", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--work", required=True)
    args = ap.parse_args()
    out = os.path.join(args.work, "ace_thermal")
    shutil.rmtree(out, ignore_errors=True)

    days = read_days(args.source)
    cmd = [args.nccomp, "analyze"]
    for name, _ in days:
        cmd += ["--log", name]
    cmd += ["--map", "bench/model/ace_thermal/ace.map.toml",
            "--config", "bench/model/ace_thermal/ace.toml", "--validate", "sessions", "--out", out]
    run = subprocess.run(cmd, cwd=args.source, capture_output=True, text=True)
    sys.stdout.write(run.stdout)
    sys.stderr.write(run.stderr)
    if run.returncode != 0:
        sys.exit("nccomp analyze exited %d" % run.returncode)
    with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
        summary = json.load(f)

    failures = []
    n_rows = sum(len(rows) for _, rows in days)
    m = re.search(r"^rows: (\d+) \(fitted (\d+), held out (\d+)\)", run.stdout, re.M)
    if len(days) != 18:
        failures.append("%d day files, expected 18" % len(days))
    if m is None or int(m.group(1)) != n_rows or int(m.group(2)) + int(m.group(3)) != n_rows:
        failures.append("expected 'rows: %d (fitted …, held out …)' in the output" % n_rows)
    if summary["outliers"]:
        failures.append("%d outliers: the expected figures below assume none" %
                        len(summary["outliers"]))

    # One session per file, in file order, each held out with all its rows.
    sessions = summary.get("validation", {}).get("sessions", [])
    expected = [(i + 1, "%s:2" % name, len(rows)) for i, (name, rows) in enumerate(days)]
    got = [(s["session"], s["first_row"], s["rows"]) for s in sessions]
    if got != expected:
        failures.append("validation sessions %s, expected %s" % (got, expected))

    if m is not None and not failures:
        # The files follow one another in time (restarts per file): the fitted rows are the first.
        fitted = int(m.group(2))
        points = [p for _, rows in days for p in rows][:fitted]
        declared = ols_rms(points)
        if abs(summary["declared_rms_um"] - declared) > 1e-3:
            failures.append("declared RMS %.6g um, least squares here %.6g um" %
                            (summary["declared_rms_um"], declared))
        session = [e for e in summary["effects"] if e["name"] == "session_offset"]
        fitted_days = 0
        start = 0
        for _, rows in days:
            fitted_days += start < fitted
            start += len(rows)
        if len(session) != 1:
            failures.append("effects %s: no session_offset" % [e["name"] for e in summary["effects"]])
        elif len(session[0]["params"]["session_offsets"]) != fitted_days:
            failures.append("%d session offsets, expected one per fitted day (%d)" %
                            (len(session[0]["params"]["session_offsets"]), fitted_days))

    # The directory read with the same map: the same files in name order, the same analysis.
    out_dir = out + "_dir"
    shutil.rmtree(out_dir, ignore_errors=True)
    cmd_dir = [args.nccomp, "analyze", "--log", "bench/data/ace_spindle_thermal"] + \
        cmd[cmd.index("--map"):-1] + [out_dir]
    run_dir = subprocess.run(cmd_dir, cwd=args.source, capture_output=True, text=True)
    if run_dir.returncode != 0:
        failures.append("--log DIR --map: exit %d: %s" % (run_dir.returncode, run_dir.stderr))
    else:
        with open(os.path.join(out_dir, "summary.json"), encoding="utf-8") as f:
            if json.load(f) != summary:
                failures.append("--log DIR: summary.json differs from the files listed one by one")
    for f in failures:
        print("FAIL:", f)
    if failures:
        sys.exit(1)
    print("PASS: %d rows of %d days, one session each, session_offset found" % (n_rows, len(days)))


if __name__ == "__main__":
    main()
