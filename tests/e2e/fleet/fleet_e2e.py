#!/usr/bin/python3
"""Fleet analysis on ncsim (issue 23 item 2), label e2e.

Five machines of one type, m1..m5: ncsim + nccompd in lock-step over Modbus (the runner of
tests/e2e/nccomp_e2e.py), the side-wall daemon of config/demo/nccompd-walls.toml with its own
`machine_id` in the measurement log. Every machine has the same thermal effect, undeclared,
along the wall normal (Y) at its own size, and m4 has an effect of its own: tool wear (its tool
wears 20 um per m of cut path; the others' do not wear). `nccomp analyze` over the five logs
(a directory, as `nccomp collect` writes them) must call thermal_drift common to the type with
a type mean near the machines' mean slope, the wear m4's own, and write five machine models and
the type's prior. A sixth machine (slope in the middle of the type) then machines its first
parts twice, without a model and with the prior's thermal_drift term applied as a trim on the
radius wear register: the prior must make those parts better (ncsim's checkpoint errors).

  fleet_e2e.py --bin-dir BUILD --source SRC --work DIR [--parts N] [--figures]
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
import tomllib

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import nccomp_e2e as e2e  # noqa: E402

# Thermal slope of each machine [um/K] along the wall normal; ncsim's temperature rises by
# RISE_C with the same first-order lag as the drift, so gain_um = slope * RISE_C.
SLOPES = {"m1": 0.8, "m2": 0.95, "m3": 1.1, "m4": 1.25, "m5": 1.4}
ODD = "m4"
SIXTH = ("m6", 1.1)
RISE_C = 8.0
# Short enough that the machine warms up within the first parts and the temperature is not
# proportional to the cut path (which grows linearly) over a run.
TIME_CONSTANT_S = 40.0
FIRST_PARTS = 3


def sets_for(slope, wear):
    return ["thermal.enabled=true", "thermal.gain_um=[0.0, %g, 0.0]" % (slope * RISE_C),
            "thermal.temperature_rise_c=%g" % RISE_C,
            "thermal.time_constant_s=%g" % TIME_CONSTANT_S,
            "wear.enabled=%s" % ("true" if wear else "false"), "wear.rate_um_per_m=20"]


def with_machine_id(machine):
    """e2e.stage_configs with `machine_id` set in the staged daemon config's [measurement_log]."""
    original = e2e.stage_configs

    def stage(source, run_dir, daemon_cfg, ncsim_cfg, port, overrides=None):
        daemon_path, ncsim_path = original(source, run_dir, daemon_cfg, ncsim_cfg, port, overrides)
        with open(daemon_path) as f:
            text = f.read()
        text, n = e2e.re.subn(r"^\[measurement_log\]\s*$",
                              '[measurement_log]\nmachine_id = "%s"' % machine, text,
                              flags=e2e.re.M)
        if n != 1:
            raise RuntimeError("%s: no [measurement_log] table" % daemon_path)
        with open(daemon_path, "w") as f:
            f.write(text)
        return daemon_path, ncsim_path

    return stage


def run_machine(b, source, work, machine, slope, wear, parts, daemon_cfg="nccompd-walls.toml",
                overrides=None, name=None):
    original = e2e.stage_configs
    e2e.stage_configs = with_machine_id(machine)
    try:
        r = e2e.run_machining(b, source, work, name or machine, daemon_cfg, "ncsim-demo.toml",
                              program="side_wall", parts=parts, sets=sets_for(slope, wear),
                              overrides=overrides, echo=print)
    finally:
        e2e.stage_configs = original
    return r


def rms(v):
    return math.sqrt(sum(e * e for e in v) / len(v)) if v else float("nan")


def predict(model_path, row):
    """The model file's prediction [um] at a logged contour row: its constant and linear terms
    (the forms this fleet's models have; another form fails the test rather than guess)."""
    with open(model_path, "rb") as f:
        terms = tomllib.load(f)["model"]["term"]
    kinds = {"tool_wear": 0.0, "contour": 1.0, "calib": 2.0}
    y = 0.0
    for t in terms:
        if "contour" not in t.get("kinds", ["contour"]):
            continue
        key = [kinds[row["kind"]] if c == "kind" else float(row[c]) for c in t.get("per", [])]
        key += [0.0] * (2 - len(key))
        coef = dict(zip((tuple(g) for g in t["groups"]), t["coef_um"]))
        if tuple(key) not in coef:
            continue
        if t["form"] == "constant":
            y += coef[tuple(key)]
        elif t["form"] == "linear":
            y += coef[tuple(key)] * float(row[t["column"]])
        else:
            raise RuntimeError("%s: form %s not evaluated here" % (model_path, t["form"]))
    return y


def checkpoint_rms(r, parts):
    rows = [x for x in e2e.read_csv_rows(os.path.join(r.out_dir, "checkpoints.csv"))
            if int(x["part"]) in parts]
    v = [float(x["error_um"]) for x in rows]
    return rms(v), len(v)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin-dir", required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--nccompd")
    ap.add_argument("--ncsim")
    ap.add_argument("--nccomp")
    ap.add_argument("--parts", type=int, default=12, help="parts per machine")
    args = ap.parse_args()
    b = e2e.Binaries(args.bin_dir, args.nccompd, args.ncsim, args.nccomp)
    source = os.path.abspath(args.source)
    work = os.path.abspath(args.work)
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    t0 = time.monotonic()
    c = e2e.Check("fleet")
    logs = os.path.join(work, "logs")
    os.makedirs(logs)
    for machine, slope in SLOPES.items():
        r = run_machine(b, source, work, machine, slope, machine == ODD, args.parts)
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d" % (machine, r.ncsim_rc, r.daemon_rc))
        # nccomp collect's layout: one <machine>.csv per machine in one directory.
        shutil.copy(os.path.join(r.run_dir, "log", "measurements.csv"),
                    os.path.join(logs, machine + ".csv"))
    out = os.path.join(work, "analysis")
    cmd = [b.nccomp, "analyze", "--log", logs, "--config",
           os.path.join(source, "config", "demo", "model-declared.toml"), "--out", out]
    a = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    print("$ nccomp analyze --log logs --config config/demo/model-declared.toml --out analysis")
    print(a.stdout)
    c.that(a.returncode == 0, "nccomp analyze exit %d %s" % (a.returncode, a.stderr[-800:]))
    if a.returncode != 0:
        c.done()
    with open(os.path.join(out, "summary.json")) as f:
        fleet = json.load(f)["fleet"]
    terms = [t for t in fleet["terms"] if t["role"] != "declared"]
    thermal = [t for t in terms if t["name"] == "thermal_drift"]
    c.that(len(thermal) == 1 and thermal[0]["role"] == "common",
           "thermal_drift is common to the type: %s" %
           [(t["label"], t["column"], t["role"], t.get("machine")) for t in terms])
    own = [t for t in terms if t["role"] == "machine"]
    c.that(len(own) >= 1 and all(t.get("machine") == ODD for t in own) and
           all(t["column"] in ("path_mm", "part") for t in own),
           "the only machine's own effect is %s's wear (in path_mm or part): %s" %
           (ODD, [(t["label"], t["column"], t.get("machine")) for t in own]))
    if thermal and thermal[0]["coefficients"]:
        # Each machine's drift relative to the type's: the slopes' ratios (whatever the form,
        # linear in temp_c or the warm-up in time_s, the coefficient is proportional to the
        # slope, and a common lag between cutting and probing cancels).
        co = thermal[0]["coefficients"][0]
        mu = co["type_mean"]
        mean_slope = sum(SLOPES.values()) / len(SLOPES)
        print("thermal_drift (%s, %s): type mean %.4g, tau %.3g" %
              (thermal[0]["column"], thermal[0]["form"], mu, co["between_machine_sd"]))
        for m, slope in SLOPES.items():
            x = co["machines"][m]
            blup, est = x["blup"], x["estimate"]
            if m == ODD:
                # Its wear and its warm-up overlap (both grow over the run): its own slope is
                # imprecise, so its BLUP leans on the type (shrunk toward the mean, not past it).
                c.that(blup is not None and x["own_weight"] < 0.5 and
                       abs(blup - mu) <= abs(est - mu),
                       "%s: imprecise estimate %.4g +- %.2g shrunk toward the type mean %.4g: "
                       "BLUP %.4g (own weight %.2f < 0.5)" % (m, est, x["sd"], mu, blup,
                                                             x["own_weight"]))
                continue
            c.that(blup is not None and abs(blup / mu - slope / mean_slope) < 0.1,
                   "%s: BLUP / type mean = %.3f, slope / mean slope = %.3f (within 0.1; "
                   "estimate %.4g, BLUP %.4g)" % (m, blup / mu if blup is not None else
                                                  float("nan"), slope / mean_slope, est, blup))
        if thermal[0]["column"] == "temp_c":
            # Linear in the temperature: µm/K; the probe reads after the cut, a little warmer.
            c.that(0.8 * mean_slope < abs(mu) < 1.25 * mean_slope,
                   "type mean |%.3f| um/K within -20 %% / +25 %% of the mean slope %.2f" %
                   (abs(mu), mean_slope))
    # Shrinking a machine's common coefficients must not spoil its fit (its constants and own
    # effects are refitted given them): its fleet model as good as its own search alone.
    for m in SLOPES:
        f = fleet["fit"][m]
        c.that(f["rms_own_model_um"] < 1.2 * f["rms_alone_um"],
               "%s: RMS %.3f um with its fleet model, %.3f um with its own search alone" %
               (m, f["rms_own_model_um"], f["rms_alone_um"]))
    for m in list(SLOPES) + ["type"]:
        path = os.path.join(out, "model-%s.toml" % m)
        c.that(os.path.exists(path), "wrote model-%s.toml" % m)
    odd_names = {t["name"] for t in own}
    for m in SLOPES:
        with open(os.path.join(out, "model-%s.toml" % m)) as f:
            text = f.read()
        has = any('name = "%s"' % n in text for n in odd_names)
        c.that(has == (m == ODD), "model-%s.toml %s the wear term" %
               (m, "has" if has else "has not"))
    # The sixth machine: its first parts without a model and with the type's prior.
    machine, slope = SIXTH
    prior = os.path.join(out, "model-type.toml")
    first = set(range(1, FIRST_PARTS + 1))
    without = run_machine(b, source, work, machine, slope, False, FIRST_PARTS,
                          name=machine + "_without")
    with_prior = run_machine(
        b, source, work, machine, slope, False, FIRST_PARTS,
        daemon_cfg="nccompd-walls-model.toml", name=machine + "_prior",
        overrides={"nccompd.toml": {"model.file": '"%s"' % prior, "model.update": '"cycle"',
                                    "model.apply.term": '"thermal_drift"'}})
    for r in (without, with_prior):
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d" % (r.name, r.ncsim_rc, r.daemon_rc))
        c.that(not r.alarms("alarm"), "%s: no alarm (%s)" % (r.name, r.alarms("alarm")))
    # Offline: the prior's prediction of the rows the daemon logged on the first parts without a
    # model (measured + applied = the machine's error there) against no model (prediction 0).
    rows = [m for m in without.measurements() if m["kind"] == "contour" and
            int(m["part"]) in first]
    err0, err1 = [], []
    for m in rows:
        y = float(m["measured_um"]) + float(m["applied_um"])
        err0.append(y)
        err1.append(y - predict(prior, m))
    o0, o1 = rms(err0), rms(err1)
    print("sixth machine (%.2f um/K), parts 1-%d, %d logged probe rows: error RMS with no model "
          "%.3f um, with the type's prior %.3f um (%.0f %% less)" %
          (slope, FIRST_PARTS, len(rows), o0, o1, 100.0 * (1.0 - o1 / o0)))
    c.that(len(rows) == 4 * FIRST_PARTS and o1 < o0,
           "the type's prior predicts the first %d parts better than no model: %.3f < %.3f um" %
           (FIRST_PARTS, o1, o0))
    # In the loop: its thermal_drift term as a trim on the radius wear register. The term is
    # linear in temp_c (°C from 0), its intercept lives in the per-checkpoint constants, which the
    # daemon does not apply (S1 learns them from the first probed part on): part 1 gets the
    # term without its constant, the parts after it the drift S1 cannot follow.
    print("in the loop, checkpoint error RMS per part (ncsim's checkpoints.csv):")
    for p in sorted(first):
        print("  part %d: no model %.3f um, prior's thermal_drift applied %.3f um" %
              (p, checkpoint_rms(without, {p})[0], checkpoint_rms(with_prior, {p})[0]))
    later = set(range(2, FIRST_PARTS + 1))
    e0, n0 = checkpoint_rms(without, later)
    e1, n1 = checkpoint_rms(with_prior, later)
    c.that(n0 > 0 and n0 == n1 and e1 < e0,
           "in the loop, parts 2-%d (S1 has probed part 1): %.3f um with the prior's "
           "thermal_drift, %.3f um without" % (FIRST_PARTS, e1, e0))
    print("fleet e2e: %.1f s wall" % (time.monotonic() - t0))
    c.done()
    print("PASSED: fleet")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (AssertionError, RuntimeError) as e:
        print("FAILED: %s" % e, file=sys.stderr)
        sys.exit(1)
