#!/usr/bin/env bash
# Runs the vcan scenarios on real SocketCAN interfaces inside a qemu guest.
#
# Why a VM: the development and CI machines run a kernel built without CAN, so
# `vcan` exists only in a guest booting Debian's stock kernel (which ships
# can.ko, can-raw.ko, vcan.ko, ... as modules). See docs/vcan-vm.md.
#
# What it does, in order: installs the Debian packages it needs (as root; as
# another user it says what to install and stops), builds the release binaries
# and the scenario test binaries (`--features vcan`), packs an initramfs with
# them, their libraries, busybox, can-utils and the CAN modules, boots the guest
# under a time limit, and parses the guest's console. Each scenario prints one
# `vcan-result:` line; the last line is the summary `vcan: N passed, M failed`.
# A guest that hangs, panics or prints no summary fails the run.
#
# Environment:
#   VCAN_VM_TIMEOUT_S   time limit for the whole guest run (default 540 s, plus any
#                       VCAN_LOAD_S beyond 30)
#   VCAN_SCENARIO_TIMEOUT_S  time limit per scenario inside the guest (default 150 s, plus
#                       any VCAN_LOAD_S beyond 30)
#   VCAN_FILTER         only scenarios whose name contains this text
#   VCAN_WORK_DIR       where the initramfs and console log go (default target/vcan-vm)
#   VCAN_LOAD_S         seconds of full bus load in the hostile-bus scenario (default 30;
#                       issue 8's live-cost figure is taken at 60), passed into the guest
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/.." && pwd)
work=${VCAN_WORK_DIR:-$root/target/vcan-vm}
filter=${VCAN_FILTER:-}
load_s=${VCAN_LOAD_S:-30}
case "$load_s" in
    ''|*[!0-9]*) load_s=0 ;;
    *) load_s=$(( 10#$load_s )) ;;  # '060' is sixty, not octal
esac
if [ "$load_s" -le 0 ]; then
    echo "vcan-vm: VCAN_LOAD_S must be a whole number of seconds above 0, not '${VCAN_LOAD_S}'" >&2
    exit 2
fi
# A longer load lengthens the hostile scenario, and with it the whole run.
extra_load_s=$(( load_s > 30 ? load_s - 30 : 0 ))
vm_timeout_s=${VCAN_VM_TIMEOUT_S:-$(( 540 + extra_load_s ))}
scenario_timeout_s=${VCAN_SCENARIO_TIMEOUT_S:-$(( 150 + extra_load_s ))}
packages=(qemu-system-x86 linux-image-amd64 busybox-static can-utils cpio)

say() { printf 'vcan-vm: %s\n' "$*" >&2; }
fail() { say "$*"; echo "vcan: 0 passed, 1 failed"; exit 1; }

started=$(date +%s)

# --- 1. packages -------------------------------------------------------------
missing=()
for pkg in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'install ok installed' || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" -eq 0 ]; then
        say "installing ${missing[*]} (about 1.5 minutes on a fresh machine)"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    else
        say "missing Debian packages: ${missing[*]}"
        say "install them with: sudo apt-get install -y --no-install-recommends ${missing[*]}"
        exit 2
    fi
fi

# The kernel version is found at run time: the newest one with both an image and modules.
kver=""
for dir in $(ls -1 /lib/modules 2>/dev/null | sort -V); do
    [ -f "/boot/vmlinuz-$dir" ] && [ -d "/lib/modules/$dir/kernel/net/can" ] && kver=$dir
done
[ -n "$kver" ] || fail "no kernel with CAN modules found under /boot and /lib/modules"
say "guest kernel $kver"

# --- 2. binaries --------------------------------------------------------------
cd "$root"
say "building release binaries and scenarios"
cargo build --release --quiet -p canodom
mapfile -t scenario_bins < <(
    cargo test --release --quiet -p canodom-vcan-tests --features vcan --no-run --message-format=json 2>/dev/null \
        | grep -o '"executable":"[^"]*"' | sed 's/"executable":"\(.*\)"/\1/'
)
[ ${#scenario_bins[@]} -gt 0 ] || fail "cargo built no scenario binary"
target_dir=$(cargo metadata --format-version 1 --no-deps | grep -o '"target_directory":"[^"]*"' | sed 's/.*:"\(.*\)"/\1/')

# --- 3. initramfs -------------------------------------------------------------
rm -rf "$work/root"
mkdir -p "$work/root"/{bin,sbin,lib,lib64,proc,sys,dev,tmp,scenarios,modules,work,etc}
initroot=$work/root

copy_with_libs() { # copy a program and every library ldd lists, at the same paths
    local prog=$1 dest=$2
    cp "$prog" "$initroot/$dest"
    ldd "$prog" 2>/dev/null | grep -o '/[^ ]*' | while read -r lib; do
        [ -f "$lib" ] || continue
        mkdir -p "$initroot$(dirname "$lib")"
        cp -L "$lib" "$initroot$lib"
    done
}

cp /bin/busybox "$initroot/bin/busybox"
for tool in candump cansend cangen canplayer cangw cansequence; do
    path=$(command -v "$tool" || true)
    [ -n "$path" ] && copy_with_libs "$path" "bin/$tool"
done
for bin in "$target_dir"/release/canodom; do
    [ -x "$bin" ] && copy_with_libs "$bin" "bin/$(basename "$bin")"
done
for bin in "${scenario_bins[@]}"; do
    name=$(basename "$bin" | sed 's/-[0-9a-f]\{16\}$//')
    copy_with_libs "$bin" "scenarios/$name"
done
# Fixtures the scenarios read (DBC files, example configs), at paths they can find.
mkdir -p "$initroot/work/main"
for dir in data/dbc protocol/dbc daemon/examples vcan-tests/fixtures; do
    [ -d "$root/$dir" ] && mkdir -p "$initroot/work/main/$dir" && cp -r "$root/$dir/." "$initroot/work/main/$dir/"
done

for mod in net/can/can.ko net/can/can-raw.ko net/can/can-gw.ko drivers/net/can/dev/can-dev.ko \
    drivers/net/can/vcan.ko drivers/net/can/vxcan.ko; do
    src=/lib/modules/$kver/kernel/$mod
    name=$(basename "$mod")
    if [ -f "$src" ]; then cp "$src" "$initroot/modules/$name"
    elif [ -f "$src.xz" ]; then xz -dc "$src.xz" >"$initroot/modules/$name"
    elif [ -f "$src.zst" ]; then zstd -qdc "$src.zst" >"$initroot/modules/$name"
    else fail "kernel module $mod not found for $kver"
    fi
done

cat >"$initroot/init" <<EOF
#!/bin/busybox sh
/bin/busybox --install -s /bin
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev; mount -t tmpfs tmp /tmp
for m in can can-raw can-dev vcan vxcan can-gw; do
    insmod /modules/\$m.ko || echo "vcan-vm: insmod \$m failed"
done
export HOME=/tmp PATH=/bin:/sbin CANODOM_BIN=/bin/canodom \
    CANODOM_REPO=/work/main VCAN_LOAD_S=$load_s RUST_BACKTRACE=0
echo "vcan-vm: guest up after \$(cut -d' ' -f1 /proc/uptime) s"
passed=0; failed=0
for bin in /scenarios/*; do
    for name in \$(\$bin --list --format terse 2>/dev/null | sed -n 's/: test\$//p'); do
        case "\$name" in *"$filter"*) ;; *) continue ;; esac
        # A fresh vcan0/vcan1 for every scenario, so no state leaks between them.
        for i in 0 1; do ip link del vcan\$i 2>/dev/null; ip link add dev vcan\$i type vcan && ip link set vcan\$i up; done
        t0=\$(cut -d' ' -f1 /proc/uptime)
        if timeout $scenario_timeout_s \$bin --exact "\$name" --test-threads=1 --nocapture >/tmp/out.txt 2>&1; then
            passed=\$((passed+1)); verdict=PASS
        else
            failed=\$((failed+1)); verdict=FAIL
            # The panic's message first: the tail below is often the logs a
            # scenario prints after it fails, which pushed the message out.
            grep -A6 'panicked at' /tmp/out.txt | head -n 24 | sed "s/^/  ! /"
            sed "s/^/  | /" /tmp/out.txt | tail -n 40
        fi
        # -o: libtest prints a test's name without a newline, so its first metric shares that line.
        grep -o 'vcan-metric:.*' /tmp/out.txt
        echo "vcan-result: \$name \$verdict (\$(awk -v a=\$t0 -v b=\$(cut -d' ' -f1 /proc/uptime) 'BEGIN{printf "%.1f", b-a}') s)"
    done
done
echo "vcan: \$passed passed, \$failed failed"
poweroff -f
EOF
chmod +x "$initroot/init"
(cd "$initroot" && find . | cpio -o -H newc --quiet | gzip -1) >"$work/initrd.gz"
say "initramfs $(du -h "$work/initrd.gz" | cut -f1), ${#scenario_bins[@]} scenario binaries"

# --- 4. boot ------------------------------------------------------------------
# KVM hangs at "Booting from ROM" on these machines: software emulation only.
say "booting the guest (time limit ${vm_timeout_s} s)"
boot_started=$(date +%s)
set +e
timeout "$vm_timeout_s" qemu-system-x86_64 -accel tcg -cpu max -m 1024 -smp 2 -nographic -no-reboot \
    -kernel "/boot/vmlinuz-$kver" -initrd "$work/initrd.gz" \
    -append "console=ttyS0 quiet panic=-1 loglevel=3" </dev/null >"$work/console.log" 2>&1
qemu_status=$?
set -e
# The serial console carries terminal resets and colour codes; strip them so
# the line prefixes the host parses start their lines.
tr -d '\r' <"$work/console.log" | sed -e 's/\x1b\[[0-9;?]*[A-Za-z]//g' -e 's/\x1bc//g' >"$work/console.txt"

grep -E '^(vcan-vm|vcan-result|vcan-metric|  \|)' "$work/console.txt" || true
summary=$(grep -E '^vcan: [0-9]+ passed, [0-9]+ failed$' "$work/console.txt" | tail -n 1 || true)
say "guest exited with status $qemu_status after $(($(date +%s) - boot_started)) s; whole run $(($(date +%s) - started)) s"
if [ -z "$summary" ]; then
    say "the guest printed no summary (hang, panic or time limit); last console lines:"
    tail -n 30 "$work/console.txt" >&2
    echo "vcan: 0 passed, 1 failed"
    exit 1
fi
echo "$summary"
passed=$(echo "$summary" | sed 's/vcan: \([0-9]*\) passed.*/\1/')
failed=$(echo "$summary" | sed 's/.* \([0-9]*\) failed/\1/')
[ "$failed" -eq 0 ] && [ "$passed" -gt 0 ]
