#!/usr/bin/env bash
# nccompd's loop latency without and with the MQTT publisher running, A/B pairs in one run:
#   bench/mqtt/run_loop_ab.sh RELEASE_BUILD_DIR PAIRS SECONDS [CPU]
#
# Each run is bench/daemon/run_nccompd_latency.sh (the release nccompd with the shipped config
# against the Modbus NC server, beside cyclictest; CPU pins both measuring threads). A: nothing
# else. B: the MQTT side on the same host for the whole run: mosquitto, `nccomp collect`, a log
# written at 1000 rows/s (bench_mqtt_rowgen, one machine) and `nccomp publish` publishing it and
# polling this nccompd's status socket every second (the shipped defaults). The order alternates
# (A B, B A, …) so that a drift of the machine's load does not favour one side. Prints the p99.9
# of each run (nccompd and cyclictest).
# NO_STATUS=1 (optional): B's publisher does not poll the status socket (status_socket = ""),
# to tell the cost of the status queries from the rest of the MQTT side.
# Needs root (as run_nccompd_latency.sh), mosquitto, cyclictest.
set -euo pipefail
build=${1:?release build dir}
pairs=${2:?pairs}
secs=${3:?seconds}
cpu=${4:-}
src=$(cd "$(dirname "$0")/../.." && pwd)
tmp=$(mktemp -d)
side=()
cleanup() {
  for p in "${side[@]}"; do kill "$p" 2> /dev/null || true; done
  wait 2> /dev/null || true
  rm -rf "$tmp"
}
trap cleanup EXIT

start_mqtt() {
  local d=$1
  mkdir -p "$d/log"
  local port=$((20000 + RANDOM % 20000))
  : > "$d/passwd"
  chmod 600 "$d/passwd"
  mosquitto_passwd -b "$d/passwd" coll pw-coll
  mosquitto_passwd -b "$d/passwd" m000 pw-0
  printf 'user coll\ntopic read nccomp/#\npattern write nccomp/bench/%%u/#\n' > "$d/acl"
  printf 'listener %s 127.0.0.1\nallow_anonymous false\npassword_file %s\nacl_file %s\npersistence true\npersistence_location %s/\nlog_dest none\n' \
    "$port" "$d/passwd" "$d/acl" "$d" > "$d/mosquitto.conf"
  [ "$(id -u)" = 0 ] && echo "user root" >> "$d/mosquitto.conf"
  printf 'pw-coll\n' > "$d/coll.pw"
  printf 'pw-0\n' > "$d/m000.pw"
  chmod 600 "$d/coll.pw" "$d/m000.pw"
  /usr/sbin/mosquitto -c "$d/mosquitto.conf" &
  side+=($!)
  sleep 0.5
  "$build/tools/nccomp" collect --broker "tcp://127.0.0.1:$port" --out "$d/out" --username coll \
    --password-file "$d/coll.pw" > "$d/collect.log" 2>&1 &
  side+=($!)
  local status="$d/run/status.sock"
  [ "${NO_STATUS:-0}" = 1 ] && status=""
  "$build/bench/mqtt/bench_mqtt_rowgen" "$d/log" 1 1000 "$((secs + 10))" > "$d/rowgen.out" &
  side+=($!)
  cat > "$d/m000.toml" << EOT
[publish]
site = "bench"
machine = "m000"
[source]
log_directory = "log/m000"
status_socket = "$status"
[broker]
uri = "tcp://127.0.0.1:$port"
username = "m000"
password_file = "m000.pw"
[queue]
directory = "queue"
EOT
  "$build/tools/nccomp" publish --config "$d/m000.toml" > "$d/publish.log" 2>&1 &
  side+=($!)
}
stop_mqtt() {
  for p in "${side[@]}"; do kill "$p" 2> /dev/null || true; done
  wait "${side[@]}" 2> /dev/null || true
  side=()
}
p999() { sed -n 's/^\(nccompd\|cyclictest\) .* p99.9=\([0-9.]*\) .*/\1 \2/p' "$1"; }

for ((i = 1; i <= pairs; i++)); do
  if ((i % 2 == 1)); then order="A B"; else order="B A"; fi
  for s in $order; do
    d="$tmp/$i$s"
    mkdir -p "$d/run"
    [ "$s" = B ] && start_mqtt "$d"
    NCCOMPD_BENCH_RUN_DIR="$d/run" "$src/bench/daemon/run_nccompd_latency.sh" "$build" "$secs" $cpu \
      > "$d/latency.out" 2>&1
    [ "$s" = B ] && stop_mqtt
    echo "pair $i $s: $(p999 "$d/latency.out" | tr '\n' ' ')"
    if [ "$s" = B ]; then
      echo "  mqtt: $(tail -1 "$d/collect.log" | sed 's/.*\] //') $(grep -c 'answers' "$d/publish.log") status"
    fi
  done
done
