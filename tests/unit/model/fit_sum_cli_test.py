#!/usr/bin/python3
"""`nccomp fit-sum` run as a process: the [[input_sums]] and [[input_lags]] it prints, parsed and
checked against the generating model (lags computed here, as nccompd computes them), and its
errors (exit status, message).

Run by ctest (tests/unit/model/CMakeLists.txt) with /usr/bin/python3 (Debian's numpy):
    fit_sum_cli_test.py --nccomp build/x/tools/nccomp [unittest args, e.g. FitSum]
"""
import os
import subprocess
import sys
import tempfile
import tomllib
import unittest

import numpy as np

NCCOMP = None

MAP = """
[columns]
time_s = "t"
measured_um = "y"
point = "p"
[constant]
kind = "calib"
[extra]
a = "a"
b = "b"
speed = "speed"
"""


def lag(t, x, tau):
    """nccompd's first-order lag: started at the first value, the input held between samples."""
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, len(x)):
        y[i] = y[i - 1] + (1.0 - np.exp(-(t[i] - t[i - 1]) / tau)) * (x[i - 1] - y[i - 1])
    return y


class Case(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        rng = np.random.default_rng(7)
        n = 2400
        self.t = np.arange(n) * 15.0
        self.a = 20.0 + np.cumsum(rng.normal(0, 0.05, n))
        self.b = 22.0 + 0.5 * np.sin(self.t / 3000.0) + rng.normal(0, 0.02, n)
        self.speed = np.repeat(rng.choice([0.0, 2.0, 4.0, 6.0], n // 200), 200)
        self.y = (5.0 + 2.0 * self.a - 1.0 * self.b + 3.0 * lag(self.t, self.speed, 900.0)
                  + rng.normal(0, 0.1, n))
        self.log = os.path.join(self.dir.name, "log.csv")
        with open(self.log, "w") as f:
            f.write("t,y,a,b,speed,p\n")
            for i, row in enumerate(zip(self.t, self.y, self.a, self.b, self.speed)):
                f.write(",".join("%.6f" % v for v in row) + ",%d\n" % (i % 3))
            f.write("%.1f,,1,1,1,0\n" % (n * 15.0))  # a row without a measurement
        self.map = os.path.join(self.dir.name, "m.toml")
        with open(self.map, "w") as f:
            f.write(MAP)

    def tearDown(self):
        self.dir.cleanup()

    def run_fit(self, *args):
        p = subprocess.run([NCCOMP, "fit-sum", "--log", self.log, "--map", self.map, *args],
                           capture_output=True, text=True, timeout=120)
        return p.returncode, p.stdout, p.stderr


class FitSum(Case):
    def test_the_sum_and_its_lag_reproduce_the_generating_model(self):
        code, out, err = self.run_fit("--input", "a=1", "--input", "b=2", "--source", "speed=9",
                                      "--lag", "speed:900=40", "--sensor", "50",
                                      "--lambda", "1e-7", "--lambda", "1e-3")
        self.assertEqual(code, 0, err)
        doc = tomllib.loads(out)
        self.assertEqual(doc["input_lags"], [{"sensor": 40, "input_sensor": 9, "tau_s": 900}])
        s = doc["input_sums"][0]
        self.assertEqual(s["sensor"], 50)
        self.assertEqual(s["inputs"], [1, 2, 40])
        w = s["weights"]
        self.assertAlmostEqual(w[0], 2.0, delta=0.05)
        self.assertAlmostEqual(w[1], -1.0, delta=0.05)
        self.assertAlmostEqual(w[2], 3.0, delta=0.05)
        # The printed sum, computed as nccompd would, predicts the log to its noise.
        p = s["offset"] + w[0] * self.a + w[1] * self.b + w[2] * lag(self.t, self.speed, 900.0)
        self.assertLess(float(np.sqrt(np.mean((self.y - p) ** 2))), 0.12)
        self.assertIn("1 rows with an empty cell left out", out)
        self.assertIn("lambda 1e-07, chosen by the rolling-origin error", out)

    def test_before_fits_the_earlier_rows_only(self):
        code, out, err = self.run_fit("--input", "a=1", "--sensor", "50", "--before", "15000")
        self.assertEqual(code, 0, err)
        self.assertIn("on 1000 rows", out)

    def test_point_fits_that_point_only(self):
        code, out, err = self.run_fit("--input", "a=1", "--sensor", "50", "--point", "1",
                                      "--before", "15000")
        self.assertEqual(code, 0, err)
        self.assertIn("on 333 rows", out)


class Directories(Case):
    """--log DIR as `nccomp analyze` takes it."""

    def sum_of(self, log, *extra):
        p = subprocess.run([NCCOMP, "fit-sum", "--log", log, *extra, "--input", "a=1",
                            "--input", "b=2", "--sensor", "50"],
                           capture_output=True, text=True, timeout=120)
        self.assertEqual(p.returncode, 0, p.stderr)
        return p.stdout

    def test_a_directory_of_foreign_logs_is_its_csv_files_in_name_order(self):
        whole = self.sum_of(self.log, "--map", self.map)
        d = os.path.join(self.dir.name, "days")
        os.mkdir(d)
        with open(self.log) as f:
            lines = f.readlines()
        for name, part in (("day1.csv", lines[1:1201]), ("day2.csv", lines[1201:])):
            with open(os.path.join(d, name), "w") as f:
                f.write(lines[0] + "".join(part))
        with open(os.path.join(d, "notes.txt"), "w") as f:
            f.write("not a log\n")
        self.assertEqual(self.sum_of(d, "--map", self.map), whole)

    def test_a_directory_of_nccompd_logs_is_its_logs_with_their_rotated_files_oldest_first(self):
        # nccompd's log (v1 columns): rotated into measurements.csv.1, then the current file.
        header = ("time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,"
                  "measured_um,applied_um,a,b\n")
        rows = ["%.6f,,,calib,0,,,,,,,%.6f,0,%.6f,%.6f\n" % (t, y, a, b)
                for t, y, a, b in zip(self.t, self.y, self.a, self.b)]
        single = os.path.join(self.dir.name, "single.csv")
        with open(single, "w") as f:
            f.write(header + "".join(rows))
        d = os.path.join(self.dir.name, "log")
        os.mkdir(d)
        with open(os.path.join(d, "measurements.csv.1"), "w") as f:
            f.write(header + "".join(rows[:1500]))
        with open(os.path.join(d, "measurements.csv"), "w") as f:
            f.write(header + "".join(rows[1500:]))
        whole = self.sum_of(single)
        self.assertIn("on 2400 rows", whole)
        self.assertEqual(self.sum_of(d).replace(d, single), whole)


class BadInput(Case):
    def check(self, code_expected, text, *args):
        code, out, err = self.run_fit(*args)
        self.assertEqual(code, code_expected, out + err)
        self.assertIn(text, err)

    def test_errors_name_what_is_wrong(self):
        self.check(3, "zz: the model uses this extra column but the mapping's [extra] does not name it",
                   "--input", "zz=1", "--sensor", "50")
        self.check(2, "sensor 1 is used twice", "--input", "a=1", "--input", "b=1", "--sensor", "50")
        self.check(2, "is used twice (or is the --sensor of the sum)", "--input", "a=50",
                   "--sensor", "50")
        self.check(2, "needs an --input or --source", "--input", "a=1", "--lag", "speed:900=40",
                   "--sensor", "50")
        self.check(2, "expected COLUMN:TAU_S=SENSOR with TAU_S > 0", "--input", "a=1",
                   "--source", "speed=9", "--lag", "speed:-5=40", "--sensor", "50")
        self.check(2, "the sensor must be a number 0..255", "--input", "a=300", "--sensor", "50")
        many = []
        for k in range(33):
            many += ["--lag", "speed:%d=%d" % (100 + k, 100 + k)]
        self.check(2, "34 inputs and lags: an [[input_sums]] takes at most 32", "--input", "a=1",
                   "--source", "speed=9", *many, "--sensor", "50")
        self.check(3, "at least 8 needed", "--input", "a=1", "--sensor", "50", "--before", "60")

    def test_logs_of_two_machines_are_refused_naming_them(self):
        d = os.path.join(self.dir.name, "fleet")
        os.mkdir(d)
        for m in ("m1", "m2"):
            with open(os.path.join(d, m + ".csv"), "w") as f:
                f.write("machine,utc,session,time_s,measured_um\n%s,2026-11-29T00:00:00Z,0,0,1\n" % m)
        p = subprocess.run([NCCOMP, "fit-sum", "--log", d, "--input", "a=1", "--sensor", "50"],
                           capture_output=True, text=True, timeout=120)
        self.assertEqual(p.returncode, 3, p.stdout + p.stderr)
        self.assertIn("the logs are of 2 machines (m1, m2): fit-sum fits one machine's log",
                      p.stderr)

    def test_a_directory_without_logs_is_named(self):
        empty = os.path.join(self.dir.name, "empty")
        os.mkdir(empty)
        self.check(3, empty + ": no *.csv file in the directory", "--input", "a=1",
                   "--sensor", "50", "--log", empty)


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) >= 2 and args[0] == "--nccomp":
        NCCOMP = args[1]
        args = args[2:]
    unittest.main(argv=[sys.argv[0], *args])
