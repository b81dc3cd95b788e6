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
"$bin" "$cfg" latency "$events"
echo "== rate sweep ($frames frames per rate)"
for r in ${NCCOMP_BENCH_RATES:-2000 5000 10000 20000 50000}; do
  candump -L vcan0,160:7FF >"$out/candump_$r.log" &
  cpid=$!
  sleep 1
  "$bin" "$cfg" rate "$r" "$frames"
  sleep 0.5
  kill $cpid
  wait $cpid 2>/dev/null
  got=$(wc -l <"$out/candump_$r.log")
  echo "   candump (same traffic): received $got lost $((frames - got))"
done
exit 0
