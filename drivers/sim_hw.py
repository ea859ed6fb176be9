""":class:`HardwareInterface` directly on the simulator's plant, without CAN (offline daemon).

Same timing as the CANopen hardware against the lock-step device model (see
:mod:`drivers.interface`): ``read()`` of cycle k samples the plant's encoders at t_k (the
simulator's quantised ``measure()`` when the plant has one), then latches the torque written
in cycle k-1 and steps the plant over [t_k, t_k+1] with it; ``write(tau_m)`` only stores the
set-point.  A read → update → write loop thus runs the plant in lock-step, as fast as the
caller goes.  No faults happen here except the ones a plant raises.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .interface import HardwareInterface, Measurement


class SimHardware(HardwareInterface):
    def __init__(self, plant, period: float, *, torque_limit: float = math.inf,
                 tau_h_act: Callable[[float], np.ndarray] | None = None):
        self.plant = plant
        self.n = int(np.atleast_1d(plant.q).shape[0])
        self.period = float(period)
        self.torque_limit = float(torque_limit)
        self.tau_h_act = tau_h_act or (lambda t, _z=np.zeros(self.n): _z)
        self.meas = Measurement(self.n)
        self._tau = np.zeros(self.n)          # latched: acts over the current cycle
        self._pending = np.zeros(self.n)      # written, acts from the next read()
        self._cycle = -1
        self._stopped = False
        self.running = False

    def start(self) -> None:
        self.running = True
        self._stopped = False

    def read(self) -> Measurement:
        m = self.meas
        self._cycle += 1
        m.cycle, m.t, m.t_mono = self._cycle, self._cycle * self.period, float(self.plant.t)
        measure = getattr(self.plant, "measure", None)
        if measure is not None:
            q, th = measure()
        else:
            q, th = self.plant.q, self.plant.theta_m
        m.q[:] = q
        m.theta_m[:] = th
        m.tau_m_applied[:] = self._tau                 # the torque over [t_k-1, t_k]
        m.faults, m.valid = 0, True
        self._tau[:] = 0.0 if self._stopped else self._pending
        self.plant.step(self._tau.copy(), self.period, self.tau_h_act(self.plant.t))
        return m

    def write(self, tau_m: np.ndarray) -> None:
        tau = np.clip(np.nan_to_num(np.asarray(tau_m, dtype=float), nan=0.0), -self.torque_limit, self.torque_limit)
        self._pending[:] = tau

    def safe_stop(self) -> None:
        self._stopped = True
        self._pending[:] = 0.0

    def reset_fault(self) -> None:
        self._stopped = False

    def stop(self) -> None:
        self.safe_stop()
        self.running = False
