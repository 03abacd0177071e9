#!/bin/bash
# The VM for the CAN tests and bench on a real kernel (`make test-vcan`, `make bench-vcan`): Debian's
# own kernel booted by QEMU (software emulation: these machines have no usable KVM) with a busybox
# initramfs that loads the CAN modules and shares the host's root read-only over 9p. Adapted from
# the shared tools/vcan-vm (its REPORT.md measures it: boot about 7 s, Python about 12x slower
# than the host). Idempotent: a second run only rebuilds the initramfs (a second).
#
#   bash tests/vm/setup.sh        (root; apt-get and Debian's kernel package, about 90 MB once)
#
# Everything goes under $VM_DIR (default build/vm): vmlinuz, the modules, initramfs.cpio.gz.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
W=${VM_DIR:-$HERE/../../build/vm}
mkdir -p "$W"
W=$(cd "$W" && pwd)
[ "$(id -u)" = 0 ] || { echo "vm setup: needs root (apt-get, depmod)" >&2; exit 2; }

PKGS=(qemu-system-x86 busybox-static can-utils kmod iproute2)
missing=()
for p in "${PKGS[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
        || { apt-get update -qq && apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null; }
fi

# Debian's kernel: the package linux-image-amd64 depends on, unpacked (not installed).
KPKG=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
KVER=${KPKG#linux-image-}
MODS="virtio_pci 9p 9pnet_virtio vcan can-raw"
if [ ! -f "$W/kroot/boot/vmlinuz-$KVER" ] || [ ! -s "$W/mods/order" ] || [ "$(cat "$W/kernel-version" 2>/dev/null)" != "$KVER" ]; then
    rm -rf "$W/kroot" "$W/mods" "$W"/linux-image-*.deb
    (cd "$W" && apt-get download -qq "$KPKG")
    dpkg-deb -x "$W"/"$KPKG"_*.deb "$W/kroot"
    rm -f "$W"/"$KPKG"_*.deb
    depmod -b "$W/kroot" "$KVER"
    mkdir -p "$W/mods"
    for m in $MODS; do
        modprobe -d "$W/kroot" -S "$KVER" --show-depends "$m" | awk '$1=="insmod"{print $2}'
    done | awk '!seen[$0]++' | while read -r ko; do
        cp "$ko" "$W/mods/"; basename "$ko" >> "$W/mods/order"
    done
    rm -rf "$W/kroot/lib" "$W/kroot/usr"  # only vmlinuz and the modules copied above are needed
    echo "$KVER" > "$W/kernel-version"
fi
ln -sfn "kroot/boot/vmlinuz-$KVER" "$W/vmlinuz"

R=$(mktemp -d)
mkdir -p "$R"/{bin,dev,proc,sys,host}
cp /bin/busybox "$R/bin/busybox"
cp -r "$W/mods" "$R/modules"
cp "$HERE/init.sh" "$R/init"
chmod +x "$R/init"
(cd "$R" && find . | busybox cpio -o -H newc 2>/dev/null | gzip -1 > "$W/initramfs.cpio.gz")
rm -rf "$R"
echo "vm setup: kernel $KVER, $W"
