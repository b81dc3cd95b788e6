#!/usr/bin/env bash
# Coverage-guided runs of every fuzz target of the `fuzz` preset, one after the other, each for a
# set time from its committed corpus; writes the table (executions, exec/s, libFuzzer's cov and
# ft at the end, corpus size, findings) with the command and the machine to OUT.
#
#   bench/fuzz/run_fuzz_bench.sh [--seconds S] [--bus-seconds B] [--only REGEX] [--out FILE]
#
# S (default 60) per target; B (default 300) for the bus decoders (fuzz_modbus_registers,
# fuzz_can_frame), whose goal is 10^7 executions. OUT defaults to bench/results/fuzz.md. Needs a
# built fuzz preset (cmake --preset fuzz && cmake --build --preset fuzz). Work directories and
# any finding (crash-*, leak-*, timeout-*, oom-*) stay in build/fuzz/bench/<target>/.
set -euo pipefail
cd "$(dirname "$0")/../.."
seconds=60 bus_seconds=300 only="." out=bench/results/fuzz.md
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --bus-seconds) bus_seconds="$2"; shift 2 ;;
    --only) only="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    *) echo "unknown argument: $1" >&2; exit 2 ;;
  esac
done
build=build/fuzz
[[ -d "$build" ]] || { echo "no $build: cmake --preset fuzz && cmake --build --preset fuzz" >&2; exit 2; }
command_line="bench/fuzz/run_fuzz_bench.sh --seconds $seconds --bus-seconds $bus_seconds"
[[ "$only" == "." ]] || command_line+=" --only '$only'"

# name <TAB> executable <TAB> corpus, from ctest's own test list (run_libfuzzer.sh TARGET CORPUS ...).
mapfile -t tests < <(ctest --test-dir "$build" -L fuzz --show-only=json-v1 | /usr/bin/python3 -c '
import json, sys
for t in json.load(sys.stdin)["tests"]:
    c = t["command"]
    print(t["name"] + "\t" + c[1] + "\t" + c[2])')

rows=""
findings=0
for line in "${tests[@]}"; do
  IFS=$'\t' read -r name exe corpus <<< "$line"
  [[ "$name" =~ $only ]] || continue
  t=$seconds
  [[ "$name" == fuzz_modbus_registers || "$name" == fuzz_can_frame ]] && t=$bus_seconds
  work="$build/bench/$name"
  log="$build/bench/$name.log"
  mkdir -p "$build/bench"
  echo "== $name: ${t} s" >&2
  status=0
  tests/fuzz/run_libfuzzer.sh "$exe" "$corpus" "$work" -max_total_time="$t" -seed=1 \
    > "$log" 2>&1 || status=$?
  row=$(/usr/bin/python3 - "$log" "$name" "$t" "$status" "$corpus" "$work" <<'PY'
import os, re, sys
log, name, t, status, corpus, work = sys.argv[1:]
text = open(log, errors="replace").read()
stat = dict(re.findall(r"stat::(\w+):\s+(\d+)", text))
cov = ft = "?"
for m in re.finditer(r"#\d+\s+\w+\s+cov: (\d+) ft: (\d+)", text):
    cov, ft = m.group(1), m.group(2)
seeds = len(os.listdir(corpus))
found = len(os.listdir(os.path.join(work, "corpus")))
arts = sorted(f for f in os.listdir(work) if re.match(r"(crash|leak|timeout|oom|slow-unit)-", f))
if status != "0" and not arts:
    arts = ["exit status " + status]
execs = int(stat.get("number_of_executed_units", 0))
print(f"| {name} | {t} | {execs:,} | {stat.get('average_exec_per_sec', '?')} | {cov} | {ft} "
      f"| {seeds} + {found} | {', '.join(arts) if arts else 'none'} |")
PY
)
  echo "$row" >&2
  rows+="$row"$'\n'
  [[ "$status" == 0 ]] || findings=$((findings + 1))
done

{
  echo "# Coverage-guided fuzzing (libFuzzer, preset \`fuzz\`)"
  echo
  echo "Command: \`$command_line\` (each target from its committed corpus, \`-seed=1\`, one"
  echo "process at a time), at commit $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- . ':!bench/results' || echo ' plus uncommitted edits'),"
  echo "$(date -u +%Y-%m-%d)."
  echo
  echo "Machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) CPUs,"
  echo "$(free -g | awk '/Mem:/ {print $2}') GiB, $(. /etc/os-release; echo "$PRETTY_NAME"), $(clang++-14 --version | head -1);"
  echo "load average at the end $(cut -d' ' -f1-3 /proc/loadavg) (the machine is shared)."
  echo
  echo "Build: clang-14 -O1 -gline-tables-only, -fsanitize=fuzzer,address,undefined, asserts on,"
  echo "toml++ compiled from its headers. execs = libFuzzer's stat::number_of_executed_units; cov"
  echo "and ft = its coverage counters (edges, features) at the end of the run; corpus = committed"
  echo "seeds + inputs the run added."
  echo
  echo "| target | s | execs | exec/s | cov | ft | corpus | findings |"
  echo "| --- | --- | --- | --- | --- | --- | --- | --- |"
  printf '%s' "$rows"
} > "$out.new"
mv "$out.new" "$out"
echo "wrote $out ($findings target(s) with findings)" >&2
[[ "$findings" == 0 ]]
