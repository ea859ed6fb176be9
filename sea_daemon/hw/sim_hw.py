""":class:`HardwareInterface` directly on the simulator's plant, without CAN (offline daemon).

Same timing as the CANopen hardware against the lock-step device model (see
:mod:`sea_daemon.hw.interface`): ``read()`` of cycle k first steps the plant over [t_k-1, t_k] with
the torque in force, then samples the encoders at t_k (the simulator's quantised
``measure()`` when the plant has one): the one sample step of every simulated run,
:class:`sea_daemon.core.sim.sampling.SampledPlant`.  A torque given to ``write()`` in cycle k is in force
over [t_k+d, t_k+d+1], d = ``actuation_delay`` (default 0: the simulator's zero-order hold;
1: like a synchronous RPDO).  A read → update → write loop thus runs the plant in lock-step,
as fast as the caller goes.  No faults happen here except the ones a plant raises.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from sea_daemon.core.sim.sampling import SampledPlant
from sea_daemon.hw.interface import HardwareInterface, Measurement


class SimHardware(HardwareInterface):
    """The plant behind :class:`HardwareInterface`: ``read()`` steps it, ``write()`` sets the torque.

    ``tau_h_act(t)``: the subject's torque [N m] over the interval that starts at plant time t
    (default zero); ``torque_limit`` (one, or each joint's) clips the written torque like the
    drives' max torque.
    """

    def __init__(self, plant, period: float, *, torque_limit=math.inf, actuation_delay: int = 0,
                 tau_h_act: Callable[[float], np.ndarray] | None = None):
        if actuation_delay not in (0, 1):
            raise ValueError(f"actuation_delay must be 0 or 1, got {actuation_delay!r}")
        self.plant = plant
        #: the plant stepped and read per sample (its ``k`` is the cycle, ``t`` the sample time)
        self.sampled = SampledPlant(plant, period)
        self.n = self.sampled.n
        self.period = self.sampled.period
        self.torque_limit = np.array(np.broadcast_to(np.asarray(torque_limit, dtype=float), (self.n,)))
        self.actuation_delay = int(actuation_delay)
        self.tau_h_act = tau_h_act or (lambda t, _z=np.zeros(self.n): _z)
        self.meas = Measurement(self.n)
        self._tau = np.zeros(self.n)          # in force over the current interval
        self._pending = np.zeros(self.n)      # written, in force from the next SYNC (delay 1)
        self._written = np.zeros(self.n)      # last write()
        self._stopped = False
        self.running = False

    def start(self, initial_torque: np.ndarray | None = None) -> None:
        """Ready to cycle; ``initial_torque`` is in force until the first ``write()`` takes over."""
        self.running = True
        self._stopped = False
        if initial_torque is not None:
            self._written[:] = np.asarray(initial_torque, dtype=float).reshape(self.n)

    def read(self) -> Measurement:
        m = self.meas
        sp = self.sampled
        if sp.k >= 0:
            # the interval [t_k-1, t_k] with the torque in force (delay 0: written in cycle k-1)
            self._tau[:] = self._pending if self.actuation_delay else self._written
            if self._stopped:
                self._tau[:] = 0.0
            q, th = sp.read(self._tau, self.tau_h_act(self.plant.t))
        else:
            q, th = sp.read()
        self._pending[:] = self._written      # delay 1: actuated at this SYNC
        m.cycle, m.t, m.t_mono = sp.k, sp.t, float(self.plant.t)
        m.q[:] = q
        m.theta_m[:] = th
        m.tau_m_applied[:] = self._tau                 # the torque over [t_k-1, t_k]
        m.faults, m.valid, m.late = 0, True, False
        return m

    def write(self, tau_m: np.ndarray) -> None:
        tau = np.clip(np.nan_to_num(np.asarray(tau_m, dtype=float), nan=0.0), -self.torque_limit, self.torque_limit)
        self._written[:] = 0.0 if self._stopped else tau

    def safe_stop(self) -> None:
        self._stopped = True
        self._written[:] = 0.0
        self._pending[:] = 0.0

    def reset_fault(self) -> None:
        self._stopped = False

    def stop(self) -> None:
        self.safe_stop()
        self.running = False
