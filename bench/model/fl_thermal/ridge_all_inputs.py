#!/usr/bin/python3
"""FL_THERMAL: a shrunk (ridge) fit of every input at once, the alternative to the search's
greedy steps among nearly collinear temperatures. An exploration outside nccomp analyze. The
split is the bench's (fitted: the first 80 % of the rows by time; held out: the last 20 %). Two
input sets: the 16 temperatures; the 16 temperatures and 4 first-order lags of the spindle speed
(tau 900, 2 700, 8 100, 24 300 s). Each input is standardised on the fitted rows. The ridge
weight lambda is chosen on the fitted rows alone, by a rolling-origin error (4 time blocks, each
of the last 3 predicted from a fit to those before it; as rank_folds = 3); the held-out error
of every lambda is printed beside it for reading, not for choosing. The declared model (constant
+ t5) is the reference.
  /usr/bin/python3 bench/model/fl_thermal/ridge_all_inputs.py [data.csv]
"""
import numpy as np

from fl_thermal_data import load

data = load()
cut = data.cut
fitted = np.arange(cut)
temps = np.column_stack([data.temp(i) for i in range(1, 17)])


def ridge(x, y, lam, rows):
    """Prediction at every row of a ridge fit on `rows` (inputs standardised on those rows)."""
    mu = x[rows].mean(0)
    sd = x[rows].std(0) + 1e-12
    z = (x - mu) / sd
    ym = y[rows].mean()
    a = z[rows].T @ z[rows] + lam * len(rows) * np.eye(z.shape[1])
    return z @ np.linalg.solve(a, z[rows].T @ (y[rows] - ym)) + ym


def rolling(x, y, lam):
    return data.rolling(lambda rows: ridge(x, y, lam, rows), y)


def heldout(y, p):
    return float(np.sqrt(np.mean((y - p)[cut:] ** 2)))


lams = [0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0]
speed_lags = np.column_stack([data.lag(data.rpm, tau) for tau in (900.0, 2700.0, 8100.0, 24300.0)])
print("| gauge | inputs | declared held-out [µm] | lambda (rolling-origin) | held-out [µm] "
      "| change | held-out at lambda 0 / 1e-4 / 1e-3 / 1e-2 / 0.1 / 1 [µm] |")
print("| --- | --- | --- | --- | --- | --- | --- |")
for gauge in ("ch1", "ch3", "ch5"):
    y = data.col(gauge + "(um)")
    declared = heldout(y, ridge(data.temp(5)[:, None], y, 0.0, fitted))
    for name, x in (("16 temperatures", temps),
                    ("16 temperatures + 4 speed lags", np.column_stack([temps, speed_lags]))):
        lam = min((rolling(x, y, v), v) for v in lams)[1]
        h = heldout(y, ridge(x, y, lam, fitted))
        every = " / ".join("%.2f" % heldout(y, ridge(x, y, v, fitted)) for v in lams)
        print("| %s | %s | %.2f | %g | %.2f | %+.0f %% | %s |" % (
            gauge, name, declared, lam, h, 100.0 * (h / declared - 1.0), every))
