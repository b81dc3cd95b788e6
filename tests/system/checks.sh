#!/bin/bash
# The system checks of the Debian packages: what only a real init shows. Runs inside the VM of
# run_system_vm.sh, as root, with systemd as PID 1 and the host's root under a throw-away overlay.
#
#   checks.sh DEB_DIR OUT_DIR [PROCESS_TEST [BUILD_TREE]]
#
# DEB_DIR holds nccomp_*.deb and nccomp-sim_*.deb (scripts/build-deb). Each check writes
# OUT_DIR/results/<check>: "PASS <what was seen>" or "FAIL <why>"; the host side
# (system_checks.sh) reads them. Checks build on each other (installed, then running); one whose
# precondition failed says so. PROCESS_TEST: the test_nccompd_process binary, whose
# NccompdProcess.UnitLimitsGrantTheShippedRealtimePolicy needs a root that may raise a user's
# rlimits (skipped on the build host, a container). BUILD_TREE: a CMake build tree configured with
# CMAKE_INSTALL_PREFIX=/usr (the package build's): docs/daemon.md's install from source is run
# with it after the package is purged.
set -u
debs=$1
out=$2
process_test=${3:-}
build_tree=${4:-}
results=$out/results
mkdir -p "$results"
rm -f "$results"/*
export SYSTEMD_PAGER= SYSTEMD_COLORS=0 DEBIAN_FRONTEND=noninteractive

# The console line of a check ends with the seconds since the previous check ended.
check_start=$SECONDS
report() {
  echo "$2 $3" >"$results/$1"
  echo "check $1: $2 $3 [$((SECONDS - check_start)) s]"
  check_start=$SECONDS
}
pass() { report "$1" PASS "$2"; }
fail() { report "$1" FAIL "$2"; }
# Polls a command (up to $1 s) until it succeeds.
wait_for() {
  local limit=$1
  shift
  local t=0
  until "$@" >/dev/null 2>&1; do
    t=$((t + 1))
    [ "$t" -ge "$limit" ] && return 1
    sleep 1
  done
}
journal() { journalctl -u nccompd --no-pager -o cat "$@" 2>/dev/null; }
generation() {
  nccomp status --json 2>/dev/null | sed -n 's/.*"config_generation":\([0-9]*\).*/\1/p'
}
echo "checks: systemd $(systemctl --version | head -1 | cut -d' ' -f2), kernel $(uname -r)"

# --- install: dpkg -i; the user exists; the unit is installed disabled and not started ---------
installed=false
# man-db's trigger would re-index every manual page of the host (minutes under TCG); the packages'
# pages are not what is tested here.
rm -f /var/lib/man-db/auto-update
if ! dpkg -i "$debs"/nccomp_*.deb "$debs"/nccomp-sim_*.deb >"$out/dpkg-install.log" 2>&1; then
  fail install "dpkg -i failed: $(tail -3 "$out/dpkg-install.log" | tr '\n' ' ')"
elif ! getent passwd nccomp >/dev/null || ! getent group nccomp >/dev/null; then
  fail install "no user or group nccomp after install"
else
  enabled=$(systemctl is-enabled nccompd 2>&1)
  active=$(systemctl is-active nccompd 2>&1)
  if [ "$enabled" != disabled ] || [ "$active" != inactive ]; then
    fail install "after install the unit is '$enabled' and '$active' (want disabled, inactive)"
  else
    installed=true
    pass install "nccomp $(dpkg-query -W -f='${Version}' nccomp); user nccomp uid $(id -u nccomp); unit disabled, inactive"
  fi
fi

# --- config_permissions: /etc/nccompd readable by the service's user only --------------------
if ! $installed; then
  fail config_permissions "skipped: install failed"
else
  dir=$(stat -c '%U:%G %a' /etc/nccompd)
  file=$(stat -c '%U:%G %a' /etc/nccompd/nccompd.toml)
  map=$(stat -c '%U:%G %a' /etc/nccompd/reference-nc-modbus.toml)
  if [ "$dir" != "root:nccomp 750" ] || [ "$file" != "root:nccomp 640" ] ||
     [ "$map" != "root:nccomp 640" ]; then
    fail config_permissions "/etc/nccompd $dir, nccompd.toml $file, map $map (want root:nccomp 750 / 640)"
  elif ! msg=$(runuser -u nccomp -- nccomp check-config /etc/nccompd/nccompd.toml 2>&1); then
    fail config_permissions "user nccomp cannot load the config: $msg"
  elif runuser -u nobody -- nccomp check-config -q /etc/nccompd/nccompd.toml >/dev/null 2>&1; then
    fail config_permissions "user nobody can read /etc/nccompd/nccompd.toml"
  else
    pass config_permissions "/etc/nccompd $dir, nccompd.toml $file; nccomp check-config as user nccomp: OK"
  fi
fi

# --- publisher_config: /etc/nccomp readable by the MQTT publisher's user only -----------------
if ! $installed; then
  fail publisher_config "skipped: install failed"
elif ! getent passwd nccomp-publish >/dev/null; then
  fail publisher_config "no user nccomp-publish after install"
else
  # The operator's step (docs/mqtt.md): the broker password, then the permissions applied.
  echo secret >/etc/nccomp/publish.password
  systemd-tmpfiles --create nccomp-publish.conf
  dir=$(stat -c '%U:%G %a' /etc/nccomp)
  file=$(stat -c '%U:%G %a' /etc/nccomp/nccomp-publish.toml)
  pw=$(stat -c '%U:%G %a' /etc/nccomp/publish.password)
  groups=$(id -nG nccomp-publish)
  if [ "$dir" != "root:nccomp-publish 750" ] || [ "$file" != "root:nccomp-publish 640" ] ||
     [ "$pw" != "root:nccomp-publish 640" ]; then
    fail publisher_config "/etc/nccomp $dir, nccomp-publish.toml $file, password $pw (want root:nccomp-publish 750 / 640)"
  elif [[ " $groups " != *" nccomp "* ]]; then
    fail publisher_config "user nccomp-publish is in '$groups', not in nccomp (the log and the status socket)"
  elif ! msg=$(runuser -u nccomp-publish -- nccomp publish --config /etc/nccomp/nccomp-publish.toml --check 2>&1); then
    fail publisher_config "user nccomp-publish cannot load its config: $msg"
  elif runuser -u nobody -- cat /etc/nccomp/publish.password >/dev/null 2>&1; then
    fail publisher_config "user nobody can read the broker password"
  elif ! systemd-analyze verify nccomp-publish.service >"$out/publish-verify.txt" 2>&1; then
    fail publisher_config "systemd-analyze verify: $(head -3 "$out/publish-verify.txt" | tr '\n' ' ')"
  else
    pass publisher_config "/etc/nccomp $dir, config and password $file; groups '$groups'; --check as nccomp-publish: OK; unit verifies"
  fi
fi

# --- start_ready: against the Modbus NC server on loopback, systemctl start returns at READY --
running=false
if ! $installed; then
  fail start_ready "skipped: install failed"
else
  systemd-run --unit=nc-sim --quiet /usr/bin/modbus_nc --port 1502
  wait_for 20 bash -c 'exec 3<>/dev/tcp/127.0.0.1/1502'
  if ! systemctl start nccompd 2>"$out/start.err"; then
    fail start_ready "systemctl start failed: $(cat "$out/start.err") $(journal | tail -5 | tr '\n' ' ')"
  else
    state=$(systemctl is-active nccompd)
    text=$(systemctl show -p StatusText --value nccompd)
    if [ "$state" = active ] && [[ $text == running:* ]]; then
      running=true
      pass start_ready "is-active: $state; StatusText: $text"
    else
      fail start_ready "is-active: $state; StatusText: '$text'"
    fi
  fi
fi

# --- status_access: the group nccomp may read the status socket, others may not ---------------
if ! $running; then
  fail status_access "skipped: the service is not running"
else
  useradd -M -G nccomp operator1 && useradd -M outsider1
  pid=$(systemctl show -p MainPID --value nccompd)
  member=$(runuser -u operator1 -- nccomp status 2>&1)
  member_rc=$?
  other=$(runuser -u outsider1 -- nccomp status 2>&1)
  other_rc=$?
  if [ $member_rc -ne 0 ] || [[ $member != "nccompd pid $pid,"* ]]; then
    fail status_access "group member: exit $member_rc: $(echo "$member" | head -2 | tr '\n' ' ')"
  elif [ $other_rc -eq 0 ]; then
    fail status_access "a user outside the group nccomp read the status"
  else
    pass status_access "member: '$(echo "$member" | head -1)'; outsider: exit $other_rc '$other'"
  fi
fi

# --- analyzed: nccomp-analyzed's user, config and unit; started beside the running daemon ------
if ! $running; then
  fail analyzed "skipped: the service is not running"
elif ! getent passwd nccomp-analyzed >/dev/null; then
  fail analyzed "no user nccomp-analyzed after install"
else
  groups=$(id -nG nccomp-analyzed)
  file=$(stat -c '%U:%G %a' /etc/nccompd/nccomp-analyzed.toml)
  # The operator's step (docs/analyzed.md): the model the analysis fits, beside the config.
  printf '[model]\n[[model.term]]\nname = "offset"\nform = "constant"\n' >/etc/nccompd/model.toml
  chown root:nccomp /etc/nccompd/model.toml && chmod 0640 /etc/nccompd/model.toml
  if [[ " $groups " != *" nccomp "* ]] || [[ " $groups " != *" nccomp-admin "* ]]; then
    fail analyzed "user nccomp-analyzed is in '$groups', not in nccomp and nccomp-admin"
  elif [ "$file" != "root:nccomp 640" ]; then
    fail analyzed "/etc/nccompd/nccomp-analyzed.toml $file (want root:nccomp 640)"
  elif ! msg=$(runuser -u nccomp-analyzed -- nccomp-analyzed --check 2>&1); then
    fail analyzed "user nccomp-analyzed cannot load its config: $msg"
  elif ! systemd-analyze verify nccomp-analyzed.service >"$out/analyzed-verify.txt" 2>&1; then
    fail analyzed "systemd-analyze verify: $(head -3 "$out/analyzed-verify.txt" | tr '\n' ' ')"
  elif ! systemctl start nccomp-analyzed 2>"$out/analyzed-start.err" ||
       ! wait_for 10 bash -c 'journalctl -u nccomp-analyzed -o cat | grep -q "^info following"'; then
    fail analyzed "start: $(cat "$out/analyzed-start.err") $(journalctl -u nccomp-analyzed -o cat | tail -3 | tr '\n' ' ')"
  else
    policy=$(chrt -p "$(systemctl show -p MainPID --value nccomp-analyzed)" | head -1)
    systemctl stop nccomp-analyzed
    if [[ $policy != *SCHED_IDLE* ]]; then
      fail analyzed "scheduling: '$policy' (want SCHED_IDLE)"
    else
      pass analyzed "groups '$groups'; config $file; --check as nccomp-analyzed: OK; unit verifies; started: $(journalctl -u nccomp-analyzed -o cat | grep -m1 '^info following' | cut -c1-60)...; $policy"
    fi
  fi
fi

# --- reload: systemctl reload applies a changed config (the generation goes up) --------------
if ! $running; then
  fail reload "skipped: the service is not running"
else
  before=$(generation)
  sed -i '0,/^max_rate_um_per_s = /s/^max_rate_um_per_s = .*/max_rate_um_per_s = 40.0/' \
    /etc/nccompd/nccompd.toml
  if ! systemctl reload nccompd 2>"$out/reload.err"; then
    fail reload "systemctl reload failed: $(cat "$out/reload.err")"
  elif ! wait_for 30 bash -c "nccomp status --json | grep -q '\"config_generation\":$((before + 1))'"; then
    fail reload "generation stays $(generation) (was $before): $(journal | grep -i reload | tail -3 | tr '\n' ' ')"
  else
    pass reload "config generation $before -> $(generation); $(journal | grep 'reload: configuration' | tail -1)"
  fi
fi

# --- realtime: the unit's rlimits give the loop SCHED_FIFO 80 and locked memory ---------------
if ! $running; then
  fail realtime "skipped: the service is not running"
else
  pid=$(systemctl show -p MainPID --value nccompd)
  fifo=""
  for stat in /proc/"$pid"/task/*/stat; do
    # Fields after the command's closing parenthesis: 40 rt_priority, 41 policy (1 = FIFO).
    read -r -a f <<<"$(sed 's/.*) //' "$stat")"
    if [ "${f[38]}" = 1 ]; then
      tid=${stat%/stat}
      fifo="$fifo tid ${tid##*/} prio ${f[37]}"
    fi
  done
  locked=$(awk '/VmLck/ {print $2}' /proc/"$pid"/status)
  caps=$(awk '/CapEff/ {print $2}' /proc/"$pid"/status)
  if [ -z "$fifo" ] || [ "${locked:-0}" -eq 0 ] || ! journal | grep -q 'loop thread: SCHED_FIFO priority 80'; then
    fail realtime "SCHED_FIFO threads:${fifo:- none}; VmLck ${locked:-?} kB; log: $(journal | grep -E 'SCHED_FIFO|mlock|memory' | tr '\n' ' ')"
  elif [ "$caps" != 0000000000000000 ]; then
    fail realtime "the daemon has capabilities: CapEff $caps"
  else
    pass realtime "SCHED_FIFO:$fifo; VmLck $locked kB; CapEff $caps; $(journal | grep -c 'memory locked (mlockall)') 'memory locked' line(s)"
  fi
fi

# --- process_test: the rlimit test that the build host always skips, run as root here ---------
if [ -z "$process_test" ]; then
  fail process_test "no test binary given"
else
  "$process_test" --gtest_filter=NccompdProcess.UnitLimitsGrantTheShippedRealtimePolicy \
    >"$out/process_test.log" 2>&1
  rc=$?
  if [ $rc -ne 0 ]; then
    fail process_test "exit $rc: $(grep -E 'Failure|Expected|SKIPPED' "$out/process_test.log" | head -3 | tr '\n' ' ')"
  elif grep -q '\[  SKIPPED \]' "$out/process_test.log"; then
    fail process_test "skipped: $(grep -A1 'Skipped' "$out/process_test.log" | tail -1)"
  elif grep -q '\[  PASSED  \] 1 test' "$out/process_test.log"; then
    pass process_test "NccompdProcess.UnitLimitsGrantTheShippedRealtimePolicy passed (not skipped)"
  else
    fail process_test "no result: $(tail -2 "$out/process_test.log" | tr '\n' ' ')"
  fi
fi

# --- journal: PRIORITY on every line; an alarm carries its code as fields ---------------------
if ! $running; then
  fail journal "skipped: the service is not running"
else
  # The NC goes away: the Modbus bus alarm (code 54) after alarm_after_s (1 s), cleared when back.
  systemctl stop nc-sim
  wait_for 30 bash -c 'journalctl -u nccompd NCCOMP_ALARM_CODE=54 -o cat | grep -q .'
  systemd-run --unit=nc-sim2 --quiet /usr/bin/modbus_nc --port 1502
  wait_for 30 bash -c 'journalctl -u nccompd NCCOMP_ALARM_CODE=54 NCCOMP_ALARM_VALUE=0 -o cat | grep -q .'
  # One JSON object per entry: its fields, sorted, as NAME=value.
  fields() { grep -o -E "\"($1)\":\"[^\"]*\"" | sed 's/"\([^"]*\)":"\([^"]*\)"/\1=\2/' | sort -u | tr '\n' ' '; }
  raised=$(journalctl -u nccompd NCCOMP_ALARM_CODE=54 NCCOMP_ALARM_VALUE=1 -o json --no-pager |
    head -1 | fields 'PRIORITY|NCCOMP_ALARM_[A-Z]*|SYSLOG_IDENTIFIER')
  cleared=$(journalctl -u nccompd NCCOMP_ALARM_CODE=54 NCCOMP_ALARM_VALUE=0 -o json --no-pager |
    head -1 | fields 'PRIORITY')
  running_prio=$(journalctl -u nccompd -o json --no-pager | grep '"MESSAGE":"loop running' |
    head -1 | fields 'PRIORITY')
  if [[ $raised != *"NCCOMP_ALARM_NAME=bus_alarm"* ]] || [[ $raised != *"PRIORITY=3"* ]] ||
     [[ $raised != *"NCCOMP_ALARM_SUBJECT=0"* ]] || [[ $cleared != *"PRIORITY=6"* ]]; then
    fail journal "raised: '$raised'; cleared: '$cleared'"
  elif [ "$running_prio" != "PRIORITY=6 " ]; then
    fail journal "'loop running' has '$running_prio' (want PRIORITY=6)"
  else
    pass journal "bus alarm raised: $raised; cleared: $cleared; 'loop running': $running_prio"
  fi
fi

# --- watchdog: a stopped daemon is killed by the watchdog and restarted ----------------------
if ! $running; then
  fail watchdog "skipped: the service is not running"
else
  old=$(systemctl show -p MainPID --value nccompd)
  kill -STOP "$old"
  if ! wait_for 90 bash -c "p=\$(systemctl show -p MainPID --value nccompd); [ \"\$p\" != 0 ] && [ \"\$p\" != $old ] && systemctl is-active -q nccompd"; then
    fail watchdog "no restart within 90 s: $(systemctl show -p ActiveState,SubState,Result nccompd | tr '\n' ' ')"
  else
    why=$(journalctl -u nccompd --no-pager -o cat | grep -m1 'Watchdog timeout')
    restarts=$(systemctl show -p NRestarts --value nccompd)
    if [ -z "$why" ]; then
      fail watchdog "restarted, but the journal does not say 'Watchdog timeout'"
    else
      pass watchdog "pid $old -> $(systemctl show -p MainPID --value nccompd), NRestarts $restarts; journal: $why"
    fi
  fi
fi

# --- security: systemd-analyze security of the installed unit ---------------------------------
if ! $installed; then
  fail security "skipped: install failed"
else
  systemd-analyze security nccompd --no-pager >"$out/security.txt" 2>&1
  score=$(sed -n 's/.*Overall exposure level for nccompd.service: \([0-9.]*\).*/\1/p' "$out/security.txt")
  if [ -z "$score" ]; then
    fail security "no score: $(tail -2 "$out/security.txt" | tr '\n' ' ')"
  elif awk -v s="$score" 'BEGIN { exit !(s <= 2.0) }'; then
    pass security "exposure $score (at most 2.0)"
  else
    fail security "exposure $score > 2.0"
  fi
fi

# --- remove: removing the package stops the service and keeps configuration and state --------
# dpkg runs the maintainer scripts that `apt-get remove` would run (nothing depends on nccomp);
# apt-get would first read the host's package lists over 9p, slow in the VM.
if ! $installed; then
  fail remove "skipped: install failed"
else
  was=$(systemctl is-active nccompd)
  if ! dpkg --remove nccomp >"$out/remove.log" 2>&1; then
    fail remove "dpkg --remove failed: $(tail -3 "$out/remove.log" | tr '\n' ' ')"
  else
    now=$(systemctl is-active nccompd 2>&1)
    left=$(pgrep -x nccompd)
    if [ "$now" = active ] || [ -n "$left" ]; then
      fail remove "after removal: is-active '$now', process '$left'"
    elif [ ! -f /etc/nccompd/nccompd.toml ] || [ ! -f /var/lib/nccompd/state.bin ]; then
      fail remove "removal lost /etc/nccompd/nccompd.toml or /var/lib/nccompd/state.bin: $(ls /etc/nccompd /var/lib/nccompd 2>&1 | tr '\n' ' ')"
    else
      pass remove "service $was -> $now, no nccompd process; kept /etc/nccompd/nccompd.toml and /var/lib/nccompd/state.bin"
    fi
  fi
fi

# --- source_install: docs/daemon.md's steps from source give a service that reads its config --
if [ -z "$build_tree" ]; then
  fail source_install "no build tree given"
elif ! dpkg --purge nccomp >>"$out/remove.log" 2>&1 || [ -e /usr/sbin/nccompd ]; then
  fail source_install "could not purge the package first"
else
  {
    cmake --install "$build_tree" &&
      systemd-sysusers nccompd.conf &&
      systemd-tmpfiles --create nccompd.conf &&
      systemctl daemon-reload &&
      nccomp check-config /etc/nccompd/nccompd.toml &&
      systemctl start nccompd
  } >"$out/source-install.log" 2>&1
  rc=$?
  file=$(stat -c '%U:%G %a' /etc/nccompd/nccompd.toml 2>&1)
  state=$(systemctl is-active nccompd)
  if [ $rc -ne 0 ] || [ "$state" != active ] || [ "$file" != "root:nccomp 640" ]; then
    fail source_install "exit $rc, service $state, nccompd.toml $file: $(tail -3 "$out/source-install.log" | tr '\n' ' ')"
  else
    pass source_install "cmake --install + systemd-sysusers + systemd-tmpfiles: nccompd.toml $file, service $state"
  fi
  systemctl stop nccompd
fi

journalctl -b --no-pager -u nccompd >"$out/nccompd-journal.txt" 2>&1
echo "checks: done"
