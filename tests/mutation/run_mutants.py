#!/usr/bin/python3
"""Mutation check of nccomp's safety code (issue 24).

Applies the mutants of tests/mutation/mutants.toml one at a time to a scratch copy of the working
tree, rebuilds only each mutant's targets, runs its tests, and reports each mutant as killed (a
test failed), survived (every test passed) or stillborn (the mutant does not compile). The
developer's tree is never modified: the scratch copy is refreshed from it at every start.

Run with Debian's python (tomllib): /usr/bin/python3 tests/mutation/run_mutants.py --help
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MUTANTS_TOML = REPO / "tests" / "mutation" / "mutants.toml"
# The scratch tree sits at the same depth as a worktree's build/<preset>, and its build directory
# is build/dev inside it: the relative paths the compiler sees are those of every other dev build,
# so the shared ccache (base_dir) serves the unmutated objects.
DEFAULT_SCRATCH = REPO / "build" / "mutation"
RESULTS_MD = REPO / "bench" / "results" / "mutation.md"
REQUIRED = ("id", "file", "find", "replace", "targets", "tests", "why")


class MutationError(Exception):
    pass


@dataclass
class Mutant:
    id: str
    path: str
    find: str
    replace: str
    targets: list[str]
    tests: str
    why: str
    part1: bool = False
    equivalent: str = ""


@dataclass
class Outcome:
    mutant: Mutant
    status: str = "survived"  # killed | survived | stillborn | equivalent
    killed_by: str = ""
    detail: str = ""
    build_s: float = 0.0
    test_s: float = 0.0
    tests_run: int = 0


def load_mutants(tree: Path) -> list[Mutant]:
    with open(MUTANTS_TOML, "rb") as f:
        doc = tomllib.load(f)
    files = doc.get("files", {})
    mutants: list[Mutant] = []
    seen: set[str] = set()
    problems: list[str] = []
    for i, m in enumerate(doc.get("mutant", [])):
        missing = [k for k in REQUIRED if k not in m]
        if missing:
            problems.append(f"mutant #{i + 1} ({m.get('id', '?')}): missing {', '.join(missing)}")
            continue
        if m["id"] in seen:
            problems.append(f"mutant {m['id']}: id used twice")
        seen.add(m["id"])
        if m["file"] not in files:
            problems.append(f"mutant {m['id']}: file key '{m['file']}' is not in [files]")
            continue
        path = files[m["file"]]
        src = tree / path
        if not src.is_file():
            problems.append(f"mutant {m['id']}: {path} does not exist (moved? update [files])")
            continue
        n = src.read_text().count(m["find"])
        if n != 1:
            problems.append(f"mutant {m['id']}: its find text occurs {n} times in {path} "
                            "(must be exactly once)")
        if m["find"] == m["replace"]:
            problems.append(f"mutant {m['id']}: replace equals find")
        if not m["targets"]:
            problems.append(f"mutant {m['id']}: no targets")
        mutants.append(Mutant(m["id"], path, m["find"], m["replace"], list(m["targets"]),
                              m["tests"], m["why"], bool(m.get("part1", False)),
                              m.get("equivalent", "")))
    if problems:
        raise MutationError("mutants.toml:\n  " + "\n  ".join(problems))
    return mutants


def tree_files(tree: Path) -> list[str]:
    """Tracked and untracked, not ignored: what the developer would build."""
    out = subprocess.run(["git", "-C", str(tree), "ls-files", "-z", "-c", "-o",
                          "--exclude-standard"], check=True, capture_output=True).stdout
    return sorted({p for p in out.decode().split("\0") if p and (tree / p).is_file()})


def sync_scratch(tree: Path, scratch: Path) -> int:
    """Makes scratch a copy of tree's sources; returns how many files were written.

    A file is rewritten only when its content differs, and then gets a new mtime (never the
    source's: an object built from a mutant is newer than an old mtime, and ninja would keep it).
    """
    scratch.mkdir(parents=True, exist_ok=True)
    wanted = tree_files(tree)
    wanted_set = set(wanted)
    written = 0
    for rel in wanted:
        src = tree / rel
        dst = scratch / rel
        data = src.read_bytes()
        if dst.is_file() and dst.read_bytes() == data:
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(data)
        shutil.copymode(src, dst)
        written += 1
    # Files the developer removed or moved: a stale CMakeLists.txt would still be discovered.
    for dirpath, dirnames, filenames in os.walk(scratch):
        rel_dir = Path(dirpath).relative_to(scratch)
        if rel_dir == Path("."):
            dirnames[:] = [d for d in dirnames if d not in ("build", ".git")]
        for name in filenames:
            rel = (rel_dir / name).as_posix()
            if rel not in wanted_set:
                (scratch / rel).unlink()
    return written


def run(cmd: list[str], cwd: Path, timeout: float | None = None) -> tuple[int, str, float]:
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, errors="replace", timeout=timeout)
        return p.returncode, p.stdout, time.monotonic() - t0
    except subprocess.TimeoutExpired as e:
        out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        return -1, out + f"\n[timed out after {timeout} s]", time.monotonic() - t0


def configure(scratch: Path, build: Path, preset: str) -> None:
    if (build / "build.ninja").is_file():
        return
    print(f"configuring {build} (cmake --preset {preset})", flush=True)
    rc, out, _ = run(["cmake", "--preset", preset], scratch)
    if rc != 0:
        raise MutationError("cmake configure failed:\n" + out[-4000:])


def build(build_dir: Path, targets: list[str], jobs: int) -> tuple[int, str, float]:
    return run(["cmake", "--build", str(build_dir), "--target", *targets, f"-j{jobs}"],
               build_dir)


FAILED_RE = re.compile(r"^\s*\d+/\d+ Test\s+#\d+: (\S+) \.*\s*(\*\*\*\S+.*|Subprocess \S+.*)$")
PASSED_RE = re.compile(r"^\s*\d+/\d+ Test\s+#\d+: (\S+) \.*\s*Passed")


def ctest(build_dir: Path, regex: str, jobs: int, timeout_s: int,
          stop_on_failure: bool) -> tuple[int, list[str], list[str], str, float]:
    cmd = ["ctest", "--test-dir", str(build_dir), "-R", regex, "-j", str(jobs),
           "--timeout", str(timeout_s), "--output-on-failure"]
    if stop_on_failure:
        cmd.append("--stop-on-failure")
    rc, out, secs = run(cmd, build_dir)
    failed, passed = [], []
    for line in out.splitlines():
        m = FAILED_RE.match(line)
        if m:
            # "***Failed  0.10 sec", "***Timeout 300.01 sec", "Subprocess aborted ...": the kind
            kind = m.group(2).strip().lstrip("*").split()[0]
            failed.append(f"{m.group(1)} ({kind.lower()})")
            continue
        m = PASSED_RE.match(line)
        if m:
            passed.append(m.group(1))
    return rc, failed, passed, out, secs


def first_error(out: str) -> str:
    for line in out.splitlines():
        if "error:" in line:
            return line.strip()[:200]
    return out.strip().splitlines()[-1][:200] if out.strip() else "?"


def test_one(m: Mutant, scratch: Path, build_dir: Path, args: argparse.Namespace) -> Outcome:
    o = Outcome(m)
    path = scratch / m.path
    original = path.read_bytes()
    text = original.decode()
    if text.count(m.find) != 1:
        raise MutationError(f"{m.id}: find text not exactly once in the scratch copy of {m.path}")
    try:
        path.write_bytes(text.replace(m.find, m.replace, 1).encode())
        rc, out, o.build_s = build(build_dir, m.targets, args.jobs)
        if rc != 0:
            o.status = "stillborn"
            o.detail = first_error(out)
            return o
        rc, failed, passed, out, o.test_s = ctest(build_dir, m.tests, args.test_jobs,
                                                  args.test_timeout, not args.all_failures)
        o.tests_run = len(failed) + len(passed)
        if o.tests_run == 0:
            raise MutationError(f"{m.id}: no test matches '{m.tests}' (ctest output:\n"
                                f"{out[-2000:]})")
        if failed:
            o.status = "killed"
            o.killed_by = failed[0]
        elif rc != 0:
            o.status = "killed"
            o.killed_by = "ctest exit " + str(rc)
            o.detail = out.strip().splitlines()[-1] if out.strip() else ""
        else:
            o.status = "equivalent" if m.equivalent else "survived"
            o.detail = m.equivalent
        return o
    finally:
        # Restored with a new mtime: the next build recompiles it (a ccache hit).
        path.write_bytes(original)


def baseline(mutants: list[Mutant], build_dir: Path, args: argparse.Namespace) -> float:
    targets = sorted({t for m in mutants for t in m.targets})
    print(f"baseline: building {len(targets)} targets: {' '.join(targets)}", flush=True)
    rc, out, secs = build(build_dir, targets, args.jobs)
    if rc != 0:
        raise MutationError("the unmutated tree does not build:\n" + out[-4000:])
    print(f"baseline: built in {secs:.0f} s", flush=True)
    # One ctest run per regex: CMake's regular expressions allow only 9 groups, too few to join
    # them. A regex that matches nothing would let every mutant "survive" for the wrong reason.
    tsecs = 0.0
    total = 0
    for r in sorted({m.tests for m in mutants}):
        rc, failed, passed, out, secs_r = ctest(build_dir, r, args.test_jobs, args.test_timeout,
                                                False)
        tsecs += secs_r
        total += len(passed)
        if not failed and not passed:
            raise MutationError(f"no test matches the regex '{r}':\n{out[-1000:]}")
        if rc != 0 or failed:
            raise MutationError("the unmutated tree fails its tests (a mutant would be 'killed' "
                                "by them):\n  " + "\n  ".join(failed or [out[-2000:]]))
    print(f"baseline: {total} tests pass in {tsecs:.0f} s", flush=True)
    return secs + tsecs


def fmt_s(s: float) -> str:
    return f"{s:.0f}"


def print_table(outcomes: list[Outcome]) -> None:
    w = max(len(o.mutant.id) for o in outcomes)
    print(f"\n{'mutant':<{w}}  {'result':<10} {'build s':>7} {'test s':>6}  killed by / detail")
    for o in outcomes:
        print(f"{o.mutant.id:<{w}}  {o.status:<10} {fmt_s(o.build_s):>7} {fmt_s(o.test_s):>6}  "
              f"{o.killed_by or o.detail}")
    counts = {s: sum(1 for o in outcomes if o.status == s)
              for s in ("killed", "survived", "stillborn", "equivalent")}
    print("\n" + ", ".join(f"{n} {s}" for s, n in counts.items()) + f" of {len(outcomes)}")


def machine() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{platform.node()}: {os.cpu_count()} CPUs ({cpu}), Linux {platform.release()}"


def tree_version() -> str:
    """The commit the scratch copy was made from, and whether the tree differed from it."""
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True).stdout.strip()
    return f"commit {head}{' with uncommitted changes' if dirty else ''}"


def write_results(outcomes: list[Outcome], command: str, tree: str, started: datetime.datetime,
                  wall_s: float, baseline_s: float, load: tuple[float, float]) -> None:
    counts = {s: sum(1 for o in outcomes if o.status == s)
              for s in ("killed", "survived", "stillborn", "equivalent")}
    lines = [
        "# Mutation check of the safety code",
        "",
        "Each mutant of `tests/mutation/mutants.toml` applied alone to a scratch copy of the tree,",
        "its targets rebuilt (`dev` preset: Debug, ASan + UBSan), its tests run with ctest until the",
        "first failure. *killed*: a test failed (the first failing test is named); *survived*: all",
        "passed; *stillborn*: the mutant does not compile. Build and test times are wall seconds on",
        "a machine shared with other builds (they vary with its load; no figure here is a target).",
        "A build is short where the shared ccache already held the mutated object (an earlier run",
        "of the same mutant); compiled afresh, a mutant of core/model/analysis.cpp takes minutes.",
        "",
        f"- command: `{command}`",
        f"- tree: {tree}",
        f"- date: {started.strftime('%Y-%m-%d %H:%M')} UTC",
        f"- machine: {machine()}; load average {load[0]:.1f} at the start, {load[1]:.1f} at the end",
        f"- wall time: {wall_s / 60:.1f} min (baseline build and test of the unmutated tree "
        f"{baseline_s:.0f} s of it)",
        f"- result: **{counts['killed']} killed**, {counts['survived']} survived, "
        f"{counts['stillborn']} stillborn, {counts['equivalent']} equivalent of {len(outcomes)}",
        "",
        "| mutant | file | mutation | result | killed by | build s | test s |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]

    def cell(s: str) -> str:
        s = " ".join(s.split())
        return s.replace("|", "\\|")

    for o in outcomes:
        m = o.mutant
        mut = f"`{cell(m.find)}` → `{cell(m.replace)}`" if m.replace.strip() else \
            f"`{cell(m.find)}` removed"
        name = f"{m.id} (part 1)" if m.part1 else m.id
        lines.append(f"| {name} | {m.path} | {mut} | {o.status} | "
                     f"{cell(o.killed_by or o.detail)} | {fmt_s(o.build_s)} | {fmt_s(o.test_s)} |")
    lines.append("")
    RESULTS_MD.write_text("\n".join(lines))
    print(f"wrote {RESULTS_MD.relative_to(REPO)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--list", action="store_true", help="check mutants.toml and list the mutants")
    ap.add_argument("--only", action="append", default=[], metavar="ID",
                    help="run only this mutant (repeatable, or comma-separated)")
    ap.add_argument("--record", action="store_true",
                    help=f"write {RESULTS_MD.relative_to(REPO)} (only with the full list)")
    ap.add_argument("--scratch", type=Path, default=DEFAULT_SCRATCH,
                    help="the scratch copy of the tree (default build/mutation)")
    ap.add_argument("--preset", default="dev", help="configure preset of the scratch build")
    ap.add_argument("--jobs", type=int, default=2, help="build jobs (default 2)")
    ap.add_argument("--test-jobs", type=int, default=2, help="ctest jobs (default 2)")
    ap.add_argument("--test-timeout", type=int, default=300, help="per-test timeout in s")
    ap.add_argument("--all-failures", action="store_true",
                    help="run every test of a mutant, not only until the first failure")
    ap.add_argument("--skip-baseline", action="store_true",
                    help="do not build and test the unmutated tree first")
    args = ap.parse_args()

    # SIGTERM (and SIGHUP) unwind like Ctrl-C, so the scratch file is restored in `finally`.
    def interrupted(signum, _frame):
        raise KeyboardInterrupt(f"signal {signum}")
    signal.signal(signal.SIGTERM, interrupted)
    signal.signal(signal.SIGHUP, interrupted)

    try:
        mutants = load_mutants(REPO)
        if args.list:
            for m in mutants:
                print(f"{m.id:<40} {m.path:<34} {' '.join(m.targets):<30} {m.tests}")
            print(f"{len(mutants)} mutants, {sum(m.part1 for m in mutants)} of part 1")
            return 0
        only = [x for o in args.only for x in o.split(",") if x]
        if only:
            unknown = sorted(set(only) - {m.id for m in mutants})
            if unknown:
                raise MutationError("unknown mutant id: " + ", ".join(unknown))
            mutants = [m for m in mutants if m.id in only]
        if args.record and only:
            raise MutationError("--record records the full list: drop --only")
        scratch = args.scratch.resolve()
        if scratch == REPO or REPO.is_relative_to(scratch):
            raise MutationError("the scratch copy must not be the tree itself")
        build_dir = scratch / "build" / args.preset
        started = datetime.datetime.now(datetime.timezone.utc)
        tree = tree_version()
        load0 = os.getloadavg()[0]
        t0 = time.monotonic()
        n = sync_scratch(REPO, scratch)
        print(f"scratch copy {scratch}: {n} files refreshed", flush=True)
        os.environ.setdefault("CMAKE_CXX_COMPILER_LAUNCHER", "ccache")
        os.environ.setdefault("CMAKE_C_COMPILER_LAUNCHER", "ccache")
        configure(scratch, build_dir, args.preset)
        base_s = 0.0 if args.skip_baseline else baseline(mutants, build_dir, args)
        outcomes = []
        for i, m in enumerate(mutants, 1):
            o = test_one(m, scratch, build_dir, args)
            outcomes.append(o)
            print(f"[{i}/{len(mutants)}] {m.id}: {o.status} "
                  f"(build {o.build_s:.0f} s, tests {o.test_s:.0f} s) {o.killed_by or o.detail}",
                  flush=True)
        print_table(outcomes)
        if args.record:
            command = "tests/mutation/run_mutants.py " + " ".join(sys.argv[1:])
            write_results(outcomes, command, tree, started, time.monotonic() - t0, base_s,
                          (load0, os.getloadavg()[0]))
        return 0 if all(o.status in ("killed", "equivalent") for o in outcomes) else 1
    except MutationError as e:
        print(f"run_mutants: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(f"run_mutants: interrupted ({e}); the scratch copy is restored", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
