"""Joints on several CAN buses: a :class:`~sea_daemon.hw.canopen_hw.CanopenHardware` per bus.

``hardware.bus.channel`` as a list names the bus of each joint (joints of one name share it:
a bus per joint, or per limb; docs/can.md "Bus load").  :class:`CanopenBuses` is one
:class:`~sea_daemon.hw.interface.HardwareInterface` over them: each bus has its own driver with
the devices of its joints, its SYNC, its TPDO window and the daemon's heartbeat (the drives of
every bus watch it).  ``read()`` sends every bus's SYNC first and then collects each bus's TPDOs
until its deadline, so the buses answer at once; a fault on any bus raises from ``read()`` as on
one bus.  While one bus starts up (its SDO sequences), the buses started before it keep sending
the daemon's heartbeat and taking their devices' (``keepalive``).
"""
from __future__ import annotations

import time

import can
import numpy as np

from sea_daemon.core.config import ModelConfig
from sea_daemon.hw.canopen_hw import CanopenHardware
from sea_daemon.hw.interface import HardwareInterface, Measurement


class CanopenBuses(HardwareInterface):
    """The joints of ``cfg`` on the buses of ``cfg.hardware.bus`` (:meth:`BusConfig.buses`);
    ``buses``: an open handle per channel (default: each driver opens its own)."""

    def __init__(self, cfg: ModelConfig, buses: dict[str, can.BusABC] | None = None, *,
                 period: float | None = None, pdo_timeout: float | None = None, clock=time.monotonic):
        b = cfg.hardware.bus
        self.cfg, self.bus_cfg = cfg, b
        self.n = cfg.joints
        self.joints = [js for _, js in b.buses()]
        self.subs = [CanopenHardware(cfg, (buses or {}).get(c), period=period, pdo_timeout=pdo_timeout,
                                     clock=clock, bus_cfg=b.for_joints(js, c), joints=js) for c, js in b.buses()]
        for s in self.subs:
            s.peer_keepalive = self._peers
        first = self.subs[0]
        self.period, self.actuation_delay, self.pdo_timeout = first.period, first.actuation_delay, first.pdo_timeout
        #: the missed-cycle tolerance (every bus's: one configuration)
        self.max_missed = self.stall_cycles = first.max_missed
        self.meas = Measurement(self.n)
        self._act = np.zeros(self.n)
        self._t_sync = [0.0] * len(self.subs)
        self._tau = [np.zeros(len(js)) for js in self.joints]      # each bus's share of write()

    # ------------------------------------------------------------------ the buses
    def _peers(self, caller: CanopenHardware) -> None:
        """Keep the other started buses alive while ``caller`` waits (its start-up)."""
        for s in self.subs:
            if s is not caller and s.network is not None:
                s.keepalive_own()

    @property
    def network(self):
        """The first bus's canopen network (None before start() and after stop())."""
        return self.subs[0].network

    @property
    def missed_cycles(self) -> int:
        return sum(s.missed_cycles for s in self.subs)

    @property
    def late_cycles(self) -> int:
        return sum(s.late_cycles for s in self.subs)

    @property
    def bus_off(self) -> bool:
        return any(s.bus_off for s in self.subs)

    def keepalive(self) -> None:
        for s in self.subs:
            if s.network is not None:
                s.keepalive_own()

    def receive_pending(self) -> None:
        for s in self.subs:
            if s.network is not None:
                s.receive_pending()

    def heartbeat_arrival(self, node: int) -> float | None:
        for s in self.subs:
            t = s.heartbeat_arrival(node)
            if t is not None:
                return t
        return None

    # ------------------------------------------------------------------ HardwareInterface
    def start(self, initial_torque: np.ndarray | None = None) -> None:
        init = np.zeros(self.n) if initial_torque is None else np.asarray(initial_torque, dtype=float).reshape(self.n)
        try:
            for s, js in zip(self.subs, self.joints):
                s.start(initial_torque=init[list(js)])
        except BaseException:
            self.stop()
            raise
        self._gather()

    def read(self) -> Measurement:
        """Every bus's SYNC, then every bus's TPDOs: one sample of all joints (reused object)."""
        subs, t_sync = self.subs, self._t_sync
        for i in range(len(subs)):
            t_sync[i] = subs[i].begin_read()
        m = self.meas
        m.faults = 0
        try:
            for i in range(len(subs)):
                subs[i].end_read(t_sync[i])
        finally:
            self._gather()
        return m

    def _gather(self) -> None:
        """The buses' samples into the one of all joints."""
        m = self.meas
        m.faults, m.valid, m.late = 0, True, False
        for s, js in zip(self.subs, self.joints):
            ms = s.meas
            for k, j in enumerate(js):
                m.q[j], m.theta_m[j], m.tau_m_applied[j] = ms.q[k], ms.theta_m[k], ms.tau_m_applied[k]
                m.q_counts[j], m.theta_m_counts[j], m.statusword[j] = \
                    ms.q_counts[k], ms.theta_m_counts[k], ms.statusword[k]
            m.faults |= ms.faults
            m.valid = m.valid and ms.valid
            m.late = m.late or ms.late
        first = self.subs[0].meas
        m.cycle, m.t, m.t_mono = first.cycle, first.t, first.t_mono

    def write(self, tau_m: np.ndarray) -> None:
        for s, js, tau in zip(self.subs, self.joints, self._tau):
            for k, j in enumerate(js):
                tau[k] = tau_m[j]
            s.write(tau)

    def actuated(self, tau_m: np.ndarray) -> np.ndarray:
        out = self._act
        for s, js, tau in zip(self.subs, self.joints, self._tau):
            for k, j in enumerate(js):
                tau[k] = tau_m[j]
            a = s.actuated(tau)
            for k, j in enumerate(js):
                out[j] = a[k]
        return out

    def safe_stop(self) -> None:
        for s in self.subs:
            s.safe_stop()

    def reset_fault(self) -> None:
        for s in self.subs:
            s.reset_fault()
        self._gather()

    def stop(self) -> None:
        errors = []
        for s in self.subs:
            try:
                s.stop()
            except Exception as e:  # noqa: BLE001 - stop every bus, then report the first failure
                errors.append(e)
        if errors:
            raise errors[0]


def make_canopen_hardware(cfg: ModelConfig, buses: dict[str, can.BusABC] | None = None, **kw) -> HardwareInterface:
    """The CANopen driver of ``cfg``: :class:`CanopenHardware` on one bus, :class:`CanopenBuses`
    on several (``buses``: an open handle per channel)."""
    b = cfg.hardware.bus
    if len(b.buses()) == 1:
        return CanopenHardware(cfg, (buses or {}).get(b.channel), **kw)
    return CanopenBuses(cfg, buses, **kw)
