"""What the reliability benchmarks add to the runtime's rig: a configuration, a controller, probes.

The daemon's own pieces — :class:`~sea_daemon.hw.canopen_hw.CanopenHardware`, the
:class:`~sea_daemon.runtime.loop.FixedRateLoop` and its :class:`SafetySupervisor` — run
against the device model (:mod:`sea_daemon.hw.device_model`, the simulator's true plant behind a
CiA 402 drive and a CiA 406 load encoder) on one python-can ``virtual`` channel: the runtime's
:class:`~sea_daemon.runtime.rig.Rig` (:func:`bench_rig`).  The controller is a PID (the
simulator's, motor-velocity damping) tracking a slow sine (:class:`SineTracker`), so the arm
moves and every encoder has something to show.

Bus listeners of their own: :class:`HeartbeatSniffer` (when each node's heartbeat was last
seen), :class:`FrameCounter` (frames and bits on the bus).

:class:`DriveProbe` observes, at the device, the torque that reaches the arm: it waits until
the device has processed every frame the driver sent (a frame-count barrier), then reads the
drive's state machine and target torque 0x6071 — the torque the drive applies from now on is
0x6071 when OPERATION_ENABLED in CST, else zero (quick stop, fault, disabled).  Not for
production: it slows each cycle by the barrier.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
import uuid

import can
import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.core.control import PID
from sea_daemon.core.sim.plant import Plant
from sea_daemon.hw import cia402
from sea_daemon.hw.bus import frame_bits
from sea_daemon.hw.canopen_rx import arrival
from sea_daemon.hw.interface import HardwareInterface
from sea_daemon.io.configfile import default_config_path, load_config
from sea_daemon.runtime.rig import Rig, device_model_rig


def bench_config(**bus) -> ModelConfig:
    """Default exoskeleton config on a fresh virtual channel, bus keys overridden."""
    cfg = load_config(default_config_path())
    b = dataclasses.replace(cfg.hardware.bus, interface="virtual", channel=f"bench-{uuid.uuid4().hex[:8]}", **bus)
    return dataclasses.replace(cfg, hardware=dataclasses.replace(cfg.hardware, bus=b))


class SineTracker:
    """Loop controller: PID on q tracking q0 + A sin(2π f t), gravity feed-forward, clipped."""

    def __init__(self, cfg: ModelConfig, q0: float = 0.6, amplitude: float = 0.4, freq_hz: float = 0.25):
        self.q0, self.A, self.w = q0, amplitude, 2 * math.pi * freq_hz
        self.g = float(np.atleast_1d(cfg.model.gravity)[0])
        self.pid = PID(40.0, 80.0, 2.0, cfg.dt, cfg.hardware.torque_limit, derivative="motor")
        self.limit = cfg.hardware.torque_limit
        self._out = np.zeros(cfg.joints)

    def update(self, t, q, theta_m, est):
        ref = self.q0 + self.A * math.sin(self.w * t)
        dref = self.A * self.w * math.cos(self.w * t)
        u = self.pid.step(ref, q, dref, theta_m) + self.g * math.sin(ref)
        np.clip(u, -self.limit, self.limit, out=self._out)
        return self._out


def bench_rig(cfg: ModelConfig, q0: float = 0.6) -> Rig:
    """The benchmarks' rig, started: the simulator's plant at rest at ``q0`` (no torque noise)
    behind the device model (lock-step) and the driver (:func:`~sea_daemon.runtime.rig.device_model_rig`),
    primed with zero torque."""
    rig = device_model_rig(cfg, Plant(cfg, q0=q0, seed=0, torque_noise=0.0))
    try:
        rig.start()
    except BaseException:
        rig.stop()
        raise
    return rig


class _BusListener:
    """A listener of its own on a bus handle (a python-can Notifier thread calling ``_on_frame``);
    ``close()`` stops it and shuts the bus."""

    def __init__(self, bus: can.BusABC):
        self.bus = bus
        self._notifier = can.Notifier(bus, [self._on_frame], timeout=0.05)

    def _on_frame(self, msg: can.Message) -> None:
        raise NotImplementedError

    def close(self) -> None:
        self._notifier.stop(1.0)
        self.bus.shutdown()


class HeartbeatSniffer(_BusListener):
    """The monotonic time each node's heartbeat last arrived on the bus: ``hb_seen[node]``
    (dated by the frame's timestamp, as the driver dates it: :func:`sea_daemon.hw.canopen_rx.arrival`),
    and the longest time between two of its heartbeats since the caller last cleared it:
    ``hb_gap_max[node]``."""

    def __init__(self, bus: can.BusABC):
        self.hb_seen: dict[int, float] = {}
        self.hb_gap_max: dict[int, float] = {}
        super().__init__(bus)

    def _on_frame(self, msg: can.Message) -> None:
        if 0x701 <= msg.arbitration_id <= 0x77F and not msg.is_error_frame:
            node = msg.arbitration_id - 0x700
            t = arrival(time.monotonic(), msg.timestamp)
            if node in self.hb_seen:
                self.hb_gap_max[node] = max(self.hb_gap_max.get(node, 0.0), t - self.hb_seen[node])
            self.hb_seen[node] = t


class FrameCounter(_BusListener):
    """Counts the frames on the bus and their bits (:func:`sea_daemon.hw.bus.frame_bits`)."""

    def __init__(self, bus: can.BusABC):
        self.frames = 0
        self.bits_typ = 0
        self.bits_worst = 0
        super().__init__(bus)

    def _on_frame(self, msg: can.Message) -> None:
        self.frames += 1
        self.bits_typ += frame_bits(msg.dlc, stuffing="none")
        self.bits_worst += frame_bits(msg.dlc, stuffing="worst")

    def snapshot(self) -> tuple[int, int, int]:
        return self.frames, self.bits_typ, self.bits_worst


class DriveProbe(HardwareInterface):
    """Hardware wrapper for the loop: before each ``read()`` it records the torque the drive
    applies after the previous cycle (``applied[k]`` for the interval after cycle k).

    ``start``/``write``/``safe_stop``/``stop`` go to the rig's driver; ``actuated`` keeps the
    interface's default (the commanded torque)."""

    def __init__(self, rig: Rig, cycles: int, barrier_timeout: float = 1.0):
        self.rig, self.hw = rig, rig.hw
        self.n, self.period, self.actuation_delay = rig.hw.n, rig.hw.period, rig.hw.actuation_delay
        self.applied = np.full(cycles + 1, np.nan)      # per mille reaching the arm after cycle k
        self.enabled = np.zeros(cycles + 1, dtype=bool)  # drive in OPERATION_ENABLED after cycle k
        self.read_t = np.zeros(cycles + 1)               # time.monotonic() at the entry of read() of cycle k
        self.k = 0
        self.barrier_timeout = barrier_timeout
        self.barrier_misses = 0
        self._sent = 0
        self._recv = 0
        self._lock = threading.Lock()
        bus = rig.drv_bus
        orig_send = bus.send

        def send(msg, timeout=None):
            orig_send(msg, timeout)
            with self._lock:
                self._sent += 1
        bus.send = send
        net = rig.device_model.network
        orig_notify = net.notify

        def notify(can_id, data, timestamp):
            try:
                orig_notify(can_id, data, timestamp)
            finally:
                with self._lock:
                    self._recv += 1
        net.notify = notify
        self.reset_error: BaseException | None = None
        self.reset_failures: list[str] = []
        self.fail_sends = 0                 # injected send failures still to come
        self._orig_send = send

        def maybe_fail(msg, timeout=None):
            if self.fail_sends > 0:
                self.fail_sends -= 1
                raise can.CanOperationError("Transmit buffer full (injected)")
            send(msg, timeout)
        bus.send = maybe_fail

    def settle(self) -> bool:
        """Wait until the device has processed every frame the driver sent."""
        deadline = time.monotonic() + self.barrier_timeout
        while True:
            with self._lock:
                if self._recv >= self._sent:
                    return True
            if time.monotonic() > deadline:
                self.barrier_misses += 1
                return False
            time.sleep(0.0001)

    def observe(self, k: int) -> None:
        self.settle()
        d = self.rig.drive
        on = d.sm.torque_enabled and d.mode == cia402.MODE_CST
        self.enabled[k] = d.sm.state is cia402.State.OPERATION_ENABLED
        self.applied[k] = d.target_permille if on else 0

    # --------------------------------------------------------------- HardwareInterface
    def start(self, initial_torque=None):
        self.hw.start(initial_torque)

    def stop(self):
        self.hw.stop()

    def read(self):
        if self.reset_error is not None:
            # the operator reset failed: the fault it was meant to clear is still there;
            # report it in the cycle (the loop latches it) instead of dying in the reset path
            e, self.reset_error = self.reset_error, None
            self.reset_failures.append(f"{type(e).__name__}: {e}")
            raise e
        k = self.k
        if k > 0 and k - 1 < len(self.applied):
            self.observe(k - 1)
        if k < len(self.read_t):
            self.read_t[k] = time.monotonic()
        self.k += 1
        return self.hw.read()

    def write(self, tau):
        self.hw.write(tau)

    def safe_stop(self):
        self.hw.safe_stop()

    def reset_fault(self):
        try:
            self.hw.reset_fault()
        except Exception as e:  # noqa: BLE001 - see read()
            self.reset_error = e


class VirtualClock:
    """The loop's clock in lock-step runs: advances only by the loop's sleeps and injected stalls."""

    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        if s > 0:
            self.t += s


def vm_rss_kb(pid: int | str = "self") -> int:
    """Resident set size [kB] from /proc/PID/status (VmRSS)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1
