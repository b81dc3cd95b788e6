#!/usr/bin/python3
"""End-to-end runs of nccomp: ncsim (the virtual NC) + nccompd over Modbus TCP on loopback.

Used by the e2e tests (tests/e2e/CMakeLists.txt, one ctest test per scenario) and by
scripts/demo. A run stages its configs into a fresh directory (the register map with a free TCP
port, the daemon and ncsim configs from config/demo/ pointing at it), starts ncsim and nccompd
(lock-step: contract C2, or real time with ncsim at a speed factor), waits for both with time
limits, always stops both (SIGTERM, then SIGKILL of the process group), and reads the result
directory with `nccomp report --json`.

  nccomp_e2e.py --bin-dir BUILD --source SRC --work DIR scenario NAME
  nccomp_e2e.py --bin-dir BUILD --source SRC --work DIR demo [--realtime SPEED]
"""

import argparse
import json
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

# ---------------------------------------------------------------------------------------------
# Processes


def _die_with_parent():
    # A runner killed outright (ctest's timeout) must not leave a daemon behind: the kernel sends
    # the child SIGKILL when the runner's thread ends (PR_SET_PDEATHSIG = 1).
    import ctypes
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)


LIVE = set()  # every Proc not yet stopped (the SIGTERM handler stops them all)


class Proc:
    """A child process in its own process group, output to a log file."""

    def __init__(self, name, argv, log_path, cwd):
        self.name = name
        self.argv = [str(a) for a in argv]
        self.log_path = log_path
        self._log = open(log_path, "wb")
        self.p = subprocess.Popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT,
                                  stdin=subprocess.DEVNULL, cwd=cwd, start_new_session=True,
                                  preexec_fn=_die_with_parent)
        LIVE.add(self)

    def running(self):
        return self.p.poll() is None

    def wait(self, timeout_s):
        """Exit status, or None when still running after timeout_s."""
        try:
            return self.p.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, grace_s=5.0):
        """SIGTERM, then SIGKILL of the whole group after grace_s. Returns the exit status."""
        if self.running():
            try:
                os.kill(self.p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            if self.wait(grace_s) is None:
                try:
                    os.killpg(self.p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.p.wait()
        self._log.close()
        LIVE.discard(self)
        return self.p.returncode

    def log(self):
        with open(self.log_path, "rb") as f:
            return f.read().decode("utf-8", "replace")


def free_port():
    """A TCP port nobody listens on right now (the kernel's choice for port 0)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ---------------------------------------------------------------------------------------------
# Configs

PATH_KEYS = re.compile(r'^(\s*(?:[a-z_]*bus_map|[a-z_]*_file)\s*=\s*)"([^"]*)"', re.M)
INCLUDE = re.compile(r'^(\s*include\s*=\s*)\[([^\]]*)\]', re.M)


def stage_configs(source, run_dir, daemon_cfg, ncsim_cfg, port, overrides=None):
    """Copies config/demo/<daemon_cfg> and <ncsim_cfg> into run_dir. The Modbus map they share
    is staged as run_dir/map.toml with `port` (so runs never collide); every other file path in
    them becomes absolute (they stay where they are). Returns (daemon_path, ncsim_path)."""
    demo = os.path.join(source, "config", "demo")
    with open(os.path.join(source, "config", "reference-nc-modbus.toml")) as f:
        map_text = f.read()
    map_text, n = re.subn(r"^port = \d+", "port = %d" % port, map_text, flags=re.M)
    if n != 1:
        raise RuntimeError("reference-nc-modbus.toml: expected one 'port = N' line, found %d" % n)
    map_path = os.path.join(run_dir, "map.toml")
    with open(map_path, "w") as f:
        f.write(map_text)

    def fix_path(p):
        if os.path.basename(p) == "reference-nc-modbus.toml":
            return "map.toml"
        return p if os.path.isabs(p) else os.path.normpath(os.path.join(demo, p))

    def stage(name, out_name):
        with open(os.path.join(demo, name)) as f:
            text = f.read()
        text = PATH_KEYS.sub(lambda m: '%s"%s"' % (m.group(1), fix_path(m.group(2))), text)

        def fix_include(m):
            items = [s.strip().strip('"') for s in m.group(2).split(",") if s.strip()]
            return m.group(1) + "[" + ", ".join('"%s"' % fix_path(i) for i in items) + "]"

        text = INCLUDE.sub(fix_include, text)
        for key, value in (overrides or {}).get(out_name, {}).items():
            # "table.key" → replace the key's line inside that table.
            table, k = key.rsplit(".", 1)
            pat = re.compile(r"(^\[%s\]\s*$(?:(?!^\[).)*?^%s\s*=\s*)[^\n]*" %
                             (re.escape(table), re.escape(k)), re.M | re.S)
            text, n = pat.subn(lambda m: m.group(1) + value, text)
            if n != 1:
                raise RuntimeError("%s: cannot override %s" % (name, key))
        path = os.path.join(run_dir, out_name)
        with open(path, "w") as f:
            f.write(text)
        return path

    return stage(daemon_cfg, "nccompd.toml"), stage(ncsim_cfg, "ncsim.toml")


# ---------------------------------------------------------------------------------------------
# One run


class RunResult:
    def __init__(self, name, run_dir, out_dir, ncsim_rc, daemon_rc, ncsim_log, daemon_log,
                 report, wall_s):
        self.name = name
        self.run_dir = run_dir
        self.out_dir = out_dir
        self.ncsim_rc = ncsim_rc
        self.daemon_rc = daemon_rc
        self.ncsim_log = ncsim_log
        self.daemon_log = daemon_log
        self.report = report
        self.wall_s = wall_s

    def alarms(self, severity="alarm"):
        """(name, code) of every alarm the daemon logged with this severity."""
        return [(m.group(2), int(m.group(3))) for m in ALARM_LINE.finditer(self.daemon_log)
                if m.group(1) == severity]

    def measurements(self):
        """Rows of the daemon's measurement log as dicts (strings)."""
        path = os.path.join(self.run_dir, "log", "measurements.csv")
        if not os.path.exists(path):
            return []
        with open(path) as f:
            lines = f.read().splitlines()
        if not lines:
            return []
        head = lines[0].split(",")
        return [dict(zip(head, line.split(","))) for line in lines[1:] if line]

    def writes(self):
        """(t_s, register_index, value_um, effective_t_s) of every write the NC took."""
        out = []
        with open(os.path.join(self.out_dir, "writes.csv")) as f:
            for line in f.read().splitlines()[1:]:
                if line:
                    t, r, v, e = line.split(",")
                    out.append((float(t), int(r), float(v), float(e)))
        return out


ALARM_LINE = re.compile(r"\b(alarm|warning|info) ([a-z_0-9]+) \(code (\d+)\) subject")


class Binaries:
    def __init__(self, bin_dir, nccompd=None, ncsim=None, nccomp=None):
        self.nccompd = nccompd or os.path.join(bin_dir, "daemon", "nccompd")
        self.ncsim = ncsim or os.path.join(bin_dir, "sim", "ncsim", "ncsim")
        self.nccomp = nccomp or os.path.join(bin_dir, "tools", "nccomp")
        # Absolute: the processes run in their run directory.
        self.nccompd, self.ncsim, self.nccomp = (os.path.abspath(p) for p in
                                                 (self.nccompd, self.ncsim, self.nccomp))
        for p in (self.nccompd, self.ncsim, self.nccomp):
            if not os.access(p, os.X_OK):
                raise RuntimeError("missing binary %s (build nccompd ncsim nccomp)" % p)


def run_machining(b, source, work, name, daemon_cfg, ncsim_cfg, program="mould_face",
                  seed=1, parts=None, sets=(), overrides=None, speed=None, timeout_s=240.0,
                  echo=None, bus="modbus"):
    """Machines one program with ncsim + nccompd; returns a RunResult. speed=None: lock-step
    (deterministic); else real time with ncsim at that speed factor."""
    run_dir = os.path.join(work, name)
    shutil.rmtree(run_dir, ignore_errors=True)
    os.makedirs(run_dir)
    out_dir = os.path.join(run_dir, "out")
    port = free_port()
    # Unix sockets (lock-step, status) live in a short temp dir: paths are limited to 108 bytes,
    # and in the vcan VM the work directory is a 9p mount that cannot hold sockets.
    sock_dir = tempfile.mkdtemp(prefix="nccomp-e2e-")
    sock = os.path.join(sock_dir, "ls.sock")
    overrides = {k: dict(v) for k, v in (overrides or {}).items()}
    overrides.setdefault("nccompd.toml", {})["status.socket_path"] = '"%s"' % os.path.join(
        sock_dir, "status.sock")
    daemon_path, ncsim_path = stage_configs(source, run_dir, daemon_cfg, ncsim_cfg, port,
                                            overrides)
    sim_argv = [b.ncsim, "--config", ncsim_path, "--program", program, "--bus", bus,
                "--out", out_dir, "--seed", str(seed)]
    if parts is not None:
        sim_argv += ["--parts", str(parts)]
    for s in sets:
        sim_argv += ["--set", s]
    daemon_argv = [b.nccompd, "--config", daemon_path]
    if speed is None:
        sim_argv += ["--lockstep", sock]
        daemon_argv += ["--lockstep", sock]
    else:
        sim_argv += ["--speed", str(speed)]
    t0 = time.monotonic()
    sim = daemon = None
    try:
        sim = Proc("ncsim", sim_argv, os.path.join(run_dir, "ncsim.log"), run_dir)
        # The daemon connects once ncsim serves: the lock-step socket, or the Modbus port.
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and sim.running():
            if speed is None and os.path.exists(sock):
                break
            if speed is not None and "ncsim: " in sim.log():
                break
            time.sleep(0.02)
        if not sim.running():
            raise RuntimeError("ncsim ended at start (status %s):\n%s" % (sim.p.returncode,
                                                                          sim.log()))
        daemon = Proc("nccompd", daemon_argv, os.path.join(run_dir, "nccompd.log"), run_dir)
        sim_rc = sim.wait(timeout_s)
        if sim_rc is None:
            raise RuntimeError("%s: ncsim did not finish within %.0f s\nncsim:\n%s\nnccompd:\n%s" %
                               (name, timeout_s, sim.log()[-3000:], daemon.log()[-3000:]))
        # Lock-step: BYE ends the daemon (exit 0). Real time: the operator's SIGTERM.
        if speed is not None:
            daemon.stop()
        daemon_rc = daemon.wait(15.0)
        if daemon_rc is None:
            daemon_rc = daemon.stop()
            raise RuntimeError("%s: nccompd did not end after ncsim's BYE\n%s" %
                               (name, daemon.log()[-3000:]))
    finally:
        for p in (daemon, sim):
            if p is not None:
                p.stop()
        shutil.rmtree(sock_dir, ignore_errors=True)
    wall_s = time.monotonic() - t0
    # The touch program has no surface to plot.
    svg = [] if program == "touch" else ["--svg", os.path.join(out_dir, "error.svg")]
    rep = subprocess.run([b.nccomp, "report", out_dir, "--json"] + svg,
                         capture_output=True, text=True, timeout=120)
    if rep.returncode != 0:
        raise RuntimeError("%s: nccomp report failed (%d): %s" % (name, rep.returncode,
                                                                  rep.stderr))
    with open(os.path.join(out_dir, "report.txt"), "w") as f:
        f.write(subprocess.run([b.nccomp, "report", out_dir], capture_output=True, text=True,
                               timeout=120).stdout)
    result = RunResult(name, run_dir, out_dir, sim_rc, daemon_rc, sim.log(), daemon.log(),
                       json.loads(rep.stdout), wall_s)
    if echo:
        echo("%s: ncsim %d, nccompd %d, %.1f s wall; %s" % (name, sim_rc, daemon_rc, wall_s,
                                                          summary_line(result.report)))
    return result


def summary_line(rep):
    s = rep.get("surface")
    if s:
        return ("max step %.3f um (offset change %.3f um), form RMS %.3f um, max %.3f um, "
                "%d writes" % (s["max_step_um"], s["max_offset_step_um"], s["form"]["rms_um"],
                               s["form"]["max_abs_um"], rep["writes_received"]))
    w = rep.get("walls")
    if w:
        return "walls form RMS %.3f um, max %.3f um, %d writes" % (
            w["form"]["rms_um"], w["form"]["max_abs_um"], rep["writes_received"])
    return "%d writes" % rep["writes_received"]


# ---------------------------------------------------------------------------------------------
# Scenarios (the e2e tests). Each raises AssertionError with the figures on failure.

MODES = [
    ("off", "no compensation", "nccompd-off.toml"),
    ("step", "step correction", "nccompd-step.toml"),
    ("creep", "creeping", "nccompd-creep.toml"),
    ("predict", "predictive creeping", "nccompd-predict.toml"),
]


class Check:
    def __init__(self, name):
        self.name = name
        self.failures = []

    def that(self, cond, what):
        print("  [%s] %s" % ("ok" if cond else "FAIL", what))
        if not cond:
            self.failures.append(what)

    def done(self):
        if self.failures:
            raise AssertionError("%s: %d check(s) failed:\n  %s" %
                                 (self.name, len(self.failures), "\n  ".join(self.failures)))


def run_modes(b, source, work, echo=print, speed=None, prefix="", seed=1, parallel=False):
    """The mould face in the four modes. parallel: all four at once (real time: each takes the
    part's machining time divided by the speed factor, mostly waiting)."""
    def one(mode):
        key, _, cfg = mode
        return key, run_machining(b, source, work, prefix + key, cfg, "ncsim-demo.toml",
                                  seed=seed, speed=speed, echo=echo)
    if not parallel:
        return dict(one(m) for m in MODES)
    import concurrent.futures
    with concurrent.futures.ThreadPoolExecutor(max_workers=len(MODES)) as pool:
        return dict(pool.map(one, MODES))


def modes_table(results):
    lines = ["| mode | max step within a pass [um] | largest offset change [um] | "
             "form error RMS [um] | form error max [um] | offset writes |",
             "| --- | --- | --- | --- | --- | --- |"]
    for key, label, _ in MODES:
        r = results[key].report
        s = r["surface"]
        lines.append("| %s | %.3f | %.3f | %.3f | %.3f | %d |" % (
            label, s["max_step_um"], s["max_offset_step_um"], s["form"]["rms_um"],
            s["form"]["max_abs_um"], r["writes_received"]))
    return "\n".join(lines)


def scenario_modbus_modes(b, source, work):
    """Part (a), four daemon configs, lock-step: the figures that make the case for creeping."""
    res = run_modes(b, source, work)
    print(modes_table(res))
    c = Check("modbus_modes")
    for key, label, _ in MODES:
        r = res[key]
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d (both 0)" % (label, r.ncsim_rc, r.daemon_rc))
        c.that(r.report["bad_rows"] == 0, "%s: no bad rows in the result" % label)
        c.that(not r.alarms("alarm"), "%s: no alarm logged (%s)" % (label, r.alarms("alarm")))
        c.that(r.report["alarms_seen"] == 0, "%s: NC saw no alarm" % label)
    off, step, creep, pred = (res[k].report for k in ("off", "step", "creep", "predict"))
    c.that(off["writes_received"] == 0 or all(abs(v) < 1e-9 for v in off["registers"].values()),
           "off: no offset applied (registers %s)" % off["registers"])
    for rep, label in ((step, "step"), (creep, "creep"), (pred, "predict")):
        c.that(rep["writes_received"] > 0 and any(abs(v) > 0.5 for v in rep["registers"].values()),
               "%s: registers written (%d writes, last %s)" % (label, rep["writes_received"],
                                                               rep["registers"]))
    ss, cs, ps = (r["surface"] for r in (step, creep, pred))
    c.that(ss["max_offset_step_um"] > 2.0,
           "step correction moves the offset at once: %.3f um > 2 um" % ss["max_offset_step_um"])
    c.that(cs["max_step_um"] < 0.25 * ss["max_step_um"],
           "creeping max step %.3f um < 1/4 of step correction's %.3f um" %
           (cs["max_step_um"], ss["max_step_um"]))
    c.that(ps["max_step_um"] < 0.25 * ss["max_step_um"],
           "predictive creeping max step %.3f um < 1/4 of step correction's %.3f um" %
           (ps["max_step_um"], ss["max_step_um"]))
    # Not 1/100 (h·Δs/L would allow it): where a pass turns, the length / radius split of the
    # correction follows the engagement angle one NC latency late, a 0.4 um blip for ~1 mm.
    c.that(cs["max_offset_step_um"] < 0.25 * ss["max_offset_step_um"],
           "creeping offset change %.3f um < 1/4 of the step's %.3f um" %
           (cs["max_offset_step_um"], ss["max_offset_step_um"]))
    fo = off["surface"]["form"]["rms_um"]
    for rep, label in ((step, "step correction"), (creep, "creeping"),
                       (pred, "predictive creeping")):
        c.that(rep["surface"]["form"]["rms_um"] < fo,
               "%s form error RMS %.3f um < %.3f um without compensation" %
               (label, rep["surface"]["form"]["rms_um"], fo))
    c.done()


def value_in_force(writes, register, t_s):
    """The value of `register` the NC took last at or before t_s (0 before any write)."""
    v = 0.0
    for t, r, val, _ in writes:
        if r == register and t <= t_s:
            v = val
    return v


def scenario_broken_tool(b, source, work):
    """Part (a) with creeping; the tool breaks after the first laser measurement: alarm 23
    (tool_broken_or_mismeasured), and nothing of that measurement applied."""
    r = run_machining(b, source, work, "broken_tool", "nccompd-creep.toml", "ncsim-demo.toml",
                      sets=["broken_tool.enabled=true", "broken_tool.at_path_mm=700"],
                      echo=print)
    c = Check("broken_tool")
    c.that(r.ncsim_rc in (0, 4) and r.daemon_rc == 0,
           "ncsim exit %d, nccompd exit %d" % (r.ncsim_rc, r.daemon_rc))
    c.that(("tool_broken_or_mismeasured", 23) in r.alarms("alarm"),
           "alarm tool_broken_or_mismeasured (code 23) logged: %s" % r.alarms("alarm"))
    # One row per edge support point: a measurement is one time.
    times = sorted({float(m["time_s"]) for m in r.measurements() if m.get("kind") == "tool_wear"})
    c.that(len(times) >= 2, "the laser measured at least twice (at %s s)" % times)
    writes = r.writes()
    if len(times) >= 2:
        # The broken measurement is the first one after the break (path 700 mm; ncsim measures
        # every 450 mm). Everything the NC took from then on must hold the value in force then:
        # nothing applied, creep frozen.
        t_broken = times[1]
        regs = sorted({w[1] for w in writes})
        for reg in regs:
            held = value_in_force(writes, reg, t_broken + 0.05)
            later = [w[2] for w in writes if w[1] == reg and w[0] > t_broken + 0.05]
            c.that(all(abs(v - held) < 1e-6 for v in later),
                   "register %d holds %.3f um after the broken tool (%d later writes, range "
                   "%s)" % (reg, held, len(later),
                            (min(later), max(later)) if later else "-"))
            final = r.report["registers"].get(str(reg), 0.0)
            c.that(abs(final - held) < 1e-6,
                   "register %d ends at %.3f um, the value held at the break" % (reg, final))
        # The creep in progress was frozen: what it had fed in stays, never the 300 um jump.
        c.that(any(abs(v) > 0.5 for v in r.report["registers"].values()),
               "the wear measured before the break was applied: %s" % r.report["registers"])
    c.done()


def scenario_implausible_probe(b, source, work):
    """Part (b) (side wall), per-checkpoint compensation; one probe reading of part 1 is 500 um
    off (a chip under the ball): alarm, that checkpoint's value not applied."""
    r = run_machining(b, source, work, "implausible_probe", "nccompd-walls.toml",
                      "ncsim-demo.toml", program="side_wall", parts=3,
                      sets=["probe_outlier.enabled=true", "probe_outlier.part=1",
                            "probe_outlier.checkpoint=0", "probe_outlier.value_um=500"],
                      echo=print)
    c = Check("implausible_probe")
    c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
           "ncsim exit %d, nccompd exit %d" % (r.ncsim_rc, r.daemon_rc))
    names = [a[0] for a in r.alarms("alarm")] + [a[0] for a in r.alarms("warning")]
    c.that(any(n in ("probe_implausible", "probe_outlier") for n in names),
           "probe_implausible / probe_outlier raised: %s" % names)
    writes = r.writes()
    c.that(all(abs(w[2]) < 100.0 for w in writes),
           "no write carries the 500 um reading (largest %.3f um)" %
           max([abs(w[2]) for w in writes] + [0.0]))
    # Part 2 is cut with what part 1 taught: nothing at checkpoint 0 (its reading was refused),
    # the learned values at the three others.
    rows = {(int(m["part"]), int(m["point"])): m for m in r.measurements()
            if m.get("kind") == "contour"}
    c.that(abs(float(rows[(1, 0)]["measured_um"])) > 400.0 if (1, 0) in rows else False,
           "part 1 checkpoint 0 logged with the implausible reading")
    if (2, 0) in rows:
        c.that(abs(float(rows[(2, 0)]["applied_um"])) < 1e-9,
               "part 2 checkpoint 0 cut with nothing applied (applied_um %s)" %
               rows[(2, 0)]["applied_um"])
    for cp in (1, 2, 3):
        if (2, cp) in rows:
            c.that(abs(float(rows[(2, cp)]["applied_um"])) > 0.5,
                   "part 2 checkpoint %d cut with part 1's value (applied_um %s)" %
                   (cp, rows[(2, cp)]["applied_um"]))
    c.that(len(rows) == 12, "4 checkpoints x 3 parts probed and logged (%d)" % len(rows))
    c.done()


def scenario_undeclared_effect(b, source, work):
    """Issue 11 item 5: ncsim machines 12 side walls with its tool wear switched on (20 um per m
    of path), the daemon's declared model (config/demo/model-declared.toml) has no wear term;
    the daemon logs its probe measurements, and `nccomp analyze` on that log must find the
    effect (a trend over the parts: the probe rows carry no cut path) and report the error
    before and after, on fitted and held-out rows.

    (The thermal drift is not used: ncsim's probe sits in the spindle and moves with the drift,
    so the walls' probe readings do not see it; only the touch cycles on the test body do, and
    the daemon's [calibration] reference machine does not match ncsim's touch program yet.)"""
    r = run_machining(b, source, work, "undeclared", "nccompd-walls.toml", "ncsim-demo.toml",
                      program="side_wall", parts=12,
                      sets=["wear.enabled=true", "wear.rate_um_per_m=20"], echo=print)
    c = Check("undeclared_effect")
    c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
           "ncsim exit %d, nccompd exit %d" % (r.ncsim_rc, r.daemon_rc))
    log = os.path.join(r.run_dir, "log", "measurements.csv")
    rows = [m for m in r.measurements() if m.get("kind") == "contour"]
    c.that(len(rows) == 48, "the daemon logged 4 checkpoints x 12 parts = %d probe rows" %
           len(rows))
    out = os.path.join(r.run_dir, "analysis")
    a = subprocess.run([b.nccomp, "analyze", "--log", log, "--config",
                        os.path.join(source, "config", "demo", "model-declared.toml"),
                        "--out", out], capture_output=True, text=True, timeout=300)
    print(a.stdout)
    c.that(a.returncode == 0, "nccomp analyze exit %d %s" % (a.returncode, a.stderr[-500:]))
    if a.returncode == 0:
        with open(os.path.join(out, "summary.json")) as f:
            s = json.load(f)
        effects = s.get("effects", [])
        names = [e["name"] for e in effects]
        c.that(bool(effects) and effects[0]["name"] in ("part_trend", "tool_wear"),
               "analyze added the wear first, as part_trend or tool_wear: %s" % names)
        if effects:
            e = effects[0]
            c.that(e["rms_after_um"] < 0.5 * e["rms_before_um"],
                   "%s: RMS %.3f -> %.3f um (less than half)" % (
                       e["name"], e["rms_before_um"], e["rms_after_um"]))
            c.that(e["heldout_rms_after_um"] < 0.5 * e["heldout_rms_before_um"],
                   "%s: held-out RMS %.3f -> %.3f um (less than half)" % (
                       e["name"], e["heldout_rms_before_um"], e["heldout_rms_after_um"]))
        c.that(s["final_rms_um"] < 1.5 * s["noise_floor_um"],
               "final RMS %.3f um within 1.5 x the noise floor %.3f um" % (
                   s["final_rms_um"], s["noise_floor_um"]))
    c.done()


def read_csv_rows(path):
    """Rows of a result CSV as dicts (header line first, C3)."""
    import csv
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def wall_figures(r, first_part):
    """Per part: RMS of the checkpoint errors after machining and RMS / peak-to-valley of the wall
    error (walls.csv), from ncsim's result directory; and the same over parts >= first_part."""
    cps = read_csv_rows(os.path.join(r.out_dir, "checkpoints.csv"))
    walls = read_csv_rows(os.path.join(r.out_dir, "walls.csv"))

    def rms(v):
        return math.sqrt(sum(x * x for x in v) / len(v)) if v else float("nan")

    parts = sorted({int(x["part"]) for x in cps})
    per_part = {}
    for p in parts:
        ce = [float(x["error_um"]) for x in cps if int(x["part"]) == p]
        we = [float(x["error_um"]) for x in walls if int(x["part"]) == p]
        per_part[p] = (rms(ce), rms(we), (max(we) - min(we)) if we else float("nan"))
    later_c = [float(x["error_um"]) for x in cps if int(x["part"]) >= first_part]
    later_w = [float(x["error_um"]) for x in walls if int(x["part"]) >= first_part]
    return per_part, rms(later_c), rms(later_w)


def scenario_model_loop(b, source, work):
    """Issue 11 item 5, the loop closed on ncsim: 12 side walls with ncsim's tool wear switched on
    (20 um per m, an effect the declared model lacks) and S1 checkpoints only; `nccomp analyze`
    on the daemon's log adds part_trend and writes model.toml; the daemon then loads it ([model],
    config/demo/nccompd-walls-model.toml: part_trend as a trim on the radius wear register) and
    the same 12 walls are machined again. The checkpoint and wall errors of the parts themselves
    (ncsim's checkpoints.csv / walls.csv) must drop. Part 1 is left out of the comparison: it is
    cut before anything was probed in both runs."""
    sets = ["wear.enabled=true", "wear.rate_um_per_m=20"]
    before = run_machining(b, source, work, "loop_before", "nccompd-walls.toml",
                           "ncsim-demo.toml", program="side_wall", parts=12, sets=sets,
                           echo=print)
    c = Check("model_loop")
    c.that(before.ncsim_rc == 0 and before.daemon_rc == 0,
           "before: ncsim exit %d, nccompd exit %d" % (before.ncsim_rc, before.daemon_rc))
    log = os.path.join(before.run_dir, "log", "measurements.csv")
    out = os.path.join(before.run_dir, "analysis")
    a = subprocess.run([b.nccomp, "analyze", "--log", log, "--config",
                        os.path.join(source, "config", "demo", "model-declared.toml"),
                        "--out", out], capture_output=True, text=True, timeout=300)
    print(a.stdout)
    model = os.path.join(out, "model.toml")
    c.that(a.returncode == 0 and os.path.exists(model),
           "nccomp analyze exit %d %s" % (a.returncode, a.stderr[-500:]))
    if a.returncode != 0:
        c.done()
        return
    with open(os.path.join(out, "summary.json")) as f:
        names = [e["name"] for e in json.load(f).get("effects", [])]
    c.that("part_trend" in names, "analyze added part_trend: %s" % names)
    after = run_machining(b, source, work, "loop_after", "nccompd-walls-model.toml",
                          "ncsim-demo.toml", program="side_wall", parts=12, sets=sets,
                          overrides={"nccompd.toml": {"model.file": '"%s"' % model}},
                          echo=print)
    c.that(after.ncsim_rc == 0 and after.daemon_rc == 0,
           "after: ncsim exit %d, nccompd exit %d" % (after.ncsim_rc, after.daemon_rc))
    c.that(not after.alarms("alarm"), "after: no alarm logged (%s)" % after.alarms("alarm"))
    pb, cb, wb = wall_figures(before, 2)
    pa, ca, wa = wall_figures(after, 2)
    print("part | checkpoint RMS before | after | wall RMS before | after | wall p-v before | after")
    for p in sorted(pb):
        if p in pa:
            print("%4d | %8.3f | %8.3f | %8.3f | %8.3f | %8.3f | %8.3f" % (
                p, pb[p][0], pa[p][0], pb[p][1], pa[p][1], pb[p][2], pa[p][2]))
    print("parts 2-12: checkpoint RMS %.3f -> %.3f um, wall RMS %.3f -> %.3f um" % (cb, ca, wb, wa))
    c.that(len(pa) == 12 and len(pb) == 12, "12 parts in both runs (%d, %d)" % (len(pb), len(pa)))
    c.that(ca < 0.5 * cb, "checkpoint error of parts 2-12 drops by more than half: %.3f -> %.3f um"
           % (cb, ca))
    c.that(wa < wb, "wall error of parts 2-12 drops: %.3f -> %.3f um" % (wb, wa))
    c.done()


def scenario_can_modes(b, source, work):
    """Over CAN (vcan0; run inside tests/hil/vm/run_in_vm.sh): an 11-pass mould face with step
    correction and with creeping, lock-step with SYNC / SYNC-ACK frames. The CAN profile has four
    logical registers (0/1 tool wear, 2 a checkpoint, 3 the Z axis offset): ncsim is told so."""
    nc = {"nc.axis_x_register": "-1", "nc.axis_y_register": "-1", "nc.axis_z_register": "3",
          "nc.checkpoint_base_register": "2", "nc.checkpoint_register_count": "1",
          "program.mould_face.size_y_mm": "10.0"}
    res = {}
    for key, cfg in (("step", "nccompd-step-can.toml"), ("creep", "nccompd-creep-can.toml")):
        res[key] = run_machining(b, source, work, "can_" + key, cfg, "ncsim-demo.toml",
                                 bus="can", overrides={"ncsim.toml": nc}, echo=print)
    c = Check("can_modes")
    for key, r in res.items():
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d" % (key, r.ncsim_rc, r.daemon_rc))
        c.that(not r.alarms("alarm"), "%s: no alarm logged (%s)" % (key, r.alarms("alarm")))
        c.that(r.report["bus"] == "can" and r.report["writes_received"] > 0,
               "%s: offsets written over CAN (%d)" % (key, r.report["writes_received"]))
        c.that(any(abs(v) > 0.5 for v in r.report["registers"].values()),
               "%s: registers hold the wear correction: %s" % (key, r.report["registers"]))
    ss, cs = res["step"].report["surface"], res["creep"].report["surface"]
    c.that(ss["max_step_um"] > 2.0, "step correction cuts a step: %.3f um" % ss["max_step_um"])
    c.that(cs["max_step_um"] < 0.25 * ss["max_step_um"],
           "creeping max step %.3f um < 1/4 of step correction's %.3f um" %
           (cs["max_step_um"], ss["max_step_um"]))
    c.done()


def scenario_calib_touch(b, source, work):
    """S3: ncsim's touch program + nccompd, calibrated over the command channel (calib_e2e.py)."""
    import calib_e2e  # tests/e2e/calib_e2e.py, next to this file
    calib_e2e.scenario(sys.modules[__name__], b, source, work)


SCENARIOS = {
    "modbus_modes": scenario_modbus_modes,
    "broken_tool": scenario_broken_tool,
    "implausible_probe": scenario_implausible_probe,
    "undeclared_effect": scenario_undeclared_effect,
    "model_loop": scenario_model_loop,
    "can_modes": scenario_can_modes,
    "calib_touch": scenario_calib_touch,
}


# ---------------------------------------------------------------------------------------------
# The demo (scripts/demo)


def demo(b, source, work, speed):
    os.makedirs(work, exist_ok=True)
    mode = "lock-step" if speed is None else "real time, ncsim at x%g" % speed
    print("demo: machining the mould face (part a) four times over Modbus TCP on 127.0.0.1, %s"
          % mode, flush=True)
    res = run_modes(b, source, work, speed=speed, parallel=speed is not None,
                    echo=lambda s: print("  " + s, flush=True))
    print()
    print(modes_table(res))
    print()
    for key, label, _ in MODES:
        r = res[key]
        print("%-22s report: nccomp report %s   plot: %s" % (
            label, r.out_dir, os.path.join(r.out_dir, "error.svg")))
    with open(os.path.join(work, "table.md"), "w") as f:
        f.write(modes_table(res) + "\n")
    bad = [k for k, r in res.items() if r.ncsim_rc != 0 or r.daemon_rc != 0]
    if bad:
        print("demo: runs that did not end cleanly: %s (logs in %s)" % (bad, work))
        return 1
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin-dir", required=True, help="CMake build directory")
    ap.add_argument("--source", required=True, help="source tree (config/demo/)")
    ap.add_argument("--work", required=True, help="directory for the runs (recreated per run)")
    ap.add_argument("--nccompd", help="the daemon binary (default BUILD/daemon/nccompd)")
    ap.add_argument("--ncsim", help="the virtual NC (default BUILD/sim/ncsim/ncsim)")
    ap.add_argument("--nccomp", help="the operator command (default BUILD/tools/nccomp)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sc = sub.add_parser("scenario")
    sc.add_argument("name", choices=sorted(SCENARIOS))
    dm = sub.add_parser("demo")
    dm.add_argument("--realtime", type=float, default=None, metavar="SPEED",
                    help="real-time daemon, ncsim at this speed factor (default: lock-step)")
    args = ap.parse_args()
    # SIGTERM / Ctrl-C (scripts/demo's trap, an operator): stop every ncsim and nccompd this
    # runner started (runs may be in worker threads), then leave.
    def on_signal(signum, _frame):
        for p in list(LIVE):
            p.stop(grace_s=2.0)
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    b = Binaries(args.bin_dir, args.nccompd, args.ncsim, args.nccomp)
    args.source = os.path.abspath(args.source)
    args.work = os.path.abspath(args.work)
    if args.cmd == "demo":
        return demo(b, args.source, args.work, args.realtime)
    work = os.path.join(args.work, args.name)
    os.makedirs(work, exist_ok=True)
    try:
        SCENARIOS[args.name](b, args.source, work)
    except (AssertionError, RuntimeError) as e:
        print("FAILED: %s" % e, file=sys.stderr)
        return 1
    print("PASSED: %s" % args.name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
