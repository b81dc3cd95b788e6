#!/usr/bin/python3
"""`nccomp grind-path` itself (issue 5): the operator's command run as a process, its report and
the files it writes parsed and checked against numbers derived here independently (closed forms,
or brute force with numpy), its errors checked for exit status and message.

Run by ctest (tests/unit/grind/CMakeLists.txt) with /usr/bin/python3 (Debian's numpy):
    grind_path_cli_test.py --nccomp build/x/tools/nccomp/nccomp [unittest args, e.g. Crown]
"""
import math
import os
import re
import subprocess
import sys
import tempfile
import unittest

import numpy as np

NCCOMP = None


def run(*args, cwd=None):
    p = subprocess.run([NCCOMP, "grind-path", *args], capture_output=True, text=True, cwd=cwd,
                       timeout=600)
    return p.returncode, p.stdout, p.stderr


def rise(s, r):
    """g(s) = R − sqrt(R² − s²), written without cancellation (as core/grind/wheel.hpp)."""
    return s * s / (r + np.sqrt(r * r - s * s))


def radius(w, h):
    return h / 2 + w * w / (8 * h)


def verification_rows(out):
    """{'usual practice (T follows P)': (max, rms, gouge, left, z), ...} from the report."""
    rows = {}
    for name in ("usual practice (T follows P)", "three-case rule", "exact envelope",
                 "G-code polyline"):
        m = re.search(re.escape(name) + r"\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)",
                      out)
        assert m, f"no verification row '{name}' in:\n{out}"
        rows[name] = tuple(float(v) for v in m.groups())
    return rows


def every_sample_rows(out):
    """{'usual practice (T follows P)': (max, rms, gouge, left, z), 'exact envelope': ...} from the
    verification on every sample (printed after the polyline verification)."""
    tail = out[out.index("verification on every sample"):]
    rows = {}
    for name in ("usual practice (T follows P)", "exact envelope"):
        m = re.search(re.escape(name) + r"\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)",
                      tail)
        assert m, f"no every-sample row '{name}' in:\n{out}"
        rows[name] = tuple(float(v) for v in m.groups())
    return rows


def section(out, title):
    """The region lines printed under a report title, up to the next unindented line."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    body = []
    for line in lines[start + 1:]:
        if not line.startswith("    "):
            break
        body.append(line)
    return body


REGION = re.compile(r"z\s+([-\d.]+) \.\.\s+([-\d.]+) mm\s+worst\s+([-\d.]+) um at z\s+([-\d.]+) mm"
                    r"\s+cause:(.*)")


def regions(lines):
    out = []
    for line in lines:
        m = REGION.search(line)
        if m:
            out.append((float(m[1]), float(m[2]), float(m[3]), float(m[4]), m[5].strip()))
    return out


def read_csv(path):
    with open(path) as f:
        header = f.readline().strip().split(",")
        data = np.loadtxt(f, delimiter=",", ndmin=2)
    return header, data


def read_gcode(path):
    comments, blocks = [], []
    with open(path) as f:
        for line in f:
            line = line.rstrip("\n")
            if line.startswith(";"):
                comments.append(line)
                continue
            m = re.fullmatch(r"N(\d+)( G90)? G01 Z(-?\d+\.\d{4}) X(-?\d+\.\d{4})( F[\d.]+)?", line)
            assert m, f"not a block: {line!r}"
            blocks.append((int(m[1]), m[2] is not None, float(m[3]), float(m[4]), m[5]))
    return comments, blocks


def polyline_vs_trajectory(blocks, traj):
    """(below, above) in mm: how far the G-code polyline lies under / over the trajectory rows."""
    z = np.array([b[2] for b in blocks])
    u = np.array([b[3] for b in blocks])
    inside = (traj[:, 0] >= z[0] - 1e-9) & (traj[:, 0] <= z[-1] + 1e-9)
    d = np.interp(traj[inside, 0], z, u) - traj[inside, 1]
    return max(0.0, -d.min()), max(0.0, d.max())


class Crown(unittest.TestCase):
    """The seed's crown: 0.6 mm over ±500 mm, W = 150 mm, h = 0.5 mm (spacing 0.05 mm)."""

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.TemporaryDirectory()
        d = cls.dir.name
        cls.traj, cls.table, cls.gcode = (os.path.join(d, n) for n in ("t.csv", "tab.csv", "c.nc"))
        cls.rc, cls.out, cls.err = run(
            "--family", "convex", "--height-mm", "0.6", "--z-from-mm", "-500", "--z-to-mm", "500",
            "--spacing-mm", "0.05", "--wheel-width-mm", "150", "--arc-height-mm", "0.5",
            "--trajectory-out", cls.traj, "--table-out", cls.table, "--table-spacing-mm", "25",
            "--gcode-out", cls.gcode, "--feed-mm-min", "300")
        cls.r = radius(150.0, 0.5)
        cls.a = 0.6 / 500.0**2  # P = 0.6 − a·z²

    @classmethod
    def tearDownClass(cls):
        cls.dir.cleanup()

    def test_exit_and_report(self):
        self.assertEqual(self.rc, 0, self.err)
        self.assertEqual(self.err, "")
        self.assertIn("profile: family convex, 20001 samples, z -500.0000 .. 500.0000 mm", self.out)
        self.assertIn("R 5625.25 mm", self.out)
        self.assertIn("exact envelope: 23001 points, z -575.0000 .. 575.0000 mm", self.out)
        self.assertIn("tangent 20001, front end 0, rear end 0 samples", self.out)
        # Convex and gentle: the rule is exact, nothing is unreachable.
        self.assertEqual(section(self.out, "three-case rule vs exact"), ["    none above 0.1 um"])
        self.assertEqual(section(self.out, "unreachable"), ["    none above 0.1 um"])

    def test_usual_practice_errs_like_the_closed_form(self):
        # T follows P: near the end T stops at z = 500 and the wheel there cuts
        # e(z) = P(z) − P(500) − g(500 − z), largest at z* = 500/(1 + 2aR) = 486.85 mm; the
        # evaluation points are 0.5 mm apart, the nearest is z = ±487.
        rows = verification_rows(self.out)
        usual = rows["usual practice (T follows P)"]
        e487 = (self.a * (500.0**2 - 487.0**2) - rise(13.0, self.r)) * 1000.0
        self.assertAlmostEqual(e487, 15.7728, delta=1e-4)
        self.assertAlmostEqual(usual[0], e487, delta=1.5e-4)  # max |B − P|
        self.assertAlmostEqual(usual[2], e487, delta=1.5e-4)  # all of it a gouge
        self.assertEqual(usual[3], 0.0)  # nothing left
        self.assertAlmostEqual(abs(usual[4]), 487.0, delta=1e-9)

    def test_every_sample_verification(self):
        # The same paths checked at all 20001 samples: T at the grid points only (no chords), and
        # z* = 486.85 mm is a sample here, so the usual practice's maximum is the closed form
        # e(z*) = 15.7748 um itself; the exact envelope grinds P at every sample.
        self.assertIn("verification on every sample (independent: B at all 20001 profile samples",
                      self.out)
        self.assertIn("the polyline check above is at 2001 points):", self.out)
        rows = every_sample_rows(self.out)
        usual = rows["usual practice (T follows P)"]
        zs = 500.0 / (1.0 + 2.0 * self.a * self.r)
        e_star = (self.a * (500.0**2 - zs**2) - rise(500.0 - zs, self.r)) * 1000.0
        self.assertAlmostEqual(e_star, 15.7748, delta=1e-4)
        self.assertAlmostEqual(usual[0], e_star, delta=1e-4)
        self.assertAlmostEqual(usual[2], e_star, delta=1e-4)
        self.assertEqual(usual[3], 0.0)
        self.assertAlmostEqual(abs(usual[4]), 486.85, delta=1e-9)
        # RMS over every sample against numpy: B = min over grid positions within W/2, here at
        # every 20th sample (each a window of 3001 positions).
        z = -500.0 + 0.05 * np.arange(20001)
        p = 0.6 * (1.0 - (z / 500.0) ** 2)
        b = np.array([np.min(p[max(0, i - 1500):i + 1501]
                             + rise(z[max(0, i - 1500):i + 1501] - z[i], self.r))
                      for i in range(0, 20001, 20)])
        d = (b - p[::20]) * 1000.0
        self.assertAlmostEqual(usual[1], math.sqrt(np.mean(d * d)), delta=0.01)
        exact = rows["exact envelope"]
        self.assertLessEqual(exact[0], 1e-4)

    def test_exact_envelope_at_sampling_resolution(self):
        # Chords of the sampled path sag by at most Δ²/(8R) = 0.05²/(8·5625) mm = 5.6e-5 µm.
        rows = verification_rows(self.out)
        for name in ("exact envelope", "three-case rule"):
            self.assertLessEqual(rows[name][0], 1e-3, name)
            self.assertLessEqual(rows[name][2], 1e-3, name)

    def test_trajectory_file_is_the_envelope(self):
        header, t = read_csv(self.traj)
        self.assertEqual(header, ["z_mm", "u_mm"])
        self.assertEqual(len(t), 23001)
        np.testing.assert_allclose(t[:, 0], -575.0 + 0.05 * np.arange(23001), atol=1e-7)
        np.testing.assert_allclose(t[:, 1], t[::-1, 1], atol=1e-7)  # symmetric crown
        self.assertAlmostEqual(t[11500, 1], 0.6, delta=1e-7)  # top: lowest point on the crown
        self.assertAlmostEqual(t[0, 1], -0.5, delta=1e-7)  # overhanging W/2: arc end on the edge
        # Brute force U_T(Z) = max over samples within W/2 of P(z) − g(z − Z) at 300 rows.
        z = -500.0 + 0.05 * np.arange(20001)
        p = 0.6 * (1.0 - (z / 500.0) ** 2)
        rng = np.random.default_rng(5)
        for row in rng.integers(0, 23001, 300):
            zt = t[row, 0]
            near = np.abs(z - zt) <= 75.0 + 1e-9
            brute = np.max(p[near] - rise(z[near] - zt, self.r))
            self.assertAlmostEqual(t[row, 1], brute, delta=1e-7, msg=f"z {zt}")

    def test_table_file_and_its_interpolation_error(self):
        header, tab = read_csv(self.table)
        self.assertEqual(header, ["z_mm", "u_target_mm", "u_wheel_mm", "correction_um"])
        self.assertEqual(len(tab), 41)
        np.testing.assert_allclose(tab[:, 0], -500.0 + 25.0 * np.arange(41), atol=1e-9)
        np.testing.assert_allclose(tab[:, 1], 0.6 * (1 - (tab[:, 0] / 500.0) ** 2), atol=1e-6)
        np.testing.assert_allclose(tab[:, 3], (tab[:, 2] - tab[:, 1]) * 1000.0, atol=2e-3)
        # At the roll's end the correction is the largest gouge of the usual practice,
        # e(z*) = a(500² − z*²) − g(500 − z*) = 15.775 µm (the envelope there touches z*).
        zs = 500.0 / (1.0 + 2.0 * self.a * self.r)
        e_star = (self.a * (500.0**2 - zs**2) - rise(500.0 - zs, self.r)) * 1000.0
        self.assertAlmostEqual(tab[0, 3], e_star, delta=6e-4)
        self.assertAlmostEqual(tab[-1, 3], e_star, delta=6e-4)
        # u_wheel is the trajectory at the row's z; the reported interpolation error is what
        # interpolating the rows linearly misses on the trajectory inside the roll.
        _, t = read_csv(self.traj)
        np.testing.assert_allclose(np.interp(tab[:, 0], t[:, 0], t[:, 1]), tab[:, 2], atol=1e-6)
        inside = np.abs(t[:, 0]) <= 500.0 + 1e-9
        err_um = np.max(np.abs(np.interp(t[inside, 0], tab[:, 0], tab[:, 2]) - t[inside, 1])) * 1e3
        m = re.search(r"table: .* \(41 rows every 25 mm; linear interpolation between rows errs by "
                      r"up to ([\d.]+) um\)", self.out)
        self.assertIsNotNone(m, self.out)
        self.assertAlmostEqual(float(m[1]), err_um, delta=2e-3)
        self.assertGreater(float(m[1]), 0.1)  # rows 25 mm apart on a curved path: not zero

    def test_gcode_file_within_the_reported_chord_error(self):
        m = re.search(r"G-code: (\d+) linear moves, max chord error ([\d.]+) um \(([\d.]+) below, "
                      r"([\d.]+) above the trajectory; tolerance 1 um above only: gouge-free, "
                      r"4 decimals\) -> (\S+)", self.out)
        self.assertIsNotNone(m, self.out)
        moves, chord, below, above = int(m[1]), float(m[2]), float(m[3]), float(m[4])
        comments, blocks = read_gcode(self.gcode)
        self.assertEqual(comments[1], f"; wheel W 150 mm, h 0.5 mm; {moves} moves, "
                                      f"max chord error {chord:.4f} um")
        self.assertEqual(len(blocks), moves + 1)
        self.assertEqual([b[0] for b in blocks], list(range(10, 10 * (moves + 1) + 1, 10)))
        self.assertTrue(blocks[0][1] and blocks[0][4] == " F300.0")
        self.assertFalse(any(b[1] or b[4] for b in blocks[1:]))
        self.assertEqual((blocks[0][2], blocks[-1][2]), (-575.0, 575.0))
        # The polyline as written against every trajectory row (7 decimals: ±1e-7 mm).
        _, t = read_csv(self.traj)
        poly_below, poly_above = polyline_vs_trajectory(blocks, t)
        self.assertLessEqual(poly_below, 1e-7)  # gouge-free band
        self.assertEqual(below, 0.0)
        self.assertAlmostEqual(poly_above * 1e3, above, delta=2e-4)  # the reported figure is real
        self.assertAlmostEqual(chord, above, delta=1e-9)
        self.assertLessEqual(chord, 1.0)
        self.assertGreater(chord, 0.3)  # the band is used, not wasted on tiny moves
        # What the wheel leaves following the polyline: never a gouge, at most the chord error.
        g = verification_rows(self.out)["G-code polyline"]
        self.assertEqual(g[2], 0.0)
        self.assertLessEqual(g[3], chord + 1e-4)


class ConcaveTighterThanWheel(unittest.TestCase):
    """Sine 0.1 mm / 100 mm over 0..300 mm: valleys of radius 1/(A·k²) = 2533 mm < R = 5625 mm."""

    @classmethod
    def setUpClass(cls):
        cls.rc, cls.out, cls.err = run(
            "--family", "sine", "--amplitude-mm", "0.1", "--wavelength-mm", "100", "--z-from-mm",
            "0", "--z-to-mm", "300", "--spacing-mm", "0.05", "--wheel-width-mm", "150",
            "--arc-height-mm", "0.5", "--verify-points", "601")

    def test_unreachable_regions_reported_with_brute_force_depth(self):
        self.assertEqual(self.rc, 0, self.err)
        reg = regions(section(self.out, "unreachable by this wheel"))
        self.assertEqual(len(reg), 3, self.out)
        by_z = sorted(reg)
        for (z_from, z_to, _, _, cause), valley in zip(by_z, (25.0, 125.0, 225.0)):
            self.assertLess(z_from, valley)
            self.assertGreater(z_to, valley)
            self.assertIn("concave radius 2533 mm < R", cause)
            self.assertEqual("profile end (wheel overhangs)" in cause, valley != 125.0, cause)
        # The middle valley by brute force: U_T on the grid near it (max over the window), then
        # B(125) = min over wheel positions of U_T + g; what is left is B − P.
        dz, r = 0.05, radius(150.0, 0.5)
        z = dz * np.arange(6001)
        p = 0.1 * np.sin(2 * np.pi * (z - 150.0) / 100.0)
        zt = 125.0 + dz * np.arange(-1500, 1501)
        ut = np.array([np.max(p[np.abs(z - t) <= 75.0 + 1e-9]
                              - rise(z[np.abs(z - t) <= 75.0 + 1e-9] - t, r)) for t in zt])
        left_um = (np.min(ut + rise(125.0 - zt, r)) - p[2500]) * 1000.0
        middle = by_z[1]
        self.assertAlmostEqual(middle[2], left_um, delta=1e-4)
        self.assertAlmostEqual(middle[3], 125.0, delta=1e-9)
        self.assertAlmostEqual(left_um, 51.56, delta=0.01)
        # The envelope's own verification: no gouge beyond the sag of its chords between grid
        # points (arcs of radius R: Δ²/(8R) = 5.6e-5 µm, printed to 1e-4 µm), and the same
        # material left at z = 125.
        rows = verification_rows(self.out)
        self.assertLessEqual(rows["exact envelope"][2], 2e-4)
        self.assertAlmostEqual(rows["exact envelope"][3], left_um, delta=2e-4)
        self.assertAlmostEqual(rows["exact envelope"][4], 125.0, delta=1e-9)

    def test_rule_gouges_and_says_why(self):
        m = re.search(r"rule below envelope \(gouges\) by up to ([\d.]+) um", self.out)
        self.assertGreater(float(m[1]), 100.0)
        reg = regions(section(self.out, "three-case rule vs exact"))
        self.assertGreater(len(reg), 0)
        for r in reg:
            self.assertIn("concave radius 2533 mm < R", r[4])
        rows = verification_rows(self.out)
        self.assertGreater(rows["three-case rule"][2], 100.0)  # the verification sees it too
        self.assertGreater(rows["usual practice (T follows P)"][2], 50.0)


class StraightGrindingLine(unittest.TestCase):
    """h = 0: the wheel's grinding line is straight (R = ∞), the contact is always an end."""

    def test_flank_from_csv(self):
        with tempfile.TemporaryDirectory() as d:
            prof = os.path.join(d, "flank.csv")
            z = 0.05 * np.arange(4001)
            p = np.where(z < 80.0, 0.0, np.minimum(z - 80.0, 40.0) * 0.03)
            with open(prof, "w") as f:
                f.write("z_mm,u_mm\n")
                for zi, pi in zip(z, p):
                    f.write(f"{zi:.2f},{pi:.6f}\n")
            traj = os.path.join(d, "t.csv")
            gcode = os.path.join(d, "f.nc")
            rc, out, err = run("--profile", prof, "--wheel-width-mm", "150", "--arc-height-mm", "0",
                               "--verify-points", "401", "--trajectory-out", traj,
                               "--gcode-out", gcode)
            self.assertEqual(rc, 0, err)
            self.assertIn("R inf (straight grinding line), arc end slope 0.000000", out)
            self.assertIn("tangent 0, front end 2400, rear end 1601 samples", out)
            # The rule puts the line's rear end on the flat before the ramp: it lies across the
            # ramp and cuts it down to the flat, 1.2 mm at the top.
            reg = regions(section(out, "three-case rule vs exact"))
            self.assertEqual(len(reg), 1, out)
            self.assertAlmostEqual(reg[0][2], 1200.0, delta=1e-4)
            self.assertIn("steep flank (arc end grinds)", reg[0][4])
            self.assertEqual(section(out, "unreachable"), ["    none above 0.1 um"])
            rows = verification_rows(out)
            self.assertAlmostEqual(rows["three-case rule"][2], 1200.0, delta=1e-4)
            self.assertEqual(rows["exact envelope"][0], 0.0)
            # For a straight line the envelope is the running maximum over the window.
            _, t = read_csv(traj)
            self.assertEqual(len(t), 4001 + 2 * 1500)
            for row in range(0, len(t), 7):
                near = np.abs(z - t[row, 0]) <= 75.0 + 1e-9
                self.assertAlmostEqual(t[row, 1], p[near].max(), delta=1e-7)
            _, blocks = read_gcode(gcode)
            below, above = polyline_vs_trajectory(blocks, t)
            self.assertLessEqual(below, 1e-7)
            self.assertLessEqual(above, 1e-3 + 1e-7)

    def test_straight_profile_closed_form(self):
        # u = 0.2 + 0.004·(z − 50) on 0..100 mm: with the line's front end on it, U_T = P + |b|·W/2
        # inside (the window full of profile), and at the ends the edge sample decides.
        with tempfile.TemporaryDirectory() as d:
            traj = os.path.join(d, "t.csv")
            rc, out, err = run("--family", "straight", "--offset-mm", "0.2", "--slope", "0.004",
                               "--z-from-mm", "0", "--z-to-mm", "100", "--spacing-mm", "0.1",
                               "--wheel-width-mm", "40", "--arc-height-mm", "0",
                               "--trajectory-out", traj)
            self.assertEqual(rc, 0, err)
            _, t = read_csv(traj)
            self.assertEqual(len(t), 1001 + 2 * 200)
            zt, ut = t[:, 0], t[:, 1]
            inside = (zt >= 0.0) & (zt <= 80.0)
            np.testing.assert_allclose(ut[inside], 0.2 + 0.004 * (zt[inside] - 50.0) + 0.004 * 20.0,
                                       atol=1e-7)
            beyond = zt > 80.0  # the front end passes the roll's end: the last sample is highest
            np.testing.assert_allclose(ut[beyond], 0.2 + 0.004 * 50.0, atol=1e-7)
            rows = verification_rows(out)
            self.assertEqual(rows["exact envelope"][0], 0.0)
            # T following P: the line lies at P(Z) across [Z − 20, Z + 20] and cuts the rising
            # profile down to P(z − 20): b·W/2 = 80 µm too deep.
            usual = rows["usual practice (T follows P)"]
            self.assertAlmostEqual(usual[2], 80.0, delta=1e-4)
            self.assertEqual(usual[3], 0.0)
            # The same on every sample (h = 0: g ≡ 0, B is the running minimum of the path):
            # 80 um from z = 20 mm on (where exactly the maximum is found among equal values is
            # up to rounding); RMS by numpy.
            every = every_sample_rows(out)
            self.assertEqual(every["exact envelope"][0], 0.0)
            z = 0.1 * np.arange(1001)
            p = 0.2 + 0.004 * (z - 50.0)
            b = np.array([p[max(0, i - 200):i + 201].min() for i in range(1001)])
            d = (b - p) * 1000.0
            self.assertAlmostEqual(every["usual practice (T follows P)"][0], 80.0, delta=1e-4)
            self.assertAlmostEqual(every["usual practice (T follows P)"][1],
                                   math.sqrt(np.mean(d * d)), delta=1e-4)
            self.assertGreaterEqual(every["usual practice (T follows P)"][4], 20.0 - 1e-9)

    def test_every_sample_check_alone(self):
        # --verify-points 0 skips the polyline check only; --no-verify-samples the other one.
        args = ["--family", "straight", "--slope", "0.004", "--z-from-mm", "0", "--z-to-mm",
                "100", "--spacing-mm", "0.1", "--wheel-width-mm", "40", "--arc-height-mm", "0"]
        rc, out, err = run(*args, "--verify-points", "0")
        self.assertEqual(rc, 0, err)
        self.assertNotIn("brute force over path segments", out)
        self.assertIn("the rule's path and the G-code are\n  checked at --verify-points):", out)
        self.assertAlmostEqual(every_sample_rows(out)["usual practice (T follows P)"][2], 80.0,
                               delta=1e-4)
        rc, out, err = run(*args, "--no-verify-samples")
        self.assertEqual(rc, 0, err)
        self.assertIn("brute force over path segments", out)
        self.assertNotIn("verification on every sample", out)


class LocalMethod(unittest.TestCase):
    def test_outputs_follow_the_rule_with_contact_cases(self):
        with tempfile.TemporaryDirectory() as d:
            traj = os.path.join(d, "t.csv")
            rc, out, err = run("--family", "convex", "--height-mm", "0.6", "--z-from-mm", "-500",
                               "--z-to-mm", "500", "--spacing-mm", "0.5", "--wheel-width-mm", "150",
                               "--arc-height-mm", "0.5", "--method", "local",
                               "--trajectory-out", traj, "--verify-points", "0",
                               "--no-verify-samples")
            self.assertEqual(rc, 0, err)
            self.assertIn("outputs (local trajectory):", out)
            self.assertNotIn("verification", out)
            header, t = read_csv(traj)
            self.assertEqual(header, ["z_mm", "u_mm", "contact"])
            self.assertEqual(len(t), 2001)
            self.assertTrue(np.all(t[:, 2] == 1))
            # Tangent contact: Z_T = z − R·sin a, U_T = u − R(1 − cos a), a = atan P'(z).
            r = radius(150.0, 0.5)
            z = -500.0 + 0.5 * np.arange(2001)
            a = np.arctan(-2.0 * 0.6 / 500.0**2 * z)
            np.testing.assert_allclose(t[:, 0], z - r * np.sin(a), atol=1e-7)
            np.testing.assert_allclose(t[:, 1], 0.6 * (1 - (z / 500) ** 2) - r * (1 - np.cos(a)),
                                       atol=1e-7)


class BadInput(unittest.TestCase):
    FAMILY = ["--family", "convex", "--height-mm", "0.6", "--z-from-mm", "-50", "--z-to-mm", "50",
              "--spacing-mm", "0.5"]

    def refused(self, args, status, message, files=()):
        rc, out, err = run(*args)
        self.assertEqual(rc, status, err)
        self.assertEqual(out, "")  # nothing printed before the input is known to be good
        self.assertIn(message, err)
        for f in files:
            self.assertFalse(os.path.exists(f), f)
        return err

    def csv(self, d, name, text):
        path = os.path.join(d, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def test_wheel(self):
        wheel = ["--wheel-width-mm", "150", "--arc-height-mm"]
        self.refused(self.FAMILY + ["--wheel-width-mm", "0", "--arc-height-mm", "0.5"], 3,
                     "nccomp: error: wheel width W must be a finite number > 0 mm, got 0.000000")
        self.refused(self.FAMILY + ["--wheel-width-mm", "-5", "--arc-height-mm", "0.5"], 3,
                     "wheel width W must be a finite number > 0 mm, got -5.000000")
        self.refused(self.FAMILY + ["--wheel-width-mm", "nan", "--arc-height-mm", "0.5"], 3,
                     "wheel width W must be a finite number > 0 mm, got nan")
        self.refused(self.FAMILY + wheel + ["75"], 3,
                     "wheel arc height h must satisfy 0 <= h < W/2 = 75.000000 mm, got 75.000000")
        self.refused(self.FAMILY + wheel + ["80"], 3, "0 <= h < W/2 = 75.000000 mm, got 80.000000")
        self.refused(self.FAMILY + wheel + ["-0.1"], 3, "0 <= h < W/2")
        self.refused(self.FAMILY + ["--wheel-width-mm", "150", "--arc-radius-mm", "70"], 3,
                     "wheel arc radius R must be > W/2 = 75.000000 mm, got 70.000000")
        self.refused(self.FAMILY + ["--wheel-width-mm", "150"], 2,
                     "grind-path: give --arc-height-mm or --arc-radius-mm")

    def test_profile_csv(self):
        wheel = ["--wheel-width-mm", "150", "--arc-height-mm", "0.5"]
        with tempfile.TemporaryDirectory() as d:
            out = os.path.join(d, "o.nc")
            bad = self.csv(d, "bad.csv", "z_mm,u_mm\n0,0\n1,0.1\n1,0.2\n2,0.3\n")
            self.refused(["--profile", bad] + wheel + ["--gcode-out", out], 3,
                         f"nccomp: error: {bad}:4: z_mm must increase strictly: 1.000000 after "
                         "1.000000", [out])
            nan = self.csv(d, "nan.csv", "0,0\n1,0.1\n2,nan\n3,0\n")
            self.refused(["--profile", nan] + wheel, 3, f"{nan}:3: value is not finite (NaN or inf)")
            text = self.csv(d, "text.csv", "0,0\n1,abc\n")
            self.refused(["--profile", text] + wheel, 3, f"{text}:2: u_mm is not a number: 'abc'")
            one = self.csv(d, "one.csv", "z_mm,u_mm\n0,0\n")
            self.refused(["--profile", one] + wheel, 3, f"{one}: needs at least 2 samples, got 1")
            gap = self.csv(d, "gap.csv", "0,0\n1,0\n2,0\n4,0\n5,0\n")
            self.refused(["--profile", gap] + wheel, 3,
                         f"{gap}:4: samples are not uniformly spaced (z = 4.000000, uniform "
                         "spacing would put it at 3.000000); give a resampling spacing")
            rc, o, err = run("--profile", gap, "--resample-mm", "0.5", *wheel, "--verify-points", "0")
            self.assertEqual(rc, 0, err)
            self.assertIn(f"profile: {gap} (resampled), 11 samples", o)
            self.refused(["--profile", os.path.join(d, "missing.csv")] + wheel, 3,
                         "cannot open profile file")

    def test_fit_and_options(self):
        wheel = ["--wheel-width-mm", "150", "--arc-height-mm", "0.5"]
        self.refused(["--family", "convex", "--height-mm", "0.6", "--z-from-mm", "0", "--z-to-mm",
                      "0.1", "--spacing-mm", "0.1"] + wheel, 3,
                     "a degree-2 fit through 3 samples needs at least 3 samples, the profile has 2")
        self.refused(self.FAMILY + wheel + ["--fit-degree", "9"], 3, "fit degree must be 1..8, got 9")
        self.refused(self.FAMILY + wheel + ["--fit-degree", "3", "--fit-points", "3"], 3,
                     "fit points must be degree + 1 = 4 .. 64, got 3")
        self.refused(["--family", "blob", "--z-from-mm", "0", "--z-to-mm", "1", "--spacing-mm",
                      "0.1"] + wheel, 3, "unknown profile family 'blob'")
        self.refused(self.FAMILY + wheel + ["--method", "fast"], 3,
                     "--method must be exact or local, got 'fast'")
        self.refused(self.FAMILY + wheel + ["--tolerance-um", "0"], 3,
                     "--tolerance-um and --chord-tol-um must be finite and > 0")
        self.refused(self.FAMILY + wheel + ["--chord-tol-um", "0.1", "--decimals", "3"], 3,
                     "--chord-tol-um 0.1 is not above the rounding of 3 decimals")
        self.refused(self.FAMILY + wheel + ["--gcode-band", "below"], 3,
                     "--gcode-band must be above or both, got 'below'")
        self.refused(["--family", "sine", "--z-from-mm", "0", "--z-to-mm", "1", "--spacing-mm",
                      "0.1"] + wheel, 3, "profile family sine: wavelength_mm must be > 0")
        with tempfile.TemporaryDirectory() as d:
            self.refused(self.FAMILY + wheel + ["--gcode-out", os.path.join(d, "no", "x.nc")], 3,
                         f"--gcode-out {d}/no/x.nc: directory {d}/no does not exist")
            self.refused(self.FAMILY + wheel + ["--table-out", d], 3, f"--table-out {d} is a directory")
        # Errors of the option parser itself: CLI11's message and status (not 0).
        rc, out, err = run(*self.FAMILY)
        self.assertNotEqual(rc, 0)
        self.assertIn("--wheel-width-mm is required", err)


class DocsExamples(unittest.TestCase):
    """Every `$ nccomp grind-path` example in docs/grinding.md is run, and what it prints must be
    what the page shows (timings aside); the table and G-code excerpts must be in the files."""

    DOC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..", "docs",
                       "grinding.md")
    TIME = re.compile(r"\d+\.\d+ s\b")

    def blocks(self):
        with open(self.DOC) as f:
            text = f.read()
        return [b.strip("\n").split("\n") for b in re.findall(r"```\n(.*?)```", text, re.S)]

    @staticmethod
    def commands(block):
        """[(command line, [expected output lines])] of a block of `$ ...` commands."""
        out, i = [], 0
        while i < len(block):
            line = block[i]
            assert line.startswith("$ "), line
            cmd = line[2:]
            while cmd.endswith("\\"):
                i += 1
                cmd = cmd[:-1] + block[i].strip()
            cmd = cmd.split("  #")[0]
            i += 1
            expected = []
            while i < len(block) and not block[i].startswith("$ "):
                expected.append(block[i])
                i += 1
            out.append((cmd, expected))
        return out

    def test_examples_print_what_the_page_shows(self):
        blocks = self.blocks()
        ran = 0
        with tempfile.TemporaryDirectory() as d:
            with open(os.path.join(d, "bad.csv"), "w") as f:  # the Errors section's bad.csv
                f.write("z_mm,u_mm\n0,0\n1,0.1\n1,0.2\n2,0.3\n")
            bindir = os.path.join(d, "bin")
            os.mkdir(bindir)
            os.symlink(os.path.abspath(NCCOMP), os.path.join(bindir, "nccomp"))
            env = dict(os.environ, PATH=bindir + os.pathsep + os.environ["PATH"])
            for block in blocks:
                if block[0].startswith("/usr/bin/python3 -c"):  # makes an input file
                    subprocess.run("\n".join(block), shell=True, cwd=d, check=True, env=env)
                    continue
                if not block[0].startswith("$ nccomp grind-path"):
                    continue
                for cmd, expected in self.commands(block):
                    p = subprocess.run(cmd, shell=True, cwd=d, env=env, capture_output=True,
                                       text=True, timeout=600)
                    got = (p.stdout + p.stderr).rstrip("\n").split("\n")
                    norm = lambda lines: [self.TIME.sub("T s", x) for x in lines]
                    self.assertEqual(norm(got), norm(expected), cmd)
                    ran += 1
            # The excerpts of crown_table.csv and crown.nc.
            for block in blocks:
                name = ("crown_table.csv" if block[0].startswith("z_mm,u_target_mm")
                        else "crown.nc" if block[0].startswith("; nccomp grind-path") else None)
                if name is None:
                    continue
                with open(os.path.join(d, name)) as f:
                    lines = f.read().split("\n")
                head = block[:block.index("...")] if "..." in block else block
                self.assertEqual(lines[:len(head)], head, name)
                tail = block[block.index("...") + 1:] if "..." in block else []
                if tail:
                    self.assertEqual(lines[-len(tail) - 1:-1], tail, name)
                ran += 1
        self.assertGreaterEqual(ran, 10)


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) < 2 or args[0] != "--nccomp":
        sys.exit("usage: grind_path_cli_test.py --nccomp PATH [unittest args]")
    NCCOMP = args[1]
    unittest.main(argv=[sys.argv[0]] + args[2:], verbosity=2)
