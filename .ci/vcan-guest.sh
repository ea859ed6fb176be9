#!/bin/sh
# Inside the virtual machine of .ci/vcan.sh: vcan0 on the guest's kernel, then the socketcan
# tests with a missing vcan0 a failure.  Usage: sh .ci/vcan-guest.sh PYTHON OUTDIR (OUTDIR holds
# `files`, the test files to run; the log, exit status and boot time are written there).
set -eu
py=$1
out=$2
cut -d' ' -f1 /proc/uptime > "$out/boot_s"
modprobe vcan
ip link add dev vcan0 type vcan
ip link set up vcan0
ip -details link show vcan0 | head -n 3
export SEA_DAEMON_REQUIRE_SOCKETCAN=1 NUMBA_CPU_NAME=generic MPLBACKEND=Agg
touch "$out/start"
set +e
{ "$py" -m pytest -q -rs --durations=5 -m socketcan -p no:cacheprovider $(cat "$out/files"); echo $? > "$out/rc"; } 2>&1 | tee "$out/pytest.log"
# the kernels load from numba's cache: one compiled here (minutes under emulation) is reported
echo "numba: $(find sea_daemon -name '*.nbc' -newer "$out/start" | wc -l) kernels compiled in the VM"
exit "$(cat "$out/rc")"
