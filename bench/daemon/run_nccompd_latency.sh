#!/usr/bin/env bash
# The real nccompd process beside cyclictest, in the same run:
#   bench/daemon/run_nccompd_latency.sh RELEASE_BUILD_DIR [SECONDS] [CPU [IO_CPU]]
#
# - nccompd: the release binary with the shipped config/nccompd.toml and its include
#   reference-nc-modbus.toml, unchanged except the NC's TCP port (a free one on 127.0.0.1),
#   against the project's Modbus NC server (sim/modbus_nc) on loopback. Its real-time settings are
#   the shipped ones ([daemon.realtime]: SCHED_FIFO priority, lock_memory, stack pre-faulting).
#   State, logs and the status socket go to a temporary directory through $STATE_DIRECTORY,
#   $LOGS_DIRECTORY and $RUNTIME_DIRECTORY (what the systemd unit sets). A counting malloc is
#   preloaded (libnccomp_alloc_preload.so) so the daemon reports its loop thread's allocations
#   and frees after warm-up.
# - cyclictest: one thread at the same rate (1 kHz) and the same SCHED_FIFO priority, memory
#   locked, started together with nccompd.
# After SECONDS, `nccomp status --json` gives the loop's latency quantiles (its own histogram
# since start), overruns, page faults, allocations and frees on the loop thread after warm-up;
# cyclictest's histogram gives its quantiles. Both as the upper edge of a 1 µs bucket.
# CPU (optional): pin both measuring threads to that CPU (nccompd's [daemon.realtime]
# cpu_affinity = [CPU], cyclictest -a CPU), so both see the same vCPU's disturbances; the shipped
# config pins nothing.
# IO_CPU (optional, with CPU): also keep the Modbus I/O thread on that CPU ([modbus]
# io_cpu_affinity = [IO_CPU], at normal priority), away from the loop's.
# NCCOMPD_BENCH_SAME_CPU=1 (optional, without CPU): the shipped config places the loop thread on
# a CPU of its own (the highest allowed) and everything else on the others; with this setting
# cyclictest runs pinned to the CPU the daemon logged for its loop (both measure the same vCPU's
# disturbances), and the NC stand-in (sim/modbus_nc, which on a machine is another box) is moved
# to the other CPUs. The daemon's config stays the shipped one.
# NCCOMPD_BENCH_RUN_DIR (optional): the daemon's runtime directory (its status socket) instead
# of a temporary one, for a companion process to find it (bench/mqtt/run_loop_ab.sh).
# Needs root (SCHED_FIFO and mlockall without the unit's rlimits) and cyclictest (rt-tests).
set -euo pipefail
build=${1:?release build dir}
secs=${2:-60}
cpu=${3:-}
io_cpu=${4:-}
src=$(cd "$(dirname "$0")/../.." && pwd)
tmp=$(mktemp -d)
ncpid=""
dpid=""
cleanup() {
  [ -n "$dpid" ] && kill "$dpid" 2> /dev/null || true
  [ -n "$ncpid" ] && kill "$ncpid" 2> /dev/null || true
  rm -rf "$tmp"
}
trap cleanup EXIT

port=$((20000 + RANDOM % 20000))
cp "$src/config/nccompd.toml" "$src/config/reference-nc-modbus.toml" "$tmp/"
sed -i "s/^port = 1502$/port = $port/" "$tmp/reference-nc-modbus.toml"
grep -q "^port = $port$" "$tmp/reference-nc-modbus.toml"
prio=$(sed -n 's/^sched_fifo_priority = \([0-9][0-9]*\)$/\1/p' "$tmp/nccompd.toml")
[ -n "$prio" ] && [ "$prio" -gt 0 ]
run=${NCCOMPD_BENCH_RUN_DIR:-$tmp/run}
mkdir -p "$tmp/state" "$tmp/log" "$run"
pin=()
if [ -n "$cpu" ]; then
  sed -i "s/^cpu_affinity = \[\]$/cpu_affinity = [$cpu]/" "$tmp/nccompd.toml"
  grep -q "^cpu_affinity = \[$cpu\]$" "$tmp/nccompd.toml"
  pin=(-a "$cpu")
fi
if [ -n "$io_cpu" ]; then
  [ -n "$cpu" ]
  sed -i "s/^\[modbus\]$/[modbus]\nio_cpu_affinity = [$io_cpu]/" "$tmp/reference-nc-modbus.toml"
  grep -q "^io_cpu_affinity = \[$io_cpu\]$" "$tmp/reference-nc-modbus.toml"
fi

"$build/sim/modbus_nc/modbus_nc" --bind 127.0.0.1 --port "$port" > "$tmp/nc.log" 2>&1 &
ncpid=$!
sleep 0.5

same_cpu=${NCCOMPD_BENCH_SAME_CPU:-0}
start_cyclictest() {
  cyclictest -q -t1 "${pin[@]}" -p "$prio" -i 1000 -D "${secs}s" -m -h 30000 \
    --histfile="$tmp/cyc.hist" > "$tmp/cyc.out" 2>&1 &
  cpid=$!
}
[ "$same_cpu" = 1 ] || start_cyclictest
STATE_DIRECTORY="$tmp/state" LOGS_DIRECTORY="$tmp/log" RUNTIME_DIRECTORY="$run" \
  LD_PRELOAD="$build/bench/daemon/libnccomp_alloc_preload.so" \
  "$build/daemon/nccompd" --config "$tmp/nccompd.toml" > "$tmp/nccompd.log" 2>&1 &
dpid=$!
if [ "$same_cpu" = 1 ]; then
  [ -z "$cpu" ]
  loop_cpu=""
  for _ in $(seq 50); do
    loop_cpu=$(sed -n 's/.*loop thread: pinned to CPU(s) \([0-9][0-9]*\)$/\1/p' "$tmp/nccompd.log")
    [ -n "$loop_cpu" ] && break
    sleep 0.1
  done
  [ -n "$loop_cpu" ] || { echo "nccompd logged no loop CPU" >&2; cat "$tmp/nccompd.log" >&2; exit 1; }
  others=$(/usr/bin/python3 -c 'import os, sys; print(",".join(str(c) for c in sorted(os.sched_getaffinity(0)) if c != int(sys.argv[1])))' "$loop_cpu")
  [ -n "$others" ] && taskset -a -p -c "$others" "$ncpid" > /dev/null
  pin=(-a "$loop_cpu")
  cpu=$loop_cpu
  start_cyclictest
fi
sleep "$secs"
"$build/tools/nccomp" status --socket "$run/status.sock" --json > "$tmp/status.json"
"$build/tools/nccomp" status --socket "$run/status.sock" > "$tmp/status.txt"
wait "$cpid" || true
kill -TERM "$dpid"
wait "$dpid"
dpid=""

echo "== nccompd log"
cat "$tmp/nccompd.log"
echo "== nccomp status (at ${secs} s)"
sed -n '1,6p' "$tmp/status.txt"
sed -n '/^buses:/,/^state:/p' "$tmp/status.txt"
echo "== summary"
/usr/bin/python3 - "$tmp/cyc.hist" "$tmp/status.json" "$prio" "$cpu" "$io_cpu" "$same_cpu" <<'PY'
import json, re, sys
hist, status, prio = sys.argv[1], sys.argv[2], sys.argv[3]
counts, maxlat, overflow = {}, None, 0
for line in open(hist):
    if line.startswith('#'):
        m = re.search(r'Max Latencies:\s+(\d+)', line)
        if m: maxlat = int(m.group(1))
        m = re.search(r'Histogram Overflows:\s+(\d+)', line)
        if m: overflow = int(m.group(1))
        continue
    parts = line.split()
    if len(parts) >= 2:
        counts[int(parts[0])] = int(parts[1])
total = sum(counts.values()) + overflow
def q(p):
    rank, seen = p * total, 0
    for us in sorted(counts):
        seen += counts[us]
        if seen >= rank: return us + 1   # upper edge of the 1 us bucket, as the loop reports
    return maxlat
cyc = {'p50': q(0.5), 'p99': q(0.99), 'p99.9': q(0.999), 'max': maxlat}
s = json.load(open(status))
loop = s['loop']
lat = loop['latency_us']
d = {'p50': lat['p50'], 'p99': lat['p99'], 'p99.9': lat['p99_9'], 'max': lat['max']}
same = len(sys.argv) > 6 and sys.argv[6] == '1'
print(f"priority {prio}, 1000 Hz" + (f", shipped CPU placement: loop on CPU {sys.argv[4]} (as logged), cyclictest pinned there, NC stand-in on the other CPUs" if same else f", both pinned to CPU {sys.argv[4]}" if len(sys.argv) > 4 and sys.argv[4] else ", not pinned")
      + (f", Modbus I/O thread on CPU {sys.argv[5]}" if len(sys.argv) > 5 and sys.argv[5] else ""))
print(f"nccompd   cycles={loop['cycles']} overruns={loop['overruns']} "
      f"missed={loop['missed_deadlines']} max_cycle_us={loop['max_cycle_us']:.1f} "
      f"latency_us p50={d['p50']:g} p99={d['p99']:g} p99.9={d['p99.9']:g} max={d['max']:.0f}")
print(f"cyclictest samples={total} latency_us p50={cyc['p50']} p99={cyc['p99']} "
      f"p99.9={cyc['p99.9']} max={cyc['max']}")
print("ratio nccompd/cyclictest " +
      " ".join(f"{k}={d[k] / cyc[k]:.2f}" for k in ('p50', 'p99', 'p99.9', 'max')))
print(f"loop thread after warm-up: minor_faults={loop['minor_faults_after_warmup']} "
      f"major_faults={loop['major_faults_after_warmup']} "
      f"allocations={loop['allocations_after_warmup']} frees={loop['frees_after_warmup']}")
bus = s['buses'][0]
print(f"bus {bus['name']} {bus['state']} frames_rx={bus['frames_rx']} "
      f"frames_tx={bus['frames_tx']} events={bus['events_decoded']}")
PY
