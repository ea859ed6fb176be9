"""HIL test rig: the CANopen driver against the device model on a real python-can bus.

Bus kinds: ``virtual`` (python-can, in-process), ``ipc`` (:mod:`sea_daemon.hw.ipc_bus`, UNIX datagram
sockets), ``remote`` (python-can-remote: a
``python -m can_remote`` server subprocess, both sides join over websockets) and ``socketcan``
(``vcan0``, skipped with the reason when the kernel has none; marked ``socketcan``, and with
``SEA_DAEMON_REQUIRE_SOCKETCAN=1`` a missing ``vcan0`` fails instead of skipping).  The device model's physics is
the simulator's true plant (:class:`sea_daemon.core.sim.plant.Plant`), recording its steps.
"""
from __future__ import annotations

import dataclasses
import os
import socket
import subprocess
import sys
import time
import uuid

import numpy as np
import pytest

from sea_daemon.hw.bus import socketcan_available
from sea_daemon.core.config import ModelConfig
from sea_daemon.core.sim.plant import Plant
from sea_daemon.io.configfile import default_config_path, load_config, load_yaml
from sea_daemon.runtime.rig import Rig, device_model_rig

BUS_KINDS = ["virtual", "ipc", "remote", "socketcan"]

#: set to 1 where a SocketCAN ``vcan0`` must exist (the virtual machine of ``.ci/vcan.sh``):
#: its absence then fails the socketcan tests instead of skipping them
REQUIRE_SOCKETCAN = "SEA_DAEMON_REQUIRE_SOCKETCAN"


def need_socketcan(channel: str = "vcan0") -> None:
    """Skip the calling test, with the reason, when ``channel`` is no SocketCAN interface here;
    fail it instead when ``SEA_DAEMON_REQUIRE_SOCKETCAN=1``."""
    ok, why = socketcan_available(channel)
    if ok:
        return
    if os.environ.get(REQUIRE_SOCKETCAN, "") == "1":
        pytest.fail(f"socketcan: {why} ({REQUIRE_SOCKETCAN}=1)", pytrace=False)
    pytest.skip(f"socketcan: {why}")


class RecordingPlant(Plant):
    """The simulator's plant, remembering (t, tau_m, tau_h_act, q, theta_m) at the start of every step."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.steps = []

    def step(self, tau_m, dt, tau_h_act=0.0):
        self.steps.append((self.t, np.array(tau_m, dtype=float), np.array(tau_h_act, dtype=float),
                           self.q, self.theta_m))
        super().step(tau_m, dt, tau_h_act)


def true_config(joints: int = 1) -> ModelConfig:
    raw = load_yaml(default_config_path())
    if joints != 1:
        raw.update(joints=joints, estimator={}, learning={})
    return ModelConfig.from_dict(raw, f"exo_{joints}dof")


def recording_plant(q0=0.3, joints: int = 1) -> RecordingPlant:
    """The default exoskeleton at rest at q0 (motor holding it), without torque noise."""
    return RecordingPlant(true_config(joints), q0=q0, seed=0, torque_noise=0.0)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RemoteServer:
    """``python -m can_remote`` on a free local port (virtual bus behind it); bounded clean-up."""

    def __init__(self, channel: str = "hil"):
        self.port = free_port()
        self.url = f"ws://127.0.0.1:{self.port}/"
        self.proc = subprocess.Popen([sys.executable, "-m", "can_remote", "-i", "virtual", "-c", channel,
                                      "-H", "127.0.0.1", "-p", str(self.port)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 15
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                break
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.close()
                    raise RuntimeError("python -m can_remote did not start")
                time.sleep(0.05)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def hil_config(kind: str = "virtual", channel: str = "", **bus):
    """Default model config with a test bus section: fast heartbeats, and timeouts generous enough
    for a loaded 2-core machine (tests that measure a timeout set their own); the drives' RPDO
    deadline off (the tests read and write in their own order, not a loop's; the tests of the
    deadline set it)."""
    cfg = load_config(default_config_path())
    b = dataclasses.replace(cfg.hardware.bus, interface=kind, channel=channel or f"hil-{uuid.uuid4().hex[:8]}",
                            heartbeat_ms=20, heartbeat_timeout_ms=1000, pdo_timeout_ms=1000.0,
                            sdo_timeout_ms=2000, rpdo_timeout_ms=0)
    b = dataclasses.replace(b, **bus)
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))


def hil_rig(cfg, plant=None, position_preset: int = 0, lock_step: bool = True, tau_h_act=None) -> Rig:
    """Device model (stand-in plant, running) + CanopenHardware on two bus handles of one channel;
    the driver is not started (the tests start it)."""
    rig = device_model_rig(cfg, plant or recording_plant(0.3), position_preset=position_preset, lock_step=lock_step,
                           tau_h_act=tau_h_act)
    rig.start_device_model()
    return rig


@pytest.fixture(scope="module")
def remote_url():
    server = RemoteServer()
    try:
        yield server.url
    finally:
        server.close()


@pytest.fixture(params=[pytest.param(k, marks=pytest.mark.socketcan) if k == "socketcan" else k for k in BUS_KINDS])
def bus_kind(request):
    kind = request.param
    if kind == "socketcan":
        need_socketcan("vcan0")
    return kind


@pytest.fixture
def make_rig(bus_kind, request):
    """Factory: make_rig(plant=..., **bus_overrides) → started-up-able Rig; closed after the test."""
    rigs = []

    def factory(plant=None, position_preset=0, lock_step=True, tau_h_act=None, **bus):
        if bus_kind == "remote":
            bus.setdefault("channel", request.getfixturevalue("remote_url"))
        elif bus_kind == "socketcan":
            bus.setdefault("channel", "vcan0")
        rig = hil_rig(hil_config(bus_kind, **bus), plant, position_preset, lock_step, tau_h_act)
        rigs.append(rig)
        return rig

    yield factory
    for r in rigs:
        r.stop()
