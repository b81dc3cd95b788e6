#!/usr/bin/env bash
# Runs one command with a working vcan0, and returns its exit status.
#
#   run_in_vm.sh WORKDIR -- COMMAND [ARGS...]
#
# Where the running kernel has AF_CAN and vcan0 can be created (a CI machine with CAN, a
# developer's laptop), the command runs directly. Otherwise (this build host: AF_CAN refused) a
# small VM is booted: the installed Debian kernel (/boot/vmlinuz-<ver>), an initramfs built here
# from busybox-static and that kernel's virtio/9p/CAN modules, the host's root mounted read-only
# over 9p and chrooted into, so the command sees the same binaries and paths as on the host.
# WORKDIR (in the build directory) is mounted writable at the same path inside the VM: that is
# where outputs come back. The command's exit status is printed on the serial console
# ("NCCOMP_VM_EXIT=<n>") and written to WORKDIR/exit_status; this script exits with it.
#
# Environment:
#   NCCOMP_VM=auto|always|never   auto (default): direct if vcan works, else VM
#   NCCOMP_VM_ACCEL=tcg|kvm       tcg (default; /dev/kvm was seen to hang on the build host)
#   NCCOMP_VM_TIMEOUT_S=600       the whole VM run, boot included
#   NCCOMP_VM_MEM_MB=1024, NCCOMP_VM_SMP=2
#   NCCOMP_VM_KERNEL=<version>    default: the newest /boot/vmlinuz-* with a /lib/modules tree
set -euo pipefail

if [ $# -lt 3 ] || [ "$2" != "--" ]; then
  echo "usage: $0 WORKDIR -- COMMAND [ARGS...]" >&2
  exit 2
fi
workdir=$(realpath -m "$1")
shift 2
mkdir -p "$workdir"
rm -f "$workdir/exit_status" "$workdir/console.log"

mode=${NCCOMP_VM:-auto}

# --- direct run where the kernel has CAN ----------------------------------------------------
vcan_works() {
  # Needs: CAN_RAW sockets and a vcan0 that is (or can be made) up.
  /usr/bin/python3 - <<'EOF' 2>/dev/null || return 1
import socket, sys
s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
s.close()
EOF
  if ! ip link show vcan0 >/dev/null 2>&1; then
    ip link add vcan0 type vcan 2>/dev/null || return 1
  fi
  ip link set vcan0 up 2>/dev/null || return 1
  return 0
}

if [ "$mode" = "never" ] || { [ "$mode" = "auto" ] && vcan_works; }; then
  echo "run_in_vm: running directly (this kernel has vcan)"
  set +e
  "$@"
  rc=$?
  set -e
  echo "$rc" >"$workdir/exit_status"
  echo "NCCOMP_VM_EXIT=$rc"
  exit "$rc"
fi

# --- VM run -----------------------------------------------------------------------------------
pick_kernel() {
  if [ -n "${NCCOMP_VM_KERNEL:-}" ]; then
    echo "$NCCOMP_VM_KERNEL"
    return
  fi
  local best=""
  for k in /boot/vmlinuz-*; do
    [ -e "$k" ] || continue
    local v=${k#/boot/vmlinuz-}
    [ -d "/lib/modules/$v/kernel" ] || continue
    best=$(printf '%s\n%s\n' "$best" "$v" | sed '/^$/d' | sort -V | tail -1)
  done
  echo "$best"
}
kver=$(pick_kernel)
if [ -z "$kver" ] || [ ! -r "/boot/vmlinuz-$kver" ]; then
  echo "run_in_vm: no readable /boot/vmlinuz-<ver> with /lib/modules/<ver> (install linux-image-amd64)" >&2
  exit 125
fi
for tool in qemu-system-x86_64 cpio; do
  command -v "$tool" >/dev/null || { echo "run_in_vm: $tool missing (scripts/setup)" >&2; exit 125; }
done
busybox=/bin/busybox
if ! file -L "$busybox" 2>/dev/null | grep -q 'statically linked'; then
  echo "run_in_vm: $busybox is not static (install busybox-static)" >&2
  exit 125
fi

# The initramfs is rebuilt when the kernel or this script changes (cheap: ~3 MB of cpio).
initrd_dir="$workdir/initramfs"
initrd="$workdir/initramfs-$kver.cpio.gz"
self_sum=$(sha1sum "$0" | cut -c1-12)
if [ ! -f "$initrd" ] || [ "$(cat "$initrd.sum" 2>/dev/null)" != "$self_sum" ]; then
  rm -rf "$initrd_dir"
  mkdir -p "$initrd_dir"/{bin,lib/modules,proc,sys,dev,host,hosttmp,tmp}
  cp "$busybox" "$initrd_dir/bin/busybox"
  modlist=""
  for m in virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci netfs \
           fscache 9pnet 9pnet_virtio 9p can can-raw can-dev vcan; do
    # Built-in modules need no file; missing ones are skipped (a newer kernel may merge them).
    f=$(find "/lib/modules/$kver/kernel" -name "$m.ko" -o -name "$m.ko.xz" -o -name "$m.ko.zst" \
          -o -name "$m.ko.gz" 2>/dev/null | head -1)
    [ -n "$f" ] || continue
    case "$f" in
      *.ko) cp "$f" "$initrd_dir/lib/modules/$m.ko" ;;
      *.ko.xz) xz -dc "$f" >"$initrd_dir/lib/modules/$m.ko" ;;
      *.ko.zst) zstd -qdc "$f" >"$initrd_dir/lib/modules/$m.ko" ;;
      *.ko.gz) gzip -dc "$f" >"$initrd_dir/lib/modules/$m.ko" ;;
    esac
    modlist="$modlist $m"
  done
  cat >"$initrd_dir/init" <<EOF
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
for m in $modlist; do insmod /lib/modules/\$m.ko 2>/dev/null; done
EOF
  cat >>"$initrd_dir/init" <<'EOF'
rc=124
fail() { echo "NCCOMP_VM_ERROR=$1"; echo "NCCOMP_VM_EXIT=125"; poweroff -f; }
# The host root is read-only: caching it in the guest is safe and saves a virtio round trip
# per lookup (TCG makes each one slow: program and python start-up time).
mount -t 9p -o trans=virtio,version=9p2000.L,ro,msize=262144,cache=loose host /host || fail "mount host"
out=$(sed -n 's/.*nccomp.out=\([^ ]*\).*/\1/p' /proc/cmdline)
expose=$(sed -n 's/.*nccomp.expose=\([^ ]*\).*/\1/p' /proc/cmdline)
mount -t proc proc /host/proc
mount -t sysfs sys /host/sys
mount -t devtmpfs dev /host/dev
# /tmp is a writable tmpfs inside; where the checkout or the build lives under the host's /tmp
# (a CI clone in /tmp), those trees are bound back (read-only) over it.
mount -o bind /host/tmp /hosttmp || fail "bind host tmp"
mount -t tmpfs tmp /host/tmp
for p in $(echo "$expose" | tr ',' ' '); do
  rel=${p#/tmp/}
  mkdir -p "/host/tmp/$rel" && mount -o bind "/hosttmp/$rel" "/host/tmp/$rel" || fail "expose $p"
done
mount -t tmpfs run /host/run 2>/dev/null
mount -t 9p -o trans=virtio,version=9p2000.L,rw,msize=262144 out "/host$out" || fail "mount out"
ip link set lo up
ip link add vcan0 type vcan || fail "ip link add vcan0"
ip link set vcan0 up || fail "ip link set vcan0 up"
chroot /host /bin/bash "$out/vm_cmd.sh"
rc=$?
echo "NCCOMP_VM_EXIT=$rc"
sync
poweroff -f
EOF
  chmod +x "$initrd_dir/init"
  (cd "$initrd_dir" && find . | cpio -o -H newc --quiet | gzip -1) >"$initrd.tmp"
  mv "$initrd.tmp" "$initrd"
  echo "$self_sum" >"$initrd.sum"
fi

# Trees under the host's /tmp that the command needs (the checkout, the build, paths in its
# arguments): /tmp is a tmpfs inside the VM, so they are bound back in (first level below /tmp).
expose=""
repo_root=$(realpath -m "$(dirname "$0")/../../..")
for p in "$PWD" "$workdir" "$repo_root" "$@"; do
  case "$p" in
    /tmp/*) ;;
    *) continue ;;
  esac
  top=$(realpath -m "$p" | cut -d/ -f1-3)
  case "$top" in
    /tmp/*[!A-Za-z0-9._-]*) echo "run_in_vm: cannot expose '$top' inside the VM (name)" >&2; exit 125 ;;
  esac
  case ",$expose," in
    *",$top,"*) ;;
    *) expose="${expose:+$expose,}$top" ;;
  esac
done

# The command, as a script in the shared directory (quoted so arguments survive).
{
  echo "#!/bin/bash"
  echo "cd $(printf '%q' "$PWD") 2>/dev/null || cd /"
  echo 'export HOME=/tmp LANG=C.UTF-8'
  printf 'export PATH=%q\n' "$PATH"
  for v in $(compgen -e | grep -E '^(NCCOMP_|GTEST_|ASAN_|UBSAN_|TSAN_)' || true); do
    printf 'export %s=%q\n' "$v" "${!v}"
  done
  printf '%q ' "$@"
  echo
  echo 'rc=$?'
  printf 'echo $rc > %q\n' "$workdir/exit_status"
  echo 'exit $rc'
} >"$workdir/vm_cmd.sh"
chmod +x "$workdir/vm_cmd.sh"

accel=${NCCOMP_VM_ACCEL:-tcg}
cpu_opt=()
if [ "$accel" = "kvm" ]; then
  cpu_opt=(-cpu host)
else
  accel="tcg,thread=multi"
  cpu_opt=(-cpu max)
fi
timeout_s=${NCCOMP_VM_TIMEOUT_S:-600}
echo "run_in_vm: booting kernel $kver under qemu ($accel), timeout ${timeout_s}s"
start=$(date +%s)
set +e
# stdin from /dev/null: under ctest there is no terminal, and qemu must never wait on one.
timeout --kill-after=10 "$timeout_s" qemu-system-x86_64 \
  -accel "$accel" "${cpu_opt[@]}" -m "${NCCOMP_VM_MEM_MB:-1024}" -smp "${NCCOMP_VM_SMP:-2}" \
  -nodefaults -no-reboot -display none -serial stdio \
  -kernel "/boot/vmlinuz-$kver" -initrd "$initrd" \
  -append "console=ttyS0 quiet loglevel=3 panic=-1 nccomp.out=$workdir nccomp.expose=$expose" \
  -virtfs local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap \
  -virtfs "local,path=$workdir,mount_tag=out,security_model=none,multidevs=remap" \
  </dev/null 2>&1 | tee "$workdir/console.log"
qemu_rc=${PIPESTATUS[0]}
set -e
echo "run_in_vm: VM finished after $(( $(date +%s) - start )) s (qemu status $qemu_rc)"

rc=$(sed -n 's/.*NCCOMP_VM_EXIT=\([0-9]*\).*/\1/p' "$workdir/console.log" | tail -1)
if [ -z "$rc" ]; then
  if [ "$qemu_rc" = 124 ] || [ "$qemu_rc" = 137 ]; then
    echo "run_in_vm: VM timed out after ${timeout_s}s" >&2
  else
    echo "run_in_vm: VM ended without reporting an exit status" >&2
  fi
  exit 125
fi
exit "$rc"
