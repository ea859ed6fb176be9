"""``sea-daemon bench can-cycle``: one CANopen cycle (RPDO, SYNC, TPDOs, decode) against the device model.

Measures, per cycle, ``hw.write(tau)`` + ``hw.read()`` of :class:`sea_daemon.hw.canopen_hw.CanopenHardware`
talking to the device model (lock-step, the simulator's plant) over a python-can virtual bus (both
in this process), the ipc bus (UNIX datagram sockets between the two handles, one hop) or
python-can-remote (server subprocess, device model in this process: each frame crosses the relay).  The
figure includes the device model's side (SYNC handling, TPDO build, one plant step) because the
read waits for its TPDOs; it is the round trip the fixed-rate loop pays each cycle.
"""
from __future__ import annotations

import dataclasses
import socket
import subprocess
import sys
import time
import uuid

import numpy as np

from sea_daemon.apps.bench import machine, summarize
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.runtime.rig import device_model_rig


def add_arguments(p) -> None:
    p.add_argument("--bus", choices=("virtual", "ipc", "remote"), default="virtual",
                   help="virtual: python-can in-process; ipc: UNIX datagram sockets (sea_daemon.hw.ipc_bus); remote: "
                        "python-can-remote's relay process (the difference to ipc is what the relay costs)")
    p.add_argument("--cycles", type=int, default=2000)


def remote_relay():
    """``python -m can_remote`` on a free local port (a virtual bus behind it): (process, its URL)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "can_remote", "-i", "virtual", "-c", "bench", "-H", "127.0.0.1",
                             "-p", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 15
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc, f"ws://127.0.0.1:{port}/"
        except OSError:
            if time.monotonic() > deadline:
                proc.kill()
                raise RuntimeError("python -m can_remote did not start")
            time.sleep(0.05)


def run(args) -> int:
    cfg = load_config(default_config_path())
    proc = None
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    if args.bus == "remote":
        proc, channel = remote_relay()
    b = dataclasses.replace(cfg.hardware.bus, interface=args.bus, channel=channel, pdo_timeout_ms=1000.0)
    cfg = dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))
    rig = device_model_rig(cfg, Plant(cfg, q0=0.3, seed=0))
    times = np.empty(args.cycles)
    try:
        rig.start_device_model()
        t0 = time.perf_counter()
        rig.hw.start()
        t_start = time.perf_counter() - t0
        tau = np.zeros(1)
        for k in range(args.cycles):
            tau[0] = 1.0 * np.sin(0.01 * k)
            t = time.perf_counter()
            rig.hw.write(tau)
            rig.hw.read()
            times[k] = time.perf_counter() - t
    finally:
        rig.stop()
        if proc is not None:
            proc.terminate()
            proc.wait(5)
    print(f"can-cycle on {machine()}")
    print(f"bus {args.bus}, device model lock-step with the simulator's plant (1 joint), {args.cycles} cycles")
    print(f"start-up (SDO checks, PDO mapping, heartbeats, CiA 402 enable): {t_start * 1e3:.1f} ms")
    print(f"cycle write+read: {summarize(times)}")
    print(f"budget at 100 Hz: 10000 us; cycles over 5000 us: {int(np.sum(times > 5e-3))}")
    return 0
