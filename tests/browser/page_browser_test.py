#!/usr/bin/python3
"""The operator page (nccomp-page) in a real headless Chromium.

nccompd runs on a Modbus NC (pymodbus' own server on 127.0.0.1, tests/hil/modbus/pymodbus_peer.py)
with a [creep] module whose alarm and "measurement due" flags are NC registers; nccomp-page serves
its status socket. The test plays the laser over Modbus and checks, in the browser:
  1. the page loads and shows what `nccomp status --json` says at the same moment: each register's
     output (exact to the page's 0.001 um), the configured rate, the creep module's counts (exact),
     the loop's cycle count within 2 s of cycles (it moves);
  2. a broken-tool alarm raised by the daemon appears on the page within 1 s of the NC's alarm
     register rising, without a reload;
  3. the latest analysis report (--report-dir: the committed FL_THERMAL analysis under
     bench/model/figures/) with its figures from summary.json and every plot loaded;
  4. acknowledge from a browser run by `nobody` (not root, not in the admin group; chromedriver
     started with setpriv, so as root only) is refused with the reason and the daemon stays
     halted; cancelling the dialog sends nothing; acknowledge from this user's browser (root, or
     when not root the user's primary group as --admin-group), confirmed in the dialog, lifts the
     halt (status and NC flag) and both logs name who did it;
  5. the Model card (B loaded over A before the first measurement, C a candidate in shadow that
     the rule announces after one part) shows what the status JSON and `nccomp model status`
     say: live and rollback models, both scores, the rule's state, the handovers; Promote and
     Roll back from nobody's browser are refused; from this user's, confirmed, Promote makes C
     live and Roll back B again, each a handover, as status shows; the NC keeps the measured
     -5.0 um (the models predict the wear the laser measures: it is not counted twice).
Screenshots of the page go to WORK. Exit 77 (ctest SKIP_RETURN_CODE) when chromium,
chromedriver or selenium is missing; 1 on a failed check.
"""

import argparse
import grp
import json
import os
import pwd
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request

SKIP = 77


def skip(why):
    print("SKIP: " + why, flush=True)
    sys.exit(SKIP)


CHROMIUM = shutil.which("chromium")
CHROMEDRIVER = shutil.which("chromedriver")
if not CHROMIUM or not CHROMEDRIVER:
    skip("chromium and chromium-driver are needed (apt-get install chromium chromium-driver)")
try:
    from selenium import webdriver
    from selenium.webdriver.common.by import By
    from selenium.webdriver.chrome.service import Service
except ImportError:
    skip("python3-selenium is needed (apt-get install python3-selenium; run with /usr/bin/python3)")
from pymodbus.client import ModbusTcpClient

HERE = os.path.dirname(os.path.abspath(__file__))

LENGTH, ALARM, REQUEST = 200, 240, 242  # NC holding registers the daemon writes
RATE_HZ = 200


class Failed(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failed(what)
    print("ok: " + what, flush=True)


def wait_until(f, limit_s=10.0, every_s=0.02):
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        v = f()
        if v:
            return v
        time.sleep(every_s)
    return f()


def config_text(port):
    return f"""[daemon]
rate_hz = {RATE_HZ}
[state]
directory = "state"
min_interval_s = 0.05
[measurement_log]
directory = "log"
[status]
socket_path = "status.sock"
admin_group = "adm"
[modbus]
transport = "tcp"
host = "127.0.0.1"
port = {port}
poll_rate_hz = 200
response_timeout_s = 0.5
[modbus.axis]
x_mm = {{ address = 0, type = "int32", scale = 0.0001 }}
tool = {{ address = 8, type = "uint16" }}
[modbus.tool_measurement]
sequence = {{ address = 100, type = "uint16" }}
tool = {{ address = 101, type = "uint16" }}
wear_um = {{ address = 102, type = "float32" }}
broken = {{ address = 104, type = "uint16" }}
[[modbus.offset]]
register_index = 0
address = {LENGTH}
type = "int32"
scale = 0.1
[[modbus.offset]]
register_index = 1
address = {ALARM}
type = "uint16"
scale = 1.0
[[modbus.offset]]
register_index = 2
address = {REQUEST}
type = "uint16"
scale = 1.0
[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "modbus"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 50
[[registers]]
name = "creep_alarm"
kind = "flag"
bus = "modbus"
[[registers]]
name = "measure_request"
kind = "flag"
bus = "modbus"
[creep]
creep_basis = "time"
creep_time_s = 1.0
profile = "linear"
[creep.edge]
tool_shape = "tip"
normal_source = "none"
fallback_channel = "length"
[creep.output]
mode = "tool_registers"
length_register = "T1_length_wear"
alarm_register = "creep_alarm"
measurement_due_register = "measure_request"
[creep.interval]
basis = "time"
interval_s = 1.0
[model]
file = "a/model-a.toml"
update = "cycle"
[[model.apply]]
term = "offset"
register = "T1_length_wear"
gain = 1
kind = "tool_wear"
# One part decides (p = 1/2): the candidate better on the first part is announced.
[model.shadow]
min_parts = 1
alpha = 0.5
promote = "operator"
"""


def model_text(name, coef_um=0.0):
    """A fitted model with one constant tool-wear term: A and B (0 um) move no offset when
    changed; every tool measurement is scored (a part of its own)."""
    return ("[model]\n[[model.term]]\nname = \"" + name + "\"\nform = \"constant\"\n"
            "kinds = [\"tool_wear\"]\ngroups = [[0.0, 0.0]]\ncoef_um = [" + str(coef_um) + "]\n")


class Nc:
    """The test's Modbus master on the NC server: reads the daemon's writes, plays the laser."""

    def __init__(self, port):
        self.c = ModbusTcpClient("127.0.0.1", port=port)
        if not self.c.connect():
            raise Failed("cannot connect to the Modbus NC server")

    def hr(self, address, count=1):
        r = self.c.read_holding_registers(address, count)
        if r.isError():
            raise Failed(f"Modbus read of {address}: {r}")
        return r.registers

    def length_0p1um(self):
        hi, lo = self.hr(LENGTH, 2)
        return struct.unpack(">i", struct.pack(">HH", hi, lo))[0]

    def measurement(self, seq, wear_um, broken):
        hi, lo = struct.unpack(">HH", struct.pack(">f", wear_um))
        self.c.write_registers(101, [1, hi, lo, 1 if broken else 0])  # values first,
        self.c.write_registers(100, [seq])                            # then the counter


def start(name, argv, work):
    sys.path.insert(0, os.path.join(ARGS.source, "tests", "e2e"))
    import nccomp_e2e  # the e2e runner's process helper: own group, killed with the runner
    return nccomp_e2e.Proc(name, argv, os.path.join(work, name + ".log"), cwd=work)


def status_json():
    out = subprocess.run([ARGS.nccomp, "status", "--json", "--socket", SOCKET],
                         capture_output=True, text=True, timeout=10)
    if out.returncode != 0:
        return None
    return json.loads(out.stdout)


def module(status, name):
    return next(m["status"] for m in status["modules"] if m["name"] == name)


def browser(work, user=None):
    """Headless Chromium; as another user through chromedriver started as that user."""
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=1280,1000", "--no-first-run", "--disable-extensions"):
        opts.add_argument(a)
    if user is None:
        opts.add_argument("--user-data-dir=" + tempfile.mkdtemp(dir=work, prefix="chrome-"))
        return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts), None
    pw = pwd.getpwnam(user)
    home = tempfile.mkdtemp(dir=work, prefix="home-" + user + "-")
    os.chown(home, pw.pw_uid, pw.pw_gid)
    opts.add_argument("--user-data-dir=" + os.path.join(home, "chrome"))
    sys.path.insert(0, os.path.join(ARGS.source, "tests", "e2e"))
    import nccomp_e2e  # free_port(): below the kernel's ephemeral range
    port = nccomp_e2e.free_port()
    driver_proc = start("chromedriver-" + user,
                        ["setpriv", f"--reuid={pw.pw_uid}", f"--regid={pw.pw_gid}",
                         "--clear-groups", "env", "HOME=" + home, "XDG_CONFIG_HOME=" + home,
                         "XDG_CACHE_HOME=" + home, CHROMEDRIVER, f"--port={port}"], work)

    def up():
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return True
        except OSError:
            return False
    if not wait_until(up, 10):
        raise Failed("chromedriver as " + user + " did not start: " + driver_proc.log())
    return webdriver.Remote(command_executor=f"http://127.0.0.1:{port}", options=opts), driver_proc


def text(d, css):
    """The element's text now, in one script call (the page re-renders on every snapshot)."""
    return d.execute_script(
        "const e = document.querySelector(arguments[0]); return e ? e.textContent : null", css)


# Everything the comparison reads, from one rendering of the page.
READ_PAGE = """
const q = (s) => { const e = document.querySelector(s); return e ? e.textContent : null; };
const regs = {};
const limits = {};
for (const tr of document.querySelectorAll('#registers tr[data-register]')) {
  regs[tr.dataset.register] = tr.querySelector('.output').textContent;
  limits[tr.dataset.register] = tr.querySelector('.limits').textContent;
}
const creep = {};
for (const td of document.querySelectorAll("[data-module='creep'] td[data-name]"))
  creep[td.dataset.name] = td.textContent;
return {cycles: document.body.dataset.cycles, regs: regs, limits: limits, rate: q("#loop td[data-name='rate']"),
        creep: creep, updated: q('#updated')};
"""


def main():
    work = ARGS.work
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    os.chmod(work, 0o755)
    global SOCKET
    SOCKET = os.path.join(work, "status.sock")

    peer = start("nc", ["/usr/bin/python3", "-u",
                        os.path.join(ARGS.source, "tests/hil/modbus/pymodbus_peer.py"),
                        "tcp", "0", "hr=8:1"], work)
    nc_port = wait_until(lambda: next((int(l.split()[1]) for l in open(peer.log_path)
                                       if l.startswith("PORT ")), None), 15)
    check(nc_port, "the Modbus NC server listens")
    with open(os.path.join(work, "nccompd.toml"), "w") as f:
        f.write(config_text(nc_port))
    for d in ("a", "b", "c"):  # A live, B loaded later (A kept for rollback), C a candidate
        os.makedirs(os.path.join(work, d))
        with open(os.path.join(work, d, f"model-{d}.toml"), "w") as f:
            f.write(model_text("offset", 2.0 if d == "c" else 0.0))
            f.write(f"# model {d}\n")
    daemon = start("nccompd", [ARGS.nccompd, "--config", "nccompd.toml"], work)
    check(wait_until(lambda: (s := status_json()) and s["buses"][0]["state"] == "up"
                     and s["loop"]["cycles"] >= 20, 20), "nccompd runs on the NC")
    # The models before the first measurement, so that the measurements are scored: B live, A
    # kept for rollback, C a candidate in shadow.
    models = [os.path.join(work, d, f"model-{d}.toml") for d in ("a", "b", "c")]
    nccomp("model", "load", models[1])
    nccomp("model", "candidate", models[2])
    # A copy, named relative to the page's directory (the screenshots show the name).
    report_dir = os.path.join(work, "analysis")
    shutil.copytree(os.path.join(ARGS.source, "bench/model/figures/fl_thermal_ch1"), report_dir)
    # As root the test also runs a browser as nobody (outside group adm); as another user, that
    # user's own primary group is the admin group and the refused case is not run.
    admin_group = "adm" if AS_ROOT else grp.getgrgid(ME.pw_gid).gr_name
    page = start("nccomp-page", [ARGS.page, "--listen", "127.0.0.1:0", "--socket", SOCKET,
                                 "--admin-group", admin_group, "--report-dir", "analysis"], work)

    def page_port():
        for line in open(page.log_path):
            if "listening on http://127.0.0.1:" in line:
                return int(line.split("http://127.0.0.1:")[1].split("/")[0])
        return None
    port = wait_until(page_port, 15)
    check(port, "nccomp-page listens on 127.0.0.1")
    url = f"http://127.0.0.1:{port}/"
    nc = Nc(nc_port)

    # The first measurement: 5.0 um crept into the length register (-50 in 0.1 um).
    check(wait_until(lambda: nc.hr(REQUEST)[0] == 1, 10), "the first measurement is due")
    nc.measurement(1, 5.0, False)
    check(wait_until(lambda: nc.length_0p1um() == -50, 10), "5.0 um crept in on the NC")

    root, _ = browser(work)
    drivers = [root]
    try:
        root.get(url)
        check(wait_until(lambda: text(root, "#conn") == "live", 10), "the page loads and is live")
        # The NC's -50 (0.1 um, int32) is the daemon's -5.0 um.
        check(wait_until(lambda: text(root, "#registers tr[data-register='T1_length_wear'] .output")
                         == "-5.000", 5), "the page shows the crept-in offset, -5.000 um")
        # The same moment: the page's DOM, then the daemon's status, then the DOM again; values
        # that do not move must be equal, the cycle count within 2 s of the loop's rate.
        shown = root.execute_script(READ_PAGE)
        st = status_json()
        check(len(shown["regs"]) == len(st["registers"]) == 3, "three registers on both")
        for r in st["registers"]:
            check(shown["regs"][r["name"]] == f"{r['output_um']:.3f}",
                  f"register {r['name']}: page {shown['regs'][r['name']]} = status "
                  f"{r['output_um']:.3f}")
        # Limits: the config's for the length register; a flag shows only its absolute limit.
        check(shown["limits"]["T1_length_wear"] == "|x| ≤ 200 µm, step ≤ 5 µm, rate ≤ 50 µm/s",
              f"T1_length_wear's limits as configured: {shown['limits']['T1_length_wear']}")
        for r in st["registers"]:
            want = f"|x| ≤ {r['max_abs_um']:g} µm"
            if r["kind"] != "flag":
                want += f", step ≤ {r['max_step_um']:g} µm, rate ≤ {r['max_rate_um_per_s']:g} µm/s"
            check(shown["limits"][r["name"]] == want,
                  f"register {r['name']} limits: page '{shown['limits'][r['name']]}' = status")
        check(shown["rate"].startswith(f"{st['loop']['rate_hz']:.1f} Hz configured"),
              f"the configured loop rate: {shown['rate']}")
        creep = module(st, "creep")
        for key in ("measurements_accepted", "halted", "creeps_in_progress", "wear_in_force_um"):
            check(float(shown["creep"][key]) == float(creep[key]),
                  f"creep {key}: page {shown['creep'][key]} = status {creep[key]}")
        cycles = st["loop"]["cycles"]
        check(abs(int(shown["cycles"]) - cycles) <= 2 * RATE_HZ,
              f"loop cycles: page {shown['cycles']}, status {cycles} (within {2 * RATE_HZ}, 2 s)")
        root.save_screenshot(os.path.join(work, "page-live.png"))

        # The report: the figures of its summary.json, every plot of plots/ shown and loaded.
        with open(os.path.join(report_dir, "summary.json")) as f:
            summary = json.load(f)
        plots = sorted(n for n in os.listdir(os.path.join(report_dir, "plots")) if n.endswith(".svg"))
        check(wait_until(lambda: (t := text(root, "#report-meta")) and
                         f"final {summary['final_rms_um']:.3f} um" in t.replace("µ", "u"), 5),
              f"the report's final RMS {summary['final_rms_um']:.3f} um is shown")
        rows = root.execute_script("return document.querySelectorAll('#report-effects tbody tr').length")
        check(rows == len(summary["effects"]), f"{rows} effects shown, {len(summary['effects'])} in the report")
        loaded = lambda: root.execute_script(
            "return [...document.querySelectorAll('#report-plots img')]"
            ".map((i) => [i.alt, i.complete && i.naturalWidth > 0])")
        check(wait_until(lambda: (l := loaded()) and [a for a, _ in l] == plots and all(ok for _, ok in l), 10),
              f"every plot is shown and loaded: {plots}")
        root.find_element(By.ID, "report-card").screenshot(os.path.join(work, "page-report.png"))

        # A broken tool: the daemon halts and raises alarm 23; the page shows it within 1 s of
        # the NC's alarm register rising, without a reload.
        check(wait_until(lambda: nc.hr(REQUEST)[0] == 1, 10), "the next measurement is due")
        nc.measurement(2, 6.0, True)
        check(wait_until(lambda: nc.hr(ALARM)[0] == 1, 10, 0.005), "the NC's alarm register is 1")
        t_nc = time.monotonic()
        shown = wait_until(lambda: "tool_broken_or_mismeasured" in text(root, "#alarms"), 3, 0.01)
        dt = time.monotonic() - t_nc
        check(shown and dt <= 1.0, f"the alarm is on the page {dt:.3f} s after the NC's flag (<= 1 s)")
        check(wait_until(lambda: text(root, "#latched").startswith("HALTED: latched alarm 23"), 3),
              "the page shows the creep module halted")
        check(root.execute_script("return performance.getEntriesByType('navigation').length") == 1,
              "no reload")
        root.execute_script("window.scrollTo(0, 0)")
        root.save_screenshot(os.path.join(work, "page-alarm.png"))

        # nobody's browser (root only: setpriv): the dialog, confirmed; refused by the page, the
        # daemon still halted.
        if AS_ROOT:
            other, _ = browser(work, "nobody")
            drivers.append(other)
            refused_for_nobody(other, url, work, nc)
        else:
            print("note: not root: the refused case (a browser run as nobody) is not run",
                  flush=True)
        acknowledged_by_this_user(root, page, daemon, url, work, nc)
        model_card(root, drivers[1] if AS_ROOT else None, page, work, nc)
    finally:
        for d in drivers:
            d.quit()
        for p in list(__import__("nccomp_e2e").LIVE):
            p.stop()


def refused_for_nobody(other, url, work, nc):
    other.get(url)
    check(wait_until(lambda: text(other, "#conn") == "live", 10), "nobody's page is live")
    other.find_element(By.ID, "ack").click()
    check(wait_until(lambda: other.execute_script(
        "return document.getElementById('ack-dialog').open"), 3),
        "acknowledge opens a confirmation dialog")
    other.find_element(By.ID, "ack-confirm").click()
    why = ("refused (HTTP 403): permission denied: nobody (uid 65534) is not root and not in "
           "group 'adm' (--admin-group)")
    check(wait_until(lambda: text(other, "#ack-result") == why, 5), "nobody is refused: " + why)
    other.save_screenshot(os.path.join(work, "page-refused.png"))
    time.sleep(0.3)
    check(module(status_json(), "creep")["halted"] == 1 and nc.hr(ALARM)[0] == 1,
          "after the refusal the daemon is still halted and the NC's alarm still 1")


def acknowledged_by_this_user(root, page, daemon, url, work, nc):
    # Cancel sends nothing; Acknowledge, confirmed, lifts the halt.
    root.find_element(By.ID, "ack").click()
    root.save_screenshot(os.path.join(work, "page-dialog.png"))
    actions_before = open(page.log_path).read().count(" action")
    root.find_element(By.ID, "ack-cancel").click()
    time.sleep(0.5)
    check(text(root, "#ack-result") == "" and
          open(page.log_path).read().count(" action") == actions_before, "cancel sends nothing")
    root.find_element(By.ID, "ack").click()
    root.find_element(By.ID, "ack-confirm").click()
    want = "ok acknowledged: creep: halt and alarm flag cleared (alarm tool_broken_or_mismeasured 23)"
    check(wait_until(lambda: text(root, "#ack-result").startswith(want), 5),
          ME.pw_name + " acknowledges: " + want)
    check(wait_until(lambda: nc.hr(ALARM)[0] == 0, 3), "the NC's alarm register falls to 0")
    check(module(status_json(), "creep")["halted"] == 0, "the daemon is no longer halted")
    check(wait_until(lambda: text(root, "#latched") == "nothing latched", 3),
          "the page shows nothing latched")
    root.save_screenshot(os.path.join(work, "page-acknowledged.png"))
    plog = open(page.log_path).read()
    if AS_ROOT:
        check("action refused: acknowledge by nobody (uid 65534)" in plog,
              "the page's log names the refused user")
    me = f"{ME.pw_name} (uid {ME.pw_uid})"
    check(f"action acknowledge by {me}: ok acknowledged" in plog,
          "the page's log names the user who acknowledged")
    # The page runs as this user too: the daemon logs the page's user.
    check(f"operator command from uid {ME.pw_uid} ({ME.pw_name})" in open(daemon.log_path).read(),
          "the daemon's log names the page's user")
    with urllib.request.urlopen(url + "api/status", timeout=10) as r:
        counters = json.loads(r.read())["page"]
    check(counters["bad_requests"] == 0, f"no bad requests from the browsers: {counters}")


def nccomp(*args):
    out = subprocess.run([ARGS.nccomp, *args, "--socket", SOCKET], capture_output=True, text=True,
                         timeout=20)
    check(out.returncode == 0, f"nccomp {' '.join(args)}: {out.stdout.strip()} {out.stderr.strip()}")
    return out.stdout


READ_MODEL = """
const r = {};
for (const td of document.querySelectorAll('#model td[data-name]')) {
  r[td.dataset.name] = td.textContent;
  r[td.dataset.name + '_title'] = td.title;
}
r.promote_disabled = document.getElementById('promote').disabled;
r.rollback_disabled = document.getElementById('rollback').disabled;
return r;
"""


def model_text_of(r, name=lambda path: path):
    return "none" if not r["file"] else (
        f"{name(r['file'])} (hash {r['hash']})" +
        (f", live since {r['since_utc']}" if r["since_utc"] else ""))


def page_text_of(r):
    """The page names a model by its file's name and hash (the path is the row's tooltip)."""
    return model_text_of(r, os.path.basename)


def model_card(root, other, page, work, nc):
    """The Model card equals the status JSON; Promote and Roll back refused for nobody; this user
    promotes C (announced by the rule) and rolls back to B, each confirmed."""
    a, b, c = (os.path.join(work, d, f"model-{d}.toml") for d in ("a", "b", "c"))
    st = wait_until(lambda: (s := status_json()) and s["shadow"]["phase"] == "announced" and s, 5)
    check(st and st["model"]["live"]["file"] == b and st["model"]["previous"]["file"] == a and
          st["shadow"]["other"]["file"] == c,
          "status JSON: B live, A kept for rollback, C in shadow announced by the rule")
    text_status = nccomp("model", "status")
    check(f"ok model: {model_text_of(st['model']['live'])}\n" in text_status and
          f"previous (nccomp model rollback returns to it): {model_text_of(st['model']['previous'])}"
          in text_status, "nccomp model status names the same live and rollback models")
    check(wait_until(lambda: (m := root.execute_script(READ_MODEL)).get("other") ==
                     os.path.basename(c) and m.get("other_title") == c, 5),
          "the Model card shows the candidate")
    shown = root.execute_script(READ_MODEL)
    st = status_json()
    sh, h = st["shadow"], st["handover"]
    check(shown["live"] == page_text_of(st["model"]["live"]) and
          shown["live_title"] == st["model"]["live"]["file"],
          f"live model: page '{shown['live']}' (path '{shown['live_title']}') = status")
    check(shown["previous"] == page_text_of(st["model"]["previous"]) and
          shown["previous_title"] == st["model"]["previous"]["file"],
          f"kept for rollback: page '{shown['previous']}' = status")
    # One part scored (the 5.0 um measurement; the broken one waits for a next row): B predicts
    # 0 um, C 2 um, so their squared errors are 25 and 9 um².
    check(sh["live"]["parts"] == sh["other"]["parts"] == 1 and sh["live"]["mse_um2"] == 25.0 and
          sh["other"]["mse_um2"] == 9.0, f"scores: live {sh['live']}, candidate {sh['other']}")
    for key, m in (("live_score", sh["live"]), ("other_score", sh["other"])):
        want = f"{m['parts']} parts, mean squared error {m['mse_um2']:.4f} µm²"
        check(m["parts"] >= 1 and shown[key] == want, f"{key}: page '{shown[key]}' = status")
    check(shown["phase"] == "announced: the candidate is better, Promote makes it live (promote: "
          f"operator, {sh['decisions']} decision(s))", f"the rule's state: {shown['phase']}")
    check(shown["handovers"].startswith(f"{h['handovers']} (registers rebased {h['rebased']}, "
                                        f"not absorbed {h['unabsorbed']})"),
          f"handovers: {shown['handovers']}")
    check(not shown["promote_disabled"] and not shown["rollback_disabled"],
          "Promote (candidate announced) and Roll back enabled")
    card = root.find_element(By.ID, "model-card")
    root.execute_script("arguments[0].scrollIntoView()", card)
    card.screenshot(os.path.join(work, "page-model.png"))
    if other is not None:
        check(wait_until(lambda: not other.execute_script(
            "return document.getElementById('promote').disabled"), 5), "nobody's page is current")
        why = ("refused (HTTP 403): permission denied: nobody (uid 65534) is not root and not in "
               "group 'adm' (--admin-group)")
        for button in ("promote", "rollback"):
            other.execute_script("document.getElementById('model-result').textContent = ''")
            other.find_element(By.ID, button).click()
            other.find_element(By.ID, "model-confirm").click()
            check(wait_until(lambda: text(other, "#model-result") == why, 5),
                  f"nobody's {button} is refused: " + why)
        check(status_json()["model"]["live"]["file"] == b, "after the refusals B is still live")

    def press(button, dialog_starts, now, before):
        root.find_element(By.ID, button).click()
        check(root.execute_script("return document.getElementById('model-dialog').open") and
              text(root, "#model-dialog-text").startswith(dialog_starts),
              f"{button} opens a confirmation dialog: {text(root, '#model-dialog-text')}")
        root.find_element(By.ID, "model-confirm").click()
        # The daemon's answer names the models by path: the line shows their file names, its
        # tooltip the answer with the paths.
        answer = (f"ok model {'promoted' if button == 'promote' else 'rolled back to'}: "
                  "{} (hash ")
        again = "previous (nccomp model rollback returns to it): {} (hash "
        check(wait_until(lambda: (text(root, "#model-result") or "").startswith(
            answer.format(os.path.basename(now))), 10) and
              again.format(os.path.basename(before)) in text(root, "#model-result"),
              f"{button} by {ME.pw_name}: {text(root, '#model-result')}")
        title = root.execute_script("return document.getElementById('model-result').title")
        check(title.startswith(answer.format(now)) and again.format(before) in title,
              f"{button}: the answer with the models' paths is the line's tooltip: {title}")
    handovers = status_json()["handover"]["handovers"]
    press("promote", f"The candidate {os.path.basename(c)} becomes the live model", c, b)
    st = status_json()
    check(st["model"]["live"]["file"] == c and st["model"]["previous"]["file"] == b and
          st["shadow"]["phase"] == "watch", "status: C live, B kept for rollback and watched")
    # C predicts 2 um of the wear the laser measures (kind tool_wear): the creep keeps C's share
    # out of the measured wear, so the NC keeps -5.0 um (added on top, the trim would creep the
    # register to -5 + 2 = -3.0 um within the 1 s creep).
    check(wait_until(lambda: status_json()["handover"]["handovers"] == handovers + 1, 5),
          "the promotion is a handover")
    time.sleep(2.5)
    check(nc.length_0p1um() == -50, f"-5.0 um on the NC after the promotion: {nc.length_0p1um()}")
    check(wait_until(lambda: root.execute_script("return document.getElementById('promote').disabled")
                     and root.execute_script(READ_MODEL)["live"] ==
                     page_text_of(status_json()["model"]["live"]), 5),
          "the Model card shows C live, Promote disabled")
    press("rollback", f"The live model {os.path.basename(c)} ", b, c)
    st = status_json()
    check(st["model"]["live"]["file"] == b and st["model"]["previous"]["file"] == c,
          "status: B live again, C kept for rollback")
    check(wait_until(lambda: status_json()["handover"]["handovers"] == handovers + 2, 5),
          "the rollback is a handover")
    time.sleep(2.5)
    check(nc.length_0p1um() == -50, f"-5.0 um on the NC after the rollback: {nc.length_0p1um()}")
    check(wait_until(lambda: root.execute_script(READ_MODEL)["live"] ==
                     page_text_of(status_json()["model"]["live"]), 5),
          "the Model card shows B live")
    plog = open(page.log_path).read()
    me = f"{ME.pw_name} (uid {ME.pw_uid})"
    check(f"action model_promote by {me}: ok model promoted: {c}" in plog and
          f"action model_rollback by {me}: ok model rolled back to: {b}" in plog and
          (not other or "action refused: model_rollback by nobody (uid 65534)" in plog),
          "the page's log names who promoted, rolled back, and who was refused")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    for a in ("--nccompd", "--nccomp", "--page", "--source", "--work"):
        ap.add_argument(a, required=True)
    ARGS = ap.parse_args()
    SOCKET = None
    ME = pwd.getpwuid(os.geteuid())
    AS_ROOT = os.geteuid() == 0
    try:
        main()
    except Failed as e:
        print("FAILED: " + str(e), flush=True)
        sys.exit(1)
    print("PASS", flush=True)
