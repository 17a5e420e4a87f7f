#!/usr/bin/env bash
# Runs tests/vm inside a QEMU guest that loads the kernel's own virtual camera driver (vivid),
# so the V4L2 driver is tested against real /dev/video nodes, timestamps and sequence numbers.
#
#   bash tests/vm/run.sh            (uses .venv, as created by `make test`)
#
# The guest boots Debian's kernel (the package linux-image-amd64 depends on, unpacked into
# .vm/ with its modules, host untouched) under KVM when /dev/kvm can be opened, else under TCG
# (emulation, several times slower; STEREOD_VM_ACCEL=tcg forces it), with a ~1 MB busybox
# initramfs that mounts the host's root read-only over 9p and runs pytest in a chroot of it;
# results and the exit code come back through a second, writable 9p folder. The tests size
# their waits and counts from the pace they measure in the guest (tests/vm/conftest.py), so
# a loaded host makes them slower, not red; STEREOD_VM_TIMEOUT (s, default 540) bounds the run.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
CACHE="$ROOT/.vm"
PY="${PYTHON:-$ROOT/.venv/bin/python}"
TIMEOUT="${STEREOD_VM_TIMEOUT:-540}"

need=()
for cmd in qemu-system-x86_64 busybox modinfo depmod cpio; do
    command -v "$cmd" >/dev/null 2>&1 || need+=("$cmd")
done
if [ "${#need[@]}" -gt 0 ]; then
    echo "vm: installing qemu-system-x86 busybox-static kmod cpio (missing: ${need[*]})"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        qemu-system-x86 busybox-static kmod cpio >/dev/null
fi

pkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
if [ -z "$pkg" ]; then
    apt-get update -qq
    pkg=$(apt-cache depends linux-image-amd64 | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
fi
KV=${pkg#linux-image-}
KROOT="$CACHE/kernel/$KV"
if [ ! -f "$KROOT/boot/vmlinuz-$KV" ]; then
    echo "vm: fetching $pkg"
    mkdir -p "$CACHE/dl" "$KROOT"
    chmod 0777 "$CACHE/dl"  # apt downloads as its own user when it can
    (cd "$CACHE/dl" && apt-get download "$pkg" >/dev/null)
    dpkg-deb -x "$CACHE"/dl/"$pkg"_*.deb "$KROOT"
    depmod -b "$KROOT" "$KV"
    rm -f "$CACHE"/dl/"$pkg"_*.deb
fi

INITRD="$CACHE/initrd-$KV-$(sha256sum "$0" | cut -c1-12).gz"
if [ ! -f "$INITRD" ]; then
    work=$(mktemp -d)
    mkdir -p "$work"/{bin,mods,proc,sys,dev,host,out}
    cp "$(command -v busybox)" "$work/bin/busybox"
    # The 9p-over-virtio modules and what they need, dependencies first.
    declare -A seen=()
    order=()
    add() {
        local m=$1 d
        [ -n "${seen[$m]:-}" ] && return
        seen[$m]=1
        for d in $(modinfo -b "$KROOT" -k "$KV" -F depends "$m" | tr ',' ' '); do add "$d"; done
        order+=("$m")
    }
    for m in virtio_pci 9pnet_virtio 9p; do add "$m"; done
    for m in "${order[@]}"; do
        cp "$(modinfo -b "$KROOT" -k "$KV" -F filename "$m")" "$work/mods/$m.ko"
    done
    cat > "$work/init" <<INIT
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc; mount -t sysfs sysfs /sys; mount -t devtmpfs devtmpfs /dev
for m in ${order[*]}; do insmod /mods/\$m.ko; done
ip link set lo up
# cache=loose keeps what the guest read of the read-only host root (Python, its packages) in
# the guest's page cache: each Python start after the first costs no 9p round trips, which
# are slow under TCG.
mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=262144 host /host
mount -t 9p -o trans=virtio,version=9p2000.L out /out
: > /out/booted
for d in proc sys dev; do mount --bind /\$d /host/\$d; done
mkdir -p /host/dev/shm
mount -t tmpfs tmpfs /host/dev/shm
mount -t tmpfs tmpfs /host/mnt
mkdir -p /host/mnt/out
mount --bind /out /host/mnt/out
chroot /host /bin/sh /mnt/out/cmd > /out/log 2>&1
echo \$? > /out/rc
sync
poweroff -f
INIT
    chmod +x "$work/init"
    (cd "$work" && find . | cpio -o -H newc 2>/dev/null | gzip -1) > "$INITRD"
    rm -rf "$work"
fi

# KVM when /dev/kvm exists, this user can open it read-write and the guest boots under it
# (checked: the guest must reach its init within KVM_BOOT_S); TCG otherwise.
KVM_BOOT_S="${STEREOD_VM_KVM_BOOT_S:-30}"
ACCEL=tcg
why="no /dev/kvm"
if [ "${STEREOD_VM_ACCEL:-}" = tcg ]; then
    why="STEREOD_VM_ACCEL=tcg"
elif [ -e /dev/kvm ]; then
    if ! (exec 3<>/dev/kvm) 2>/dev/null; then
        why="/dev/kvm cannot be opened read-write by $(id -un)"
    elif [ -d /sys/module/kvm_pvm ]; then
        # A nested host's PVM (pagetable-based) KVM boots only kernels built as PVM guests:
        # Debian's hangs before its first console line.
        why="/dev/kvm is kvm_pvm, which does not boot Debian's kernel"
    else
        ACCEL=kvm
    fi
fi

OUT=$(mktemp -d)
qemu_pid=
trap '[ -n "$qemu_pid" ] && kill "$qemu_pid" 2>/dev/null; rm -rf "$OUT"' EXIT

# Starts the guest with accelerator $1 in the background (its pid in qemu_pid).
boot() {
    local cpu=max
    # Under KVM the host's CPU, less IA32_ARCH_CAPABILITIES: a nested KVM can refuse to set
    # that MSR, and QEMU then aborts before the guest starts.
    [ "$1" = kvm ] && cpu=host,-arch-capabilities
    rm -f "$OUT"/{booted,log,rc}
    cat > "$OUT/cmd" <<CMD
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
export HOME=/mnt TMPDIR=/mnt PYTHONDONTWRITEBYTECODE=1 VIVID_GUEST=1 VIVID_KERNEL="$KROOT"
export VIVID_ACCEL=$1 VIVID_BOOT_S=\$(cut -d' ' -f1 /proc/uptime)
cd "$ROOT"
"$PY" -m pytest -q -p no:cacheprovider --durations=0 tests/vm $ARGS
CMD
    timeout "$TIMEOUT" qemu-system-x86_64 -machine q35,accel="$1" -cpu "$cpu" -m 1536 -smp 2 \
        -nographic -no-reboot -kernel "$KROOT/boot/vmlinuz-$KV" -initrd "$INITRD" \
        -append "console=ttyS0 quiet panic=-1" \
        -fsdev local,id=host,path=/,security_model=none,readonly=on,multidevs=remap \
        -device virtio-9p-pci,fsdev=host,mount_tag=host \
        -fsdev local,id=out,path="$OUT",security_model=none \
        -device virtio-9p-pci,fsdev=out,mount_tag=out >"$OUT/console" 2>&1 &
    qemu_pid=$!
}
ARGS="$*"

# Byte-compiled here, once: the guest sees the tree read-only and would compile every module
# of the project at each Python start.
(cd "$ROOT" && "$PY" -m compileall -q stereod drivers fakes tests >/dev/null)

started=$(date +%s)
if [ "$ACCEL" = kvm ]; then
    echo "vm: booting $KV with KVM"
    boot kvm
    for _ in $(seq $((KVM_BOOT_S * 10))); do
        [ -f "$OUT/booted" ] || ! kill -0 "$qemu_pid" 2>/dev/null && break
        sleep 0.1
    done
    if [ ! -f "$OUT/booted" ]; then
        kill "$qemu_pid" 2>/dev/null || true
        wait "$qemu_pid" 2>/dev/null || true
        ACCEL=tcg
        why="the guest did not reach its init under KVM in STEREOD_VM_KVM_BOOT_S=$KVM_BOOT_S s"
        err=$(grep -a -m1 -i 'error' "$OUT/console" | tr -d '\r' || true)
        if [ -n "$err" ]; then why="$why: $err"; fi
    fi
fi
if [ "$ACCEL" = tcg ]; then
    echo "vm: booting $KV with TCG, emulated: several times slower ($why)"
    boot tcg
fi
status=0
wait "$qemu_pid" || status=$?
qemu_pid=
cat "$OUT/log" 2>/dev/null || true
echo "vm: the $ACCEL guest ran $(($(date +%s) - started)) s"
if [ ! -f "$OUT/rc" ]; then
    echo "vm: the guest did not finish in STEREOD_VM_TIMEOUT=$TIMEOUT s (qemu exit $status); console:"
    tail -30 "$OUT/console"
    exit 1
fi
exit "$(cat "$OUT/rc")"
