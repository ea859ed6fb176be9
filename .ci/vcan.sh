#!/usr/bin/env bash
# SocketCAN on a real kernel: boots Debian's kernel in a QEMU virtual machine (virtme-ng) that
# sees this machine's file system, creates vcan0 there and runs every test marked `socketcan`
# (.ci/vcan-guest.sh), the daemon's calibrate and run on vcan0 among them.  Installs what it
# needs (Debian packages, virtme-ng from PyPI; nothing when they are there already): run it as
# root on Debian.  No KVM needed (TCG emulation; VCAN_KVM=1 uses KVM where it works).
# Fails when a test fails, is skipped in the virtual machine, or is missing from its run.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)

need=()
for p in qemu-system-x86 linux-image-amd64 busybox-static iproute2 kmod; do
    dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if ((${#need[@]})); then
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${need[@]}"
fi
python -m pip show virtme-ng >/dev/null 2>&1 || python -m pip install --quiet virtme-ng
py=$(python -c 'import sys; print(sys.executable)')
vng=$(dirname "$py")/vng
[ -x "$vng" ] || vng=$(command -v vng)
kernel=$(ls -1 /boot/vmlinuz-*-amd64 | sort -V | tail -n 1)

# numba's cache entries are per CPU: the guest runs on QEMU's CPU and loads the entries compiled
# for the generic x86-64 one, compiled here natively beside the host's (no recompilation in the VM)
# (of this checkout's package, whichever one is installed)
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
NUMBA_CPU_NAME=generic python .ci/compile.py 0 2 & first=$!
NUMBA_CPU_NAME=generic python .ci/compile.py 1 2
wait "$first"

# the guest's /tmp is its own: what it reports goes to a directory of the checkout
mkdir -p out
out=$(mktemp -d "$PWD/out/vcan.XXXXXX")
python -m pytest -q --collect-only -m socketcan tests/ | grep '::' > "$out/ids"
expected=$(wc -l < "$out/ids")
cut -d: -f1 "$out/ids" | sort -u > "$out/files"
t1=$(date +%s)
echo "vcan: ${expected} socketcan tests; booting $(basename "$kernel") under QEMU ($(( t1 - t0 )) s of set-up)"

accel=(--disable-kvm)
[ "${VCAN_KVM:-0}" = 1 ] && accel=()
# through a pipe: QEMU opens its standard output anew, which would truncate a log file
{ rc=0; timeout 2400 "$vng" --run "$kernel" "${accel[@]}" --memory 4G --cpus 2 --rw --cwd "$PWD" \
    --exec "sh .ci/vcan-guest.sh '$py' '$out'" || rc=$?; echo "$rc" > "$out/vng_rc"; } 2>&1 | cat
rc=$(cat "$out/vng_rc")
t2=$(date +%s)

summary=$(tail -n 1 "$out/pytest.log" 2>/dev/null || true)
boot=$(cat "$out/boot_s" 2>/dev/null || echo '?')
echo "vcan: in the VM: ${summary:-no test summary}; boot ${boot} s, VM total $(( t2 - t1 )) s"
passed=$(sed -n 's/^\([0-9]*\) passed.*/\1/p' <<< "$summary")
if [ "$rc" != 0 ] || [ "$(cat "$out/rc" 2>/dev/null)" != 0 ]; then
    echo "vcan: FAILED (vng exit $rc, pytest exit $(cat "$out/rc" 2>/dev/null || echo none))" >&2
    exit 1
fi
if grep -Eq 'skipped|failed|error' <<< "$summary" || [ "${passed:-0}" != "$expected" ]; then
    echo "vcan: FAILED: ${passed:-0} of ${expected} socketcan tests passed in the VM, none may be skipped" >&2
    exit 1
fi
rm -rf "$out"
