#!/bin/bash
# Run one command in the CAN VM (tests/vm/setup.sh first): as root, chrooted into the host's root
# (read-only; /tmp a fresh tmpfs), vcan0 up. The exit status is the command's.
#
#   bash tests/vm/run.sh 'COMMAND'      (under ~1.3 KB: it travels on the kernel command line)
#
# env: VM_DIR (build/vm), VM_OUT (a host folder mounted read-write at the same path inside),
#      VM_CPUS (2), VM_MEM (1G), VM_TIMEOUT (seconds, 1800). The VM has no network device.
set -u
HERE=$(cd "$(dirname "$0")" && pwd)
W=${VM_DIR:-$HERE/../../build/vm}
CMD="$*"
[ -n "$CMD" ] || { echo "usage: $0 'command'" >&2; exit 2; }
[ -f "$W/initramfs.cpio.gz" ] || { echo "vm: run tests/vm/setup.sh first (as root)" >&2; exit 2; }
OUT=${VM_OUT:-}
RCF=$(mktemp); LOG=$(mktemp)
trap 'rm -f "$RCF" "$LOG"' EXIT
# shellcheck disable=SC2054  # QEMU options are comma-separated lists, one word each
FS=(-fsdev local,id=hr,path=/,security_model=none,readonly=on,multidevs=remap -device virtio-9p-pci,fsdev=hr,mount_tag=hostroot)
if [ -n "$OUT" ]; then
    mkdir -p "$OUT"; OUT=$(cd "$OUT" && pwd)
    # shellcheck disable=SC2054
    FS+=(-fsdev local,id=vo,path="$OUT",security_model=none -device virtio-9p-pci,fsdev=vo,mount_tag=vmout)
fi
B64=$(printf %s "$CMD" | base64 -w0)
[ ${#B64} -le 1800 ] || { echo "vm: the command is too long for the kernel command line: put it in a script" >&2; exit 2; }
# q35 with qboot (SeaBIOS is slower; -machine microvm hangs under TCG calibrating the TSC).
timeout "${VM_TIMEOUT:-1800}" qemu-system-x86_64 -accel tcg,thread=multi,tb-size=256 -cpu max \
    -machine q35 -bios /usr/share/qemu/qboot.rom -smp "${VM_CPUS:-2}" -m "${VM_MEM:-1G}" \
    -nodefaults -no-user-config -nic none -display none -monitor none -no-reboot \
    -chardev file,id=con,path=/proc/self/fd/1 -serial chardev:con -serial file:"$RCF" "${FS[@]}" \
    -kernel "$W/vmlinuz" -initrd "$W/initramfs.cpio.gz" \
    -append "console=ttyS0 quiet loglevel=3 panic=-1 vm.cmd=$B64 vm.out=$OUT" </dev/null | tee "$LOG"
qemu_rc=${PIPESTATUS[0]}
rc=$(tr -dc '0-9' < "$RCF")
[ -n "$rc" ] || rc=$(sed -n 's/^vm init: the command exited \([0-9]*\).*/\1/p' "$LOG" | tail -1)
[ -n "$rc" ] || { echo "vm: no exit status from the VM (qemu $qemu_rc)" >&2; exit 98; }
exit "$rc"
