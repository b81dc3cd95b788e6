#!/usr/bin/python3
"""FL_THERMAL: would the spindle speed squared, as the heat input of a first-order lag, close the
gap to issue 21's goal (held-out error -80 %)? An exploration outside nccomp analyze (the same
candidate inside the search was tried and not kept: bench/results/model.md). The declared model
(constant + t5 linear) is fitted on the first 80 % of the rows and the last 20 % are held out
(as bench/model/fl_thermal/fl_thermal.toml). Four terms are added greedily from first-order lags
of speed^p (p as offered, tau on a log grid of 25 values from 300 s to 40 000 s) and t1, t2, t9
linear. Two rules pick each step: the best fitted RMS (as the search's BIC), and the six best by
fitted RMS re-ranked by a rolling-origin error on the fitted rows (4 time blocks, each of the
last 3 predicted from those before it; as rank_folds = 3).
Prints one line per gauge, power set and rule: the held-out RMS after each step.
  /usr/bin/python3 bench/model/fl_thermal/heat_input_power.py [data.csv]
      [--powers "1;1,2;2"] [--rerank 6]
--powers: the sets of speed powers offered, one run of the search each (';' between sets, ','
within one; a power may be a fraction such as 5/3). --rerank: how many of the best by fitted
RMS the rolling rule re-ranks (0: every candidate).
"""
import argparse
from fractions import Fraction

import numpy as np

from fl_thermal_data import DEFAULT_PATH, load

parser = argparse.ArgumentParser()
parser.add_argument("data", nargs="?", default=DEFAULT_PATH)
parser.add_argument("--powers", default="1;1,2;2")
parser.add_argument("--rerank", type=int, default=6)
args = parser.parse_args()
power_sets = [tuple(Fraction(p) for p in s.split(",")) for s in args.powers.split(";")]
data = load(args.data)
n = data.n
cut = data.cut
rpm = data.rpm
temp = {i: data.temp(i) for i in range(1, 17)}


def lstsq_prediction(cols, y, rows):
    """Prediction at every row of a least-squares fit (with a constant) on `rows`."""
    x = np.column_stack([np.ones(n)] + cols)
    b, *_ = np.linalg.lstsq(x[rows], y[rows], rcond=None)
    return x @ b


def fit(cols, y):
    """Fitted and held-out RMS of a least-squares fit (with a constant) on the first 80 %."""
    r = y - lstsq_prediction(cols, y, np.arange(cut))
    return np.sqrt(np.mean(r[:cut] ** 2)), np.sqrt(np.mean(r[cut:] ** 2))


def rolling(cols, y):
    return data.rolling(lambda rows: lstsq_prediction(cols, y, rows), y)


taus = np.geomspace(300.0, 40000.0, 25)
print("| gauge | speed powers offered | rule | declared held-out [µm] "
      "| steps: added, held-out RMS [µm] | final change |")
print("| --- | --- | --- | --- | --- | --- |")
for gauge in ("ch1", "ch3", "ch5"):
    y = data.col(gauge + "(um)")
    for powers in power_sets:
        cands = {}
        for p in powers:
            for tau in taus:
                heat = rpm ** float(p) / 5000.0 ** float(p - 1)
                cands["lag(rpm^%s, %.0f s)" % (p, tau)] = data.lag(heat, tau)
        for i in (1, 2, 9):
            cands["t%d" % i] = temp[i]
        for rule in ("fitted", "rolling"):
            chosen = []
            x = [temp[5]]
            declared = fit(x, y)[1]
            steps = []
            for _ in range(4):
                ranked = sorted((fit(x + [v], y)[0], k) for k, v in cands.items()
                                if k not in chosen)
                if rule == "rolling":
                    ranked = sorted((rolling(x + [cands[k]], y), k) for _, k in (ranked[:args.rerank] if args.rerank > 0 else ranked))
                k = ranked[0][1]
                chosen.append(k)
                x = x + [cands[k]]
                steps.append("%s %.2f" % (k, fit(x, y)[1]))
            final = fit(x, y)[1]
            print("| %s | %s | %s | %.2f | %s | %+.0f %% |" % (
                gauge, ", ".join(map(str, powers)), rule if rule == "fitted" or args.rerank == 6
                else "%s (%s)" % (rule, args.rerank or "all"), declared, "; ".join(steps),
                100.0 * (final / declared - 1.0)))
