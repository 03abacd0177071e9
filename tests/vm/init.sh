#!/bin/busybox sh
# /init of the VM's initramfs (tests/vm/setup.sh): loads the virtio, 9p and CAN modules, mounts the
# host's root read-only at /host with a fresh tmpfs /tmp, creates vcan0 (up, MTU 16: classical CAN
# frames), runs the command of the kernel command line (vm.cmd=, base64) in `chroot /host` and
# writes its exit status to the second serial port. vm.out= names a host folder shared read-write.
/bin/busybox mkdir -p /bin /sbin /usr/bin /usr/sbin
/bin/busybox --install -s
export PATH=/bin:/sbin:/usr/bin:/usr/sbin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev
for m in $(cat /modules/order); do insmod "/modules/$m" || echo "vm init: insmod $m failed"; done
CMD=""; OUT=""
for a in $(cat /proc/cmdline); do
    case "$a" in
        vm.cmd=*) CMD=$(echo "${a#vm.cmd=}" | base64 -d) ;;
        vm.out=*) OUT="${a#vm.out=}" ;;
    esac
done
mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=512000 hostroot /host \
    || { echo "vm init: cannot mount the host's root"; echo 99 > /dev/ttyS1; poweroff -f; }
mount -t tmpfs -o mode=1777 tmpfs /host/tmp
mount -t tmpfs tmpfs /host/run
mount -t proc proc /host/proc
mount -t sysfs sysfs /host/sys
mount -t devtmpfs devtmpfs /host/dev
mkdir -p /host/dev/pts /host/dev/shm
mount -t devpts devpts /host/dev/pts
mount -t tmpfs tmpfs /host/dev/shm
[ -n "$OUT" ] && mkdir -p "/host$OUT" && mount -t 9p -o trans=virtio,version=9p2000.L vmout "/host$OUT"
ip link set lo up
ip link add dev vcan0 type vcan && ip link set vcan0 mtu 16 && ip link set up vcan0
echo "vm init: uptime $(cut -d' ' -f1 /proc/uptime) s, running the command"
HOME=/root TERM=dumb chroot /host /bin/sh -c "$CMD"
rc=$?
echo "vm init: the command exited $rc at uptime $(cut -d' ' -f1 /proc/uptime) s"
echo "$rc" > /dev/ttyS1
sync
poweroff -f
