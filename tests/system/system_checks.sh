#!/usr/bin/env bash
# The ctest test `system_vm` (label system): ONE boot of a VM with systemd as init
# (run_system_vm.sh) runs every check of checks.sh against the Debian packages; this script then
# reads one result per check and fails if any check failed or did not report.
#
#   system_checks.sh DEB_DIR WORKDIR [PROCESS_TEST]
#
# DEB_DIR: the output of scripts/build-deb (nccomp_*.deb, nccomp-sim_*.deb).
set -euo pipefail
here=$(dirname "$(realpath "$0")")
debs=$(realpath -m "$1")
workdir=$(realpath -m "$2")
process_test=${3:+$(realpath "$3")}
checks=(install config_permissions publisher_config start_ready status_access analyzed reload realtime process_test
        journal watchdog security remove source_install)

if ! ls "$debs"/nccomp_*.deb "$debs"/nccomp-sim_*.deb >/dev/null 2>&1; then
  echo "system_checks: no packages in $debs: run scripts/build-deb first" >&2
  exit 1
fi
mkdir -p "$workdir"
start=$(date +%s)
set +e
# The package build's CMake tree (prefix /usr) for the install from source.
tree=$(ls -d "$debs"/src/nccomp-*/obj-* 2>/dev/null | head -1 || true)
"$here/run_system_vm.sh" "$workdir" "$here/checks.sh" "$debs" "$workdir" "$process_test" "$tree"
vm_rc=$?
set -e
echo "system_checks: VM run took $(( $(date +%s) - start )) s (exit $vm_rc)"
[ -f "$workdir/script.log" ] && cat "$workdir/script.log"

failed=0
for c in "${checks[@]}"; do
  if [ ! -f "$workdir/results/$c" ]; then
    echo "system_checks: $c: no result" >&2
    failed=1
  elif ! grep -q '^PASS' "$workdir/results/$c"; then
    echo "system_checks: $c: $(cat "$workdir/results/$c")" >&2
    failed=1
  fi
done
if [ $failed -ne 0 ] || [ $vm_rc -ne 0 ]; then
  echo "system_checks: FAILED (console: $workdir/console.log, journal: $workdir/journal.txt)" >&2
  exit 1
fi
echo "system_checks: all ${#checks[@]} checks passed"
