"""HIL across processes: python-can-remote server, device model process, driver in this process.

Where the kernel has no SocketCAN this is how separate processes share a CAN bus: a
``python -m can_remote`` server bridges a virtual bus over websockets on 127.0.0.1; the device
model (``sea-daemon device-model --bus remote``) and the driver join it as clients.
"""
from __future__ import annotations

import importlib.util
import os
import queue
import subprocess
import sys
import threading

import numpy as np
import pytest

from _hil import RemoteServer, hil_config
from sea_daemon.hw.canopen_hw import CanopenHardware
from sea_daemon.hw.errors import EncoderJump
from _paths import repo_root



def _have_simulator() -> bool:
    try:
        return importlib.util.find_spec("sea_daemon.core.sim.plant") is not None
    except ModuleNotFoundError:
        return False


pytestmark = pytest.mark.skipif(not _have_simulator(),
                                reason="the device-model process needs the simulator's Plant (sea_daemon.core.sim)")


class DeviceProcess:
    """``python -m sea_daemon device-model`` in a child process on ``bus`` (remote by default) and
    ``channel``; bounded start and clean-up."""

    def __init__(self, channel: str, *args: str, bus: str = "remote", duration: float = 120.0, ready_s: float = 30.0):
        env = dict(os.environ, PYTHONPATH=str(repo_root()) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-m", "sea_daemon", "device-model", "--bus", bus,
                                      "--channel", channel, "--duration", str(duration), *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [lines.put(x) for x in self.proc.stdout], daemon=True).start()
        try:
            line = lines.get(timeout=ready_s)
        except queue.Empty:
            line = ""
        if "device-model ready" not in line:
            self.close()
            raise RuntimeError(f"device model did not start: {line!r} {self.proc.stderr.read()[-2000:]}")

    def close(self) -> int:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return self.proc.returncode


@pytest.fixture
def remote_pair():
    server = RemoteServer()
    procs = []

    def start(*args):
        procs.append(DeviceProcess(server.url, *args))
        return server.url
    try:
        yield start
    finally:
        codes = [p.close() for p in procs]
        server.close()
        assert all(c == 0 for c in codes), f"device-model exit codes {codes}"


def test_two_processes_over_python_can_remote(remote_pair):
    url = remote_pair("--q0", "0.4", "--fault", "jump:target=encoder,rad=0.5,at=0.6")
    cfg = hil_config("remote", channel=url)
    hw = CanopenHardware(cfg)                   # opens its own remote bus from the config
    try:
        hw.start()
        q0 = hw.meas.q[0]
        assert q0 == pytest.approx(0.4, abs=0.05)
        qs, taus = [], []
        with pytest.raises(EncoderJump, match=r"node 2: 0x6004 load position value jumped \+0\.50\d\d rad") as e:
            for k in range(200):
                m = hw.read()
                qs.append(m.q[0])
                taus.append(m.tau_m_applied[0])
                hw.write(np.array([1.5 + 0.5 * np.sin(0.2 * k)]))
        # the fault was scheduled at device time 0.6 s = the 60th SYNC after the priming one
        assert e.value.cycle == pytest.approx(60, abs=1)
        assert np.ptp(qs) > 1e-3                                      # the remote plant moves
        assert max(abs(t) for t in taus[3:]) > 0.9                    # and gets our torque (0x6077)
    finally:
        hw.stop()
