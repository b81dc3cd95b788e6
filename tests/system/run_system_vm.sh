#!/usr/bin/env bash
# Boots a VM whose init is systemd and runs one script in it as a service: the system tests of
# the Debian package (tests/system/CMakeLists.txt) — what only a real init shows.
#
#   run_system_vm.sh WORKDIR SCRIPT [ARGS...]
#
# The VM runs the installed Debian kernel (/boot/vmlinuz-<ver>) under qemu (TCG by default) with
# a busybox initramfs built here. Its root is the host's root, read-only over 9p, under an
# overlay whose upper layer is a tmpfs: the VM may install packages, add users and write /etc,
# and nothing of the host changes. WORKDIR is mounted writable at the same path: the script's
# outputs come back there. The initramfs switches to the overlay and executes /lib/systemd/systemd
# with its own target (systemd.unit=nccomp-system.target: sysinit and the test service only; no
# getty, no network services, no timers), whose service runs
#   /bin/bash SCRIPT ARGS...
# with stdout and stderr in WORKDIR/script.log, then powers the VM off (SuccessAction= /
# FailureAction=). The script's exit status is written to WORKDIR/exit_status; this script exits
# with it (125 when the VM could not boot or run the script).
#
# Environment: NCCOMP_VM_ACCEL=tcg|kvm (tcg), NCCOMP_VM_TIMEOUT_S (900), NCCOMP_VM_MEM_MB (1536),
# NCCOMP_VM_SMP (2), NCCOMP_VM_KERNEL=<version> (the newest /boot/vmlinuz-* with modules).
set -euo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 WORKDIR SCRIPT [ARGS...]" >&2
  exit 2
fi
workdir=$(realpath -m "$1")
script=$(realpath "$2")
shift 2
mkdir -p "$workdir"
rm -f "$workdir/exit_status" "$workdir/console.log" "$workdir/script.log"

kver=${NCCOMP_VM_KERNEL:-}
if [ -z "$kver" ]; then
  for k in /boot/vmlinuz-*; do
    [ -e "$k" ] || continue
    v=${k#/boot/vmlinuz-}
    [ -d "/lib/modules/$v/kernel" ] || continue
    kver=$(printf '%s\n%s\n' "$kver" "$v" | sed '/^$/d' | sort -V | tail -1)
  done
fi
if [ -z "$kver" ] || [ ! -r "/boot/vmlinuz-$kver" ]; then
  echo "run_system_vm: no readable /boot/vmlinuz-<ver> with /lib/modules/<ver>" >&2
  exit 125
fi
for tool in qemu-system-x86_64 cpio; do
  command -v "$tool" >/dev/null || { echo "run_system_vm: $tool missing (scripts/setup)" >&2; exit 125; }
done
if ! file -L /bin/busybox 2>/dev/null | grep -q 'statically linked'; then
  echo "run_system_vm: /bin/busybox is not static (install busybox-static)" >&2
  exit 125
fi
if [ ! -x /lib/systemd/systemd ]; then
  echo "run_system_vm: /lib/systemd/systemd missing (install systemd)" >&2
  exit 125
fi

# --- initramfs: busybox, the modules for virtio, 9p and overlayfs, and an init that switches to
# the overlay. Rebuilt when the kernel or this script changes.
initrd="$workdir/initramfs-$kver.cpio.gz"
self_sum=$(sha1sum "$0" | cut -c1-12)
if [ ! -f "$initrd" ] || [ "$(cat "$initrd.sum" 2>/dev/null)" != "$self_sum" ]; then
  dir="$workdir/initramfs"
  rm -rf "$dir"
  mkdir -p "$dir"/{bin,lib/modules,proc,sys,dev,lower,rw,newroot}
  cp /bin/busybox "$dir/bin/busybox"
  modlist=""
  for m in virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci netfs \
           fscache 9pnet 9pnet_virtio 9p overlay; do
    f=$(find "/lib/modules/$kver/kernel" -name "$m.ko" -o -name "$m.ko.xz" -o -name "$m.ko.zst" \
          -o -name "$m.ko.gz" 2>/dev/null | head -1)
    [ -n "$f" ] || continue
    case "$f" in
      *.ko) cp "$f" "$dir/lib/modules/$m.ko" ;;
      *.ko.xz) xz -dc "$f" >"$dir/lib/modules/$m.ko" ;;
      *.ko.zst) zstd -qdc "$f" >"$dir/lib/modules/$m.ko" ;;
      *.ko.gz) gzip -dc "$f" >"$dir/lib/modules/$m.ko" ;;
    esac
    modlist="$modlist $m"
  done
  cat >"$dir/init" <<INIT
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
for m in $modlist; do insmod /lib/modules/\$m.ko 2>/dev/null; done
INIT
  cat >>"$dir/init" <<'INIT'
fail() { echo "NCCOMP_VM_ERROR=$1"; echo "NCCOMP_VM_EXIT=125"; poweroff -f; }
out=$(sed -n 's/.*nccomp.out=\([^ ]*\).*/\1/p' /proc/cmdline)
# The host root is read-only: caching it in the guest saves a virtio round trip per lookup.
mount -t 9p -o trans=virtio,version=9p2000.L,ro,msize=262144,cache=loose host /lower ||
  fail "mount host"
mount -t tmpfs -o size=768m,mode=0755 rw /rw || fail "tmpfs"
mkdir -p /rw/upper /rw/work
mount -t overlay overlay -o lowerdir=/lower,upperdir=/rw/upper,workdir=/rw/work /newroot ||
  fail "overlay"
mount -t 9p -o trans=virtio,version=9p2000.L,rw,msize=262144 out "/newroot$out" || fail "mount out"
# The test's target and service. /tmp is not emptied at boot (tmpfiles.d tmp.conf overridden):
# the script, the packages or the build may live there.
cp "/newroot$out/units/"* /newroot/etc/systemd/system/ || fail "units"
mkdir -p /newroot/etc/tmpfiles.d && : >/newroot/etc/tmpfiles.d/tmp.conf || fail "tmp.conf"
# The host is a container image: without this file systemd in the VM would believe it runs in a
# container and ignore the kernel command line (systemd.unit=, systemd.mask=).
rm -f /newroot/.dockerenv /newroot/run/.containerenv
# Nor may the image's policy-rc.d (exit 101: "no service actions") stand in for a real system's:
# the packages' maintainer scripts must start and stop services as on a machine.
rm -f /newroot/usr/sbin/policy-rc.d
umount /proc /sys /dev
exec switch_root /newroot /lib/systemd/systemd
INIT
  chmod +x "$dir/init"
  (cd "$dir" && find . | cpio -o -H newc --quiet | gzip -1) >"$initrd.tmp"
  mv "$initrd.tmp" "$initrd"
  echo "$self_sum" >"$initrd.sum"
fi

# --- the target and the service that runs the script
mkdir -p "$workdir/units"
rm -f "$workdir/units/"*
cat >"$workdir/units/nccomp-system.target" <<EOF2
[Unit]
Description=nccomp system test
Requires=sysinit.target nccomp-system-script.service
After=sysinit.target
AllowIsolate=yes
EOF2
{
  echo "#!/bin/bash"
  echo "cd /"
  printf '/bin/bash %s >%q 2>&1\n' "$(printf '%q ' "$script" "$@")" "$workdir/script.log"
  echo 'rc=$?'
  printf 'echo $rc >%q\n' "$workdir/exit_status"
  printf 'journalctl -b --no-pager -o short-monotonic >%q 2>&1\n' "$workdir/journal.txt"
  echo 'echo "NCCOMP_VM_EXIT=$rc" >/dev/console'
} >"$workdir/run.sh"
cat >"$workdir/units/nccomp-system-script.service" <<EOF2
[Unit]
Description=nccomp system test script
After=sysinit.target systemd-journald.service
SuccessAction=poweroff-force
FailureAction=poweroff-force
[Service]
Type=oneshot
Environment=HOME=/root LANG=C.UTF-8
ExecStart=/bin/bash $workdir/run.sh
EOF2

accel=${NCCOMP_VM_ACCEL:-tcg}
cpu_opt=()
if [ "$accel" = "kvm" ]; then
  cpu_opt=(-cpu host)
else
  accel="tcg,thread=multi"
  cpu_opt=(-cpu max)
fi
timeout_s=${NCCOMP_VM_TIMEOUT_S:-900}
# What sysinit.target would start but the tests do not need: device management (no device is
# used; under TCG udev's coldplug alone costs tens of seconds), kernel modules, the clock.
masks="systemd-udevd.service systemd-udevd-control.socket systemd-udevd-kernel.socket"
masks="$masks systemd-udev-trigger.service systemd-udev-settle.service systemd-modules-load.service"
masks="$masks modprobe@drm.service modprobe@fuse.service modprobe@dm_mod.service"
masks="$masks modprobe@loop.service modprobe@efi_pstore.service sys-fs-fuse-connections.mount"
masks="$masks systemd-timesyncd.service systemd-pstore.service systemd-networkd.service"
mask_args=""
for m in $masks; do
  mask_args="$mask_args systemd.mask=$m"
done
echo "run_system_vm: booting kernel $kver with systemd under qemu ($accel), timeout ${timeout_s}s"
start=$(date +%s)
set +e
timeout --kill-after=10 "$timeout_s" qemu-system-x86_64 \
  -accel "$accel" "${cpu_opt[@]}" -m "${NCCOMP_VM_MEM_MB:-1536}" -smp "${NCCOMP_VM_SMP:-2}" \
  -nodefaults -no-reboot -display none -serial stdio \
  -kernel "/boot/vmlinuz-$kver" -initrd "$initrd" \
  -append "console=ttyS0 quiet loglevel=3 panic=-1 nccomp.out=$workdir systemd.unit=nccomp-system.target systemd.show_status=0 systemd.log_level=notice systemd.journald.forward_to_console=0$mask_args" \
  -virtfs local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap \
  -virtfs "local,path=$workdir,mount_tag=out,security_model=none,multidevs=remap" \
  </dev/null 2>&1 | tee "$workdir/console.log"
qemu_rc=${PIPESTATUS[0]}
set -e
echo "run_system_vm: VM finished after $(( $(date +%s) - start )) s (qemu status $qemu_rc)"
if [ ! -s "$workdir/exit_status" ]; then
  echo "run_system_vm: the script did not finish (console: $workdir/console.log)" >&2
  exit 125
fi
exit "$(cat "$workdir/exit_status")"
