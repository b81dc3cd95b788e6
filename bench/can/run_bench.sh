#!/usr/bin/env bash
# The CAN benchmark, in the HIL VM (or directly where the kernel has vcan), one VM boot:
#   tests/hil/vm/run_in_vm.sh BUILD/bench-can -- bench/can/run_bench.sh BUILD BUILD/bench-can/out
# BUILD is a Release build with bench_can, nccompd and nccomp. Everything printed is also written
# to OUT/bench_can.txt (the raw output recorded in bench/results/).
# 1. latency: trigger frame -> offset frame over NCCOMP_BENCH_EVENTS (10,000) events;
# 2. rate: a sweep of mapped frames, candump receiving the same traffic in the same run (its loss
#    is counted from its output), per receive buffer size in NCCOMP_BENCH_RCVBUFS;
# 3. loop: nccompd (SCHED_FIFO 80, memory locked) at each rate of NCCOMP_BENCH_LOOP_RATES
#    ("1000 250" Hz) with cyclictest beside it at the same rate and priority, idle and during a
#    full-rate cangen flood on unmapped IDs, alternating, NCCOMP_BENCH_LOOP_ROUNDS (2) rounds of
#    NCCOMP_BENCH_LOOP_S (20) seconds per phase. The loop's cycles and overruns are counted from
#    a status snapshot after NCCOMP_BENCH_WARMUP_S (3) s to the end; its wake-up latency
#    quantiles (since start) come from `nccomp status --json`.
# NCCOMP_BENCH_SECTIONS selects sections (default "latency rate loop").
set -u
build=$(realpath "$1")
out=$2
src=$(cd "$(dirname "$0")/../.." && pwd)
bin=$build/bench/can/bench_can
cfg=$src/config/reference-nc-can.toml
events=${NCCOMP_BENCH_EVENTS:-10000}
frames=${NCCOMP_BENCH_FRAMES:-10000}
sections=${NCCOMP_BENCH_SECTIONS:-latency rate loop}
mkdir -p "$out"

main() {
echo "== machine: $(uname -r), $(nproc) vCPUs, load $(cat /proc/loadavg)"

if [[ " $sections " == *" latency "* ]]; then
echo "== latency"
NCCOMP_BENCH_RCVBUF_BYTES= "$bin" "$cfg" latency "$events"
fi

if [[ " $sections " == *" rate "* ]]; then
echo "== load: $(cat /proc/loadavg) (VM), $(nproc) vCPUs"
for NCCOMP_BENCH_RCVBUF_BYTES in ${NCCOMP_BENCH_RCVBUFS:-0 4194304}; do
export NCCOMP_BENCH_RCVBUF_BYTES
[ "$NCCOMP_BENCH_RCVBUF_BYTES" = 0 ] && NCCOMP_BENCH_RCVBUF_BYTES=
echo "== rate sweep ($frames frames per rate), receive buffer ${NCCOMP_BENCH_RCVBUF_BYTES:-default}"
for r in ${NCCOMP_BENCH_RATES:-2000 5000 10000 0}; do
  # candump writes to the VM's tmpfs: a 9p file would make candump, not the bus, the bottleneck.
  # Same receive buffer as the driver (-r), so the two receivers are compared on equal terms.
  rbuf=()
  [ -n "${NCCOMP_BENCH_RCVBUF_BYTES:-}" ] && rbuf=(-r "$NCCOMP_BENCH_RCVBUF_BYTES")
  candump "${rbuf[@]}" -L vcan0,160:7FF >"/tmp/candump_$r.log" &
  cpid=$!
  sleep 1
  "$bin" "$cfg" rate "$r" "$frames"
  sleep 0.5
  kill $cpid
  wait $cpid 2>/dev/null
  got=$(wc -l <"/tmp/candump_$r.log")
  echo "   candump (same traffic): received $got lost $((frames - got))"
done
done
unset NCCOMP_BENCH_RCVBUF_BYTES
fi

# --- 3. nccompd's loop timing, idle vs an unmapped cangen flood ------------------------------
jget() {  # first "key":number of a JSON text
  grep -o "\"$1\":[-0-9.eE+]*" <<<"$2" | head -1 | cut -d: -f2
}
# cyclictest histogram (1 us buckets) -> "p50 p99 p99.9 max", quantile = upper bucket edge as the
# loop reports it.
cyc_quantiles() {
  awk '/^#/ { if ($0 ~ /Max Latencies/) max = $NF; if ($0 ~ /Histogram Overflows/) ov = $NF; next }
       NF >= 2 { n[$1 + 0] = $2; tot += $2; if ($1 + 0 > top) top = $1 + 0 }
       END { tot += ov; split("0.5 0.99 0.999", q, " ")
             for (i = 1; i <= 3; i++) { seen = 0; r[i] = max
               for (us = 0; us <= top; us++) { seen += n[us]; if (seen >= q[i] * tot) { r[i] = us + 1; break } } }
             printf "%s %s %s %s %d", r[1], r[2], r[3], max + 0, tot }' "$1"
}
loop_phase() {  # loop_phase NAME FLOOD(0|1) SECONDS RATE_HZ
  local name=$1 flood=$2 secs=$3 rate=$4 dir=/tmp/nccompd_bench_$1
  local warm=${NCCOMP_BENCH_WARMUP_S:-3}
  rm -rf "$dir"
  mkdir -p "$dir"
  cat >"$dir/nccompd.toml" <<EOF
[daemon]
rate_hz = $rate
[daemon.realtime]
sched_fifo_priority = 80
lock_memory = true
prefault_stack_kib = 256
[state]
directory = "$dir/state"
[measurement_log]
enabled = false
[status]
socket_path = "$dir/status.sock"
[can]
interface = "vcan0"
[[can.rx]]
id = 0x100
length_bytes = 4
event = "axis_sample"
[[can.rx.signal]]
name = "x_mm"
start_bit = 0
length_bits = 32
type = "signed"
scale = 0.0001
[[can.offset]]
register = 0
id = 0x300
length_bytes = 4
[can.offset.value]
start_bit = 0
length_bits = 32
type = "signed"
scale = 0.1
[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "can"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 1000
EOF
  local fpid=""
  if [ "$flood" = 1 ]; then
    cangen vcan0 -g 0 -I 7A5 -L 8 -D r -i &
    fpid=$!
    sleep 1
  fi
  local tx0 t0
  tx0=$(cat /sys/class/net/vcan0/statistics/tx_packets)
  t0=$(date +%s.%N)
  cyclictest -q -t1 -p 80 -i $((1000000 / rate)) -D "${secs}s" -m -h 30000 \
    --histfile="$dir/cyc.hist" >"$dir/cyc.out" 2>&1 &
  local cpid=$!
  "$build/daemon/nccompd" --config "$dir/nccompd.toml" >"$dir/nccompd.log" 2>&1 &
  local dpid=$!
  sleep "$warm"
  local json0 json
  json0=$("$build/tools/nccomp" status --json --socket "$dir/status.sock")
  sleep $((secs - warm))
  json=$("$build/tools/nccomp" status --json --socket "$dir/status.sock")
  local tx1 t1
  tx1=$(cat /sys/class/net/vcan0/statistics/tx_packets)
  t1=$(date +%s.%N)
  kill -TERM "$dpid"
  wait "$dpid"
  local drc=$?
  wait "$cpid"
  [ -n "$fpid" ] && { kill "$fpid"; wait "$fpid" 2>/dev/null; }
  local canjson=${json#*\"buses\":}
  local c0 c1 o0 o1 m0 m1
  c0=$(jget cycles "$json0"); c1=$(jget cycles "$json")
  o0=$(jget overruns "$json0"); o1=$(jget overruns "$json")
  m0=$(jget missed_deadlines "$json0"); m1=$(jget missed_deadlines "$json")
  printf '%-12s nccompd after warm-up: cycles %s overruns %s missed %s | since start: latency_us p50 %s p99 %s p99.9 %s max %s max_cycle_us %s can_frames_rx %s exit %s | flood %s frames/s\n' \
    "$name" "$((c1 - c0))" "$((o1 - o0))" "$((m1 - m0))" \
    "$(jget p50 "$json")" "$(jget p99 "$json")" "$(jget p99_9 "$json")" "$(jget max "$json")" \
    "$(jget max_cycle_us "$json")" "$(jget frames_rx "$canjson")" "$drc" \
    "$(awk -v n=$((tx1 - tx0)) -v a="$t0" -v b="$t1" 'BEGIN { printf "%.0f", n / (b - a) }')"
  # (no process substitution: the VM's /dev has no /dev/fd)
  local q
  q=$(cyc_quantiles "$dir/cyc.hist")
  set -- $q
  printf '%-12s cyclictest samples %s latency_us p50 %s p99 %s p99.9 %s max %s\n' \
    "$name" "$5" "$1" "$2" "$3" "$4"
}
if [[ " $sections " == *" loop "* ]]; then
  secs=${NCCOMP_BENCH_LOOP_S:-20}
  echo "== loop: nccompd SCHED_FIFO 80 + cyclictest (same rate, priority), ${secs} s per phase; flood = cangen vcan0 -g 0 -I 7A5 -L 8 -D r -i (unmapped)"
  for rate in ${NCCOMP_BENCH_LOOP_RATES:-1000 250}; do
    for round in $(seq 1 "${NCCOMP_BENCH_LOOP_ROUNDS:-2}"); do
      loop_phase "idle$round@$rate" 0 "$secs" "$rate"
      loop_phase "flood$round@$rate" 1 "$secs" "$rate"
    done
  done
fi
}

main 2>&1 | tee "$out/bench_can.txt"
exit 0
