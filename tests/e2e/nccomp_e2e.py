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

demo: the four modes, the loop (run_demo) and WORK/summary.json.
"""

import argparse
import json
import math
import os
import random
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
    """A TCP port nobody listens on right now, for a server a test starts later. Drawn below the
    kernel's ephemeral range (net.ipv4.ip_local_port_range): the kernel's own choice for port 0
    comes from that range, so a client's source port (this test's or another's, two tests run at
    once) could take it between this call and the server's bind; below the range only another
    test's draw can, one in ~12 000."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            low = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768
    top = max(low, 20001)
    rng = random.SystemRandom()
    for _ in range(200):
        port = rng.randrange(max(1024, top - 12000), top)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError("no free TCP port below %d after 200 draws" % top)


# ---------------------------------------------------------------------------------------------
# Configs

PATH_KEYS = re.compile(r'^(\s*(?:[a-z_]*bus_map|(?:[a-z_]*_)?file)\s*=\s*)"([^"]*)"', re.M)
# Keys that hold a list of files: the daemon's include, ncsim's extra map files.
PATH_LISTS = re.compile(r'^(\s*(?:include|bus_map_extra|can_bus_map_extra)\s*=\s*)\[([^\]]*)\]',
                        re.M)


def stage_configs(source, run_dir, daemon_cfg, ncsim_cfg, port, overrides=None):
    """Copies config/demo/<daemon_cfg> and <ncsim_cfg> into run_dir. The Modbus map they share
    is staged as run_dir/map.toml with `port` (so runs never collide); every other file path in
    them becomes absolute (they stay where they are). overrides: {staged name: {"table.key":
    value}}; an included file named there by its base name (e.g. "side_wall_checkpoints.toml")
    is staged too, with its overrides. Returns (daemon_path, ncsim_path)."""
    demo = os.path.join(source, "config", "demo")
    with open(os.path.join(source, "config", "reference-nc-modbus.toml")) as f:
        map_text = f.read()
    map_text, n = re.subn(r"^port = \d+", "port = %d" % port, map_text, flags=re.M)
    if n != 1:
        raise RuntimeError("reference-nc-modbus.toml: expected one 'port = N' line, found %d" % n)
    map_path = os.path.join(run_dir, "map.toml")
    with open(map_path, "w") as f:
        f.write(map_text)

    overrides = overrides or {}

    def fix_path(p, base):
        if os.path.basename(p) == "reference-nc-modbus.toml":
            return "map.toml"
        full = p if os.path.isabs(p) else os.path.normpath(os.path.join(base, p))
        if os.path.basename(p) in overrides:
            return stage(full, os.path.basename(p))
        return full

    def stage(src, out_name):
        base = os.path.dirname(src)
        with open(src) as f:
            text = f.read()
        text = PATH_KEYS.sub(lambda m: '%s"%s"' % (m.group(1), fix_path(m.group(2), base)), text)

        def fix_list(m):
            items = [s.strip().strip('"') for s in m.group(2).split(",") if s.strip()]
            return m.group(1) + "[" + ", ".join('"%s"' % fix_path(i, base) for i in items) + "]"

        text = PATH_LISTS.sub(fix_list, text)
        name = os.path.basename(src)
        for key, value in overrides.get(out_name, {}).items():
            # "table.key" → replace the key's line inside that table; "table#N.key": inside the
            # N-th (from 0) entry of an array of tables.
            table, k = key.rsplit(".", 1)
            table, _, nth = table.partition("#")
            pat = re.compile(r"(^\[\[?%s\]\]?\s*$(?:(?!^\[).)*?^%s\s*=\s*)[^\n]*" %
                             (re.escape(table), re.escape(k)), re.M | re.S)
            found = list(pat.finditer(text))
            if len(found) != 1 and not (nth and int(nth) < len(found)):
                raise RuntimeError("%s: cannot override %s" % (name, key))
            m = found[int(nth) if nth else 0]
            text = text[:m.start()] + m.group(1) + value + text[m.end():]
        path = os.path.join(run_dir, out_name)
        with open(path, "w") as f:
            f.write(text)
        return path

    return (stage(os.path.join(demo, daemon_cfg), "nccompd.toml") if daemon_cfg else None,
            stage(os.path.join(demo, ncsim_cfg), "ncsim.toml"))


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

    def report_json_alarms(self):
        """ncsim's result.json "alarms": every rise of an NC alarm register."""
        with open(os.path.join(self.out_dir, "result.json")) as f:
            return json.load(f).get("alarms", [])

    def laser(self):
        """ncsim's laser rows of measurements.csv (dicts of strings)."""
        return [m for m in read_csv_rows(os.path.join(self.out_dir, "measurements.csv"))
                if m["kind"] == "laser"]

    def tool_wear_paths(self):
        """(time_s, path_mm) of every tool measurement the daemon logged (one per measurement,
        not per edge point)."""
        seen = {}
        for m in self.measurements():
            if m.get("kind") == "tool_wear":
                seen.setdefault(m["time_s"], float(m["path_mm"]))
        return sorted((float(t), p) for t, p in seen.items())

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


def state_on_disk(b, status_sock):
    """True when nccompd's persister has written every state export its loop submitted."""
    p = subprocess.run([b.nccomp, "status", "--json", "--socket", status_sock],
                       capture_output=True, text=True, timeout=30)
    try:
        st = json.loads(p.stdout)
        return st["state"]["writes"] + st["state"]["failures"] >= st["loop"]["state_exports"]
    except (ValueError, KeyError):
        return False


def run_machining(b, source, work, name, daemon_cfg, ncsim_cfg, program="mould_face",
                  seed=1, parts=None, sets=(), overrides=None, speed=None, timeout_s=240.0,
                  echo=None, bus="modbus", continue_from=None, outage=None):
    """Machines one program with ncsim + nccompd; returns a RunResult. speed=None: lock-step
    (deterministic); else real time with ncsim at that speed factor. continue_from: the result
    directory of an earlier run that ncsim continues (`ncsim --continue`: the next part number,
    the worn tool). outage = (n, after_s, down_s) (lock-step, Modbus): after_s of simulated time
    after the NC's request register rose for the n-th time (the NC sends the tool to the laser),
    ncsim stops ticking (`ncsim --lockstep-outage`), nccompd is killed (SIGKILL) and started
    again, and ncsim machines down_s of simulated time without it before it takes the new one."""
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
    if continue_from is not None:
        sim_argv += ["--continue", continue_from]
    for s in sets:
        sim_argv += ["--set", s]
    daemon_argv = [b.nccompd, "--config", daemon_path]
    if speed is None:
        sim_argv += ["--lockstep", sock]
        daemon_argv += ["--lockstep", sock]
        if outage is not None:
            sim_argv += ["--lockstep-outage", "%d,%g,%g" % outage]
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
        if outage is not None:
            deadline = time.monotonic() + timeout_s
            while ("lock-step outage at cycle" not in sim.log() and sim.running() and
                   time.monotonic() < deadline):
                time.sleep(0.02)
            if "lock-step outage at cycle" not in sim.log():
                raise RuntimeError("%s: ncsim did not stop for the outage\n%s" %
                                   (name, sim.log()[-3000:]))
            # Killed once every state export the loop submitted is on disk (the persister writes
            # them on its own thread, at the disk's pace), so that the killed state is the same
            # in every run; at most 15 s (ncsim gives up on a daemon still there after 30 s).
            status_sock = os.path.join(sock_dir, "status.sock")
            written_by = time.monotonic() + 15.0
            while not state_on_disk(b, status_sock):
                if time.monotonic() > written_by:
                    print("  [note] %s: nccompd's state exports not all on disk after 15 s; "
                          "killed anyway" % name)
                    break
                time.sleep(0.05)
            os.killpg(daemon.p.pid, signal.SIGKILL)
            daemon.p.wait()
            killed_log = daemon.log()
            daemon.stop()
            daemon = Proc("nccompd", daemon_argv, os.path.join(run_dir, "nccompd-2.log"),
                          run_dir)
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
    # Kept with the run (`nccomp report DIR` prints the same as text).
    with open(os.path.join(out_dir, "report.json"), "w") as f:
        f.write(rep.stdout)
    daemon_log = daemon.log()
    if outage is not None:
        daemon_log = killed_log + "--- nccompd killed (SIGKILL), started again ---\n" + daemon_log
    result = RunResult(name, run_dir, out_dir, sim_rc, daemon_rc, sim.log(), daemon_log,
                       json.loads(rep.stdout), wall_s)
    if echo:
        echo("%s: ncsim %d, nccompd %d, %.1f s wall; %s" % (name, sim_rc, daemon_rc, wall_s,
                                                          summary_line(result.report)))
    return result


def run_ncsim_alone(b, source, work, name, program, sets=(), timeout_s=120.0):
    """ncsim without a daemon (nothing writes offsets), as fast as it goes; returns the report
    of its result directory (nccomp report --json) and the result directory."""
    run_dir = os.path.join(work, name)
    shutil.rmtree(run_dir, ignore_errors=True)
    os.makedirs(run_dir)
    out_dir = os.path.join(run_dir, "out")
    _, ncsim_path = stage_configs(source, run_dir, None, "ncsim-demo.toml", free_port())
    argv = [b.ncsim, "--config", ncsim_path, "--program", program, "--bus", "modbus",
            "--out", out_dir, "--speed", "1000000", "--wait-client", "0"]
    for s_ in sets:
        argv += ["--set", s_]
    sim = Proc("ncsim", argv, os.path.join(run_dir, "ncsim.log"), run_dir)
    try:
        rc = sim.wait(timeout_s)
    finally:
        sim.stop()
    if rc != 0:
        raise RuntimeError("%s: ncsim exit %s\n%s" % (name, rc, sim.log()[-3000:]))
    rep = subprocess.run([b.nccomp, "report", out_dir, "--json", "--svg",
                          os.path.join(out_dir, "error.svg")],
                         capture_output=True, text=True, timeout=120)
    if rep.returncode != 0:
        raise RuntimeError("%s: nccomp report failed (%d): %s" % (name, rep.returncode,
                                                                  rep.stderr))
    return json.loads(rep.stdout), out_dir


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
# The laser interval of the demo daemons ([creep.interval] interval_mm): ncsim measures when the
# daemon asks (its request register). Without compensation nothing asks, so ncsim measures on its own at the
# same interval: every mode's part sees the same laser trips.
LASER_INTERVAL_MM = 450.0
MODE_SETS = {"off": ["program.mould_face.measure_interval_mm=%g" % LASER_INTERVAL_MM]}


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
                                  seed=seed, speed=speed, echo=echo,
                                  sets=MODE_SETS.get(key, []))
    if not parallel:
        return dict(one(m) for m in MODES)
    import concurrent.futures
    with concurrent.futures.ThreadPoolExecutor(max_workers=len(MODES)) as pool:
        return dict(pool.map(one, MODES))


def modes_table(results):
    """The table of the modes in results (MODES' order, then the demo's model row)."""
    lines = ["| mode | max step within a pass [um] | largest offset change [um] | "
             "form error RMS [um] | form error max [um] | offset writes |",
             "| --- | --- | --- | --- | --- | --- |"]
    for key, label in [(k, l) for k, l, _ in MODES] + [LOOP_MODE]:
        if key not in results:
            continue
        r = results[key].report
        s = r["surface"]
        lines.append("| %s | %.3f | %.3f | %.3f | %.3f | %d |" % (
            label, s["max_step_um"], s["max_offset_step_um"], s["form"]["rms_um"],
            s["form"]["max_abs_um"], r["writes_received"]))
    return "\n".join(lines)


# Flag registers of the demo NC per bus (config/demo/nc-flags-modbus.toml, nc-extra-can.toml):
# the daemon's creep alarm flag (the NC shows it as an alarm) and its "measurement due" flag (the
# NC sends the tool to the laser when it rises).
FLAGS = {"modbus": (9, 10), "can": (4, 5)}
# nccompd's start-up line when it read the NC's registers back (Modbus read_offset).
READ_BACK_LINE = re.compile(r"registers: (\d+) of (\d+) read back from the NC")
REQUEST_TOLERANCE_MM = 3.0
LASER_TRIP_S = 4.0  # ncsim-demo.toml program.mould_face.laser_trip_s: measured half-way


def offsets(report):
    """The last value of every offset register the NC took (the flag registers left out)."""
    return {k: v for k, v in report["registers"].items()
            if int(k) not in FLAGS[report["bus"]]}


def request_edges(r):
    """Times [s] at which the NC's request register went from 0 to 1 (the value in force)."""
    request = FLAGS[r.report["bus"]][1]
    edges, v = [], 0.0
    for _, reg, val, eff in r.writes():
        if reg == request:
            if v == 0.0 and val != 0.0:
                edges.append(eff)
            v = val
    return edges


def check_laser_on_request(c, r, label, interval_mm, trip_s=LASER_TRIP_S, min_trips=3,
                           speed=None):
    """The laser measured when the daemon asked, and only then: every rise of the NC's request
    register (the daemon's "measurement due" flag) sent the tool to the laser (measured half-way
    through the trip), there was no other trip, the daemon logged each measurement at ncsim's
    time, each interval_mm of the daemon's cut path after the previous one (plus the request's
    lag: one cycle and the NC's latency, ~1 mm). speed: the daemon ran on the wall clock and ncsim
    at this speed factor, so the daemon's times are ncsim's divided by it (compared from the first
    measurement on) and the request's lag covers speed times as much path."""
    due = [a for a in r.alarms("info") if a[1] == 24]
    edges = request_edges(r)
    laser = r.laser()
    logged = r.tool_wear_paths()
    if speed is not None and len(edges) == len(laser) + 1:
        # On the wall clock the request reaches the NC a poll and a write later in ncsim's time
        # (x speed): one raised in the part's last millimetres can arrive after the program
        # ended, and an NC does not go to the laser after the end of its program.
        print("  [note] %s: the last request (at %.3f s) reached the NC after the program's last "
              "cut; not served" % (label, edges[-1]))
        edges = edges[:-1]
    c.that(len(laser) >= min_trips and len(laser) == len(edges) == len(logged) and
           len(due) >= len(edges),
           "%s: %d laser trips, %d rises of the request register, %d measurements logged "
           "(equal, >= %d), %d requests raised" %
           (label, len(laser), len(edges), len(logged), min_trips, len(due)))
    c.that(len(laser) == len(edges) and
           all(0 <= float(m["t_s"]) - e - trip_s / 2 <= 0.05 for m, e in zip(laser, edges)),
           "%s: each trip started when the request reached the NC (at %s s; laser at %s s)" %
           (label, ["%.3f" % e for e in edges], [m["t_s"] for m in laser]))
    if speed is None:
        c.that(all(abs(float(m["t_s"]) - t) < 0.02 for m, (t, _) in zip(laser, logged)),
               "%s: laser at %s s, the daemon logged %s s" %
               (label, [m["t_s"] for m in laser], [t for t, _ in logged]))
    else:
        sim = [float(m["t_s"]) - float(laser[0]["t_s"]) for m in laser] if laser else []
        own = [(t - logged[0][0]) * speed for t, _ in logged] if logged else []
        c.that(len(sim) == len(own) and all(abs(a - b) < 0.1 for a, b in zip(sim, own)),
               "%s: the daemon logged each measurement at ncsim's time / %g (from the first: "
               "ncsim %s s, daemon x%g %s s)" % (label, speed, ["%.3f" % t for t in sim], speed,
                                                 ["%.3f" % t for t in own]))
    tolerance_mm = REQUEST_TOLERANCE_MM * (1.0 if speed is None else speed)
    steps = [b - a for a, b in zip([0.0] + [p for _, p in logged], [p for _, p in logged])]
    c.that(all(interval_mm <= d <= interval_mm + tolerance_mm for d in steps),
           "%s: the daemon's cut path between measurements %s mm is its interval %g mm (+ < %g)" %
           (label, ["%.2f" % d for d in steps], interval_mm, tolerance_mm))


def check_modes(c, res, interval_mm, trip_s, min_step_um, speed=None):
    """The assertions of the four modes on one part (Modbus and CAN alike). speed: the
    daemon ran against the wall clock (ncsim at a speed factor), so the absolute bound on the
    creeping step (set by the lock-step's one offset update per cycle of simulated time) is not
    asserted; the comparisons with step correction and no compensation are."""
    for key, label, _ in MODES:
        r = res[key]
        bus = r.report["bus"]
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d (both 0)" % (label, r.ncsim_rc, r.daemon_rc))
        c.that(r.report["bad_rows"] == 0, "%s: no bad rows in the result" % label)
        c.that(not r.alarms("alarm"), "%s: no alarm logged (%s)" % (label, r.alarms("alarm")))
        c.that(r.report["alarms_seen"] == 0, "%s: NC saw no alarm" % label)
        if key != "off":
            # The alarm register is live: the daemon's flag (0) is what the NC's alarm register
            # holds. Either the daemon wrote it, or (Modbus, read back at start-up) it read the
            # NC's 0 and its limiter started there, so there was nothing to write. That it rises
            # is checked by the broken tool.
            alarm = FLAGS[bus][0]
            written = any(w[1] == alarm for w in r.writes())
            read_back = READ_BACK_LINE.search(r.daemon_log)
            c.that((written or (read_back is not None and
                                read_back.group(1) == read_back.group(2))) and
                   r.report["registers"].get(str(alarm), 0) == 0,
                   "%s: the NC's alarm register %d holds the daemon's flag 0 (%s)" %
                   (label, alarm, "written" if written else
                    "read back at start-up: %s" % (read_back.group(0) if read_back else "no")))
            check_laser_on_request(c, r, label, interval_mm, trip_s, speed=speed)
    laser_off = [float(m["cut_path_mm"]) for m in res["off"].laser()]
    steps_off = [b_ - a_ for a_, b_ in zip([0.0] + laser_off, laser_off)]
    c.that(len(laser_off) >= 3 and all(interval_mm <= d < interval_mm + 0.1 for d in steps_off),
           "off: ncsim measured on its own every %g mm (+ one model step): %s" %
           (interval_mm, laser_off))
    off, step, creep, pred = (res[k].report for k in ("off", "step", "creep", "predict"))
    c.that(off["writes_received"] == 0 or all(abs(v) < 1e-9 for v in offsets(off).values()),
           "off: no offset applied (registers %s)" % off["registers"])
    for rep, label in ((step, "step"), (creep, "creep"), (pred, "predict")):
        c.that(rep["writes_received"] > 0 and any(abs(v) > 0.5 for v in offsets(rep).values()),
               "%s: registers written over %s (%d writes, last %s)" % (
                   label, rep["bus"], rep["writes_received"], offsets(rep)))
    ss, cs, ps = (r["surface"] for r in (step, creep, pred))
    c.that(ss["max_offset_step_um"] > min_step_um,
           "step correction moves the offset at once: %.3f um > %g um" % (
               ss["max_offset_step_um"], min_step_um))
    c.that(cs["max_step_um"] < 0.25 * ss["max_step_um"],
           "creeping max step %.3f um < 1/4 of step correction's %.3f um" %
           (cs["max_step_um"], ss["max_step_um"]))
    c.that(ps["max_step_um"] < 0.25 * ss["max_step_um"],
           "predictive creeping max step %.3f um < 1/4 of step correction's %.3f um" %
           (ps["max_step_um"], ss["max_step_um"]))
    # Across the laser trips too: the NC publishes no normal while the tool is away, the daemon
    # holds the last one, so the radius / length split does not move (it used to: 0.30 um steps
    # at the return). What is left is the registers' 0.1 um resolution and the creep's slope.
    if speed is None:
        for label, surf in (("creeping", cs), ("predictive creeping", ps)):
            c.that(surf["max_step_um"] < 0.2,
                   "%s max step %.3f um < 0.2 um (two counts of the registers' 0.1 um)" %
                   (label, surf["max_step_um"]))
    # Not 1/100 (h·Δs/L would allow it): where a pass turns, the length / radius split of the
    # correction follows the engagement angle one NC latency late, a blip for ~1 mm.
    c.that(cs["max_offset_step_um"] < 0.25 * ss["max_offset_step_um"],
           "creeping offset change %.3f um < 1/4 of the step's %.3f um" %
           (cs["max_offset_step_um"], ss["max_offset_step_um"]))
    fo = off["surface"]["form"]["rms_um"]
    for rep, label in ((step, "step correction"), (creep, "creeping"),
                       (pred, "predictive creeping")):
        c.that(rep["surface"]["form"]["rms_um"] < fo,
               "%s form error RMS %.3f um < %.3f um without compensation" %
               (label, rep["surface"]["form"]["rms_um"], fo))


def scenario_modbus_modes(b, source, work):
    """Part (a), four daemon configs, lock-step: the figures that make the case for creeping.
    The daemons ask for the laser every 450 mm of cut path (ncsim measures on that request
    only; without compensation ncsim measures on its own at the same interval)."""
    res = run_modes(b, source, work)
    print(modes_table(res))
    c = Check("modbus_modes")
    check_modes(c, res, LASER_INTERVAL_MM, LASER_TRIP_S, min_step_um=2.0)
    c.done()


# The README's main job (scripts/demo) runs the daemon in real time against ncsim at a speed
# factor, not in lock-step: the same four modes, sequentially, ncsim at x4 (about 15 s a part).
REALTIME_SPEED = 4.0


def scenario_modbus_realtime(b, source, work):
    """Part (a), four daemon configs, nccompd on the wall clock and ncsim at a speed factor (the
    demo's path): every process ends cleanly, no alarm, the laser on the daemon's request, and
    creeping leaves a quarter of step correction's step or less."""
    res = run_modes(b, source, work, speed=REALTIME_SPEED)
    print(modes_table(res))
    c = Check("modbus_realtime")
    check_modes(c, res, LASER_INTERVAL_MM, LASER_TRIP_S, min_step_um=2.0, speed=REALTIME_SPEED)
    c.done()


# The restart of issue 17 (lock-step, so that both runs are deterministic): nccompd killed 1 s
# of machining after the NC's second request rose, while the tool is at the laser (ncsim-demo:
# a 4 s trip, measured half-way), and back 2 s later (systemd's RestartSec), so that the laser
# measurement is published while it is down. By then the daemon has saved the raised request
# (its state's min_interval_s is 0.5 s).
RESTART_OUTAGE = (2, 1.0, 2.0)
RECOVERED_LINE = re.compile(r"bus modbus: (\d+) events? of tool_measurement happened while "
                            r"nccompd was down \(counter #(\d+) -> #(\d+)\): (the newest )?"
                            r"delivered")


def scenario_modbus_restart(b, source, work):
    """Issue 17, finding 3: the mould face with creeping, once uninterrupted and once with
    nccompd killed (SIGKILL) while the NC is at the laser and started again 2 s of machining
    later. The restarted daemon delivers the measurement published while it was down (its log
    says so), the laser measures as often as without the restart (the request does not stick),
    and the machined part is within 10 % of the uninterrupted one (form error RMS and maximum
    step within a pass, nccomp report)."""
    plain = run_machining(b, source, work, "uninterrupted", "nccompd-creep.toml",
                          "ncsim-demo.toml", echo=print)
    restarted = run_machining(b, source, work, "restarted", "nccompd-creep.toml",
                              "ncsim-demo.toml", echo=print, outage=RESTART_OUTAGE)
    c = Check("modbus_restart")
    for r in (plain, restarted):
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d (both 0)" % (r.name, r.ncsim_rc, r.daemon_rc))
    c.that("lock-step outage at cycle" in restarted.ncsim_log,
           "ncsim ran without the daemon: %s" %
           [l for l in restarted.ncsim_log.splitlines() if "outage" in l])
    m = RECOVERED_LINE.search(restarted.daemon_log)
    c.that(m is not None and m.group(1) == "1" and m.group(3) == "2",
           "the restarted nccompd delivered the laser measurement published while it was down "
           "(the second, counter #2): %s" % (m.group(0) if m else "no such line in its log"))
    lp, lr = plain.laser(), restarted.laser()
    c.that(len(lr) == len(lp) >= 3,
           "laser trips: %d with the restart, %d without (equal, >= 3: the request did not stick)"
           % (len(lr), len(lp)))
    ps, rs = plain.report["surface"], restarted.report["surface"]
    c.that(rs["form"]["rms_um"] <= 1.1 * ps["form"]["rms_um"],
           "form error RMS %.3f um with the restart, %.3f um without (<= +10 %%)" %
           (rs["form"]["rms_um"], ps["form"]["rms_um"]))
    c.that(rs["max_step_um"] <= 1.1 * ps["max_step_um"],
           "max step within a pass %.3f um with the restart, %.3f um without (<= +10 %%)" %
           (rs["max_step_um"], ps["max_step_um"]))
    c.done()


def value_in_force(writes, register, t_s):
    """The value of `register` the NC took last at or before t_s (0 before any write)."""
    v = 0.0
    for t, r, val, _ in writes:
        if r == register and t <= t_s:
            v = val
    return v


def check_broken_tool(c, r, interval_mm, trip_s=LASER_TRIP_S):
    """The tool broke between the first and the second laser measurement: alarm 23 in the
    daemon's log and on the NC's alarm register right after the second, nothing of it applied."""
    c.that(r.ncsim_rc in (0, 4) and r.daemon_rc == 0,
           "ncsim exit %d, nccompd exit %d" % (r.ncsim_rc, r.daemon_rc))
    c.that(("tool_broken_or_mismeasured", 23) in r.alarms("alarm"),
           "alarm tool_broken_or_mismeasured (code 23) logged: %s" % r.alarms("alarm"))
    # The daemon asks again in the cycle it refuses the broken measurement (its cut path since the
    # last accepted one is beyond the interval), so its flag never drops and the NC, which reacts
    # to a rise, does not go again: two trips for three requests.
    check_laser_on_request(c, r, "broken_tool", interval_mm, trip_s, min_trips=2)
    laser = r.laser()
    c.that(len(laser) >= 2 and laser[0]["broken"] == "0" and laser[1]["broken"] == "1" and
           float(laser[1]["true_um"]) > 300.0,
           "ncsim: the second laser reading (at %s mm) reports the broken tool, true wear %s um" %
           (laser[1]["cut_path_mm"] if len(laser) > 1 else "-",
            laser[1]["true_um"] if len(laser) > 1 else "-"))
    # One row per edge support point: a measurement is one time.
    times = [t for t, _ in r.tool_wear_paths()]
    c.that(len(times) >= 2, "the laser measured at least twice (at %s s)" % times)
    # The NC showed the alarm: its alarm register (the daemon's creep alarm flag) rose once, right
    # after the broken measurement, and the daemon's code for it is 23.
    alarm_reg, request_reg = FLAGS[r.report["bus"]]
    alarms = r.report_json_alarms()
    c.that(r.report["alarms_seen"] == 1 and len(alarms) == 1 and
           alarms[0]["register"] == alarm_reg and len(times) >= 2 and
           times[1] <= alarms[0]["t_s"] <= times[1] + 0.1,
           "NC alarm register %d rose once, just after the broken measurement at %s s: %s" %
           (alarm_reg, times[1] if len(times) > 1 else "-", alarms))
    writes = r.writes()
    if len(times) >= 2:
        # Everything the NC took from the broken measurement on must hold the value in force
        # then: nothing applied, creep frozen.
        t_broken = times[1]
        regs = sorted({w[1] for w in writes})
        for reg in regs:
            if reg in (alarm_reg, request_reg):
                continue  # flags, not offsets
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
        c.that(any(abs(v) > 0.5 for v in offsets(r.report).values()),
               "the wear measured before the break was applied: %s" % offsets(r.report))


def scenario_broken_tool(b, source, work):
    """Part (a) with creeping; the tool breaks after the first laser measurement: alarm 23
    (tool_broken_or_mismeasured) in the daemon's log and on the NC's alarm register, and nothing
    of that measurement applied. The daemon asks for the laser every 600 mm here (not the demo's
    450 mm; ncsim's config is unchanged): the trips follow the daemon's interval."""
    r = run_machining(b, source, work, "broken_tool", "nccompd-creep.toml", "ncsim-demo.toml",
                      sets=["broken_tool.enabled=true", "broken_tool.at_path_mm=700"],
                      overrides={"nccompd.toml": {"creep.interval.interval_mm": "600.0"}},
                      echo=print)
    c = Check("broken_tool")
    check_broken_tool(c, r, 600.0)
    c.done()


def check_implausible_probe(c, r, parts):
    """One probe reading of part 1 (checkpoint 0) is 500 um off: alarm 30 in the daemon's log,
    nothing of it written, part 2 cut with 0 there and with part 1's values elsewhere. The S1
    module has no alarm register, so the NC does not see this alarm (alarms_seen stays 0)."""
    c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
           "ncsim exit %d, nccompd exit %d" % (r.ncsim_rc, r.daemon_rc))
    c.that(("probe_implausible", 30) in r.alarms("alarm"),
           "alarm probe_implausible (code 30) logged: %s" % r.alarms("alarm"))
    c.that(r.report["alarms_seen"] == 0,
           "no NC alarm register (S1 has none): alarms_seen %d" % r.report["alarms_seen"])
    writes = r.writes()
    c.that(all(abs(w[2]) < 100.0 for w in writes),
           "no write carries the 500 um reading (largest %.3f um)" %
           max([abs(w[2]) for w in writes] + [0.0]))
    # ncsim's own record of the reading it produced: 500 um above what a perfect probe shows.
    probe = [m for m in read_csv_rows(os.path.join(r.out_dir, "measurements.csv"))
             if m["kind"] == "probe"]
    first = next((m for m in probe if m["part"] == "1" and m["checkpoint"] == "0"), None)
    c.that(first is not None and
           abs(float(first["reading_um"]) - float(first["true_um"]) - 500.0) < 3.0,
           "ncsim's measurements.csv: part 1 checkpoint 0 read %s um where the wall shows %s um" %
           (first["reading_um"] if first else "-", first["true_um"] if first else "-"))
    # Part 2 is cut with what part 1 taught: nothing at checkpoint 0 (its reading was refused),
    # the learned values at the three others.
    rows = {(int(m["part"]), int(m["point"])): m for m in r.measurements()
            if m.get("kind") == "contour"}
    c.that(abs(float(rows[(1, 0)]["measured_um"])) > 400.0 if (1, 0) in rows else False,
           "part 1 checkpoint 0 logged with the implausible reading")
    c.that((2, 0) in rows and abs(float(rows[(2, 0)]["applied_um"])) < 1e-9,
           "part 2 checkpoint 0 cut with nothing applied (applied_um %s)" %
           (rows[(2, 0)]["applied_um"] if (2, 0) in rows else "-"))
    for cp in (1, 2, 3):
        c.that((2, cp) in rows and abs(float(rows[(2, cp)]["applied_um"])) > 0.5,
               "part 2 checkpoint %d cut with part 1's value (applied_um %s)" %
               (cp, rows[(2, cp)]["applied_um"] if (2, cp) in rows else "-"))
    c.that(len(rows) == 4 * parts and len(probe) == 4 * parts,
           "4 checkpoints x %d parts probed and logged (%d, ncsim %d)" % (
               parts, len(rows), len(probe)))


def check_applied_is_what_the_nc_took(c, r, tolerance_um):
    """Every contour row's applied_um is the compensation the NC had in force when it cut that
    checkpoint's wall: ncsim's walls.csv offset_um (the live radius wear register along the
    normal) at the sample nearest the checkpoint's (part, layer, s_mm) of checkpoints.csv."""
    cps = {(int(p["part"]), int(p["checkpoint"])): p
           for p in read_csv_rows(os.path.join(r.out_dir, "checkpoints.csv"))}
    walls = {}
    for w in read_csv_rows(os.path.join(r.out_dir, "walls.csv")):
        walls.setdefault((int(w["part"]), int(w["layer"])), []).append(
            (float(w["s_mm"]), float(w["offset_um"])))
    rows = [m for m in r.measurements() if m.get("kind") == "contour"]
    worst = (0.0, None)
    for m in rows:
        key = (int(m["part"]), int(m["point"]))
        cp = cps.get(key)
        samples = walls.get((key[0], int(cp["layer"]))) if cp else None
        if not samples:
            c.that(False, "part %d checkpoint %d: no cut of it in ncsim's walls.csv" % key)
            continue
        s_mm = float(cp["s_mm"])
        in_force = min(samples, key=lambda x: abs(x[0] - s_mm))[1]
        d = abs(float(m["applied_um"]) - in_force)
        if d >= worst[0]:
            worst = (d, "part %d checkpoint %d: applied_um %s, the NC's %.3f um" % (
                key + (m["applied_um"], in_force)))
    c.that(rows and worst[0] <= tolerance_um,
           "applied_um of %d contour rows is the NC's offset at the cut within %.2f um "
           "(largest difference %.3f um, %s)" % (len(rows), tolerance_um, worst[0], worst[1]))


def scenario_implausible_probe(b, source, work):
    """Part (b) (side wall), per-checkpoint compensation; one probe reading of part 1 is 500 um
    off (a chip under the ball): alarm, that checkpoint's value not applied. The live radius wear
    register (the second [[registers]]) slews at 1 um/s here, so that the limiter holds it back
    from the learned values at the checkpoints: the log's applied_um must be what the NC took,
    not what S1 asked for."""
    r = run_machining(b, source, work, "implausible_probe", "nccompd-walls.toml",
                      "ncsim-demo.toml", program="side_wall", parts=3,
                      sets=["probe_outlier.enabled=true", "probe_outlier.part=1",
                            "probe_outlier.checkpoint=0", "probe_outlier.value_um=500"],
                      overrides={"nccompd.toml": {"registers#1.max_rate_um_per_s": "1.0"}},
                      echo=print)
    c = Check("implausible_probe")
    check_implausible_probe(c, r, 3)
    # Half a count of the 0.1 um register, and 1 um/s over the NC's 20 ms latency and the
    # daemon's 10 ms poll plus a 4 ms cycle behind the cut.
    check_applied_is_what_the_nc_took(c, r, 0.05 + 1.0 * 0.034 + 0.01)
    c.done()


def per_part_walls(r):
    """Per part, from ncsim's result: wall RMS, wall max |error| (walls.csv) and the checkpoint
    errors after machining by checkpoint id (checkpoints.csv)."""
    walls = read_csv_rows(os.path.join(r.out_dir, "walls.csv"))
    cps = read_csv_rows(os.path.join(r.out_dir, "checkpoints.csv"))
    out = {}
    for p in sorted({int(w["part"]) for w in walls}):
        e = [float(w["error_um"]) for w in walls if int(w["part"]) == p]
        cp = {int(x["checkpoint"]): float(x["error_um"]) for x in cps if int(x["part"]) == p}
        out[p] = (math.sqrt(sum(v * v for v in e) / len(e)), max(abs(v) for v in e), cp)
    return out


def scenario_walls_modes(b, source, work):
    """S1 end to end over Modbus: the side wall (part b), 3 parts, with push-off (3 um at the
    reference lever) and a hardness scatter that differs from blank to blank (amplitude 0.1,
    per_part), no wear. The daemon learns each checkpoint from the previous part's probe reading
    (learning_mode previous_part) and drives the live radius wear register, switching at each
    checkpoint (apply = "step", the original method) or creeping from one checkpoint's value to
    the next (apply = "creep"). Part 1 is cut with nothing learned; part 2 must have the smaller
    wall error; creeping must leave smaller steps in the wall than switching."""
    sets = ["wear.enabled=false", "hardness.per_part=true", "hardness.amplitude=0.2"]
    res = {}
    for key in ("step", "creep"):
        res[key] = run_machining(
            b, source, work, "walls_" + key, "nccompd-walls.toml", "ncsim-demo.toml",
            program="side_wall", parts=3, sets=sets,
            overrides={"side_wall_checkpoints.toml": {"checkpoints.apply": '"%s"' % key}},
            echo=print)
    c = Check("walls_modes")
    print("mode  | part | wall RMS [um] | wall max [um] | checkpoint errors [um] (0..3)")
    figs = {}
    for key, r in res.items():
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d" % (key, r.ncsim_rc, r.daemon_rc))
        c.that(not r.alarms("alarm") and r.report["alarms_seen"] == 0,
               "%s: no alarm logged (%s), none on the NC" % (key, r.alarms("alarm")))
        figs[key] = f = per_part_walls(r)
        for p, (rms, mx, cp) in sorted(f.items()):
            print("%-5s | %4d | %13.3f | %13.3f | %s" % (
                key, p, rms, mx, " ".join("%6.3f" % cp[i] for i in sorted(cp))))
        c.that(sorted(f) == [1, 2, 3], "%s: 3 parts machined (%s)" % (key, sorted(f)))
        if len(f) == 3:
            c.that(f[1][0] > 1.5,
                   "%s: part 1, nothing learned yet, carries the push-off: wall RMS %.3f um > 1.5"
                   % (key, f[1][0]))
            for n in (1, 2):
                c.that(f[n + 1][0] < 0.5 * f[1][0],
                       "%s: part %d wall RMS %.3f um < half of part 1's %.3f um" % (
                           key, n + 1, f[n + 1][0], f[1][0]))
            worst1 = max(abs(v) for v in f[1][2].values())
            worst2 = max(abs(v) for v in f[2][2].values())
            c.that(worst2 < 0.5 * worst1,
                   "%s: worst checkpoint error part 2 %.3f um < half of part 1's %.3f um" % (
                       key, worst2, worst1))
    if len(res) == 2:
        sw, cw = res["step"].report["walls"], res["creep"].report["walls"]
        print("max step in the wall: step %.3f um (offset %.3f um), creep %.3f um (offset %.3f "
              "um)" % (sw["max_step_um"], sw["max_offset_step_um"], cw["max_step_um"],
                       cw["max_offset_step_um"]))
        c.that(sw["max_offset_step_um"] > 0.3,
               "step: the live register switches at a checkpoint: %.3f um" %
               sw["max_offset_step_um"])
        c.that(cw["max_step_um"] < 0.5 * sw["max_step_um"],
               "creep max step in the wall %.3f um < half of step's %.3f um" % (
                   cw["max_step_um"], sw["max_step_um"]))
        # Creeping moves the live register in steps of the daemon's write_threshold_um (0.1 um,
        # the default of [checkpoints]).
        c.that(cw["max_offset_step_um"] <= 0.1 + 1e-6,
               "creep largest change of the offset in force %.3f um <= the write threshold "
               "0.1 um (step: %.3f um)" % (cw["max_offset_step_um"], sw["max_offset_step_um"]))
    c.done()


ROLL_HALF_LENGTH_MM, ROLL_CROWN_MM = 150.0, 0.2
ROLL_WHEEL = ("100", "0.2")  # ncsim-demo.toml program.roll wheel_width_mm, wheel_height_mm
GRIND_PATH_ROW = re.compile(r"^\s*(usual practice \(T follows P\)|exact envelope)\s+([0-9.]+)\s+"
                            r"([0-9.]+)\s+([0-9.]+)\s+([0-9.]+)", re.M)


def scenario_roll(b, source, work):
    """S2 end to end: a 300 mm roll with a 0.2 mm convex crown, wheel W = 100 mm, h = 0.2 mm.
    `nccomp grind-path` computes the exact-envelope trajectory of the wheel's midpoint T and
    verifies it (and the usual practice, T following P) with its own brute-force computation;
    `ncsim --program roll` grinds the roll once along each trajectory (machine effects off: the
    comparison is the geometry); `nccomp report` measures the profile error of the ground roll.
    The exact trajectory must grind P to within the grid's discretisation, the usual practice
    must gouge by what grind-path predicts (about 20 um near the ends)."""
    os.makedirs(work, exist_ok=True)
    crown = os.path.join(work, "crown.csv")
    step_mm = 0.05  # ncsim-demo.toml ncsim.step_mm: the profile's spacing too
    n = int(round(2 * ROLL_HALF_LENGTH_MM / step_mm))
    with open(crown, "w") as f:
        f.write("z_mm,u_mm\n")
        for i in range(n + 1):
            z = -ROLL_HALF_LENGTH_MM + i * step_mm
            f.write("%.4f,%.9f\n" % (z, ROLL_CROWN_MM * (1 - (z / ROLL_HALF_LENGTH_MM) ** 2)))
    traj = os.path.join(work, "crown_traj.csv")
    g = subprocess.run([b.nccomp, "grind-path", "--profile", crown, "--wheel-width-mm",
                        ROLL_WHEEL[0], "--arc-height-mm", ROLL_WHEEL[1], "--trajectory-out",
                        traj, "--verify-points", "601"],
                       capture_output=True, text=True, timeout=120)
    print(g.stdout)
    c = Check("roll")
    c.that(g.returncode == 0, "nccomp grind-path exit %d %s" % (g.returncode, g.stderr[-300:]))
    if g.returncode != 0:
        c.done()
    ver = {m.group(1): [float(m.group(k)) for k in (2, 3, 4, 5)]
           for m in GRIND_PATH_ROW.finditer(g.stdout)}
    usual_pred = ver.get("usual practice (T follows P)")
    c.that(usual_pred is not None and "exact envelope" in ver,
           "grind-path verified both paths: %s" % ver)
    off = ["wear.enabled=false", "pushoff.enabled=false", "pitch.enabled=false",
           "hardness.enabled=false", "thermal.enabled=false", "program.roll.passes=1",
           "program.roll.profile_file=%s" % crown]
    res = {}
    for key, path in (("exact", traj), ("usual", crown)):
        res[key], _ = run_ncsim_alone(b, source, work, "roll_" + key, "roll",
                                      off + ["program.roll.trajectory_file=%s" % path])
        f = res[key]["surface"]["form"]
        print("roll %-5s (trajectory %s): profile error RMS %.4f um, max %.4f um (at z %.3f "
              "mm), %d samples" % (key, os.path.basename(path), f["rms_um"], f["max_abs_um"],
                                   f["max_at"]["position_mm"], f["samples"]))
    ex, us = res["exact"]["surface"]["form"], res["usual"]["surface"]["form"]
    c.that(ex["samples"] == n + 1 and us["samples"] == n + 1,
           "every profile sample ground (%d, %d of %d)" % (ex["samples"], us["samples"], n + 1))
    # Discretisation: the wheel is sampled every step_mm along the path, so on slope k the grid
    # misses up to k * step_mm; the crown's slope is at most 2 * crown / half length.
    bound = 2 * ROLL_CROWN_MM / ROLL_HALF_LENGTH_MM * step_mm * 1000 + 0.01
    c.that(ex["max_abs_um"] <= bound,
           "exact envelope: profile error max %.4f um <= the grid's %.3f um" % (
               ex["max_abs_um"], bound))
    if usual_pred:
        c.that(us["max_at"]["value_um"] < 0 and
               abs(us["max_abs_um"] - usual_pred[0]) <= 0.02 * usual_pred[0] + bound,
               "usual practice gouges %.3f um (at z %.1f mm), grind-path predicted %.3f um" % (
                   -us["max_at"]["value_um"], us["max_at"]["position_mm"], usual_pred[0]))
        c.that(abs(us["rms_um"] - usual_pred[1]) <= 0.03 * usual_pred[1],
               "usual practice profile RMS %.3f um, grind-path %.3f um (at 601 points)" % (
                   us["rms_um"], usual_pred[1]))
    c.that(us["max_abs_um"] > 15.0 and ex["max_abs_um"] < us["max_abs_um"] / 50,
           "the exact trajectory grinds the crown %.0f times better than T following P "
           "(%.4f vs %.3f um)" % (us["max_abs_um"] / max(ex["max_abs_um"], 1e-6),
                                  ex["max_abs_um"], us["max_abs_um"]))
    c.done()


def scenario_undeclared_effect(b, source, work):
    """Issue 11 item 5: ncsim machines 12 side walls with its tool wear switched on (20 um per m
    of path), the daemon's declared model (config/demo/model-declared.toml) has no wear term;
    the daemon logs its probe measurements, and `nccomp analyze` on that log must find the
    effect (as tool_wear in the cut path the probe rows carry, or as a trend over the parts)
    and report the error before and after, on fitted and held-out rows.

    (The thermal drift is not used: ncsim's default drift is along Z only, which moves a vertical
    wall along itself, not along its normal, so the walls do not show it.)"""
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
    on the daemon's log adds the wear (tool_wear, linear in the cut path the probe rows carry)
    and writes model.toml; the daemon is restarted with it ([model],
    config/demo/nccompd-walls-model.toml: the term as a trim on the radius wear register,
    evaluated every cycle) and the machine CONTINUES: ncsim --continue machines parts 13-24 with the same, by
    then worn, tool (its wear and the push-off growing with it go on from where part 12 left
    them). The daemon starts afresh (new state: S1 has learned nothing, the NC's registers are
    at 0, and the daemon counts the tool's cut path from 0), so part 13, like part 1, is cut
    before S1 has probed anything and with a wear trim that starts at 0: it carries the tool's
    whole wear (its figures are printed, not compared). The checkpoint and wall errors of the
    parts themselves (ncsim's checkpoints.csv / walls.csv) must drop: parts 2-12 before against
    parts 14-24 after."""
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
    # The daemon's probe rows carry the finishing tool's cut path: the wear shows as tool_wear
    # (linear in path_mm, evaluated every cycle); on a log without the path, as part_trend.
    trend = next((n for n in names if n in ("tool_wear", "part_trend")), None)
    c.that(trend is not None, "analyze added the wear as tool_wear or part_trend: %s" % names)
    if trend is None:
        c.done()
    with open(os.path.join(before.out_dir, "result.json")) as f:
        end = json.load(f)["end"]
    c.that(end["next_part"] == 13, "before: ncsim's end state says part 13 is next (%s)" % end)
    after = run_machining(b, source, work, "loop_after", "nccompd-walls-model.toml",
                          "ncsim-demo.toml", program="side_wall", parts=12, sets=sets,
                          overrides={"nccompd.toml": {
                              "model.file": '"%s"' % model,
                              "model.update": '"%s"' % ("cycle" if trend == "tool_wear" else
                                                        "part"),
                              "model.apply.term": '"%s"' % trend}},
                          continue_from=before.out_dir, echo=print)
    c.that(after.ncsim_rc == 0 and after.daemon_rc == 0,
           "after: ncsim exit %d, nccompd exit %d" % (after.ncsim_rc, after.daemon_rc))
    c.that(not after.alarms("alarm"), "after: no alarm logged (%s)" % after.alarms("alarm"))
    # The tool went on: the first probe of part 13 was taken with the cut path part 12 ended at.
    probes_b = [m for m in read_csv_rows(os.path.join(before.out_dir, "measurements.csv"))
                if m["kind"] == "probe"]
    probes_a = [m for m in read_csv_rows(os.path.join(after.out_dir, "measurements.csv"))
                if m["kind"] == "probe"]
    c.that(bool(probes_a) and int(probes_a[0]["part"]) == 13 and
           float(probes_a[0]["cut_path_mm"]) > float(probes_b[-1]["cut_path_mm"]),
           "after: part 13 first, the tool's cut path continues (%s mm after %s mm)" % (
               probes_a[0]["cut_path_mm"] if probes_a else "-",
               probes_b[-1]["cut_path_mm"] if probes_b else "-"))
    pb, cb, wb = wall_figures(before, 2)
    pa, ca, wa = wall_figures(after, 14)
    print("part | checkpoint RMS | wall RMS | wall p-v   || part | checkpoint RMS | wall RMS | "
          "wall p-v   (before: no model || after: with the model, the tool continued)")
    for p in sorted(pb):
        q = p + 12
        if q in pa:
            print("%4d | %14.3f | %8.3f | %8.3f   || %4d | %14.3f | %8.3f | %8.3f" % (
                p, pb[p][0], pb[p][1], pb[p][2], q, pa[q][0], pa[q][1], pa[q][2]))
    print("before parts 2-12 -> after parts 14-24: checkpoint RMS %.3f -> %.3f um, wall RMS "
          "%.3f -> %.3f um" % (cb, ca, wb, wa))
    c.that(sorted(pb) == list(range(1, 13)) and sorted(pa) == list(range(13, 25)),
           "parts 1-12 before, 13-24 after (%s, %s)" % (sorted(pb), sorted(pa)))
    c.that(ca < 0.5 * cb, "checkpoint error drops by more than half: parts 2-12 %.3f um -> "
           "parts 14-24 %.3f um" % (cb, ca))
    c.that(wa < wb, "wall error drops: parts 2-12 %.3f um -> parts 14-24 %.3f um" % (wb, wa))
    c.done()



def run_continued(b, source, work, name, daemon_cfg, daemon_overrides, parts, sets,
                  continue_from, state_from, reload_cfg=None, reload_overrides=None,
                  timeout_s=240.0, program="side_wall", model_load=None, speed=None):
    """Over Modbus: ncsim continues the run in continue_from (`--continue`; None: a new run, e.g.
    with a new tool) for `parts` more parts of `program`, and nccompd starts from the state of the
    run in state_from (its state/ directory, as after a restart of the daemon). speed=None:
    lock-step, else real time with ncsim at that speed factor. model_load (real time): the daemon
    is started first, on the state of the batch before, while the NC is not machining (its bus
    is down: it keeps reconnecting); once it serves its status socket, `nccomp model load
    MODEL_LOAD` puts that model into it (an operator's command between two batches), and ncsim
    starts when the load has been answered, so the model is in force from the batch's first
    part; the load's answer is RunResult.model_load (exit status, output). reload_cfg: the
    daemon is started first, and before ncsim ticks its config file is replaced by reload_cfg
    (staged with reload_overrides) and it gets SIGHUP, so the RUNNING daemon swaps in the new
    configuration with its state at a cycle boundary (the reload is taken while ncsim already
    ticks: where it lands is read back).
    Returns (RunResult, swap_s): swap_s, the machine time [s] at which the new configuration was
    swapped in (`nccomp status --json`'s daemon.config_since_cycle: the cycle of the swap itself,
    not of the query, during which ncsim ticks on), None without reload; with
    a reload, RunResult.handover is `nccomp status --json`'s "handover" object once it counts
    the handover (or as it was after 10 s)."""
    run_dir = os.path.join(work, name)
    shutil.rmtree(run_dir, ignore_errors=True)
    os.makedirs(run_dir)
    out_dir = os.path.join(run_dir, "out")
    port = free_port()
    sock_dir = tempfile.mkdtemp(prefix="nccomp-e2e-")
    sock = os.path.join(sock_dir, "ls.sock")
    status_sock = os.path.join(sock_dir, "status.sock")

    def staged(cfg, overrides, into):
        o = {"nccompd.toml": dict(overrides or {})}
        o["nccompd.toml"]["status.socket_path"] = '"%s"' % status_sock
        os.makedirs(into, exist_ok=True)
        return stage_configs(source, into, cfg, "ncsim-demo.toml", port, o)

    daemon_path, ncsim_path = staged(daemon_cfg, daemon_overrides, run_dir)
    shutil.copytree(os.path.join(state_from, "state"), os.path.join(run_dir, "state"))
    sim_argv = [b.ncsim, "--config", ncsim_path, "--program", program, "--bus", "modbus",
                "--out", out_dir, "--seed", "1", "--parts", str(parts)]
    if continue_from is not None:
        sim_argv += ["--continue", continue_from]
    for x in sets:
        sim_argv += ["--set", x]
    daemon_argv = [b.nccompd, "--config", daemon_path]
    if speed is None:
        sim_argv += ["--lockstep", sock]
        daemon_argv += ["--lockstep", sock]
    else:
        sim_argv += ["--speed", str(speed)]
    t0 = time.monotonic()
    sim = daemon = loader = None
    swap_s = None
    handover = None
    load_answer = None
    try:
        if speed is not None and model_load is None:
            # Real time: the daemon connects to the NC's Modbus port, so ncsim serves first.
            sim = Proc("ncsim", sim_argv, os.path.join(run_dir, "ncsim.log"), run_dir)
            deadline = time.monotonic() + 30.0
            while "ncsim: " not in sim.log() and sim.running() and time.monotonic() < deadline:
                time.sleep(0.02)
        daemon = Proc("nccompd", daemon_argv, os.path.join(run_dir, "nccompd.log"), run_dir)
        if model_load is not None:
            if speed is None:
                raise RuntimeError("model_load: real time only (in lock-step the status socket "
                                   "comes once ncsim ticks: use reload_cfg)")
            # The load is answered once the loop runs the new configuration.
            deadline = time.monotonic() + 30.0
            while not os.path.exists(status_sock) and daemon.running():
                if time.monotonic() > deadline:
                    raise RuntimeError("%s: no status socket\n%s" % (name, daemon.log()[-3000:]))
                time.sleep(0.02)
            loader = subprocess.Popen([b.nccomp, "model", "load", model_load, "--socket",
                                       status_sock], stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True)
            load_answer = (loader.wait(60), loader.stdout.read())
            # The NC starts the next batch now; the daemon's reconnect back-off (at most
            # reconnect_max_s, 5 s) is within ncsim's --wait-client (10 s).
        if reload_cfg is not None:
            deadline = time.monotonic() + 30.0
            while "lock-step: connecting" not in daemon.log() and daemon.running():
                if time.monotonic() > deadline:
                    raise RuntimeError("%s: nccompd did not reach lock-step\n%s" %
                                       (name, daemon.log()[-3000:]))
                time.sleep(0.02)
            # Signals are blocked from the start: SIGHUP waits in the daemon's signalfd.
            reload_path, _ = staged(reload_cfg, reload_overrides, os.path.join(run_dir, "reload"))
            shutil.copyfile(reload_path, daemon_path)
            # NCCOMP_E2E_LATE_HUP=1: the SIGHUP only after the daemon's first poll of the
            # continued NC, so that the swap lands later (the case of the swap cycle's spike
            # recorded in bench/results/e2e.md, fixed: the step assertion below covers it).
            if os.environ.get("NCCOMP_E2E_LATE_HUP"):
                if sim is None:
                    sim = Proc("ncsim", sim_argv, os.path.join(run_dir, "ncsim.log"), run_dir)
                while "counter went back" not in daemon.log() and daemon.running():
                    time.sleep(0.001)
            os.kill(daemon.p.pid, signal.SIGHUP)
        if sim is None:
            sim = Proc("ncsim", sim_argv, os.path.join(run_dir, "ncsim.log"), run_dir)
        if reload_cfg is not None:
            deadline = time.monotonic() + timeout_s
            while ("configuration 2 is running" not in daemon.log() and daemon.running() and
                   time.monotonic() < deadline):
                time.sleep(0.01)
            st = subprocess.run([b.nccomp, "status", "--json", "--socket", status_sock],
                                capture_output=True, text=True, timeout=30)
            try:
                # The cycle of the swap itself (ncsim ticks on while this query runs).
                swap_s = json.loads(st.stdout)["daemon"]["config_since_cycle"] / 250.0
            except (ValueError, KeyError):
                swap_s = None
            # The handover runs in the swap's cycle; its counters are published at the cycle's
            # end, which the log line may precede.
            deadline = time.monotonic() + 10.0
            while daemon.running():
                st = subprocess.run([b.nccomp, "status", "--json", "--socket", status_sock],
                                    capture_output=True, text=True, timeout=30)
                try:
                    handover = json.loads(st.stdout)["handover"]
                except (ValueError, KeyError):
                    handover = None
                if (handover is not None and handover["handovers"] > 0) or \
                        time.monotonic() > deadline:
                    break
                time.sleep(0.05)
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
        if loader is not None and loader.poll() is None:
            loader.kill()
            loader.wait()
        for p in (daemon, sim):
            if p is not None:
                p.stop()
        shutil.rmtree(sock_dir, ignore_errors=True)
    svg = ["--svg", os.path.join(out_dir, "error.svg")] if program == "mould_face" else []
    rep = subprocess.run([b.nccomp, "report", out_dir, "--json"] + svg, capture_output=True,
                         text=True, timeout=120)
    if rep.returncode != 0:
        raise RuntimeError("%s: nccomp report failed (%d): %s" % (name, rep.returncode,
                                                                  rep.stderr))
    result = RunResult(name, run_dir, out_dir, sim_rc, daemon_rc, sim.log(), daemon.log(),
                       json.loads(rep.stdout), time.monotonic() - t0)
    result.handover = handover
    result.model_load = load_answer
    print("%s: ncsim %d, nccompd %d, %.1f s wall%s" % (
        name, sim_rc, daemon_rc, result.wall_s,
        "" if swap_s is None else "; new configuration running from t = %.2f s" % swap_s))
    return result, swap_s


RADIUS_REGISTER = 1  # T1_radius_wear in config/demo/nccompd-walls*.toml


def part_times(r):
    """{part: (start_s, end_s)} from ncsim's probe rows: a part ends with its last probe, the next
    one starts there (the first at 0)."""
    ends = {}
    for m in read_csv_rows(os.path.join(r.out_dir, "measurements.csv")):
        if m["kind"] == "probe":
            ends[int(m["part"])] = float(m["t_s"])
    out, start = {}, 0.0
    for p in sorted(ends):
        out[p] = (start, ends[p])
        start = ends[p]
    return out


def handover_figures(r, first_after):
    """(largest change of the radius register between successive writes the NC took, over the
    run; the same within part first_after; per-part checkpoint RMS)."""
    times = part_times(r)
    writes = [w for w in r.writes() if w[1] == RADIUS_REGISTER]
    steps = [(writes[k][0], abs(writes[k][2] - writes[k - 1][2])) for k in range(1, len(writes))]
    t0, t1 = times.get(first_after, (0.0, 0.0))
    largest = max((d for _, d in steps), default=0.0)
    at_switch = max((d for t, d in steps if t0 <= t <= t1), default=0.0)
    per_part, _, _ = wall_figures(r, 0)
    return largest, at_switch, per_part


def scenario_model_handover(b, source, work):
    """Issue 19 item 1, on ncsim over Modbus in lock-step: 12 side walls with ncsim's tool wear
    switched on (an effect the declared model lacks), S1 checkpoints only; `nccomp analyze` on
    the daemon's log; then the machine continues (ncsim --continue, the worn tool) in three more
    runs of 6 parts, each daemon starting from the previous one's state:
      load:     the daemon runs without the model, and a SIGHUP swaps in the config with the
                model ([model] + [[model.apply]] on T1_radius_wear) while it runs (parts 13-18);
      restart:  the daemon restarted with the model config and its state (parts 19-24);
      rollback: the daemon with the model, and a SIGHUP back to the config without (25-30).
    The swap lands in the first part of its run, before its first cut (checked: each part's
    approach is made 3 s long for that). Checks: the first part that starts after the new configuration runs is
    cut within 1.5x the checkpoint error (RMS) of the parts after it; the part the swap landed in
    is cut within 1.5x the later parts' error after the load and after the rollback, and after
    the load with at most half the error of the last part before it (S1 alone), where no part may be worse than 1.5x the
    worst of parts 2-12 (S1 alone, before the model); no write of the radius register changes it
    by more than its max_step_um (20 um); no alarm."""
    sets = ["wear.enabled=true", "wear.rate_um_per_m=20"]
    c = Check("model_handover")
    before = run_machining(b, source, work, "handover_before", "nccompd-walls.toml",
                           "ncsim-demo.toml", program="side_wall", parts=12, sets=sets,
                           echo=print)
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
    before_parts, _, _ = wall_figures(before, 0)
    # The continued runs wait 3 s of machine time before each part's first cut, so that the
    # reload (taken while ncsim ticks) lands before part 13's / 25's finishing starts.
    approach_s = 3.0
    sets = sets + ["program.side_wall.approach_s=%g" % approach_s]
    with_model = {"model.file": '"%s"' % model, "model.update": '"cycle"',
                  "model.apply.term": '"tool_wear"'}
    load, load_swap = run_continued(b, source, work, "handover_load", "nccompd-walls.toml", {},
                                    6, sets, before.out_dir, before.run_dir,
                                    reload_cfg="nccompd-walls-model.toml",
                                    reload_overrides=with_model)
    restart, _ = run_continued(b, source, work, "handover_restart", "nccompd-walls-model.toml",
                               with_model, 6, sets, load.out_dir, load.run_dir)
    rollback, back_swap = run_continued(b, source, work, "handover_rollback",
                                        "nccompd-walls-model.toml", with_model, 6, sets,
                                        restart.out_dir, restart.run_dir,
                                        reload_cfg="nccompd-walls.toml", reload_overrides={})
    rows = []
    for label, r, swap_s in (("load", load, load_swap), ("restart", restart, 0.0),
                             ("rollback", rollback, back_swap)):
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0,
               "%s: ncsim exit %d, nccompd exit %d" % (label, r.ncsim_rc, r.daemon_rc))
        if label != "restart":
            c.that("configuration 2 is running" in r.daemon_log and swap_s is not None,
                   "%s: the running daemon swapped the configuration in" % label)
            # nccomp status counts it: one handover, the radius register rebased by S1.
            h = r.handover or {}
            c.that(h.get("handovers") == 1 and h.get("rebased") == 1 and
                   h.get("unabsorbed") == 0 and h.get("last_trim_change_um", 0.0) > 0.0,
                   "%s: nccomp status --json shows the handover: %s" % (label, h))
            print("%s: nccomp status --json handover %s" % (label, json.dumps(h)))
            c.that(swap_s is not None and swap_s < approach_s,
                   "%s: the swap ran before the first part's first cut (at t = %s s, the cut "
                   "starts at %g s)" % (label, swap_s, approach_s))
        times = part_times(r)
        parts = sorted(times)
        after = [p for p in parts if times[p][0] >= (swap_s or 0.0)]
        if len(after) < 2:
            c.that(False, "%s: parts after the switch (%s)" % (label, after))
            continue
        p0 = after[0]
        landed = next(p for p in parts if times[p][1] >= (swap_s or 0.0))
        largest, at_switch, per_part = handover_figures(r, p0)
        later = [per_part[p][0] for p in after[1:]]
        later_rms = math.sqrt(sum(x * x for x in later) / len(later))
        print("%s: parts %s; swap in part %d (%.3f um); first part after it %d: %.3f um; parts "
              "%d-%d: %.3f um; largest radius change in part %d %.3f um, in the run %.3f um" % (
                  label, " ".join("%d:%.2f" % (p, per_part[p][0]) for p in parts), landed,
                  per_part[landed][0], p0, per_part[p0][0], after[1], after[-1], later_rms, p0,
                  at_switch, largest))
        rows.append((label, landed, per_part[landed][0], p0, per_part[p0][0], later_rms,
                     at_switch, largest))
        c.that(r.alarms("alarm") == [], "%s: no alarm (%s)" % (label, r.alarms("alarm")))
        c.that(largest <= 20.0 + 1e-6, "%s: no write beyond max_step_um 20 (largest %.3f um)" % (
            label, largest))
        c.that(per_part[p0][0] <= 1.5 * later_rms,
               "%s: part %d within 1.5x the later parts' error: %.3f um against %.3f um" % (
                   label, p0, per_part[p0][0], later_rms))
        if label == "load":
            # Issue 19: the part cut right after the load too (S1's residuals take the model's
            # trim at each checkpoint's own cut path, not at the swap).
            c.that(per_part[landed][0] <= 1.5 * later_rms,
                   "load: part %d (the swap landed in it) within 1.5x the later parts' error: "
                   "%.3f um against %.3f um" % (landed, per_part[landed][0], later_rms))
            last = before_parts[max(before_parts)][0]
            c.that(per_part[landed][0] <= 0.5 * last,
                   "load: part %d (the swap landed in it) at most half the error of part %d "
                   "before, S1 alone: %.3f um against %.3f um" % (landed, max(before_parts),
                                                                  per_part[landed][0], last))
        elif label == "rollback":
            c.that(per_part[landed][0] <= 1.5 * later_rms,
                   "rollback: part %d (the swap landed in it) within 1.5x the later parts' "
                   "error: %.3f um against %.3f um" % (landed, per_part[landed][0], later_rms))
            # S1 alone again: no part worse than S1 alone was before the model (parts 2-12).
            worst_before = max(before_parts[p][0] for p in before_parts if p >= 2)
            worst = max(per_part[p][0] for p in parts)
            c.that(worst <= 1.5 * worst_before,
                   "rollback: every part within 1.5x the worst of parts 2-12 before the model "
                   "(S1 alone): %.3f um against %.3f um" % (worst, worst_before))
    print("| switch | part the swap landed in | its RMS [um] | first part after the switch | "
          "its RMS [um] | later parts' RMS [um] | largest radius change in that part [um] | "
          "largest in the run [um] |")
    for row in rows:
        print("| %s | %d | %.3f | %d | %.3f | %.3f | %.3f | %.3f |" % row)
    c.done()


# Over CAN the runs are shorter than over Modbus: lock-step inside the TCG VM costs ~6-10 ms of
# CPU per cycle (Debug + ASan), so the demo's 54 s face at 250 Hz (13 450 cycles) would take
# minutes per run. Here: a 30 x 10 mm face (11 passes, 330 mm of cut) at 6000 mm/min, the loop at
# 100 Hz (1 mm of path per cycle), the laser every 100 mm with 0.5 s trips, and a faster wear (24
# um per m) so that each measurement still brings a correction of ~2.4 um: ~500 cycles per run.
CAN_RATE_HZ = "100"
CAN_FACE = ["program.mould_face.size_x_mm=30.0", "program.mould_face.size_y_mm=10.0",
            "program.mould_face.feed_mm_per_min=6000.0", "program.mould_face.laser_trip_s=0.5",
            "wear.rate_um_per_m=24.0"]
CAN_INTERVAL_MM, CAN_TRIP_S = 100.0, 0.5
# The CAN profile's logical registers (config/reference-nc-can.toml + config/demo/nc-extra-can.toml):
# 0/1 tool wear, 2 one checkpoint register, 3 the Z axis offset, 4/5 the flags, 6..9 a
# checkpoint table. ncsim is told so.
CAN_NC = {"nc.axis_x_register": "-1", "nc.axis_y_register": "-1", "nc.axis_z_register": "3",
          "nc.checkpoint_base_register": "6", "nc.checkpoint_register_count": "4",
          "nc.measure_request_register": "5", "nc.alarm_registers": "[4]",
          "ncsim.lockstep_rate_hz": CAN_RATE_HZ}


def scenario_can_modes(b, source, work):
    """Over CAN (vcan0; run inside tests/hil/vm/run_in_vm.sh, one VM boot), lock-step with SYNC /
    SYNC-ACK frames at 100 Hz: the four modes of modbus_modes on a smaller face (CAN_FACE), the broken tool
    (alarm 23 on the NC's alarm register over CAN) and the implausible probe (alarm 30) on 2 side
    walls, with the same assertions as over Modbus. The daemon configs are nccompd-step-can.toml
    and nccompd-creep-can.toml (off = creep with [creep] enabled = false, predict = creep with
    predict.enabled = true) and nccompd-walls-can.toml."""
    import tomllib
    with open(os.path.join(source, "sim", "ncsim", "config", "side_wall_checkpoints.toml"),
              "rb") as f:
        plan = tomllib.load(f)["checkpoints"]
    with open(os.path.join(source, "sim", "ncsim", "config", "side_wall_checkpoints_can.toml"),
              "rb") as f:
        plan_can = tomllib.load(f)["checkpoints"]
    c = Check("can_modes")
    c.that({k: v for k, v in plan.items() if k != "register_base"} ==
           {k: v for k, v in plan_can.items() if k != "register_base"} and
           plan_can["register_base"] == 6,
           "side_wall_checkpoints_can.toml is side_wall_checkpoints.toml with register_base 6")
    interval = {"creep.interval.interval_mm": "%.1f" % CAN_INTERVAL_MM,
                "daemon.rate_hz": CAN_RATE_HZ}
    runs = [
        ("off", "nccompd-creep-can.toml", dict(interval, **{"creep.enabled": "false"}),
         CAN_FACE + ["program.mould_face.measure_interval_mm=%g" % CAN_INTERVAL_MM]),
        ("step", "nccompd-step-can.toml", interval, CAN_FACE),
        ("creep", "nccompd-creep-can.toml", interval, CAN_FACE),
        ("predict", "nccompd-creep-can.toml",
         dict(interval, **{"creep.predict.enabled": "true"}), CAN_FACE),
    ]
    res = {}
    for key, cfg, dover, sets in runs:
        res[key] = run_machining(b, source, work, "can_" + key, cfg, "ncsim-demo.toml",
                                 bus="can", sets=sets,
                                 overrides={"ncsim.toml": CAN_NC, "nccompd.toml": dover},
                                 echo=print)
    print(modes_table(res))
    check_modes(c, res, CAN_INTERVAL_MM, CAN_TRIP_S, min_step_um=1.0)
    broken = run_machining(b, source, work, "can_broken_tool", "nccompd-creep-can.toml",
                           "ncsim-demo.toml", bus="can",
                           sets=CAN_FACE + ["broken_tool.enabled=true",
                                            "broken_tool.at_path_mm=150"],
                           overrides={"ncsim.toml": CAN_NC, "nccompd.toml": interval},
                           echo=print)
    check_broken_tool(c, broken, CAN_INTERVAL_MM, CAN_TRIP_S)
    probe = run_machining(b, source, work, "can_implausible_probe", "nccompd-walls-can.toml",
                          "ncsim-demo.toml", program="side_wall", parts=2, bus="can",
                          sets=["probe_outlier.enabled=true", "probe_outlier.part=1",
                                "probe_outlier.checkpoint=0", "probe_outlier.value_um=500",
                                "program.side_wall.feed_mm_per_min=6000.0",
                                "program.side_wall.probe_time_s=0.3"],
                          overrides={"ncsim.toml": CAN_NC,
                                     "nccompd.toml": {"daemon.rate_hz": CAN_RATE_HZ}},
                          echo=print)
    check_implausible_probe(c, probe, 2)
    c.done()


def scenario_demo_loop(b, source, work):
    """scripts/demo in lock-step (issue 19 item 4): the four modes with the assertions of
    modbus_modes, then the loop: the loop daemon's first batch, `nccomp analyze` on its log, the
    model into the daemon (its [model] file and SIGHUP, the reload `nccomp model load` runs), the
    second batch with it, and summary.json. Checks: the analysis finds the wear ncsim adds
    (tool_wear, linear in path_mm, its rate within 15 % of ncsim's wear.rate_um_per_m); the
    running daemon swaps the model in (one handover, nothing unabsorbed: `nccomp status --json`);
    the five rows and summary.json (a list of five objects with exactly mode, max_step_um,
    form_rms_um, form_max_um, the modes in order, each figure the one of `nccomp report` of its
    run)."""
    import tomllib
    res, analysis = run_demo(b, source, work)
    print(modes_table(res))
    c = Check("demo_loop")
    check_modes(c, res, LASER_INTERVAL_MM, LASER_TRIP_S, min_step_um=2.0)
    with open(os.path.join(source, "config", "demo", "ncsim-demo.toml"), "rb") as f:
        rate_um_per_mm = tomllib.load(f)["effects"]["wear"]["rate_um_per_m"] / 1000.0
    wear = [e for e in analysis.get("effects", []) if e["name"] == "tool_wear"]
    c.that(len(wear) == 1 and wear[0]["column"] == "path_mm" and wear[0]["form"] == "linear",
           "analyze added tool_wear (path_mm, linear): %s" % [
               (e["name"], e["column"], e["form"]) for e in analysis.get("effects", [])])
    if wear:
        coef = wear[0]["params"]["coef_um"][0]
        c.that(abs(coef - rate_um_per_mm) <= 0.15 * rate_um_per_mm,
               "its rate %.5f um/mm is ncsim's wear rate %.5f um/mm (within 15 %%)" % (
                   coef, rate_um_per_mm))
    # Every probe reading of the first batch is a contour row, the face's edge passes (y = 0 and
    # 30 mm, where the ball's centre lies 0.59 mm off the cut point) included.
    probed = sorted((int(r["part"]), int(r["point"])) for r in read_csv_rows(
        os.path.join(work, "batch1", "log", "measurements.csv")) if r["kind"] == "contour")
    parts = sorted({p for p, _ in probed})
    c.that(len(parts) == LOOP_FIRST_BATCH and
           probed == [(p, k) for p in parts for k in range(LOOP_PROBE_POINTS)],
           "first batch: %d contour rows, one per probed point of each part (%d x %d): %s" % (
               len(probed), LOOP_FIRST_BATCH, LOOP_PROBE_POINTS, probed))
    m = res["model"]
    h = m.handover or {}
    c.that("configuration 2 is running" in m.daemon_log and h.get("handovers") == 1 and
           h.get("unabsorbed") == 0,
           "model: the running daemon swapped the model in, one handover, nothing unabsorbed: %s"
           % h)
    c.that(m.ncsim_rc == 0 and m.daemon_rc == 0 and not m.alarms("alarm"),
           "model: ncsim exit %d, nccompd exit %d, no alarm (%s)" % (
               m.ncsim_rc, m.daemon_rc, m.alarms("alarm")))
    table = modes_table(res).splitlines()
    c.that(len(table) == 7 and table[-1].startswith("| %s |" % LOOP_MODE[1]),
           "the table has the five rows, the model last: %s" % [l.split("|")[1] for l in table[2:]])
    with open(os.path.join(work, "summary.json")) as f:
        summary = json.load(f)
    modes = [k for k, _, _ in MODES] + [LOOP_MODE[0]]
    c.that(isinstance(summary, list) and [r.get("mode") for r in summary] == modes and
           all(sorted(r) == sorted(SUMMARY_KEYS) for r in summary),
           "summary.json: %d rows, modes %s, keys %s" % (
               len(summary), [r.get("mode") for r in summary],
               sorted({k for r in summary for k in r})))
    for row in summary if isinstance(summary, list) else []:
        rep = res[row["mode"]].report["surface"]
        want = (rep["max_step_um"], rep["form"]["rms_um"], rep["form"]["max_abs_um"])
        got = tuple(row.get(k) for k in SUMMARY_KEYS[1:])
        c.that(all(isinstance(g, float) and math.isfinite(g) and g == w
                   for g, w in zip(got, want)),
               "summary.json %s: %s = nccomp report's %s" % (row["mode"], got, want))
    # The loop pays: the model predicts the wear between the laser's measurements and S0 learns
    # only the residual (not the wear a second time), so the part with the model is better
    # than creeping alone, and the continued NC keeps its registers (no step at the start).
    creep_s, model_s = res["creep"].report["surface"], m.report["surface"]
    c.that(model_s["form"]["rms_um"] < creep_s["form"]["rms_um"],
           "the model row's form RMS %.3f um is below the creep row's %.3f um" % (
               model_s["form"]["rms_um"], creep_s["form"]["rms_um"]))
    # The swap is bumpless wherever it lands (NCCOMP_E2E_LATE_HUP=1: after the daemon's first
    # poll of the continued NC, where the creep's limiters once slewed from 0 for a cycle).
    c.that(model_s["max_step_um"] <= 1.5 * creep_s["max_step_um"],
           "the model row's largest step %.3f um is within 1.5x the creep row's %.3f um" % (
               model_s["max_step_um"], creep_s["max_step_um"]))
    # Issue 19's targets: the model row at most 1.5 um form RMS, its largest step at most
    # 0.15 um. The push-off the laser never sees (4.8-5.7 um on this part) is fitted to the first
    # batch's face probe rows (pushoff + pushoff_wear, kind contour, on the length wear
    # register) and, loaded between two parts (in ncsim's approach), is in force from the first
    # cut: 1.27 um (1.84 um when it faded in over the first passes, 6.24 um without it; the same
    # part with the initial model, nothing fitted: 8.72 um).
    c.that(model_s["form"]["rms_um"] <= MODEL_ROW_RMS_BOUND_UM,
           "the model row's form RMS %.3f um is at most %.2f um" % (model_s["form"]["rms_um"],
                                                                  MODEL_ROW_RMS_BOUND_UM))
    c.that(model_s["max_step_um"] <= 0.15,
           "the model row's largest step %.3f um is at most 0.15 um" % model_s["max_step_um"])
    c.done()


def scenario_calib_touch(b, source, work):
    """S3: ncsim's touch program + nccompd, calibrated over the command channel (calib_e2e.py)."""
    import calib_e2e  # tests/e2e/calib_e2e.py, next to this file
    calib_e2e.scenario(sys.modules[__name__], b, source, work)


def scenario_calib_strategies(b, source, work):
    """S3: the calib_touch shift once per drift strategy, the estimator's among them."""
    import calib_e2e
    calib_e2e.scenario_strategies(sys.modules[__name__], b, source, work)


# S0's end-to-end ordering (issue 22): the demo face with each wear strategy, and the same with
# [creep.estimator] (its defaults; docs/estimation.md), on the same parts: same seed, same NC,
# lock-step. S0_PARTS parts with one tool, so that the estimator sees 12 laser measurements.
S0_PARTS = 3
S0_ROWS = [
    ("step", "step correction", "nccompd-step.toml", False),
    ("creep", "creeping", "nccompd-creep.toml", False),
    ("predict", "predictive creeping", "nccompd-predict.toml", False),
    ("creep_est", "creeping, estimator", "nccompd-creep.toml", True),
    ("predict_est", "predictive creeping, estimator", "nccompd-predict.toml", True),
]


def s0_estimator_config(source, work, cfg):
    """config/demo/<cfg> with [creep.estimator] enabled = true appended (the demo configs have
    no such table to override), written to work; its includes made absolute."""
    demo = os.path.join(source, "config", "demo")
    with open(os.path.join(demo, cfg)) as f:
        text = f.read()

    def absolute(m):
        items = [i.strip().strip('"') for i in m.group(2).split(",") if i.strip()]
        return m.group(1) + "[" + ", ".join(
            '"%s"' % os.path.normpath(os.path.join(demo, i)) for i in items) + "]"

    text, n = PATH_LISTS.subn(absolute, text)
    if n != 1 or "[creep.estimator]" in text:
        raise RuntimeError("%s: expected one include list and no [creep.estimator]" % cfg)
    path = os.path.join(work, "estimator-" + cfg)
    with open(path, "w") as f:
        f.write(text + "\n[creep.estimator]\nenabled = true\n")
    return path


def s0_table(res):
    lines = ["| strategy | form error RMS [um] | form error max [um] | max step within a pass "
             "[um] | laser measurements |", "| --- | --- | --- | --- | --- |"]
    for key, label, _, _ in S0_ROWS:
        r = res[key]
        s = r.report["surface"]
        lines.append("| %s | %.3f | %.3f | %.3f | %d |" % (
            label, s["form"]["rms_um"], s["form"]["max_abs_um"], s["max_step_um"],
            len(r.tool_wear_paths())))
    return "\n".join(lines)


def scenario_s0_estimator(b, source, work):
    """Issue 22, S0 end to end: the demo face (S0_PARTS parts, one tool) with step, creeping,
    predictive creeping and both creeping modes with [creep.estimator], over Modbus in lock-step.
    Prints each one's form error; asserts what the lock-step makes deterministic: clean exits,
    no alarm, the laser on the daemon's request at the same cut paths in every row (the same
    measurements), the estimator rows' status mode, and the creeping rows' bounded steps. The
    ordering is reported, not asserted (bench/results/e2e.md)."""
    res = {}
    for key, label, cfg, estimator in S0_ROWS:
        # An absolute path: stage_configs takes it as it is.
        daemon_cfg = s0_estimator_config(source, work, cfg) if estimator else cfg
        res[key] = run_machining(b, source, work, "s0_" + key, daemon_cfg, "ncsim-demo.toml",
                                 parts=S0_PARTS, echo=print, timeout_s=600.0)
    print(s0_table(res))
    c = Check("s0_estimator")
    for key, label, _, _ in S0_ROWS:
        r = res[key]
        c.that(r.ncsim_rc == 0 and r.daemon_rc == 0 and r.report["bad_rows"] == 0,
               "%s: ncsim exit %d, nccompd exit %d, %d bad rows" % (
                   label, r.ncsim_rc, r.daemon_rc, r.report["bad_rows"]))
        c.that(not r.alarms("alarm") and r.report["alarms_seen"] == 0,
               "%s: no alarm (%s), NC saw none" % (label, r.alarms("alarm")))
        check_laser_on_request(c, r, label, LASER_INTERVAL_MM, min_trips=3 * S0_PARTS)
    paths = {k: [round(p, 1) for _, p in res[k].tool_wear_paths()] for k in res}
    c.that(all(p == paths["step"] for p in paths.values()),
           "every row measured at the same cut paths: %s" % paths["step"])
    for key, base in (("creep_est", "creep"), ("predict_est", "predict")):
        c.that(res[key].writes() != res[base].writes(),
               "%s: [creep.estimator] changed the offsets the NC took (against %s)" % (key, base))
    ss = res["step"].report["surface"]
    for key, label, _, _ in S0_ROWS[1:]:
        s = res[key].report["surface"]
        c.that(s["max_step_um"] < 0.25 * ss["max_step_um"],
               "%s max step %.3f um < 1/4 of step correction's %.3f um" % (
                   label, s["max_step_um"], ss["max_step_um"]))
    rms = {k: res[k].report["surface"]["form"]["rms_um"] for k in res}
    print("ordering by form error RMS: %s" % " < ".join(
        "%s %.3f" % (k, rms[k]) for k in sorted(rms, key=rms.get)))
    # The benchmark's ordering where it is wide (bench/results/creep.md, section 5: predictive +
    # estimator 0.67x the step correction's RMS, creeping 1.03x); lock-step makes it repeatable.
    for key in ("step", "creep"):
        c.that(rms["predict_est"] < rms[key],
               "predictive creeping with the estimator: form RMS %.3f um < %s's %.3f um" % (
                   rms["predict_est"], key, rms[key]))
    c.done()


SCENARIOS = {
    "modbus_modes": scenario_modbus_modes,
    "modbus_realtime": scenario_modbus_realtime,
    "modbus_restart": scenario_modbus_restart,
    "broken_tool": scenario_broken_tool,
    "implausible_probe": scenario_implausible_probe,
    "walls_modes": scenario_walls_modes,
    "roll": scenario_roll,
    "undeclared_effect": scenario_undeclared_effect,
    "model_loop": scenario_model_loop,
    "model_handover": scenario_model_handover,
    "can_modes": scenario_can_modes,
    "calib_touch": scenario_calib_touch,
    "calib_strategies": scenario_calib_strategies,
    "s0_estimator": scenario_s0_estimator,
    "demo_loop": scenario_demo_loop,
}


# ---------------------------------------------------------------------------------------------
# The demo (scripts/demo)


# The demo's loop (issue 19 item 4). First batch: the loop daemon (nccompd-loop.toml:
# nccompd-creep.toml plus a [model] section with nothing fitted yet, so it cuts as the creep row)
# machines LOOP_FIRST_BATCH parts with one tool (one part gives the analysis four laser
# measurements: too few to tell a line from a curve). `nccomp analyze` fits
# model-face-declared.toml to that daemon's measurement log; the daemon, started again on the
# first batch's state, gets the analysis's model.toml, and the second batch, one more part with
# the same tool (ncsim --continue), is machined with it.
LOOP_MODE = ("model", "creeping + the model from the analysis")
LOOP_CONFIG = "nccompd-loop.toml"
LOOP_FIRST_BATCH = 2
# The first batch's probe cycle of the finished face (ncsim; nccompd-loop.toml's
# [measurement_log.face_probe] logs each reading as a contour row): mid-X of passes 0, 8, 15,
# 23 and 30.
LOOP_PROBE_POINTS = 5
SUMMARY_KEYS = ("mode", "max_step_um", "form_rms_um", "form_max_um")
# The second batch's part starts with an approach of 0.5 s, not cutting (ncsim's
# program.mould_face.approach_s): the model the operator loads between the batches swaps in
# there, between two parts, so what the laser does not see (the push-off) is in force from the
# first cut (docs/demo.md, "The loop").
LOOP_SECOND_SETS = ["program.mould_face.approach_s=0.5"]
# The model row's form RMS in lock-step [um]: issue 19's target (1.270 measured: the push-off
# fitted to the face probe's rows and loaded in the approach before the first cut;
# bench/results/handover.md).
MODEL_ROW_RMS_BOUND_UM = 1.5


# Real time: the first batch's parts run this much faster than the four modes (the wear follows
# the cut path, not the clock), so that the batch takes half a part's time of the four modes.
# Faster first batches lose the face probe's rows (x8: 4 of 10).
LOOP_SPEEDUP = 2.0
# Real time: the part with the model runs this much faster than the four modes. The daemon's
# writes are then 1.5 times sparser in machine time than in the rows it is compared with; at x2
# the radius register's fast changes along a pass came two 0.1 um counts per write at times, and
# the max step reached 0.155 um in 3 of 6 runs; at x1.5 and x1 it stayed at or under 0.130 um in
# 6 of 6 (bench/results/handover.md), and x1.5 keeps the demo at about a minute.
LOOP_MODEL_SPEEDUP = 1.5


def run_first_batch(b, source, work, speed=None, echo=print):
    """The loop daemon on LOOP_FIRST_BATCH parts; real time: ncsim at speed x LOOP_SPEEDUP x
    LOOP_FIRST_BATCH, so that the batch takes half a part's time of the four modes."""
    return run_machining(b, source, work, "batch1", LOOP_CONFIG, "ncsim-demo.toml",
                         parts=LOOP_FIRST_BATCH, echo=echo,
                         sets=["program.mould_face.probe_points=%d" % LOOP_PROBE_POINTS],
                         speed=None if speed is None else speed * LOOP_SPEEDUP * LOOP_FIRST_BATCH)


def run_loop(b, source, work, first, speed=None, echo=print):
    """After the first batch: the analysis, the model into the daemon, the second batch. Lock-step
    (deterministic): the daemon's [model] file is pointed at the model and it gets SIGHUP before
    ncsim ticks (the reload `nccomp model load` runs); real time: `nccomp model load FILE` on its
    status socket. Returns (RunResult of the second batch, the analysis's summary.json)."""
    log = os.path.join(first.run_dir, "log", "measurements.csv")
    out = os.path.join(work, "analysis")
    shutil.rmtree(out, ignore_errors=True)
    a = subprocess.run([b.nccomp, "analyze", "--log", log, "--config",
                        os.path.join(source, "config", "demo", "model-face-declared.toml"),
                        "--out", out], capture_output=True, text=True, timeout=300)
    echo("nccomp analyze --log %s: exit %d\n%s" % (log, a.returncode, a.stdout.rstrip()))
    if a.returncode != 0:
        raise RuntimeError("nccomp analyze failed (%d): %s" % (a.returncode, a.stderr[-2000:]))
    with open(os.path.join(out, "summary.json")) as f:
        analysis = json.load(f)
    model = os.path.join(out, "model.toml")
    initial = {"model.file": '"%s"' % os.path.join(source, "config", "demo",
                                                   "model-face-initial.toml")}
    if speed is None:
        second, _ = run_continued(b, source, work, "model", LOOP_CONFIG, initial, 1,
                                  LOOP_SECOND_SETS, first.out_dir, first.run_dir,
                                  program="mould_face", reload_cfg=LOOP_CONFIG,
                                  reload_overrides={"model.file": '"%s"' % model})
        second.model_load = None
        echo("the daemon's [model] file set to %s, SIGHUP: %s" % (
            model, json.dumps(second.handover)))
    else:
        second, _ = run_continued(b, source, work, "model", LOOP_CONFIG, initial, 1,
                                  LOOP_SECOND_SETS, first.out_dir, first.run_dir,
                                  program="mould_face", model_load=model,
                                  speed=speed * LOOP_MODEL_SPEEDUP)
        rc, answer = second.model_load
        echo("nccomp model load %s: exit %d\n%s" % (model, rc, answer.rstrip()))
    echo("%s: %s" % (second.name, summary_line(second.report)))
    return second, analysis


def summary_rows(res):
    """summary.json: one row per mode, the figures of `nccomp report` of its run."""
    rows = []
    for key in [k for k, _, _ in MODES] + [LOOP_MODE[0]]:
        s = res[key].report["surface"]
        rows.append(dict(zip(SUMMARY_KEYS, (key, s["max_step_um"], s["form"]["rms_um"],
                                            s["form"]["max_abs_um"]))))
    return rows


def run_demo(b, source, work, speed=None, echo=print):
    """The four modes and the loop; returns ({mode: RunResult}, analysis summary). The loop (first
    batch, analysis, the part with the model) depends on none of the four modes, so it runs
    beside them: lock-step, two runs at a time (each pair of processes keeps about one CPU busy;
    lock-step is deterministic whatever runs beside it), the loop on one worker and the four
    modes one after the other on the other; real time, the four modes side by side and the loop
    beside them (its first batch LOOP_SPEEDUP x LOOP_FIRST_BATCH faster)."""
    import concurrent.futures

    def loop():
        return run_loop(b, source, work, run_first_batch(b, source, work, speed, echo),
                        speed=speed, echo=echo)
    if speed is None:
        with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
            looped = pool.submit(loop)
            modes = {key: pool.submit(run_machining, b, source, work, key, cfg, "ncsim-demo.toml",
                                      echo=echo, sets=MODE_SETS.get(key, []))
                     for key, _, cfg in MODES}
            res = {key: f.result() for key, f in modes.items()}
            res["model"], analysis = looped.result()
    else:
        with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
            looped = pool.submit(loop)
            res = run_modes(b, source, work, speed=speed, parallel=True, echo=echo)
            res["model"], analysis = looped.result()
    with open(os.path.join(work, "summary.json"), "w") as f:
        json.dump(summary_rows(res), f, indent=1)
        f.write("\n")
    return res, analysis


def demo(b, source, work, speed):
    os.makedirs(work, exist_ok=True)
    mode = "lock-step" if speed is None else "real time, ncsim at x%g" % speed
    print("demo: machining the mould face (part a) four times over Modbus TCP on 127.0.0.1, %s; "
          "the loop: %d parts with creeping, nccomp analyze on that daemon's log, the model into "
          "the daemon, one more part" % (mode, LOOP_FIRST_BATCH), flush=True)
    res, _ = run_demo(b, source, work, speed=speed,
                      echo=lambda s: print("  " + s.replace("\n", "\n  "), flush=True))
    print()
    print(modes_table(res))
    print()
    for key, label in [(k, l) for k, l, _ in MODES] + [LOOP_MODE]:
        r = res[key]
        print("%-40s report: nccomp report %s   plot: %s" % (
            label, r.out_dir, os.path.join(r.out_dir, "error.svg")))
    print("summary: %s" % os.path.join(work, "summary.json"))
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
