#!/bin/bash
# `make test-arm` (ARCH=aarch64) and `make test-bundle ARCH=x86_64`: the gateway bundle installed
# and run in a Debian root of that architecture, built from Debian's packages, with no network.
#
#   bash tests/bundle/in_debian_root.sh ARCH BUNDLE.tar.gz FAULT.csv
#
# The root (debootstrap --variant=minbase, python3 only) is built once and cached in
# build/debian-<suite>-<arch>/ (a second run starts at the install); an arm64 root runs under
# qemu-user-static, registered with binfmt_misc. Each run removes what an install puts there
# (/opt/bogiemon, /etc/bogiemon, /var/lib/bogiemon) and runs tests/bundle/inside.sh in the root:
# chroot, in a network namespace of its own (unshare -n: a loopback that is down, no route, no
# DNS), with /proc mounted. Root only (debootstrap, chroot, unshare, binfmt_misc).
set -euo pipefail
ARCH=$1 BUNDLE=$2 FAULT=$3
SUITE=${DEBIAN_SUITE:-bookworm}
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
REPO=$(cd "$(dirname "$0")/../.." && pwd)
case "$ARCH" in
    aarch64) DEBARCH=arm64 ;;
    x86_64) DEBARCH=amd64 ;;
    *) echo "in_debian_root: unknown architecture '$ARCH' (aarch64 or x86_64)" >&2; exit 2 ;;
esac
ROOT=$REPO/build/debian-$SUITE-$ARCH
ts() { date +%s.%N; }
el() { awk "BEGIN{printf \"%.1f\", $(ts) - $1}"; }
[ "$(id -u)" = 0 ] || { echo "in_debian_root: needs root (debootstrap, chroot, unshare)" >&2; exit 2; }

need=()
command -v debootstrap >/dev/null || need+=(debootstrap)
if [ "$ARCH" != "$(uname -m)" ]; then
    command -v qemu-aarch64-static >/dev/null || need+=(qemu-user-static binfmt-support)
fi
if [ ${#need[@]} -gt 0 ]; then
    echo "in_debian_root: apt-get install ${need[*]}"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null \
        || { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null; }
fi
if [ "$ARCH" != "$(uname -m)" ]; then
    [ -e /proc/sys/fs/binfmt_misc/register ] || mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
    [ -e /proc/sys/fs/binfmt_misc/"qemu-$ARCH" ] || update-binfmts --enable "qemu-$ARCH"
    [ -e /proc/sys/fs/binfmt_misc/"qemu-$ARCH" ] || { echo "in_debian_root: qemu-$ARCH is not registered with binfmt_misc" >&2; exit 2; }
fi

t=$(ts)
if [ ! -f "$ROOT/.bogiemon-root-complete" ]; then
    rm -rf "$ROOT"
    echo "in_debian_root: debootstrap $SUITE $DEBARCH into $ROOT (once; a few minutes)"
    debootstrap --arch="$DEBARCH" --variant=minbase --include=python3 "$SUITE" "$ROOT" "$MIRROR" > "$ROOT.log" 2>&1 \
        || { tail -20 "$ROOT.log" >&2; echo "in_debian_root: debootstrap failed ($ROOT.log)" >&2; exit 1; }
    touch "$ROOT/.bogiemon-root-complete"
    echo "in_debian_root: the $SUITE $DEBARCH root took $(el "$t") s to build"
else
    echo "in_debian_root: the cached $SUITE $DEBARCH root ($ROOT)"
fi

rm -rf "$ROOT/opt/bogiemon" "$ROOT/etc/bogiemon" "$ROOT/var/lib/bogiemon" "$ROOT/var/lib/private/bogiemon" "$ROOT/tmp/bogiemon-test"
mkdir -p "$ROOT/tmp/bogiemon-test"
cp "$BUNDLE" "$FAULT" "$REPO/tests/bundle/inside.sh" "$REPO/bogiemon/config/demo_calibration.toml" "$ROOT/tmp/bogiemon-test/"
t=$(ts)
# A gateway's environment, not this machine's: no PIP_* variable, no venv, no PYTHONPATH.
unshare --mount --net env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8 \
    /bin/sh -c "mount -t proc proc '$ROOT/proc' && exec chroot '$ROOT' /bin/sh /tmp/bogiemon-test/inside.sh '$(basename "$BUNDLE")' '$(basename "$FAULT")'"
echo "in_debian_root: PASS: $SUITE $DEBARCH, $(el "$t") s in the root"
