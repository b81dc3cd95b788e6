#!/usr/bin/python3
"""A workbook read by `nccomp analyze --map` after docs/analyze.md's conversion (issue 21).

A two-sheet .xlsx (a title row above the column names, text tool ids, values with more digits
than a sheet shows) is made by ssconvert from two CSVs, converted back to one CSV per sheet by
the exact command docs/analyze.md gives ("Spreadsheets"), and analysed with a --map alone. The
rows read and each tool's fitted offset (the mean of its values, computed here) are checked.

  spreadsheet_e2e.py --nccomp NCCOMP --source SRC --work DIR
"""

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib

# Sheet name -> (text id of its tool, tool number the id gives, values [um]).
SHEETS = {
    "Steel": ("T1", 1, [10.123456789012345, 10.5, 9.876543210987654, 10.25, 10.000012345678,
                        10.0625, 9.9, 10.4]),
    "Alu": ("T7", 7, [20.5, 21.25, 19.75, 20.015625, 20.999999999, 19.5, 20.25, 20.125]),
}

MAP = """\
# A title line above the names.
header_rows = 2
[columns]
tool = "tool"
time_s = "cut"
measured_um = "wear_um"
[ids]
tool = "digits"
[constant]
kind = "tool_wear"
"""

CONFIG = """\
[model]
heldout_fraction = 0.25
# The offsets only: the check is what was read, not the search.
max_effects = 0
[[model.term]]
name = "offset"
form = "constant"
per = ["tool"]
"""


def documented_command(source):
    """The ssconvert command of docs/analyze.md's "Spreadsheets" section, as an argv."""
    with open(os.path.join(source, "docs", "analyze.md"), encoding="utf-8") as f:
        text = f.read()
    section = text.split("### Spreadsheets", 1)[1]
    block = re.search(r"```\n(ssconvert .*?)```", section, re.S)
    if block is None:
        sys.exit("no ssconvert command block in docs/analyze.md, Spreadsheets")
    return shlex.split(block.group(1).replace("\\\n", " "))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--nccomp", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--work", required=True)
    args = ap.parse_args()
    if shutil.which("ssconvert") is None:
        sys.exit("ssconvert not found: scripts/setup installs gnumeric")

    work = os.path.join(args.work, "spreadsheet")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)

    # The workbook: one sheet per CSV, named after the file (no extension, so the sheet name
    # is the bare name).
    for sheet, (tool_id, _, values) in SHEETS.items():
        with open(os.path.join(work, sheet), "w", encoding="utf-8") as f:
            f.write("Flank wear test, lab 2\ntool,cut,wear_um\n")
            for i, v in enumerate(values):
                f.write("%s,%d,%r\n" % (tool_id, i + 1, v))
    subprocess.run(["ssconvert", "-I", "Gnumeric_stf:stf_csvtab", "--merge-to=wear.xlsx"] +
                   list(SHEETS), cwd=work, check=True, capture_output=True)
    for sheet in SHEETS:
        os.remove(os.path.join(work, sheet))

    cmd = documented_command(args.source)
    assert "wear.xlsx" in cmd and "wear-%s.csv" in cmd, cmd
    subprocess.run(cmd, cwd=work, check=True, capture_output=True)
    logs = ["wear-%s.csv" % s for s in SHEETS]
    for log in logs:
        if not os.path.exists(os.path.join(work, log)):
            sys.exit("the documented command wrote no %s (files: %s)" % (log, os.listdir(work)))

    with open(os.path.join(work, "wear.map.toml"), "w") as f:
        f.write(MAP)
    with open(os.path.join(work, "config.toml"), "w") as f:
        f.write(CONFIG)
    run = subprocess.run([args.nccomp, "analyze", "--log", logs[0], "--log", logs[1],
                          "--map", "wear.map.toml", "--config", "config.toml", "--out", "out"],
                         cwd=work, capture_output=True, text=True)
    sys.stdout.write(run.stdout)
    sys.stderr.write(run.stderr)
    if run.returncode != 0:
        sys.exit("nccomp analyze exited %d" % run.returncode)

    failures = []
    n_rows = sum(len(v) for _, _, v in SHEETS.values())
    if not re.search(r"^rows: %d \(" % n_rows, run.stdout, re.M):
        failures.append("expected 'rows: %d' in analyze's output" % n_rows)
    with open(os.path.join(work, "out", "model.toml"), "rb") as f:
        model = tomllib.load(f)
    offset = [t for t in model["model"]["term"] if t["name"] == "offset"]
    if len(offset) != 1:
        failures.append("model.toml: %d offset terms" % len(offset))
    else:
        fitted = dict(zip((int(g[0]) for g in offset[0]["groups"]), offset[0]["coef_um"]))
        expected = {number: sum(v) / len(v) for _, number, v in SHEETS.values()}
        if sorted(fitted) != sorted(expected):
            failures.append("tools %s, expected %s" % (sorted(fitted), sorted(expected)))
        for tool, mean in expected.items():
            if tool in fitted and abs(fitted[tool] - mean) > 1e-9:
                failures.append("tool %d offset %.12g um, expected the mean %.12g um" %
                                (tool, fitted[tool], mean))
    for f in failures:
        print("FAIL:", f)
    if failures:
        sys.exit(1)
    print("PASS: %d rows of 2 sheets, each tool's offset its mean" % n_rows)


if __name__ == "__main__":
    main()
