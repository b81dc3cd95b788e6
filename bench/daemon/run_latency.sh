#!/usr/bin/env bash
# Wake-up latency of nccompd's loop beside cyclictest, same rate and priority, same run.
#   bench/daemon/run_latency.sh BUILD_DIR [SECONDS] [PRIORITY]
# Prints both latency summaries and the ratios loop / cyclictest.
set -euo pipefail
build=${1:?build dir (Release)}
secs=${2:-60}
prio=${3:-80}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# Both at 1 kHz, SCHED_FIFO $prio, memory locked, one measuring thread each, started together.
cyclictest -q -t1 -p "$prio" -i 1000 -D "${secs}s" -m -h 30000 --histfile="$tmp/cyc.hist" \
  > "$tmp/cyc.out" 2>&1 &
cpid=$!
"$build/bench/daemon/bench_daemon_loop" --seconds "$secs" --rate-hz 1000 --priority "$prio" \
  --lock-memory > "$tmp/loop.out" 2>&1
wait "$cpid" || true
cat "$tmp/loop.out"
/usr/bin/python3 - "$tmp/cyc.hist" "$tmp/loop.out" <<'PY'
import re, sys
hist, loop = sys.argv[1], sys.argv[2]
counts = {}
maxlat = None
overflow = 0
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
    rank = p * total; seen = 0
    for us in sorted(counts):
        seen += counts[us]
        if seen >= rank: return us + 1   # upper edge of the 1 us bucket, as the loop reports
    return maxlat
cyc = {'p50': q(0.5), 'p99': q(0.99), 'p99.9': q(0.999), 'max': maxlat}
print(f"cyclictest samples={total} latency_us p50={cyc['p50']} p99={cyc['p99']} p99.9={cyc['p99.9']} max={cyc['max']}")
m = re.search(r'latency_us p50=(\d+) p99=(\d+) p99.9=(\d+) max=(\d+)', open(loop).read())
lp = dict(zip(['p50', 'p99', 'p99.9', 'max'], map(int, m.groups())))
print("ratio loop/cyclictest " + " ".join(f"{k}={lp[k] / cyc[k]:.2f}" for k in lp))
PY
