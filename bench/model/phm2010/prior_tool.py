#!/usr/bin/python3
"""PHM 2010: does an earlier cutter's whole life (c1) help predict the last cuts of c4 and c6?
An exploration outside nccomp analyze (numpy least squares). Each series: an initial wear and a
wear rate of its own (per cutter, or per flute of c4/c6), plus wear-curve shapes in path L, from
a grid: break-in 1 - exp(-L/l), rate change max(L - L0, 0), (L/L_end)^2, growth exp((L - L_end)/l);
one shared coefficient per shape (all series) or one per series. Fitted: c1's 315 cuts (when
used) and cuts 1-252 of c4/c6; held out: cuts 253-315 of c4/c6. For each setting the shape
combination with the least fitted RMS is reported, and for reference the one with the least
held-out RMS (chosen on the held-out cuts: not a rule, a bound on what these shapes can do).
  /usr/bin/python3 bench/model/phm2010/prior_tool.py [data folder]
"""
import itertools
import sys

import numpy as np

folder = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/phm2010_milling_wear"
per_cut = np.genfromtxt(folder + "/phm2010_wear_percut.csv", delimiter=",", skip_header=1,
                        dtype=None, encoding="utf-8")
envelope = {}
for cutter, _, wear in per_cut:
    envelope.setdefault(cutter, []).append(wear)
envelope = {c: np.array(v) for c, v in envelope.items()}
flutes = {}
for c in ("c4", "c6"):
    table = np.genfromtxt("%s/%s_wear.csv" % (folder, c), delimiter=",", skip_header=1)
    for j in range(3):
        flutes["%s flute %d" % (c, j + 1)] = table[:, j + 1]
cut = np.arange(1, 316)
path = cut * 108.0
end = path[-1]
held = cut > 252

SHAPES = {
    "break-in": (lambda l: 1.0 - np.exp(-path / l), (300, 600, 1000, 2000, 4000)),
    "rate change": (lambda l0: np.maximum(path - l0, 0.0), (15000, 20000, 23760, 26000, 28000, 30000)),
    "square": (lambda _: (path / end) ** 2, (0,)),
    "growth": (lambda l: np.exp((path - end) / l), (3000, 5000, 8000, 12000, 20000)),
}
COMBOS = [("break-in", "rate change"), ("break-in", "square"), ("break-in", "growth"),
          ("break-in", "rate change", "square"), ("rate change",), ("square",), ("growth",),
          ("break-in", "square", "growth")]


def rms(series, shapes, shared):
    """Fitted and held-out RMS of one least-squares fit of every series together."""
    blocks, ys, fitted = [], [], []
    k = len(series)
    for i, (y, in_fit) in enumerate(series):
        cols = []
        for j in range(k):
            one = np.full(315, 1.0 if i == j else 0.0)
            cols += [one, one * path]
        for s in shapes:
            if shared:
                cols.append(s)
            else:
                cols += [s * (1.0 if i == j else 0.0) for j in range(k)]
        blocks.append(np.column_stack(cols))
        ys.append(y)
        fitted.append(in_fit)
    x, y, f = np.vstack(blocks), np.concatenate(ys), np.concatenate(fitted)
    b, *_ = np.linalg.lstsq(x[f], y[f], rcond=None)
    r = y - x @ b
    return np.sqrt(np.mean(r[f] ** 2)), np.sqrt(np.mean(r[~f] ** 2))


print("| view | c1's life fitted | shapes | least fitted RMS: shapes, fitted / held-out [µm] "
      "| least held-out RMS (chosen on it) [µm] |")
print("| --- | --- | --- | --- | --- |")
for view in ("max", "flute"):
    targets = ({c: envelope[c] for c in ("c4", "c6")} if view == "max" else flutes)
    for with_c1 in (False, True):
        series = [(envelope["c1"], np.ones(315, bool))] if with_c1 else []
        series += [(y, ~held) for y in targets.values()]
        for shared in (False, True):
            results = []
            for combo in COMBOS:
                for params in itertools.product(*[SHAPES[s][1] for s in combo]):
                    shapes = [SHAPES[s][0](p) for s, p in zip(combo, params)]
                    f, h = rms(series, shapes, shared)
                    name = ", ".join("%s %g" % (s, p) if s != "square" else s
                                     for s, p in zip(combo, params))
                    results.append((f, h, name))
            by_fit = min(results)
            by_held = min(results, key=lambda t: t[1])
            print("| %s | %s | %s | %s: %.2f / **%.2f** | %.2f (%s) |" % (
                view, "yes" if with_c1 else "no", "shared" if shared else "per series",
                by_fit[2], by_fit[0], by_fit[1], by_held[1], by_held[2]))
