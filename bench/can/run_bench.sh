#!/usr/bin/env bash
# The CAN benchmark, in the HIL VM (or directly where the kernel has vcan):
#   tests/hil/vm/run_in_vm.sh BUILD/bench-can -- bench/can/run_bench.sh BUILD/bench/can/bench_can \
#       config/reference-nc-can.toml BUILD/bench-can
# 1. trigger → offset latency over 10,000 events; 2. a rate sweep of mapped frames, candump
# receiving the same traffic in the same run (its loss is counted from its output).
set -u
bin=$1
cfg=$2
out=$3
events=${NCCOMP_BENCH_EVENTS:-10000}
frames=${NCCOMP_BENCH_FRAMES:-10000}
mkdir -p "$out"
echo "== latency"
NCCOMP_BENCH_RCVBUF_BYTES= "$bin" "$cfg" latency "$events"
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
exit 0
