#!/usr/bin/python3
"""The level + rate Kalman filter of core/estimation against an independent numpy one.

Inputs: a wear-like curve (break-in, then a rate that grows), irregular clock steps, noise and
three outliers that the gate must refuse. The numpy filter uses the textbook covariance update
P = (I - K H) P (the C++ one the Joseph form), its own Q built from the integrals, and its own
gate test. Every step must agree: accepted / refused, the normalised innovation, x and P.
Usage: kalman_vs_numpy.py PATH/TO/kalman_trace
"""
import subprocess
import sys

import numpy as np


def numpy_filter(ql, qr, r, gate, x, p, steps):
    out = []
    h = np.array([[1.0, 0.0]])
    for d, z in steps:
        f = np.array([[1.0, d], [0.0, 1.0]])
        # Q = ∫0^d Φ(s) G G^T Φ(s)^T ds with the rate's white noise, plus the level's own walk.
        q = qr * np.array([[d**3 / 3.0, d**2 / 2.0], [d**2 / 2.0, d]]) + ql * np.array(
            [[d, 0.0], [0.0, 0.0]])
        x = f @ x
        p = f @ p @ f.T + q
        s = (h @ p @ h.T)[0, 0] + r
        nu = z - (h @ x)[0]
        norm = abs(nu) / np.sqrt(s)
        accepted = gate <= 0 or norm <= gate
        if accepted:
            k = (p @ h.T)[:, 0] / s
            x = x + k * nu
            p = (np.eye(2) - np.outer(k, h[0])) @ p
            p = 0.5 * (p + p.T)
        out.append((1 if accepted else 0, norm, x[0], x[1], p[0, 0], p[0, 1], p[1, 1]))
    return out


def main():
    trace = sys.argv[1]
    rng = np.random.default_rng(22)
    n = 300
    d = rng.uniform(50.0, 200.0, n)  # clock steps [mm of path]
    s = np.cumsum(d)
    true = 8.0 * (1.0 - np.exp(-s / 2000.0)) + 1e-4 * s + 2e-9 * s**2
    sigma = 1.0
    z = true + rng.normal(0.0, sigma, n)
    outliers = [60, 150, 240]
    z[outliers] += np.array([15.0, -20.0, 40.0])
    ql, qr, r, gate = 1e-4, 1e-9, sigma**2, 5.0
    x0, p0 = np.array([0.0, 0.0]), np.diag([0.25, 1e-4])
    header = f"{ql!r} {qr!r} {r!r} {gate!r} {x0[0]!r} {x0[1]!r} {p0[0,0]!r} {p0[0,1]!r} {p0[1,1]!r}\n"
    body = "".join(f"{a!r} {b!r}\n" for a, b in zip(d, z))
    run = subprocess.run([trace], input=header + body, capture_output=True, text=True, check=True)
    got = [tuple(float(v) for v in line.split()) for line in run.stdout.splitlines()]
    want = numpy_filter(ql, qr, r, gate, x0, p0, zip(d, z))
    if len(got) != len(want):
        print(f"FAIL: {len(got)} steps from kalman_trace, {len(want)} from numpy")
        return 1
    bad = 0
    for i, (g, w) in enumerate(zip(got, want)):
        if int(g[0]) != w[0]:
            print(f"FAIL step {i}: accepted {int(g[0])} vs numpy {w[0]}")
            bad += 1
            continue
        for name, a, b in zip(("normalized", "x0", "x1", "p00", "p01", "p11"), g[1:], w[1:]):
            if not np.isclose(a, b, rtol=1e-9, atol=1e-12):
                print(f"FAIL step {i}: {name} {a!r} vs numpy {b!r}")
                bad += 1
    refused = [i for i, w in enumerate(want) if w[0] == 0]
    if refused != outliers:
        print(f"FAIL: numpy's gate refused steps {refused}, the outliers are {outliers}")
        bad += 1
    rms = float(np.sqrt(np.mean((np.array([w[2] for w in want])[n // 2:] - true[n // 2:]) ** 2)))
    print(f"{n} steps compared (rtol 1e-9), {bad} mismatches; refused {refused}; estimate RMS, "
          f"second half {rms:.3f} (measurement sigma {sigma})")
    if not rms < 0.6 * sigma:
        print("FAIL: the estimate is not better than the measurements")
        bad += 1
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
