#!/usr/bin/env bash
# MQTT publisher + broker + collector under load, on this machine:
#   bench/mqtt/run_mqtt_bench.sh RELEASE_BUILD_DIR MACHINES RATE_PER_MACHINE SECONDS [RESTARTS]
#
# - mosquitto (Debian's) on 127.0.0.1 with a password file (one user per machine + coll), an ACL
#   (pattern write nccomp/bench/%u/#), persistence on;
# - `nccomp collect` and bench_mqtt_probe (latency: arrival − the row's utc, i.e. from the
#   moment the row was handed to the log writer, through the writer's 20 ms batches, the
#   publisher's 0.2 s log poll, its queue, the broker, to the subscriber);
# - bench_mqtt_rowgen writing MACHINES logs with nccompd's writer at RATE_PER_MACHINE rows/s;
# - one `nccomp publish` per machine with the shipped defaults (poll_s 0.2, max_inflight 64,
#   fsync_interval_s 1);
# - RESTARTS broker restarts (SIGTERM, start at once) evenly spread over the run.
# Prints: rows written, rows in the collector's logs (and whether each machine's seq is 1..n
# once), the probe's latency quantiles, duplicates and gaps, the CPU time of the broker and of
# all publishers.
set -euo pipefail
build=${1:?release build dir}
machines=${2:?machines}
rate=${3:?rows per second per machine}
secs=${4:?seconds}
restarts=${5:-0}
tmp=$(mktemp -d)
pids=()
bpid=""
cleanup() {
  for p in "${pids[@]}" $bpid; do kill "$p" 2> /dev/null || true; done
  wait 2> /dev/null || true
  rm -rf "$tmp"
}
trap cleanup EXIT

port=$((20000 + RANDOM % 20000))
uri="tcp://127.0.0.1:$port"
: > "$tmp/passwd"
chmod 600 "$tmp/passwd"
mosquitto_passwd -b "$tmp/passwd" coll pw-coll
for ((m = 0; m < machines; m++)); do
  mosquitto_passwd -b "$tmp/passwd" "$(printf m%03d "$m")" "pw-$m"
done
printf 'user coll\ntopic read nccomp/#\npattern write nccomp/bench/%%u/#\n' > "$tmp/acl"
{
  echo "listener $port 127.0.0.1"
  echo "allow_anonymous false"
  echo "password_file $tmp/passwd"
  echo "acl_file $tmp/acl"
  echo "persistence true"
  echo "persistence_location $tmp/"
  echo "max_queued_messages 0"
  echo "log_dest file $tmp/broker.log"
  [ "$(id -u)" = 0 ] && echo "user root"
} > "$tmp/mosquitto.conf"
printf 'pw-coll\n' > "$tmp/coll.pw"
chmod 600 "$tmp/coll.pw"

cpu_ticks() { awk '{print $14 + $15}' "/proc/$1/stat" 2> /dev/null || echo 0; }
broker_ticks=0
start_broker() {
  /usr/sbin/mosquitto -c "$tmp/mosquitto.conf" &
  bpid=$!
  for _ in $(seq 100); do
    (exec 3<> "/dev/tcp/127.0.0.1/$port") 2> /dev/null && return 0
    sleep 0.05
  done
  echo "broker did not start" >&2
  exit 1
}
stop_broker() {
  broker_ticks=$((broker_ticks + $(cpu_ticks "$bpid")))
  kill -TERM "$bpid"
  wait "$bpid" || true
  bpid=""
}

start_broker
"$build/tools/nccomp" collect --broker "$uri" --out "$tmp/out" --username coll \
  --password-file "$tmp/coll.pw" --client-id bench-collector > "$tmp/collect.log" 2>&1 &
pids+=($!)
cpid=$!
for _ in $(seq 100); do grep -q subscribed "$tmp/collect.log" && break; sleep 0.1; done
"$build/bench/mqtt/bench_mqtt_probe" "$uri" coll "$tmp/coll.pw" 15 "$tmp/probe.json" \
  > "$tmp/probe.log" 2>&1 &
probe=$!
sleep 1

mkdir -p "$tmp/log"
"$build/bench/mqtt/bench_mqtt_rowgen" "$tmp/log" "$machines" "$rate" "$secs" > "$tmp/rowgen.out" &
gen=$!
pubs=()
for ((m = 0; m < machines; m++)); do
  name=$(printf m%03d "$m")
  printf 'pw-%d\n' "$m" > "$tmp/$name.pw"
  chmod 600 "$tmp/$name.pw"
  cat > "$tmp/$name.toml" << EOT
[publish]
site = "bench"
machine = "$name"
[source]
log_directory = "log/$name"
status_socket = ""
[broker]
uri = "$uri"
username = "$name"
password_file = "$name.pw"
[queue]
directory = "queue/$name"
EOT
  "$build/tools/nccomp" publish --config "$tmp/$name.toml" > "$tmp/$name.log" 2>&1 &
  pubs+=($!)
done
pids+=("${pubs[@]}")

for ((r = 1; r <= restarts; r++)); do
  sleep "$(echo "$secs / ($restarts + 1)" | bc -l)"
  echo "broker restart $r at $(date -u +%T)"
  stop_broker
  start_broker
done
wait "$gen"
echo "rows generated: $(cat "$tmp/rowgen.out")"
wait "$probe" || true
pub_ticks=0
for p in "${pubs[@]}"; do pub_ticks=$((pub_ticks + $(cpu_ticks "$p"))); done
broker_ticks=$((broker_ticks + $(cpu_ticks "$bpid")))
for p in "${pubs[@]}"; do kill -TERM "$p"; done
kill -TERM "$cpid"
wait "${pubs[@]}" "$cpid" || true
pids=()
hz=$(getconf CLK_TCK)

echo "== probe"
cat "$tmp/probe.json"
echo "== collector"
tail -1 "$tmp/collect.log"
ok=0
bad=0
total=0
for f in "$tmp"/out/bench/*.csv; do
  n=$(($(wc -l < "$f") - 1))
  total=$((total + n))
  if awk -F, 'NR > 1 { if ($NF != NR - 1) exit 1 }' "$f"; then ok=$((ok + 1)); else bad=$((bad + 1)); fi
done
echo "rows in the collector's logs: $total; machines with seq 1..n each once: $ok; others: $bad"
echo "== CPU over the run (${secs} s + drain)"
echo "broker: $(echo "$broker_ticks / $hz" | bc -l | cut -c1-6) s"
echo "publishers (all $machines): $(echo "$pub_ticks / $hz" | bc -l | cut -c1-6) s"
grep -h "queue full\|refused\|cannot connect" "$tmp"/m*.log | head -5 || true
