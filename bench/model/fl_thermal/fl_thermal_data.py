"""What the FL_THERMAL exploration scripts beside this file share: the data read as the bench
maps it, the bench's split (fitted: the first 80 % of the rows by time; held out: the last
20 %), a first-order lag, and the rolling-origin error on the fitted rows (as rank_folds = 3)."""
import csv
import sys

import numpy as np

DEFAULT_PATH = "../shared/data/fl_thermal_spindle_drift/data.csv"


class Data:
    def __init__(self, path):
        rows = list(csv.reader(open(path, encoding="utf-8")))
        self._head = [c.strip() for c in rows[0]]
        self._d = np.array([[float(x) for x in r] for r in rows[1:]])
        self.t = self.col("時間(s)")
        self.rpm = self.col("spindle(RPM)")
        self.n = len(self.t)
        self.cut = int(0.8 * self.n)

    def col(self, name):
        return self._d[:, self._head.index(name)]

    def temp(self, i):
        return self.col("t%d(°C)" % i)

    def lag(self, x, tau):
        """First-order lag of x (zero at the start), exact for x held over each sample interval."""
        y = np.zeros_like(x)
        a = 0.0
        for i in range(1, self.n):
            a += (1.0 - np.exp(-(self.t[i] - self.t[i - 1]) / tau)) * (x[i - 1] - a)
            y[i] = a
        return y

    def rolling(self, predict, y):
        """RMS error over the last 3 of 4 time blocks of the fitted rows, each block predicted by
        predict(rows) (a prediction at every row from a fit on `rows`) fitted on those before."""
        edge = np.linspace(0, self.cut, 5).astype(int)
        ss, m = 0.0, 0
        for k in range(1, 4):
            p = predict(np.arange(edge[k]))
            r = y[edge[k]: edge[k + 1]] - p[edge[k]: edge[k + 1]]
            ss += float(np.sum(r * r))
            m += len(r)
        return np.sqrt(ss / m)


def load(path=None):
    """The data file given, else the first argument, else the shared data folder beside the
    checkout."""
    if path is None:
        path = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_PATH
    return Data(path)
